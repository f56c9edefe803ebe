import sys
sys.path.insert(0, "/work/i43am")
import numpy as np
from config.loader import load_config
from tools import pipeline
from tools.experiment.learn import walk_seed
from controller.factory import step_bounds
from controller.policy import StepPolicy
from sim.sensors import rpy_from_matrix
cfg = load_config(sys.argv[1]); i = int(sys.argv[2]); every = int(sys.argv[3])
c = cfg.controller.compensation
n = [0]
def on_tick(res, core, host):
    n[0] += 1
    if n[0] % every: return
    w = host.patient; p = w.patient; world = w.world
    o, rot = world.link_frame("trunk"); r, pi, _ = rpy_from_matrix(rot)
    f = world.contact_normal_force
    q = world.q; ji = world.joint_index
    el = [q[ji[f"elbow_{s}"]] for s in "lr"]
    tau = world.exo.applied
    print(f"{w.t:6.2f} {core.fsm.state.name[:8]:8s} {core.gait_part[:5]:5s} {p.phase.value:6s} pitch={pi:+.2f} goal={core.gait.pitch_goal_rad:+.2f} com={w.kin.com[0]:.3f} st=({f('forearm_l'):.0f},{f('forearm_r'):.0f}) ft=({f('foot_l'):.0f},{f('foot_r'):.0f}) el=({el[0]:.2f},{el[1]:.2f}) tau={np.round(tau,0)} hip={o[2]:.3f}")
out = pipeline.walk(cfg, cycles=10, seed=walk_seed(0, 100, i), mode="full3d", on_tick=on_tick, compare_ratio=False,
                    policy=StepPolicy(step_bounds(cfg.controller), theta=(c.alpha, c.xhat_com)))
print(out.fall_reason, out.fault, out.cycles_completed)
