"""dd.py: shoulder-tip distance, hip height, pitch and elbows, sampled by phase."""
import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path
from tools import pipeline
from sim.sensors import rpy_from_matrix
ap = argparse.ArgumentParser(); ap.add_argument("--config", default=None); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=2); ap.add_argument("--every", type=int, default=15)
a = ap.parse_args()
cfg = load_config(a.config or default_config_path())
n = [0]
def on_tick(res, core, host):
    n[0] += 1
    if n[0] % a.every: return
    w = host.patient; p = w.patient; world = w.world
    o, rot = world.link_frame("trunk")
    row = []
    for s in "lr":
        sh, tp = p.shoulder(s), p.tip_point(s)
        row.append(f"{s}: dx={tp[0]-sh[0]:+.3f} shz={sh[2]:.3f} D={np.linalg.norm(sh-tp):.3f} el={world.q[world.joint_index[f'elbow_{s}']]:.2f}")
    f = world.contact_normal_force
    print(f"{w.t:6.2f} {p.phase.value:6s} hip={o[2]:.3f} pit={rpy_from_matrix(rot)[1]:+.2f} " + " | ".join(row) + f" st=({f('forearm_l'):.0f},{f('forearm_r'):.0f})")
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, on_tick=on_tick, compare_ratio=False)
