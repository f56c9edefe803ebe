"""``trace replay``: the schedule on a manual clock (exact), stalls without a catch-up burst, speed,
gaps, loops, backwards timestamps, roles from the DBC, and a real-time run on the virtual bus."""

from __future__ import annotations

import can
import pytest

from protocol.catalog import default_catalog
from protocol.clock import ManualClock, MonotonicClock
from protocol.codec import Codec
from tools.cli import main
from tools.trace.decode import Selection, TraceDecoder
from tools.trace.reader import Frame
from tools.trace.replay import ReplayOptions, replay
from tools.trace.synthetic import lockstep_frames

CODEC = Codec()
FRAMES = lockstep_frames(CODEC, 20)
T0 = FRAMES[0].timestamp


class Sink:
    """``send`` that notes the clock's time; it can block once, as a descheduled process."""

    def __init__(self, clock, stall_at=None, stall_ns=0):
        self.clock, self.stall_at, self.stall_ns = clock, stall_at, stall_ns
        self.times, self.messages = [], []

    def __call__(self, msg):
        if len(self.times) == self.stall_at:
            self.clock.advance(self.stall_ns)
        self.times.append(self.clock.now_ns())
        self.messages.append(msg)


def _offsets_ns(frames):
    return [round((f.timestamp - frames[0].timestamp) * 1e9) for f in frames]


def test_frames_leave_at_their_recorded_times_on_an_absolute_schedule():
    clock = ManualClock(5_000)
    sink = Sink(clock)
    report = replay(FRAMES, sink, clock)
    assert [t - 5_000 for t in sink.times] == _offsets_ns(FRAMES)
    assert [(m.arbitration_id, bytes(m.data)) for m in sink.messages] == [(f.arbitration_id, f.data) for f in FRAMES]
    assert report.sent == len(FRAMES) and report.late_frames == 0 and max(report.lateness_ns) == 0


def test_speed_factor():
    clock = ManualClock()
    sink = Sink(clock)
    replay(FRAMES, sink, clock, ReplayOptions(speed=4.0))
    assert sink.times == [pytest.approx(o / 4, abs=1) for o in _offsets_ns(FRAMES)]


def test_a_stall_gives_no_catch_up_burst_and_the_schedule_is_caught_up():
    stall_at, stall_ns = 100, 50_000_000
    clock = ManualClock()
    sink = Sink(clock, stall_at, stall_ns)
    report = replay(FRAMES, sink, clock)
    offsets = _offsets_ns(FRAMES)
    recorded_gaps = [b - a for a, b in zip(offsets, offsets[1:])]
    sent_gaps = [b - a for a, b in zip(sink.times, sink.times[1:])]
    # After the stall every frame keeps at least half its recorded gap: no burst.
    assert all(s >= g // 2 for s, g in zip(sent_gaps[stall_at:], recorded_gaps[stall_at:]))
    assert report.late_frames > 5
    # ... and the replay is back on its original schedule by the end (no drift).
    assert sink.times[-1] == offsets[-1]
    # python-can's MessageSync and canplayer behaviour, on request: the overdue frames at once.
    clock = ManualClock()
    burst = Sink(clock, stall_at, stall_ns)
    replay(FRAMES, burst, clock, ReplayOptions(catch_up=True))
    after = burst.times[stall_at:]
    assert sum(1 for t in after if t == after[0]) > 20


def test_long_gaps_are_shortened_and_backwards_timestamps_sent_at_once():
    frames = [Frame(0.0, 0x80, b"\x00" * 5), Frame(5.0, 0x80, b"\x01" * 5), Frame(4.0, 0x80, b"\x02" * 5),
              Frame(4.01, 0x80, b"\x03" * 5)]
    clock = ManualClock()
    sink = Sink(clock)
    report = replay(frames, sink, clock, ReplayOptions(max_gap_s=0.5))
    assert sink.times == [0, 500_000_000, 500_000_000, 510_000_000]
    assert report.gaps_shortened == 1 and report.backwards == 1


def test_loops_continue_the_schedule_and_error_frames_are_never_sent():
    frames = FRAMES[:10] + [Frame(FRAMES[9].timestamp + 0.001, 0, b"", is_error_frame=True)]
    clock = ManualClock()
    sink = Sink(clock)
    report = replay(frames, sink, clock, ReplayOptions(loops=3))
    assert report.sent == 30 and report.loops_done == 3 and report.error_frames_skipped == 1
    offsets = _offsets_ns(FRAMES[:10])
    period = offsets[-1] + offsets[-1] // 9
    assert sink.times[10:20] == [o + period for o in offsets]


def test_stop_ends_a_replay_that_loops_forever():
    clock = ManualClock()
    sink = Sink(clock)
    report = replay(FRAMES, sink, clock, ReplayOptions(loops=None), stop=lambda: len(sink.times) >= 500)
    assert report.stopped and report.sent == 500


def test_roles_come_from_the_dbc_senders():
    catalog = default_catalog()
    nodes = tuple(n for n in catalog.nodes if n != "CONTROLLER")
    node_rows = list(TraceDecoder(CODEC).rows(FRAMES, Selection(senders=nodes).compile(catalog)))
    ctl_rows = list(TraceDecoder(CODEC).rows(FRAMES, Selection(senders=("CONTROLLER",)).compile(catalog)))
    assert len(node_rows) + len(ctl_rows) == len(FRAMES)
    assert {r.spec.name for r in ctl_rows} >= {"SYNC", "JOINT_COMMAND_LH", "CONTROLLER_HEARTBEAT"}
    assert {r.spec.sender for r in node_rows} == set(nodes)


def test_a_real_time_replay_on_the_virtual_bus_delivers_every_frame_in_order():
    """On the monotonic clock (the figures are the benchmark's; nothing here asserts a time)."""
    frames = FRAMES[:60]
    with can.Bus(interface="virtual", channel="trace-replay-test", ignore_config=True) as tx, \
            can.Bus(interface="virtual", channel="trace-replay-test", ignore_config=True) as rx:
        report = replay(frames, tx.send, MonotonicClock(), ReplayOptions(speed=5.0, spin_s=0.0002))
        got = []
        while (msg := rx.recv(timeout=0.0)) is not None:
            got.append((msg.arbitration_id, bytes(msg.data)))
    assert got == [(f.arbitration_id, f.data) for f in frames] and report.sent == 60


def test_cli_replay_refuses_the_virtual_bus(tmp_path, capsys):
    log = tmp_path / "t.log"
    log.write_text("(0.0) vcan0 080#00\n")
    assert main(["trace", "replay", str(log)]) == 1
    assert "virtual bus lives inside one process" in capsys.readouterr().err
