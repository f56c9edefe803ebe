"""slam.py: per stick set-down: peak normal force in the 0.4 s after the tip path ends; tip slide while planted."""
import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config, default_config_path
from tools import pipeline
ap = argparse.ArgumentParser(); ap.add_argument("--config", default=None); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=3)
a = ap.parse_args()
cfg = load_config(a.config or default_config_path())
st = {"l": None, "r": None}; peaks = []; slides = []; maxf = {"l": 0.0, "r": 0.0}
def on_tick(res, core, host):
    w = host.patient; p = w.patient; world = w.world
    for s in "lr":
        f = world.contact_normal_force(f"forearm_{s}")
        moving = s in p.tip_path
        d = st[s]
        if moving and (d is None or d[0] != "move"):
            if d is not None and d[0] == "planted":
                slides.append(abs(p.tip_point(s)[0] - d[2]))
            st[s] = ["move", w.t, 0.0]
        elif not moving and d is not None and d[0] == "move":
            st[s] = ["set", w.t, 0.0]
        d = st[s]
        if d is not None and d[0] == "move" and p.tip_path[s][2] >= 0.9:
            d[2] = max(d[2], f)
        if d is not None and d[0] == "set":
            d[2] = max(d[2], f)
            if w.t - d[1] > 0.3:
                peaks.append(d[2]); st[s] = ["planted", w.t, p.tip_point(s)[0]]
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, on_tick=on_tick, compare_ratio=False)
print(f"seed {a.seed}: cycles {out.cycles_completed}; set-down peak N: median {np.median(peaks):.0f} max {max(peaks):.0f}; slide while planted m: median {np.median(slides):.3f} max {max(slides):.3f}")
