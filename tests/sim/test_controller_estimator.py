"""The state estimator against the simulation's ground truth, from the sensor values the nodes send
(noisy and quantised), over a walk of the scripted gait."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from config import default_config_path, load_config
from controller.estimator import Measurements, StateEstimator, rot_rpy
from protocol.geometry import fore_aft_ratio
from sim.truth import extent_on_line, pivot_polygon
from sim.walk import OTHER, Walker, gait_settings, initial_pose
from sim.world import World

CFG = load_config(default_config_path())


def measurements(reading) -> Measurements:
    return Measurements(
        reading.joint_position_rad, reading.trunk_rpy_rad, reading.stick_rpy_rad, reading.stick_force_n,
        reading.heel_force_n, reading.toe_force_n,
    )


def test_rot_rpy_matches_the_imu_convention():
    from sim.linalg import rpy_from_matrix

    rng = np.random.default_rng(0)
    for _ in range(20):
        rpy = rng.uniform([-1, -1.2, -3], [1, 1.2, 3])
        assert np.allclose(rpy_from_matrix(rot_rpy(*rpy)), rpy)


def truth(walker: Walker, world: World, threshold_n: float = 20.0):
    """Ground truth in the heading frame: CoM, ankles, tips, loaded contacts, X_CoM/X_SP."""
    origin, rot = world.link_frame("trunk")
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    to_heading = rot_rpy(0.0, 0.0, -yaw)

    def h(p):
        return to_heading @ (np.asarray(p) - origin)

    com = h(walker.kin.com)
    ankles = np.array([h(walker.kin.joint_origin[walker.patient.ankle_idx[s]]) for s in "lr"])
    tips = np.array([h(walker.tip_point(s)) for s in "lr"])
    feet = [world.contact_normal_force(f"foot_{s}") > threshold_n for s in "lr"]
    sticks = [world.contact_normal_force(f"forearm_{s}") > threshold_n for s in "lr"]
    poly = pivot_polygon(ankles[feet][:, :2], tips[sticks][:, :2], ankle_halfwidth=CFG.hardware.foot.half_width_m)
    return com, ankles, tips, feet, sticks, fore_aft_ratio(float(com[0]), poly[:, 0].tolist(), 0.0)


@pytest.mark.parametrize("mode", ["sagittal", "full3d"])
def test_estimates_match_the_ground_truth_over_a_walk(mode):
    sim_cfg = dataclasses.replace(CFG.sim, mode=mode)
    estimator = StateEstimator(CFG.controller.body, CFG.controller.legs, CFG.hardware)
    errors: dict[str, list[float]] = {"com": [], "ankle": [], "tip": [], "ratio": [], "stance": []}
    agree = []
    with World(sim_cfg) as world:
        world.place(initial_pose(sim_cfg))
        walker = Walker(world, sim_cfg, gait_settings(sim_cfg, step_length_m=0.10), np.random.default_rng(2))
        reading = walker.start()
        for _ in range(500):  # 10 s: the first steps
            reading = walker.tick(reading)
            assert walker.fall is None
            est = estimator.update(measurements(reading))
            com, ankles, tips, feet, sticks, ratio = truth(walker, world)
            errors["com"].append(np.linalg.norm(est.com[:2] - com[:2]))
            errors["ankle"].append(np.abs(est.ankles - ankles).max())
            for i in range(2):
                if sticks[i] and est.sticks_loaded[i]:
                    errors["tip"].append(np.linalg.norm(est.tips[i][:2] - tips[i][:2]))
            agree.append(list(est.feet_loaded) == feet and list(est.sticks_loaded) == sticks)
            if not (math.isnan(ratio) or math.isnan(est.x_ratio)):  # nan: no fore-aft extent to speak of
                errors["ratio"].append(abs(est.x_ratio - ratio))
            if all(feet) and all(sticks):  # where a swing may start: over its stance sole and the tips
                stance = "lr".index(OTHER[walker.next_swing])
                foot = CFG.hardware.foot
                sole = [ankles[stance][:2] + (dx, dy) for dx in (-foot.heel_back_m, foot.toe_front_m) for dy in (-foot.half_width_m, foot.half_width_m)]
                support = np.vstack([sole, tips[:, :2]])
                rear, front = support[:, 0].min(), extent_on_line(support, com[:2])[1]  # the heel, the tips' line
                want = (com[0] - rear) / (front - rear)
                errors["stance"].append(abs(estimator.stance_ratio(est, stance) - want))
        assert len(walker.steps) >= 2
    worst = {k: float(np.max(v)) for k, v in errors.items()}
    mean = {k: float(np.mean(v)) for k, v in errors.items()}
    # Measured (seed 2): ankle 2 / 6 mm mean / worst, CoM 0.7 / 5 mm, tips 4-6 / 30 mm, ratio 0.010.
    assert mean["ankle"] < 0.004 and worst["ankle"] < 0.01  # encoder and IMU noise over a 0.9 m leg
    assert mean["com"] < 0.005 and worst["com"] < 0.015
    assert mean["tip"] < 0.015 and worst["tip"] < 0.05
    assert mean["ratio"] <= 0.05  # the goal for X_CoM/X_SP
    assert len(errors["stance"]) > 50 and mean["stance"] <= 0.05  # the compensation's input
    assert np.mean(agree) > 0.85  # loaded or not: the sensors' thresholds agree with the contacts' (2 N noise near a 10 N threshold)
    assert len(errors["ratio"]) > 0.7 * len(errors["com"])


def test_a_stick_that_cannot_reach_the_floor_keeps_the_last_elbow_angle_and_says_so():
    estimator = StateEstimator(CFG.controller.body, CFG.controller.legs, CFG.hardware)
    standing = Measurements(
        np.array([0.2, 0.2, 0.2, 0.2]), np.zeros(3), np.array([[0.0, -0.3, 0.0], [0.0, -0.3, 0.0]]),
        np.array([100.0, 100.0]), np.array([200.0, 200.0]), np.array([200.0, 200.0]),
    )
    first = estimator.update(standing)
    assert first.tips_on_floor == (True, True)
    assert first.tips[:, 2] == pytest.approx([first.floor_z] * 2, abs=1e-9)
    lifted = dataclasses.replace(standing, stick_rpy_rad=np.array([[0.0, -2.8, 0.0], [0.0, -0.3, 0.0]]))  # raised high
    second = estimator.update(lifted)
    assert second.tips_on_floor == (False, True) and second.elbow_rad[0] == first.elbow_rad[0]
    assert all(np.isfinite(second.com)) and not math.isnan(second.x_ratio)
