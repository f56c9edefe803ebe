"""The sensors AIDER has, sampled once per 20 ms tick with seeded noise and realistic resolution.

* joint encoders (exoskeleton hips and knees): position, velocity, applied motor torque;
* per stick: axial ground-reaction force (load cell) and the stick IMU's orientation;
* trunk IMU: orientation, angular rate and specific force in the body frame;
* plantar insoles: heel and toe normal force per foot.

Everything the node boards report comes from here; the controller never sees the world itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from config.sim_schema import SensorsConfig
from sim.linalg import rpy_from_matrix
from sim.model import EXO_JOINTS
from sim.world import GRAVITY, World


def contact_force_on_robot(cp: tuple) -> np.ndarray:
    """World force the floor exerts on the robot at one PyBullet contact point (robot = body A).

    The normal force acts along ``contactNormalOnB`` (B towards A); the reported lateral friction
    forces act on A *against* their direction vectors (checked against static equilibrium of the
    joint torques in tests/sim/test_sim_kinematics.py).
    """
    n, (nx, ny, nz), f1, (ax, ay, az), f2, (bx, by, bz) = cp[9], cp[7], cp[10], cp[11], cp[12], cp[13]
    # in floats, the arithmetic of the numpy expression n * normal - f1 * dir1 - f2 * dir2, per component
    return np.array((n * nx - f1 * ax - f2 * bx, n * ny - f1 * ay - f2 * by, n * nz - f1 * az - f2 * bz))


def quantise(value: np.ndarray | float, resolution: float) -> np.ndarray:
    """``value`` to the nearest multiple of ``resolution`` (``np.round``: halves to even; its
    method, without the function's dispatch)."""
    return (np.asarray(value) / resolution).round() * resolution


@dataclass(frozen=True)
class Reading:
    """One tick's sensor values (SI units; arrays ordered left then right, joints in node order)."""

    time_s: float
    joint_position_rad: np.ndarray  # (4,) left hip, left knee, right hip, right knee
    joint_velocity_rad_s: np.ndarray  # (4,)
    joint_torque_nm: np.ndarray  # (4,)
    stick_force_n: np.ndarray  # (2,)
    stick_rpy_rad: np.ndarray  # (2, 3)
    trunk_rpy_rad: np.ndarray  # (3,)
    trunk_rate_rad_s: np.ndarray  # (3,) body frame
    trunk_specific_force_m_s2: np.ndarray  # (3,) body frame
    heel_force_n: np.ndarray  # (2,)
    toe_force_n: np.ndarray  # (2,)


class Sensors:
    """Samples a :class:`World`; noise from an injected generator (same seed, same readings)."""

    def __init__(self, world: World, cfg: SensorsConfig, rng: np.random.Generator) -> None:
        self.world, self.cfg, self.rng = world, cfg, rng
        self._exo = [world.joint_index[n] for n in EXO_JOINTS]
        foot = world.cfg.hardware.foot
        self._heel_toe_split_x = (foot.toe_front_m - foot.heel_back_m) / 2
        self._gravity = np.array([0.0, 0.0, GRAVITY])  # what an accelerometer at rest reads, world frame
        # each value's resolution, in the order :meth:`read` lays the values out
        self._resolution = np.repeat(
            [cfg.encoder_resolution_rad, 0.001, 0.05, cfg.force_resolution_n, cfg.imu_orientation_resolution_rad,
             cfg.imu_orientation_resolution_rad, cfg.gyro_resolution_rad_s, cfg.accel_resolution_m_s2,
             cfg.force_resolution_n, cfg.force_resolution_n],
            [4, 4, 4, 2, 6, 3, 3, 3, 2, 2],
        )
        # each noisy value's standard deviation (the values from the stick forces on), in that order;
        # a sensor without noise draws nothing from the stream
        self._noise_std = np.repeat(
            [cfg.force_noise_n, cfg.imu_orientation_noise_rad, cfg.imu_orientation_noise_rad, cfg.gyro_noise_rad_s,
             cfg.accel_noise_m_s2, cfg.force_noise_n, cfg.force_noise_n],
            [2, 6, 3, 3, 3, 2, 2],
        )
        self._noisy = np.flatnonzero(self._noise_std > 0)
        self._noisy_std = self._noise_std[self._noisy]

    def _noise(self) -> np.ndarray:
        """One tick's noise of the noisy values: the draws of ``normal(0, std)`` value by value,
        in one call (the same numbers from the stream)."""
        noise = np.zeros(len(self._noise_std))
        noise[self._noisy] = self._noisy_std * self.rng.standard_normal(len(self._noisy))
        return noise

    def stick_force(self, side: str) -> float:
        """Axial force along the stick (compression positive) from the tip's contact forces."""
        w = self.world
        _, rot = w.link_frame(f"forearm_{side}")
        axis = rot[:, 2]  # the stick points along -z of the forearm frame; ground pushes along +z
        total = np.zeros(3)
        for cp in w.contacts(f"forearm_{side}"):
            total += contact_force_on_robot(cp)
        return float(total @ axis)

    def plantar(self, side: str) -> tuple[float, float]:
        """Heel and toe normal force: contacts binned by their position along the foot."""
        w = self.world
        origin, rot = w.link_frame(f"foot_{side}")
        (ox, oy, oz), (ax, ay, az) = origin.tolist(), rot[:, 0].tolist()
        heel = toe = 0.0
        for cp in w.contacts(f"foot_{side}"):
            px, py, pz = cp[6]
            x_local = (px - ox) * ax + (py - oy) * ay + (pz - oz) * az  # along the sole
            if x_local < self._heel_toe_split_x:
                heel += cp[9]
            else:
                toe += cp[9]
        return heel, toe

    def read(self) -> Reading:
        w = self.world
        q = w.q[self._exo]
        qd = w.qd[self._exo]
        tau = w.exo.applied
        sticks = (self.stick_force("l"), self.stick_force("r"))
        stick_rpy = [rpy_from_matrix(w.link_frame(f"forearm_{s}")[1]) for s in "lr"]
        links = w.link_states()
        rot = links.rot[0]  # the trunk's
        specific = rot.T @ (w.base_acceleration + self._gravity)
        (heel_l, toe_l), (heel_r, toe_r) = self.plantar("l"), self.plantar("r")
        # Noise drawn in the order of the Reading's fields (one seeded stream), then every value
        # quantised to its sensor's resolution in one vectorised round.
        raw = np.concatenate([
            q, qd, tau, sticks, *stick_rpy, links.trunk_rpy, rot.T @ links.base_angular_velocity, specific, (heel_l, heel_r), (toe_l, toe_r),
        ])
        raw[12:] += self._noise()
        raw[29:] = np.maximum(raw[29:], 0.0)  # a load cell under a foot reads no pull
        v = quantise(raw, self._resolution)
        return Reading(
            time_s=w.time_s,
            joint_position_rad=v[0:4], joint_velocity_rad_s=v[4:8], joint_torque_nm=v[8:12],
            stick_force_n=v[12:14], stick_rpy_rad=v[14:20].reshape(2, 3), trunk_rpy_rad=v[20:23],
            trunk_rate_rad_s=v[23:26], trunk_specific_force_m_s2=v[26:29], heel_force_n=v[29:31], toe_force_n=v[31:33],
        )
