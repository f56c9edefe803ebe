"""The real-time set-up of a process with a 20 ms loop (the controller, the emulated node boards,
the trace player).

:func:`realtime_setup` applies the hygiene of docs/REALTIME.md where the OS permits it
(``gc.freeze``, ``mlockall``, CPU pinning, SCHED_FIFO, ``/dev/cpu_dma_latency`` held at 0) and
returns one warning per step it could not take, for the caller to log: a process without the
privileges still runs, and says so.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import struct
from dataclasses import dataclass, field

import numpy as np

MCL_CURRENT, MCL_FUTURE = 1, 2


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
    *, priority: int | None = 50, cpu: int | None = None, lock_memory: bool = True, dma_latency_path: str = "/dev/cpu_dma_latency"
) -> RealtimeReport:
    """The start-up sequence of docs/REALTIME.md, each step tried and reported (``priority`` None: the
    process keeps the normal scheduler)."""
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
    if priority is not None:
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
