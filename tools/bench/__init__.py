"""Benchmarks behind ``aider-exo bench``: each prints figures beside a baseline measured in the same run."""

from __future__ import annotations

import statistics
from typing import Any


def median_of_runs(runs: list[Any]) -> Any:
    """One result from repeated runs of the same benchmark: every number is the median of its
    values over the runs (nested dicts key by key); anything else (a walk's outcome, a name) is
    the first run's, since the runs are of the same deterministic work."""
    first = runs[0]
    if isinstance(first, dict):
        return {key: median_of_runs([r[key] for r in runs]) for key in first}
    if isinstance(first, (int, float)) and not isinstance(first, bool) and all(isinstance(r, (int, float)) for r in runs):
        value = statistics.median(runs)
        return round(value, 3) if isinstance(value, float) else value
    return first
