"""Trace hip depth, elbows, stick loads, X per tick (lock-step controller walk)."""
import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path, with_overrides
from tools import pipeline
ap = argparse.ArgumentParser(); ap.add_argument("--seed", type=int, default=0); ap.add_argument("--cycles", type=int, default=3)
ap.add_argument("--every", type=int, default=10); ap.add_argument("--set", action="append", default=[])
a = ap.parse_args()
cfg = load_config(default_config_path())
ov = {}
for kv in a.set:
    k, v = kv.split("="); ov[k] = float(v) if v.replace('.','',1).replace('-','',1).isdigit() else v
cfg = with_overrides(cfg, ov)
n = [0]
def on_tick(res, core, host):
    n[0] += 1
    if n[0] % a.every: return
    w = host.patient; p = w.patient; world = w.world; g = core.gait
    el = [world.q[p.arm_joints[s][2]] for s in "lr"]
    f = world.contact_normal_force
    print(f"{w.t:6.2f} {core.fsm.state.name[:6]:6s} {core.gait_part[:5]:5s} stand={g.stand_height_m:.3f} depth={g.depth_m:.3f} elbow=({el[0]:.2f},{el[1]:.2f}) sticks {f('forearm_l'):4.0f} {f('forearm_r'):4.0f} feet {f('foot_l'):4.0f} {f('foot_r'):4.0f} arms_el={np.round(world.arms.applied,0).tolist()[2::3]}")
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode="full3d", on_tick=on_tick, compare_ratio=False)
print("RESULT", out.cycles_completed, out.fell, out.fall_reason, [round(s.length_m, 3) for s in out.steps])
