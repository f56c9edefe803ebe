"""The message catalogue, read once from ``protocol/aider.dbc`` by cantools.

Everything about frames (IDs, senders, lengths, bit layouts, scalings, ranges, periods, Data IDs)
comes from the DBC. This module turns cantools' database into small frozen specs and checks the
project's conventions on it (end-to-end protection layout, ranges on the raw grid, unique Data ID
seeds), so that a malformed DBC fails at start-up with a message naming the message and signal.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

from protocol import crc as _crc
from protocol.clock import TICK_MS
from protocol.enums import check_enums
from protocol.errors import ProtocolError

DBC_PATH = Path(__file__).with_name("aider.dbc")

#: Signals every frame starts with (AUTOSAR E2E profile 1 layout on classic CAN).
CRC_SIGNAL = "e2e_crc"
COUNTER_SIGNAL = "e2e_counter"
COUNTER_MODULO = 16


@dataclass(frozen=True)
class SignalSpec:
    """One payload signal (little-endian) of a message."""

    name: str
    start: int
    length: int
    signed: bool
    scale: float
    offset: float
    minimum: float
    maximum: float
    unit: str
    choices: dict[int, str] | None
    comment: str
    raw_min: int
    raw_max: int
    sensor: str = ""
    sensor_resolution: float | None = None  # of the measuring device, where the signal is a sensor reading

    @property
    def raw_min_representable(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max_representable(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    @property
    def is_integer(self) -> bool:
        """True where the physical value is the raw integer (enumerations, counters, codes)."""
        return self.scale == 1 and self.offset == 0


@dataclass(frozen=True)
class MessageSpec:
    """One CAN message of the protocol."""

    frame_id: int
    name: str
    family: str
    sender: str
    receivers: tuple[str, ...]
    dlc: int
    cycle_ms: int | None
    tick_phase: int
    data_id: int
    crc_seed: int
    signals: tuple[SignalSpec, ...]
    comment: str
    record: type = field(repr=False, compare=False)

    @property
    def is_cyclic(self) -> bool:
        return self.cycle_ms is not None

    @property
    def period_ticks(self) -> int | None:
        return None if self.cycle_ms is None else self.cycle_ms // TICK_MS

    def sent_in_tick(self, tick: int) -> bool:
        """Whether this cyclic message goes out in controller tick ``tick``."""
        period = self.period_ticks
        return period is not None and tick % period == self.tick_phase

    def signal(self, name: str) -> SignalSpec:
        for sig in self.signals:
            if sig.name == name:
                return sig
        raise KeyError(f"{self.name} has no signal {name!r}")


@dataclass(frozen=True)
class Catalog:
    """All messages and nodes of the protocol."""

    messages: tuple[MessageSpec, ...]
    node_ids: dict[str, int]
    version: int
    source: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_id", {m.frame_id: m for m in self.messages})
        object.__setattr__(self, "_by_name", {m.name: m for m in self.messages})

    def by_id(self, frame_id: int) -> MessageSpec | None:
        return self._by_id.get(frame_id)  # type: ignore[attr-defined]

    def by_name(self, name: str) -> MessageSpec:
        try:
            return self._by_name[name]  # type: ignore[attr-defined]
        except KeyError:
            raise ProtocolError(f"unknown message {name!r}") from None

    def sent_by(self, node: str) -> tuple[MessageSpec, ...]:
        return tuple(m for m in self.messages if m.sender == node)

    def cyclic_in_tick(self, tick: int, sender: str | None = None) -> tuple[MessageSpec, ...]:
        """Cyclic messages (of ``sender``, or all) that go out in controller tick ``tick``."""
        return tuple(
            m for m in self.messages if m.sent_in_tick(tick) and (sender is None or m.sender == sender)
        )

    @property
    def nodes(self) -> tuple[str, ...]:
        return tuple(self.node_ids)

    @property
    def joint_nodes(self) -> tuple[str, ...]:
        """The joint node boards (the senders of a JOINT_STATUS), in node-id order."""
        senders = {m.sender for m in self.messages if m.family == "JOINT_STATUS"}
        return tuple(sorted(senders, key=self.node_ids.__getitem__))

    def message(self, family: str, node: str) -> MessageSpec:
        """The message of ``family`` that ``node`` sends, or that is addressed to it alone
        (``message("JOINT_COMMAND", "LEFT_HIP")``)."""
        for m in self.messages:
            if m.family == family and (m.sender == node or m.receivers == (node,)):
                return m
        raise ProtocolError(f"no {family} message of node {node}")


def _attr(obj: Any, name: str, default: Any = None) -> Any:
    """Value of a DBC attribute (enumerations by their label), or ``default``."""
    attrs = obj.dbc.attributes if obj.dbc is not None else {}
    if name not in attrs:
        return default
    attribute = attrs[name]
    choices = getattr(attribute.definition, "choices", None)
    if choices and isinstance(attribute.value, int):
        return choices[attribute.value]
    return attribute.value


def _on_grid(value: float, sig: Any, what: str, msg_name: str) -> int:
    raw = (value - sig.offset) / sig.scale
    nearest = round(raw)
    if not math.isclose(raw, nearest, rel_tol=0, abs_tol=1e-6):
        raise ProtocolError(
            f"{msg_name}.{sig.name}: {what} {value} is not a multiple of the scale {sig.scale}"
        )
    return int(nearest)


def _signal_spec(msg: Any, sig: Any) -> SignalSpec:
    where = f"{msg.name}.{sig.name}"
    if sig.byte_order != "little_endian":
        raise ProtocolError(f"{where}: only little-endian (Intel) signals are supported")
    if sig.is_float or sig.is_multiplexer or sig.multiplexer_ids:
        raise ProtocolError(f"{where}: float and multiplexed signals are not supported")
    if sig.minimum is None or sig.maximum is None or sig.minimum > sig.maximum:
        raise ProtocolError(f"{where}: needs a physical range [min|max] with min <= max")
    raw_min = _on_grid(sig.minimum, sig, "minimum", msg.name)
    raw_max = _on_grid(sig.maximum, sig, "maximum", msg.name)
    if sig.scale < 0:
        raw_min, raw_max = raw_max, raw_min
    lo, hi = (-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.is_signed else (0, (1 << sig.length) - 1)
    if raw_min < lo or raw_max > hi:
        raise ProtocolError(
            f"{where}: range [{sig.minimum}, {sig.maximum}] needs raw [{raw_min}, {raw_max}], "
            f"beyond what {sig.length} {'signed' if sig.is_signed else 'unsigned'} bits hold"
        )
    choices = None
    if sig.choices:
        choices = {int(k): str(v) for k, v in sig.choices.items()}
        outside = [k for k in choices if not raw_min <= k <= raw_max]
        if outside or sig.scale != 1 or sig.offset != 0:
            raise ProtocolError(f"{where}: enumerated values must be raw integers inside the range")
    return SignalSpec(
        name=sig.name,
        start=sig.start,
        length=sig.length,
        signed=sig.is_signed,
        scale=float(sig.scale),
        offset=float(sig.offset),
        minimum=float(sig.minimum),
        maximum=float(sig.maximum),
        unit=sig.unit or "",
        choices=choices,
        comment=sig.comment or "",
        raw_min=raw_min,
        raw_max=raw_max,
        sensor=str(_attr(sig, "AiderSensor", "")),
        sensor_resolution=float(_attr(sig, "AiderSensorResolution", 0)) or None,
    )


def _check_e2e(msg: Any) -> None:
    by_name = {s.name: s for s in msg.signals}
    for name, start, length in ((CRC_SIGNAL, 0, 8), (COUNTER_SIGNAL, 8, 4)):
        sig = by_name.get(name)
        if sig is None or sig.start != start or sig.length != length or sig.is_signed:
            raise ProtocolError(
                f"{msg.name}: every message must carry unsigned {name} at bit {start}, {length} bits"
            )


def _check_layout(msg: Any, signals: tuple[SignalSpec, ...]) -> None:
    used = (1 << 12) - 1  # CRC and counter
    for sig in signals:
        bits = ((1 << sig.length) - 1) << sig.start
        if sig.start < 12 or sig.start + sig.length > 8 * msg.length or used & bits:
            raise ProtocolError(f"{msg.name}.{sig.name}: overlaps another signal or leaves the frame")
        used |= bits


def _message_spec(msg: Any, node_ids: dict[str, int]) -> MessageSpec:
    if msg.is_extended_frame or msg.is_fd or msg.length > 8 or msg.length < 2:
        raise ProtocolError(f"{msg.name}: only classic CAN frames with 11-bit IDs and DLC 2..8")
    if len(msg.senders) != 1 or msg.senders[0] not in node_ids:
        raise ProtocolError(f"{msg.name}: needs exactly one sender among the nodes {sorted(node_ids)}")
    _check_e2e(msg)
    signals = tuple(
        _signal_spec(msg, s) for s in msg.signals if s.name not in (CRC_SIGNAL, COUNTER_SIGNAL)
    )
    _check_layout(msg, signals)
    send_type = _attr(msg, "GenMsgSendType", "Event")
    cycle = _attr(msg, "GenMsgCycleTime", 0) if send_type == "Cyclic" else 0
    if send_type == "Cyclic" and (cycle <= 0 or cycle % TICK_MS):
        raise ProtocolError(f"{msg.name}: a cyclic message needs a cycle time that is a multiple of {TICK_MS} ms")
    phase = int(_attr(msg, "AiderTickPhase", 0))
    if cycle and phase >= cycle // TICK_MS:
        raise ProtocolError(f"{msg.name}: AiderTickPhase {phase} must be below its period in ticks")
    data_id = int(_attr(msg, "AiderDataId", 0))
    family = str(_attr(msg, "AiderFamily", "")) or msg.name
    receivers = sorted({r for s in msg.signals for r in s.receivers})
    record = namedtuple(family.title().replace("_", ""), [s.name for s in signals])  # type: ignore[misc]
    return MessageSpec(
        frame_id=msg.frame_id,
        name=msg.name,
        family=family,
        sender=msg.senders[0],
        receivers=tuple(receivers),
        dlc=msg.length,
        cycle_ms=int(cycle) if cycle else None,
        tick_phase=phase,
        data_id=data_id,
        crc_seed=_crc.seed_for_data_id(data_id),
        signals=signals,
        comment=msg.comment or "",
        record=record,
    )


def load_catalog(path: str | Path = DBC_PATH) -> Catalog:
    """Read and check a DBC file; raises :class:`ProtocolError` with a one-line reason."""
    import cantools  # imported here: the runtime needs it only at start-up

    path = Path(path)
    try:
        db = cantools.database.load_file(str(path), database_format="dbc", strict=True)
    except FileNotFoundError:
        raise ProtocolError(f"{path}: no such DBC file") from None
    except Exception as exc:  # cantools raises many types for a bad file
        raise ProtocolError(f"{path}: not a valid DBC file: {str(exc).splitlines()[0]}") from None
    node_ids = {}
    for node in db.nodes:
        node_id = _attr(node, "AiderNodeId")
        if node_id is None:
            raise ProtocolError(f"{path}: node {node.name} has no AiderNodeId")
        node_ids[node.name] = int(node_id)
    messages = tuple(_message_spec(m, node_ids) for m in sorted(db.messages, key=lambda m: m.frame_id))
    # Distinct CRC seeds make a frame sent under another message's ID fail its CRC (masquerade).
    seeds: dict[int, str] = {}
    for m in messages:
        if m.crc_seed in seeds:
            raise ProtocolError(f"{m.name}: Data ID {m.data_id:#06x} gives the same CRC seed as {seeds[m.crc_seed]}")
        seeds[m.crc_seed] = m.name
    version = int(db.dbc.attributes["ProtocolVersion"].value) if "ProtocolVersion" in db.dbc.attributes else 0
    catalog = Catalog(messages=messages, node_ids=node_ids, version=version, source=str(path))
    check_enums(catalog)
    return catalog


@lru_cache(maxsize=None)
def default_catalog() -> Catalog:
    """The project's protocol, loaded once per process."""
    return load_catalog(DBC_PATH)
