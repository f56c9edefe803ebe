"""The main controller's tick logic at the level of decoded frames, without I/O.

:class:`ControllerCore` takes the frames the nodes sent in a tick (already decoded and E2E-checked
by :class:`protocol.e2e.Receiver`) and returns the frames the controller sends: SYNC at the start
of the tick, then the four joint commands (applied by the nodes at the next SYNC), the
controller's heartbeat with the gait state, and NMT commands. In between it runs the node
supervision (boot-up, NMT state, drive faults, EMCY, lost nodes), the state estimator on the
sensor frames of the tick, and the gait FSM.

It brings the nodes up (NMT start once all four have booted), supervises them, estimates the
state every tick and runs the gait: in DOUBLE_SUPPORT and the swings the legs follow the
:class:`~controller.gait.GaitPlanner` (weight shift, lean, DMP swing), every other state holds them
(HOLD commands). The step length of each swing comes from the :class:`~controller.policy.StepPolicy`
(fixed, compensated, or learning) with X_CoM/X_SP estimated at the swing's start. The budgets are the
configuration's ``controller.safety`` (docs/SAFETY.md lists every row of docs/FAULTS.md). FAULT latches
on a lost node (no status for ``lost_ticks`` ticks), a drive fault or a fault EMCY, a node that
reboots, a command beyond the safety envelope, a fall (trunk tilt beyond ``fall_tilt_rad`` for
``fall_ticks`` ticks, F18), an encoder stuck while its setpoint moves away from it (F14), a measured joint angle beyond its limit by more than the
envelope's ``position_excess_rad`` (F16), a sensor frame missing as long as a lost node's status,
``integrity_errors`` node frames rejected for their CRC or counter
sequence within ``integrity_window_ticks`` (F6-F8), and sends failing in ``send_failure_ticks`` ticks
in a row (F12, F13); overruns (``overrun_limit`` in ``overrun_window_ticks``, or one skipping more
than ``overrun_max_ticks``) make a protective stop, HOLD (F25); an error frame within the
integrity window lets no new step start (F11). An operator reset leaves HOLD or FAULT as the FSM
allows. The loop reports what only it sees: rejected frames (:meth:`rejected`), failed sends
(:meth:`send_failed`) and overruns (:meth:`overran`). Walking starts on
:meth:`ControllerCore.request_walk` (the operator's start) and ends with :meth:`request_stop`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from config.controller_schema import ControllerConfig
from controller.dmp import Dmp, DmpWeights
from controller.envelope import Envelope, JointBounds
from controller.estimator import Estimate, Measurements, StateEstimator
from controller.faults import Fault, FaultKind, Reaction
from controller.factory import balance_gains, leg as make_leg, leg_loads, step_bounds, swing_duration_s
from controller.fsm import FsmInputs, GaitFsm
from controller.gait import GaitPlanner
from controller.policy import StepPolicy, StepRecord
from protocol.catalog import COUNTER_MODULO, Catalog, default_catalog
from protocol.clock import TICK_S
from protocol.codec import Decoded, RejectReason, Rejection
from protocol.commands import JointCommand
from protocol.enums import SWINGS, WALKING, DriveState, GaitState, JointMode, NmtCommand, NmtState, PolicyMode

# Rejections that say a node's frame was damaged, masqueraded or out of order (F6-F8). Not these: a
# repeated counter (a duplicate, F5, or a frozen node, F9), a wrong length or a value out of the
# DBC's range (F10, F15): the frame counts as missing, and the lost-node supervision handles a node
# whose frames stay missing.
INTEGRITY_REASONS = frozenset({RejectReason.BAD_CRC, RejectReason.WRONG_SEQUENCE})

MAX_AGE = 8  # a counter more than this many SYNCs behind is taken as a new sequence, not as late

SENSOR_MESSAGES = (
    "STICK_LEFT", "STICK_RIGHT", "PLANTAR_LEFT", "PLANTAR_RIGHT", "TRUNK_IMU_ORIENTATION", "TRUNK_IMU_RATE",
)


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


@dataclass
class TickResult:
    tick: int
    state: GaitState
    frames: list[tuple[str, tuple]]  # (message name, values in signal order) to send after the tick's work
    # (the cyclic heartbeat and telemetry: :meth:`ControllerCore.scheduled_frames`, after these)
    estimate: Estimate | None
    events: list[str] = field(default_factory=list)
    landed: StepRecord | None = None  # the step that landed this tick
    commands: tuple[JointCommand, ...] = ()  # the four joint commands of ``frames`` (node order), as sent


class ControllerCore:
    def __init__(
        self, cfg: ControllerConfig, *, catalog: Catalog | None = None,
        swing_weights: DmpWeights | None = None, policy: StepPolicy | None = None,
    ) -> None:
        """``swing_weights``: the fitted DMP (default: the cached fit of the configuration);
        ``policy``: where step lengths come from (default: the compensation with the configured theta)."""
        self.cfg = cfg
        catalog = catalog or default_catalog()
        self.node_names = catalog.joint_nodes  # left hip, left knee, right hip, right knee
        self._command_of = {n: catalog.message("JOINT_COMMAND", n).name for n in self.node_names}
        self._scheduled = [catalog.by_name(n) for n in ("CONTROLLER_HEARTBEAT", "CONTROLLER_STEP", "CONTROLLER_LEARNING")]
        self.safety = safety = cfg.safety
        self.fsm = GaitFsm(reset_healthy_ticks=safety.reset_healthy_ticks)
        self.estimator = StateEstimator(cfg.body, cfg.legs)
        legs = cfg.legs
        joints = tuple(
            JointBounds(f"{kind}_{side}", lo, hi)
            for side in ("l", "r")
            for kind, lo, hi in (("hip", legs.hip_min_rad, legs.hip_max_rad), ("knee", legs.knee_min_rad, legs.knee_max_rad))
        )
        self.envelope = Envelope.from_config(joints, cfg.envelope)
        self.joint_names = [j.name for j in joints]
        excess = cfg.envelope.position_excess_rad  # a measured angle this far beyond a limit is a fault
        self._measured_range = {n: (j.lower_rad - excess, j.upper_rad + excess) for n, j in zip(self.node_names, joints)}
        self.lost_ticks = safety.lost_ticks
        self.hold_torque_nm = safety.hold_torque_nm
        self.nodes = {n: NodeState() for n in self.node_names}
        # what each node sends per SYNC (the cyclic frames but the heartbeat); the loop waits for them too
        self.per_sync = {n: tuple(m.frame_id for m in catalog.sent_by(n) if m.is_cyclic and m.family != "HEARTBEAT")
                         for n in self.node_names}
        self._sensor_sender = {name: catalog.by_name(name).sender for name in SENSOR_MESSAGES}
        self.latest: dict[str, tuple[int, Any]] = {}  # sensor message -> (tick it was sent for, values)
        self.syncs = 0  # SYNCs of finished ticks: the index of this tick's SYNC
        self._phase: dict[int, int] = {}  # per-SYNC frame ID -> (SYNC index - counter) mod 16 of an on-time frame
        self._late_now: dict[int, int] = {}  # per-SYNC frame ID -> its age, of this tick's late frames
        self._shift = (0, 0)  # (a uniform lateness of every node's frames, for how many ticks in a row)
        self.started = False
        self.pending_faults: list[Fault] = []
        self.reset_requested = False
        self.measurements: Measurements | None = None  # of the last tick
        if swing_weights is None:
            from controller.swing import load_swing

            swing_weights = load_swing(cfg)
        self.gait = GaitPlanner(make_leg(cfg), Dmp(swing_weights), cfg.gait, leg_loads(cfg), balance_gains(cfg),
                                ankle_height_m=cfg.legs.ankle_height_m, swing_s=swing_duration_s(cfg), dt_s=TICK_S,
                                substeps=cfg.swing.substeps)
        self.policy = policy or StepPolicy(step_bounds(cfg), theta=(cfg.compensation.alpha, cfg.compensation.xhat_com))
        self.fall_tilt_rad = safety.fall_tilt_rad
        self._tilted_ticks = 0
        self._integrity: deque[tuple[int, str]] = deque()  # (tick, reason) of the nodes' damaged frames
        self._error_frame_tick = -(10**9)  # the last error frame's tick
        self._failed_sends: deque[int] = deque(maxlen=safety.send_failure_ticks)  # ticks with a failed send
        self._overruns: deque[int] = deque()  # ticks that followed an overrun
        self._overrun_stop: Fault | None = None  # a protective stop asked by the loop's timing
        self._unloaded = [0, 0]  # per stick: ticks in a row of this swing below stick_unloaded_n
        self._slipped: Fault | None = None  # F19: a stick unloaded in this swing, a HOLD once it has landed
        self._supply_low = [0, 0]  # F29: ticks in a row with the lowest supply below warn, below critical
        self._follow = _Following()
        self.walk_requested = False
        self.stop_requested = False
        self.steps: list[StepRecord] = []
        self._step = StepRecord(index=0, leg="", start_tick=0)  # the step in the making
        self._targets: np.ndarray | None = None  # the setpoints sent last tick (None: the last commands held)
        self.gait_part = ""  # shift, lean or swing while walking

    # -- input -----------------------------------------------------------------------------------

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
                    self.pending_faults.append(Fault(FaultKind.NODE_REBOOTED, sender))
            elif node.was_operational and state != NmtState.OPERATIONAL:
                self.pending_faults.append(Fault(FaultKind.NODE_NOT_OPERATIONAL, sender))
            node.nmt, node.supply_v = state, v.supply_voltage_V
            if state == NmtState.OPERATIONAL and not node.was_operational:
                node.operational_since = tick
        elif family == "EMCY":
            if v.error_register != 0:
                self.pending_faults.append(Fault(FaultKind.EMCY, sender, f"{v.emcy_code:#06x}"))
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

    def overran(self, tick: int, skipped: int) -> None:
        """The loop overran into ``tick``, skipping ``skipped`` ticks (F25). In INIT, before the
        nodes are operational, the controller commands nothing, and a process's first ticks are
        its slowest: there an overrun is only counted (the loop's statistics), not budgeted. In the
        vcan sandbox the controller started beside a starting nodes process overran 3 times in its
        first 12-15 ticks and was in HOLD before any node was up."""
        if self.fsm.state == GaitState.INIT:
            return
        s = self.safety
        self._overruns.append(tick)
        while self._overruns[0] <= tick - s.overrun_window_ticks:
            self._overruns.popleft()
        if skipped > s.overrun_max_ticks:
            self._overrun_stop = Fault(FaultKind.OVERRUN, detail=f"{skipped} ticks skipped")
        elif len(self._overruns) >= s.overrun_limit:
            self._overrun_stop = Fault(FaultKind.OVERRUN, detail=f"{len(self._overruns)} in {s.overrun_window_ticks} ticks")

    def _check_following(self, m: Measurements | None, fresh: bool) -> None:
        """F14: while the joints track, an encoder stuck while its joint moves: its reading stays
        exactly the same while the setpoint moves away from it. A tick counts when the reading
        is the one of the tick before and the setpoint stands ``stuck_motion_rad`` further from it
        than when the reading last changed; ``stuck_ticks`` such ticks are ENCODER_STUCK.

        Not a setpoint that merely moves while the reading stands: a loaded knee at a swing's
        start keeps its reading while the setpoint first closes the gap it held the knee at (in
        the real-time walks of 2026-12-05 up to 4 such ticks while the setpoint moved 0.03-0.04
        rad; an extra tick of the nodes' latency made ENCODER_STUCK of a sound knee, once in CI).
        Measured away from the frozen reading, the same walks count at most 2. A following-error
        rule (the measured angle far from the setpoint) is not used either: a step too long for
        the patient drives the joints off their setpoints as the body falls, and would name the
        fall a fault of the legs. O(1) a joint and tick."""
        f = self._follow
        if self._targets is None or m is None or not fresh:
            f.reset()
            return
        s = self.safety
        q, c = m.joint_position_rad.tolist(), self._targets.tolist()
        for j in range(4):
            gap = abs(c[j] - q[j])
            if q[j] != f.reading[j]:
                f.reading[j], f.away[j], f.gap[j] = q[j], 0, gap
            elif gap - f.gap[j] >= s.stuck_motion_rad:
                f.away[j] += 1
                if f.away[j] >= s.stuck_ticks:
                    self.pending_faults.append(Fault(FaultKind.ENCODER_STUCK, self.node_names[j]))

    def _check_sticks(self, before: GaitState, m: Measurements | None, fresh: bool) -> Fault | None:
        """F19: a stick that carries less than ``stick_unloaded_n`` for ``stick_unloaded_ticks``
        ticks in a row of a swing has slipped or been lifted while the patient needs it. The swing
        goes on to its landing (stopping the legs mid-swing would drop the patient on one leg);
        the tick after the landing is a HOLD, whose cause this returns. The next step is inhibited
        anyway: no step starts without both sticks loaded (I2)."""
        if before in SWINGS:
            if m is not None and fresh:
                s = self.safety
                for i, force in enumerate(m.stick_force_n.tolist()):
                    self._unloaded[i] = self._unloaded[i] + 1 if force < s.stick_unloaded_n else 0
                    if self._unloaded[i] == s.stick_unloaded_ticks and self._slipped is None:
                        self._slipped = Fault(FaultKind.STICK_UNLOADED, f"{('left', 'right')[i]} stick",
                                              f"below {s.stick_unloaded_n:g} N for {s.stick_unloaded_ticks} ticks in the swing")
            return None
        self._unloaded = [0, 0]
        slipped, self._slipped = self._slipped, None
        return slipped if before in (GaitState.DOUBLE_SUPPORT, GaitState.STOP) else None  # landed (a HOLD or FAULT has stopped it anyway)

    def _check_supply(self, state: GaitState, events: list[str]) -> Fault | None:
        """F29: the lowest supply voltage of the nodes' heartbeats below ``supply_warn_v`` for
        ``supply_warn_ticks`` ticks is a warning (an event; nothing else changes); below
        ``supply_critical_v`` for ``supply_critical_ticks`` no step starts any more: in double
        support (a swing lands first, its next tick is in double support) the cause of a HOLD this
        returns, as often as the operator resets and starts again."""
        s = self.safety
        volts = [n.supply_v for n in self.nodes.values() if n.supply_v is not None]
        low = min(volts) if volts else math.inf
        warn, critical = self._supply_low
        self._supply_low = [warn + 1 if low < s.supply_warn_v else 0, critical + 1 if low < s.supply_critical_v else 0]
        if self._supply_low[0] == s.supply_warn_ticks:
            events.append(f"SUPPLY_LOW({low:.2f} V below {s.supply_warn_v:g} V for {s.supply_warn_ticks} ticks): warning")
        if self._supply_low[1] >= s.supply_critical_ticks and state == GaitState.DOUBLE_SUPPORT:
            return Fault(FaultKind.SUPPLY_CRITICAL, detail=f"{low:.2f} V below {s.supply_critical_v:g} V for {self._supply_low[1]} ticks")
        return None

    def _supervise_bus(self, tick: int) -> None:
        """The integrity window and the failed sends (see the module doc)."""
        s = self.safety
        window = self._integrity
        while window and window[0][0] <= tick - s.integrity_window_ticks:
            window.popleft()
        if len(window) >= s.integrity_errors:
            self.pending_faults.append(Fault(FaultKind.FRAME_INTEGRITY, detail=f"{len(window)} in {s.integrity_window_ticks} ticks: {window[-1][1]}"))
            window.clear()
        failed = self._failed_sends
        if len(failed) == failed.maxlen and failed[0] == tick - failed.maxlen:
            self.pending_faults.append(Fault(FaultKind.BUS_SEND_FAILED, detail=f"{failed.maxlen} ticks"))
            failed.clear()

    def request_walk(self) -> None:
        """The operator's start: walk from STAND (or STOP)."""
        self.walk_requested, self.stop_requested = True, False

    def request_stop(self) -> None:
        """The operator's stop: end walking after the current swing."""
        self.stop_requested, self.walk_requested = True, False

    def request_reset(self) -> None:
        """The operator's reset of HOLD or FAULT (sent to the nodes as FAULT_RESET too)."""
        self.reset_requested = True

    # -- the tick --------------------------------------------------------------------------------

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

    def tick(self, tick: int) -> TickResult:
        """The work of ``tick`` after its node frames are in; returns what to send."""
        frames: list[tuple[str, tuple]] = []
        events: list[str] = []
        self._missed_sync(tick)
        if not self.started and all(n.nmt is not None for n in self.nodes.values()):  # all booted or heard
            frames.append(("NMT_COMMAND", (int(NmtCommand.START), 0)))
            self.started = True
            events.append("NMT start")
        operational = all(n.nmt == NmtState.OPERATIONAL for n in self.nodes.values())
        ages = [tick - n.status_tick if n.status is not None else 10**9 for n in self.nodes.values()]
        for name, node in self.nodes.items():
            if node.was_operational and tick - max(node.status_tick, node.operational_since) >= self.lost_ticks:
                self.pending_faults.append(Fault(FaultKind.NODE_LOST, name))
            if node.status is not None and node.status_tick == tick:
                if node.status.drive_state == DriveState.FAULT:
                    self.pending_faults.append(Fault(FaultKind.DRIVE_FAULT, name, f"error {node.status.error_code}"))
                lo, hi = self._measured_range[name]
                if not lo <= node.status.position_rad <= hi:  # F16: a joint beyond its range is a fault
                    self.pending_faults.append(Fault(FaultKind.JOINT_LIMIT, name, f"{node.status.position_rad:.3f} rad"))
        latest = self.latest
        for name, sender in self._sensor_sender.items():  # a sensor frame missing as long as a lost node's status
            node = self.nodes[sender]
            if node.was_operational and tick - max(latest.get(name, (-1,))[0], node.operational_since) >= self.lost_ticks:
                self.pending_faults.append(Fault(FaultKind.SENSOR_LOST, name))
            elif name in latest:
                ages.append(tick - latest[name][0])
        self._supervise_bus(tick)
        measurements, fresh = self._measurements(tick)
        self.measurements = measurements
        estimate = self.estimator.update(measurements) if measurements is not None else None
        self._check_fall(measurements)
        self._check_following(measurements, fresh)
        slipped = self._check_sticks(self.fsm.state, measurements, fresh)
        supply_stop = self._check_supply(self.fsm.state, events)
        healthy = operational and max(ages) <= 2 and not self.pending_faults
        quiet_bus = tick - self._error_frame_tick >= self.safety.integrity_window_ticks  # F11: no new step
        # The gait of the state the FSM is in: whether the step is ready, whether the swing is done.
        before = self.fsm.state
        ready = done = landed = False
        sticks_loaded = bool(estimate and all(estimate.sticks_loaded))
        if estimate is not None and fresh and before in WALKING:
            self.gait.track_sticks(estimate, measurements)
            self._step.add(measurements.stick_force_n)
            if before == GaitState.DOUBLE_SUPPORT:
                ds = self.gait.double_support(estimate, measurements, _leg_index(self.fsm.next_swing))
                # a step starts on sticks planted and leant on (the gait's swing_stick_n), which a
                # trailing foot propping the body on its toe leaves below the support polygon's threshold
                ready, self.gait_part, sticks_loaded = ds.ready, ds.part, ds.sticks_loaded
            else:
                self.gait_part = "swing"
                swing = self.gait.swing(estimate, measurements)
                done, landed = swing.done, swing.landed
        # every cause of this tick to the state machine by its kind's reaction (controller.faults)
        causes = [*self.pending_faults, *(f for f in (self._overrun_stop, slipped, supply_stop) if f is not None)]
        faults = [f for f in causes if f.kind.reaction is Reaction.FAULT]
        holds = [f for f in causes if f.kind.reaction is Reaction.HOLD]
        inputs = FsmInputs(
            nodes_operational=operational,
            nodes_healthy=healthy,
            data_fresh=fresh and quiet_bus,
            sticks_loaded=sticks_loaded,
            sticks_ahead=ready,
            swing_done=done,
            fault=faults[0] if faults else None,
            other_faults=tuple(faults[1:]),
            protective_stop=holds[0] if holds else None,
            reset=self.reset_requested,
            start=self.walk_requested,
            stop=self.stop_requested,
        )
        n_transitions = len(self.fsm.transitions)
        state = self.fsm.step(tick, inputs)
        events += [f"{t.source.name} -> {t.target.name}: {t.cause}" for t in self.fsm.transitions[n_transitions:]]
        self._overrun_stop = None
        if self.reset_requested:
            frames.append(("NMT_COMMAND", (int(NmtCommand.FAULT_RESET), 0)))
            self.reset_requested = False
        if state != before:
            self.walk_requested = self.walk_requested and state in (GaitState.INIT, GaitState.STAND, GaitState.STOP)
            self.stop_requested = self.stop_requested and state in WALKING
        finished = self._gait_transition(tick, before, state, estimate, measurements, landed, events)
        self.pending_faults.clear()
        commands = self._command(state, frames, measurements)
        self.syncs += 1
        return TickResult(tick, state, frames, estimate, events, finished, commands)

    def _check_fall(self, m: Measurements | None) -> None:
        """docs/FAULTS.md F18: the trunk tilted beyond ``fall_tilt_rad`` for ``fall_ticks`` ticks in a row."""
        tilt = max(abs(float(m.trunk_rpy_rad[0])), abs(float(m.trunk_rpy_rad[1]))) if m is not None else 0.0
        self._tilted_ticks = self._tilted_ticks + 1 if tilt > self.fall_tilt_rad else 0
        if self._tilted_ticks >= self.safety.fall_ticks:
            self.pending_faults.append(Fault(FaultKind.FALL, detail=f"trunk tilt {tilt:.2f} rad"))

    def _gait_transition(
        self, tick: int, before: GaitState, state: GaitState, est: Estimate | None, m: Measurements | None,
        landed: bool, events: list[str],
    ) -> StepRecord | None:
        """Start walking, start a swing, close a step; returns the step that ended this tick."""
        finished = None
        if state != before and state in (GaitState.FAULT, GaitState.HOLD, GaitState.STOP):
            fault = self.fsm.transitions[-1].fault
            if fault is not None and fault.kind is FaultKind.FALL:
                self.policy.fell()  # the roll-out ends with its terminal cost
            else:
                self.policy.abandon()
        if before in SWINGS and state not in SWINGS:
            step = self.steps[-1]
            step.end_tick, step.landed = tick, landed
            finished = step
            if landed:
                self.policy.landed(step)
            self._step = StepRecord(index=len(self.steps), leg="", start_tick=tick)
        if state == GaitState.DOUBLE_SUPPORT and before in (GaitState.STAND, GaitState.STOP):
            self.gait.stand_here(est, m)
            self._step = StepRecord(index=len(self.steps), leg="", start_tick=tick)
        if state in SWINGS and before == GaitState.DOUBLE_SUPPORT:
            leg = _leg_index(state)
            x_ratio = self.estimator.stance_ratio(est, 1 - leg)
            goal, theta = self.policy.goal(x_ratio)
            if self.steps and self.steps[-1].landed:
                # the last step as the double support after it left it (a landing foot may still slide)
                last = self.steps[-1]
                front = "lr".index(last.leg)
                last.placed_m = float(est.ankles[front][0] - est.ankles[1 - front][0])
                self.gait.placed(last.length_m, last.placed_m)
            aim = self.gait.start_swing(leg, est, goal.length_m)
            step = self._step
            step.leg, step.swing_tick, step.x_ratio, step.theta = "lr"[leg], tick, x_ratio, theta
            step.x_ratio_planted = self.estimator.planted_ratio(est)
            step.length_m, step.requested_m, step.clamped, step.aimed_m = goal.length_m, goal.requested_m, goal.clamped, aim
            self.steps.append(step)
            events.append(f"step {step.index} ({step.leg}): {goal.length_m:.3f} m at X_CoM/X_SP {x_ratio:.2f}"
                          + (f" (clamped: {goal.reason})" if goal.clamped else ""))
        return finished

    # -- telemetry ---------------------------------------------------------------------------------

    def scheduled_frames(self, tick: int, state: GaitState) -> list[tuple[str, tuple]]:
        """The controller's cyclic frames of tick ``tick`` besides SYNC, on the DBC's schedule,
        sent after the tick's commands: its heartbeat (the gait state) and the low-rate telemetry
        that monitors read (the step, the compensation and the learner; no node acts on it)."""
        heartbeat, step, learning = self._scheduled
        out: list[tuple[str, tuple]] = []
        if heartbeat.sent_in_tick(tick):
            out.append((heartbeat.name, (int(state),)))
        if step.sent_in_tick(tick):
            out.append((step.name, _within(step, self._step_telemetry())))
        if learning.sent_in_tick(tick):
            out.append((learning.name, _within(learning, self._learning_telemetry())))
        return out

    def _step_telemetry(self) -> tuple:
        last = self.steps[-1] if self.steps else None
        before = self.steps[-2] if len(self.steps) > 1 else None
        landed = next((st for st in reversed(self.steps) if st.landed), None)
        policy = PolicyMode.__members__.get(self.policy.mode.upper(), PolicyMode.FIXED)  # an experiment's random lengths: no theta
        return (len(self.steps), last.length_m if last else 0.0, before.placed_m if before else 0.0,
                landed.mean_stick_force_n if landed else 0.0, int(policy))

    def _learning_telemetry(self) -> tuple:
        theta = next((st.theta for st in reversed(self.steps) if st.theta is not None), None)
        if theta is None:
            theta = self.policy.theta if self.policy.fixed_m is None and self.policy.learner is None else (0.0, 0.0)
        learner = self.policy.learner
        if learner is None:
            return (theta[0], theta[1], 0, 0, 0, 0.0)
        costs = self.policy.cycle_costs
        return (theta[0], theta[1], learner.n_updates, learner.rollouts_in_batch, len(costs), costs[-1] if costs else 0.0)

    def _command(self, state: GaitState, frames: list[tuple[str, tuple]], m: Measurements | None) -> tuple[JointCommand, ...]:
        """The four joint commands, through the envelope: the gait's targets in the walking
        states, HOLD in every other (docs/FAULTS.md I2); appended to ``frames`` and returned."""
        moving = self.fsm.moving and m is not None
        if not moving:
            self._targets = None
        previous = (self._targets if self._targets is not None else (m.joint_position_rad if m is not None else np.zeros(4))).tolist()
        targets = self.gait.targets.tolist() if moving else None
        limit = self.cfg.envelope.max_torque_nm
        torques = np.clip(self.gait.torques, -limit, limit).tolist() if moving else None
        hold = JointCommand(JointMode.HOLD, torque_limit_nm=self.hold_torque_nm)
        sent, commands = [], []
        for i, (name, joint) in enumerate(zip(self.node_names, self.joint_names)):
            if moving:
                cmd = JointCommand(JointMode.TRACK, targets[i], torque_nm=torques[i], torque_limit_nm=limit)
            else:
                cmd = hold
            checked = self.envelope.check(joint, cmd, previous[i])
            if checked.violation is not None:
                self.pending_faults.append(Fault(FaultKind.ENVELOPE, detail=checked.violation))  # latches FAULT next tick
            c = checked.command
            commands.append(c)
            sent.append(c.position_rad)
            frames.append((self._command_of[name], (int(c.mode), c.position_rad, c.velocity_rad_s, c.torque_nm,
                                                    float(round(c.torque_limit_nm)))))
        if moving:
            self._targets = np.array(sent)
        return tuple(commands)


@dataclass
class _Following:
    """Per joint: the reading, the setpoint's distance from it when it last changed, and the ticks
    since that the setpoint stood ``stuck_motion_rad`` further away (ControllerCore._check_following)."""

    away: list[int] = field(default_factory=lambda: [0] * 4)
    reading: list[float] = field(default_factory=lambda: [math.nan] * 4)
    gap: list[float] = field(default_factory=lambda: [0.0] * 4)

    def reset(self) -> None:
        self.away[:], self.reading[:] = [0] * 4, [math.nan] * 4


def _within(spec: Any, values: tuple) -> tuple:
    """Telemetry values inside their DBC ranges (a value beyond one is shown at its end; not a
    number, 0): a monitor's frame never fails to encode."""
    out = []
    for sig, v in zip(spec.signals, values):
        v = float(v) if math.isfinite(v) else 0.0
        v = min(max(v, sig.minimum), sig.maximum)
        out.append(int(round(v)) if sig.is_integer or sig.choices is not None else v)
    return tuple(out)


def _leg_index(swing: GaitState) -> int:
    """0 for the left leg's swing, 1 for the right one's."""
    return 0 if swing == GaitState.SWING_LEFT else 1
