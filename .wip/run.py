"""Runner: walks of the scripted gait with config overrides, in parallel; prints outcome per walk."""
import sys, json, math, importlib, argparse
sys.path.insert(0, "/work/main"); sys.path.insert(0, "/tmp/probe")
import numpy as np
from concurrent.futures import ProcessPoolExecutor
from config.loader import load_config, default_config_path, with_overrides
import config.sim_schema as _ss; _ss.ModelConfig.validate = lambda self: None

def one(args):
    modname, overrides, length, seed, steps = args
    mod = importlib.import_module(modname)
    cfg = with_overrides(load_config(default_config_path()), overrides).sim
    settings = mod.gait_settings(cfg, step_length_m=length)
    r = mod.walk(cfg, settings, seed=seed, max_steps=steps, max_time_s=150)
    landed = [s for s in r.steps if s.landed]
    xs = [getattr(s, "x_swing", math.nan) for s in r.steps]
    return dict(L=length, seed=seed, steps=r.steps_completed, fell=r.fell, why=(r.fall_reason or "")[:60], phase=r.fall_phase,
                t=round(r.duration_s,1), F=round(float(np.mean([s.mean_stick_force_n for s in landed])),1) if landed else None,
                X=[round(x,2) for x in xs][:12], extra=getattr(r, "extra", None))

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--mod", default="sim.walk")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--lengths", default="0.10")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=20)
    a = ap.parse_args()
    ov = {"sim.mode": "full3d", "sim.patient.intention.regime": "steady"}
    for s in a.set:
        k, v = s.split("=", 1)
        try: ov[k] = json.loads(v)
        except ValueError: ov[k] = v
    jobs = [(a.mod, ov, float(L), s, a.steps) for L in a.lengths.split(",") for s in range(a.seeds)]
    with ProcessPoolExecutor(2) as pool:
        for r in pool.map(one, jobs):
            print(json.dumps(r))
