"""The exoskeleton as the controller's hardware (ros2_control's system interface): ``read`` a
tick's :class:`~controller.interfaces.Snapshot`, ``write`` its
:class:`~controller.interfaces.Commands`.

:class:`CanHardware` is the four node boards on a python-can bus: ``read`` sends SYNC(k) and reads
the nodes' answers until the deadline its loop gives (or until every operational node's per-SYNC
frames are in), each through the end-to-end :class:`~protocol.e2e.Receiver`; ``write`` sends the
tick's frames (:meth:`CanSystem.frames`), each retried once on a failed send. :class:`ReplayHardware`
reads a recorded trace's node frames instead and keeps what would have been written, for
``aider-exo trace resim`` and the tests. What both know of the nodes and the bus, and the mapping to
frames, is :class:`~controller.cansystem.CanSystem`'s.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Protocol

import can

from config.controller_schema import ControllerConfig
from controller.cansystem import BusCounters, CanSystem, NodeState
from controller.interfaces import Commands, Snapshot
from protocol.bus import send_of
from protocol.busload import wire_time_ns
from protocol.clock import TICK_NS, Clock, MonotonicClock
from protocol.codec import Codec, Decoded
from protocol.e2e import Receiver, Transmitter


class Hardware(Protocol):
    """What a loop needs of its hardware (ros2_control's system interface)."""

    clock: Clock
    idle_ns: int  # of the last read: waiting for (or running) the nodes, not the controller's work
    nodes: dict[str, NodeState]
    counters: BusCounters

    def operational_nodes(self) -> set[str]: ...

    def read(self, tick: int, until_ns: int, first_read_ns: int = 0) -> Snapshot: ...

    def write(self, tick: int, commands: Commands) -> None: ...


class CanHardware(CanSystem):
    """The node boards on a bus (see the module doc). ``pump`` lets an in-process peer (the
    emulated nodes) run between the controller's sends and reads; across processes it is None."""

    def __init__(
        self, cfg: ControllerConfig, bus: can.BusABC, *, codec: Codec | None = None, max_delta_counter: int = 2,
        max_frames_per_tick: int = 200, pump: Callable[[], object] | None = None, clock: Clock | None = None,
    ) -> None:
        self.codec = codec or Codec()
        super().__init__(cfg, catalog=self.codec.catalog)
        self.bus = bus
        self._bus_send = send_of(bus)  # each message is made for one send
        self.rx = Receiver(self.codec, max_delta_counter=max_delta_counter)
        self.tx = Transmitter(self.codec)
        self.max_frames = max_frames_per_tick  # per 20 ms read (1 Mbit/s carries at most about 180 frames in 20 ms)
        self.pump = pump
        self.clock = clock or MonotonicClock()
        self.idle_ns = 0  # of this tick: waiting for (or running) the nodes
        self.tick = -1
        self._status_ids = {self.catalog.message("JOINT_STATUS", n).frame_id: n for n in self.node_names}
        # Read before a SYNC: twice a tick's answers (a flood's frames beyond wait for the tick's read)
        self._queued_max = 2 * sum(len(ids) for ids in self.per_sync.values())

    def sync_window_ns(self, bitrate_bit_s: int) -> int:
        """SYNC and every node's per-SYNC answers back to back at ``bitrate_bit_s`` with worst-case
        stuffing: the earliest time all the answers can be on the wire (CANopen's synchronous window)."""
        answers = tuple(self.catalog.by_id(fid) for n in self.node_names for fid in self.per_sync[n])
        return wire_time_ns((self.codec.spec("SYNC"), *answers), bitrate_bit_s)

    # -- read ------------------------------------------------------------------------------------

    def read(self, tick: int, until_ns: int, first_read_ns: int = 0) -> Snapshot:
        """SYNC(``tick``), then the nodes' frames from ``first_read_ns`` until ``until_ns`` or until
        every operational node has answered; the tick's snapshot."""
        self.tick = tick
        self.idle_ns = 0
        expected = self.operational_nodes()
        if self.pump is None:  # in process the last read ended on an empty queue, and only our sends fill it
            self._read_queued(tick)
        self._send("SYNC", (tick,))
        t0 = self.clock.now_ns()
        if first_read_ns > t0:
            self.clock.sleep_until(first_read_ns)
            self.idle_ns += self.clock.now_ns() - t0
        self._drain(tick, until_ns, expected)
        return self.snapshot(tick)

    def _drain(self, tick: int, until_ns: int, expected: set[str]) -> None:
        """Read this tick's frames until every expected node has reported or the deadline.

        Across processes (no ``pump``) the tick ends as soon as every expected node's per-SYNC
        frames are in, not at the deadline: ``recv`` would otherwise wait out the rest of the
        timeout once the last frame has come. In process the peer is pumped whenever the bus has
        nothing for us: the peer's frames come only from what we sent, so the frames read, and
        their order, are those of pumping before every read (with about two pumps a tick, not one a frame)."""
        got: set[str] = set()
        pending = set().union(*(self.per_sync[n] for n in expected)) if self.pump is None else set()
        read = 0
        now_ns, recv, pump = self.clock.now_ns, self.bus.recv, self.pump  # looked up once: the loop runs per frame
        receive, accept, status_ids = self.rx.receive, self.accept, self._status_ids
        max_frames, begin = self.max_frames, now_ns()
        while True:
            # At most max_frames per tick's worth of waiting: a lock-step tick waits as long as its
            # peer takes (seconds when the nodes process stalls), and a flood of foreign frames on
            # vcan0 (no bitrate) outran a bound per tick while the nodes' answers were still to come.
            if read >= max_frames and read >= max_frames * (1 + (now_ns() - begin) // TICK_NS):
                break
            if pump is None:  # across processes a read waits for the nodes: not the controller's work
                t0 = now_ns()
                remaining_ns = until_ns - t0
                msg = recv(timeout=max(0.0, remaining_ns / 1e9))
                self.idle_ns += now_ns() - t0
            else:  # in process a read never waits; running the nodes (the pump) is their work
                msg = recv(timeout=0.0)
                if msg is None:
                    t0 = now_ns()
                    pump()
                    self.idle_ns += now_ns() - t0
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
        self.counters.drained_max = max(self.counters.drained_max, read)
        if not expected <= got:
            self.counters.timeouts += 1

    def _read_queued(self, tick: int) -> None:
        """Before tick ``tick``'s SYNC, what came after the last tick's read: answers to earlier
        SYNCs, never this tick's (:meth:`CanSystem._age`). Across processes a tick's read ends
        once the frames it waits for are in, and a node's slower frames come after it. Read without
        waiting and at most ``_queued_max`` frames, so that a flood does not hold the SYNC back."""
        recv, receive, accept = self.bus.recv, self.rx.receive, self.accept
        for _ in range(self._queued_max):
            msg = recv(timeout=0.0)
            if msg is None:
                return
            accept(receive(msg), tick, queued=True)

    # -- write -----------------------------------------------------------------------------------

    def write(self, tick: int, commands: Commands) -> None:
        """Send the tick's frames (:meth:`CanSystem.frames`)."""
        for name, values in self.frames(tick, commands):
            self._send(name, values)

    def _send(self, name: str, values: tuple) -> None:
        """Send one frame; a failed send is retried once within the tick (a full transmit queue
        clears in microseconds), and a second failure counts for the bus supervision (docs/FAULTS.md F12, F13)."""
        msg = self.tx.message(name, values)
        for _ in range(2):
            try:
                self._bus_send(msg)
                self.counters.frames_sent += 1
                return
            except can.CanError:
                self.counters.send_failures += 1
        self.send_failed(self.tick)


class ReplayHardware(CanSystem):
    """A recorded trace's node frames as the hardware: :meth:`feed` gives the frames the next
    ``read`` reads (through the receiver), ``write`` keeps the frames the controller would have
    sent (:attr:`written`)."""

    def __init__(self, cfg: ControllerConfig, *, codec: Codec, max_delta_counter: int, clock: Clock | None = None) -> None:
        super().__init__(cfg, catalog=codec.catalog)
        self.rx = Receiver(codec, max_delta_counter=max_delta_counter)
        self.clock = clock or MonotonicClock()
        self.idle_ns = 0  # a replay never waits
        self.frames_fed = 0
        self.frames_rejected = 0
        self.written: list[tuple[str, tuple]] = []
        self._fed: tuple[Iterable[can.Message], Iterable[can.Message]] = ((), ())

    def feed(self, queued: Iterable[can.Message], frames: Iterable[can.Message]) -> None:
        """The next tick's frames: ``queued``, read before its SYNC (late answers), then ``frames``."""
        self._fed = (queued, frames)

    def read(self, tick: int, until_ns: int = 0, first_read_ns: int = 0) -> Snapshot:
        """The tick's snapshot from the fed frames (the deadlines are the recording's, already passed)."""
        for batch, late in zip(self._fed, (True, False)):
            for msg in batch:
                result = self.rx.receive(msg)
                self.frames_fed += 1
                self.frames_rejected += type(result) is not Decoded
                self.accept(result, tick, late)
        self._fed = ((), ())
        return self.snapshot(tick)

    def write(self, tick: int, commands: Commands) -> None:
        self.written = self.frames(tick, commands)
