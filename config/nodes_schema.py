"""Schema of the ``nodes`` section: the emulated node boards' watchdogs and their fault injection."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from .loader import fail, field_spec

NODE_NAMES = ("LEFT_HIP", "LEFT_KNEE", "RIGHT_HIP", "RIGHT_KNEE")

#: Faults that act on one of the node's messages (and need ``message``).
MESSAGE_FAULTS = ("drop", "delay", "duplicate", "corrupt", "out_of_range", "sensor_value")
#: Faults that set one signal of the message (and need ``signal`` and ``value``).
VALUE_FAULTS = ("out_of_range", "sensor_value")


@dataclass(frozen=True, kw_only=True)
class FaultConfig:
    """One injected fault of one node, active over a range of ticks.

    Kinds: ``drop``, ``delay`` (by ``delay_ticks``), ``duplicate`` or ``corrupt`` (one bit flipped,
    so its CRC fails) a message the node sends, with ``probability`` per frame; ``out_of_range``: a
    sensor signal of the message carries ``value`` (raw grid, beyond its DBC range) under a good
    CRC; ``sensor_value``: a sensor signal of the message reads ``value`` (within its range: a
    sensor that has failed, or a stick that slipped, reads 0 N); ``freeze``: the node's application stops, its last frames are re-sent unchanged (same
    counters) and commands are no longer applied; ``stuck_encoder``: the joint's reported position
    stays at its value when the fault starts; ``reboot``: the node restarts once at ``start_tick``
    (boot-up, pre-operational, counters from 0); ``drive_fault``: the drive reports an over-current
    fault (EMCY, quick stop, latched until the controller's fault reset); ``supply_ramp``: the supply
    voltage the node reports falls by ``value`` volts a second from ``start_tick`` (the nominal again
    from ``end_tick``: a battery swapped).
    """

    kind: Literal[
        "drop", "delay", "duplicate", "corrupt", "out_of_range", "sensor_value", "freeze", "stuck_encoder", "reboot",
        "drive_fault", "supply_ramp",
    ] = field_spec(doc="What goes wrong (see the class doc).")
    node: Literal["LEFT_HIP", "LEFT_KNEE", "RIGHT_HIP", "RIGHT_KNEE"] = field_spec(doc="The node it happens to.")
    start_tick: int = field_spec(doc="First tick (SYNC tick number) with the fault.", min=0, max=2**28 - 1)
    end_tick: int | None = field_spec(
        doc="First tick without it (absent: until the process ends).", min=1, max=2**28, default=None
    )
    message: str | None = field_spec(
        doc="Message the fault acts on (drop, delay, duplicate, corrupt, out_of_range, sensor_value): one the node sends.",
        default=None,
    )
    signal: str | None = field_spec(doc="out_of_range, sensor_value: the signal of ``message`` that the fault sets.", default=None)
    value: float | None = field_spec(
        doc="out_of_range: the physical value sent (beyond the signal's range, within its bits); sensor_value: within its range; supply_ramp: volts a second.",
        default=None,
    )
    probability: float = field_spec(doc="Chance per frame for drop, duplicate and corrupt.", min=0.0, max=1.0, default=1.0)
    delay_ticks: int = field_spec(doc="delay: how many ticks a frame is held back.", min=1, max=50, default=1)

    def validate(self) -> None:
        if self.end_tick is not None and self.end_tick <= self.start_tick:
            fail("end_tick", f"must be after start_tick {self.start_tick}")
        if self.kind in MESSAGE_FAULTS and not self.message:
            fail("message", f"a {self.kind} fault needs the message it acts on")
        if self.kind not in MESSAGE_FAULTS and self.message:
            fail("message", f"a {self.kind} fault acts on the whole node, not on a message")
        if self.kind == "supply_ramp" and (self.value is None or not 0.0 < self.value <= 100.0):
            fail("value", "a supply_ramp fault needs value: the fall in volts a second, in (0, 100]")
        if self.kind in VALUE_FAULTS and (self.signal is None or self.value is None):
            fail("signal" if self.signal is None else "value", f"an {self.kind} fault needs signal and value")


@dataclass(frozen=True, kw_only=True)
class NodesConfig:
    """The four emulated node boards (CANopen-style firmware, docs/FAULTS.md)."""

    command_timeout_ticks: int = field_spec(
        doc=(
            "Command watchdog: an operational node that receives no valid joint command for this many "
            "consecutive ticks quick-stops and stays (holds its measured position), sends EMCY and waits for "
            "the controller's fault reset. Hard bound 5 (100 ms)."
        ),
        min=1,
        max=5,
    )
    heartbeat_timeout_ms: int = field_spec(
        doc=(
            "Heartbeat consumer time: no controller heartbeat for this long is the same fault as the command "
            "watchdog (CiA 301 practice: three producer periods of 100 ms)."
        ),
        unit="ms",
        min=120,
        max=1000,
    )
    supply_voltage_v: float = field_spec(
        doc="Supply voltage the boards report in their heartbeats: the battery's DC bus (a 7-cell Li-ion pack, 25.2 V full).",
        unit="V", min=5.0, max=60.0,
    )
    status_interval_s: float = field_spec(
        doc="Seconds between the one-line status reports of `aider-exo nodes`.", unit="s", min=0.1, max=60.0, default=1.0
    )
    faults: dict[str, FaultConfig] = field_spec(
        doc="Injected faults by name; none by default (tests and fault drills add them).", default_factory=dict
    )
