"""A fault-injecting wrapper around a python-can bus (docs/FAULTS.md injection layer BW), seeded.

:class:`FaultBus` wraps the bus of one process (in the safety tests and the soak, the
controller's end of the in-process virtual bus) and applies :class:`BusFault` rules to the frames
it receives (``rx``) and sends (``tx``):

* ``drop``: the frame is lost (``burst`` frames in a row once a rule fires);
* ``delay``: the frame comes ``delay_ticks`` ticks late;
* ``duplicate``: the frame comes twice;
* ``reorder``: the frame swaps places with the next frame of the same ID;
* ``corrupt``: ``bits`` random bits of the payload flip (the CRC byte included);
* ``truncate``: the frame loses its last byte (a wrong length);
* ``masquerade``: the frame comes with the ID ``to_id`` (another node's data on its ID);
* ``error_frame``: ``burst`` error frames come before the frame;
* ``send_failure`` (``tx`` only): ``send`` raises :class:`can.CanOperationError`, as a full
  transmit queue (ENOBUFS) or bus-off does, and the frame is not sent.

A rule applies to the frames of ``frame_ids`` (every frame when empty) from ``start_tick`` until
``end_tick`` (exclusive, open when None), each matching frame with ``probability``, and fires at
most ``times`` times (None: no limit); a drop burst once begun runs to its end. Ticks are
counted by the SYNC frames the wrapped side sends (``tick_frame_id``; a resend of the same bytes
is the same tick): the first SYNC starts tick 0 (before it, the tick is -1); a delayed frame is released when its tick begins. Every injection is counted by rule and
kind (:attr:`FaultBus.counts`), the newest ones with their tick and frame ID (:attr:`FaultBus.log`),
so a test or the soak can say what it did. One generator
(:class:`numpy.random.Generator`, injected) makes a run repeatable.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import can
import numpy as np

KINDS = ("drop", "delay", "duplicate", "reorder", "corrupt", "truncate", "masquerade", "error_frame", "send_failure")
DIRECTIONS = ("rx", "tx")


@dataclass(frozen=True)
class BusFault:
    """One injection rule (see the module doc)."""

    kind: str
    direction: str = "rx"
    frame_ids: frozenset[int] = frozenset()  # empty: every frame
    start_tick: int = -1  # -1: from the start, before the first SYNC
    end_tick: int | None = None
    probability: float = 1.0
    burst: int = 1  # drop: frames lost in a row once the rule fires; error_frame: error frames injected
    delay_ticks: int = 1
    bits: int = 1
    times: int | None = None  # the most firings (None: no limit)
    to_id: int | None = None  # masquerade: the ID the frame comes with
    name: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"bus fault {self.name or self.kind!r}: kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.direction not in DIRECTIONS:
            raise ValueError(f"bus fault {self.label}: direction must be rx or tx, got {self.direction!r}")
        if self.kind == "send_failure" and self.direction != "tx":
            raise ValueError(f"bus fault {self.label}: send_failure applies to sent frames (direction tx)")
        if not 0.0 < self.probability <= 1.0:
            raise ValueError(f"bus fault {self.label}: probability must be in (0, 1], got {self.probability}")
        if self.burst < 1 or self.delay_ticks < 1 or self.bits < 1 or (self.times is not None and self.times < 1):
            raise ValueError(f"bus fault {self.label}: burst, delay_ticks, bits and times must be at least 1")
        if (self.kind == "masquerade") != (self.to_id is not None):
            raise ValueError(f"bus fault {self.label}: to_id is needed by a masquerade and only by it")
        if self.start_tick < -1:
            raise ValueError(f"bus fault {self.label}: start_tick must be -1 (from the start) or a tick, got {self.start_tick}")
        if self.end_tick is not None and self.end_tick <= self.start_tick:
            raise ValueError(f"bus fault {self.label}: end_tick {self.end_tick} must be after start_tick {self.start_tick}")
        object.__setattr__(self, "frame_ids", frozenset(self.frame_ids))

    @property
    def label(self) -> str:
        return self.name or f"{self.direction}:{self.kind}"

    def active(self, tick: int) -> bool:
        return tick >= self.start_tick and (self.end_tick is None or tick < self.end_tick)


def _copy(msg: can.Message, data: bytes | bytearray | None = None, arbitration_id: int | None = None) -> can.Message:
    return can.Message(
        timestamp=msg.timestamp, arbitration_id=msg.arbitration_id if arbitration_id is None else arbitration_id,
        is_extended_id=msg.is_extended_id,
        is_remote_frame=msg.is_remote_frame, is_error_frame=msg.is_error_frame, channel=msg.channel,
        dlc=msg.dlc if data is None else len(data), data=bytearray(msg.data if data is None else data),
        is_fd=msg.is_fd, is_rx=msg.is_rx, check=False,
    )


class FaultBus(can.BusABC):
    """``inner`` with the :class:`BusFault` rules applied (see the module doc)."""

    def __init__(
        self, inner: can.BusABC, faults: Iterable[BusFault] = (), *, rng: np.random.Generator,
        tick_frame_id: int = 0x080, log_size: int = 10_000, **kwargs: Any,
    ) -> None:
        self.inner = inner
        self.faults: list[BusFault] = list(faults)
        self.rng = rng
        self.tick_frame_id = tick_frame_id
        self.tick = -1  # before the first SYNC
        self.counts: Counter[tuple[str, str]] = Counter()  # (rule label, kind) -> injections
        self._pending: deque[can.Message] = deque()  # received frames ready to hand out
        self._delayed: dict[str, list[tuple[int, can.Message]]] = {"rx": [], "tx": []}
        self._held: dict[int, can.Message] = {}  # reorder: a frame waiting for the next of its ID
        self._bursts: dict[int, int] = {}  # rule index -> frames still to drop
        self._fired: Counter[int] = Counter()  # rule index -> times fired
        self._last_sync: bytes | None = None
        self.log: deque[tuple[int, str, int]] = deque(maxlen=log_size)  # (tick, kind, frame ID), the newest injections
        self.channel_info = f"faults on {getattr(inner, 'channel_info', inner)}"
        super().__init__(channel=getattr(inner, "channel", None), **kwargs)

    # -- rules -------------------------------------------------------------------------------------

    def add(self, fault: BusFault) -> None:
        self.faults.append(fault)

    def clear(self) -> None:
        """Remove every rule (frames already delayed or held still come)."""
        self.faults.clear()
        self._bursts.clear()
        self._fired.clear()

    def _apply(self, msg: can.Message, direction: str) -> list[can.Message]:
        """What becomes of one frame: the frames to pass on now (none when dropped, delayed or held)."""
        out = [msg]
        tick, held_now = self.tick, False
        for index, f in enumerate(self.faults):
            if f.direction != direction or not out or (f.frame_ids and msg.arbitration_id not in f.frame_ids):
                continue
            if self._bursts.get(index, 0) > 0:  # the rest of a drop burst, whatever the window
                self._bursts[index] -= 1
                self.counts[(f.label, f.kind)] += 1
                self.log.append((tick, f.kind, msg.arbitration_id))
                return []
            if not f.active(tick) or (f.times is not None and self._fired[index] >= f.times):
                continue
            if f.probability < 1.0 and self.rng.random() >= f.probability:
                continue
            self._fired[index] += 1
            self.counts[(f.label, f.kind)] += 1
            self.log.append((tick, f.kind, msg.arbitration_id))
            if f.kind == "drop":
                self._bursts[index] = f.burst - 1
                return []
            if f.kind == "delay":
                self._delayed[direction] += [(tick + f.delay_ticks, m) for m in out]
                return []
            if f.kind == "duplicate":
                out = [m for m in out for m in (m, _copy(m))]
            elif f.kind == "reorder" and msg.arbitration_id not in self._held:
                self._held[msg.arbitration_id] = out.pop()
                held_now = True
            elif f.kind == "corrupt":
                out = [self._corrupt(m, f.bits) for m in out]
            elif f.kind == "truncate":
                out = [_copy(m, m.data[:-1]) for m in out]
            elif f.kind == "masquerade":
                out = [_copy(m, arbitration_id=f.to_id) for m in out]
            elif f.kind == "error_frame":
                errors = [can.Message(timestamp=msg.timestamp, is_error_frame=True, arbitration_id=0x20000004,
                                      is_extended_id=True, dlc=8, data=bytes(8), check=False) for _ in range(f.burst)]
                out = [*errors, *out]
            elif f.kind == "send_failure":
                raise can.CanOperationError(f"injected send failure ({f.label}, tick {tick})")
        if not held_now and msg.arbitration_id in self._held:
            out.append(self._held.pop(msg.arbitration_id))  # a held frame comes after the next of its ID
        return out

    def _corrupt(self, msg: can.Message, bits: int) -> can.Message:
        data = bytearray(msg.data)
        if not data:
            return msg
        for bit in self.rng.choice(8 * len(data), size=min(bits, 8 * len(data)), replace=False).tolist():
            data[bit // 8] ^= 1 << (bit % 8)
        return _copy(msg, data)

    def _release(self, direction: str) -> list[can.Message]:
        """Delayed frames whose tick has come, in the order they were delayed."""
        waiting = self._delayed[direction]
        if not waiting:
            return []
        due = [m for t, m in waiting if t <= self.tick]
        self._delayed[direction] = [(t, m) for t, m in waiting if t > self.tick]
        return due

    # -- can.BusABC --------------------------------------------------------------------------------

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == self.tick_frame_id and not msg.is_error_frame and bytes(msg.data) != self._last_sync:
            self._last_sync = bytes(msg.data)  # the same bytes again are a resend of this tick's SYNC
            self.tick += 1
            self._pending.extend(self._release("rx"))
            for late in self._release("tx"):
                self.inner.send(late, timeout)
        for m in self._apply(msg, "tx"):
            self.inner.send(m, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._pending:
            return self._pending.popleft(), False
        msg = self.inner.recv(timeout)
        while msg is not None:
            self._pending.extend(self._apply(msg, "rx"))
            if self._pending:
                return self._pending.popleft(), False
            msg = self.inner.recv(0.0)  # that one was dropped, delayed or held: the next, if any
        return None, False

    def shutdown(self) -> None:
        super().shutdown()
        self.inner.shutdown()

    @property
    def injected(self) -> dict[str, int]:
        """Injections per rule label and kind, for reports (``label:kind`` -> count)."""
        return {f"{label}:{kind}": n for (label, kind), n in sorted(self.counts.items())}


def ids_of(catalog: Any, names: Sequence[str]) -> frozenset[int]:
    """The frame IDs of messages named in ``names`` (by the DBC through ``catalog``)."""
    return frozenset(catalog.by_name(n).frame_id for n in names)
