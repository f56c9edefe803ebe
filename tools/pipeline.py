"""A walk through the whole pipeline: the main controller, the four emulated node boards and the
simulated HHEA, talking CAN frames in lock-step.

* :func:`walk`: everything in one process on python-can's in-process virtual bus. Every frame the
  controller sends or reads is encoded, CRC-protected and counted exactly as on a real bus; only
  the transport is a queue. What ``aider-exo walk`` runs by default and the experiments build on.
* :func:`walk_controller`: the controller's side alone on a bus whose nodes run elsewhere (``aider-exo
  nodes`` in another process on ``vcan0``).

Lock-step makes a walk deterministic for a seed. The simulation's ground truth (falls, X_CoM/X_SP)
is read beside the pipeline, never fed into it.
"""

from __future__ import annotations

import math
import subprocess
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from config import Config, with_overrides
from controller.core import ControllerCore, TickResult
from controller.hardware import CanHardware
from controller.faults import FaultKind
from controller.loop import LockstepLoop
from controller.session import Session
from controller.policy import StepPolicy, StepRecord
from controller.telemetry import TelemetryLog
from protocol.bus import virtual_bus
from protocol.clock import TICK_MS, MonotonicClock
from protocol.enums import GaitState
from sim.pace import default_max_time_s

#: called after every tick with the tick's result and the controller core
TickHook = Callable[[TickResult, Session], None]


@dataclass
class WalkOutcome:
    """A walk through the pipeline, as the controller saw it and as the simulation knows it."""

    mode: str
    seed: int
    policy: str
    steps: list[StepRecord]
    fell: bool = False
    fall_reason: str | None = None  # the simulation's fall criterion, or the controller's fall detection
    fault: str | None = None  # the cause the controller's FAULT latched on
    hold: str | None = None  # the cause of the controller's protective stop (HOLD, latched until a reset)
    stalled: bool = False  # the time ran out before the cycles were walked
    final_state: str = ""
    patient: dict[str, Any] | None = None  # the simulated patient's place in its gait at the end (whom a stall waits for)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    ticks: int = 0
    ratio_errors: list[float] = field(default_factory=list)  # |estimate - truth| per tick where both exist
    arm_torques_nm: list[float] = field(default_factory=list)  # ground truth: mean upper-body torque of each landed step
    # ground truth: the patient's intended stick placement (sim.patient.intention) per step, the one in the making last
    intentions_m: list[float] = field(default_factory=list)
    stick_clamps: dict[str, int] = field(default_factory=dict)  # stick goals the patient's arm reach or advance moved
    events: list[str] = field(default_factory=list)
    receiver: dict[str, Any] = field(default_factory=dict)
    theta: tuple[float, float] | None = None
    timing: dict[str, Any] = field(default_factory=dict)

    @property
    def landed(self) -> list[StepRecord]:
        return [s for s in self.steps if s.landed]

    @property
    def cycles_completed(self) -> int:
        return len(self.landed) // 2

    @property
    def mean_stick_force_n(self) -> float:
        forces = [s.mean_stick_force_n for s in self.landed]
        return float(np.mean(forces)) if forces else math.nan

    @property
    def mean_arm_torque_nm(self) -> float:
        return float(np.mean(self.arm_torques_nm)) if self.arm_torques_nm else math.nan

    @property
    def ratio_mae(self) -> float:
        return float(np.mean(self.ratio_errors)) if self.ratio_errors else math.nan

    def summary(self) -> dict[str, Any]:
        lengths = [s.length_m for s in self.landed]
        return {
            "mode": self.mode,
            "seed": self.seed,
            "policy": self.policy,
            "theta": None if self.theta is None else [round(v, 4) for v in self.theta],
            "cycles_completed": self.cycles_completed,
            "steps_completed": len(self.landed),
            "falls": int(self.fell),
            "fall_reason": self.fall_reason,
            "fault": self.fault,
            "hold": self.hold,
            "stalled": self.stalled,
            "final_state": self.final_state,
            "patient": self.patient,
            "stick_clamps": self.stick_clamps,
            "mean_stick_force_n": _round(self.mean_stick_force_n, 2),
            "mean_arm_torque_nm": _round(self.mean_arm_torque_nm, 2),
            "step_length_m": _spread(lengths),
            # as the feet stood when the next swing started (the last step has none)
            "placed_step_m": _spread([s.placed_m for s in self.landed if math.isfinite(s.placed_m)]),
            "x_ratio_mae": _round(self.ratio_mae),
            "x_ratio_samples": len(self.ratio_errors),
            "sim_time_s": round(self.sim_time_s, 2),
            "wall_time_s": round(self.wall_time_s, 2),
            "ticks": self.ticks,
            "receiver": self.receiver,
            "timing": self.timing,
            "steps": [s.as_dict() for s in self.steps],
        }


def _round(x: float, digits: int = 4) -> float | None:
    return round(x, digits) if math.isfinite(x) else None


def _spread(values: list[float]) -> dict[str, float | None]:
    """Mean, min and max of ``values`` (None for none)."""
    return {"mean": _round(float(np.mean(values)) if values else math.nan),
            "min": _round(min(values, default=math.nan)), "max": _round(max(values, default=math.nan))}


class Pace:
    """Holds a lock-step walk to ``factor`` times real time: tick ``k`` ends no earlier than
    ``k + 1`` ticks of 20 ms (divided by ``factor``) after the first (0: no pacing)."""

    def __init__(self, factor: float, clock: MonotonicClock | None = None) -> None:
        self.factor = factor
        self.clock = clock or MonotonicClock()
        self._t0_ns: int | None = None

    def __call__(self, tick: int) -> None:
        if self.factor <= 0:
            return
        tick_ns = int(TICK_MS * 1_000_000 / self.factor)
        if self._t0_ns is None:
            self._t0_ns = self.clock.now_ns() - tick * tick_ns
        self.clock.sleep_until(self._t0_ns + (tick + 1) * tick_ns)


def walk_config(cfg: Config, mode: str, channel: str) -> Config:
    """``cfg`` for an in-process walk: the simulation in ``mode`` on a virtual bus named ``channel``."""
    return with_overrides(cfg, {"sim.mode": mode, "bus.interface": "virtual", "bus.channel": channel})


#: simulated seconds without a step landing after which a walk counts as stalled (its slowest
#: steps take about 20 s: stick moves, a lean that waits for the swing foot to come free)
STALL_S = 40.0


def drive(
    session: Session, outcome: WalkOutcome, *, cycles: int, max_ticks: int,
    truth_ratio: Callable[[], float] | None = None, fallen: Callable[[], str | None] | None = None,
    on_tick: TickHook | None = None, stall_s: float = STALL_S,
) -> TickResult | None:
    """Run ``session`` with walking asked until ``cycles`` gait cycles have landed, a fall, a FAULT, a
    HOLD, ``max_ticks``, or ``stall_s`` of simulated time without a step landing (both a stall); fills
    ``outcome`` (the steps are the core's own list)."""
    core, loop = session.core, session.loop
    session.operator.start()
    result = None
    stall_ticks = int(stall_s * 1000 / TICK_MS)
    landed, last_landing = 0, 0
    for tick in range(max_ticks):
        result = session.step()
        if truth_ratio is not None and result.estimate is not None and math.isfinite(result.estimate.x_ratio):
            truth = truth_ratio()  # the simulation's ground truth costs about 5 % of a walk: only when compared
            if math.isfinite(truth):
                outcome.ratio_errors.append(abs(result.estimate.x_ratio - truth))
        if on_tick is not None:
            on_tick(result, session)
        fall = fallen() if fallen is not None else None
        if fall:
            outcome.fell, outcome.fall_reason = True, fall
            core.walk_ended(fell=True)
            break
        if result.state == GaitState.FAULT:
            fault = core.fsm.transitions[-1].fault
            outcome.fault = str(fault)
            if fault.kind is FaultKind.FALL:
                outcome.fell, outcome.fall_reason = True, outcome.fault
            break
        if result.state == GaitState.HOLD:
            # latched until an operator's reset, which an in-process walk has not: it ends here
            # (waiting out the stall time would only hide the cause)
            outcome.hold = str(core.fsm.transitions[-1].cause)
            break
        if len(outcome.landed) >= 2 * cycles:
            break
        if len(outcome.landed) != landed:
            landed, last_landing = len(outcome.landed), tick
        elif tick - last_landing >= stall_ticks:
            outcome.stalled = True
            break
    else:
        outcome.stalled = True
    outcome.final_state = result.state.name if result else ""
    outcome.ticks = loop.report.ticks
    outcome.events = loop.report.events
    outcome.receiver = loop.hardware.rx.stats.as_dict()
    outcome.timing = loop.stats.summary()
    outcome.theta = core.policy.current_theta() if core.policy.learner is None else tuple(core.policy.learner.evaluation_theta())
    return result


def walk(
    cfg: Config, *, cycles: int, seed: int, mode: str | None = None, policy: StepPolicy | None = None,
    max_time_s: float | None = None, on_tick: Callable[[TickResult, Session, Any], None] | None = None,
    channel: str | None = None, telemetry: TelemetryLog | None = None, stall_s: float = STALL_S,
    compare_ratio: bool = True,
) -> WalkOutcome:
    """Walk ``cycles`` gait cycles (a left and a right step each) with everything in this process;
    ``mode``: the simulation's (default ``cfg.sim.mode``). Ends early at a fall, a controller fault,
    or a stall: ``max_time_s`` of simulated time (default
    :func:`default_max_time_s`) or ``stall_s`` without a step landing. Deterministic for ``seed``. ``on_tick(result, core,
    host)`` sees the nodes' host too (the simulation, for recording). ``compare_ratio``: the estimated
    X_CoM/X_SP against the simulation's ground truth every tick (``ratio_errors``; about 5 % of the
    walk's time; the walk itself is the same without it)."""
    from nodes.host import NodesHost

    channel = channel or f"aider-walk-{seed}-{id(cfg)}"
    mode = mode or cfg.sim.mode
    cfg = walk_config(cfg, mode, channel)
    max_time_s = max_time_s if max_time_s is not None else default_max_time_s(cycles)
    core = ControllerCore(cfg.controller, policy=policy)
    outcome = WalkOutcome(mode=mode, seed=seed, policy=core.policy.mode, steps=core.steps)
    clock = MonotonicClock()
    t0 = clock.now_ns()
    with virtual_bus(channel) as node_bus, \
            virtual_bus(channel) as ctl_bus:
        host = NodesHost(cfg, node_bus, lockstep=True, seed=seed)
        try:
            host.boot()
            hardware = CanHardware(cfg.controller, ctl_bus, pump=lambda: host.poll(0.0),
                                   max_delta_counter=cfg.protocol.max_delta_counter)
            session = Session(LockstepLoop(core, hardware, telemetry=telemetry))
            drive(
                session, outcome, cycles=cycles, max_ticks=int(max_time_s * 1000 / TICK_MS),
                truth_ratio=(lambda: host.truth()["x_ratio"]) if compare_ratio else None,
                fallen=lambda: host.plant.patient.fall,
                on_tick=None if on_tick is None else (lambda r, s: on_tick(r, s, host)), stall_s=stall_s,
            )
            outcome.sim_time_s, outcome.patient = host.plant.patient.t, host.plant.patient.patient_state()
            # the simulation's own steps (foot contacts): the six arm joints' absolute torques, summed
            outcome.arm_torques_nm = [st.mean_arm_torque_nm for st in host.plant.patient.steps if st.landed]
            outcome.intentions_m, outcome.stick_clamps = host.plant.patient.intentions_m(), dict(host.plant.patient.clamps)
        finally:
            host.close()
    outcome.wall_time_s = (clock.now_ns() - t0) / 1e9
    return outcome


def walk_controller(
    cfg: Config, bus: can.BusABC, *, cycles: int, seed: int, mode: str, policy: StepPolicy | None = None,
    max_time_s: float | None = None, on_tick: TickHook | None = None, telemetry: TelemetryLog | None = None,
) -> WalkOutcome:
    """The controller's side of a lock-step walk over ``bus``, whose nodes run in another process
    (they must be up, in lock-step). Falls are the controller's own fall detection; the
    simulation's ground truth stays with the nodes."""
    max_time_s = max_time_s if max_time_s is not None else default_max_time_s(cycles)
    core = ControllerCore(cfg.controller, policy=policy)
    outcome = WalkOutcome(mode=mode, seed=seed, policy=core.policy.mode, steps=core.steps)
    clock = MonotonicClock()
    t0 = clock.now_ns()
    session = Session(LockstepLoop(core, CanHardware(cfg.controller, bus, max_delta_counter=cfg.protocol.max_delta_counter),
                                   telemetry=telemetry))
    drive(session, outcome, cycles=cycles, max_ticks=int(max_time_s * 1000 / TICK_MS), on_tick=on_tick)
    outcome.sim_time_s = outcome.ticks * TICK_MS / 1000.0
    outcome.wall_time_s = (clock.now_ns() - t0) / 1e9
    return outcome


def wait_for_boot_ups(bus_cfg: Any, nodes: subprocess.Popen, timeout_s: float = 120.0) -> None:
    """Until the four node boards' boot-up heartbeats are on the bus ``bus_cfg`` (seen on a socket of
    our own), from the nodes process ``nodes`` (an error when it exits first or after ``timeout_s``)."""
    from config.errors import AiderError
    from protocol.bus import open_bus
    from protocol.codec import Codec, Decoded
    from protocol.enums import NmtState

    codec, clock = Codec(), MonotonicClock()
    booted: set[str] = set()
    deadline = clock.now_ns() + int(timeout_s * 1e9)
    probe = open_bus(bus_cfg)
    try:
        while len(booted) < len(codec.catalog.joint_nodes):
            if nodes.poll() is not None:
                raise AiderError(f"the nodes process exited with {nodes.returncode} before booting")
            if clock.now_ns() > deadline:
                raise AiderError(f"the nodes did not boot within {timeout_s:.0f} s (seen: {sorted(booted) or 'none'})")
            msg = probe.recv(timeout=0.1)
            if msg is None:
                continue
            result = codec.decode(msg.arbitration_id, bytes(msg.data))  # total: foreign frames are rejections
            if type(result) is Decoded and result.message.family == "HEARTBEAT" and result.values.nmt_state == NmtState.BOOT_UP:
                booted.add(result.message.sender)
    finally:
        probe.shutdown()
