"""Per-phase arm state: elbow angle, elbow torque, stick forces, X, in a lock-step walk."""
import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path
from tools import pipeline
ap = argparse.ArgumentParser(); ap.add_argument("--config", default=None); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=3); ap.add_argument("--every", type=int, default=10)
a = ap.parse_args()
cfg = load_config(a.config or default_config_path())
n = [0]
def on_tick(res, core, host):
    n[0] += 1
    if n[0] % a.every: return
    w = host.patient; p = w.patient; world = w.world
    el = [world.q[world.joint_index[f"elbow_{s}"]] for s in "lr"]
    ap_ = world.arms.applied
    f = world.contact_normal_force
    est = core.estimator.last if hasattr(core.estimator, "last") else None
    print(f"{w.t:6.2f} {p.phase.value:6s} elbow=({el[0]:.2f},{el[1]:.2f}) tau_el=({ap_[2]:+.0f},{ap_[5]:+.0f}) sh=({ap_[0]:+.0f},{ap_[3]:+.0f}) sticks {f('forearm_l'):4.0f} {f('forearm_r'):4.0f} feet {f('foot_l'):4.0f} {f('foot_r'):4.0f} com={w.kin.com[0]:.3f} lx={p.lean_goal_x:.3f}")
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, on_tick=on_tick, compare_ratio=False)
print("RESULT", out.cycles_completed, out.fell, out.fall_reason, out.stalled, [round(s.x_ratio, 2) for s in out.steps])
