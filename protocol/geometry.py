"""The exoskeleton's geometry that the controller and the simulation share, one definition each.

* The sagittal leg in the joints' convention (docs/PROTOCOL.md: hip flexion positive, thigh
  forward; knee flexion positive, shank back relative to the thigh; 0 the straight leg hanging
  down): where the ankle is for a hip and knee angle, and the angles that put it at a point, in
  the thigh's pitch frame (x forward, z up, from the hip). What a JOINT_STATUS position means and
  what a JOINT_COMMAND setpoint asks; the controller commands by it, the simulation poses by it.
* X_CoM/X_SP, the paper's measure (SPEC): the centre of mass's place between the rear-most and the
  front-most point of a support along the walking direction. The controller estimates it from the
  sensors, the simulation knows it; both by this definition.

Pure floats, no numpy: the controller calls these every tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

#: a knee cosine this far beyond +-1 is rounding (an ankle at the leg's full reach), not out of reach
REACH_TOLERANCE = 1e-12


def leg_forward(thigh_m: float, shank_m: float, hip_rad: float, knee_rad: float) -> tuple[float, float]:
    """The ankle's (x, z) from the hip for the hip and knee flexion (no limit check)."""
    shank = hip_rad - knee_rad
    return (thigh_m * math.sin(hip_rad) + shank_m * math.sin(shank),
            -thigh_m * math.cos(hip_rad) - shank_m * math.cos(shank))


def leg_inverse(thigh_m: float, shank_m: float, x_m: float, z_m: float) -> tuple[float, float]:
    """The hip and knee flexion (the knee bent backward, as a human knee) that put the ankle at
    (x, z) from the hip. ValueError, saying why, for a point out of the leg's reach or not finite."""
    if not (math.isfinite(x_m) and math.isfinite(z_m)):
        raise ValueError(f"ankle target ({x_m}, {z_m}) is not finite")
    d2 = x_m * x_m + z_m * z_m
    cos_knee = (d2 - thigh_m**2 - shank_m**2) / (2.0 * thigh_m * shank_m)
    if cos_knee > 1.0 + REACH_TOLERANCE or cos_knee < -1.0 - REACH_TOLERANCE:
        raise ValueError(f"ankle target ({x_m:.3f}, {z_m:.3f}) m is {math.sqrt(d2):.3f} m from the hip: "
                         f"outside the leg's reach [{abs(thigh_m - shank_m):.3f}, {thigh_m + shank_m:.3f}] m")
    knee = math.acos(min(1.0, max(-1.0, cos_knee)))
    hip = math.atan2(x_m, -z_m) + math.atan2(shank_m * math.sin(knee), thigh_m + shank_m * math.cos(knee))
    return hip, knee


def fore_aft_ratio(com_m: float, support_m: Sequence[float], min_extent_m: float) -> float:
    """X_CoM/X_SP: ``(com - rear) / (front - rear)`` with rear and front the least and the greatest
    of the support's points ``support_m``, all measured along the walking direction; 0 at the
    rear, 1 at the front. nan for no support or one shorter than ``min_extent_m``, which says
    nothing fore-aft."""
    if not support_m:
        return math.nan
    rear, front = min(support_m), max(support_m)
    return (com_m - rear) / (front - rear) if front - rear >= min_extent_m and front > rear else math.nan
