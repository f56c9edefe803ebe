import sys, dataclasses, math
sys.path.insert(0, "/work/i43")
from config import default_config_path, load_config, with_overrides
from sim.walk import walk, gait_settings
from sim.patient import Patient, OTHER, Phase
mode, seed = sys.argv[1], int(sys.argv[2])
SIM = with_overrides(load_config(default_config_path()), {"sim.mode": mode, "sim.patient.intention.regime": "steady"}).sim
def start(self):
    self.stick_queue = [OTHER[self.front_foot()]]
    self.plan.intention = self.intention.next()
    self._set_phase(Phase.SHIFT)
Patient._start_stick_moves = start
Patient.lift_window = lambda self, lifting: (-math.inf, math.inf)
r = walk(SIM, gait_settings(SIM, step_length_m=0.10), seed=seed, max_steps=4, max_time_s=30)
print(mode, seed, r.fell, r.fall_direction, r.fall_reason, r.steps_completed, r.fall_phase)
