"""Whole-body kinematics checked against the physics: static equilibrium of every joint."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from config import default_config_path, load_config
from sim.kinematics import Kinematics
from sim.model import ANKLE_JOINTS, JOINT_ORDER
from sim.sensors import contact_force_on_robot
from sim.world import StancePose, World

CFG = load_config(default_config_path())


@pytest.mark.parametrize("mode", ["full3d", "sagittal"])
def test_joint_torques_balance_gravity_and_contact_forces_at_rest(mode):
    pose = StancePose(foot_x_m=(-0.05, 0.05), tip_xy_m=((0.42, 0.30), (0.38, -0.28)), trunk_pitch_rad=0.12, hip_x_m=0.07)
    with World(dataclasses.replace(CFG.sim, mode=mode)) as world:
        world.place(pose)
        kin = Kinematics(world)
        applied, expected = np.zeros(kin.n), np.zeros(kin.n)
        for step in range(700):
            world.step()
            if step < 500:
                continue
            kin.update()
            generalised = np.zeros(kin.n)
            for cp in world.client.getContactPoints(bodyA=world.robot, bodyB=world.floor):
                generalised += kin.point_jacobian(cp[3], np.asarray(cp[5])).T @ contact_force_on_robot(cp)
            applied += world.tau
            expected += kin.gravity_torques() - generalised
        actuated = [i for i, name in enumerate(JOINT_ORDER) if name not in ANKLE_JOINTS]
        assert np.max(np.abs(applied - expected)[actuated]) / 200 < 0.5  # N.m, averaged over 200 steps
        assert kin.com == pytest.approx(world.com())


def test_the_generalised_force_of_many_contacts_is_the_sum_of_their_jacobian_products():
    """``generalised_force`` sums ``J^T f`` over contacts at once; the same as one by one."""
    rng = np.random.default_rng(3)
    with World(CFG.sim) as world:
        world.place(StancePose(foot_x_m=(-0.05, 0.05), tip_xy_m=((0.42, 0.30), (0.38, -0.28))))
        kin = Kinematics(world)
        links = [-1, 2, 5, kin.n - 1, 5]
        points = rng.normal(size=(len(links), 3))
        forces = rng.normal(scale=50.0, size=(len(links), 3))
        one_by_one = sum(kin.point_jacobian(link, p).T @ f for link, p, f in zip(links, points, forces))
        assert kin.generalised_force(links, points, forces) == pytest.approx(one_by_one, abs=1e-9)
