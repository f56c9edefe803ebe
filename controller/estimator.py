"""State estimation from the sensors alone (pure: no I/O; its chain compiled, protocol/compiled.py):
where the feet, the stick tips and the centre of mass are, which of them carry load, and so
X_CoM/X_SP, the CoM's fore-aft place in the support polygon that the step-length compensation
(paper equation (8)) needs.

Everything is expressed in the *heading frame*: origin midway between the hip joints, z up, x the
trunk's heading (its yaw removed), so the ratio needs no global position. Per tick:

* the trunk's roll and pitch from its IMU rotate the body model into the heading frame;
* legs: hip and knee encoders give the ankle joints (the sagittal chain of the exoskeleton); a
  foot with heel and toe loaded is flat on the floor, so the floor lies ``ankle height`` below
  its ankle (with no flat foot, as on a risen heel, the floor stays where it was);
* arms: the stick's IMU gives the forearm-and-stick orientation; the elbow's axis is the forearm's
  y axis, so the upper arm lies in the forearm's x-z plane at an unknown elbow angle ``e``; a
  loaded stick's tip touches the floor, which fixes ``e`` (``A cos e + B sin e = C``, the root
  inside the elbow's range, the one nearer the last tick's when both are);
* the support polygon is the pivot polygon of the loaded contacts (a passive ankle is a pin: its
  pivot, widened by half the sole across the heading, and the loaded tips), as the simulation's
  ground truth defines it; X_CoM/X_SP is the CoM's place between its rear and front extent;
* at a swing's start (not every tick), :meth:`StateEstimator.stance_ratio`, the step-length
  compensation's input, as SPEC defines it: the CoM's place along the walking direction in the
  swing's support polygon (the stance sole, heel to toe, and both tips, whatever they carry: a
  stick's load crosses its threshold as the swing starts), from its rear-most point (the heel) to
  its front edge where the CoM's line crosses it (the tips' line): the share of the way from the
  foot to the sticks, which the lever rule makes the sticks' share of the weight;
  :meth:`StateEstimator.planted_ratio`, the same over both soles and both tips.
"""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field

import cython
import numpy as np

if cython.compiled:
    from cython.cimports.libc.math import acos, atan2, cos, fabs, sin
else:
    from math import acos, atan2, cos, fabs, sin

from controller.support import convex_hull, window_on_line
from protocol.geometry import fore_aft_ratio

SIDES = ("l", "r")


def rot_rpy(roll: float, pitch: float, yaw: float = 0.0) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll): the IMUs' roll-pitch-yaw convention (:func:`_rows`)."""
    r = array("d", bytes(72))
    _rows(roll, pitch, yaw, r)
    return np.array(r).reshape(3, 3)


@dataclass(frozen=True)
class Measurements:
    """One tick's sensor values as decoded from the nodes' frames (SI units; left then right)."""

    joint_position_rad: np.ndarray  # (4,) left hip, left knee, right hip, right knee
    trunk_rpy_rad: np.ndarray  # (3,)
    stick_rpy_rad: np.ndarray  # (2, 3)
    stick_force_n: np.ndarray  # (2,)
    heel_force_n: np.ndarray  # (2,)
    toe_force_n: np.ndarray  # (2,)
    trunk_rate_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) body frame


@dataclass
class Estimate:
    """The estimated state of one tick (heading frame, metres)."""

    com: np.ndarray  # (3,)
    ankles: np.ndarray  # (2, 3)
    tips: np.ndarray  # (2, 3) stick tip contact points
    feet_loaded: tuple[bool, bool]
    sticks_loaded: tuple[bool, bool]
    floor_z: float  # the floor below the hip midpoint
    support: np.ndarray  # (k, 2) pivot polygon vertices of the loaded contacts
    x_ratio: float  # X_CoM / X_SP over the loaded contacts (nan without a support extent)
    elbow_rad: tuple[float, float]
    tips_on_floor: tuple[bool, bool]  # whether the elbow angle could put the tip on the floor
    stick_axes: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.0, -1.0]] * 2))  # (2, 3) unit, toward the tips


@dataclass
class StateEstimator:
    body: object  # config.controller_schema.BodyConfig
    legs: object  # config.controller_schema.LegConfig
    hardware: object  # config.hardware_schema.HardwareConfig: the foot plates and the sticks' tips
    _elbow: list[float] = field(default_factory=lambda: [1.0, 1.0])
    _floor_z: float | None = None

    def __post_init__(self) -> None:
        b, legs = self.body, self.legs
        # the segments' masses in the order of the chain's points (trunk, each leg's thigh, shank and
        # foot, each arm's upper arm and forearm) and their total, numpy's sum as over an array
        masses = (b.trunk_kg, *(b.thigh_kg, b.shank_kg, b.foot_kg) * 2, *(b.upper_arm_kg, b.forearm_kg) * 2)
        self._masses_buffer = array("d", (*masses, float(np.asarray(masses).sum())))
        self._shape = array("d", (
            b.trunk_com_xz_m[0], b.trunk_com_xz_m[1], b.hip_half_width_m, *b.shoulder_xyz_m, legs.thigh_m, legs.shank_m,
            b.thigh_com_m, b.shank_com_m, b.foot_com_xz_m[0], b.foot_com_xz_m[1], legs.ankle_height_m, b.upper_arm_m,
            b.elbow_to_tip_m, b.upper_arm_com_m, b.forearm_com_m, self.hardware.sticks.tip_radius_m, b.foot_flat_n,
            b.elbow_min_rad, b.elbow_max_rad))
        assert len(self._shape) == _SHAPE_LEN
        self._inputs = array("d", bytes(8 * 19))
        self._state = array("d", (self._elbow[0], self._elbow[1], 0.0, 0.0))  # elbows, floor z, whether it is known
        self._work = array("d", bytes(8 * 9))
        self._out = array("d", bytes(8 * 24))

    def update(self, m: Measurements) -> Estimate:
        """One tick's estimate: the body model's chain over scalars (:func:`_chain`, compiled),
        then the pivot polygon and X_CoM/X_SP."""
        b = self.body
        heel, toe, stick_force = m.heel_force_n.tolist(), m.toe_force_n.tolist(), m.stick_force_n.tolist()
        feet_loaded = (heel[0] + toe[0] > b.foot_loaded_n, heel[1] + toe[1] > b.foot_loaded_n)
        sticks_loaded = (stick_force[0] > b.stick_loaded_n, stick_force[1] > b.stick_loaded_n)
        inputs, out = self._inputs, self._out
        inputs[0:4] = array("d", m.joint_position_rad.tolist())
        inputs[4:7] = array("d", m.trunk_rpy_rad.tolist())
        inputs[7:13] = array("d", [x for row in m.stick_rpy_rad.tolist() for x in row])
        inputs[13:17] = array("d", (heel[0], heel[1], toe[0], toe[1]))
        inputs[17:19] = array("d", (1.0 if feet_loaded[0] else 0.0, 1.0 if feet_loaded[1] else 0.0))
        _chain(self._shape, self._masses_buffer, inputs, self._state, self._work, out)
        values = out.tolist()
        com, ankles, tips, axes = values[0:3], (values[3:6], values[6:9]), (values[9:12], values[12:15]), (values[15:18], values[18:21])
        self._elbow = [self._state[0], self._state[1]]
        self._floor_z = self._state[2] if self._state[3] else None
        support = self._pivot_polygon(ankles, tips, feet_loaded, sticks_loaded)
        return Estimate(np.array(com), np.array(ankles), np.array(tips), feet_loaded, sticks_loaded, values[21],
                        np.array(support).reshape(-1, 2), fore_aft_ratio(com[0], [p[0] for p in support], self.body.min_support_m),
                        (self._elbow[0], self._elbow[1]), (values[22] != 0.0, values[23] != 0.0), np.array(axes))

    def stance_ratio(self, est: Estimate, stance: int) -> float:
        """X_CoM/X_SP over the support of a swing of the other leg (SPEC): where the CoM lies along
        the walking direction in the polygon of leg ``stance``'s sole (0 left, 1 right) and both
        stick tips, from its rear-most point (the heel) to its front edge on the CoM's line (the
        tips' line); nan for a span shorter than ``min_support_m``."""
        return self._ratio_on_line(est.com, [est.ankles[stance]], est.tips)

    def planted_ratio(self, est: Estimate) -> float:
        """:meth:`stance_ratio` over both soles and both stick tips."""
        return self._ratio_on_line(est.com, list(est.ankles), est.tips)

    def _ratio_on_line(self, com, ankles, tips) -> float:
        b, foot = self.body, self.hardware.foot
        corners = [(float(a[0]) + dx, float(a[1]) + dy) for a in ankles
                   for dx in (-foot.heel_back_m, foot.toe_front_m) for dy in (-foot.half_width_m, foot.half_width_m)]
        points = corners + [(float(t[0]), float(t[1])) for t in tips]
        rear, front = min(x for x, _ in points), window_on_line(convex_hull(points), float(com[1]), 0.0)[1]
        return (float(com[0]) - rear) / (front - rear) if front - rear >= b.min_support_m else math.nan

    def _pivot_polygon(self, ankles, tips, feet_loaded, sticks_loaded) -> list[tuple[float, float]]:
        """The pivot polygon's vertices (x, y): each loaded ankle widened by half the sole across the heading, each loaded tip."""
        half = self.hardware.foot.half_width_m
        pts = []
        for i in range(2):
            if feet_loaded[i]:
                x, y = ankles[i][0], ankles[i][1]
                pts += [(x, y + half), (x, y - half)]
            if sticks_loaded[i]:
                pts.append((tips[i][0], tips[i][1]))
        return pts


_SHAPE_LEN = 21
_PI = cython.declare(cython.double, math.pi)


@cython.ccall
@cython.boundscheck(False)
@cython.wraparound(False)
def _rows(roll: cython.double, pitch: cython.double, yaw: cython.double, r: cython.double[::1]) -> cython.void:
    """Rz(yaw) Ry(pitch) Rx(roll) into ``r`` (row-major 3 x 3)."""
    cr: cython.double = cos(roll)
    sr: cython.double = sin(roll)
    cp: cython.double = cos(pitch)
    sp: cython.double = sin(pitch)
    cy: cython.double = cos(yaw)
    sy: cython.double = sin(yaw)
    r[0], r[1], r[2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    r[3], r[4], r[5] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    r[6], r[7], r[8] = -sp, cp * sr, cp * cr


@cython.cfunc
@cython.boundscheck(False)
@cython.wraparound(False)
@cython.locals(s=cython.double)
def _rotated(r: cython.double[::1], x: cython.double, y: cython.double, z: cython.double, row: cython.Py_ssize_t) -> cython.double:
    """Row ``row`` of ``r`` times (x, y, z), summed from 0 in order, as numpy's matmul loop does."""
    s = 0.0
    s += r[3 * row] * x
    s += r[3 * row + 1] * y
    s += r[3 * row + 2] * z
    return s


@cython.cfunc
@cython.locals(rr=cython.double, base=cython.double, spread=cython.double, e=cython.double, last=cython.double,
               r0=cython.double, r1=cython.double, n=cython.int, k=cython.int)
def _elbow_angle(state: cython.double[::1], i: cython.Py_ssize_t, a: cython.double, b: cython.double, c: cython.double,
                 lo: cython.double, hi: cython.double) -> cython.bint:
    """The elbow angle that puts the tip on the floor (``a cos e + b sin e = c``), the root inside
    [lo, hi] nearer the last tick's (``state[i]``, updated), the first on a tie; False (the last
    angle kept) when none reaches."""
    rr = math.hypot(a, b)  # Python's (its own algorithm, not libm's): the same either way
    if rr < 1e-9 or fabs(c) > rr:
        return False
    base, spread = atan2(b, a), acos(c / rr)
    n = 0
    r0 = r1 = 0.0
    for k in range(2):
        e = base + spread if k == 0 else base - spread
        e = (e + _PI) % (2 * _PI) - _PI  # Python's modulo (cdivision off): the sign of the divisor
        if lo - 1e-6 <= e <= hi + 1e-6:
            e = lo if lo > e else e  # min(max(e, lo), hi)
            e = hi if hi < e else e
            if n == 0:
                r0 = e
            else:
                r1 = e
            n += 1
    if n == 0:
        return False
    last = state[i]
    state[i] = r0 if n == 1 or fabs(r0 - last) <= fabs(r1 - last) else r1
    return True


@cython.cfunc
@cython.boundscheck(False)
@cython.wraparound(False)
@cython.locals(i=cython.Py_ssize_t, sign=cython.double, hip_q=cython.double, shank_q=cython.double, hx=cython.double,
               hy=cython.double, hz=cython.double, tx=cython.double, ty=cython.double, tz=cython.double,
               kx=cython.double, ky=cython.double, kz=cython.double, nx=cython.double, ny=cython.double,
               nz=cython.double, ax=cython.double, ay=cython.double, az=cython.double, cx=cython.double,
               cy=cython.double, cz=cython.double, total=cython.double, count=cython.int, floor_z=cython.double,
               sx=cython.double, sy=cython.double, sz=cython.double, ux=cython.double, uy=cython.double,
               uz=cython.double, fx=cython.double, fy=cython.double, fz=cython.double, a_=cython.double,
               b_=cython.double, c_=cython.double, e=cython.double, ce=cython.double, se=cython.double,
               wx=cython.double, wy=cython.double, wz=cython.double, ex=cython.double, ey=cython.double,
               ez=cython.double, px=cython.double, py=cython.double, pz=cython.double, mass=cython.double,
               tip_radius=cython.double, flat=cython.double)
def _chain(p: cython.double[::1], masses: cython.double[::1], inputs: cython.double[::1], state: cython.double[::1],
           r: cython.double[::1], out: cython.double[::1]) -> cython.void:
    """The body model's chain in the heading frame (see the module doc), over scalars.

    ``p``: the body (``StateEstimator._shape``: trunk CoM x, z; hip half width; shoulder x, y, z;
    thigh, shank; thigh CoM, shank CoM; foot CoM x, z; ankle height; upper arm, elbow to tip; upper
    arm CoM, forearm CoM; tip radius; flat foot force; elbow range); ``masses``: the 11 segments' and their total;
    ``inputs``: joint positions (4), trunk roll, pitch, yaw, the sticks' roll, pitch, yaw (2 x 3),
    heel forces (2), toe forces (2), feet loaded (2, 0 or 1); ``state``: the elbow angles (2), the
    floor's z and whether it is known; ``r``: scratch (9). ``out``: CoM (3), ankles (2 x 3), tips
    (2 x 3), stick axes (2 x 3), the floor's z, tips on the floor (2, 0 or 1)."""
    tip_radius, flat = p[17], p[18]
    _rows(inputs[4], inputs[5], 0.0, r)
    # the trunk's CoM: the first point
    px, py, pz = _rotated(r, p[0], 0.0, p[1], 0), _rotated(r, p[0], 0.0, p[1], 1), _rotated(r, p[0], 0.0, p[1], 2)
    cx, cy, cz = 0.0 + masses[0] * px, 0.0 + masses[0] * py, 0.0 + masses[0] * pz
    for i in range(2):
        sign = 1.0 if i == 0 else -1.0
        hip_q = inputs[2 * i]
        shank_q = hip_q - inputs[2 * i + 1]
        hx, hy, hz = _rotated(r, 0.0, sign * p[2], 0.0, 0), _rotated(r, 0.0, sign * p[2], 0.0, 1), _rotated(r, 0.0, sign * p[2], 0.0, 2)
        tx, ty, tz = _rotated(r, sin(hip_q), 0.0, -cos(hip_q), 0), _rotated(r, sin(hip_q), 0.0, -cos(hip_q), 1), _rotated(r, sin(hip_q), 0.0, -cos(hip_q), 2)
        kx, ky, kz = _rotated(r, sin(shank_q), 0.0, -cos(shank_q), 0), _rotated(r, sin(shank_q), 0.0, -cos(shank_q), 1), _rotated(r, sin(shank_q), 0.0, -cos(shank_q), 2)
        nx, ny, nz = hx + p[6] * tx, hy + p[6] * ty, hz + p[6] * tz  # the knee
        ax, ay, az = nx + p[7] * kx, ny + p[7] * ky, nz + p[7] * kz  # the ankle
        out[3 + 3 * i], out[4 + 3 * i], out[5 + 3 * i] = ax, ay, az
        # the thigh's, the shank's and the foot's CoM
        mass = masses[1 + 3 * i]
        cx, cy, cz = cx + mass * (hx + p[8] * tx), cy + mass * (hy + p[8] * ty), cz + mass * (hz + p[8] * tz)
        mass = masses[2 + 3 * i]
        cx, cy, cz = cx + mass * (nx + p[9] * kx), cy + mass * (ny + p[9] * ky), cz + mass * (nz + p[9] * kz)
        mass = masses[3 + 3 * i]
        cx, cy, cz = cx + mass * (ax + p[10]), cy + mass * (ay + 0.0), cz + mass * (az + p[11])
    # the floor from the feet that are flat (heel and toe loaded); with none the last tick's
    total, count = 0.0, 0
    for i in range(2):
        if inputs[17 + i] != 0.0 and inputs[13 + i] > flat and inputs[15 + i] > flat:
            total += out[5 + 3 * i] - p[12]
            count += 1
    if count:
        state[2], state[3] = total / count, 1.0
    if state[3] != 0.0:
        floor_z = state[2]
    else:
        floor_z = (out[8] if out[8] < out[5] else out[5]) - p[12]  # min(): the first of equals
    out[21] = floor_z
    for i in range(2):
        sign = 1.0 if i == 0 else -1.0
        sx, sy, sz = _rotated(r, p[3], sign * p[4], p[5], 0), _rotated(r, p[3], sign * p[4], p[5], 1), _rotated(r, p[3], sign * p[4], p[5], 2)
        # the forearm's rotation relative to the trunk's heading; the stick's axis (toward the tip), the forearm's x
        _rows(inputs[7 + 3 * i], inputs[8 + 3 * i], inputs[9 + 3 * i] - inputs[6], r)
        ux, uy, uz = -r[2], -r[5], -r[8]
        fx, fy, fz = r[0], r[3], r[6]
        out[15 + 3 * i], out[16 + 3 * i], out[17 + 3 * i] = ux, uy, uz
        # upper arm w = cos e u - sin e x_f; the tip at the floor: A cos e + B sin e = C
        a_, b_ = p[13] * uz, -p[13] * fz
        c_ = floor_z + tip_radius - sz - p[14] * uz
        out[22 + i] = 1.0 if _elbow_angle(state, i, a_, b_, c_, p[19], p[20]) else 0.0
        e = state[i]
        ce, se = cos(e), sin(e)
        wx, wy, wz = ce * ux - se * fx, ce * uy - se * fy, ce * uz - se * fz
        ex, ey, ez = sx + p[13] * wx, sy + p[13] * wy, sz + p[13] * wz  # the elbow
        out[9 + 3 * i], out[10 + 3 * i], out[11 + 3 * i] = ex + p[14] * ux, ey + p[14] * uy, ez + p[14] * uz - tip_radius
        mass = masses[7 + 2 * i]
        cx, cy, cz = cx + mass * (sx + p[15] * wx), cy + mass * (sy + p[15] * wy), cz + mass * (sz + p[15] * wz)
        mass = masses[8 + 2 * i]
        cx, cy, cz = cx + mass * (ex + p[16] * ux), cy + mass * (ey + p[16] * uy), cz + mass * (ez + p[16] * uz)
        _rows(inputs[4], inputs[5], 0.0, r)  # the trunk's again for the other shoulder
    out[0], out[1], out[2] = cx / masses[11], cy / masses[11], cz / masses[11]
