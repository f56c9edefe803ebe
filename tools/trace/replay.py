"""Replaying a trace onto a bus with its original timing, on an absolute schedule behind the clock
abstraction (:mod:`protocol.clock`), so tests run it on a :class:`~protocol.clock.ManualClock`.

Frame ``i`` is due at ``start + (t_i - t_0) / speed``: an absolute schedule, so sleep errors
never accumulate into a drift. When the replay falls behind (the process was descheduled, the
bus pushed back), the overdue frames do not leave in a burst, as with python-can's
``MessageSync`` and ``canplayer``: each keeps at least ``min_spacing`` (default half) of its
recorded gap to the frame before, so the replay catches up gradually, at most twice as fast as
recorded, and is back on the original schedule soon after. ``catch_up=True`` sends overdue frames
at once instead. The last ``spin_s`` before a due time are spent polling the clock instead of
sleeping (the kernel's sleep overshoots by some 50-100 us). A timestamp that goes backwards
is sent at once and counted; a gap longer than ``max_gap_s`` is shortened to it (0: sent at
once); ``loops`` plays the trace again after one mean frame interval. Error frames are never
sent.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from protocol.clock import Clock
from tools.trace.reader import Frame

#: while waiting longer than this, the stop request is checked
_STOP_POLL_NS = 200_000_000


@dataclass(frozen=True)
class ReplayOptions:
    speed: float = 1.0
    loops: int | None = 1  # None: until stopped
    max_gap_s: float | None = None
    catch_up: bool = False
    min_spacing: float = 0.5  # behind schedule: the fraction of a recorded gap kept (unless catch_up)
    spin_s: float = 0.0


@dataclass
class ReplayReport:
    frames_in_trace: int = 0
    sent: int = 0
    send_failures: int = 0
    error_frames_skipped: int = 0
    late_frames: int = 0  # sent more than 1 ms after their due time
    backwards: int = 0
    gaps_shortened: int = 0
    loops_done: int = 0
    stopped: bool = False
    lateness_ns: list[int] = field(default_factory=list, repr=False)

    def as_dict(self) -> dict[str, Any]:
        late = np.asarray(self.lateness_ns, dtype=float) / 1e3
        summary = None
        if late.size:
            summary = {k: round(float(v), 1) for k, v in (("p50", np.percentile(late, 50)), ("p99", np.percentile(late, 99)),
                                                          ("max", late.max()))}
        return {
            "frames_in_trace": self.frames_in_trace, "sent": self.sent, "send_failures": self.send_failures,
            "error_frames_skipped": self.error_frames_skipped, "late_frames_over_1ms": self.late_frames,
            "timestamps_backwards": self.backwards, "gaps_shortened": self.gaps_shortened,
            "loops_done": self.loops_done, "stopped": self.stopped, "lateness_us": summary,
        }


def schedule_offsets_ns(frames: Sequence[Frame], options: ReplayOptions, report: ReplayReport) -> list[int]:
    """Each frame's due time after the first one's, in ns of the replay (speed and gaps applied);
    a backwards timestamp gives a gap of 0 and is marked in ``report``."""
    offsets, offset, previous = [], 0.0, None
    for frame in frames:
        gap = 0.0 if previous is None else frame.timestamp - previous
        if gap < 0:
            report.backwards += 1
            gap = 0.0
        elif options.max_gap_s is not None and gap > options.max_gap_s:
            report.gaps_shortened += 1
            gap = options.max_gap_s
        offset += gap / options.speed
        offsets.append(round(offset * 1e9))
        previous = frame.timestamp
    return offsets


def _wait(clock: Clock, due_ns: int, spin_ns: int) -> None:
    if spin_ns:
        clock.sleep_until(due_ns - spin_ns)
        last = clock.now_ns()
        while last < due_ns:
            now = clock.now_ns()
            if now == last:  # a clock that moves only when slept on (ManualClock)
                break
            last = now
    clock.sleep_until(due_ns)


def replay(
    frames: Sequence[Frame], send: Callable[[can.Message], None], clock: Clock, options: ReplayOptions = ReplayOptions(),
    *, stop: Callable[[], bool] = lambda: False,
) -> ReplayReport:
    """Send ``frames`` through ``send`` (usually ``bus.send``) on their schedule (see the module doc)."""
    report = ReplayReport(frames_in_trace=len(frames))
    playable = [f for f in frames if not f.is_error_frame]
    report.error_frames_skipped = len(frames) - len(playable)
    if not playable:
        return report
    messages = [f.to_message() for f in playable]
    offsets = schedule_offsets_ns(playable, options, report)
    span = offsets[-1]
    loop_gap = span // (len(offsets) - 1) if len(offsets) > 1 else 0
    spacing = 0.0 if options.catch_up else options.min_spacing
    spin_ns = round(options.spin_s * 1e9)
    origin = clock.now_ns()
    sent_at = previous = None
    loop = 0
    while options.loops is None or loop < options.loops:
        for msg, offset in zip(messages, offsets):
            due = origin + offset
            target = due if sent_at is None else max(due, sent_at + round(spacing * (due - previous)))
            while target - clock.now_ns() > _STOP_POLL_NS:
                if stop():
                    report.stopped = True
                    return report
                clock.sleep_until(clock.now_ns() + _STOP_POLL_NS)
            _wait(clock, target, spin_ns)
            late = clock.now_ns() - due
            try:
                send(msg)
                report.sent += 1
            except can.CanError:
                report.send_failures += 1
            sent_at, previous = clock.now_ns(), due  # after the send: a send that blocked counts
            report.lateness_ns.append(max(0, late))
            report.late_frames += late > 1_000_000
            if stop():
                report.stopped = True
                return report
        loop += 1
        report.loops_done = loop
        origin += span + loop_gap
    return report
