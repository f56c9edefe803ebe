"""The HHEA world: loads from config, stands on feet and sticks, sensors read what physics does."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from config import ConfigError, default_config_path, load_config, with_overrides
from sim.model import JOINT_ORDER, build_body, urdf
from sim.sensors import Sensors
from sim.world import GRAVITY, StancePose, World

CFG = load_config(default_config_path())
STAND = StancePose(foot_x_m=(0.0, 0.0), tip_xy_m=((0.40, 0.30), (0.40, -0.30)), trunk_pitch_rad=0.10, hip_x_m=0.06)


def _world(mode: str = "full3d") -> World:
    return World(dataclasses.replace(CFG.sim, mode=mode))


def test_body_matches_the_configured_patient_and_exoskeleton():
    body = build_body(CFG.sim)
    exo = CFG.sim.model.exoskeleton
    sticks = 2 * CFG.hardware.sticks.mass_kg
    expected = CFG.sim.model.patient.mass_kg + exo.trunk_kg + 2 * (exo.thigh_kg + exo.shank_kg + exo.foot_kg) + sticks
    assert body.total_mass_kg == pytest.approx(expected + 2 * 0.05)  # + the two shoulder link stubs
    text = urdf(CFG.sim)
    assert text.count('type="revolute"') == 12 and 'name="knee_l"' in text


@pytest.mark.parametrize("mode", ["full3d", "sagittal"])
def test_standing_contact_forces_carry_the_weight(mode):
    with _world(mode) as world:
        world.place(STAND)
        for _ in range(int(2.0 / world.dt)):
            world.step()
        links = ("foot_l", "foot_r", "forearm_l", "forearm_r")
        forces = [world.contact_normal_force(link) for link in links]
        weight = world.total_mass * GRAVITY
        assert sum(forces) == pytest.approx(weight, rel=0.02)
        assert all(f > 5.0 for f in forces), forces  # both feet and both sticks carry load
        assert world.touching_links() == set(links)


def test_state_queries_read_the_current_state_once_per_step():
    """Frames and contacts are read once per physics state and shared read-only; a step or a
    placement makes them stale, and each answer is what PyBullet's own per-link query gives."""
    with _world("sagittal") as world:
        world.place(STAND)
        for _ in range(100):
            world.step()
        c = world.client
        for link in ("foot_l", "forearm_r"):
            state = c.getLinkState(world.robot, world.link_index[link])
            origin, rot = world.link_frame(link)
            assert np.array_equal(origin, state[4])
            assert np.array_equal(rot, np.reshape(c.getMatrixFromQuaternion(state[5]), (3, 3)))
            assert world.contacts(link) == list(c.getContactPoints(bodyA=world.robot, bodyB=world.floor,
                                                                      linkIndexA=world.link_index[link]))
            with pytest.raises(ValueError):
                origin[0] = 0.0  # shared with every reader of this state
        assert world.link_states() is world.link_states()  # one query per state
        lin, ang = c.getBaseVelocity(world.robot)
        assert np.array_equal(world.link_states().com_velocity[0], lin)
        assert np.array_equal(world.link_states().base_angular_velocity, ang)
        before = world.link_frame("shank_l")[0].copy()
        world.exo.command(world.exo.index("knee_l"), 1, 0.6)
        for _ in range(10):
            world.step()
        assert not np.array_equal(world.link_frame("shank_l")[0], before)
        world.place(STAND)
        assert np.array_equal(world.link_states().com_velocity[0], np.zeros(3))


@pytest.mark.parametrize("mode", ["full3d", "sagittal"])
def test_several_steps_at_once_are_the_single_steps(mode):
    """``step(n)`` reads the base's velocity only where it is used: the state, the links and the
    trunk IMU's acceleration after it are those of ``n`` single steps, to the bit."""
    states = []
    for batched in (False, True):
        with _world(mode) as world:
            world.place(STAND)
            for _ in range(20):
                if batched:
                    world.step(5)
                else:
                    for _ in range(5):
                        world.step()
            links = world.link_states()
            states.append([world.q, world.qd, world.tau, world.base_acceleration, links.com, links.com_velocity, links.rot,
                           links.base_angular_velocity, world.steps])
    for single, batched in zip(*states):
        assert np.array_equal(single, batched)


def test_trunk_imu_reads_gravity_at_a_known_tilt():
    pose = dataclasses.replace(STAND, trunk_pitch_rad=0.30, hip_x_m=0.02)
    with _world("sagittal") as world:
        world.place(pose)
        for _ in range(int(1.5 / world.dt)):
            world.step()
        sensors = Sensors(world, CFG.sim.sensors, np.random.default_rng(0))
        readings = [sensors.read() for _ in range(1)]
        pitch = world.link_frame("trunk")[1]
        true_pitch = -np.arcsin(pitch[2, 0])
        r = readings[0]
        assert r.trunk_rpy_rad[1] == pytest.approx(true_pitch, abs=0.01)
        expected = GRAVITY * np.array([-np.sin(true_pitch), 0.0, np.cos(true_pitch)])
        assert r.trunk_specific_force_m_s2 == pytest.approx(expected, abs=0.3)


def test_encoders_match_joint_angles_within_their_resolution():
    with _world() as world:
        world.place(STAND)
        for _ in range(50):
            world.step()
        sensors = Sensors(world, CFG.sim.sensors, np.random.default_rng(1))
        reading = sensors.read()
        idx = [JOINT_ORDER.index(n) for n in ("hip_l", "knee_l", "hip_r", "knee_r")]
        res = CFG.sim.sensors.encoder_resolution_rad
        assert np.all(np.abs(reading.joint_position_rad - world.q[idx]) <= res / 2 + 1e-12)


def _stream(seed: int, ticks: int = 25) -> list[np.ndarray]:
    with _world() as world:
        world.place(STAND)
        sensors = Sensors(world, CFG.sim.sensors, np.random.default_rng(seed))
        out = []
        steps = world.cfg.physics.rate_hz // 50
        for _ in range(ticks):
            for _ in range(steps):
                world.step()
            r = sensors.read()
            out.append(np.concatenate([np.ravel(getattr(r, f.name)) for f in dataclasses.fields(r)]))
        return out


def test_same_seed_same_sensor_stream_and_another_seed_differs():
    a, b, c = _stream(7), _stream(7), _stream(8)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))


def test_invalid_actuator_commands_are_rejected_and_counted():
    with _world() as world:
        world.place(STAND)
        target = world.exo.target.copy()
        assert not world.exo.command(0, 1, float("nan"))
        assert not world.exo.command(1, 1, 0.2, torque=float("inf"))
        assert not world.exo.command(2, 1, 5.0)  # beyond the hip's range
        assert not world.exo.command(3, 1, 0.2, limit=500.0)  # beyond the motor's rating
        assert not world.exo.command(0, 9, 0.2)
        assert world.exo.rejected == 5
        assert np.array_equal(world.exo.target, target)
        world.step()
        assert np.all(np.isfinite(world.q))


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("sim.model.patient.mass_kg", -70.0, "sim.model.patient.mass_kg: -70.0 is below the minimum 30"),
        ("hardware.joints.knee.lower_rad", 2.5, "hardware.joints.knee.lower_rad: 2.5 must be below upper_rad 2.0"),
        ("hardware.sticks.length_m", 0.30, "hardware.sticks.length_m: the sticks cannot reach the ground"),
        ("sim.model.exoskeleton.thigh_kg", -1.0, "sim.model.exoskeleton.thigh_kg: -1.0 is below the minimum 0"),
    ],
)
def test_invalid_model_parameters_fail_at_load_naming_the_key(key, value, message):
    with pytest.raises(ConfigError) as info:
        with_overrides(CFG, {key: value})
    assert message in str(info.value) and "\n" not in str(info.value)


def test_tracking_every_arm_joint_at_once_is_each_joints_command():
    """``JointImpedance.track`` sets the same loop as ``command(i, TRACK, ...)`` joint by joint,
    and rejects (and counts) an invalid joint alone, its previous command kept."""
    rng = np.random.default_rng(5)
    with World(CFG.sim) as a, World(CFG.sim) as b:
        arms = a.arms
        n = len(arms.names)
        targets, torques = (arms.lower + arms.upper) / 2 + 0.1, np.linspace(-5.0, 5.0, n)
        q, qd = targets + rng.normal(scale=0.01, size=n), rng.normal(scale=0.1, size=n)  # within the torque limits
        assert arms.track(targets, torques) == 0
        for i in range(n):
            assert b.arms.command(i, 1, float(targets[i]), 0.0, float(torques[i]))
        assert np.array_equal(arms.torques(q, qd), b.arms.torques(q, qd)) and np.array_equal(arms.mode, b.arms.mode)
        bad_targets, bad_torques = targets + 0.01, torques.copy()
        bad_targets[1], bad_torques[4] = arms.upper[1] + 0.5, float("nan")
        assert arms.track(bad_targets, bad_torques) == 2 and arms.rejected == 2
        moved, kept = arms.torques(q, qd), b.arms.torques(q, qd)
        assert moved[1] == kept[1] and moved[4] == kept[4]  # the invalid joints' loops as they were
        assert all(moved[i] != kept[i] for i in (0, 2, 3, 5))  # the valid ones took the new targets
