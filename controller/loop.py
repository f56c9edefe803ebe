"""The controller's tick loop on a bus: read (drain, bounded), update (:class:`ControllerCore`),
write; lock-step, behind the one clock abstraction.

Lock-step: tick ``k`` sends SYNC(k), then waits until every operational node's frames of the tick
(its JOINT_STATUS and the sensors it sends per SYNC, from the DBC) are in (at most
``tick_timeout_s``; a node whose JOINT_STATUS does not come is counted, and the core's
lost-node supervision makes it a fault after ``lost_ticks``), runs the core and sends its commands
and, on the DBC's schedule, the controller's heartbeat and telemetry. Before the nodes are operational a tick
waits ``boot_wait_s`` for frames. ``pump`` lets an in-process peer (the emulated nodes) run
between the controller's sends and receives; across processes it is None.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import can

from controller.core import ControllerCore, TickResult
from controller.telemetry import TelemetryLog
from controller.timing import TickStats
from protocol.bus import send_of
from protocol.busload import wire_time_ns
from protocol.clock import MAX_STALLS, STALL_NS, TICK_NS, Clock, MonotonicClock, TickTimer
from protocol.codec import Codec
from protocol.e2e import Receiver, Transmitter
from protocol.enums import SWINGS, JointMode, NmtState


@dataclass
class LoopReport:
    ticks: int = 0
    timeouts: int = 0  # ticks whose node frames were not all in within the timeout
    frames_sent: int = 0
    send_failures: int = 0
    drained_max: int = 0  # most frames read in one tick
    events: list[str] = field(default_factory=list)
    # ticks woken STALL_NS or more late, or whose work took that much longer than its CPU time
    # (protocol.clock), and real-time ticks that overran while mostly off the CPU: (tick, ms not run)
    stalls: list[tuple[int, float]] = field(default_factory=list)



class LockstepLoop:
    """Lock-step: each tick waits for the nodes' frames of its SYNC (see the module doc)."""

    def __init__(
        self, core: ControllerCore, bus: can.BusABC, *, codec: Codec | None = None, max_delta_counter: int = 2,
        tick_timeout_s: float = 2.0, boot_wait_s: float = 0.05, max_frames_per_tick: int = 200,
        pump: Callable[[], object] | None = None, clock: Clock | None = None, telemetry: TelemetryLog | None = None,
    ) -> None:
        self.core, self.bus = core, bus
        self._bus_send = send_of(bus)  # each message is made for one send
        self.codec = codec or Codec()
        self.rx = Receiver(self.codec, max_delta_counter=max_delta_counter)
        self.tx = Transmitter(self.codec)
        self.tick_timeout_s, self.boot_wait_s = tick_timeout_s, boot_wait_s
        self.max_frames = max_frames_per_tick  # per 20 ms read (1 Mbit/s carries at most about 180 frames in 20 ms)
        self.tick_ns = TICK_NS
        self.pump = pump
        self.telemetry = telemetry
        self.clock = clock or MonotonicClock()
        self.stats = TickStats(self.tick_ns)
        self.report = LoopReport()
        self.tick = -1
        self._idle_ns = 0  # time of the tick spent waiting for (or running) the nodes
        self._ran_ns = 0  # the thread's CPU time in the last tick
        catalog = self.codec.catalog
        self._status_ids = {catalog.message("JOINT_STATUS", n).frame_id: n for n in core.node_names}
        # Read before a SYNC: twice a tick's answers (a flood's frames beyond wait for the tick's read)
        self._queued_max = 2 * sum(len(ids) for ids in core.per_sync.values())

    def _send(self, name: str, values: tuple) -> None:
        """Send one frame; a failed send is retried once within the tick (a full transmit queue
        clears in microseconds), and a second failure is reported to the core (docs/FAULTS.md F12, F13)."""
        msg = self.tx.message(name, values)
        for _ in range(2):
            try:
                self._bus_send(msg)
                self.report.frames_sent += 1
                return
            except can.CanError:
                self.report.send_failures += 1
        self.core.send_failed(self.tick)

    def _drain(self, tick: int, until_ns: int, expected: set[str]) -> None:
        """Read this tick's frames until every expected node has reported or the deadline.

        Across processes (no ``pump``) the tick ends as soon as every expected node's per-SYNC
        frames are in, not at the deadline: ``recv`` would otherwise wait out the rest of the
        timeout once the last frame has come. In process the peer is pumped whenever the bus has
        nothing for us: the peer's frames come only from what we sent, so the frames read, and
        their order, are those of pumping before every read (with about two pumps a tick, not one a frame)."""
        got: set[str] = set()
        pending = set().union(*(self.core.per_sync[n] for n in expected)) if self.pump is None else set()
        read = 0
        now_ns, recv, pump = self.clock.now_ns, self.bus.recv, self.pump  # looked up once: the loop runs per frame
        receive, accept, status_ids = self.rx.receive, self.core.accept, self._status_ids
        max_frames, begin = self.max_frames, now_ns()
        while True:
            # At most max_frames per tick's worth of waiting: a lock-step tick waits as long as its
            # peer takes (seconds when the nodes process stalls), and a flood of foreign frames on
            # vcan0 (no bitrate) outran a bound per tick while the nodes' answers were still to come.
            if read >= max_frames and read >= max_frames * (1 + (now_ns() - begin) // self.tick_ns):
                break
            if pump is None:  # across processes a read waits for the nodes: not the controller's work
                t0 = now_ns()
                remaining_ns = until_ns - t0
                msg = recv(timeout=max(0.0, remaining_ns / 1e9))
                self._idle_ns += now_ns() - t0
            else:  # in process a read never waits; running the nodes (the pump) is their work
                msg = recv(timeout=0.0)
                if msg is None:
                    t0 = now_ns()
                    pump()
                    self._idle_ns += now_ns() - t0
                    remaining_ns = until_ns - t0
                    msg = recv(timeout=0.0)
            if msg is None:
                if expected <= got or remaining_ns <= 0:
                    break
                continue
            read += 1
            result = receive(msg)
            if accept(result, tick):  # a late frame is not this tick's
                frame_id = result.message.frame_id
                node = status_ids.get(frame_id)
                if node is not None:
                    got.add(node)
                if pending:
                    pending.discard(frame_id)
                    if not pending and expected <= got:
                        break
        self.report.drained_max = max(self.report.drained_max, read)
        if not expected <= got:
            self.report.timeouts += 1

    def _read_queued(self, tick: int) -> None:
        """Before tick ``tick``'s SYNC, what came after the last tick's read: answers to earlier
        SYNCs, never this tick's (:meth:`ControllerCore._age`). Across processes a tick's read ends
        once the frames it waits for are in, and a node's slower frames come after it. Read without
        waiting and at most ``_queued_max`` frames, so that a flood does not hold the SYNC back."""
        recv, receive, accept = self.bus.recv, self.rx.receive, self.core.accept
        for _ in range(self._queued_max):
            msg = recv(timeout=0.0)
            if msg is None:
                return
            accept(receive(msg), tick, queued=True)

    def _expected(self) -> set[str]:
        return {n for n, s in self.core.nodes.items() if s.nmt == NmtState.OPERATIONAL}

    def _tick(self, k: int, start_ns: int, read_until_ns: int, lateness_ns: int, expected: set[str],
              first_read_ns: int = 0) -> TickResult:
        """SYNC, read (from ``first_read_ns`` on, until the ``expected`` nodes reported), update, write:
        one tick ``k`` that started at ``start_ns``."""
        self.tick = k
        self._idle_ns = 0
        cpu0 = self.clock.cpu_ns()
        if self.pump is None:  # in process the last read ended on an empty queue, and only our sends fill it
            self._read_queued(k)
        self._send("SYNC", (k,))
        t0 = self.clock.now_ns()
        if first_read_ns > t0:
            self.clock.sleep_until(first_read_ns)
            self._idle_ns += self.clock.now_ns() - t0
        self._drain(k, read_until_ns, expected)
        result = self.core.tick(k)
        for name, values in result.frames:
            self._send(name, values)
        for name, values in self.core.scheduled_frames(k, result.state):
            self._send(name, values)
        self.report.events += [f"tick {k}: {e}" for e in result.events]
        self.report.ticks += 1
        elapsed = self.clock.now_ns() - start_ns
        work = elapsed - self._idle_ns
        self.stats.record(lateness_ns, work, elapsed)
        self._ran_ns = self.clock.cpu_ns() - cpu0
        self._stall(k, work - self._ran_ns)  # not run while working (a lower bound: reads count as waiting)
        if self.telemetry is not None:
            self.telemetry.put(self._record(result, work, lateness_ns))
        return result

    def _stall(self, tick: int, ns: int, least_ns: int = STALL_NS) -> None:
        if ns >= least_ns and len(self.report.stalls) < MAX_STALLS:
            self.report.stalls.append((tick, round(ns / 1e6, 1)))

    def _record(self, result: TickResult, work_ns: int, lateness_ns: int) -> dict:
        m, est = self.core.measurements, result.estimate
        step = self.core.steps[-1] if self.core.steps and result.state in SWINGS else None
        return {
            "tick": result.tick,
            "state": result.state.name,
            "q_rad": None if m is None else m.joint_position_rad,
            "setpoint_rad": [c.position_rad if c.mode == JointMode.TRACK else None for c in result.commands],
            "mode": [c.mode.name for c in result.commands],
            "stick_force_n": None if m is None else m.stick_force_n,
            "plantar_n": None if m is None else m.heel_force_n + m.toe_force_n,
            "trunk_rpy_rad": None if m is None else m.trunk_rpy_rad,
            "com_m": None if est is None else est.com,
            "x_ratio": None if est is None else est.x_ratio,
            "gait": (self.core.gait_part or None) if self.core.fsm.moving else None,  # "" before the first gait tick
            "step": None if step is None else step.index,
            "step_length_m": None if step is None else step.length_m,
            "step_cost_n": None if result.landed is None else result.landed.mean_stick_force_n,  # paper eq. (10), at landing
            "theta": None if step is None else step.theta,
            "work_us": round(work_ns / 1e3, 1),
            "lateness_us": round(lateness_ns / 1e3, 1),
            "events": result.events,
        }

    def step(self) -> TickResult:
        start = self.clock.now_ns()
        expected = self._expected()
        wait = self.tick_timeout_s if expected else self.boot_wait_s
        return self._tick(self.tick + 1, start, start + int(wait * 1e9), 0, expected)


READ_WINDOW_S = 0.012  # real time: the nodes' frames count for the tick if read this soon after its start


class RealtimeLoop(LockstepLoop):
    """Real time: tick ``k`` starts at its absolute monotonic deadline (``TickTimer``: an overrun is
    counted and the loop re-aligns to the next boundary, never a catch-up burst); the nodes' frames
    are read for at most ``read_window_s`` into the tick (12 ms: the nodes answer in 1-2 ms, in the
    vcan sandbox in 1-5 ms and now and then 8-15 ms; the core's work, 0.2-0.4 ms here and 1-2 ms
    in the sandbox, fits in what is left), then the core runs and the commands go out for the
    nodes to apply at the next SYNC.

    Reading starts once the nodes' answers can all be on the wire (CANopen's synchronous window):
    SYNC and every node's per-SYNC frames back to back at ``bitrate_bit_s`` with worst-case
    stuffing (1.5 ms at 1 Mbit/s). Woken for each frame as it came, the controller (the higher
    priority) took the CPU from the nodes between their frames where both share one (the vcan
    sandbox: the last frames came after the read window, and three such ticks were a lost node)."""

    def __init__(self, core: ControllerCore, bus: can.BusABC, *, read_window_s: float = READ_WINDOW_S,
                 bitrate_bit_s: int = 1_000_000, **kwargs) -> None:
        super().__init__(core, bus, **kwargs)
        self.read_window_ns = int(read_window_s * 1e9)
        catalog = self.codec.catalog
        answers = tuple(catalog.by_id(fid) for n in core.node_names for fid in core.per_sync[n])
        self.sync_window_ns = wire_time_ns((self.codec.spec("SYNC"), *answers), bitrate_bit_s)
        self.timer = TickTimer(self.clock, self.tick_ns)

    def step(self) -> TickResult:
        skipped_before = self.timer.skipped
        ended_ns = self.clock.now_ns()  # of the last tick and what its caller did after it
        k = self.timer.wait()
        start = self.clock.now_ns()
        self.stats.skipped = self.timer.skipped
        if self.timer.skipped > skipped_before:
            self.core.overran(k, self.timer.skipped - skipped_before)
            # The last tick, on the CPU for under half a period (its thread's CPU time; what the
            # caller does between ticks is microseconds), overran because the machine did not run
            # it: a stall, shorter than STALL_NS but an overrun all the same (this VM's hypervisor
            # takes the CPU for 20-40 ms, and three such in 50 ticks are the overrun budget's HOLD).
            # An overrun of the controller's own work is none.
            if self._ran_ns < self.tick_ns // 2:
                self._stall(self.tick, ended_ns - self.timer.deadline_ns(self.tick) - self._ran_ns, least_ns=0)
        lateness = self.timer.last_lateness_ns
        self._stall(k, lateness)
        # With no node operational (booting, or all lost) no answer is due: read what came, do not wait.
        expected = self._expected()
        read_until = start + (self.read_window_ns if expected else self.sync_window_ns)
        return self._tick(k, start, read_until, lateness, expected, start + self.sync_window_ns)
