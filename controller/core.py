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
(fixed, compensated, or learning) with X_CoM/X_SP estimated at the swing's start. FAULT latches on
a lost node (no status for ``lost_ticks`` ticks), a drive fault or a fault EMCY, a node that
reboots, a command beyond the safety envelope, and a fall (trunk tilt beyond ``fall_tilt_rad``
for two ticks, FAULTS.md F18); an operator reset leaves it as the FSM allows. Walking starts on
:meth:`ControllerCore.request_walk` (the operator's start) and ends with :meth:`request_stop`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from config.controller_schema import ControllerConfig
from controller.dmp import Dmp, DmpWeights
from controller.envelope import Envelope, JointBounds, JointCommand
from controller.estimator import Estimate, Measurements, StateEstimator
from controller.factory import leg as make_leg, step_bounds
from controller.fsm import SWINGS, FsmInputs, GaitFsm
from controller.gait import GaitPlanner
from controller.policy import StepPolicy, StepRecord
from protocol.catalog import TICK_MS, Catalog, default_catalog
from protocol.codec import Decoded
from protocol.enums import DriveState, GaitState, JointMode, NmtCommand, NmtState

SENSOR_MESSAGES = (
    "STICK_LEFT", "STICK_RIGHT", "PLANTAR_LEFT", "PLANTAR_RIGHT", "TRUNK_IMU_ORIENTATION", "TRUNK_IMU_RATE",
)


@dataclass
class NodeState:
    nmt: NmtState | None = None  # from its heartbeat (None: never heard)
    status: Any = None  # the newest JOINT_STATUS values
    status_tick: int = -1  # the tick it arrived in
    operational_since: int = -1  # the tick its heartbeat first said OPERATIONAL (-1: never)

    @property
    def was_operational(self) -> bool:
        return self.operational_since >= 0


@dataclass
class TickResult:
    tick: int
    state: GaitState
    frames: list[tuple[str, tuple]]  # (message name, values in signal order) to send after the tick's work
    # (the controller's heartbeat with ``state`` is the loop's, on the DBC's schedule)
    estimate: Estimate | None
    events: list[str] = field(default_factory=list)
    landed: StepRecord | None = None  # the step that landed this tick


class ControllerCore:
    def __init__(
        self, cfg: ControllerConfig, *, catalog: Catalog | None = None, lost_ticks: int = 3, hold_torque_nm: float = 80.0,
        swing_weights: DmpWeights | None = None, policy: StepPolicy | None = None, fall_tilt_rad: float = 0.5,
    ) -> None:
        """``swing_weights``: the fitted DMP (default: the cached fit of the configuration);
        ``policy``: where step lengths come from (default: the compensation with the configured theta)."""
        self.cfg = cfg
        catalog = catalog or default_catalog()
        self.node_names = catalog.joint_nodes  # left hip, left knee, right hip, right knee
        self._command_of = {n: catalog.message("JOINT_COMMAND", n).name for n in self.node_names}
        self.fsm = GaitFsm()
        self.estimator = StateEstimator(cfg.body, cfg.legs)
        legs = cfg.legs
        joints = tuple(
            JointBounds(f"{kind}_{side}", lo, hi)
            for side in ("l", "r")
            for kind, lo, hi in (("hip", legs.hip_min_rad, legs.hip_max_rad), ("knee", legs.knee_min_rad, legs.knee_max_rad))
        )
        self.envelope = Envelope.from_config(joints, cfg.envelope)
        self.joint_names = [j.name for j in joints]
        self.lost_ticks = lost_ticks
        self.hold_torque_nm = hold_torque_nm
        self.nodes = {n: NodeState() for n in self.node_names}
        self.latest: dict[str, tuple[int, Any]] = {}  # sensor message -> (tick, values)
        self.started = False
        self.pending_faults: list[str] = []
        self.reset_requested = False
        self.measurements: Measurements | None = None  # of the last tick
        if swing_weights is None:
            from controller.swing import load_swing

            swing_weights = load_swing(cfg)
        self.gait = GaitPlanner(make_leg(cfg), Dmp(swing_weights), cfg.gait, dt_s=TICK_MS / 1000.0, substeps=cfg.swing.substeps)
        self.policy = policy or StepPolicy(step_bounds(cfg), theta=(cfg.compensation.alpha, cfg.compensation.xhat_com))
        self.fall_tilt_rad = fall_tilt_rad
        self._tilted_ticks = 0
        self.walk_requested = False
        self.stop_requested = False
        self.steps: list[StepRecord] = []
        self._step = StepRecord(index=0, leg="", start_tick=0)  # the step in the making
        self._targets: np.ndarray | None = None  # the setpoints sent last tick (None: the last commands held)
        self.gait_part = ""  # shift, lean or swing while walking

    # -- input -----------------------------------------------------------------------------------

    def receive(self, frame: Decoded, tick: int) -> None:
        """One accepted frame from a node, received during ``tick``."""
        spec, v = frame.message, frame.values
        family, sender = spec.family, spec.sender
        if family == "JOINT_STATUS":
            node = self.nodes[sender]
            node.status, node.status_tick = v, tick
        elif family == "HEARTBEAT":
            node = self.nodes[sender]
            state = NmtState(v.nmt_state)
            if state == NmtState.BOOT_UP:
                if node.was_operational:
                    self.pending_faults.append(f"NODE_REBOOTED({sender})")
            elif node.was_operational and state != NmtState.OPERATIONAL:
                self.pending_faults.append(f"NODE_NOT_OPERATIONAL({sender})")
            node.nmt = state
            if state == NmtState.OPERATIONAL and not node.was_operational:
                node.operational_since = tick
        elif family == "EMCY":
            if v.error_register != 0:
                self.pending_faults.append(f"EMCY {v.emcy_code:#06x} from {sender}")
        else:
            self.latest[spec.name] = (tick, v)

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
        stick_l, stick_r, plantar_l, plantar_r, o, _ = (v for _, v in sensors)
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
        ), fresh

    def tick(self, tick: int) -> TickResult:
        """The work of ``tick`` after its node frames are in; returns what to send."""
        frames: list[tuple[str, tuple]] = []
        events: list[str] = []
        if not self.started and all(n.nmt is not None for n in self.nodes.values()):  # all booted or heard
            frames.append(("NMT_COMMAND", (int(NmtCommand.START), 0)))
            self.started = True
            events.append("NMT start")
        operational = all(n.nmt == NmtState.OPERATIONAL for n in self.nodes.values())
        ages = [tick - n.status_tick if n.status is not None else 10**9 for n in self.nodes.values()]
        for name, node in self.nodes.items():
            if node.was_operational and tick - max(node.status_tick, node.operational_since) >= self.lost_ticks:
                self.pending_faults.append(f"NODE_LOST({name})")
            if node.status is not None and node.status.drive_state == DriveState.FAULT and node.status_tick == tick:
                self.pending_faults.append(f"DRIVE_FAULT({name}: error {node.status.error_code})")
        measurements, fresh = self._measurements(tick)
        self.measurements = measurements
        estimate = self.estimator.update(measurements) if measurements is not None else None
        self._check_fall(measurements)
        healthy = operational and max(ages) <= 2 and not self.pending_faults
        # The gait of the state the FSM is in: whether the step is ready, whether the swing is done.
        before = self.fsm.state
        ready = done = landed = False
        sticks_loaded = bool(estimate and all(estimate.sticks_loaded))
        if estimate is not None and fresh and before in (GaitState.DOUBLE_SUPPORT, *SWINGS):
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
        inputs = FsmInputs(
            nodes_operational=operational,
            nodes_healthy=healthy,
            data_fresh=fresh,
            sticks_loaded=sticks_loaded,
            sticks_ahead=ready,
            swing_done=done,
            fault=self.pending_faults[0] if self.pending_faults else None,
            reset=self.reset_requested,
            start=self.walk_requested,
            stop=self.stop_requested,
        )
        n_transitions = len(self.fsm.transitions)
        state = self.fsm.step(tick, inputs)
        events += [f"{t.source.name} -> {t.target.name}: {t.cause}" for t in self.fsm.transitions[n_transitions:]]
        if self.reset_requested:
            frames.append(("NMT_COMMAND", (int(NmtCommand.FAULT_RESET), 0)))
            self.reset_requested = False
        if state != before:
            self.walk_requested = self.walk_requested and state in (GaitState.INIT, GaitState.STAND, GaitState.STOP)
            self.stop_requested = self.stop_requested and state in (GaitState.DOUBLE_SUPPORT, *SWINGS)
        finished = self._gait_transition(tick, before, state, estimate, measurements, landed, events)
        self.pending_faults.clear()
        self._command(state, frames, measurements)
        return TickResult(tick, state, frames, estimate, events, finished)

    def _check_fall(self, m: Measurements | None) -> None:
        """FAULTS.md F18: the trunk tilted beyond ``fall_tilt_rad`` for two ticks in a row."""
        tilt = max(abs(float(m.trunk_rpy_rad[0])), abs(float(m.trunk_rpy_rad[1]))) if m is not None else 0.0
        self._tilted_ticks = self._tilted_ticks + 1 if tilt > self.fall_tilt_rad else 0
        if self._tilted_ticks >= 2:
            self.pending_faults.append(f"FALL(trunk tilt {tilt:.2f} rad)")

    def _gait_transition(
        self, tick: int, before: GaitState, state: GaitState, est: Estimate | None, m: Measurements | None,
        landed: bool, events: list[str],
    ) -> StepRecord | None:
        """Start walking, start a swing, close a step; returns the step that ended this tick."""
        finished = None
        if state != before and state in (GaitState.FAULT, GaitState.HOLD, GaitState.STOP):
            cause = self.fsm.transitions[-1].cause
            if state == GaitState.FAULT and cause.startswith("FALL"):
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
            goal, theta = self.policy.goal(est.x_ratio_planted)
            leg = _leg_index(state)
            self.gait.start_swing(leg, est, goal.length_m)
            step = self._step
            step.leg, step.swing_tick, step.x_ratio, step.theta = "lr"[leg], tick, float(est.x_ratio_planted), theta
            step.length_m, step.requested_m, step.clamped = goal.length_m, goal.requested_m, goal.clamped
            self.steps.append(step)
            events.append(f"step {step.index} ({step.leg}): {goal.length_m:.3f} m at X_CoM/X_SP {est.x_ratio_planted:.2f}"
                          + (f" (clamped: {goal.reason})" if goal.clamped else ""))
        return finished

    def _command(self, state: GaitState, frames: list[tuple[str, tuple]], m: Measurements | None) -> None:
        """The four joint commands, through the envelope: the gait's targets in the walking
        states, HOLD in every other (FAULTS.md I2)."""
        moving = self.fsm.moving and m is not None
        if not moving:
            self._targets = None
        previous = (self._targets if self._targets is not None else (m.joint_position_rad if m is not None else np.zeros(4))).tolist()
        targets = self.gait.targets.tolist() if moving else None
        hold = JointCommand(JointMode.HOLD, torque_limit_nm=self.hold_torque_nm)
        sent = []
        for i, (name, joint) in enumerate(zip(self.node_names, self.joint_names)):
            if moving:
                cmd = JointCommand(JointMode.TRACK, targets[i], torque_limit_nm=self.cfg.envelope.max_torque_nm)
            else:
                cmd = hold
            checked = self.envelope.check(joint, cmd, previous[i])
            if checked.violation is not None:
                self.pending_faults.append(f"ENVELOPE({checked.violation})")  # latches FAULT next tick
            c = checked.command
            sent.append(c.position_rad)
            frames.append((self._command_of[name], (int(c.mode), c.position_rad, c.velocity_rad_s, c.torque_nm,
                                                    float(round(c.torque_limit_nm)))))
        if moving:
            self._targets = np.array(sent)


def _leg_index(swing: GaitState) -> int:
    """0 for the left leg's swing, 1 for the right one's."""
    return 0 if swing == GaitState.SWING_LEFT else 1
