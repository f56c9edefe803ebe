"""State estimation from the sensors alone (pure numpy): where the feet, the stick tips and the
centre of mass are, which of them carry load, and so X_CoM/X_SP, the CoM's fore-aft place in the
support polygon that the step-length compensation (paper equation (8)) needs.

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
from dataclasses import dataclass, field

import numpy as np

from controller.support import convex_hull, window_on_line
from protocol.geometry import fore_aft_ratio

SIDES = ("l", "r")
Vec3 = tuple[float, float, float] | list[float]


def rpy_rows(roll: float, pitch: float, yaw: float = 0.0) -> tuple[tuple[float, float, float], ...]:
    """The rows of :func:`rot_rpy` as floats (no array: the estimator's per-tick arithmetic)."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


def _along(p: Vec3, s: float, d: Vec3) -> Vec3:
    """``p + s d`` for 3-vectors of floats."""
    return (p[0] + s * d[0], p[1] + s * d[1], p[2] + s * d[2])


def rot_rpy(roll: float, pitch: float, yaw: float = 0.0) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll): the IMUs' roll-pitch-yaw convention."""
    return np.array(rpy_rows(roll, pitch, yaw))


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
        b = self.body
        # the segments' masses in the order of update's points (trunk, each leg's thigh, shank and
        # foot, each arm's upper arm and forearm) and their total, numpy's sum as over an array
        self._masses = (b.trunk_kg, *(b.thigh_kg, b.shank_kg, b.foot_kg) * 2, *(b.upper_arm_kg, b.forearm_kg) * 2)
        self._mass_total = float(np.asarray(self._masses).sum())

    def update(self, m: Measurements) -> Estimate:
        """One tick's estimate. Three-element vectors are plain floats (numpy's call overhead is
        most of the cost on arrays this small); the rotations by the trunk are one batched numpy
        product, the same per-vector arithmetic as ``trunk @ v`` for each."""
        b, legs, tip_radius = self.body, self.legs, self.hardware.sticks.tip_radius_m
        roll, pitch, yaw = m.trunk_rpy_rad.tolist()
        heel, toe, stick_force = m.heel_force_n.tolist(), m.toe_force_n.tolist(), m.stick_force_n.tolist()
        feet_loaded = (heel[0] + toe[0] > b.foot_loaded_n, heel[1] + toe[1] > b.foot_loaded_n)
        sticks_loaded = (stick_force[0] > b.stick_loaded_n, stick_force[1] > b.stick_loaded_n)
        # in the trunk's frame: its CoM; per leg the hip, the thigh's and the shank's axes; per arm the shoulder
        sx, sy, sz = b.shoulder_xyz_m
        body_vectors = [[b.trunk_com_xz_m[0], 0.0, b.trunk_com_xz_m[1]]]
        q = m.joint_position_rad.tolist()
        for i, side in enumerate(SIDES):
            sign = 1.0 if side == "l" else -1.0
            hip_q, knee_q = q[2 * i], q[2 * i + 1]
            body_vectors += [[0.0, sign * b.hip_half_width_m, 0.0], [math.sin(hip_q), 0.0, -math.cos(hip_q)],
                             [math.sin(hip_q - knee_q), 0.0, -math.cos(hip_q - knee_q)]]
        body_vectors += [[sx, sign * sy, sz] for sign in (1.0, -1.0)]
        rotated = (rot_rpy(roll, pitch) @ np.array(body_vectors)[:, :, None])[:, :, 0].tolist()
        points = [rotated[0]]

        ankles = []
        fx, fz = b.foot_com_xz_m
        for i in range(2):
            hip, thigh, shank = rotated[1 + 3 * i], rotated[2 + 3 * i], rotated[3 + 3 * i]
            knee = _along(hip, legs.thigh_m, thigh)
            ankle = _along(knee, legs.shank_m, shank)
            ankles.append(ankle)
            points += [_along(hip, b.thigh_com_m, thigh), _along(knee, b.shank_com_m, shank), (ankle[0] + fx, ankle[1] + 0.0, ankle[2] + fz)]
        # the floor from the feet that are flat (heel and toe loaded); with none (a heel risen in the
        # swing, the foot on its toe, its ankle higher by the foot's tilt) the last tick's
        loaded_z = [ankles[i][2] - legs.ankle_height_m for i in range(2)
                    if feet_loaded[i] and heel[i] > b.foot_flat_n and toe[i] > b.foot_flat_n]
        if loaded_z:
            total = 0.0
            for z in loaded_z:  # summed in order, as numpy's mean of so few values
                total += z
            self._floor_z = total / len(loaded_z)
        floor_z = self._floor_z if self._floor_z is not None else min(ankles[0][2], ankles[1][2]) - legs.ankle_height_m

        tips, axes = [], []
        on_floor = [False, False]
        stick_rpy = m.stick_rpy_rad.tolist()
        for i in range(2):
            shoulder = rotated[7 + i]
            s_roll, s_pitch, s_yaw = stick_rpy[i]
            forearm = rpy_rows(s_roll, s_pitch, s_yaw - yaw)  # relative to the trunk's heading
            u = (-forearm[0][2], -forearm[1][2], -forearm[2][2])  # stick axis (toward the tip)
            axes.append(u)
            x_f = (forearm[0][0], forearm[1][0], forearm[2][0])  # forearm x
            # upper arm w = cos e u - sin e x_f; the tip at the floor: A cos e + B sin e = C
            a_, b_ = b.upper_arm_m * u[2], -b.upper_arm_m * x_f[2]
            c_ = floor_z + tip_radius - shoulder[2] - b.elbow_to_tip_m * u[2]
            e, on_floor[i] = self._elbow_angle(i, a_, b_, c_)
            ce, se = math.cos(e), math.sin(e)
            w = (ce * u[0] - se * x_f[0], ce * u[1] - se * x_f[1], ce * u[2] - se * x_f[2])
            elbow = _along(shoulder, b.upper_arm_m, w)
            tip = _along(elbow, b.elbow_to_tip_m, u)
            tips.append((tip[0], tip[1], tip[2] - tip_radius))
            points += [_along(shoulder, b.upper_arm_com_m, w), _along(elbow, b.forearm_com_m, u)]
        cx = cy = cz = 0.0
        for mass, (x, y, z) in zip(self._masses, points):  # summed point by point, as numpy's sum over axis 0
            cx, cy, cz = cx + mass * x, cy + mass * y, cz + mass * z
        com = (cx / self._mass_total, cy / self._mass_total, cz / self._mass_total)

        support = self._pivot_polygon(ankles, tips, feet_loaded, sticks_loaded)
        return Estimate(np.array(com), np.array(ankles), np.array(tips), feet_loaded, sticks_loaded, floor_z,
                        np.array(support).reshape(-1, 2), fore_aft_ratio(com[0], [p[0] for p in support], self.body.min_support_m),
                        (self._elbow[0], self._elbow[1]), (on_floor[0], on_floor[1]), np.array(axes))

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

    def _elbow_angle(self, i: int, a: float, b: float, c: float) -> tuple[float, bool]:
        lo, hi = self.body.elbow_min_rad, self.body.elbow_max_rad
        r = math.hypot(a, b)
        if r < 1e-9 or abs(c) > r:
            return self._elbow[i], False  # the tip cannot reach the floor: keep the last elbow angle
        base, spread = math.atan2(b, a), math.acos(c / r)
        roots = []
        for e in (base + spread, base - spread):
            e = (e + math.pi) % (2 * math.pi) - math.pi
            if lo - 1e-6 <= e <= hi + 1e-6:
                roots.append(min(max(e, lo), hi))
        if not roots:
            return self._elbow[i], False
        last = self._elbow[i]
        e = roots[0] if len(roots) == 1 or abs(roots[0] - last) <= abs(roots[1] - last) else roots[1]  # min() by nearness: the first on a tie
        self._elbow[i] = e
        return e, True

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
