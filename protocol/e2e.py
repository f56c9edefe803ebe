"""End-to-end protection on top of the codec: alive counters on send, counter checks on receive.

:class:`Transmitter` stamps each frame of a message with the next value of its 4-bit counter.
:class:`Receiver` is the one receive path of a process: it decodes a frame, checks its counter
against the last accepted frame of the same message (AUTOSAR E2E profile 1 semantics with a
configurable ``max_delta_counter``), and counts every rejection by reason. It never raises.

Counter rule for a frame whose CRC is good, with ``delta = (counter - last) mod 16``:

* first frame of a message (or after :meth:`Receiver.reset`, or after its sender restarted: a
  node's boot-up heartbeat or the controller's SYNC of tick 0, each with counter 0): accepted;
* ``delta == 0``: rejected, ``REPEATED`` (a duplicate or a frozen sender);
* ``1 <= delta <= max_delta_counter``: accepted; ``delta - 1`` frames were lost (counted);
* ``delta > max_delta_counter``: rejected, ``WRONG_SEQUENCE`` (too many lost, or reordered);
  the receiver re-synchronises on this counter, so the next frame in sequence is accepted.

A frame rejected for its CRC leaves the counter state untouched; a frame with a good CRC and
counter but an out-of-range value advances it (its data is lost, its sequence is not).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import can

from protocol.catalog import COUNTER_MODULO, MessageSpec
from protocol.codec import Codec, Decoded, RejectReason, Rejection, _new
from protocol.codec_kernel import BAD_CRC, WRONG_LENGTH
from protocol.codec_kernel import decode as decode_payload
from protocol.enums import NmtState


@dataclass
class RxStats:
    """Counts of a :class:`Receiver` (plain integers, cheap to update in the tick)."""

    accepted: int = 0
    lost: int = 0  # frames missing according to counter gaps within max_delta_counter

    def __post_init__(self) -> None:
        self.rejected: Counter[RejectReason] = Counter()
        self.rejected_by_id: Counter[int] = Counter()
        self.lost_by_id: Counter[int] = Counter()

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    def as_dict(self) -> dict[str, Any]:
        return {
            "accepted": self.accepted,
            "lost": self.lost,
            "rejected": self.rejected_total,
            "rejected_by_reason": {r.value: n for r, n in sorted(self.rejected.items(), key=lambda i: i[0].value)},
            "rejected_by_id": {f"{i:#05x}": n for i, n in sorted(self.rejected_by_id.items())},
        }


class Receiver:
    """Decode, check and count received frames. One per receiving process."""

    def __init__(self, codec: Codec, *, max_delta_counter: int = 2) -> None:
        if not 1 <= max_delta_counter < COUNTER_MODULO - 1:
            raise ValueError(f"max_delta_counter must be in 1..{COUNTER_MODULO - 2}, got {max_delta_counter}")
        self.codec = codec
        self.max_delta_counter = max_delta_counter
        self.stats = RxStats()
        self._last: dict[int, int] = {}

    def reset(self, frame_id: int | None = None) -> None:
        """Forget counter history (of one message, or all): the next frame is accepted as first."""
        if frame_id is None:
            self._last.clear()
        else:
            self._last.pop(frame_id, None)

    def _restart(self, sender: str) -> None:
        """``sender`` booted: every counter of its messages starts again, each next frame is first."""
        for spec in self.codec.catalog.sent_by(sender):
            self._last.pop(spec.frame_id, None)

    def _reject(self, rejection: Rejection) -> Rejection:
        self.stats.rejected[rejection.reason] += 1
        self.stats.rejected_by_id[rejection.frame_id] += 1
        return rejection

    def receive(self, msg: can.Message) -> Decoded | Rejection:
        """Process one python-can message."""
        frame_id = msg.arbitration_id
        if msg.is_error_frame:
            return self._reject(Rejection(RejectReason.ERROR_FRAME, frame_id, "error frame", timestamp=msg.timestamp))
        if msg.is_remote_frame:
            return self._reject(Rejection(RejectReason.REMOTE_FRAME, frame_id, "remote frame", timestamp=msg.timestamp))
        if msg.is_extended_id or msg.is_fd:
            kind = "CAN FD" if msg.is_fd else "29-bit ID"
            return self._reject(Rejection(RejectReason.NOT_CLASSIC, frame_id, f"{kind} frame", timestamp=msg.timestamp))
        return self.receive_data(frame_id, msg.data, msg.timestamp)

    def receive_data(self, frame_id: int, data: bytes | bytearray, timestamp: float | None = None) -> Decoded | Rejection:
        """Process one classic frame given by its 11-bit ID and payload."""
        try:
            compiled = self.codec.layout(frame_id)
            if compiled is None:
                return self._reject(self.codec.unknown(frame_id, timestamp))
            spec = compiled[0]
            result = decode_payload(compiled[1], data)
            if result == WRONG_LENGTH or result == BAD_CRC:
                return self._reject(self.codec.rejection(spec, result, data, timestamp))
            counter = data[1] & 0xF
            if counter == 0 and _sender_started(spec, result):
                self._restart(spec.sender)
            last = self._last.get(frame_id)
            if last is not None:
                delta = (counter - last) % COUNTER_MODULO
                if delta == 0 or delta > self.max_delta_counter:
                    if delta == 0:
                        reason, detail = RejectReason.REPEATED, f"{spec.name}: counter {counter} repeated"
                    else:
                        reason, detail = RejectReason.WRONG_SEQUENCE, f"{spec.name}: counter {last} -> {counter}"
                        self._last[frame_id] = counter
                    return self._reject(Rejection(reason, frame_id, detail, spec, timestamp))
                if delta > 1:
                    self.stats.lost += delta - 1
                    self.stats.lost_by_id[frame_id] += delta - 1
            self._last[frame_id] = counter
            if type(result) is int:
                return self._reject(self.codec.rejection(spec, result, data, timestamp))
            self.stats.accepted += 1
            return _new(Decoded, (spec, result, counter, timestamp))
        except Exception as exc:  # a receive path never raises; a fault here is counted and visible
            fid = frame_id if isinstance(frame_id, int) else -1
            return self._reject(Rejection(RejectReason.DECODER_FAULT, fid, repr(exc), timestamp=timestamp))


def _sender_started(spec: MessageSpec, values: Any) -> bool:
    """Whether a frame (with counter 0) is the first of a sender that (re)started, and every
    counter of its messages with it: a node's boot-up heartbeat (NMT state BOOT_UP, docs/FAULTS.md F23)
    or the controller's first SYNC (tick 0; a restarted controller's first NMT command, counter 0
    again, was otherwise rejected as a repeat of the last one's, F22). ``values`` is an int when a
    signal is out of range (rejected after the counter check): no start then."""
    if type(values) is int:
        return False
    if spec.family == "HEARTBEAT":
        return values.nmt_state == NmtState.BOOT_UP
    return spec.family == "SYNC" and values.tick == 0


class Transmitter:
    """Encode frames of one sender with consecutive alive counters, as python-can messages."""

    def __init__(self, codec: Codec) -> None:
        self.codec = codec
        self._counters: dict[int, int] = {}

    def reset(self) -> None:
        """Restart every counter at 0 (as after a reboot)."""
        self._counters.clear()

    def payload(self, message: str | int | MessageSpec, values: Any) -> bytes:
        """Encode ``values`` with the message's next counter; raises :class:`EncodeError` like
        :meth:`Codec.encode`, in which case the counter does not advance."""
        spec = message if isinstance(message, MessageSpec) else self.codec.spec(message)
        frame_id = spec.frame_id
        counter = self._counters.get(frame_id, 0)
        data = self.codec.encode(spec, values, counter)
        self._counters[frame_id] = (counter + 1) & 0xF
        return data

    def message(self, message: str | int | MessageSpec, values: Any) -> can.Message:
        spec = message if isinstance(message, MessageSpec) else self.codec.spec(message)
        return can.Message(arbitration_id=spec.frame_id, data=self.payload(spec, values), is_extended_id=False, check=False)
