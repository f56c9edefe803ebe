"""The stance legs' torque feed-forward: the exoskeleton carries the body (pure: no I/O; compiled:
protocol/compiled.py).

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

from dataclasses import dataclass

import cython
import numpy as np

if cython.compiled:
    from cython.cimports.libc.math import cos, sin
else:
    from math import cos, sin

from controller import kinematics as kin
from controller.distribution import Buffers, distribute_into
from controller.estimator import Estimate, Measurements

GRAVITY = 9.81
LEGS = (0, 1)


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


class LegLoads:
    """Segment masses and the legs' geometry of the estimator's body model, and the foot plate."""

    def __init__(self, body, leg: kin.Leg, foot) -> None:
        self.body, self.leg, self.foot = body, leg, foot
        b = body
        self.total_kg = b.trunk_kg + 2 * (b.thigh_kg + b.shank_kg + b.foot_kg + b.upper_arm_kg + b.forearm_kg)
        #: the figures the feed-forward's arithmetic reads (thigh, shank, thigh kg, thigh CoM, shank kg,
        #: shank CoM, foot kg, foot CoM x, the sole's half width), in the order its loops index them
        self.shape = np.array([leg.thigh_m, leg.shank_m, b.thigh_kg, b.thigh_com_m, b.shank_kg, b.shank_com_m, b.foot_kg,
                               b.foot_com_xz_m[0], foot.half_width_m])
        self.jacobian = np.zeros((2, 3, 2))
        #: the distribution's work arrays for one and for two stance feet (two contacts across each sole)
        self.buffers = {feet: Buffers(2 * feet) for feet in (1, 2)}


@cython.cfunc
@cython.boundscheck(False)
@cython.wraparound(False)
def _gravity_and_jacobian(shape: cython.double[::1], q: cython.const[cython.double][::1], roll: cython.double, pitch: cython.double,
                          left: cython.bint, right: cython.bint, torques: cython.double[::1],
                          jac: cython.double[:, :, ::1]) -> cython.void:
    """The torques (4,) that hold each leg's segments against gravity (a stance foot's weight rests
    on the floor), and per leg the (3, 2) Jacobian of its ankle w.r.t. (hip, knee) in the heading
    frame, into ``jac`` (2, 3, 2); over scalars."""
    thigh_m: cython.double = shape[0]
    shank_m: cython.double = shape[1]
    thigh_kg: cython.double = shape[2]
    thigh_com: cython.double = shape[3]
    shank_kg: cython.double = shape[4]
    shank_com: cython.double = shape[5]
    foot_kg: cython.double = shape[6]
    foot_x: cython.double = shape[7]
    # Ry(pitch) Rx(roll) (yaw 0: the heading frame), its rows' x and z columns (the directions'
    # y part is 0)
    cr: cython.double = cos(roll)
    sr: cython.double = sin(roll)
    cp: cython.double = cos(pitch)
    sp: cython.double = sin(pitch)
    r00: cython.double = cp
    r02: cython.double = sp * cr
    r10: cython.double = 0.0
    r12: cython.double = -sr
    r20: cython.double = -sp
    r22: cython.double = cp * cr
    i: cython.Py_ssize_t
    hip: cython.double
    shank: cython.double
    ch: cython.double
    shh: cython.double
    cs: cython.double
    ss: cython.double
    tx: cython.double
    ty: cython.double
    tz: cython.double
    kx: cython.double
    ky: cython.double
    kz: cython.double
    dz0: cython.double
    dz1: cython.double
    for i in range(2):
        hip = q[2 * i]
        shank = hip - q[2 * i + 1]
        ch, shh, cs, ss = cos(hip), sin(hip), cos(shank), sin(shank)
        tx, ty, tz = r00 * ch + r02 * shh, r10 * ch + r12 * shh, r20 * ch + r22 * shh  # d(thigh direction)/d hip
        kx, ky, kz = r00 * cs + r02 * ss, r10 * cs + r12 * ss, r20 * cs + r22 * ss  # d(shank direction)/d(hip - knee)
        jac[i, 0, 0], jac[i, 1, 0], jac[i, 2, 0] = thigh_m * tx + shank_m * kx, thigh_m * ty + shank_m * ky, thigh_m * tz + shank_m * kz
        jac[i, 0, 1], jac[i, 1, 1], jac[i, 2, 1] = -shank_m * kx, -shank_m * ky, -shank_m * kz
        # d z / d (hip, knee) of each segment's CoM, times its weight
        dz0 = thigh_kg * (thigh_com * tz) + shank_kg * (thigh_m * tz + shank_com * kz)
        dz1 = shank_kg * (-shank_com * kz)
        if not (left if i == 0 else right):
            # the foot turns with the shank about the ankle (hip: about -y, knee: about +y), its
            # CoM taken where it is with the foot flat: (-y) x r has the z part r_x
            dz0 += foot_kg * (jac[i, 2, 0] + foot_x)
            dz1 += foot_kg * (jac[i, 2, 1] - foot_x)
        torques[2 * i] = GRAVITY * dz0
        torques[2 * i + 1] = GRAVITY * dz1


def feed_forward(loads: LegLoads, gains: BalanceGains, est: Estimate, m: Measurements, stance: tuple[bool, bool],
                 goals: Goals) -> np.ndarray:
    """The four joints' torque feed-forward (left hip, left knee, right hip, right knee)."""
    torques = np.zeros(4)
    feet = int(stance[0]) + int(stance[1])
    g, o = gains, goals
    _feed_forward(loads.shape, loads.total_kg, loads.jacobian, loads.buffers.get(feet), stance[0], stance[1],
                  g.com_n_m, g.com_ns_m, g.height_n_m, g.height_ns_m, g.tilt_nm_rad, g.tilt_nms_rad, g.friction, g.min_foot_n,
                  g.ankle_stiffness_nm_rad, g.ankle_rest_rad, o.com_offset_m, o.com_velocity_m_s, o.hip_height_m,
                  o.hip_height_now_m, o.hip_velocity_m_s, o.roll_rad, o.pitch_rad, est.com, est.ankles, est.tips,
                  est.stick_axes, m.joint_position_rad, m.trunk_rpy_rad, m.trunk_rate_rad_s, m.stick_force_n, torques)
    return torques


@cython.cfunc
@cython.boundscheck(False)
@cython.wraparound(False)
@cython.locals(i=cython.Py_ssize_t, j=cython.Py_ssize_t, c=cython.Py_ssize_t, k=cython.Py_ssize_t, roll=cython.double,
               pitch=cython.double, mass=cython.double, fx=cython.double, fz=cython.double, mx=cython.double,
               my=cython.double, axis_down=cython.double, up=cython.double, shank=cython.double, half=cython.double,
               side=cython.double, f0=cython.double, f1=cython.double, f2=cython.double,
               contacts=cython.double[:, ::1], wrench=cython.double[::1], forces=cython.double[:, ::1])
def _feed_forward(shape: cython.double[::1], total_kg: cython.double, jac: cython.double[:, :, ::1], buffers,
                  left: cython.bint, right: cython.bint, com_n_m: cython.double, com_ns_m: cython.double,
                  height_n_m: cython.double, height_ns_m: cython.double, tilt_nm_rad: cython.double,
                  tilt_nms_rad: cython.double, friction: cython.double, min_foot_n: cython.double,
                  ankle_stiffness: cython.double, ankle_rest: cython.double, com_offset: cython.double,
                  com_velocity: cython.double, hip_height: cython.double, hip_height_now: cython.double,
                  hip_velocity: cython.double, goal_roll: cython.double, goal_pitch: cython.double,
                  com: cython.const[cython.double][::1], ankles: cython.const[cython.double][:, ::1],
                  tips: cython.const[cython.double][:, ::1], stick_axes: cython.const[cython.double][:, ::1],
                  q: cython.const[cython.double][::1], rpy: cython.const[cython.double][::1],
                  rate: cython.const[cython.double][::1], stick_force: cython.const[cython.double][::1],
                  torques: cython.double[::1]) -> cython.void:
    """:func:`feed_forward` over scalars: the gravity torques; with a stance foot, the wrench at the
    CoM toward the goals (a spring-damper fore-aft, upward the weight and the stance height, roll
    and pitch toward the goal attitude), less the sticks' measured upward loads and their moments
    and the planted ankles' spring moments, distributed over two contacts across each stance sole;
    less the Jacobians' transposes times each foot's force."""
    roll, pitch = rpy[0], rpy[1]
    _gravity_and_jacobian(shape, q, roll, pitch, left, right, torques, jac)
    if not (left or right):
        return
    contacts, wrench, forces = buffers.contacts, buffers.wrench, buffers.forces
    mass = total_kg - (int(left) + int(right)) * shape[6]
    fx = com_n_m * com_offset - com_ns_m * com_velocity
    fz = mass * GRAVITY + height_n_m * (hip_height - hip_height_now) - height_ns_m * hip_velocity
    mx = tilt_nm_rad * (goal_roll - roll) - tilt_nms_rad * rate[0]
    my = tilt_nm_rad * (goal_pitch - pitch) - tilt_nms_rad * rate[1]
    for i in range(2):  # each stick's load along its axis: its upward part and that part's moment
        axis_down = -stick_axes[i, 2]
        up = stick_force[i] * (axis_down if axis_down > 0.0 else 0.0)
        fz -= up
        mx -= (tips[i, 1] - com[1]) * up
        my -= -(tips[i, 0] - com[0]) * up
    half, c = shape[8], 0
    for i in range(2):
        if not (left if i == 0 else right):
            continue
        # the pitch moment (about +y, nose down positive) of a planted foot's ankle spring: the
        # shank's forward tilt from vertical is the ankle's dorsiflexion (the foot flat)
        shank = (q[2 * i] - q[2 * i + 1]) - pitch
        my -= -ankle_stiffness * (-shank - ankle_rest)
        for side in (1.0, -1.0):
            contacts[c, 0] = ankles[i, 0] + 0.0 - com[0]
            contacts[c, 1] = ankles[i, 1] + side * half - com[1]
            contacts[c, 2] = ankles[i, 2] + 0.0 - com[2]
            c += 1
    wrench[0], wrench[1], wrench[2], wrench[3] = fx, fz, mx, my
    distribute_into(wrench, contacts, friction, min_foot_n, buffers.gram, buffers.rows, buffers.work, buffers.low,
                buffers.flags, forces)
    k = 0
    for i in range(2):
        if not (left if i == 0 else right):
            continue
        f0, f1, f2 = forces[k, 0] + forces[k + 1, 0], forces[k, 1] + forces[k + 1, 1], forces[k, 2] + forces[k + 1, 2]
        for j in range(2):  # less the Jacobian's transpose times the foot's force
            torques[2 * i + j] -= jac[i, 0, j] * f0 + jac[i, 1, j] * f1 + jac[i, 2, j] * f2
        k += 2
