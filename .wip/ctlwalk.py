"""A lock-step controller walk with the prototype patient swapped in."""
import sys, json, argparse, importlib, math
sys.path.insert(0, "/work/main"); sys.path.insert(0, "/tmp/probe")
import numpy as np
from config.loader import load_config, default_config_path, with_overrides
import config.sim_schema as _ss; _ss.ModelConfig.validate = lambda self: None
ap = argparse.ArgumentParser()
ap.add_argument("--mod", default="w7"); ap.add_argument("--set", action="append", default=[]); ap.add_argument("--seeds", type=int, default=2)
ap.add_argument("--mode", default="full3d"); ap.add_argument("--cycles", type=int, default=5); ap.add_argument("--fixed", type=float, default=None)
ap.add_argument("--jobs", type=int, default=2)
a = ap.parse_args()
ov = {}
for s in a.set:
    k, v = s.split("=", 1)
    try: ov[k] = json.loads(v)
    except ValueError: ov[k] = v

def one(seed):
    mod = importlib.import_module(a.mod)
    import nodes.host as nh
    nh.Walker = mod.Walker; nh.initial_pose = mod.initial_pose
    from tools import pipeline
    from controller.policy import StepPolicy
    cfg = with_overrides(load_config(default_config_path()), ov)
    policy = None
    if a.fixed is not None:
        from controller.policy import StepPolicy
        policy = StepPolicy.fixed(a.fixed) if hasattr(StepPolicy, "fixed") else None
    out = pipeline.walk(cfg, cycles=a.cycles, seed=seed, mode=a.mode, policy=policy, compare_ratio=False)
    xs = [round(s.x_ratio, 2) for s in out.landed] if out.landed and hasattr(out.landed[0], "x_ratio") else []
    return dict(seed=seed, cycles=out.cycles_completed, fell=out.fell, why=(out.fall_reason or out.fault or out.hold or ("stall" if out.stalled else ""))[:70],
                F=round(out.mean_stick_force_n, 1) if out.landed else None, t=round(out.sim_time_s, 1), X=xs[:10], patient=out.patient)

from concurrent.futures import ProcessPoolExecutor
with ProcessPoolExecutor(a.jobs) as pool:
    for r in pool.map(one, range(a.seeds)):
        print(json.dumps(r))
