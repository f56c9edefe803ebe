"""The main controller's tick logic over typed data, without I/O (ros2_control's controller).

:meth:`ControllerCore.update` takes one tick's :class:`~controller.interfaces.Snapshot` (the
sensors and the health of the nodes and the bus, as the hardware read them: :mod:`controller.hardware`)
and returns its :class:`~controller.interfaces.Commands`: the four joint commands, the gait
state, the operator's reset and the telemetry. It knows no CAN message, signal or counter.

Every tick it estimates the state, runs the safety monitors (:mod:`controller.monitors`) and the
gait FSM, and commands the legs: in DOUBLE_SUPPORT and the swings they follow the
:class:`~controller.gait.GaitPlanner` (weight shift, lean, DMP swing), in every other state they
hold (HOLD commands, docs/FAULTS.md I2), and every command passes the safety envelope. The step
length of each swing comes from the :class:`~controller.policy.StepPolicy` (fixed, compensated,
or learning) with X_CoM/X_SP estimated at the swing's start. Each cause of a stop goes to the FSM
by its kind's reaction (:mod:`controller.faults`): the hardware's (a lost node, frame integrity,
...), the monitors' and the envelope's. Walking starts on :meth:`request_walk` (the operator's
start), ends with :meth:`request_stop`; :meth:`request_reset` leaves HOLD or FAULT as the FSM
allows. The loop reports its overruns (:meth:`overran`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from config.controller_schema import ControllerConfig
from controller.dmp_model import DmpWeights
from controller.envelope import Envelope
from controller.estimator import Estimate, Measurements, StateEstimator
from controller.factory import gait_planner, joint_bounds, step_bounds
from controller.faults import Fault, FaultKind, Reaction
from controller.fsm import FsmInputs, GaitFsm
from controller.interfaces import Commands, LearningTelemetry, Snapshot, StepTelemetry
from controller.monitors import Monitors
from controller.policy import StepPolicy, StepRecord, learning_telemetry, step_telemetry
from protocol.commands import JointCommand
from protocol.enums import SWINGS, WALKING, GaitState, JointMode


@dataclass
class TickResult:
    tick: int
    state: GaitState
    commands: Commands  # for the hardware to write
    estimate: Estimate | None
    measurements: Measurements | None  # the snapshot's
    events: list[str] = field(default_factory=list)
    landed: StepRecord | None = None  # the step that landed this tick


class ControllerCore:
    def __init__(
        self, cfg: ControllerConfig, *, swing_weights: DmpWeights | None = None, policy: StepPolicy | None = None,
    ) -> None:
        """``swing_weights``: the fitted DMP (default: the cached fit of the configuration);
        ``policy``: where step lengths come from (default: the compensation with the configured theta)."""
        self.cfg = cfg
        self.safety = safety = cfg.safety
        self.fsm = GaitFsm(reset_healthy_ticks=safety.reset_healthy_ticks)
        self.estimator = StateEstimator(cfg.body, cfg.legs, cfg.hardware)
        joints = joint_bounds(cfg)
        self.envelope = Envelope.from_config(joints, cfg.envelope)
        self.joint_names = tuple(j.name for j in joints)
        self.monitors = Monitors(safety, self.joint_names)
        self.hold_torque_nm = safety.hold_torque_nm
        self.reset_requested = False
        if swing_weights is None:
            from controller.swing import load_swing

            swing_weights = load_swing(cfg)
        self.gait = gait_planner(cfg, swing_weights)
        self.policy = policy or StepPolicy(step_bounds(cfg), theta=(cfg.compensation.alpha, cfg.compensation.xhat_com))
        self._envelope_faults: list[Fault] = []  # the last tick's commands beyond the envelope: FAULT this tick
        self.walk_requested = False
        self.stop_requested = False
        self.steps: list[StepRecord] = []
        self._step = StepRecord(index=0, leg="", start_tick=0)  # the step in the making
        self._targets: np.ndarray | None = None  # the setpoints sent last tick (None: the last commands held)
        self.gait_part = ""  # shift, lean or swing while walking
        self._telemetry = self._current_telemetry()

    def _current_telemetry(self) -> tuple[StepTelemetry, LearningTelemetry]:
        return step_telemetry(self.steps, self.policy), learning_telemetry(self.steps, self.policy)

    # -- the operator and the loop ---------------------------------------------------------------

    def request_walk(self) -> None:
        """The operator's start: walk from STAND (or STOP)."""
        self.walk_requested, self.stop_requested = True, False

    def request_stop(self) -> None:
        """The operator's stop: end walking after the current swing."""
        self.stop_requested, self.walk_requested = True, False

    def request_reset(self) -> None:
        """The operator's reset of HOLD or FAULT (the nodes clear their faults too)."""
        self.reset_requested = True

    def walk_ended(self, *, fell: bool) -> None:
        """The walk stopped: a fall ends the learner's roll-out with its terminal cost, any other
        stop discards it. The one way the learner hears of a fall: the controller's own fall
        detection, or a fall the simulation's ground truth saw first (an experiment's walk)."""
        if fell:
            self.policy.fell()
        else:
            self.policy.abandon()

    def overran(self, tick: int, skipped: int) -> None:
        """The loop overran into ``tick``, skipping ``skipped`` ticks (F25: :meth:`Monitors.overran`)."""
        self.monitors.overran(self.fsm.state, tick, skipped)

    # -- the tick --------------------------------------------------------------------------------

    def update(self, snapshot: Snapshot) -> TickResult:
        """The work of one tick on what the hardware read; returns what to write."""
        tick, measurements, fresh = snapshot.tick, snapshot.measurements, snapshot.fresh
        events = list(snapshot.events)
        faults, self._envelope_faults = [*self._envelope_faults, *snapshot.faults], []
        estimate = self.estimator.update(measurements) if measurements is not None else None
        monitors = self.monitors
        monitors.fall(measurements, faults)
        monitors.following(self._targets, measurements, fresh, faults)
        slipped = monitors.sticks(self.fsm.state, measurements, fresh)
        supply_stop = monitors.supply(self.fsm.state, snapshot.lowest_supply_v, events)
        healthy = snapshot.operational and snapshot.oldest_sample_ticks <= 2 and not faults
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
        causes = [*faults, *(f for f in (monitors.overrun_stop, slipped, supply_stop) if f is not None)]
        latched = [f for f in causes if f.kind.reaction is Reaction.FAULT]
        holds = [f for f in causes if f.kind.reaction is Reaction.HOLD]
        inputs = FsmInputs(
            nodes_operational=snapshot.operational,
            nodes_healthy=healthy,
            data_fresh=fresh and snapshot.quiet_bus,  # F11: no new step after an error frame
            sticks_loaded=sticks_loaded,
            sticks_ahead=ready,
            swing_done=done,
            fault=latched[0] if latched else None,
            other_faults=tuple(latched[1:]),
            protective_stop=holds[0] if holds else None,
            reset=self.reset_requested,
            start=self.walk_requested,
            stop=self.stop_requested,
        )
        n_transitions = len(self.fsm.transitions)
        state = self.fsm.step(tick, inputs)
        events += [f"{t.source.name} -> {t.target.name}: {t.cause}" for t in self.fsm.transitions[n_transitions:]]
        monitors.overrun_stop = None
        reset, self.reset_requested = self.reset_requested, False
        if state != before:
            self.walk_requested = self.walk_requested and state in (GaitState.INIT, GaitState.STAND, GaitState.STOP)
            self.stop_requested = self.stop_requested and state in WALKING
        finished = self._gait_transition(tick, before, state, estimate, measurements, landed, events)
        if state != before:  # a step, a landing, a roll-out's end: what the telemetry shows changes only with the state
            self._telemetry = self._current_telemetry()
        commands = Commands(state, self._command(measurements), reset, *self._telemetry)
        return TickResult(tick, state, commands, estimate, measurements, events, finished)

    def _gait_transition(
        self, tick: int, before: GaitState, state: GaitState, est: Estimate | None, m: Measurements | None,
        landed: bool, events: list[str],
    ) -> StepRecord | None:
        """Start walking, start a swing, close a step; returns the step that ended this tick."""
        finished = None
        if state != before and state in (GaitState.FAULT, GaitState.HOLD, GaitState.STOP):
            fault = self.fsm.transitions[-1].fault
            self.walk_ended(fell=fault is not None and fault.kind is FaultKind.FALL)
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

    def _command(self, m: Measurements | None) -> tuple[JointCommand, ...]:
        """The four joint commands, through the envelope: the gait's targets in the walking
        states, HOLD in every other (docs/FAULTS.md I2). A command beyond the envelope's allowance
        is a FAULT at the next tick."""
        moving = self.fsm.moving and m is not None
        if not moving:
            self._targets = None
        previous = (self._targets if self._targets is not None else (m.joint_position_rad if m is not None else np.zeros(4))).tolist()
        targets = self.gait.targets.tolist() if moving else None
        limit = self.cfg.envelope.max_torque_nm
        torques = np.clip(self.gait.torques, -limit, limit).tolist() if moving else None
        hold = JointCommand(JointMode.HOLD, torque_limit_nm=self.hold_torque_nm)
        commands = []
        for i, joint in enumerate(self.joint_names):
            cmd = JointCommand(JointMode.TRACK, targets[i], torque_nm=torques[i], torque_limit_nm=limit) if moving else hold
            checked = self.envelope.check(joint, cmd, previous[i])
            if checked.violation is not None:
                self._envelope_faults.append(Fault(FaultKind.ENVELOPE, detail=checked.violation))
            commands.append(checked.command)
        if moving:
            self._targets = np.array([c.position_rad for c in commands])
        return tuple(commands)


def _leg_index(swing: GaitState) -> int:
    """0 for the left leg's swing, 1 for the right one's."""
    return 0 if swing == GaitState.SWING_LEFT else 1
