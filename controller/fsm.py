"""The gait-phase state machine of the main controller (paper Fig. 2, docs/FAULTS.md), pure.

One call per 20 ms tick: :meth:`GaitFsm.step` takes what the tick knows (:class:`FsmInputs`) and
returns the state for this tick. States are the protocol's :class:`~protocol.enums.GaitState`, so
the controller's heartbeat carries them unchanged.

::

    INIT --all nodes operational and healthy--> STAND --start--> DOUBLE_SUPPORT
    DOUBLE_SUPPORT --both sticks loaded and ahead, nodes healthy, data fresh--> SWING_LEFT/RIGHT
    SWING_x --swing done (foot down)--> DOUBLE_SUPPORT  (or STOP when a stop was asked)
    DOUBLE_SUPPORT --stop--> STOP --start--> DOUBLE_SUPPORT
    any --protective stop--> HOLD --reset, when healthy--> STAND
    any --fault--> FAULT (latched) --reset, healthy for `reset_healthy_ticks`, both sticks loaded--> STAND

Rules that are invariants (docs/FAULTS.md I2, I4, I6): no swing starts unless both sticks are loaded and
every node is healthy with fresh data; FAULT is left only by an operator reset with its
preconditions; every entry into HOLD or FAULT produces exactly one :class:`Transition` record with
its cause; a fault overrides a protective stop, which overrides everything else. A stop asked
during a swing takes effect when the swing ends (a foot in the air is never frozen by a stop).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from controller.faults import Fault, FaultKind
from protocol.enums import SWINGS, WALKING, GaitState
#: the cause of leaving HOLD or FAULT
OPERATOR_RESET = "operator reset"


@dataclass(frozen=True)
class FsmInputs:
    """What one tick knows, already reduced to the FSM's questions."""

    nodes_operational: bool = False  # all four nodes report NMT OPERATIONAL
    nodes_healthy: bool = False  # all four E2E-valid, no drive fault, data no older than 2 ticks
    data_fresh: bool = False  # every sample of this tick is new (age <= 1): needed to start a step
    sticks_loaded: bool = False  # both stick forces above the loading threshold
    sticks_ahead: bool = False  # both tips placed ahead of the stance foot
    swing_done: bool = False  # the swing's trajectory has ended and the swing foot carries load
    fault: Fault | None = None  # a fault detected this tick (latches FAULT)
    other_faults: tuple[Fault, ...] = ()  # further faults detected in the same tick (kept with the first)
    protective_stop: Fault | None = None  # the cause of a protective stop this tick (HOLD)
    start: bool = False  # operator: walk
    stop: bool = False  # operator: stop walking
    reset: bool = False  # operator: reset HOLD or FAULT


@dataclass(frozen=True)
class Transition:
    """One state change, for the event log (I6: one record per entry into HOLD or FAULT): its cause
    is the :class:`Fault` of an entry into HOLD or FAULT, else what the gait did (text)."""

    tick: int
    source: GaitState
    target: GaitState
    cause: Fault | str

    @property
    def fault(self) -> Fault | None:
        return self.cause if isinstance(self.cause, Fault) else None


@dataclass
class GaitFsm:
    """The state machine; ``state`` is the state of the last tick."""

    reset_healthy_ticks: int = 25
    state: GaitState = GaitState.INIT
    next_swing: GaitState = GaitState.SWING_RIGHT
    transitions: list[Transition] = field(default_factory=list)
    _healthy_ticks: int = 0
    _stop_pending: bool = False
    _fault_causes: list[Fault] = field(default_factory=list)

    def _go(self, tick: int, target: GaitState, cause: Fault | str) -> None:
        if target != self.state:
            self.transitions.append(Transition(tick, self.state, target, cause))
            self.state = target

    def step(self, tick: int, i: FsmInputs) -> GaitState:
        """Advance one tick; returns the new state."""
        self._healthy_ticks = self._healthy_ticks + 1 if i.nodes_healthy else 0
        s = self.state
        # Highest severity first: a fault latches from any state (a new cause while latched is
        # remembered but not re-announced).
        if i.fault is not None:
            if s != GaitState.FAULT:
                self._fault_causes = []
                self._stop_pending = False
                self._go(tick, GaitState.FAULT, i.fault)
            for cause in (i.fault, *i.other_faults):
                if cause not in self._fault_causes:
                    self._fault_causes.append(cause)
            return self.state
        if s == GaitState.FAULT:
            if i.reset and self._healthy_ticks >= self.reset_healthy_ticks and i.sticks_loaded:
                self._go(tick, GaitState.STAND, OPERATOR_RESET)
            return self.state
        if i.protective_stop is not None:
            self._stop_pending = False
            self._go(tick, GaitState.HOLD, i.protective_stop)
            return self.state
        if s == GaitState.HOLD:
            if i.reset and i.nodes_healthy:
                self._go(tick, GaitState.STAND, OPERATOR_RESET)
            return self.state
        if not i.nodes_healthy and s != GaitState.INIT:
            # Unhealthy without a fault (yet): a protective stop; the fault detectors escalate.
            self._go(tick, GaitState.HOLD, Fault(FaultKind.NODES_UNHEALTHY))
            return self.state

        if s == GaitState.INIT:
            if i.nodes_operational and i.nodes_healthy:
                self._go(tick, GaitState.STAND, "all nodes operational")
        elif s in (GaitState.STAND, GaitState.STOP):
            if i.start:
                self._go(tick, GaitState.DOUBLE_SUPPORT, "start")
        elif s == GaitState.DOUBLE_SUPPORT:
            if i.stop:
                self._go(tick, GaitState.STOP, "stop")
            elif i.sticks_loaded and i.sticks_ahead and i.data_fresh:
                self._go(tick, self.next_swing, "sticks loaded and ahead")
        elif s in SWINGS:
            self._stop_pending = self._stop_pending or i.stop
            if i.swing_done:
                self.next_swing = GaitState.SWING_LEFT if s == GaitState.SWING_RIGHT else GaitState.SWING_RIGHT
                if self._stop_pending:
                    self._stop_pending = False
                    self._go(tick, GaitState.STOP, "stop after the swing")
                else:
                    self._go(tick, GaitState.DOUBLE_SUPPORT, "swing done")
        return self.state

    @property
    def healthy_ticks(self) -> int:
        """Ticks in a row with every node healthy (a reset leaves FAULT after ``reset_healthy_ticks``)."""
        return self._healthy_ticks

    @property
    def fault_causes(self) -> tuple[Fault, ...]:
        """Every cause seen since FAULT latched (the first one is the one announced)."""
        return tuple(self._fault_causes) if self.state == GaitState.FAULT else ()

    @property
    def moving(self) -> bool:
        """Whether the legs may get non-hold commands this tick (I2)."""
        return self.state in WALKING
