"""CoM compensation of the step length (paper equation (8)) and its safety clamp.

    g = g_init + alpha * (Xhat_CoM - X_CoM / X_SP)

``X_CoM / X_SP`` is where the CoM lies fore-aft in the support polygon (0 = rear edge, 1 = front
edge); ``alpha`` and ``Xhat_CoM`` are the learned parameters theta. The result is clamped to the
configured safe step lengths before it can reach a motor, and a clamp is always reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


class CompensationError(ValueError):
    """Non-finite or inconsistent inputs to the compensation."""


@dataclass(frozen=True)
class StepBounds:
    init_m: float  # g_init: the step length without compensation
    min_m: float
    max_m: float

    def __post_init__(self) -> None:
        if not (0.0 < self.min_m <= self.init_m <= self.max_m):
            raise CompensationError(f"need 0 < min <= init <= max, got {self.min_m}, {self.init_m}, {self.max_m}")


@dataclass(frozen=True)
class StepGoal:
    """The step length to use, and what the clamp did to it."""

    length_m: float
    requested_m: float
    clamped: bool
    reason: str = ""


def compensated_step(bounds: StepBounds, alpha: float, xhat_com: float, com_ratio: float) -> StepGoal:
    """Step length from the CoM's place in the support polygon, clamped to ``bounds``.

    A non-finite ``com_ratio`` (no support polygon estimate) falls back to the uncompensated
    ``init_m``, reported as clamped with its reason; non-finite parameters raise.
    """
    if not (math.isfinite(alpha) and math.isfinite(xhat_com)):
        raise CompensationError(f"compensation parameters must be finite, got alpha={alpha}, xhat={xhat_com}")
    if not math.isfinite(com_ratio):
        return StepGoal(bounds.init_m, math.nan, True, "no CoM ratio: uncompensated step")
    requested = bounds.init_m + alpha * (xhat_com - com_ratio)
    if requested < bounds.min_m:
        return StepGoal(bounds.min_m, requested, True, f"{requested:.3f} m below the minimum {bounds.min_m} m")
    if requested > bounds.max_m:
        return StepGoal(bounds.max_m, requested, True, f"{requested:.3f} m above the maximum {bounds.max_m} m")
    return StepGoal(requested, requested, False)
