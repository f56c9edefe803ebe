"""Where each step's length comes from, and what each step cost (pure; the learner's file I/O is
the caller's).

* **fixed**: every step the same length (the baseline without compensation);
* **compensated**: the paper's equation (8) with a fixed theta = (alpha, Xhat_CoM), from the
  configuration or a patient's learned file;
* **learning**: the compensation with the theta that online PI² (:class:`controller.pi2.Pi2Learner`)
  proposes for the current roll-out of ``N`` gait cycles; each cycle's cost is the mean stick force
  over its two steps (paper equation (10)), a fall ends the roll-out with its terminal cost.

A step runs from the previous landing (or the start of walking) to its own landing; its mean stick
force is the mean over those ticks of the two sticks' mean force, as the simulation's ground truth
defines a step's cost.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from config.errors import AiderError
from controller.compensation import StepBounds, StepGoal, compensated_step
from controller.interfaces import LearningTelemetry, StepTelemetry
from controller.pi2 import Pi2Learner, UpdateRecord
from protocol.enums import PolicyMode


class PolicyError(AiderError):
    """A step policy that cannot be used (a fixed step outside the safe range, ...)."""


@dataclass
class StepRecord:
    """One step as the controller saw it."""

    index: int
    leg: str  # "l" or "r"
    start_tick: int  # the previous landing (or the start of walking)
    swing_tick: int = -1
    end_tick: int = -1
    length_m: float = math.nan  # commanded (after the clamp)
    aimed_m: float = math.nan  # where the swing aimed: the length plus the foot placement's offset
    placed_m: float = math.nan  # as placed: the swing ankle ahead of the other when the next swing starts
    requested_m: float = math.nan
    clamped: bool = False
    # X_CoM / X_SP at the swing's start over the support that carries the swing (the stance ankle
    # and both stick tips): the compensation's input
    x_ratio: float = math.nan
    x_ratio_planted: float = math.nan  # the same over both feet and both tips
    theta: tuple[float, float] | None = None
    landed: bool = False
    force_sum_n: float = 0.0
    samples: int = 0

    def add(self, stick_force_n: np.ndarray) -> None:
        left, right = stick_force_n.tolist()  # the two sticks' mean, as np.mean sums and divides
        self.force_sum_n += (left + right) / 2
        self.samples += 1

    @property
    def mean_stick_force_n(self) -> float:
        return self.force_sum_n / self.samples if self.samples else math.nan

    def as_dict(self) -> dict:
        return {
            "index": self.index, "leg": self.leg, "start_tick": self.start_tick, "swing_tick": self.swing_tick,
            "end_tick": self.end_tick, "length_m": _r(self.length_m), "aimed_m": _r(self.aimed_m), "placed_m": _r(self.placed_m), "requested_m": _r(self.requested_m),
            "clamped": self.clamped, "x_ratio": _r(self.x_ratio), "x_ratio_planted": _r(self.x_ratio_planted),
            "theta": None if self.theta is None else [round(v, 4) for v in self.theta],
            "landed": self.landed, "mean_stick_force_n": _r(self.mean_stick_force_n, 2),
        }


def cycle_costs(step_forces: list[float]) -> list[float]:
    """The immediate cost of every completed gait cycle, from the mean stick force of each step in
    order: the mean over the cycle's two steps (paper equation (10))."""
    return [float(np.mean(step_forces[i:i + 2])) for i in range(0, len(step_forces) - 1, 2)]


def _r(x: float, digits: int = 4) -> float | None:
    return round(x, digits) if math.isfinite(x) else None


@dataclass
class StepPolicy:
    """The step length of every swing, and the bookkeeping of what the steps cost."""

    bounds: StepBounds
    fixed_m: float | None = None
    theta: tuple[float, float] = (0.0, 0.0)  # (alpha, Xhat_CoM) when not learning
    learner: Pi2Learner | None = None
    on_update: Callable[[Pi2Learner, UpdateRecord | None], None] | None = None  # after every roll-out
    cycle_costs: list[float] = field(default_factory=list)  # of the current roll-out
    _pending: list[float] = field(default_factory=list)  # step costs of the unfinished gait cycle

    def __post_init__(self) -> None:
        if self.fixed_m is not None and not self.bounds.min_m <= self.fixed_m <= self.bounds.max_m:
            raise PolicyError(f"fixed step {self.fixed_m} m outside the safe range [{self.bounds.min_m}, {self.bounds.max_m}] m (controller.step)")
        if self.fixed_m is not None and self.learner is not None:
            raise PolicyError("a fixed step length cannot be learned")

    @property
    def mode(self) -> str:
        return "fixed" if self.fixed_m is not None else "learning" if self.learner is not None else "compensated"

    def current_theta(self) -> tuple[float, float] | None:
        if self.fixed_m is not None:
            return None
        if self.learner is not None:
            alpha, xhat = self.learner.ask()
            return float(alpha), float(xhat)
        return self.theta

    def goal(self, x_ratio: float) -> tuple[StepGoal, tuple[float, float] | None]:
        """The step length for a swing that starts with the CoM at ``x_ratio`` of the support."""
        if self.fixed_m is not None:
            return StepGoal(self.fixed_m, self.fixed_m, False), None
        theta = self.current_theta()
        return compensated_step(self.bounds, theta[0], theta[1], x_ratio), theta

    def landed(self, step: StepRecord) -> None:
        """A step has landed: with learning, every second one closes a gait cycle."""
        if self.learner is None:
            return
        self._pending.append(step.mean_stick_force_n)
        if len(self._pending) < 2:
            return
        (cost,) = cycle_costs(self._pending)
        self._pending.clear()
        self.learner.tell_step(cost)
        self.cycle_costs.append(cost)
        if len(self.cycle_costs) >= self.learner.params.steps_per_rollout:
            self._end_rollout(fell=False)

    def fell(self) -> None:
        """The walk ended in a fall: the roll-out ends with its terminal cost."""
        if self.learner is not None and self.learner.in_rollout:
            self._end_rollout(fell=True)

    def abandon(self) -> None:
        """The walk stopped without a fall before the roll-out's end: it never enters an update."""
        if self.learner is not None:
            self.learner.abort_rollout()
            self.cycle_costs.clear()
            self._pending.clear()

    def _end_rollout(self, fell: bool) -> None:
        record = self.learner.end_rollout(fell)
        self.cycle_costs.clear()
        self._pending.clear()
        if self.on_update is not None:
            self.on_update(self.learner, record)


def step_telemetry(steps: list[StepRecord], policy: StepPolicy) -> StepTelemetry:
    """The newest step for monitors: its length, the one before it as placed, the newest landed
    step's cost and the policy's mode (an experiment's random lengths show as fixed: no theta)."""
    last = steps[-1] if steps else None
    before = steps[-2] if len(steps) > 1 else None
    landed = next((st for st in reversed(steps) if st.landed), None)
    mode = PolicyMode.__members__.get(policy.mode.upper(), PolicyMode.FIXED)
    return StepTelemetry(len(steps), last.length_m if last else 0.0, before.placed_m if before else 0.0,
                         landed.mean_stick_force_n if landed else 0.0, mode)


def learning_telemetry(steps: list[StepRecord], policy: StepPolicy) -> LearningTelemetry:
    """The theta of the newest step (or the compensation's before the first) and the learner's progress."""
    theta = next((st.theta for st in reversed(steps) if st.theta is not None), None)
    if theta is None:
        theta = policy.theta if policy.fixed_m is None and policy.learner is None else (0.0, 0.0)
    learner = policy.learner
    if learner is None:
        return LearningTelemetry(*theta)
    costs = policy.cycle_costs
    return LearningTelemetry(theta[0], theta[1], learner.n_updates, learner.rollouts_in_batch, len(costs),
                             costs[-1] if costs else 0.0)
