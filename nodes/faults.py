"""Fault injection inside the emulated nodes (docs/FAULTS.md layer NE), off unless configured.

:class:`FaultInjector` holds the configured faults and a seeded generator. The host asks it, per
tick, which node-level faults start (reboot, drive fault), whether a node is frozen or its encoder
stuck, and passes every outgoing frame through :meth:`FaultInjector.outgoing`, which drops,
delays, duplicates, corrupts, pushes a signal out of range or sets it as configured. Every injection is
counted by kind, so a test or the status line can show what was done.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np

from config.errors import AiderError
from config.nodes_schema import VALUE_FAULTS, FaultConfig
from protocol.catalog import Catalog, MessageSpec
from protocol.clock import TICK_MS
from protocol.codec import with_raw_value
from protocol.errors import ProtocolError


class FaultConfigError(AiderError):
    """A fault names a message or signal that its node does not send."""


@dataclass(frozen=True)
class _Fault:
    name: str
    cfg: FaultConfig
    spec: MessageSpec | None
    raw: int | None  # out_of_range, sensor_value: the raw value sent

    def active(self, tick: int) -> bool:
        end = self.cfg.end_tick
        return tick >= self.cfg.start_tick and (end is None or tick < end)


class FaultInjector:
    def __init__(self, faults: dict[str, FaultConfig], catalog: Catalog, rng: np.random.Generator) -> None:
        self.rng = rng
        self.catalog = catalog
        self.counts: Counter[str] = Counter()
        self._faults: list[_Fault] = []
        self._delayed: dict[int, list[tuple[MessageSpec, bytes]]] = defaultdict(list)
        for name, cfg in faults.items():
            self.add(name, cfg)

    def add(self, name: str, cfg: FaultConfig) -> None:
        """One more fault (the configured ones are added at start; a test may add one later)."""
        catalog = self.catalog
        spec = raw = None
        if cfg.message is not None:
            try:
                spec = catalog.by_name(cfg.message)
            except ProtocolError:
                raise FaultConfigError(f"nodes.faults.{name}.message: unknown message {cfg.message!r}") from None
            if spec.sender != cfg.node:
                raise FaultConfigError(f"nodes.faults.{name}.message: {cfg.message} is sent by {spec.sender}, not {cfg.node}")
        if cfg.kind in VALUE_FAULTS:
            assert spec is not None and cfg.signal is not None and cfg.value is not None
            try:
                sig = spec.signal(cfg.signal)
            except KeyError:
                raise FaultConfigError(f"nodes.faults.{name}.signal: {cfg.message} has no signal {cfg.signal!r}") from None
            raw = round((cfg.value - sig.offset) / sig.scale)
            in_range = sig.raw_min <= raw <= sig.raw_max
            if cfg.kind == "sensor_value" and not in_range:
                raise FaultConfigError(
                    f"nodes.faults.{name}.value: {cfg.value} must lie within {cfg.message}.{cfg.signal}'s range "
                    f"[{sig.minimum}, {sig.maximum}] (beyond it: out_of_range)"
                )
            if cfg.kind == "out_of_range" and (in_range or not sig.raw_min_representable <= raw <= sig.raw_max_representable):
                raise FaultConfigError(
                    f"nodes.faults.{name}.value: {cfg.value} must lie outside {cfg.message}.{cfg.signal}'s range "
                    f"[{sig.minimum}, {sig.maximum}] and within its {sig.length} bits"
                )
        self._faults.append(_Fault(name, cfg, spec, raw))

    def __bool__(self) -> bool:
        return bool(self._faults)

    def _node_faults(self, node: str, kind: str, tick: int) -> list[_Fault]:
        if not self._faults:  # none configured (every walk but the fault tests): the per-tick questions answer at once
            return []
        return [f for f in self._faults if f.cfg.node == node and f.cfg.kind == kind and f.active(tick)]

    def starting(self, node: str, kind: str, tick: int) -> bool:
        """Whether a one-shot fault (reboot, drive_fault) of ``node`` starts at ``tick``."""
        hit = bool(self._faults) and any(f.cfg.node == node and f.cfg.kind == kind and f.cfg.start_tick == tick for f in self._faults)
        if hit:
            self.counts[kind] += 1
        return hit

    def frozen(self, node: str, tick: int) -> bool:
        return bool(self._node_faults(node, "freeze", tick))

    def stuck_encoder(self, node: str, tick: int) -> bool:
        return bool(self._node_faults(node, "stuck_encoder", tick))

    def supply_drop_v(self, node: str, tick: int) -> float:
        """How far below its nominal the supply of ``node`` has fallen at ``tick`` (supply_ramp)."""
        return sum(f.cfg.value * (tick - f.cfg.start_tick) * TICK_MS / 1000 for f in self._node_faults(node, "supply_ramp", tick))

    def outgoing(self, node: str, spec: MessageSpec, payload: bytes, tick: int) -> list[bytes]:
        """The payloads to send now in place of ``payload`` (none when dropped or delayed)."""
        out = [payload]
        if not self._faults:  # none configured: every walk but the fault tests, for every frame
            return out
        for f in self._faults:
            if f.spec is not spec or not f.active(tick):
                continue
            kind = f.cfg.kind
            if kind in VALUE_FAULTS:
                out = [with_raw_value(spec, p, f.cfg.signal, f.raw) for p in out]  # type: ignore[arg-type]
                self.counts[kind] += 1
                continue
            if f.cfg.probability < 1.0 and self.rng.random() >= f.cfg.probability:
                continue
            self.counts[kind] += 1
            if kind == "drop":
                return []
            if kind == "delay":
                self._delayed[tick + f.cfg.delay_ticks].extend((spec, p) for p in out)
                return []
            if kind == "duplicate":
                out = [p for p in out for _ in (0, 1)]
            elif kind == "corrupt":
                bit = int(self.rng.integers(8, 8 * len(payload)))  # a payload bit, not the CRC byte
                out = [bytes(b ^ (1 << (bit % 8)) if i == bit // 8 else b for i, b in enumerate(p)) for p in out]
        return out

    def due(self, tick: int) -> list[tuple[MessageSpec, bytes]]:
        """Delayed frames whose time has come (at or before ``tick``)."""
        ready: list[tuple[MessageSpec, bytes]] = []
        if not self._delayed:
            return ready
        for t in sorted(k for k in self._delayed if k <= tick):
            ready += self._delayed.pop(t)
        return ready
