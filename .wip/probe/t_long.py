import sys, dataclasses, math
sys.path.insert(0, "/work/i43")
from config import default_config_path, load_config, with_overrides
from sim.walk import walk, gait_settings
from sim.sweep import episode_summary
mode, length, seed = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
SIM = with_overrides(load_config(default_config_path()), {"sim.mode": mode, "sim.patient.intention.regime": "steady"}).sim
r = walk(SIM, gait_settings(SIM, step_length_m=length), seed=seed, max_steps=6, max_time_s=30.0)
s = episode_summary(r)
print(mode, length, seed, r.fell, r.steps_completed, s.get("fall_reason"), s.get("fall_phase"), s.get("fall_step"), s.get("fall_margin_m"), getattr(r, "stalled", None))
