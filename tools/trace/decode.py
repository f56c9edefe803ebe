"""Decoding a trace with the DBC: every frame checked (CRC, alive counter, length, ranges) by the
project's own receiver, selected by node, message, signal and time, and written as an aligned
table, CSV (one row per signal) or JSON lines (one object per frame after a schema line).

A frame that fails a check is kept and marked with the receiver's reason (``bad_crc``,
``repeated_counter``, ``wrong_sequence``, ``wrong_dlc``, ``out_of_range``, ...); a frame whose
counter jumped within the allowed delta is ``ok`` with the frames lost before it counted; a
frame of an ID the DBC does not know is shown raw (``unknown_id``). Every frame, shown or not,
goes through the one receiver, so a filter never changes the counter checks.
"""

from __future__ import annotations

import csv
import fnmatch
import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any, NamedTuple, TextIO

from protocol.catalog import Catalog, MessageSpec, SignalSpec
from protocol.codec import Codec, Decoded, RejectReason
from protocol.e2e import Receiver
from tools.trace import TraceError
from tools.trace.reader import Frame

OK = "ok"
UNKNOWN = RejectReason.UNKNOWN_ID.value
#: reasons whose frame has a good CRC, so its values are shown beside the mark
_COUNTER_REASONS = (RejectReason.REPEATED, RejectReason.WRONG_SEQUENCE)


class Row(NamedTuple):
    """One frame of a trace after the checks."""

    frame: Frame
    time_s: float  # since the first frame of the trace
    spec: MessageSpec | None
    values: Any  # the message's record of physical values, or None
    counter: int | None
    status: str  # "ok" or a RejectReason value
    detail: str
    lost_before: int  # frames of this message missing before this one (alive-counter gap)


@dataclass(frozen=True)
class Selection:
    """What to show: nodes (a node's frames: those it sends and those addressed to it alone),
    messages (names or IDs, shell patterns, any case), signals (``name`` or ``MESSAGE.name``
    patterns) and a time range in seconds from the first frame of the trace."""

    nodes: tuple[str, ...] = ()
    messages: tuple[str, ...] = ()
    signals: tuple[str, ...] = ()
    start_s: float | None = None
    end_s: float | None = None
    senders: tuple[str, ...] = ()  # strictly the sender (replay roles)

    @property
    def filters_ids(self) -> bool:
        return bool(self.nodes or self.messages or self.signals or self.senders)

    def compile(self, catalog: Catalog) -> CompiledSelection:
        """Check every name against the DBC (one clear error for a name it lacks) and resolve."""
        if self.start_s is not None and self.end_s is not None and self.end_s < self.start_s:
            raise TraceError(f"the time range ends ({self.end_s} s) before it starts ({self.start_s} s)")
        specs = list(catalog.messages)
        extra_ids: set[int] = set()
        for name in self.nodes + self.senders:
            if name.upper() not in catalog.node_ids:
                raise TraceError(f"no node {name!r} in the DBC; nodes: {', '.join(catalog.nodes)}")
        if self.nodes:
            wanted = {n.upper() for n in self.nodes}
            specs = [m for m in specs if m.sender in wanted or (len(m.receivers) == 1 and m.receivers[0] in wanted)]
        if self.senders:
            wanted = {n.upper() for n in self.senders}
            specs = [m for m in specs if m.sender in wanted]
        if self.messages:
            chosen = []
            for pattern in self.messages:
                ident = _as_id(pattern)
                hits = [m for m in catalog.messages if (m.frame_id == ident if ident is not None
                                                        else fnmatch.fnmatchcase(m.name, pattern.upper()))]
                if ident is not None and not hits:
                    extra_ids.add(ident)  # an ID the DBC does not know: shown raw
                elif not hits:
                    raise TraceError(f"no message matches {pattern!r} in the DBC; e.g. {', '.join(m.name for m in catalog.messages[:4])}, ...")
                chosen += hits
            specs = [m for m in specs if m in chosen]
        signals: dict[int, tuple[int, ...]] = {}
        if self.signals:
            for pattern in self.signals:
                if not any(_signal_indices(m, (pattern,)) for m in catalog.messages):
                    raise TraceError(f"no signal matches {pattern!r} in the DBC (use NAME or MESSAGE.NAME, shell patterns)")
            specs = [m for m in specs if _signal_indices(m, self.signals)]
            signals = {m.frame_id: _signal_indices(m, self.signals) for m in specs}
        ids = {m.frame_id for m in specs} | extra_ids if self.filters_ids else None
        return CompiledSelection(ids, signals, self.start_s, self.end_s)


def _as_id(text: str) -> int | None:
    try:
        return int(text, 16) if text.lower().startswith("0x") else None
    except ValueError:
        return None


def _signal_indices(spec: MessageSpec, patterns: Iterable[str]) -> tuple[int, ...]:
    out = []
    for k, sig in enumerate(spec.signals):
        for pattern in patterns:
            msg_part, dot, sig_part = pattern.rpartition(".")
            if dot and not fnmatch.fnmatchcase(spec.name, msg_part.upper()):
                continue
            if fnmatch.fnmatchcase(sig.name.lower(), sig_part.lower()):
                out.append(k)
                break
    return tuple(out)


class CompiledSelection(NamedTuple):
    ids: set[int] | None  # None: every frame, unknown IDs included
    signals: dict[int, tuple[int, ...]]  # frame ID -> shown signal indices (absent: all)
    start_s: float | None
    end_s: float | None

    def signal_indices(self, spec: MessageSpec) -> tuple[int, ...] | range:
        return self.signals.get(spec.frame_id, range(len(spec.signals)))


class TraceDecoder:
    """Frames in, :class:`Row` out, through one :class:`protocol.e2e.Receiver`."""

    def __init__(self, codec: Codec, *, max_delta_counter: int = 2) -> None:
        self.codec = codec
        self.receiver = Receiver(codec, max_delta_counter=max_delta_counter)
        self.origin: float | None = None  # timestamp of the first frame

    def rows(self, frames: Iterable[Frame], selection: CompiledSelection | None = None) -> Iterator[Row]:
        ids = selection.ids if selection is not None else None
        start = selection.start_s if selection is not None else None
        end = selection.end_s if selection is not None else None
        receive = self.receiver.receive
        stats = self.receiver.stats
        decode = self.codec.decode
        new = tuple.__new__  # a Row without its Python-level __new__ (the hot path)
        for frame in frames:
            if self.origin is None:
                self.origin = frame.timestamp
            lost = stats.lost
            result = receive(frame)
            t = frame.timestamp - self.origin
            if (ids is not None and frame.arbitration_id not in ids) or (start is not None and t < start):
                continue
            if end is not None and t > end:
                continue
            if type(result) is Decoded:
                yield new(Row, (frame, t, result.message, result.values, result.counter, OK, "", stats.lost - lost))
                continue
            values = counter = None
            if result.reason in _COUNTER_REASONS:  # good CRC: the values are still worth showing
                again = decode(frame.arbitration_id, frame.data)
                if type(again) is Decoded:
                    values, counter = again.values, again.counter
            yield Row(frame, t, result.message, values, counter, result.reason.value, result.detail, 0)


# -- output --------------------------------------------------------------------------------------


def _digits(x: float) -> int:
    """Digits after the point that ``x`` needs (at most 9)."""
    return next((d for d in range(10) if math.isclose(x * 10**d, round(x * 10**d), abs_tol=1e-9)), 9)


def decimals(sig: SignalSpec) -> int:
    """Digits after the point that show every value on the signal's grid exactly."""
    return 0 if sig.is_integer else max(_digits(sig.scale), _digits(sig.offset))


def _csv_cell(text: str) -> str:
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\n\r') else text


def _braces(text: str) -> str:
    return text.replace("{", "{{").replace("}", "}}")


# Arguments of every compiled line: 0 time since the first frame, 1 timestamp, 2 counter, 3 frames
# lost before, 4 payload in hex, then the shown signals' values from 5 on.
_FIRST_VALUE = 5


class Formatter:
    """Presentation compiled once per message from the DBC: which signals, their decimals, units
    and enumeration labels, and for each output format a line template of a frame that passed
    every check (the hot path; other frames take the general path of each writer)."""

    KINDS = ("table", "csv", "jsonl")

    def __init__(self, catalog: Catalog, selection: CompiledSelection | None, *, labels: bool = True) -> None:
        self.labels = labels
        self._signals: dict[int, list[tuple[int, SignalSpec, int]]] = {}
        self._lines: dict[str, dict[int, tuple[str, tuple[int, ...] | None, list[tuple[int, dict[int, str]]]]]] = {
            kind: {} for kind in self.KINDS}
        for spec in catalog.messages:
            indices = selection.signal_indices(spec) if selection is not None else range(len(spec.signals))
            shown = [(k, spec.signals[k], decimals(spec.signals[k])) for k in indices]
            self._signals[spec.frame_id] = shown
            picks = None if len(shown) == len(spec.signals) else tuple(k for k, _, _ in shown)
            for kind in self.KINDS:
                template, names = self._template(kind, spec, shown)
                self._lines[kind][spec.frame_id] = (template, picks, names)

    def _template(self, kind: str, spec: MessageSpec, shown: list[tuple[int, SignalSpec, int]]) -> tuple[str, list]:
        fields, names = [], []
        for i, (_, sig, digits) in enumerate(shown):
            arg = _FIRST_VALUE + i
            if self.labels and sig.choices is not None:
                quote = json.dumps if kind == "jsonl" else (_csv_cell if kind == "csv" else str)
                names.append((i, {raw: _braces(quote(label)) for raw, label in sig.choices.items()}))
                fields.append((sig, f"{{{arg}}}"))
            else:
                fields.append((sig, f"{{{arg}:.{digits}f}}" if digits else f"{{{arg}:d}}"))
        ident = f"{spec.frame_id:03X}"
        if kind == "table":
            body = "  ".join(f"{_braces(sig.name)}={value}{_braces(' ' + sig.unit) if sig.unit else ''}" for sig, value in fields)
            return f"{{0:12.6f}}  {ident:>3}  {_braces(spec.name):<22} {_braces(spec.sender):<11}{{2:>3}}  {body}\n", names
        if kind == "csv":
            head = f"{{0:.6f}},{{1:.6f}},0x{ident},{_braces(_csv_cell(spec.name))},{_braces(_csv_cell(spec.sender))},{{2}},ok,{{3}}"
            return "".join(f"{head},{_braces(_csv_cell(sig.name))},{value},{_braces(_csv_cell(sig.unit))},{{4}}\n"
                           for sig, value in fields) or f"{head},,,,{{4}}\n", names
        signals = ", ".join(f"{_braces(json.dumps(sig.name))}: {value}" for sig, value in fields)
        return (f'{{{{"t": {{0:.6f}}, "ts": {{1!r}}, "id": {spec.frame_id}, "message": {_braces(json.dumps(spec.name))}, '
                f'"sender": {_braces(json.dumps(spec.sender))}, "counter": {{2}}, "status": "ok", "lost_before": {{3}}, '
                f'"signals": {{{{{signals}}}}}, "data": "{{4}}"}}}}\n'), names

    def line(self, kind: str, row: Row) -> str:
        """The compiled line of a frame that passed every check (``row.status`` is ``ok``)."""
        template, picks, names = self._lines[kind][row.spec.frame_id]
        values = row.values if picks is None else [row.values[k] for k in picks]
        if names:
            values = list(values)
            for i, labels in names:
                values[i] = labels[values[i]]
        frame = row.frame
        return template.format(row.time_s, frame.timestamp, row.counter, row.lost_before, frame.data.hex().upper(), *values)

    def signals(self, row: Row) -> list[tuple[SignalSpec, Any]]:
        """(signal, value) of the shown signals; labels for enumerations, values on their grid."""
        out = []
        for k, sig, digits in self._signals[row.spec.frame_id]:
            value = row.values[k]
            if self.labels and sig.choices is not None:
                value = sig.choices.get(value, value)
            elif digits == 0:
                value = int(value)
            else:
                value = round(value, digits)
            out.append((sig, value))
        return out


def _mark(row: Row) -> str:
    if row.status != OK:
        return f"!{row.status.upper()}"
    return f"(lost {row.lost_before})" if row.lost_before else ""


def write_table(rows: Iterable[Row], fmt: Formatter, out: TextIO, *, flush: bool = False) -> int:
    n = 0
    out.write(f"{'time_s':>12}  {'id':>3}  {'message':<22} {'sender':<11}{'ctr':>3}  signals\n")
    line = fmt.line
    for row in rows:
        n += 1
        if row.status == OK and not row.lost_before:
            out.write(line("table", row))
        else:
            out.write(_table_line(row, fmt))
        if flush:
            out.flush()
    return n


def _table_line(row: Row, fmt: Formatter) -> str:
    frame = row.frame
    ident = f"{frame.arbitration_id:08X}" if frame.is_extended_id else f"{frame.arbitration_id:03X}"
    if row.spec is None or row.values is None:
        name = row.spec.name if row.spec is not None else "?"
        sender = row.spec.sender if row.spec is not None else ""
        body = f"[{len(frame.data)}] {frame.data.hex(' ').upper()}"
        counter = ""
    else:
        name, sender = row.spec.name, row.spec.sender
        counter = str(row.counter)
        body = "  ".join(f"{sig.name}={value}{' ' + sig.unit if sig.unit else ''}" for sig, value in fmt.signals(row))
    mark = _mark(row)
    return (f"{row.time_s:12.6f}  {ident:>3}  {name:<22} {sender:<11}{counter:>3}  {body}{'  ' + mark if mark else ''}"
            f"{'  ' + row.detail if row.detail and row.status != UNKNOWN else ''}\n")


CSV_COLUMNS = ("time_s", "timestamp", "frame_id", "message", "sender", "counter", "status", "lost_before",
               "signal", "value", "unit", "data")


def write_csv(rows: Iterable[Row], fmt: Formatter, out: TextIO, *, flush: bool = False) -> int:
    """One row per shown signal of a frame (one row without a signal for a frame not decodable)."""
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    n = 0
    line = fmt.line
    for row in rows:
        n += 1
        if row.status == OK:
            out.write(line("csv", row))
        else:
            frame = row.frame
            head = [f"{row.time_s:.6f}", f"{frame.timestamp:.6f}", f"0x{frame.arbitration_id:03X}",
                    row.spec.name if row.spec else "", row.spec.sender if row.spec else "",
                    "" if row.counter is None else row.counter, row.status, row.lost_before]
            data = frame.data.hex().upper()
            if row.spec is None or row.values is None:
                writer.writerow(head + ["", "", "", data])
            else:
                writer.writerows(head + [sig.name, value, sig.unit, data] for sig, value in fmt.signals(row))
        if flush:
            out.flush()
    return n


JSONL_SCHEMA = "aider-exo trace decode 1"


def write_jsonl(rows: Iterable[Row], fmt: Formatter, out: TextIO, *, catalog: Catalog, flush: bool = False) -> int:
    """One schema line (fields, units per message and signal), then one object per frame."""
    units = {m.name: {s.name: s.unit for s in m.signals if s.unit} for m in catalog.messages}
    schema = {
        "schema": JSONL_SCHEMA,
        "fields": {"t": "s since the first frame", "ts": "s, the trace's timestamp", "id": "CAN ID",
                   "message": "DBC message (null: unknown ID)", "sender": "DBC sender", "counter": "alive counter",
                   "status": "ok or the receiver's rejection reason", "lost_before": "frames lost before this one",
                   "signals": "physical values (null when not decodable)", "data": "payload, hex",
                   "detail": "why a frame was rejected (only then)"},
        "units": {name: u for name, u in units.items() if u},
    }
    out.write(json.dumps(schema) + "\n")
    n = 0
    line = fmt.line
    for row in rows:
        n += 1
        if row.status == OK:
            out.write(line("jsonl", row))
        else:
            frame = row.frame
            obj = {"t": round(row.time_s, 6), "ts": frame.timestamp, "id": frame.arbitration_id,
                   "message": row.spec.name if row.spec else None, "sender": row.spec.sender if row.spec else None,
                   "counter": row.counter, "status": row.status, "lost_before": row.lost_before,
                   "signals": None if row.spec is None or row.values is None
                   else {sig.name: value for sig, value in fmt.signals(row)},
                   "data": frame.data.hex().upper(), "detail": row.detail}
            out.write(json.dumps(obj) + "\n")
        if flush:
            out.flush()
    return n
