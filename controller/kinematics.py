"""Sagittal leg kinematics of the exoskeleton: ankle position relative to the hip <-> hip and knee,
within the leg's joint limits (the geometry itself: :mod:`protocol.geometry`, which the simulation
shares).

Conventions (those of the node boards' encoders and of the protocol): hip flexion positive (thigh
forward), knee flexion positive (shank backward relative to the thigh), 0 = straight leg hanging
down. Positions are in the sagittal plane of the trunk: x forward, z up, relative to the hip joint.
The trunk's pitch is added by the caller: a thigh angle in the world is ``hip - trunk_pitch``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocol.geometry import leg_forward, leg_inverse


class KinematicsError(ValueError):
    """An ankle target the leg cannot reach, or joint angles outside their limits."""


@dataclass(frozen=True)
class Leg:
    """Segment lengths and joint limits of one exoskeleton leg."""

    thigh_m: float
    shank_m: float
    hip_min_rad: float
    hip_max_rad: float
    knee_min_rad: float
    knee_max_rad: float

    def __post_init__(self) -> None:
        if not (self.thigh_m > 0 and self.shank_m > 0):
            raise KinematicsError("segment lengths must be positive")
        if not (self.hip_min_rad < self.hip_max_rad and self.knee_min_rad < self.knee_max_rad):
            raise KinematicsError("joint limits must have min below max")

    @property
    def reach_m(self) -> float:
        return self.thigh_m + self.shank_m


def forward(leg: Leg, hip_rad: float, knee_rad: float) -> tuple[float, float]:
    """Ankle (x, z) relative to the hip for the given joint angles (no limit check)."""
    return leg_forward(leg.thigh_m, leg.shank_m, hip_rad, knee_rad)


def inverse(leg: Leg, x_m: float, z_m: float) -> tuple[float, float]:
    """Hip and knee flexion (knee bent backward, as a human knee) placing the ankle at (x, z).

    Raises :class:`KinematicsError` when the point is out of reach, non-finite, or needs joint
    angles beyond the limits; the message says which.
    """
    try:
        hip, knee = leg_inverse(leg.thigh_m, leg.shank_m, x_m, z_m)
    except ValueError as e:
        raise KinematicsError(str(e)) from None
    if not leg.hip_min_rad <= hip <= leg.hip_max_rad:
        raise KinematicsError(f"ankle target ({x_m:.3f}, {z_m:.3f}) m needs hip {hip:.3f} rad outside [{leg.hip_min_rad}, {leg.hip_max_rad}]")
    if not leg.knee_min_rad <= knee <= leg.knee_max_rad:
        raise KinematicsError(f"ankle target ({x_m:.3f}, {z_m:.3f}) m needs knee {knee:.3f} rad outside [{leg.knee_min_rad}, {leg.knee_max_rad}]")
    return hip, knee


def jacobian(leg: Leg, hip_rad: float, knee_rad: float) -> np.ndarray:
    """(2, 2) d(ankle x, z) / d(hip, knee)."""
    shank = hip_rad - knee_rad
    return np.array([
        [leg.thigh_m * math.cos(hip_rad) + leg.shank_m * math.cos(shank), -leg.shank_m * math.cos(shank)],
        [leg.thigh_m * math.sin(hip_rad) + leg.shank_m * math.sin(shank), -leg.shank_m * math.sin(shank)],
    ])
