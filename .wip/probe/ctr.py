"""Trace a controller walk (lock-step) with the sim's truth."""
import sys, argparse, dataclasses
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path, with_overrides
from tools import pipeline
from controller.policy import StepPolicy
ap = argparse.ArgumentParser(); ap.add_argument("--config", default=None); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=3); ap.add_argument("--fixed", type=float, default=None)
ap.add_argument("--every", type=int, default=10); ap.add_argument("--t0", type=float, default=0.0)
a = ap.parse_args()
cfg = load_config(a.config or default_config_path())
policy = None
if a.fixed is not None:
    from controller.factory import step_bounds
    policy = StepPolicy(step_bounds(cfg.controller), fixed_m=a.fixed)
n = [0]
def on_tick(res, core, host):
    n[0] += 1
    w = host.patient
    if n[0] % a.every or w.t < a.t0: return
    p = w.patient; kin = w.kin; world = w.world
    g = core.gait
    com = kin.com
    f = world.contact_normal_force
    tp = [p.tip_point(s)[0] for s in "lr"]
    print(f"{w.t:6.2f} {core.fsm.state.name[:6]:6s} {core.gait_part[:5]:5s} pat={p.phase.value:6s} com=({com[0]:.3f},{com[1]:+.3f}) goal={g.goal_x:+.3f} cx={g._com_x:+.3f} v={g.com_velocity_m_s:+.2f} "
          f"ank=({p.ankle_xy('l')[0]:.3f},{p.ankle_xy('r')[0]:.3f}) tips=({tp[0]:.3f},{tp[1]:.3f}) feet {f('foot_l'):4.0f} {f('foot_r'):4.0f} sticks {f('forearm_l'):4.0f} {f('forearm_r'):4.0f} "
          f"tau={np.round(g.torques,0).tolist()} ct={p.com_target[0]:.3f} rp={np.round(core.measurements.trunk_rpy_rad[:2],2).tolist() if core.measurements is not None else None} arms={np.round(world.arms.applied,0).tolist()} still={g._lean_still_s:.1f} moved={g.sticks.moved} sf={np.round(g.sticks.force_n,0).tolist()} lx={p.lean_goal_x:.3f} lifted={g.sticks.lifted}")
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, policy=policy, on_tick=on_tick, compare_ratio=False)
print("RESULT", out.cycles_completed, out.fell, out.fall_reason, out.fault, out.stalled, [round(s.length_m, 3) for s in out.steps], [round(s.placed_m, 3) for s in out.steps])
