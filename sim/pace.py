"""The simulated gait's pace: how long a walk may take before it counts as stalled."""

from __future__ import annotations


def default_max_time_s(cycles: int) -> float:
    """Simulated time a walk of ``cycles`` gait cycles may take before it counts as stalled."""
    return 20.0 + 15.0 * cycles
