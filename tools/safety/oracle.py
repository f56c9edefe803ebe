"""docs/FAULTS.md's global invariants I1-I7, checked on every tick from what is on the bus and what the
controller decided (I8, the configuration, is checked where the configuration is loaded).

:class:`Oracle` gets, per tick, the controller's :class:`~controller.core.TickResult` and the
frames a passive listener saw on the bus during that tick (so a frame the controller meant to send
but a fault swallowed is not there). Each broken invariant is one line in
:attr:`Oracle.violations`: ``tick N: I<k> <what>``. It also keeps, per entry into HOLD or FAULT,
the tick it happened and the first tick whose four joint commands on the bus were all HOLD.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import can

from controller.cansystem import SENSOR_MESSAGES, CanSystem
from controller.core import ControllerCore, TickResult
from controller.faults import Fault
from controller.fsm import OPERATOR_RESET
from protocol.codec import Codec, Decoded
from protocol.enums import SWINGS, WALKING, DriveState, GaitState, JointMode, NmtState

EPS = 1e-3  # the encoding's quantum is 1e-4 rad, 0.002 rad/s, 0.1 N.m, 1 N.m: the bounds hold to it
STOP_STATES = (GaitState.HOLD, GaitState.FAULT)


@dataclass
class StopRecord:
    tick: int  # the tick the FSM entered it
    state: GaitState
    cause: Fault
    hold_on_bus_tick: int | None = None  # the first tick with four HOLD commands on the bus


@dataclass
class Oracle:
    core: ControllerCore
    hardware: CanSystem
    codec: Codec = field(default_factory=Codec)
    violations: list[str] = field(default_factory=list)
    stops: list[StopRecord] = field(default_factory=list)
    ticks: int = 0
    _last_sync: int | None = None
    _last_track: dict[str, float] = field(default_factory=dict)  # node -> its last TRACK setpoint (last tick)
    _state: GaitState = GaitState.INIT
    _steps_seen: int = 0

    def _fail(self, tick: int, text: str) -> None:
        self.violations.append(f"tick {tick}: {text}")

    def check(self, result: TickResult, frames: list[can.Message]) -> None:
        """The invariants of one tick."""
        k = result.tick
        self.ticks += 1
        decoded = [d for d in (self.codec.decode(m.arbitration_id, m.data) for m in frames if not m.is_error_frame)
                   if type(d) is Decoded]
        # I7: one SYNC per tick, in order, at most one command per joint.
        syncs = [d.values.tick for d in decoded if d.name == "SYNC"]
        if self._last_sync is not None and syncs and syncs[0] <= self._last_sync:
            self._fail(k, f"I7 SYNC {syncs[0]} after {self._last_sync}")
        if len(syncs) > 1:
            self._fail(k, f"I7 {len(syncs)} SYNCs in one tick")
        if syncs:
            self._last_sync = syncs[-1]
        commands = {d.message.receivers[0]: d.values for d in decoded if d.message.family == "JOINT_COMMAND"}
        if sum(d.message.family == "JOINT_COMMAND" for d in decoded) > len(commands):
            self._fail(k, "I7 two commands for one joint in one tick")
        self._envelope(k, commands)
        tracking = [n for n, c in commands.items() if c.mode == JointMode.TRACK]
        if tracking:
            self._health(k, result.state)
        self._learning(k)
        self._transitions(k, result, commands)

    # -- I1 --------------------------------------------------------------------------------------

    def _envelope(self, k: int, commands: dict) -> None:
        env = self.core.envelope
        track = {}
        for node, c in commands.items():
            joint = self.core.joint_names[self.hardware.node_names.index(node)]
            values = (c.position_setpoint_rad, c.velocity_ff_rad_s, c.torque_ff_Nm, c.torque_limit_Nm)
            if not all(map(math.isfinite, values)):
                self._fail(k, f"I1 {joint}: non-finite {values}")
                continue
            if not 0.0 <= c.torque_limit_Nm <= env.max_torque + EPS:
                self._fail(k, f"I1 {joint}: torque limit {c.torque_limit_Nm}")
            if c.mode != JointMode.TRACK:
                continue
            b = env.joints[joint]
            q = c.position_setpoint_rad
            if not b.lower_rad + env.margin - EPS <= q <= b.upper_rad - env.margin + EPS:
                self._fail(k, f"I1 {joint}: setpoint {q:.4f} outside [{b.lower_rad + env.margin:.4f}, {b.upper_rad - env.margin:.4f}]")
            if abs(c.velocity_ff_rad_s) > env.max_velocity + EPS or abs(c.torque_ff_Nm) > env.max_torque + EPS:
                self._fail(k, f"I1 {joint}: feed-forward {c.velocity_ff_rad_s} rad/s, {c.torque_ff_Nm} N.m")
            last = self._last_track.get(node)
            if last is not None and abs(q - last) > env.max_step + EPS:
                self._fail(k, f"I1 {joint}: setpoint step {q - last:+.4f} rad")
            track[node] = q
        self._last_track = track

    # -- I2, I5 ----------------------------------------------------------------------------------

    def _health(self, k: int, state: GaitState) -> None:
        """A TRACK command went out: the FSM moves, and every node is healthy with fresh data."""
        hardware = self.hardware
        if state not in WALKING:
            self._fail(k, f"I2 TRACK command in {state.name}")
        for name, node in hardware.nodes.items():
            if node.nmt != NmtState.OPERATIONAL:
                self._fail(k, f"I2 TRACK command with {name} {node.nmt}")
            if node.status is None or k - node.status_tick > 2:
                self._fail(k, f"I5 TRACK command on {name}'s status of tick {node.status_tick}")
            elif node.status.drive_state == DriveState.FAULT:
                self._fail(k, f"I2 TRACK command with {name}'s drive in FAULT")
        for name in SENSOR_MESSAGES:
            tick = hardware.latest.get(name, (-(10**9), None))[0]
            if k - tick > 2:
                self._fail(k, f"I5 TRACK command on {name} of tick {tick}")

    # -- I3 --------------------------------------------------------------------------------------

    def _learning(self, k: int) -> None:
        """Every new step's theta and length are finite, the length within the step bounds, and the
        swing's aim within the foot placement's offset of it."""
        steps = self.core.steps
        bounds = self.core.policy.bounds
        for step in steps[self._steps_seen:]:
            theta = step.theta
            if theta is not None and not all(map(math.isfinite, theta)):
                self._fail(k, f"I3 step {step.index}: theta {theta}")
            if not (math.isfinite(step.length_m) and bounds.min_m - 1e-9 <= step.length_m <= bounds.max_m + 1e-9):
                self._fail(k, f"I3 step {step.index}: length {step.length_m}")
            if not abs(step.aimed_m - step.length_m) <= self.core.cfg.gait.max_aim_offset_m + 1e-9:  # a NaN fails too
                self._fail(k, f"I3 step {step.index}: aimed at {step.aimed_m} for a length of {step.length_m}")
        self._steps_seen = len(steps)

    # -- I2 (a step), I4, I6 ---------------------------------------------------------------------

    def _transitions(self, k: int, result: TickResult, commands: dict) -> None:
        core, state, before = self.core, result.state, self._state
        moves = [t for t in core.fsm.transitions if t.tick == k]
        if state != before and not moves:
            self._fail(k, f"I6 {before.name} -> {state.name} without a record")
        for t in moves:
            records = [e for e in result.events if f"-> {t.target.name}:" in e]
            if t.target in STOP_STATES and len(records) != 1:
                self._fail(k, f"I6 {len(records)} records of the entry into {t.target.name}")
            if t.target in STOP_STATES:
                self.stops.append(StopRecord(k, t.target, t.cause))
            if t.source == GaitState.FAULT and t.cause != OPERATOR_RESET:
                self._fail(k, f"I4 FAULT left without an operator reset ({t.cause})")
            if t.source == GaitState.FAULT and core.fsm.healthy_ticks < core.fsm.reset_healthy_ticks:
                self._fail(k, f"I4 FAULT left after {core.fsm.healthy_ticks} healthy ticks")
            if t.target in SWINGS:
                stale = [n for n, s in self.hardware.nodes.items() if s.status_tick != k]
                stale += [n for n in SENSOR_MESSAGES if self.hardware.latest.get(n, (-1,))[0] != k]
                if stale:
                    self._fail(k, f"I2 a step started on data older than this tick: {stale}")
        # The first tick whose commands on the bus are all HOLD, after each entry into HOLD or FAULT.
        all_hold = len(commands) == len(self.hardware.node_names) and all(c.mode != JointMode.TRACK for c in commands.values())
        for stop in self.stops:
            if stop.hold_on_bus_tick is None and all_hold and state in STOP_STATES:
                stop.hold_on_bus_tick = k
        if state in STOP_STATES and any(c.mode == JointMode.TRACK for c in commands.values()):
            self._fail(k, f"I2 TRACK command in {state.name}")
        self._state = state
