"""fine.py --seed S --t0 A --t1 B [--every N]: per-tick patient/world state in a time window."""
import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path
from tools import pipeline
from sim.sensors import rpy_from_matrix
ap = argparse.ArgumentParser(); ap.add_argument("--config", default=None); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=4)
ap.add_argument("--t0", type=float); ap.add_argument("--t1", type=float); ap.add_argument("--every", type=int, default=3)
a = ap.parse_args()
cfg = load_config(a.config or default_config_path())
n = [0]
def on_tick(res, core, host):
    w = host.patient; p = w.patient; world = w.world
    t = w.t
    if not (a.t0 <= t <= a.t1): return
    n[0] += 1
    if n[0] % a.every: return
    f = world.contact_normal_force
    tp = [p.tip_point(s)[0] for s in "lr"]
    o, rot = world.link_frame("trunk")
    pitch = rpy_from_matrix(rot)[1]
    win = p.next_lift_window() if p.phase.value == "shift" else (float('nan'),)*2
    print(f"{t:6.2f} {core.fsm.state.name[:8]:8s} {core.gait_part[:5]:5s} {p.phase.value:6s} q={p.stick_queue} ank=({p.ankle_xy('l')[0]:.3f},{p.ankle_xy('r')[0]:.3f}) "
          f"com={w.kin.com[0]:.3f},{w.kin.com[1]:.3f} v={w.kin.com_velocity[0]:+.2f} tgt={p.com_target[0]:.3f} win=({win[0]:.3f},{win[1]:.3f}) goal={core.gait.goal_x:.3f} "
          f"tips=({tp[0]:.3f},{tp[1]:.3f}) st=({f('forearm_l'):.0f},{f('forearm_r'):.0f}) ft=({f('foot_l'):.0f},{f('foot_r'):.0f}) hip={o[2]:.3f} pit={pitch:+.2f} res={p.last.residual:.0f} push={p.push[0]:.0f}")
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, on_tick=on_tick, compare_ratio=False)
