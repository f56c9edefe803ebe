import sys; sys.path.insert(0, "/work/i43"); sys.path.insert(0, "/work/i43/tests")
import numpy as np, dataclasses
import test_controller_estimator as T
sim_cfg = dataclasses.replace(T.CFG.sim, mode="sagittal")
est_ = T.StateEstimator(T.CFG.controller.body, T.CFG.controller.legs)
with T.World(sim_cfg) as world:
    world.place(T.initial_pose(sim_cfg))
    walker = T.Walker(world, sim_cfg, T.gait_settings(sim_cfg, step_length_m=0.10), np.random.default_rng(2))
    reading = walker.start()
    for k in range(500):
        reading = walker.tick(reading)
        est = est_.update(T.measurements(reading))
        com, ankles, tips, feet, sticks, ratio = T.truth(walker, world)
        for i in range(2):
            if sticks[i] and est.sticks_loaded[i]:
                e = np.linalg.norm(est.tips[i][:2] - tips[i][:2])
                if e > 0.03: print(k, i, round(e,3), walker.patient.phase.value, round(world.contact_normal_force("forearm_" + "lr"[i]),0), est.tips[i].round(3), tips[i].round(3), "elbow est", np.round(est.elbow_rad,3), "true", round(world.q[world.joint_index["elbow_" + "lr"[i]]],3), "floor", round(est.floor_z,3))
