"""The real-time loop's timing rules on a manual clock: the read window, late frames, a lost node
and the overrun budget (docs/FAULTS.md F1, F4, F25), deterministic.

The controller's :class:`~controller.loop.RealtimeLoop` runs as in the process, on a
:class:`~protocol.clock.ManualClock`; the emulated node boards and the simulated HHEA answer each
SYNC at once in lock-step, and :class:`_LatencyBus` delivers each of their frames to the
controller a chosen latency after the SYNC, moving the clock as a wait on the bus would. The
budgets are the configuration's; what real time adds (a machine that does not run a process) is
played by the latencies and by a core whose update takes long."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import can
import pytest

from config import default_config_path, load_config, with_overrides
from controller.core import ControllerCore
from controller.faults import FaultKind
from controller.hardware import CanHardware
from controller.loop import READ_WINDOW_S, RealtimeLoop
from controller.session import Session
from nodes.host import NodesHost
from protocol.bus import virtual_bus
from protocol.clock import TICK_NS, ManualClock
from protocol.codec import Codec
from protocol.enums import GaitState

BASE = load_config(default_config_path())
SAFETY = BASE.controller.safety
MS = 1_000_000
READ_WINDOW_NS = int(READ_WINDOW_S * 1e9)
CODEC = Codec()
SYNC = CODEC.spec("SYNC")


class _LatencyBus(can.BusABC):
    """The controller's end of the bus on a manual clock: what a node sends (pumped at once, in
    lock-step) arrives ``latency_ns(node, tick)`` after it was sent (None: lost); a read waits on
    the clock for the next arrival, at most its timeout."""

    def __init__(self, inner: can.BusABC, clock: ManualClock, pump: Callable[[], object],
                 latency_ns: Callable[[str, int], int | None]) -> None:
        self.inner, self.clock, self.pump, self.latency_ns = inner, clock, pump, latency_ns
        self.channel_info = "latency bus"
        self.tick = -1  # of the last SYNC sent
        self._coming: deque[tuple[int, can.Message]] = deque()
        super().__init__(channel=None)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)
        if msg.arbitration_id == SYNC.frame_id:
            self.tick = CODEC.decode(msg.arbitration_id, msg.data).values.tick
        self.pump()  # the nodes answer what was sent, at once
        now = self.clock.now_ns()
        while (m := self.inner.recv(0.0)) is not None:
            delay = self.latency_ns(CODEC.catalog.by_id(m.arbitration_id).sender, self.tick)
            if delay is not None:  # None: the frame is lost
                self._coming.append((now + delay, m))
        self._coming = deque(sorted(self._coming, key=lambda c: c[0]))

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame that arrives within ``timeout`` on the manual clock (python-can's own
        ``recv`` would measure the timeout on the wall clock)."""
        deadline = self.clock.now_ns() + int((timeout or 0.0) * 1e9)
        if self._coming and self._coming[0][0] <= deadline:
            at, msg = self._coming.popleft()
            self.clock.sleep_until(at)
            return msg
        self.clock.sleep_until(deadline)
        return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        raise NotImplementedError("recv reads the manual clock")

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()


class _Harness:
    def __init__(self, channel: str, latency_ns: Callable[[str, int], int | None], *,
                 update_ns: Callable[[int], int] = lambda tick: 0, **overrides) -> None:
        cfg = with_overrides(BASE, {"bus.channel": channel, "sim.mode": "sagittal", **overrides})
        self.clock = ManualClock(1_000 * TICK_NS)
        self.node_bus = virtual_bus(channel)
        self.host = NodesHost(cfg, self.node_bus, lockstep=True, seed=4)
        self.host.boot()
        self.bus = _LatencyBus(virtual_bus(channel), self.clock, lambda: self.host.poll(0.0), latency_ns)
        core = ControllerCore(cfg.controller)
        update = core.update

        def timed_update(snapshot):  # the core's work, as long as the test says
            self.clock.advance(update_ns(snapshot.tick))
            return update(snapshot)

        core.update = timed_update
        hardware = CanHardware(cfg.controller, self.bus, clock=self.clock, max_delta_counter=cfg.protocol.max_delta_counter)
        self.session = Session(RealtimeLoop(core, hardware))
        self.results = []

    def run(self, ticks: int) -> list:
        for _ in range(ticks):
            self.results.append(self.session.step())
        return self.results

    def close(self) -> None:
        self.host.close()
        self.bus.shutdown()
        self.node_bus.shutdown()

    def stops(self) -> list:
        return [t for t in self.session.core.fsm.transitions if t.target in (GaitState.HOLD, GaitState.FAULT)]


@pytest.fixture
def harness(request):
    made = []

    def make(latency_ns, **kwargs) -> _Harness:
        h = _Harness(f"timing-{request.node.name}-{len(made)}", latency_ns, **kwargs)
        made.append(h)
        return h

    yield make
    for h in made:
        h.close()


WALK_TICKS = 600


def test_answers_within_the_read_window_stand_and_walk_with_every_tick_fresh(harness):
    h = harness(lambda node, tick: 2 * MS)
    h.session.operator.start()
    h.run(WALK_TICKS)
    core, hw, stats = h.session.core, h.session.hardware, h.session.loop.stats.summary()
    assert h.stops() == [] and hw.counters.timeouts == 0 and stats["overruns"] == 0
    assert any(s.landed for s in core.steps)  # walking in real time on the manual clock
    assert [r.tick for r in h.results] == list(range(WALK_TICKS))  # no tick skipped


def test_frames_after_the_read_window_are_the_next_ticks_late_answers_and_start_no_step(harness):
    """F4: a node whose answers come after the read window (12 ms) is read in the next tick, dated
    from its counter to the tick it answered: one tick old, never taken for the tick's own. The
    controller holds on (age <= 2 is healthy) but starts no step on old data, where the same walk
    with every answer in time has started its first."""
    h = harness(lambda node, tick: (READ_WINDOW_NS + 3 * MS) if node == "RIGHT_HIP" and tick >= 100 else 2 * MS)
    h.session.operator.start()
    h.run(WALK_TICKS)
    hw, core = h.session.hardware, h.session.core
    assert h.stops() == []
    assert hw.nodes["RIGHT_HIP"].status_tick == h.session.tick - 1  # its newest status is last tick's
    assert hw.counters.timeouts == WALK_TICKS - 100  # every tick from 100 on waited out its window for that node
    assert core.steps == [] and h.session.state == GaitState.DOUBLE_SUPPORT  # walking, but no step on old data
    on_time = harness(lambda node, tick: 2 * MS)
    on_time.session.operator.start()
    on_time.run(WALK_TICKS)
    assert on_time.session.core.steps  # the same walk on time has started a step


def test_a_node_that_stops_answering_is_lost_after_lost_ticks(harness):
    """F1: no status from an operational node for ``lost_ticks`` ticks is NODE_LOST: FAULT."""
    silent_from = 150
    h = harness(lambda node, tick: None if node == "LEFT_KNEE" and tick >= silent_from else 2 * MS)
    h.run(200)
    [stop] = h.stops()
    assert stop.fault.kind in (FaultKind.NODE_LOST, FaultKind.SENSOR_LOST) and stop.target == GaitState.FAULT
    assert stop.tick == silent_from - 1 + SAFETY.lost_ticks  # its last status was of tick silent_from - 1


def test_overruns_within_the_budget_window_are_a_protective_stop(harness):
    """F25: ``overrun_limit`` overruns within ``overrun_window_ticks`` ticks stop walking (HOLD);
    fewer are counted only. The core's update takes 25 ms in the chosen ticks."""
    slow = {120, 140, 160}  # three overruns in 41 ticks: the third stops
    h = harness(lambda node, tick: 2 * MS, update_ns=lambda tick: 25 * MS if tick in slow else 0)
    h.run(200)
    [stop] = h.stops()
    assert stop.target == GaitState.HOLD and stop.fault.kind is FaultKind.OVERRUN
    assert h.session.loop.timer.overruns == 3 and stop.tick == 162  # tick 161 skipped by the third


def test_one_overrun_that_skips_more_than_the_limit_stops_at_once(harness):
    h = harness(lambda node, tick: 2 * MS, update_ns=lambda tick: (SAFETY.overrun_max_ticks + 2) * TICK_NS if tick == 120 else 0)
    h.run(160)
    [stop] = h.stops()
    assert stop.target == GaitState.HOLD and stop.fault.kind is FaultKind.OVERRUN and "skipped" in stop.fault.detail
    assert h.session.loop.timer.overruns == 1


def test_overruns_before_the_nodes_are_up_are_not_budgeted(harness):
    """In INIT nothing is commanded and a process's first ticks are its slowest: counted, not budgeted."""
    h = harness(lambda node, tick: 2 * MS, update_ns=lambda tick: 30 * MS if tick < 3 else 0)
    h.run(60)
    assert h.session.loop.timer.overruns >= 2 and h.stops() == []
    assert h.session.state == GaitState.STAND
