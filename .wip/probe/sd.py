import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path
from tools import pipeline
ap = argparse.ArgumentParser(); ap.add_argument("--seed", type=int); ap.add_argument("--mode"); ap.add_argument("--cycles", type=int)
ap.add_argument("--t0", type=float); ap.add_argument("--t1", type=float); ap.add_argument("--side", default="r")
a = ap.parse_args()
cfg = load_config(default_config_path())
def on_tick(res, core, host):
    w = host.patient; p = w.patient; world = w.world
    if not (a.t0 <= w.t <= a.t1): return
    s = a.side; f = world.contact_normal_force
    tp = p.tip_point(s); sh = p.shoulder(s)
    u = p.tip_path[s][2] if s in p.tip_path else -1
    print(f"{w.t:6.2f} {p.phase.value:6s} u={u:+.2f} planted={p.planted[s]} tip=({tp[0]:.3f},{tp[2]:+.3f}) sh-dx={tp[0]-sh[0]:+.3f} el={world.q[world.joint_index[f'elbow_{s}']]:.2f} F={f(f'forearm_{s}'):.0f} Fo={f('forearm_'+('l' if s=='r' else 'r')):.0f} feet=({f('foot_l'):.0f},{f('foot_r'):.0f}) com={w.kin.com[0]:.3f} ank={p.ankle_xy('r')[0]:.3f} tau={np.round(world.arms.applied,0).tolist()}")
pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, on_tick=on_tick, compare_ratio=False)
