"""The one clock abstraction: every time read and every sleep in the project goes through here.

:class:`MonotonicClock` is real time (CLOCK_MONOTONIC; immune to wall-clock jumps);
:class:`ManualClock` is driven by its owner (tests, lock-step, replay), so nothing waits on the
wall clock. :class:`TickTimer` paces a periodic loop on absolute deadlines: an overrun is
counted and the loop re-aligns to the next future tick boundary, never catching up in a burst.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

#: The controller's tick: every cyclic message of the DBC is a multiple of it, every loop runs on it.
TICK_MS = 20
TICK_S = TICK_MS / 1000
TICK_NS = TICK_MS * 1_000_000


class Clock(Protocol):
    def now_ns(self) -> int:
        """Monotonic time in nanoseconds."""

    def sleep_until(self, deadline_ns: int) -> None:
        """Return at (or after) ``deadline_ns``; at once if it has passed."""

    def cpu_ns(self) -> int:
        """CPU time of the calling thread in nanoseconds: less than the time passed while it ran
        when it was not running (another process, or the host, had the CPU)."""


def epoch_s() -> float:
    """Wall-clock seconds since the epoch: only for stamping CAN messages as python-can does
    (``time.time()``), never for timing."""
    return time.time()


class MonotonicClock:
    """Real time. CPython >= 3.11 sleeps with clock_nanosleep on CLOCK_MONOTONIC."""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_until(self, deadline_ns: int) -> None:
        delay = deadline_ns - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay / 1e9)

    def cpu_ns(self) -> int:
        return time.thread_time_ns()


class ManualClock:
    """Time that moves only when told to: ``advance``, or ``sleep_until`` (which jumps to the deadline)."""

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns

    def now_ns(self) -> int:
        return self._now

    def advance(self, delta_ns: int) -> None:
        if delta_ns < 0:
            raise ValueError("a monotonic clock cannot go back")
        self._now += delta_ns

    def sleep_until(self, deadline_ns: int) -> None:
        if deadline_ns > self._now:
            self._now = deadline_ns

    def cpu_ns(self) -> int:
        """The thread runs whenever time moves."""
        return self._now


#: A periodic loop that wakes this late to a tick beyond its own work, or whose work took this much
#: longer than the CPU time it used, was not running: another process or the host had the CPU.
#: The real-time loops report such stalls (at most MAX_STALLS).
STALL_NS = 40_000_000
MAX_STALLS = 20


@dataclass
class TickTimer:
    """Absolute-deadline pacing of a periodic loop.

    ``wait()`` sleeps until the start of the next tick and returns its number. When work ran
    past one or more tick boundaries, those ticks are skipped (counted in ``skipped``) and the
    loop resumes at the next boundary still in the future: no burst of late ticks.
    """

    clock: Clock
    period_ns: int
    start_ns: int | None = None
    tick: int = -1
    overruns: int = 0
    skipped: int = 0
    last_lateness_ns: int = 0

    def __post_init__(self) -> None:
        if self.period_ns <= 0:
            raise ValueError("period must be positive")
        if self.start_ns is None:
            self.start_ns = self.clock.now_ns()

    def deadline_ns(self, tick: int) -> int:
        assert self.start_ns is not None
        return self.start_ns + tick * self.period_ns

    def wait(self) -> int:
        """Sleep until the next tick boundary and return that tick's number."""
        nxt = self.tick + 1
        now = self.clock.now_ns()
        if now > self.deadline_ns(nxt) and self.tick >= 0:
            # Overrun: the work of the previous tick ended after this boundary.
            first_future = (now - self.start_ns) // self.period_ns + 1  # type: ignore[operator]
            self.overruns += 1
            self.skipped += first_future - nxt
            nxt = first_future
        self.clock.sleep_until(self.deadline_ns(nxt))
        self.last_lateness_ns = max(0, self.clock.now_ns() - self.deadline_ns(nxt))
        self.tick = nxt
        return nxt
