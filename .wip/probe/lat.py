import sys
sys.path.insert(0, "/work/main")
import numpy as np
from config.loader import load_config, default_config_path
from sim.walk import Walker, gait_settings, initial_pose
from sim.world import World
from sim.sensors import rpy_from_matrix
cfg = load_config(default_config_path()).sim
L, seed = float(sys.argv[1]), int(sys.argv[2])
rows = []
def on_tick(_world, _t):
    w = W[0]
    p = w.patient; world = w.world
    o, rot = world.link_frame("trunk"); r, pi, _ = rpy_from_matrix(rot)
    f = world.contact_normal_force
    tips = [p.tip_point(s) for s in "lr"]
    win = p.next_lift_window() if p.phase.value == "shift" else (np.nan, np.nan)
    rows.append(f"{w.t:6.2f} {p.phase.value:6s} q={p.stick_queue} planted={[p.planted[s] for s in 'lr']} com=({w.kin.com[0]:.3f},{w.kin.com[1]:+.3f}) tgt=({p.com_target[0]:.3f},{p.com_target[1]:+.3f}) win=({win[0]:.3f},{win[1]:.3f}) ank=({p.ankle_xy('l')[0]:.3f},{p.ankle_xy('l')[1]:+.3f} / {p.ankle_xy('r')[0]:.3f},{p.ankle_xy('r')[1]:+.3f}) tips=({tips[0][0]:.3f},{tips[0][1]:+.3f} / {tips[1][0]:.3f},{tips[1][1]:+.3f}) st=({f('forearm_l'):.0f},{f('forearm_r'):.0f}) ft=({f('foot_l'):.0f},{f('foot_r'):.0f}) roll={r:+.2f} hip={o[2]:.3f} res={p.last.residual:.0f}")
W = []
with World(cfg) as world:
    world.place(initial_pose(cfg))
    W.append(Walker(world, cfg, gait_settings(cfg, step_length_m=L), np.random.default_rng(seed)))
    res = W[0].run(20, on_tick=on_tick)
print(res.fall_reason, res.fall_phase, len(res.steps))
for line in rows[-int(sys.argv[3]):][::int(sys.argv[4])]: print(line)
