"""Frame codec compiled from the catalogue.

For every message the DBC layout is compiled once, at start-up, into two straight-line Python
functions (payload -> record and record -> payload) over one integer, which is several times
faster than a generic bit-walking codec. The DBC stays the only source: the generated code is
derived from :class:`protocol.catalog.MessageSpec` and can be read with :meth:`Codec.source`.

Decoding is total: :meth:`Codec.decode` returns a :class:`Decoded` or a :class:`Rejection` for
any input and never raises. Encoding raises :class:`protocol.errors.EncodeError` for a value
that is not finite, outside its range, or not an enumerated value.
"""

from __future__ import annotations

import enum
from typing import Any, Callable, NamedTuple

from protocol.catalog import Catalog, MessageSpec, SignalSpec, default_catalog
from protocol.crc import TABLE, XOR_OUT
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


def _physical_expr(var: str, sig: SignalSpec) -> str:
    if sig.is_integer:
        return var
    expr = f"{var} * {sig.scale!r}"
    return f"({expr} + {sig.offset!r})" if sig.offset else expr


def _crc_lines(var: str, first: int, last: int) -> list[str]:
    """Unrolled CRC over ``var[first..last]`` starting from the message's seed (no Python loop)."""
    lines = [f"    c = TABLE[SEED ^ {var}[{first}]]"]
    lines += [f"    c = TABLE[c ^ {var}[{i}]]" for i in range(first + 1, last + 1)]
    return lines


def _decoder_source(spec: MessageSpec) -> str:
    """Source of ``decode(data)``: the record, -1 for a bad CRC, or the index of the first
    out-of-range signal. ``data`` must have the message's DLC (checked by the caller)."""
    lines = ["def decode(d):"]
    lines += _crc_lines("d", 1, spec.dlc - 1)
    lines.append(f"    if c ^ {XOR_OUT:#x} != d[0]:")
    lines.append("        return -1")
    lines.append("    raw = FROM_BYTES(d, 'little')")
    for k, sig in enumerate(spec.signals):
        mask = (1 << sig.length) - 1
        lines.append(f"    r{k} = (raw >> {sig.start}) & {mask:#x}")
        if sig.signed:
            lines.append(f"    if r{k} & {1 << (sig.length - 1):#x}:")
            lines.append(f"        r{k} -= {1 << sig.length:#x}")
        if sig.choices is not None:
            lines.append(f"    if r{k} not in CHOICES_{k}:")
            lines.append(f"        return {k}")
        else:
            if (sig.raw_min, sig.raw_max) != (sig.raw_min_representable, sig.raw_max_representable):
                lines.append(f"    if not {sig.raw_min} <= r{k} <= {sig.raw_max}:")
                lines.append(f"        return {k}")
    fields = "".join(f"{_physical_expr(f'r{k}', sig)}, " for k, sig in enumerate(spec.signals))
    lines.append(f"    return TUPLE_NEW(RECORD, ({fields}))")
    return "\n".join(lines) + "\n"


def _encoder_source(spec: MessageSpec) -> str:
    """Source of ``encode(values, counter) -> bytes`` (CRC in byte 0, counter in bits 8..11).

    Every value is range-checked before conversion; the chained comparison is also False for NaN.
    """
    names = [f"v{k}" for k in range(len(spec.signals))]
    lines = ["def encode(values, counter):"]
    if names:
        lines.append(f"    {', '.join(names)}{',' if len(names) == 1 else ''} = values")
    parts = ["(counter & 0xF)"]
    for k, sig in enumerate(spec.signals):
        v = f"v{k}"
        if sig.choices is not None:
            lines.append(f"    if {v} not in CHOICES_{k}:")
            lines.append(f"        bad({k}, {v})")
            raw = f"int({v})"
        else:
            lines.append(f"    if not {sig.minimum!r} <= {v} <= {sig.maximum!r}:")
            lines.append(f"        bad({k}, {v})")
            if sig.is_integer:
                raw = f"int({v})"
            else:
                shifted = f"({v} - {sig.offset!r})" if sig.offset else v
                raw = f"round({shifted} / {sig.scale!r})"
        if sig.signed:
            raw = f"({raw} & {(1 << sig.length) - 1:#x})"
        parts.append(f"({raw} << {sig.start - 8})")
    lines.append(f"    b = ({' | '.join(parts)}).to_bytes({spec.dlc - 1}, 'little')")
    lines += _crc_lines("b", 0, spec.dlc - 2)
    lines.append(f"    return bytes((c ^ {XOR_OUT:#x},)) + b")
    return "\n".join(lines) + "\n"


def _compile(source: str, name: str, namespace: dict[str, Any]) -> Callable[..., Any]:
    code = compile(source, f"<codec {name}>", "exec")
    exec(code, namespace)  # noqa: S102 - source generated from the validated catalogue only
    return namespace[source.split("(", 1)[0].removeprefix("def ")]


class _Compiled(NamedTuple):
    spec: MessageSpec
    decode: Callable[[bytes | bytearray], Any]
    encode: Callable[[Any, int], bytes]


class Codec:
    """Encode and decode every message of a catalogue (stateless; counters live in :mod:`protocol.e2e`)."""

    def __init__(self, catalog: Catalog | None = None) -> None:
        self.catalog = catalog if catalog is not None else default_catalog()
        self._sources: dict[str, str] = {}
        self._compiled: dict[int, _Compiled] = {
            spec.frame_id: self._compile_message(spec) for spec in self.catalog.messages
        }

    def _compile_message(self, spec: MessageSpec) -> _Compiled:
        def bad(index: int, value: Any) -> None:
            sig = spec.signals[index]
            if sig.choices is not None:
                allowed = ", ".join(f"{k} ({v})" for k, v in sig.choices.items())
                raise EncodeError(f"{spec.name}.{sig.name}: {value!r} is not one of {allowed}")
            raise EncodeError(
                f"{spec.name}.{sig.name}: {value!r} is outside [{sig.minimum:g}, {sig.maximum:g}] {sig.unit}".rstrip()
            )

        namespace: dict[str, Any] = {
            "RECORD": spec.record,
            "TABLE": TABLE,
            "SEED": spec.crc_seed,
            "FROM_BYTES": int.from_bytes,
            "TUPLE_NEW": tuple.__new__,
            "bad": bad,
        }
        for k, sig in enumerate(spec.signals):
            if sig.choices is not None:
                namespace[f"CHOICES_{k}"] = frozenset(sig.choices)
        dec_src, enc_src = _decoder_source(spec), _encoder_source(spec)
        self._sources[spec.name] = dec_src + "\n" + enc_src
        return _Compiled(spec, _compile(dec_src, spec.name, dict(namespace)), _compile(enc_src, spec.name, dict(namespace)))

    # -- introspection -------------------------------------------------------------------------

    def source(self, name: str) -> str:
        """The generated decoder and encoder of message ``name`` (for debugging)."""
        return self._sources[self.catalog.by_name(name).name]

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
            return self._compiled[spec.frame_id].encode(values, counter)
        except EncodeError:
            raise
        except (TypeError, ValueError, OverflowError) as exc:
            raise EncodeError(f"{spec.name}: cannot encode {values!r}: {exc}") from None

    def encoder(self, message: str | int | MessageSpec) -> Callable[[Any, int], bytes]:
        """The compiled ``encode(values, counter)`` of one message, for hot paths that send it every tick.

        ``values`` must be a sequence in signal order; raises :class:`EncodeError` like :meth:`encode`.
        """
        spec = message if isinstance(message, MessageSpec) else self.spec(message)
        return self._compiled[spec.frame_id].encode

    @staticmethod
    def record_from_mapping(spec: MessageSpec, values: dict[str, Any]) -> Any:
        names = [s.name for s in spec.signals]
        missing = [n for n in names if n not in values]
        extra = sorted(set(values) - set(names))
        if missing or extra:
            raise EncodeError(f"{spec.name}: missing signals {missing}, unknown signals {extra}")
        return spec.record(**values)

    # -- decoding ------------------------------------------------------------------------------

    def lookup(self, frame_id: int, data: bytes | bytearray) -> _Compiled | Rejection:
        """The compiled message for a frame, or a rejection for an unknown ID or a wrong length."""
        compiled = self._compiled.get(frame_id)
        if compiled is None:
            return Rejection(RejectReason.UNKNOWN_ID, frame_id, f"unknown frame ID {frame_id:#x}")
        if len(data) != compiled.spec.dlc:
            spec = compiled.spec
            return Rejection(RejectReason.WRONG_DLC, frame_id, f"{spec.name}: DLC {len(data)}, expected {spec.dlc}", spec)
        return compiled

    @staticmethod
    def rejection(compiled: _Compiled, code: int, frame_id: int) -> Rejection:
        """The rejection for an integer result of a compiled decoder (-1: CRC, k: signal k)."""
        spec = compiled.spec
        if code < 0:
            return Rejection(RejectReason.BAD_CRC, frame_id, f"{spec.name}: CRC mismatch", spec)
        return Rejection(RejectReason.OUT_OF_RANGE, frame_id, f"{spec.name}.{spec.signals[code].name} out of range", spec)

    def decode(self, frame_id: int, data: bytes | bytearray, timestamp: float | None = None) -> Decoded | Rejection:
        """Stateless decode: ID, length, CRC and ranges (alive counters are checked by :mod:`protocol.e2e`).

        Total: returns a :class:`Decoded` or a :class:`Rejection` for any input, never raises.
        """
        try:
            compiled = self.lookup(frame_id, data)
            if type(compiled) is Rejection:
                return compiled
            result = compiled.decode(data)
            if type(result) is int:
                return self.rejection(compiled, result, frame_id)._replace(timestamp=timestamp)
            return _new(Decoded, (compiled.spec, result, data[1] & 0xF, timestamp))
        except Exception as exc:  # never let a receive path raise; counted as a decoder fault
            return Rejection(RejectReason.DECODER_FAULT, frame_id if isinstance(frame_id, int) else -1, repr(exc))

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
