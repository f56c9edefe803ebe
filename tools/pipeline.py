"""The whole pipeline in one process: the main controller, the four emulated node boards and the
simulated HHEA, talking CAN frames over python-can's in-process virtual bus in lock-step.

This is what ``aider-exo walk`` runs (and the experiments build on): every frame the controller
sends or reads is encoded, CRC-protected and counted exactly as on a real bus; only the transport
is a queue. Lock-step makes a walk deterministic for a seed. The simulation's ground truth (falls,
X_CoM/X_SP) is read beside the pipeline, never fed into it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from config import Config, with_overrides
from controller.core import ControllerCore, TickResult
from controller.loop import LockstepLoop
from controller.policy import StepPolicy, StepRecord
from nodes.host import NodesHost
from protocol.catalog import TICK_MS
from protocol.clock import MonotonicClock


@dataclass
class WalkOutcome:
    """A walk through the pipeline, as the controller saw it and as the simulation knows it."""

    mode: str
    seed: int
    policy: str
    steps: list[StepRecord]
    fell: bool = False
    fall_reason: str | None = None
    stalled: bool = False  # the time ran out before the cycles were walked
    final_state: str = ""
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    ticks: int = 0
    ratio_errors: list[float] = field(default_factory=list)  # |estimate - truth| per tick where both exist
    events: list[str] = field(default_factory=list)
    receiver: dict[str, Any] = field(default_factory=dict)
    theta: tuple[float, float] | None = None

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
            "stalled": self.stalled,
            "final_state": self.final_state,
            "mean_stick_force_n": _round(self.mean_stick_force_n, 2),
            "step_length_m": {"mean": _round(float(np.mean(lengths)) if lengths else math.nan),
                              "min": _round(min(lengths, default=math.nan)), "max": _round(max(lengths, default=math.nan))},
            "x_ratio_mae": _round(self.ratio_mae),
            "x_ratio_samples": len(self.ratio_errors),
            "sim_time_s": round(self.sim_time_s, 2),
            "wall_time_s": round(self.wall_time_s, 2),
            "ticks": self.ticks,
            "receiver": self.receiver,
            "steps": [s.as_dict() for s in self.steps],
        }


def _round(x: float, digits: int = 4) -> float | None:
    return round(x, digits) if math.isfinite(x) else None


def walk_config(cfg: Config, mode: str, channel: str) -> Config:
    """``cfg`` for an in-process walk: the simulation in ``mode`` on a virtual bus named ``channel``."""
    return with_overrides(cfg, {"sim.mode": mode, "bus.interface": "virtual", "bus.channel": channel})


def walk(
    cfg: Config, *, cycles: int, seed: int, mode: str = "sagittal", policy: StepPolicy | None = None,
    max_time_s: float | None = None, on_tick: Callable[[TickResult, ControllerCore, NodesHost], None] | None = None,
    channel: str | None = None,
) -> WalkOutcome:
    """Walk ``cycles`` gait cycles (a left and a right step each) through the pipeline; ends early
    at a fall, a controller fault, or ``max_time_s`` of simulated time (default: 20 s plus 15 s per
    cycle, a stall). Deterministic for ``seed``."""
    channel = channel or f"aider-walk-{seed}-{id(cfg)}"
    cfg = walk_config(cfg, mode, channel)
    max_time_s = max_time_s if max_time_s is not None else 20.0 + 15.0 * cycles
    max_ticks = int(max_time_s * 1000 / TICK_MS)
    core = ControllerCore(cfg.controller, policy=policy)
    outcome = WalkOutcome(mode=mode, seed=seed, policy=core.policy.mode, steps=core.steps)
    body = cfg.controller.body
    clock = MonotonicClock()
    t0 = clock.now_ns()
    with can.Bus(interface="virtual", channel=channel, ignore_config=True) as node_bus, \
            can.Bus(interface="virtual", channel=channel, ignore_config=True) as ctl_bus:
        host = NodesHost(cfg, node_bus, lockstep=True, seed=seed)
        try:
            host.boot()
            loop = LockstepLoop(core, ctl_bus, pump=lambda: host.poll(0.0), max_delta_counter=cfg.protocol.max_delta_counter)
            core.request_walk()
            result = None
            for _ in range(max_ticks):
                result = loop.step()
                if result.estimate is not None:
                    truth = host.patient.x_ratio_truth(body.foot_loaded_n, body.stick_loaded_n, body.min_support_m)
                    if math.isfinite(truth) and math.isfinite(result.estimate.x_ratio):
                        outcome.ratio_errors.append(abs(result.estimate.x_ratio - truth))
                if on_tick is not None:
                    on_tick(result, core, host)
                if host.patient.fall:
                    outcome.fell, outcome.fall_reason = True, host.patient.fall
                    core.policy.fell()
                    break
                if result.state.name == "FAULT":
                    break
                if len([s for s in core.steps if s.landed]) >= 2 * cycles:
                    break
            else:
                outcome.stalled = True
            outcome.final_state = result.state.name if result else ""
            outcome.sim_time_s = host.patient.t
            outcome.ticks = loop.report.ticks
            outcome.events = loop.report.events
            outcome.receiver = loop.rx.stats.as_dict()
        finally:
            host.close()
    outcome.theta = core.policy.current_theta() if core.policy.learner is None else None
    outcome.wall_time_s = (clock.now_ns() - t0) / 1e9
    return outcome
