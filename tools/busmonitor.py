"""Bus checks that are safe on a real bus with powered motor boards (``aider-exo buscheck``).

* **listen**: the bus is only read (:class:`ListenOnlyBus` refuses every send). Reported per node:
  heartbeats and their NMT states, supply voltage, drive states and error codes, EMCYs; per
  message: frames, the longest gap against its DBC cycle time, every signal's range seen; and the
  receiver's CRC, counter and range rejections. Run it with the nodes powered (heartbeats only),
  or beside a running controller (every frame).
* **hold**: the controller's part with every joint commanded to HOLD (the drive holds the position
  it measures, within the configured HOLD torque): NMT START, then per tick SYNC, four HOLD
  commands and the controller heartbeat, and at the end ENTER_PRE_OPERATIONAL (the nodes keep
  holding). Besides what *listen* checks: every node frame due in every tick arrives, every drive
  reports HOLD, every heartbeat OPERATIONAL.

Neither moves a joint on purpose. The full-range sweep (``tools/buscheck.py``) commands TRACK over
every signal's range and is refused on a real bus (:func:`tools.buscheck.sweep_refusal`).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import can

from config import Config
from protocol.bus import ListenOnly, open_bus
from protocol.catalog import Catalog, MessageSpec
from protocol.clock import TICK_MS, TICK_NS, Clock, TickTimer
from protocol.codec import Codec, Decoded
from protocol.e2e import Receiver, Transmitter
from protocol.enums import DriveState, GaitState, JointMode, NmtCommand, NmtState, NodeError
from tools.buscheck import CONTROLLER, BusCheckError

GAP_FACTOR = 2.0  # a cyclic message whose interval exceeds this many cycle times has a gap


class ListenOnlyBus(ListenOnly):
    """The listen check's bus: every send attempt is counted and refused."""

    REFUSAL = "listen-only: this check never sends"
    error = BusCheckError


# -- what was seen --------------------------------------------------------------------------------


@dataclass
class MessageSeen:
    """One message's frames: count, intervals and the range of every signal."""

    spec: MessageSpec
    frames: int = 0
    last_s: float | None = None
    max_interval_s: float = 0.0
    gaps: int = 0
    ranges: dict[str, list[float]] = field(default_factory=dict)

    def add(self, values: Any, t: float, timing: bool) -> None:
        self.frames += 1
        if timing and self.last_s is not None and self.spec.cycle_ms:
            interval = t - self.last_s
            self.max_interval_s = max(self.max_interval_s, interval)
            if interval > GAP_FACTOR * self.spec.cycle_ms / 1000:
                self.gaps += 1
        self.last_s = t
        for name, value in zip(values._fields, values):
            if isinstance(value, (int, float)) and math.isfinite(value):
                lo_hi = self.ranges.get(name)
                if lo_hi is None:
                    self.ranges[name] = [value, value]
                elif value < lo_hi[0]:
                    lo_hi[0] = value
                elif value > lo_hi[1]:
                    lo_hi[1] = value

    def as_dict(self, timing: bool) -> dict[str, Any]:
        out: dict[str, Any] = {"sender": self.spec.sender, "frames": self.frames, "cycle_ms": self.spec.cycle_ms}
        if timing and self.spec.cycle_ms and self.frames > 1:
            out["max_interval_ms"] = round(self.max_interval_s * 1000, 1)
            out["gaps"] = self.gaps
        out["signals"] = {k: [round(v, 4) for v in lo_hi] for k, lo_hi in self.ranges.items()}
        return out


@dataclass
class NodeSeen:
    """One node board: NMT states, supply voltage, drive states, error codes and EMCYs."""

    nmt_states: Counter[str] = field(default_factory=Counter)
    last_nmt: str | None = None
    supply_v: list[float] = field(default_factory=list)  # lowest, highest
    drive_states: Counter[str] = field(default_factory=Counter)
    errors: Counter[str] = field(default_factory=Counter)
    emcy: list[dict[str, int]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {
            "heartbeats": sum(self.nmt_states.values()),
            "nmt_states": dict(self.nmt_states),
            "last_nmt_state": self.last_nmt,
            "supply_voltage_V": [round(v, 2) for v in self.supply_v],
            "drive_states": dict(self.drive_states),
            "error_codes": dict(self.errors),
            "emcy": self.emcy[:10],
            "emcy_total": len(self.emcy),
        }


def _name(enum_type: Any, value: int) -> str:
    try:
        return enum_type(int(value)).name
    except ValueError:
        return str(int(value))


class BusMonitor:
    """Everything the checks report about what they received (no I/O: fed decoded frames)."""

    def __init__(self, catalog: Catalog, *, timing: bool) -> None:
        self.catalog = catalog
        self.timing = timing  # intervals mean something only when the bus runs in real time
        self.messages: dict[str, MessageSeen] = {}
        self.nodes: dict[str, NodeSeen] = {n: NodeSeen() for n in catalog.joint_nodes}

    def add(self, decoded: Decoded, t: float) -> None:
        spec, values = decoded.message, decoded.values
        seen = self.messages.get(spec.name)
        if seen is None:
            seen = self.messages[spec.name] = MessageSeen(spec)
        seen.add(values, t, self.timing)
        node = self.nodes.get(spec.sender)
        if node is None:
            return
        if spec.family == "HEARTBEAT":
            node.last_nmt = _name(NmtState, values.nmt_state)
            node.nmt_states[node.last_nmt] += 1
            v = float(values.supply_voltage_V)
            node.supply_v = [min(v, node.supply_v[0]), max(v, node.supply_v[1])] if node.supply_v else [v, v]
        elif spec.family == "JOINT_STATUS":
            node.drive_states[_name(DriveState, values.drive_state)] += 1
            node.errors[_name(NodeError, values.error_code)] += 1
        elif spec.family == "EMCY":
            node.emcy.append({"code": int(values.emcy_code), "error_register": int(values.error_register), "detail": int(values.detail)})

    def problems(self, receiver: Receiver) -> list[str]:
        """What makes a check fail, one line each (empty: clean)."""
        out = []
        stats = receiver.stats
        if stats.rejected_total:
            out.append(f"{stats.rejected_total} frames rejected {stats.as_dict()['rejected_by_reason']}")
        if stats.lost:
            out.append(f"{stats.lost} frames lost (alive-counter gaps)")
        for name, node in self.nodes.items():
            if not node.nmt_states:
                out.append(f"{name}: no heartbeat")
            errors = {k: n for k, n in node.errors.items() if k != NodeError.NONE.name}
            if node.drive_states[DriveState.FAULT.name] or errors:
                out.append(f"{name}: {node.drive_states[DriveState.FAULT.name]} status frames in FAULT, error codes {errors}")
            if any(e["code"] for e in node.emcy):
                out.append(f"{name}: {sum(1 for e in node.emcy if e['code'])} EMCY (first {node.emcy[0]})")
        for name, seen in self.messages.items():
            if seen.gaps:
                out.append(f"{name}: {seen.gaps} gaps longer than {GAP_FACTOR:g} cycles (longest {seen.max_interval_s * 1000:.0f} ms, cycle {seen.spec.cycle_ms} ms)")
        return out

    def report(self, receiver: Receiver) -> dict[str, Any]:
        return {
            "receiver": receiver.stats.as_dict(),
            "nodes": {name: node.as_dict() for name, node in self.nodes.items()},
            "messages": {name: self.messages[name].as_dict(self.timing) for name in sorted(self.messages)},
        }


def _receive(bus: Any, receiver: Receiver, monitor: BusMonitor, clock: Clock, timeout_s: float) -> Decoded | None:
    """One frame from ``bus`` through ``receiver`` into ``monitor``: the decoded frame, or None
    (nothing within the timeout, or a rejected frame, which ``receiver`` counts)."""
    msg = bus.recv(timeout=max(timeout_s, 0.0))
    if msg is None:
        return None
    result = receiver.receive(msg)
    if isinstance(result, Decoded):
        monitor.add(result, msg.timestamp or clock.now_ns() / 1e9)
        return result
    return None


# -- listen ---------------------------------------------------------------------------------------


def listen(bus: Any, codec: Codec, clock: Clock, *, duration_s: float, max_delta_counter: int) -> dict[str, Any]:
    """Read ``bus`` for ``duration_s`` and report (it is wrapped so that nothing can be sent)."""
    quiet = ListenOnlyBus(bus)
    receiver = Receiver(codec, max_delta_counter=max_delta_counter)
    monitor = BusMonitor(codec.catalog, timing=True)
    end = clock.now_ns() + int(duration_s * 1e9)
    while (remaining := (end - clock.now_ns()) / 1e9) > 0:
        _receive(quiet, receiver, monitor, clock, min(remaining, 0.1))
    frames = receiver.stats.accepted + receiver.stats.rejected_total
    result = {"mode": "listen", "duration_s": duration_s, "frames_received": frames,
              "frames_sent": quiet.sends_refused, **monitor.report(receiver)}
    result["problems"] = monitor.problems(receiver)
    result["ok"] = not result["problems"] and quiet.sends_refused == 0
    return result


def run_listen(cfg: Config, clock: Clock, duration_s: float) -> dict[str, Any]:
    codec = Codec()
    with open_bus(cfg.bus) as bus:
        result = listen(bus, codec, clock, duration_s=duration_s, max_delta_counter=cfg.protocol.max_delta_counter)
    return {"bus": {"interface": cfg.bus.interface, "channel": cfg.bus.channel}, **result}


# -- hold -----------------------------------------------------------------------------------------


class HoldCheck:
    """The controller's traffic with every joint held: what the nodes answer, checked."""

    def __init__(self, bus: can.BusABC, codec: Codec, clock: Clock, *, max_delta_counter: int, hold_torque_nm: float,
                 period_ns: int | None, tick_timeout_s: float) -> None:
        self.bus, self.codec, self.clock = bus, codec, clock
        self.catalog = codec.catalog
        self.tx = Transmitter(codec)
        self.rx = Receiver(codec, max_delta_counter=max_delta_counter)
        self.monitor = BusMonitor(self.catalog, timing=period_ns is not None)
        self.period_ns = period_ns
        self.tick_timeout_s = tick_timeout_s
        self.hold_torque_nm = hold_torque_nm
        self.sent = 0
        self.timer: TickTimer | None = None
        self.settled_ns = 0  # heartbeats from then on must say OPERATIONAL
        self.due: Counter[str] = Counter()  # node frames due (answers to our SYNCs)
        self.not_operational: Counter[str] = Counter()  # heartbeats after START in another state

    def _send(self, spec: MessageSpec, values: Any) -> None:
        self.bus.send(self.tx.message(spec, values))
        self.sent += 1

    def _nmt(self, command: NmtCommand) -> None:
        nmt = self.catalog.by_name("NMT_COMMAND")
        self._send(nmt, nmt.record(command=int(command), node_id=0))

    def _receive(self, timeout_s: float) -> Decoded | None:
        return _receive(self.bus, self.rx, self.monitor, self.clock, timeout_s)

    def wait_for_nodes(self, timeout_s: float) -> None:
        """A heartbeat (in any state) from every node: they are powered and on this bus."""
        deadline = self.clock.now_ns() + int(timeout_s * 1e9)
        while missing := [n for n, seen in self.monitor.nodes.items() if not seen.nmt_states]:
            remaining = (deadline - self.clock.now_ns()) / 1e9
            if remaining <= 0:
                raise BusCheckError(f"no heartbeat from {', '.join(missing)} within {timeout_s:g} s: are the nodes powered and on this bus?")
            self._receive(min(remaining, 0.1))

    def run(self, ticks: int, *, fault_reset: bool) -> dict[str, Any]:
        if fault_reset:
            self._nmt(NmtCommand.FAULT_RESET)
        self._nmt(NmtCommand.START)
        # In real time a heartbeat a node sent just before START reached it may still say
        # PRE_OPERATIONAL (in lock-step the nodes take START before the first SYNC).
        period_ms = max(m.cycle_ms or 0 for m in self.catalog.messages if m.family == "HEARTBEAT")
        self.settled_ns = self.clock.now_ns() + (2 * period_ms * 1_000_000 if self.period_ns else 0)
        self.timer = timer = TickTimer(self.clock, self.period_ns) if self.period_ns else None
        hold = {m.name: m.record(mode=int(JointMode.HOLD), position_setpoint_rad=0.0, velocity_ff_rad_s=0.0,
                                 torque_ff_Nm=0.0, torque_limit_Nm=float(round(self.hold_torque_nm)))
                for m in self.catalog.messages if m.family == "JOINT_COMMAND"}
        try:
            for n in range(ticks):
                tick = timer.wait() if timer else n
                expected = Counter(m.name for m in self.catalog.cyclic_in_tick(tick) if m.sender != CONTROLLER and m.family != "HEARTBEAT")
                self.due.update(expected)
                for spec in self.catalog.cyclic_in_tick(tick, CONTROLLER):
                    if spec.name == "SYNC":
                        self._send(spec, spec.record(tick=tick))
                    elif spec.family == "JOINT_COMMAND":
                        self._send(spec, hold[spec.name])
                    elif spec.family == "CONTROLLER_HEARTBEAT":
                        self._send(spec, spec.record(gait_state=int(GaitState.HOLD)))
                    # the controller's telemetry frames carry nothing a node acts on: not sent
                self._collect(expected, self.clock.now_ns() + int(self.tick_timeout_s * 1e9) if timer is None else timer.deadline_ns(tick + 1))
            self._collect(Counter(), self.clock.now_ns() + 2 * TICK_NS)  # the last tick's answers
        finally:  # also after an error or Ctrl-C: the drives go on holding, and no command watchdog trips
            self._nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
        return self.report(ticks)

    def _collect(self, expected: Counter[str], deadline_ns: int) -> None:
        """Receive until the tick's expected frames came (lock-step) or the deadline passed."""
        while True:
            remaining = (deadline_ns - self.clock.now_ns()) / 1e9
            if remaining <= 0 or (self.period_ns is None and not +expected):
                return
            decoded = self._receive(remaining)
            if decoded is None:
                continue
            spec = decoded.message
            expected[spec.name] -= 1
            if (spec.family == "HEARTBEAT" and decoded.values.nmt_state != NmtState.OPERATIONAL
                    and self.clock.now_ns() >= self.settled_ns):
                self.not_operational[spec.sender] += 1

    @property
    def overruns(self) -> int:
        """Real time: ticks skipped because this side ran late (their SYNCs never went out)."""
        return self.timer.skipped if self.timer else 0

    def report(self, ticks: int) -> dict[str, Any]:
        got = {name: seen.frames for name, seen in self.monitor.messages.items()}
        missing = {name: n - got.get(name, 0) for name, n in sorted(self.due.items()) if n > got.get(name, 0)}
        out: dict[str, Any] = {"mode": "hold", "ticks": ticks, "frames_sent": self.sent, "missing_frames": missing,
                               "overruns": self.overruns, **self.monitor.report(self.rx)}
        problems = self.monitor.problems(self.rx)
        if missing:
            problems.append(f"node frames missing: {missing}")
        for name, node in self.monitor.nodes.items():
            other = {k: n for k, n in node.drive_states.items() if k != DriveState.HOLD.name}
            if other:
                problems.append(f"{name}: drive not in HOLD {other}")
            if not node.drive_states:
                problems.append(f"{name}: no status frame")
        for name, n in self.not_operational.items():
            problems.append(f"{name}: {n} heartbeats not OPERATIONAL after START")
        out["problems"] = problems
        out["ok"] = not problems
        return out


def hold_check(bus: can.BusABC, cfg: Config, clock: Clock, *, ticks: int, lockstep: bool, tick_timeout_s: float,
               handshake_timeout_s: float, fault_reset: bool) -> dict[str, Any]:
    """The HOLD check on an open bus (the nodes may boot after it opened: their boot-ups count)."""
    check = HoldCheck(
        bus, Codec(), clock, max_delta_counter=cfg.protocol.max_delta_counter,
        hold_torque_nm=cfg.controller.safety.hold_torque_nm,
        period_ns=None if lockstep else TICK_NS, tick_timeout_s=tick_timeout_s,
    )
    check.wait_for_nodes(handshake_timeout_s)
    result = check.run(ticks, fault_reset=fault_reset)
    return {"bus": {"interface": cfg.bus.interface, "channel": cfg.bus.channel},
            "timing": "lockstep" if lockstep else f"real time, {TICK_MS} ms ticks", **result}


def run_hold(cfg: Config, clock: Clock, **options: Any) -> dict[str, Any]:
    """:func:`hold_check` on the configured bus."""
    with open_bus(cfg.bus) as bus:
        return hold_check(bus, cfg, clock, **options)
