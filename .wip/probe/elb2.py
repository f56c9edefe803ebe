"""Trace with a config: hip depth, elbows, arm torques, stick loads, CoM vs supports."""
import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path
from tools import pipeline
ap = argparse.ArgumentParser(); ap.add_argument("--seed", type=int, default=0); ap.add_argument("--cycles", type=int, default=3)
ap.add_argument("--every", type=int, default=10); ap.add_argument("--config", default=None); ap.add_argument("--t0", type=float, default=0)
a = ap.parse_args()
cfg = load_config(a.config or default_config_path())
n = [0]
def on_tick(res, core, host):
    n[0] += 1
    w = host.patient
    if n[0] % a.every or w.t < a.t0: return
    p = w.patient; world = w.world; g = core.gait; kin = w.kin
    el = [world.q[p.arm_joints[s][2]] for s in "lr"]
    f = world.contact_normal_force
    tp = [p.tip_point(s) for s in "lr"]
    print(f"{w.t:6.2f} {core.fsm.state.name[:6]:6s} {core.gait_part[:5]:5s} pat={p.phase.value[:5]} depth={g.depth_m:.3f} com=({kin.com[0]:.3f},{kin.com[1]:+.3f}) ank=({p.ankle_xy('l')[0]:.3f},{p.ankle_xy('r')[0]:.3f}) tips=({tp[0][0]:.3f},{tp[1][0]:.3f}) el=({el[0]:.2f},{el[1]:.2f}) sticks {f('forearm_l'):4.0f} {f('forearm_r'):4.0f} feet {f('foot_l'):4.0f} {f('foot_r'):4.0f} arms={np.round(world.arms.applied,0).astype(int).tolist()} ct={p.com_target[0]:.3f} goal={g.goal_x:+.3f}")
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode="full3d", on_tick=on_tick, compare_ratio=False)
print("RESULT", out.cycles_completed, out.fell, out.fall_reason, [round(s.length_m, 3) for s in out.steps], [None if s.x_ratio is None else round(s.x_ratio,3) for s in out.steps] if hasattr(out.steps[0],'x_ratio') else '')
