"""State estimation from the sensors alone (pure numpy): where the feet, the stick tips and the
centre of mass are, which of them carry load, and so X_CoM/X_SP, the CoM's fore-aft place in the
support polygon that the step-length compensation (paper equation (8)) needs.

Everything is expressed in the *heading frame*: origin midway between the hip joints, z up, x the
trunk's heading (its yaw removed), so the ratio needs no global position. Per tick:

* the trunk's roll and pitch from its IMU rotate the body model into the heading frame;
* legs: hip and knee encoders give the ankle joints (the sagittal chain of the exoskeleton); a
  loaded foot is flat on the floor, so the floor lies ``ankle height`` below its ankle;
* arms: the stick's IMU gives the forearm-and-stick orientation; the elbow's axis is the forearm's
  y axis, so the upper arm lies in the forearm's x-z plane at an unknown elbow angle ``e``; a
  loaded stick's tip touches the floor, which fixes ``e`` (``A cos e + B sin e = C``, the root
  inside the elbow's range, the one nearer the last tick's when both are);
* the support polygon is the pivot polygon of the loaded contacts (a passive ankle is a pin: its
  pivot, widened by half the sole across the heading, and the loaded tips), as the simulation's
  ground truth defines it; X_CoM/X_SP is the CoM's place between its rear and front extent;
* ``x_ratio_planted``, the same between the rear-most and front-most of both ankles and both tips
  whatever they carry: the step-length compensation's input at a swing's start, when all four are
  on the floor (the loaded support flips as a stick's load crosses its threshold, and with it the
  ratio, by up to 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SIDES = ("l", "r")


def rot_rpy(roll: float, pitch: float, yaw: float = 0.0) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll): the IMUs' roll-pitch-yaw convention."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


@dataclass(frozen=True)
class Measurements:
    """One tick's sensor values as decoded from the nodes' frames (SI units; left then right)."""

    joint_position_rad: np.ndarray  # (4,) left hip, left knee, right hip, right knee
    trunk_rpy_rad: np.ndarray  # (3,)
    stick_rpy_rad: np.ndarray  # (2, 3)
    stick_force_n: np.ndarray  # (2,)
    heel_force_n: np.ndarray  # (2,)
    toe_force_n: np.ndarray  # (2,)


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
    x_ratio_planted: float  # X_CoM / X_SP between the rear-most and front-most of both feet and both stick tips
    elbow_rad: tuple[float, float]
    tips_on_floor: tuple[bool, bool]  # whether the elbow angle could put the tip on the floor


@dataclass
class StateEstimator:
    body: object  # config.controller_schema.BodyConfig
    legs: object  # config.controller_schema.LegConfig
    _elbow: list[float] = field(default_factory=lambda: [1.0, 1.0])
    _floor_z: float | None = None

    def update(self, m: Measurements) -> Estimate:
        b, legs = self.body, self.legs
        roll, pitch, yaw = (float(v) for v in m.trunk_rpy_rad)
        trunk = rot_rpy(roll, pitch)
        feet_loaded = tuple(bool(m.heel_force_n[i] + m.toe_force_n[i] > b.foot_loaded_n) for i in range(2))
        sticks_loaded = tuple(bool(m.stick_force_n[i] > b.stick_loaded_n) for i in range(2))
        masses: list[float] = [b.trunk_kg]
        points: list[np.ndarray] = [trunk @ np.array([b.trunk_com_xz_m[0], 0.0, b.trunk_com_xz_m[1]])]

        ankles = np.zeros((2, 3))
        q = m.joint_position_rad
        for i, side in enumerate(SIDES):
            sign = 1.0 if side == "l" else -1.0
            hip_q, knee_q = float(q[2 * i]), float(q[2 * i + 1])
            hip = trunk @ np.array([0.0, sign * b.hip_half_width_m, 0.0])
            thigh = trunk @ np.array([math.sin(hip_q), 0.0, -math.cos(hip_q)])
            shank = trunk @ np.array([math.sin(hip_q - knee_q), 0.0, -math.cos(hip_q - knee_q)])
            knee = hip + legs.thigh_m * thigh
            ankles[i] = knee + legs.shank_m * shank
            masses += [b.thigh_kg, b.shank_kg, b.foot_kg]
            points += [hip + b.thigh_com_m * thigh, knee + b.shank_com_m * shank,
                       ankles[i] + np.array([b.foot_com_xz_m[0], 0.0, b.foot_com_xz_m[1]])]
        loaded_z = [ankles[i][2] - legs.ankle_height_m for i in range(2) if feet_loaded[i]]
        if loaded_z:
            self._floor_z = float(np.mean(loaded_z))
        floor_z = self._floor_z if self._floor_z is not None else float(ankles[:, 2].min() - legs.ankle_height_m)

        tips = np.zeros((2, 3))
        on_floor = [False, False]
        for i, side in enumerate(SIDES):
            sign = 1.0 if side == "l" else -1.0
            sx, sy, sz = b.shoulder_xyz_m
            shoulder = trunk @ np.array([sx, sign * sy, sz])
            s_roll, s_pitch, s_yaw = (float(v) for v in m.stick_rpy_rad[i])
            forearm = rot_rpy(s_roll, s_pitch, s_yaw - yaw)  # relative to the trunk's heading
            u, x_f = -forearm[:, 2], forearm[:, 0]  # stick axis (toward the tip) and forearm x
            # upper arm w = cos e u - sin e x_f; the tip at the floor: A cos e + B sin e = C
            a_, b_ = b.upper_arm_m * u[2], -b.upper_arm_m * x_f[2]
            c_ = floor_z + b.tip_radius_m - shoulder[2] - b.elbow_to_tip_m * u[2]
            e, on_floor[i] = self._elbow_angle(i, a_, b_, c_)
            w = math.cos(e) * u - math.sin(e) * x_f
            elbow = shoulder + b.upper_arm_m * w
            tips[i] = elbow + b.elbow_to_tip_m * u - np.array([0.0, 0.0, b.tip_radius_m])
            masses += [b.upper_arm_kg, b.forearm_kg]
            points += [shoulder + b.upper_arm_com_m * w, elbow + b.forearm_com_m * u]
        weights = np.asarray(masses)
        com = (weights[:, None] * np.asarray(points)).sum(axis=0) / weights.sum()

        support = self._pivot_polygon(ankles, tips, feet_loaded, sticks_loaded)
        planted = np.concatenate([ankles[:, 0], tips[:, 0]])
        return Estimate(com, ankles, tips, feet_loaded, sticks_loaded, floor_z, support,
                        self._fore_aft_ratio(float(com[0]), support[:, 0]), self._fore_aft_ratio(float(com[0]), planted),
                        (self._elbow[0], self._elbow[1]), (on_floor[0], on_floor[1]))

    def _fore_aft_ratio(self, com_x: float, xs: np.ndarray) -> float:
        """The CoM's place between the rear-most and the front-most of ``xs``; nan for a support
        shorter than ``min_support_m`` fore-aft, which says nothing fore-aft."""
        if not len(xs):
            return math.nan
        rear, front = float(xs.min()), float(xs.max())
        return (com_x - rear) / (front - rear) if front - rear >= self.body.min_support_m else math.nan

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
        e = min(roots, key=lambda x: abs(x - self._elbow[i]))
        self._elbow[i] = e
        return e, True

    def _pivot_polygon(self, ankles, tips, feet_loaded, sticks_loaded) -> np.ndarray:
        half = self.body.foot_half_width_m
        pts = []
        for i in range(2):
            if feet_loaded[i]:
                pts += [ankles[i][:2] + [0.0, half], ankles[i][:2] - [0.0, half]]
            if sticks_loaded[i]:
                pts.append(tips[i][:2])
        return np.array(pts).reshape(-1, 2)
