"""Frame codec compiled from the catalogue.

For every message the DBC layout is read once, at start-up, into a :class:`protocol.codec_kernel.Layout`
(its signals' bits, ranges and scaling as numbers), which the kernel's compiled decode and encode
walk per frame. The DBC stays the only source.

Decoding is total: :meth:`Codec.decode` returns a :class:`Decoded` or a :class:`Rejection` for
any input and never raises. Encoding raises :class:`protocol.errors.EncodeError` for a value
that is not finite, outside its range, or not an enumerated value.
"""

from __future__ import annotations

import enum
from typing import Any, NamedTuple

from protocol.catalog import Catalog, MessageSpec, default_catalog
from protocol import codec_kernel as kernel
from protocol.errors import EncodeError, ProtocolError


class RejectReason(enum.Enum):
    """Why a received frame was not accepted."""

    UNKNOWN_ID = "unknown_id"
    WRONG_DLC = "wrong_dlc"
    BAD_CRC = "bad_crc"
    REPEATED = "repeated_counter"
    WRONG_SEQUENCE = "wrong_sequence"
    OUT_OF_RANGE = "out_of_range"
    ERROR_FRAME = "error_frame"
    REMOTE_FRAME = "remote_frame"
    NOT_CLASSIC = "not_classic_frame"
    DECODER_FAULT = "decoder_fault"


class Decoded(NamedTuple):
    """An accepted frame: its message, the payload record, and its alive counter."""

    message: MessageSpec
    values: Any  # the message's record (a namedtuple of physical values in signal order)
    counter: int
    timestamp: float | None = None

    @property
    def name(self) -> str:
        return self.message.name


_new = tuple.__new__  # builds a NamedTuple without its Python-level __new__ (hot paths)


class Rejection(NamedTuple):
    """A frame that was not accepted, and why."""

    reason: RejectReason
    frame_id: int
    detail: str = ""
    message: MessageSpec | None = None
    timestamp: float | None = None


class _Compiled(NamedTuple):
    spec: MessageSpec
    layout: kernel.Layout


def _bad_value(spec: MessageSpec, index: int, value: Any) -> EncodeError:
    sig = spec.signals[index]
    if sig.choices is not None:
        allowed = ", ".join(f"{k} ({v})" for k, v in sig.choices.items())
        return EncodeError(f"{spec.name}.{sig.name}: {value!r} is not one of {allowed}")
    return EncodeError(f"{spec.name}.{sig.name}: {value!r} is outside [{sig.minimum:g}, {sig.maximum:g}] {sig.unit}".rstrip())


class Codec:
    """Encode and decode every message of a catalogue (stateless; counters live in :mod:`protocol.e2e`)."""

    def __init__(self, catalog: Catalog | None = None) -> None:
        self.catalog = catalog if catalog is not None else default_catalog()
        self._compiled: dict[int, _Compiled] = {spec.frame_id: _Compiled(spec, kernel.layout_of(spec)) for spec in self.catalog.messages}

    # -- introspection -------------------------------------------------------------------------

    def spec(self, name_or_id: str | int) -> MessageSpec:
        if isinstance(name_or_id, int):
            compiled = self._compiled.get(name_or_id)
            if compiled is None:
                raise ProtocolError(f"unknown frame ID {name_or_id:#x}")
            return compiled.spec
        return self.catalog.by_name(name_or_id)

    # -- encoding ------------------------------------------------------------------------------

    def encode(self, message: str | int | MessageSpec, values: Any, counter: int) -> bytes:
        """Frame payload of ``message`` for ``values`` (record, tuple in signal order, or mapping).

        Raises :class:`EncodeError` for a missing, non-finite, out-of-range or non-enumerated value.
        """
        spec = message if isinstance(message, MessageSpec) else self.spec(message)
        if isinstance(values, dict):
            values = self.record_from_mapping(spec, values)
        elif len(values) != len(spec.signals):
            raise EncodeError(f"{spec.name}: expected {len(spec.signals)} values, got {len(values)}")
        try:
            data = kernel.encode(self._compiled[spec.frame_id].layout, values, counter)
        except (TypeError, ValueError, OverflowError) as exc:
            raise EncodeError(f"{spec.name}: cannot encode {values!r}: {exc}") from None
        if type(data) is int:
            raise _bad_value(spec, data, values[data])
        return data

    @staticmethod
    def record_from_mapping(spec: MessageSpec, values: dict[str, Any]) -> Any:
        names = [s.name for s in spec.signals]
        missing = [n for n in names if n not in values]
        extra = sorted(set(values) - set(names))
        if missing or extra:
            raise EncodeError(f"{spec.name}: missing signals {missing}, unknown signals {extra}")
        return spec.record(**values)

    # -- decoding ------------------------------------------------------------------------------

    def decode(self, frame_id: int, data: bytes | bytearray, timestamp: float | None = None) -> Decoded | Rejection:
        """Stateless decode: ID, length, CRC and ranges (alive counters are checked by :mod:`protocol.e2e`).

        Total: returns a :class:`Decoded` or a :class:`Rejection` for any input, never raises.
        """
        try:
            compiled = self._compiled.get(frame_id)
            if compiled is None:
                return self.unknown(frame_id, timestamp)
            result = kernel.decode(compiled.layout, data)
            if type(result) is int:
                return self.rejection(compiled.spec, result, data, timestamp)
            return _new(Decoded, (compiled.spec, result, data[1] & 0xF, timestamp))
        except Exception as exc:  # never let a receive path raise; counted as a decoder fault
            return Rejection(RejectReason.DECODER_FAULT, frame_id if isinstance(frame_id, int) else -1, repr(exc))

    def layout(self, frame_id: int) -> _Compiled | None:
        """A known frame ID's message and its layout for :func:`protocol.codec_kernel.decode` (hot paths)."""
        return self._compiled.get(frame_id)

    @staticmethod
    def unknown(frame_id: int, timestamp: float | None = None) -> Rejection:
        return Rejection(RejectReason.UNKNOWN_ID, frame_id, f"unknown frame ID {frame_id:#x}", timestamp=timestamp)

    @staticmethod
    def rejection(spec: MessageSpec, code: int, data: bytes | bytearray, timestamp: float | None = None) -> Rejection:
        """The rejection for an integer answer of :func:`protocol.codec_kernel.decode`."""
        if code == kernel.WRONG_LENGTH:
            return Rejection(RejectReason.WRONG_DLC, spec.frame_id, f"{spec.name}: DLC {len(data)}, expected {spec.dlc}", spec, timestamp)
        if code == kernel.BAD_CRC:
            return Rejection(RejectReason.BAD_CRC, spec.frame_id, f"{spec.name}: CRC mismatch", spec, timestamp)
        return Rejection(RejectReason.OUT_OF_RANGE, spec.frame_id, f"{spec.name}.{spec.signals[code].name} out of range", spec, timestamp)

    @staticmethod
    def as_dict(decoded: Decoded, *, choices: bool = False) -> dict[str, Any]:
        """Signal name -> value (enumerations as their names when ``choices``)."""
        out = decoded.values._asdict()
        if choices:
            for sig in decoded.message.signals:
                if sig.choices is not None:
                    out[sig.name] = sig.choices[out[sig.name]]
        return out


def with_raw_value(spec: MessageSpec, payload: bytes, signal: str, raw: int) -> bytes:
    """``payload`` of ``spec`` with ``signal`` set to the raw integer ``raw`` and the CRC made good
    again: what a sensor that has gone out of range sends (``raw`` may lie outside the DBC range
    but must fit the signal's bits). For fault injection and tests; never used to send data."""
    from protocol.crc import crc8

    sig = spec.signal(signal)
    if not sig.raw_min_representable <= raw <= sig.raw_max_representable:
        raise EncodeError(f"{spec.name}.{signal}: raw {raw} does not fit in {sig.length} bits")
    mask = (1 << sig.length) - 1
    word = int.from_bytes(payload, "little")
    word = (word & ~(mask << sig.start)) | ((raw & mask) << sig.start)
    data = word.to_bytes(len(payload), "little")
    return bytes((crc8(spec.crc_seed, data[1:]),)) + data[1:]
