"""The four node boards that drive the simulated HHEA over CAN, in one process.

The host owns the bus connection and four :class:`~nodes.firmware.NodeFirmware`; what they drive
and measure is the simulation's :class:`~sim.plant.Plant` (the PyBullet world and the patient
inside it), which the host ticks. It speaks only CAN through :mod:`protocol`:

* every received frame goes through one :class:`~protocol.e2e.Receiver` (CRC, counter and length
  errors are counted and ignored), then to the firmware it concerns: NMT commands, joint
  commands, the controller's heartbeat (whose gait state also tells the patient when to walk);
* per SYNC each node applies its newest valid command to its joint through the simulation's
  actuation interface, and sends its status and the sensors it carries, with alive counters and
  CRCs, as the DBC assigns them (the left hip board carries the trunk IMU and the left stick, the
  knee boards the plantar sensors);
* timing: in lock-step each SYNC first advances the physics by exactly one 20 ms tick, so a run
  is deterministic and as fast as the CPU allows; in real time the physics is paced by the clock
  (one tick per 20 ms, re-aligned after an overrun, never caught up in a burst) and a SYNC samples
  the newest state. The boards' cycle is synchronised to the SYNC, as a CiA 402 drive in a cyclic
  synchronous mode locks its control cycle to it: the physics tick runs half a period after each
  SYNC (:data:`SYNC_PHASE_NS`), so a SYNC never waits for a physics tick in progress. Without it
  the two processes' phases were whatever their start times made them; where a physics tick
  takes a third of the period (the vcan sandbox: 6 ms), a SYNC that came at a tick's start was
  answered after the controller's 8 ms read window, three times in a row a lost node.

Heartbeats follow the node's time: the SYNC tick in lock-step, its own timer in real time.

A crashed controller sends no SYNC again. Real boards notice that on their own clock; lock-step
boards, whose clock is the SYNC, would wait for ever. With ``silence_s`` (``aider-exo nodes
--lockstep --silence S``) a controller silent that long in wall time is taken as gone: from the
last SYNC's tick on the boards run on their own 20 ms timer (watchdogs, physics, heartbeats, as
in real time) until a SYNC comes again and leads once more. Off by default: a lock-step run whose
controller is only slow must stay deterministic.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import can
import numpy as np

from config import Config
from config.errors import AiderError
from nodes.faults import FaultInjector
from nodes.firmware import ERR_CURRENT, ERR_GENERIC, JointLimits, NodeFirmware
from protocol.bus import send_of
from protocol.catalog import MessageSpec
from protocol.clock import MAX_STALLS, STALL_NS, TICK_MS, TICK_NS, Clock, MonotonicClock
from protocol.codec import Codec, Decoded
from protocol.commands import JointCommand
from protocol.e2e import Receiver, Transmitter
from protocol.enums import WALKING, DriveState, EmcyCode, GaitState, NmtCommand, NmtState, NodeError
from protocol.errors import EncodeError
from sim.model import EXO_JOINTS
from sim.plant import Plant

RX_PER_TICK = 200  # real time: queued frames handled before a tick, at most (the controller's own bound)
SYNC_PHASE_NS = TICK_NS // 2  # real time: the physics tick this long after a SYNC (see the module doc)
SYNC_PULL = 8  # once locked, a SYNC corrects the phase by 1/8 of its error (a SYNC read late moves it little)
#: gait states in which the patient walks (moves the sticks and leans); otherwise the patient stands


_NMT_SHORT = {"BOOT_UP": "boot", "PRE_OPERATIONAL": "preop", "OPERATIONAL": "op", "STOPPED": "stopped"}


class NodesError(AiderError):
    """The nodes process cannot run (no simulation section, bad fault configuration)."""


@dataclass
class NodePort:
    """One node board's identity on the bus and its firmware."""

    name: str
    node_id: int
    joint: int  # index into the exoskeleton's joints (sim.model.EXO_JOINTS)
    side: int  # 0 left, 1 right
    firmware: NodeFirmware
    tx: Transmitter
    heartbeat: MessageSpec
    emcy: MessageSpec
    cyclic: tuple[MessageSpec, ...]  # status and sensors, sent per SYNC when operational
    stale: dict[int, bytes] = field(default_factory=dict)  # last payload per frame ID (a frozen node re-sends it)
    stuck_position: float | None = None


@dataclass
class HostStats:
    syncs: int = 0
    physics_ticks: int = 0
    overruns: int = 0
    silences: int = 0  # lock-step: times the controller fell silent and the boards took their own clock
    # real time: ticks come to STALL_NS or more late beyond the physics work (protocol.clock): (SYNC tick, ms late)
    stalls: list[tuple[int, float]] = field(default_factory=list)
    frames_sent: int = 0
    send_failures: int = 0
    saturated: Counter[str] = field(default_factory=Counter)  # sensor values clipped to their full scale


class _Lists(NamedTuple):
    """The arrays of a :class:`~sim.sensors.Reading` that the nodes report, as lists."""

    joint_position_rad: list[float]
    joint_velocity_rad_s: list[float]
    joint_torque_nm: list[float]
    stick_force_n: list[float]
    stick_rpy_rad: list[list[float]]
    trunk_rpy_rad: list[float]
    trunk_rate_rad_s: list[float]
    trunk_specific_force_m_s2: list[float]
    heel_force_n: list[float]
    toe_force_n: list[float]


class NodesHost:
    """The simulation and four node boards on one bus (see the module doc)."""

    def __init__(
        self, cfg: Config, bus: can.BusABC, *, lockstep: bool, seed: int = 0, gui: bool = False,
        clock: Clock | None = None, codec: Codec | None = None, silence_s: float | None = None,
    ) -> None:
        if cfg.sim is None or cfg.nodes is None:
            raise NodesError("the configuration needs a sim and a nodes section to emulate the nodes")
        if silence_s is not None and not (lockstep and silence_s > 0):
            raise NodesError(f"a controller's silence (here {silence_s} s) is watched in lock-step only, and must be positive")
        self.cfg, self.bus, self.lockstep = cfg, bus, lockstep
        self._silence_ns = None if silence_s is None else int(silence_s * 1e9)
        self._bus_send = send_of(bus)  # each frame is made for one send
        self.clock = clock or MonotonicClock()
        self.codec = codec or Codec()
        catalog = self.codec.catalog
        self.rx = Receiver(self.codec, max_delta_counter=cfg.protocol.max_delta_counter)
        self.stats = HostStats()
        seeds = np.random.SeedSequence(seed).spawn(2)
        self.faults = FaultInjector(cfg.nodes.faults, catalog, np.random.default_rng(seeds[1]))
        self.plant = Plant(cfg.sim, np.random.default_rng(seeds[0]), gui=gui)
        joints = cfg.hardware.joints
        self.ports: dict[str, NodePort] = {}
        # The node boards in node-id order drive the exoskeleton's joints in the same order.
        for joint, (node, joint_name) in enumerate(zip(catalog.joint_nodes, EXO_JOINTS, strict=True)):
            spec = joints.hip if joint_name.startswith("hip") else joints.knee
            limits = JointLimits(spec.lower_rad, spec.upper_rad, spec.velocity_limit_rad_s, spec.torque_limit_nm)
            sent = catalog.sent_by(node)
            self.ports[node] = NodePort(
                name=node,
                node_id=catalog.node_ids[node],
                joint=joint,
                side=0 if joint_name.endswith("_l") else 1,
                firmware=NodeFirmware(
                    node, limits, command_timeout_ticks=cfg.nodes.command_timeout_ticks,
                    heartbeat_timeout_ms=cfg.nodes.heartbeat_timeout_ms,
                ),
                tx=Transmitter(self.codec),
                heartbeat=next(m for m in sent if m.family == "HEARTBEAT"),
                emcy=next(m for m in sent if m.family == "EMCY"),
                cyclic=tuple(m for m in sent if m.is_cyclic and m.family != "HEARTBEAT"),
            )
        self._port_of_command = {
            m.frame_id: self.ports[m.receivers[0]] for m in catalog.messages if m.family == "JOINT_COMMAND"
        }
        self._by_id = {p.node_id: p for p in self.ports.values()}
        self._scale_cache: dict[int, tuple[tuple[float, float, str] | None, ...]] = {}  # constant per message (the DBC)
        self._lists_of: Any = None  # the reading :meth:`_reading_lists` last converted
        self._lists: _Lists | None = None
        self.start_ns = self.clock.now_ns()
        self.own_tick = -1  # real time, or lock-step on the boards' own clock: the node's own tick counter
        self.own_clock = not lockstep  # the boards' own timer ticks them (lock-step: after a silent controller)
        self._last_sync_ns: int | None = None
        self.phase_ns = 0  # real time: the tick schedule's shift that locks it to the SYNC
        self._physics_end_ns = 0  # real time: when the last physics tick ended
        self.sync_locked = False
        self.last_sync_tick = -1
        self.gait_state: GaitState | None = None
        self.on_sync_hook: Callable[[int], None] | None = None  # after each SYNC's reports (recording the ground truth)

    # -- lifecycle -------------------------------------------------------------------------------

    def close(self) -> None:
        self.plant.close()

    def now_ms(self) -> float:
        return (self.clock.now_ns() - self.start_ns) / 1e6

    def _node_time_ms(self, tick: int) -> float:
        return tick * TICK_MS if self.lockstep else self.now_ms()

    def _watch_silence(self, now: int) -> int | None:
        """Lock-step with ``silence_s``: take the boards' own clock once the controller has been
        silent that long (their next tick is the last SYNC's tick + 1, due now). Returns when to look
        again, or None."""
        if self.own_clock or self._silence_ns is None or self._last_sync_ns is None:
            return None
        due = self._last_sync_ns + self._silence_ns
        if now < due:
            return due
        self.own_clock = True
        self.stats.silences += 1
        self.own_tick = self.last_sync_tick
        self.phase_ns += now - self._next_tick_ns()
        self._physics_end_ns = now
        return None

    def boot(self) -> None:
        """Power-on: the boards' time and tick schedule start now (not at construction: the
        real-time set-up between the two took 0.3-1.6 s in the vcan sandbox, which the first tick
        reported as a stall), and every node sends its boot-up message."""
        self.start_ns = self.clock.now_ns()
        for port in self.ports.values():
            self._emit(port, 0)

    def _emit(self, port: NodePort, tick: int) -> None:
        """Send what the firmware has for the bus outside the per-SYNC frames: its boot-up after a
        (re)boot, with counters from 0 and nothing stale kept, then its queued EMCYs."""
        fw = port.firmware
        if fw.boot_up_pending:
            fw.boot_up_pending = False
            port.tx.reset()
            port.stale.clear()
            port.stuck_position = None
            self._send_heartbeat(port, NmtState.BOOT_UP, tick)
        while fw.emcy:
            e = fw.emcy.pop(0)
            self._send(port, port.emcy, (int(e.code), e.error_register, e.detail), tick)

    # -- receive ---------------------------------------------------------------------------------

    def handle(self, msg: can.Message) -> None:
        """One received frame (any frame: foreign, corrupt or our own are counted and ignored)."""
        result = self.rx.receive(msg)
        if type(result) is not Decoded:
            return
        spec, values = result.message, result.values
        family = spec.family
        if family == "SYNC":
            self.on_sync(values.tick)
        elif family == "JOINT_COMMAND":
            port = self._port_of_command[spec.frame_id]
            if not self.faults.frozen(port.name, self.last_sync_tick + 1):
                port.firmware.on_command(*values)
        elif family == "CONTROLLER_HEARTBEAT":
            now = self._node_time_ms(self.last_sync_tick)
            for port in self.ports.values():
                port.firmware.on_controller_heartbeat(now)
            self.gait_state = GaitState(values.gait_state)
            self.plant.walking = self.gait_state in WALKING
        elif family == "NMT_COMMAND":
            targets = self.ports.values() if values.node_id == 0 else [self._by_id.get(values.node_id)]
            now = self._node_time_ms(self.last_sync_tick)
            for port in targets:
                if port is None:
                    continue  # addressed to a node we do not emulate
                port.firmware.on_nmt(NmtCommand(values.command), now)
                self._emit(port, max(self.last_sync_tick, 0))

    # -- the tick --------------------------------------------------------------------------------

    def on_sync(self, tick: int) -> None:
        """A SYNC: apply commands; in lock-step advance the physics one tick; report."""
        self.stats.syncs += 1
        self.last_sync_tick = tick
        if self.lockstep:
            self.own_clock = False  # a SYNC (again): it leads
            self._last_sync_ns = self.clock.now_ns()
        for port in self.ports.values():
            if self.faults.starting(port.name, "reboot", tick):
                port.firmware.boot()
                self._emit(port, tick)
            if self.faults.starting(port.name, "drive_fault", tick):
                port.firmware.raise_fault(NodeError.OVER_CURRENT, EmcyCode.OVER_CURRENT, ERR_GENERIC | ERR_CURRENT, 0)
            if self.faults.frozen(port.name, tick):
                continue  # a frozen application neither watches nor applies commands
            if self.lockstep:
                port.firmware.on_tick(tick * TICK_MS)
            self._apply(port, port.firmware.on_sync())
        if self.lockstep:
            self._physics_tick()
            self._heartbeats(tick)
        else:
            self._lock_to_sync(self.clock.now_ns())
        self._report(tick)
        if self.on_sync_hook is not None:
            self.on_sync_hook(tick)

    def _next_tick_ns(self) -> int:
        return self.start_ns + self.phase_ns + (self.own_tick + 1) * TICK_NS

    def _lock_to_sync(self, sync_ns: int) -> None:
        """Real time: move the tick schedule toward its next tick ``SYNC_PHASE_NS`` after a SYNC
        seen at ``sync_ns``: at once the first time, then by 1/``SYNC_PULL`` of the error. The node's
        time (watchdogs, heartbeats) is not moved."""
        error = (sync_ns + SYNC_PHASE_NS - self._next_tick_ns()) % TICK_NS
        if error > TICK_NS // 2:
            error -= TICK_NS  # the shortest way: a tick earlier or later by at most half a period
        self.phase_ns += error if not self.sync_locked else int(error / SYNC_PULL)
        self.sync_locked = True

    def on_timer(self) -> None:
        """The nodes' own 20 ms tick (physics, watchdogs, heartbeats): real time, or lock-step boards
        whose controller fell silent."""
        self.own_tick += 1
        now = self._node_time_ms(self.own_tick)
        for port in self.ports.values():
            if not self.faults.frozen(port.name, self.last_sync_tick):
                port.firmware.on_tick(now)
                self._apply(port, port.firmware.drive_command())
        self._physics_tick()
        self._heartbeats(self.own_tick)
        for port in self.ports.values():
            self._emit(port, self.own_tick)

    def _physics_tick(self) -> None:
        # a fall's tick is the controller's last SYNC (in real time the nodes may run on after the
        # controller has stopped sending them)
        self.plant.tick(self.last_sync_tick)
        self.stats.physics_ticks += 1

    def _apply(self, port: NodePort, cmd: JointCommand) -> None:
        self.plant.drive(port.joint, cmd)

    # -- transmit --------------------------------------------------------------------------------

    def _heartbeats(self, tick: int) -> None:
        for port in self.ports.values():
            if not port.heartbeat.sent_in_tick(tick):
                continue
            if self.faults.frozen(port.name, max(self.last_sync_tick, 0)):
                stale = port.stale.get(port.heartbeat.frame_id)
                if stale is not None:  # a frozen application's heartbeat: the same bytes again
                    self._transmit(port.heartbeat, stale)
                continue
            self._send_heartbeat(port, port.firmware.state, tick)

    def _send_heartbeat(self, port: NodePort, state: NmtState, tick: int) -> None:
        """The board's heartbeat: its NMT state and the supply voltage it measures (the nominal,
        less an injected ramp; never below 0)."""
        supply_v = max(0.0, self.cfg.nodes.supply_voltage_v - self.faults.supply_drop_v(port.name, tick))
        self._send(port, port.heartbeat, (int(state), supply_v), tick)

    def _report(self, tick: int) -> None:
        for spec, payload in self.faults.due(tick):
            self._transmit(spec, payload)
        for port in self.ports.values():
            if self.faults.frozen(port.name, tick):
                for spec in port.cyclic:  # the same bytes again: counters and CRCs of the last frames
                    if spec.frame_id in port.stale and port.firmware.state == NmtState.OPERATIONAL:
                        self._transmit(spec, port.stale[spec.frame_id])
                continue
            self._emit(port, tick)
            if port.firmware.state != NmtState.OPERATIONAL:
                continue
            stuck = self.faults.stuck_encoder(port.name, tick)
            if stuck and port.stuck_position is None:
                port.stuck_position = float(self.plant.reading.joint_position_rad[port.joint])
            elif not stuck:
                port.stuck_position = None
            for spec in port.cyclic:
                self._send(port, spec, self._values(port, spec), tick)

    def _values(self, port: NodePort, spec: MessageSpec) -> tuple[Any, ...]:
        """The sensor values of one cyclic message, as Python numbers (the encoder's fast path)."""
        r, j, side = self._reading_lists(), port.joint, port.side
        family = spec.family
        if family == "JOINT_STATUS":
            fw = port.firmware
            q = r.joint_position_rad[j] if port.stuck_position is None else port.stuck_position
            return (int(fw.drive_state), int(fw.error), q, r.joint_velocity_rad_s[j], r.joint_torque_nm[j])
        if family == "STICK":
            return (r.stick_force_n[side], *r.stick_rpy_rad[side])
        if family == "PLANTAR":
            return (r.heel_force_n[side], r.toe_force_n[side])
        if family == "TRUNK_IMU_ORIENTATION":
            return tuple(r.trunk_rpy_rad)
        if family == "TRUNK_IMU_RATE":
            return tuple(r.trunk_rate_rad_s)
        if family == "TRUNK_IMU_ACCEL":
            return tuple(r.trunk_specific_force_m_s2)
        raise NodesError(f"{spec.name}: no sensor source for message family {family}")

    def _reading_lists(self) -> _Lists:
        """This tick's reading with its arrays as lists of Python floats, made once per reading:
        the encoder is three times slower on numpy scalars than on floats (measured)."""
        if self._lists_of is not self.plant.reading:
            r = self.plant.reading
            self._lists = _Lists(*(getattr(r, name).tolist() for name in _Lists._fields))
            self._lists_of = r
        return self._lists

    def _saturated(self, spec: MessageSpec, values: tuple[Any, ...]) -> tuple[Any, ...]:
        """``values`` with each beyond its signal's full scale clamped to it, counted (the sensor
        saturates); enumerations and non-finite values are left for the encoder to refuse."""
        out = []
        for scale, value in zip(self._scales(spec), values):
            if scale is not None:
                lo, hi, key = scale
                value = float(value)
                if not lo <= value <= hi:
                    self.stats.saturated[key] += 1
                    value = min(max(value, lo), hi)
            out.append(value)
        return tuple(out)

    def _scales(self, spec: MessageSpec) -> tuple[tuple[float, float, str] | None, ...]:
        """Per signal of ``spec``: its full scale and saturation counter key, None for an enumeration."""
        scales = self._scale_cache.get(spec.frame_id)
        if scales is None:
            scales = tuple(None if sig.choices is not None else (sig.minimum, sig.maximum, f"{spec.name}.{sig.name}")
                           for sig in spec.signals)
            self._scale_cache[spec.frame_id] = scales
        return scales

    def _send(self, port: NodePort, spec: MessageSpec, values: tuple[Any, ...], tick: int) -> None:
        try:
            payload = port.tx.payload(spec, values)  # in range: the common case, checked by the encoder
        except EncodeError:
            try:
                payload = port.tx.payload(spec, self._saturated(spec, values))
            except EncodeError as exc:  # a non-finite sensor value: the frame is not sent (the controller sees it missing)
                self.stats.saturated[f"{spec.name}: {exc}"] += 1
                return
        port.stale[spec.frame_id] = payload
        for data in self.faults.outgoing(port.name, spec, payload, tick):
            self._transmit(spec, data)

    def _transmit(self, spec: MessageSpec, data: bytes) -> None:
        try:
            self._bus_send(can.Message(arbitration_id=spec.frame_id, data=data, is_extended_id=False, check=False))
            self.stats.frames_sent += 1
        except can.CanError:
            self.stats.send_failures += 1

    # -- the loop --------------------------------------------------------------------------------

    def poll(self, timeout_s: float) -> bool:
        """Handle every frame that arrives within ``timeout_s`` (then whatever is queued); real time
        (or a silent controller's lock-step boards) also runs the nodes' timer. Returns whether a
        frame was handled."""
        handled = False
        deadline = self.clock.now_ns() + int(timeout_s * 1e9)
        while True:
            now = self.clock.now_ns()
            wait_until = deadline
            if (look_again := self._watch_silence(now)) is not None:
                wait_until = min(deadline, look_again)
            if self.own_clock:
                next_tick = self._next_tick_ns()
                if now >= next_tick:
                    stalled_ns = now - max(next_tick, self._physics_end_ns)
                    if stalled_ns >= STALL_NS and len(self.stats.stalls) < MAX_STALLS:
                        self.stats.stalls.append((self.last_sync_tick, round(stalled_ns / 1e6, 1)))
                    # A board's CAN receive is interrupt-driven: what arrived while the last tick
                    # ran is seen before the next one, even when the physics overruns every tick.
                    handled |= self._drain_queued()
                    late_ticks = (now - next_tick) // TICK_NS
                    if late_ticks:  # overrun: re-align to the next boundary, no burst of late ticks
                        self.stats.overruns += 1
                        self.own_tick += int(late_ticks)
                    self.on_timer()
                    self._physics_end_ns = self.clock.now_ns()
                    if self._physics_end_ns >= deadline:
                        return handled  # ticks that overrun every time still return to the caller
                    continue
                wait_until = min(deadline, next_tick)
            msg = self.bus.recv(timeout=max(0.0, (wait_until - now) / 1e9))
            if msg is not None:
                self.handle(msg)
                handled = True
                continue
            if self.clock.now_ns() >= deadline:
                return handled

    def _drain_queued(self) -> bool:
        """Handle the frames already queued, at most ``RX_PER_TICK`` (a flood cannot stop the tick)."""
        for n in range(RX_PER_TICK):
            msg = self.bus.recv(timeout=0.0)
            if msg is None:
                return n > 0
            self.handle(msg)
        return True

    def status(self) -> dict[str, Any]:
        """Machine-readable state (the one-line status is made from it)."""
        patient = self.plant.patient
        return {
            "mode": "lockstep" if self.lockstep else "realtime",
            "sim_mode": self.cfg.sim.mode if self.cfg.sim else None,
            "sim_time_s": round(patient.t, 3),
            "last_sync_tick": self.last_sync_tick,
            "nodes": {
                p.name: {
                    "nmt": NmtState(p.firmware.state).name,
                    "drive": DriveState(p.firmware.drive_state).name,
                    "error": p.firmware.error.name,
                    "clamped": p.firmware.clamped,
                    "ignored": p.firmware.ignored,
                    "boots": p.firmware.boots,
                }
                for p in self.ports.values()
            },
            "frames_sent": self.stats.frames_sent,
            "send_failures": self.stats.send_failures,
            "syncs": self.stats.syncs,
            "physics_ticks": self.stats.physics_ticks,
            "overruns": self.stats.overruns,
            "silences": self.stats.silences,
            "own_clock": self.own_clock,
            "stalls": [list(x) for x in self.stats.stalls],
            "receiver": self.rx.stats.as_dict(),
            "faults_injected": dict(self.faults.counts),
            "sensor_saturations": dict(self.stats.saturated),
            "fall": patient.fall,
            "fall_at": self.plant.fall_at,
            "patient": patient.patient_state(),
        }

    def truth(self) -> dict[str, Any]:
        """The simulation's ground truth now (tests, experiments and the walk's report; never
        sent on the bus): X_CoM/X_SP by the estimator's contact thresholds of the ``controller``
        section (nan without one), and the fall criterion."""
        body = self.cfg.controller.body if self.cfg.controller is not None else None
        return {"tick": self.last_sync_tick, **self.plant.truth(body)}

    def status_line(self) -> str:
        s = self.status()
        nodes = " ".join(
            f"{n[0]}{n.split('_')[1][0]}:{_NMT_SHORT[v['nmt']]}/{v['drive']}" + (f"!{v['error']}" if v["error"] != "NONE" else "")
            for n, v in s["nodes"].items()
        )
        rx = s["receiver"]
        mode = f"{s['mode']} (own clock)" if self.lockstep and self.own_clock else s["mode"]
        return (
            f"nodes {mode} tick {s['last_sync_tick']} sim {s['sim_time_s']:.1f} s | {nodes} | "
            f"rx {rx['accepted']} ok {rx['rejected']} rejected | tx {s['frames_sent']}"
            + (f" | fall: {s['fall']}" if s["fall"] else "")
        )



@contextmanager
def running_in_thread(host: NodesHost, poll_s: float = 0.05) -> Iterator[NodesHost]:
    """Boot ``host`` and run it in a background thread until the block ends: real-time nodes in
    the same process as their peer (tests and benchmarks; a deployment runs them as a process)."""
    done = threading.Event()

    def loop() -> None:
        host.boot()
        while not done.is_set():
            host.poll(poll_s)

    thread = threading.Thread(target=loop, name="nodes", daemon=True)
    thread.start()
    try:
        yield host
    finally:
        done.set()
        thread.join(timeout=30)
