"""One session of the controller (ros2_control's controller manager): the tick loop over one
hardware and the core, the operator's buttons, and one status record.

Every driver of a walk is a configuration of :class:`Session`: the controller process on a bus
(real time or lock-step), the in-process lock-step walk of the experiments, the safety rig and
its soak, and the re-simulation of a recorded trace (:class:`~controller.hardware.ReplayHardware`
with the trace's tick numbers). They differ in the hardware and the timing of the loop, and in
when their operator presses a button; what a tick does, how the operator is heard and what the
status says is the session's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.core import ControllerCore, TickResult
from controller.hardware import Hardware
from controller.loop import LockstepLoop
from protocol.enums import DriveState, GaitState


class Operator:
    """The operator's three buttons as the core hears them: start (walk from STAND or STOP), stop
    (after the swing in progress) and reset (of HOLD or FAULT; the nodes clear their faults too).
    Each press counts for the next tick; :attr:`presses` keeps (tick, button)."""

    def __init__(self, core: ControllerCore) -> None:
        self.core = core
        self.next_tick = 0  # the tick a press counts for
        self.presses: list[tuple[int, str]] = []
        self._recovering = False

    def start(self) -> None:
        self.core.request_walk()
        self.presses.append((self.next_tick, "start"))

    def stop(self) -> None:
        self.core.request_stop()
        self.presses.append((self.next_tick, "stop"))

    def reset(self) -> None:
        self.core.request_reset()
        self.presses.append((self.next_tick, "reset"))

    def recover(self) -> None:
        """The reset procedure of a latched FAULT: reset now (the nodes unlatch their quick stop),
        and again once the nodes have been healthy for ``reset_healthy_ticks`` with both sticks
        loaded, which the FSM needs before it leaves FAULT (I4: it takes a reset only when its
        preconditions already hold). Ends when the FSM has left FAULT."""
        self.reset()
        self._recovering = True

    @property
    def recovering(self) -> bool:
        return self._recovering

    def heard(self, result: TickResult) -> None:
        """After each tick: the reset procedure's second press when its time has come."""
        self.next_tick = result.tick + 1
        if not self._recovering:
            return
        fsm = self.core.fsm
        if result.state != GaitState.FAULT:
            self._recovering = False
        elif fsm.healthy_ticks >= fsm.reset_healthy_ticks and result.estimate is not None and all(result.estimate.sticks_loaded):
            self.reset()


@dataclass(frozen=True, slots=True)
class Status:
    """What the session shows its operator, one record a tick (:meth:`line` is the one printer)."""

    tick: int
    state: GaitState
    nodes: tuple[tuple[str, str], ...]  # (node, its NMT state's name; "" before its first heartbeat)
    drive_faults: tuple[str, ...]  # nodes whose drive reports FAULT
    healthy_ticks: int
    reset_healthy_ticks: int
    timeouts: int  # ticks whose node frames were not all in by the read's deadline
    steps: int  # steps started
    step: str  # the newest step: "3 (l) 0.120 m", or ""
    stick_force_n: tuple[float, float] | None
    x_ratio: float  # X_CoM/X_SP (nan without an estimate)
    sticks_loaded: int | None
    feet_loaded: int | None

    def line(self, t_s: float | None = None) -> str:
        """One line: the tick (and ``t_s``, the session's time), the state, the nodes, the newest
        step, the sticks and X_CoM/X_SP; in FAULT or HOLD what a reset waits for."""
        nodes = " ".join(f"{n.split('_')[0][0]}{n.split('_')[1][0]}:{(nmt[:4] if nmt else '----')}" for n, nmt in self.nodes)
        text = f"tick {self.tick}" + (f" {t_s:6.1f} s" if t_s is not None else "") + f" {self.state.name:<14} | {nodes}"
        if self.step:
            text += f" | step {self.step}"
        if self.stick_force_n is not None:
            text += f" | sticks {self.stick_force_n[0]:4.0f} {self.stick_force_n[1]:4.0f} N"
        if math.isfinite(self.x_ratio):
            text += f" | X_CoM/X_SP {self.x_ratio:.2f} | loaded: sticks {self.sticks_loaded} feet {self.feet_loaded}"
        if self.state in (GaitState.FAULT, GaitState.HOLD):  # what a reset waits for (I4): the operator sees why nothing happens
            text += f" | healthy {self.healthy_ticks}/{self.reset_healthy_ticks} ticks"
            if self.drive_faults:
                text += f", drive FAULT: {' '.join(self.drive_faults)}"
        return text + f" | timeouts {self.timeouts}"


class Session:
    """The loop, the core, the hardware and the operator of one controller run (see the module doc)."""

    def __init__(self, loop: LockstepLoop) -> None:
        self.loop = loop
        self.core: ControllerCore = loop.core
        self.hardware: Hardware = loop.hardware
        self.operator = Operator(self.core)
        self.last: TickResult | None = None

    @property
    def state(self) -> GaitState:
        return self.core.fsm.state

    @property
    def tick(self) -> int:
        return self.loop.tick

    def step(self) -> TickResult:
        """One tick: read, update, write (:class:`~controller.loop.LockstepLoop`), and the operator hears it."""
        result = self.loop.step()
        self.operator.heard(result)
        self.last = result
        return result

    def skipped(self, tick: int, ticks: int) -> None:
        """``ticks`` ticks before ``tick`` did not run (a recorded real-time run's overrun): the
        core hears of it as from the real-time loop's timer, and the next step is ``tick``."""
        self.core.overran(tick, ticks)
        self.loop.resume_at(tick)

    def status(self) -> Status:
        result, core, hw = self.last, self.core, self.hardware
        est = result.estimate if result is not None else None
        m = result.measurements if result is not None else None
        last = core.steps[-1] if core.steps else None
        return Status(
            tick=result.tick if result is not None else -1,
            state=core.fsm.state,
            nodes=tuple((n, s.nmt.name if s.nmt is not None else "") for n, s in hw.nodes.items()),
            drive_faults=tuple(n for n, s in hw.nodes.items() if s.status is not None and s.status.drive_state == DriveState.FAULT),
            healthy_ticks=core.fsm.healthy_ticks,
            reset_healthy_ticks=core.fsm.reset_healthy_ticks,
            timeouts=hw.counters.timeouts,
            steps=len(core.steps),
            step=f"{last.index + 1} ({last.leg}) {last.length_m:.3f} m" if last is not None else "",
            stick_force_n=None if m is None else (float(m.stick_force_n[0]), float(m.stick_force_n[1])),
            x_ratio=est.x_ratio if est is not None else math.nan,
            sticks_loaded=sum(est.sticks_loaded) if est is not None else None,
            feet_loaded=sum(est.feet_loaded) if est is not None else None,
        )
