"""Tick timing of the 20 ms loop: cyclictest-style statistics and the real-time set-up.

:class:`TickStats` keeps the work time and the wake-up lateness of every tick in pre-allocated
arrays (no allocation in the tick) and reports min, avg, p99, max and overruns, as ``cyclictest``
does. :func:`realtime_setup` applies the hygiene of ../shared/REALTIME.md where the OS permits it
(``gc.freeze``, ``mlockall``, CPU pinning, SCHED_FIFO, ``/dev/cpu_dma_latency`` held at 0) and
returns one warning per step it could not take, for the caller to log: a controller without the
privileges still runs, and says so.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

MCL_CURRENT, MCL_FUTURE = 1, 2


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
    def _summary(values: np.ndarray) -> dict[str, float]:
        if values.size == 0:
            return {"min_us": 0.0, "avg_us": 0.0, "p99_us": 0.0, "max_us": 0.0}
        us = values / 1e3
        return {
            "min_us": round(float(us.min()), 1),
            "avg_us": round(float(us.mean()), 1),
            "p99_us": round(float(np.percentile(us, 99)), 1),
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


@dataclass
class RealtimeReport:
    """What :func:`realtime_setup` did, and what it could not do."""

    applied: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    dma_latency_fd: int | None = None  # keep open while the loop runs; close() releases it

    def close(self) -> None:
        if self.dma_latency_fd is not None:
            os.close(self.dma_latency_fd)
            self.dma_latency_fd = None


def warm_up_linear_algebra() -> None:
    """Make numpy's BLAS and LAPACK allocate the work buffers they take on their first call
    (OpenBLAS: 8 MiB at the first matrix product, 32 MiB at the first solve) before the memory is
    locked and the loop runs. Under ``mlockall(MCL_FUTURE)`` every page of them is faulted in at
    that first call, which is the DMP fit at the first swing: measured in the vcan sandbox, 8215
    page faults in one tick of 23-64 ms, an overrun that skipped up to 4 ticks."""
    a = np.eye(4) + 0.1
    np.linalg.solve(a @ a, np.ones(4))


def realtime_setup(
    *, priority: int = 50, cpu: int | None = None, lock_memory: bool = True, dma_latency_path: str = "/dev/cpu_dma_latency"
) -> RealtimeReport:
    """The start-up sequence of REALTIME.md, each step tried and reported."""
    report = RealtimeReport()
    warm_up_linear_algebra()
    report.applied.append("linear-algebra buffers allocated")
    gc.collect()
    gc.freeze()
    report.applied.append("gc.freeze")
    if lock_memory:
        libc_name = ctypes.util.find_library("c")
        try:
            libc = ctypes.CDLL(libc_name, use_errno=True)
            if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
                raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()))
            report.applied.append("mlockall")
        except OSError as exc:
            report.warnings.append(f"mlockall failed ({exc}); pages may fault in the loop (needs root or a memlock rlimit)")
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
            report.applied.append(f"pinned to CPU {cpu}")
        except (OSError, ValueError) as exc:
            report.warnings.append(f"cannot pin to CPU {cpu} ({exc})")
    try:
        policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
        os.sched_setscheduler(0, policy, os.sched_param(priority))
        report.applied.append(f"SCHED_FIFO {priority}")
    except (OSError, AttributeError) as exc:
        report.warnings.append(f"SCHED_FIFO {priority} refused ({exc}); the loop runs at normal priority (needs CAP_SYS_NICE or an rtprio rlimit)")
    try:
        fd = os.open(dma_latency_path, os.O_WRONLY)
        os.write(fd, struct.pack("i", 0))
        report.dma_latency_fd = fd
        report.applied.append(f"{dma_latency_path} held at 0")
    except OSError as exc:
        report.warnings.append(f"cannot hold {dma_latency_path} at 0 ({exc}); deep CPU idle states add wake-up latency")
    return report
