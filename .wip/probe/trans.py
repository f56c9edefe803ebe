"""Print the FSM/patient transitions with ankles, CoM, tips: where steps land and slide."""
import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path
from tools import pipeline
ap = argparse.ArgumentParser(); ap.add_argument("--config", default=None); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=3); ap.add_argument("--fixed", type=float, default=None)
a = ap.parse_args()
cfg = load_config(a.config or default_config_path())
policy = None
if a.fixed is not None:
    from controller.factory import step_bounds
    from controller.policy import StepPolicy
    policy = StepPolicy(step_bounds(cfg.controller), fixed_m=a.fixed)
last = [None, None, -1.0]
def on_tick(res, core, host):
    w = host.patient; p = w.patient; world = w.world
    key = (core.fsm.state.name, core.gait_part, p.phase.value)
    t = w.t
    if key != last[0] or (last[2] >= 0 and t - last[2] >= 0.4 and last[2] > 0):
        f = world.contact_normal_force
        tp = [p.tip_point(s)[0] for s in "lr"]
        el = [world.q[world.joint_index[f"elbow_{s}"]] for s in "lr"]
        print(f"{t:6.2f} {key[0][:10]:10s} {key[1][:5]:5s} {key[2]:6s} ank=({p.ankle_xy('l')[0]:.3f},{p.ankle_xy('r')[0]:.3f}) com={w.kin.com[0]:.3f} tips=({tp[0]:.3f},{tp[1]:.3f}) sticks=({f('forearm_l'):.0f},{f('forearm_r'):.0f}) feet=({f('foot_l'):.0f},{f('foot_r'):.0f}) el=({el[0]:.2f},{el[1]:.2f}) lx={p.lean_goal_x:.3f}")
        last[2] = t if key[0].startswith("SWING") or "LAND" in key[0] else (t if key != last[0] and False else last[2])
    if key != last[0]:
        last[2] = t if key[0].startswith("SWING") else -1.0
    last[0] = key
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, policy=policy, on_tick=on_tick, compare_ratio=False)
print("RESULT", out.cycles_completed, out.fell, out.fall_reason, out.fault, out.stalled)
for s in out.steps: print(f"  step leg={s.leg} len={s.length_m:.3f} placed={s.placed_m:.3f} X={s.x_ratio:.2f}")
