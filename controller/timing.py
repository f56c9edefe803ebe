"""Tick timing of the 20 ms loop: cyclictest-style statistics.

:class:`TickStats` keeps the work time and the wake-up lateness of every tick in pre-allocated
arrays (no allocation in the tick) and reports min, avg, p99, max and overruns, as ``cyclictest``
does. The real-time set-up of the process is :func:`protocol.realtime.realtime_setup`.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def quantile_interval(values: np.ndarray, q: float, z: float = 1.96) -> tuple[float, float]:
    """The 95 % (``z`` 1.96) confidence interval of the ``q`` quantile of the distribution that
    ``values`` sample, from their order statistics (no assumption about the distribution): the
    values at ranks ``n q -/+ z sqrt(n q (1 - q))``. Two runs' p99 differ by chance within it."""
    ordered = np.sort(np.asarray(values, dtype=float))
    n = ordered.size
    half = z * np.sqrt(n * q * (1 - q))
    lo = int(np.clip(np.floor(n * q - half), 1, n))
    hi = int(np.clip(np.ceil(n * q + half), 1, n))
    return float(ordered[lo - 1]), float(ordered[hi - 1])


class TickStats:
    """Per-tick work time and wake-up lateness, in a ring of ``capacity`` ticks (the newest kept)."""

    def __init__(self, period_ns: int, capacity: int = 1 << 20) -> None:
        self.period_ns = period_ns
        self.work_ns = np.zeros(capacity, dtype=np.int64)
        self.late_ns = np.zeros(capacity, dtype=np.int64)
        self.count = 0
        self.overruns = 0  # ticks whose work ran past the next boundary
        self.skipped = 0  # tick boundaries skipped to re-align after overruns

    def record(self, lateness_ns: int, work_ns: int, elapsed_ns: int | None = None) -> None:
        """One tick: its wake-up lateness, its own work, and (when it also waited, e.g. for the
        nodes' frames) the whole time from wake-up to the end; past the period is an overrun."""
        i = self.count % self.work_ns.size
        self.late_ns[i] = lateness_ns
        self.work_ns[i] = work_ns
        self.count += 1
        if (work_ns if elapsed_ns is None else elapsed_ns) + lateness_ns > self.period_ns:
            self.overruns += 1

    @staticmethod
    def _summary(values: np.ndarray) -> dict[str, Any]:
        if values.size == 0:
            return {"min_us": 0.0, "avg_us": 0.0, "p50_us": 0.0, "p99_us": 0.0, "p99_ci_us": [0.0, 0.0], "max_us": 0.0}
        us = values / 1e3
        return {
            "min_us": round(float(us.min()), 1),
            "avg_us": round(float(us.mean()), 1),
            "p50_us": round(float(np.percentile(us, 50)), 1),
            "p99_us": round(float(np.percentile(us, 99)), 1),
            "p99_ci_us": [round(x, 1) for x in quantile_interval(us, 0.99)],
            "max_us": round(float(us.max()), 1),
        }

    def summary(self) -> dict[str, Any]:
        n = min(self.count, self.work_ns.size)
        return {
            "ticks": self.count,
            "samples": n,
            "period_ms": self.period_ns / 1e6,
            "work": self._summary(self.work_ns[:n]),
            "wakeup_lateness": self._summary(self.late_ns[:n]),
            "overruns": self.overruns,
            "skipped_ticks": self.skipped,
        }

    def format(self) -> str:
        s = self.summary()
        w, lat = s["work"], s["wakeup_lateness"]
        return (
            f"T: {s['ticks']} ticks of {s['period_ms']:g} ms | work us min {w['min_us']} avg {w['avg_us']} p99 {w['p99_us']} "
            f"max {w['max_us']} | lateness us min {lat['min_us']} avg {lat['avg_us']} p99 {lat['p99_us']} max {lat['max_us']} "
            f"| overruns {s['overruns']}, skipped {s['skipped_ticks']}"
        )
