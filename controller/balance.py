"""The stance legs' torque feed-forward: the exoskeleton carries the body (pure numpy).

With passive spring ankles the legs and trunk rock about the ankles in a mode that the joints'
position targets cannot hold (every hip and knee angle stays as it is while the body turns over
both ankle pins); only the legs' share of the load moves it. Every walking tick the controller
therefore asks for a wrench at the CoM, from its estimate:

* fore-aft, a spring-damper toward the gait's CoM goal;
* upward, the weight (the stance feet carry their own) and a spring-damper toward the stance height;
* roll and pitch, a spring-damper of the trunk toward its goal attitude (IMU angles and rates);

less what the sticks measurably carry upward (each stick's load cell along the stick's axis from
its IMU) and the moment of that load about the CoM. The sticks' fore-aft pushes are left to act:
they are how the patient slows or stops a lean. The rest is distributed over the stance feet (two
contacts across each sole, each force within a friction pyramid and above a minimum load, so a
foot pushes but never pulls) by non-negative least squares, less the known moment of the ankle
springs, and becomes joint torques: ``G - J^T f``, the torques that hold each leg's segments
against gravity less those the floor's forces at the ankle supply. A swing leg carries its own
weight.

Frames: the estimator's heading frame (x the trunk's heading, z up, origin midway between the
hips). Joint conventions as :mod:`controller.kinematics`: hip flexion turns the thigh forward (a
rotation about -y), knee flexion the shank backward (about +y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller import kinematics as kin
from controller.estimator import Estimate, Measurements, rot_rpy

GRAVITY = 9.81
LEGS = (0, 1)
#: weights of the wrench rows of the distribution: force x, force z, moment x (roll), moment y (pitch)
ROW_WEIGHTS = np.array([1.0, 1.0, 2.0, 2.0])
FOOT_COST = 1e-4  # regularisation of each pyramid edge's load


@dataclass(frozen=True)
class BalanceGains:
    """The wrench's spring-dampers (controller.balance)."""

    com_n_m: float
    com_ns_m: float
    height_n_m: float
    height_ns_m: float
    tilt_nm_rad: float
    tilt_nms_rad: float
    friction: float
    min_foot_n: float
    ankle_stiffness_nm_rad: float
    ankle_rest_rad: float


@dataclass(frozen=True)
class Goals:
    """Where the legs carry the body this tick."""

    com_offset_m: float  # the CoM goal less the CoM, fore-aft
    com_velocity_m_s: float  # the CoM's fore-aft velocity over the planted feet
    hip_height_m: float  # the hips above the floor, goal
    hip_height_now_m: float
    hip_velocity_m_s: float  # upward
    roll_rad: float
    pitch_rad: float


def nnls(a: np.ndarray, b: np.ndarray, max_iter: int = 60) -> np.ndarray:
    """argmin ||a x - b|| subject to x >= 0 (Lawson and Hanson's active-set method)."""
    m, n = a.shape
    x = np.zeros(n)
    passive = np.zeros(n, dtype=bool)
    w = a.T @ (b - a @ x)
    for _ in range(max_iter):
        if passive.all() or not (w[~passive] > 1e-10).any():
            break
        j = int(np.argmax(np.where(passive, -np.inf, w)))
        passive[j] = True
        while True:
            z = np.zeros(n)
            z[passive] = np.linalg.lstsq(a[:, passive], b, rcond=None)[0]
            if (z[passive] > 0.0).all():
                x = z
                break
            blocking = passive & (z <= 0.0)
            alpha = float(np.min(x[blocking] / (x[blocking] - z[blocking])))
            x = x + alpha * (z - x)
            passive &= x > 1e-12
            x[~passive] = 0.0
        w = a.T @ (b - a @ x)
    return x


class LegLoads:
    """Segment masses and the legs' geometry of the estimator's body model, and the foot plate."""

    def __init__(self, body, leg: kin.Leg, foot) -> None:
        self.body, self.leg, self.foot = body, leg, foot
        b = body
        self.total_kg = b.trunk_kg + 2 * (b.thigh_kg + b.shank_kg + b.foot_kg + b.upper_arm_kg + b.forearm_kg)

    def gravity_and_jacobian(self, q: np.ndarray, roll: float, pitch: float, stance: tuple[bool, bool]) -> tuple[np.ndarray, list[np.ndarray]]:
        """The torques (4,) that hold each leg's segments against gravity (a stance foot's weight
        rests on the floor), and per leg the (3, 2) Jacobian of its ankle w.r.t. (hip, knee) in
        the heading frame."""
        b, leg = self.body, self.leg
        rot = rot_rpy(roll, pitch)
        torques = np.zeros(4)
        jacobians = []
        for i in LEGS:
            hip, knee = float(q[2 * i]), float(q[2 * i + 1])
            shank = hip - knee
            d_thigh = rot @ np.array([math.cos(hip), 0.0, math.sin(hip)])  # d(thigh direction)/d hip
            d_shank = rot @ np.array([math.cos(shank), 0.0, math.sin(shank)])  # d(shank direction)/d(hip - knee)
            ankle_j = np.column_stack([leg.thigh_m * d_thigh + leg.shank_m * d_shank, -leg.shank_m * d_shank])
            jacobians.append(ankle_j)
            # d z / d (hip, knee) of each segment's CoM, times its weight
            dz = b.thigh_kg * np.array([b.thigh_com_m * d_thigh[2], 0.0])
            dz += b.shank_kg * np.array([leg.thigh_m * d_thigh[2] + b.shank_com_m * d_shank[2], -b.shank_com_m * d_shank[2]])
            if not stance[i]:
                # the foot turns with the shank about the ankle (hip: about -y, knee: about +y), its
                # CoM taken where it is with the foot flat: (-y) x r has the z part r_x
                fx = b.foot_com_xz_m[0]
                dz += b.foot_kg * np.array([ankle_j[2, 0] + fx, ankle_j[2, 1] - fx])
            torques[2 * i: 2 * i + 2] = GRAVITY * dz
        return torques, jacobians


def desired_wrench(gains: BalanceGains, mass_kg: float, goals: Goals, roll: float, pitch: float, rate_xy: tuple[float, float]) -> np.ndarray:
    """(fx, fz, mx, my) at the CoM toward the goals."""
    g = gains
    return np.array([
        g.com_n_m * goals.com_offset_m - g.com_ns_m * goals.com_velocity_m_s,
        mass_kg * GRAVITY + g.height_n_m * (goals.hip_height_m - goals.hip_height_now_m) - g.height_ns_m * goals.hip_velocity_m_s,
        g.tilt_nm_rad * (goals.roll_rad - roll) - g.tilt_nms_rad * rate_xy[0],
        g.tilt_nm_rad * (goals.pitch_rad - pitch) - g.tilt_nms_rad * rate_xy[1],
    ])


def distribute(wrench: np.ndarray, contacts: np.ndarray, friction: float, min_n: float) -> np.ndarray:
    """Forces (k, 3) at ``contacts`` (k, 3; relative to the CoM) that best give ``wrench``
    (fx, fz, mx, my): each ``min_n`` upward plus non-negative loads on the edges (+-friction, 1)
    of its fore-aft friction pyramid, each edge's load regularised at ``FOOT_COST``."""
    k = len(contacts)
    edges = np.array([[friction, 0.0, 1.0], [-friction, 0.0, 1.0]])
    rows = np.zeros((4 + 2 * k, 2 * k))
    # the edges' moments about the CoM, r x f, written out (np.cross's own products and
    # differences: its argument handling costs more than the arithmetic on 3-vectors)
    for c, (rx, ry, rz) in enumerate(contacts.tolist()):
        for e, (fx, fy, fz) in enumerate(edges.tolist()):
            rows[:4, 2 * c + e] = (fx, fz, ry * fz - rz * fy, rz * fx - rx * fz)
    rows[:4] *= ROW_WEIGHTS[:, None]
    rows[4:] = math.sqrt(FOOT_COST) * np.eye(2 * k)
    base = np.zeros(4)
    for rx, ry, rz in contacts.tolist():
        base += (0.0, min_n, ry * min_n - rz * 0.0, rz * 0.0 - rx * min_n)
    rhs = np.zeros(4 + 2 * k)
    rhs[:4] = ROW_WEIGHTS * (wrench - base)
    lam = nnls(rows, rhs)
    forces = np.zeros((k, 3))
    forces[:, 2] = min_n
    for c in range(k):
        forces[c] += lam[2 * c] * edges[0] + lam[2 * c + 1] * edges[1]
    return forces


def ankle_spring_pitch(q: np.ndarray, pitch: float, leg: int, gains: BalanceGains) -> float:
    """The pitch moment (about +y, nose down positive) a planted foot's ankle spring puts on the
    body: the shank's forward tilt from vertical is the ankle's dorsiflexion (the foot flat)."""
    shank = float(q[2 * leg] - q[2 * leg + 1]) - pitch  # the shank's angle in the world, forward positive at the top
    dorsiflexion = -shank
    return -gains.ankle_stiffness_nm_rad * (dorsiflexion - gains.ankle_rest_rad)


def feed_forward(loads: LegLoads, gains: BalanceGains, est: Estimate, m: Measurements, stance: tuple[bool, bool],
                 goals: Goals) -> np.ndarray:
    """The four joints' torque feed-forward (left hip, left knee, right hip, right knee)."""
    roll, pitch, _ = m.trunk_rpy_rad.tolist()
    q = m.joint_position_rad
    grav, jac = loads.gravity_and_jacobian(q, roll, pitch, stance)
    feet = [i for i in LEGS if stance[i]]
    if not feet:
        return grav
    b = loads.body
    mass = loads.total_kg - len(feet) * b.foot_kg
    rate = m.trunk_rate_rad_s.tolist()
    wrench = desired_wrench(gains, mass, goals, roll, pitch, (rate[0], rate[1]))
    com = est.com
    for i in LEGS:  # each stick's load along its axis: its upward part and that part's moment
        up = float(m.stick_force_n[i]) * max(-float(est.stick_axes[i][2]), 0.0)
        r = est.tips[i] - com
        wrench -= (0.0, up, r[1] * up, -r[0] * up)
    for i in feet:
        wrench[3] -= ankle_spring_pitch(q, pitch, i, gains)
    half = loads.foot.half_width_m
    contacts = np.array([est.ankles[i] + (0.0, s * half, 0.0) - com for i in feet for s in (1.0, -1.0)])
    forces = distribute(wrench, contacts, gains.friction, gains.min_foot_n)
    torques = grav.copy()
    for n, i in enumerate(feet):
        f = forces[2 * n] + forces[2 * n + 1]
        torques[2 * i: 2 * i + 2] -= jac[i].T @ f
    return torques
