"""The CAN system without I/O: the nodes' frames in, a typed :class:`~controller.interfaces.Snapshot`
out, and the frames of a tick's :class:`~controller.interfaces.Commands`.

:class:`CanSystem` takes the frames the nodes sent in a tick (decoded and end-to-end checked by
:class:`protocol.e2e.Receiver`) and keeps what the controller knows of each node: its NMT state
from its heartbeat, its newest joint status and sensor values with the tick each was sent for
(from the alive counters, so a late frame is not taken for this tick's), its supply voltage. Once
a tick's frames are in, :meth:`CanSystem.snapshot` supervises the nodes and the bus (docs/FAULTS.md:
a lost node or sensor F1, frame integrity F6-F8, failed sends F12-F13, a measured joint beyond its
range F16, a reboot or a node leaving OPERATIONAL F23, a drive fault or EMCY F24) and returns the
tick's measurements with the faults it found. :meth:`CanSystem.frames` turns the core's commands
into the tick's frames: the NMT start once every node has booted, the operator's FAULT_RESET, the
four joint commands, then the controller's heartbeat and telemetry on the DBC's schedule.

Every message and signal name of the controller lives here and in :mod:`controller.hardware`;
the core sees none (a layout test).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from config.controller_schema import ControllerConfig
from controller.estimator import Measurements
from controller.faults import Fault, FaultKind
from controller.interfaces import Commands, Snapshot
from protocol.catalog import COUNTER_MODULO, Catalog, default_catalog
from protocol.codec import Decoded, RejectReason, Rejection
from protocol.enums import DriveState, NmtCommand, NmtState

# repeated counter (a duplicate, F5, or a frozen node, F9), a wrong length or a value out of the
# DBC's range (F10, F15): the frame counts as missing, and the lost-node supervision handles a node
# whose frames stay missing.
INTEGRITY_REASONS = frozenset({RejectReason.BAD_CRC, RejectReason.WRONG_SEQUENCE})

MAX_AGE = 8  # a counter more than this many SYNCs behind is taken as a new sequence, not as late

SENSOR_MESSAGES = (
    "STICK_LEFT", "STICK_RIGHT", "PLANTAR_LEFT", "PLANTAR_RIGHT", "TRUNK_IMU_ORIENTATION", "TRUNK_IMU_RATE",
)


@dataclass
class BusCounters:
    timeouts: int = 0  # ticks whose node frames were not all in by the read's deadline
    frames_sent: int = 0
    send_failures: int = 0  # failed sends (each retried once)
    drained_max: int = 0  # most frames read in one tick


@dataclass
class NodeState:
    nmt: NmtState | None = None  # from its heartbeat (None: never heard)
    status: Any = None  # the newest JOINT_STATUS values
    status_tick: int = -1  # the tick it arrived in
    operational_since: int = -1  # the tick its heartbeat first said OPERATIONAL (-1: never)
    supply_v: float | None = None  # the supply voltage of its newest heartbeat

    @property
    def was_operational(self) -> bool:
        return self.operational_since >= 0




class CanSystem:
    """The nodes and the bus as the controller knows them (see the module doc)."""

    def __init__(self, cfg: ControllerConfig, *, catalog: Catalog | None = None) -> None:
        catalog = catalog or default_catalog()
        self.catalog = catalog
        self.node_names = catalog.joint_nodes  # left hip, left knee, right hip, right knee
        self._command_of = {n: catalog.message("JOINT_COMMAND", n).name for n in self.node_names}
        self._scheduled = [catalog.by_name(n) for n in ("CONTROLLER_HEARTBEAT", "CONTROLLER_STEP", "CONTROLLER_LEARNING")]
        self.safety = safety = cfg.safety
        joints, excess = cfg.hardware.joints, cfg.envelope.position_excess_rad  # a measured angle this far beyond a limit is a fault
        self._measured_range = {n: (j.lower_rad - excess, j.upper_rad + excess)
                                for n, j in zip(self.node_names, (joints.hip, joints.knee) * 2)}
        self.lost_ticks = safety.lost_ticks
        self.nodes = {n: NodeState() for n in self.node_names}
        # what each node sends per SYNC (the cyclic frames but the heartbeat); a tick's read waits for them too
        self.per_sync = {n: tuple(m.frame_id for m in catalog.sent_by(n) if m.is_cyclic and m.family != "HEARTBEAT")
                         for n in self.node_names}
        self._sensor_sender = {name: catalog.by_name(name).sender for name in SENSOR_MESSAGES}
        self.latest: dict[str, tuple[int, Any]] = {}  # sensor message -> (tick it was sent for, values)
        self.syncs = 0  # SYNCs of finished ticks: the index of this tick's SYNC
        self._phase: dict[int, int] = {}  # per-SYNC frame ID -> (SYNC index - counter) mod 16 of an on-time frame
        self._late_now: dict[int, int] = {}  # per-SYNC frame ID -> its age, of this tick's late frames
        self._shift = (0, 0)  # (a uniform lateness of every node's frames, for how many ticks in a row)
        self.started = False  # the NMT start sent
        self._start_now = False  # the NMT start due in this tick's frames
        self._faults: list[Fault] = []  # found since the last snapshot
        self._lost: set[str] = set()  # the nodes lost (F1) at the last snapshot
        self._integrity: deque[tuple[int, str]] = deque()  # (tick, reason) of the nodes' damaged frames
        self._error_frame_tick = -(10**9)  # the last error frame's tick
        self._failed_sends: deque[int] = deque(maxlen=safety.send_failure_ticks)  # ticks with a failed send
        self.counters = BusCounters()

    def operational_nodes(self) -> set[str]:
        """The nodes whose heartbeat says OPERATIONAL and that were not lost at the last tick: a
        tick's read waits for their frames (for a lost node's, which may never come, a lock-step
        tick would wait out its whole timeout every tick; its frames are read when they come)."""
        return {n for n, s in self.nodes.items() if s.nmt == NmtState.OPERATIONAL and n not in self._lost}

    # -- the frames in ------------------------------------------------------------------------------

    def _age(self, frame_id: int, counter: int, queued: bool = False) -> int:
        """How many SYNCs late a per-SYNC frame is, from its alive counter (docs/FAULTS.md F4, I5).

        A node sends each of its per-SYNC frames once per SYNC with the next counter, so an on-time
        frame keeps (SYNC index - counter) mod 16 constant; a lost frame keeps it too (both advance),
        a frame that comes late raises it by its lateness. The smallest value seen is the on-time one.

        A ``queued`` frame was already waiting when this tick's SYNC went out, so it answers an
        earlier SYNC: at least one tick late whatever its counter says. If the counter says on
        time, the on-time value was learnt from a late frame (a node's first frame that came after
        its tick's read, or a delay of every node taken for a missed SYNC) and is learnt again from
        this one (else its later answers, read before the tick's own, count as on time while a tick
        old, for the rest of the walk: docs/CONTROLLER.md). A late answer that came before the next
        SYNC is no sign of a missed SYNC (:meth:`_missed_sync`)."""
        lag = (self.syncs - counter) % COUNTER_MODULO
        base = self._phase.get(frame_id)
        age = MAX_AGE + 1 if base is None else (lag - base) % COUNTER_MODULO
        if age > MAX_AGE or (queued and age == 0):
            least = 1 if queued else 0  # the least lateness it can have
            self._phase[frame_id] = (lag - least) % COUNTER_MODULO
            return least
        if age and not queued:
            self._late_now[frame_id] = age
        return age

    def _missed_sync(self, tick: int) -> None:
        """A SYNC the nodes did not see (lost on the bus, or its send failed) shifts the counters of
        every node's frames alike: all of this tick's per-SYNC frames, of every operational node,
        late by the same ``a`` ticks, as in the tick before. One node's frames coming late do not
        (F4); a uniform delay of every node is indistinguishable from it without a SYNC echo in the
        frames (docs/SAFETY.md). The frames are then this tick's: their phase moves by ``a``."""
        late = self._late_now
        if not late:
            self._shift = (0, 0)
            return  # every frame of this tick on time (the common case)
        self._late_now = {}
        expected = [fid for name, node in self.nodes.items() if node.nmt == NmtState.OPERATIONAL for fid in self.per_sync[name]]
        ages = {late.get(fid) for fid in expected}  # None: on time or missing
        shift = ages.pop() if len(ages) == 1 and expected else None
        if shift is None:
            self._shift = (0, 0)
            return
        ticks = self._shift[1] + 1 if self._shift[0] == shift else 1
        self._shift = (shift, ticks)
        if ticks < 2:
            return
        self._shift = (0, 0)
        for fid in expected:
            self._phase[fid] = (self._phase[fid] + shift) % COUNTER_MODULO
        for node in self.nodes.values():
            if node.status_tick == tick - shift:
                node.status_tick = tick
        for name, (sent, values) in list(self.latest.items()):
            if sent == tick - shift:
                self.latest[name] = (tick, values)

    def receive(self, frame: Decoded, tick: int, queued: bool = False) -> bool:
        """One accepted frame from a node, received during ``tick`` (``queued``: read before the
        tick's SYNC went out). A per-SYNC frame (status and sensors) counts for the tick it was sent
        for, which a late frame is not (:meth:`_age`). Returns False for a late per-SYNC frame (the
        loop goes on waiting for this tick's)."""
        spec, v = frame.message, frame.values
        family, sender = spec.family, spec.sender
        if family == "JOINT_STATUS":
            node = self.nodes[sender]
            sent = tick - self._age(spec.frame_id, frame.counter, queued)
            if sent > node.status_tick:  # never an older sample over a newer one
                node.status, node.status_tick = v, sent
            return sent == tick
        elif family == "HEARTBEAT":
            node = self.nodes[sender]
            state = NmtState(v.nmt_state)
            if state != NmtState.OPERATIONAL:
                for m in self.per_sync[sender]:  # a rebooted node's counters start again
                    self._phase.pop(m, None)
            if state == NmtState.BOOT_UP:
                if node.was_operational:
                    self._faults.append(Fault(FaultKind.NODE_REBOOTED, sender))
            elif node.was_operational and state != NmtState.OPERATIONAL:
                self._faults.append(Fault(FaultKind.NODE_NOT_OPERATIONAL, sender))
            node.nmt, node.supply_v = state, v.supply_voltage_V
            if state == NmtState.OPERATIONAL and not node.was_operational:
                node.operational_since = tick
        elif family == "EMCY":
            if v.error_register != 0:
                self._faults.append(Fault(FaultKind.EMCY, sender, f"{v.emcy_code:#06x}"))
        else:
            sent = tick - self._age(spec.frame_id, frame.counter, queued)
            if sent > self.latest.get(spec.name, (-(10**9),))[0]:
                self.latest[spec.name] = (sent, v)
            return sent == tick
        return True

    def accept(self, result: Decoded | Rejection, tick: int, queued: bool = False) -> bool:
        """One frame as the receiver judged it, read during ``tick``: a rejection is counted
        (:meth:`rejected`), the controller's own frames (a bus that echoes them) are passed over,
        a node's goes to :meth:`receive`. Returns True for a node's per-SYNC frame of this tick."""
        if type(result) is not Decoded:
            self.rejected(result, tick)
            return False
        return result.message.sender != "CONTROLLER" and self.receive(result, tick, queued)

    def rejected(self, rejection: Rejection, tick: int) -> None:
        """A frame the receiver rejected during ``tick`` (foreign frames only count as such)."""
        reason = rejection.reason
        if reason == RejectReason.ERROR_FRAME:
            self._error_frame_tick = tick
        elif reason in INTEGRITY_REASONS and rejection.message is not None and rejection.message.sender in self.nodes:
            self._integrity.append((tick, f"{reason.value} {rejection.message.name}"))
            if reason == RejectReason.WRONG_SEQUENCE:  # the receiver re-synchronises on it: so does the age
                self._phase.pop(rejection.frame_id, None)

    def send_failed(self, tick: int) -> None:
        """A frame of ``tick`` could not be sent, even after one retry."""
        if not self._failed_sends or self._failed_sends[-1] != tick:
            self._failed_sends.append(tick)
    # -- the tick's snapshot --------------------------------------------------------------------------

    def _supervise_bus(self, tick: int) -> None:
        """The integrity window and the failed sends (see the module doc)."""
        s = self.safety
        window = self._integrity
        while window and window[0][0] <= tick - s.integrity_window_ticks:
            window.popleft()
        if len(window) >= s.integrity_errors:
            self._faults.append(Fault(FaultKind.FRAME_INTEGRITY, detail=f"{len(window)} in {s.integrity_window_ticks} ticks: {window[-1][1]}"))
            window.clear()
        failed = self._failed_sends
        if len(failed) == failed.maxlen and failed[0] == tick - failed.maxlen:
            self._faults.append(Fault(FaultKind.BUS_SEND_FAILED, detail=f"{failed.maxlen} ticks"))
            failed.clear()

    def _measurements(self, tick: int) -> tuple[Measurements | None, bool]:
        """The tick's sensor values, and whether every one of them is from this tick."""
        latest, nodes = self.latest, self.nodes.values()
        if any(n not in latest for n in SENSOR_MESSAGES) or any(s.status is None for s in nodes):
            return None, False
        sensors = [latest[n] for n in SENSOR_MESSAGES]  # (tick, values) in SENSOR_MESSAGES' order
        fresh = all(t == tick for t, _ in sensors) and all(s.status_tick == tick for s in nodes)
        stick_l, stick_r, plantar_l, plantar_r, o, rate = (v for _, v in sensors)
        q = np.array([s.status.position_rad for s in nodes])
        stick = [stick_l, stick_r]
        plantar = [plantar_l, plantar_r]
        return Measurements(
            joint_position_rad=q,
            trunk_rpy_rad=np.array([o.roll_rad, o.pitch_rad, o.yaw_rad]),
            stick_rpy_rad=np.array([[s.roll_rad, s.pitch_rad, s.yaw_rad] for s in stick]),
            stick_force_n=np.array([s.force_N for s in stick]),
            heel_force_n=np.array([p.heel_force_N for p in plantar]),
            toe_force_n=np.array([p.toe_force_N for p in plantar]),
            trunk_rate_rad_s=np.array([rate.rate_x_rad_s, rate.rate_y_rad_s, rate.rate_z_rad_s]),
        ), fresh

    def snapshot(self, tick: int) -> Snapshot:
        """Supervise the nodes and the bus once ``tick``'s frames are in; the tick's snapshot."""
        events: tuple[str, ...] = ()
        self._missed_sync(tick)
        if not self.started and all(n.nmt is not None for n in self.nodes.values()):  # all booted or heard
            self.started = self._start_now = True
            events = ("NMT start",)
        operational = all(n.nmt == NmtState.OPERATIONAL for n in self.nodes.values())
        ages = [tick - n.status_tick if n.status is not None else 10**9 for n in self.nodes.values()]
        faults, self._lost = self._faults, set()
        for name, node in self.nodes.items():
            if node.was_operational and tick - max(node.status_tick, node.operational_since) >= self.lost_ticks:
                faults.append(Fault(FaultKind.NODE_LOST, name))
                self._lost.add(name)
            if node.status is not None and node.status_tick == tick:
                if node.status.drive_state == DriveState.FAULT:
                    faults.append(Fault(FaultKind.DRIVE_FAULT, name, f"error {node.status.error_code}"))
                lo, hi = self._measured_range[name]
                if not lo <= node.status.position_rad <= hi:  # F16: a joint beyond its range is a fault
                    faults.append(Fault(FaultKind.JOINT_LIMIT, name, f"{node.status.position_rad:.3f} rad"))
        latest = self.latest
        for name, sender in self._sensor_sender.items():  # a sensor frame missing as long as a lost node's status
            node = self.nodes[sender]
            if node.was_operational and tick - max(latest.get(name, (-1,))[0], node.operational_since) >= self.lost_ticks:
                faults.append(Fault(FaultKind.SENSOR_LOST, name))
            elif name in latest:
                ages.append(tick - latest[name][0])
        self._supervise_bus(tick)
        measurements, fresh = self._measurements(tick)
        volts = [n.supply_v for n in self.nodes.values() if n.supply_v is not None]
        self._faults = []
        self.syncs += 1
        return Snapshot(
            tick, measurements, fresh, operational, max(ages), min(volts) if volts else math.inf,
            quiet_bus=tick - self._error_frame_tick >= self.safety.integrity_window_ticks,
            faults=tuple(faults), events=events,
        )

    # -- the frames out ---------------------------------------------------------------------------

    def frames(self, tick: int, commands: Commands) -> list[tuple[str, tuple]]:
        """The frames of ``tick`` after its work, in order: the nodes' start (once), the
        operator's reset, the four joint commands (applied at the next SYNC), then the controller's
        heartbeat and telemetry on the DBC's schedule (monitors read it; no node acts on it)."""
        out: list[tuple[str, tuple]] = []
        if self._start_now:
            out.append(("NMT_COMMAND", (int(NmtCommand.START), 0)))
            self._start_now = False
        if commands.reset:
            out.append(("NMT_COMMAND", (int(NmtCommand.FAULT_RESET), 0)))
        for name, c in zip(self.node_names, commands.joints):
            out.append((self._command_of[name], (int(c.mode), c.position_rad, c.velocity_rad_s, c.torque_nm,
                                                 float(round(c.torque_limit_nm)))))
        heartbeat, step, learning = self._scheduled
        if heartbeat.sent_in_tick(tick):
            out.append((heartbeat.name, (int(commands.state),)))
        if step.sent_in_tick(tick):
            s = commands.step
            out.append((step.name, _within(step, (s.steps, s.length_m, s.placed_m, s.cost_n, int(s.policy)))))
        if learning.sent_in_tick(tick):
            g = commands.learning
            out.append((learning.name, _within(learning, (g.alpha, g.xhat_com, g.updates, g.rollouts_in_batch,
                                                          g.cycles, g.last_cost))))
        return out


def _within(spec: Any, values: tuple) -> tuple:
    """Telemetry values inside their DBC ranges (a value beyond one is shown at its end; not a
    number, 0): a monitor's frame never fails to encode."""
    out = []
    for sig, v in zip(spec.signals, values):
        v = float(v) if math.isfinite(v) else 0.0
        v = min(max(v, sig.minimum), sig.maximum)
        out.append(int(round(v)) if sig.is_integer or sig.choices is not None else v)
    return tuple(out)

