import sys, argparse
sys.path.insert(0, "/work/i43")
import numpy as np
from config.loader import load_config
from tools import pipeline
ap = argparse.ArgumentParser(); ap.add_argument("--config", default="/work/i43/config/default.yaml"); ap.add_argument("--seed", type=int, default=0)
ap.add_argument("--t0", type=float); ap.add_argument("--t1", type=float); ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=3)
ap.add_argument("--every", type=int, default=5)
a = ap.parse_args()
cfg = load_config(a.config)
n=[0]
def on_tick(res, core, host):
    w = host.patient; p = w.patient
    n[0]+=1
    if not (a.t0 <= w.t <= a.t1) or n[0] % a.every: return
    g = core.gait; est = res.estimate
    ref = g._ref if g._ref is not None else 0
    try:
        clo = chi = 0
    except Exception as e:
        clo = chi = float('nan')
    lo, hi = p.next_lift_window()
    refx = p.ankle_xy("lr"[ref])[0]
    print(f"{w.t:6.2f} {core.fsm.state.name[:8]} pat={p.phase.value} lifting={p._lifting()} queue={p.stick_queue} pwin=({lo:.3f},{hi:.3f})   com={w.kin.com[0]:.3f},{w.kin.com[1]:+.3f} ct={p.com_target[0]:.3f} cgoal_abs={g.goal_x+refx:.3f} ank=({p.ankle_xy('l')[0]:.3f},{p.ankle_xy('l')[1]:+.3f};{p.ankle_xy('r')[0]:.3f},{p.ankle_xy('r')[1]:+.3f}) tips=({p.tip_point('l')[0]:.3f},{p.tip_point('r')[0]:.3f}) moved={g.sticks.moved}")
out = pipeline.walk(cfg, cycles=a.cycles, seed=a.seed, mode=a.mode, on_tick=on_tick, compare_ratio=False)
