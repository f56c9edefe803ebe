"""Online PI² from the paper's starting points (Fig. 7), one roll-out per walk.

A learning run is a generator: it yields the walks it needs next (the roll-outs of a batch, and
the noise-free evaluation of the last update beside them) and receives their results, so that
:func:`tools.experiment.schedule.drive` can run many runs' walks in parallel. Every roll-out is a
fresh walk of ``N`` gait cycles from standing (the world reloaded); the learner's exploration comes
from its own seeded stream, and :meth:`controller.pi2.Pi2Learner.ask_batch` draws it exactly as
roll-outs one after another would.

Common random numbers (:class:`RolloutDesign`, a property of the experiment in simulation, not of
the learner: a real patient cannot walk the same intentions twice):

* **Paired roll-outs.** The K roll-outs of an update walk one patient seed (seeded from seed, start
  and update), so they see the same intention sequence and their costs differ by theta rather than
  by the patient's luck; every update draws a new one. Unpaired, each roll-out has its own seed.
* **Averaged evaluation.** The noise-free walk of an update is ``evaluation_walks`` walks of theta
  on a fixed set of seeds (the same for every update of the run), its cost their mean.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from config import Config
from controller.factory import pi2_params
from controller import pi2
from controller.pi2 import Pi2Learner
from tools.experiment.runner import ExperimentError, WalkJob

#: the paper's starting points (Table II) as theta = (alpha, Xhat_CoM)
STARTS: dict[str, tuple[float, float]] = {"A": (-1.0, 0.6), "B": (-0.4, 0.9)}

Results = list[dict[str, Any]]
RunGenerator = Generator[list[WalkJob], Results, "LearningRun"]


def walk_seed(*path: int) -> int:
    """A walk's patient seed from its place in the experiment (a 31-bit integer)."""
    return int(np.random.SeedSequence(list(path)).generate_state(1)[0] >> 1)


def rollout_cost(result: dict[str, Any], n: int, fall_cost: float, force_cost: float) -> float:
    """Paper equation (11) for one walk (:func:`controller.pi2.rollout_cost`): ``lambda1 (N - m) / N
    + lambda2 sum r`` with m the gait cycles it completed."""
    costs = result["cycle_costs"][:n]
    return pi2.rollout_cost(costs, len(costs), n, fall_cost, force_cost)


@dataclass(frozen=True)
class RolloutDesign:
    """How a learning run draws its walks' seeds (the module docstring)."""

    paired: bool = True
    evaluation_walks: int = 5

    def __post_init__(self) -> None:
        if self.evaluation_walks < 1:
            raise ExperimentError(f"evaluation walks must be at least 1, got {self.evaluation_walks}")

    def walks_per_run(self, updates: int, rollouts: int) -> int:
        """Walks of one learning run of ``updates`` updates of ``rollouts`` roll-outs: each update's
        roll-outs and the evaluation before it, and the last evaluation."""
        return updates * (rollouts + self.evaluation_walks) + self.evaluation_walks


@dataclass
class Update:
    """One point of the learning curve: theta after ``index`` updates (0: the start)."""

    index: int
    theta: tuple[float, float]  # the running theta
    evaluation_theta: tuple[float, float]  # the deployed (averaged) theta, walked noise-free
    evaluation_cost: float  # the mean over the evaluation walks
    evaluation_cycles: int  # the fewest gait cycles any evaluation walk completed
    evaluation_end: str  # "walked" when every evaluation walk did, else the end of the one with the fewest cycles
    evaluation_costs: list[float] = field(default_factory=list)  # per evaluation walk
    batch_mean_cost: float | None = None  # the roll-outs that made this update
    batch_mean_cycles: float | None = None  # their average stable gait cycles
    batch_falls: int | None = None
    noise: tuple[float, float] | None = None


@dataclass
class LearningRun:
    start: str
    seed: int
    theta0: tuple[float, float]
    updates: list[Update] = field(default_factory=list)
    rollouts: list[dict[str, Any]] = field(default_factory=list)  # every roll-out walk, in order, with its update index
    rejections: list[str] = field(default_factory=list)
    learning_disabled: bool = False

    @property
    def name(self) -> str:
        return f"{self.start}-s{self.seed}"

    @property
    def final(self) -> Update:
        return self.updates[-1]

    def as_dict(self) -> dict[str, Any]:
        return {
            "start": self.start, "seed": self.seed, "theta0": list(self.theta0),
            "updates": [u.__dict__ for u in self.updates],
            "rejections": self.rejections, "learning_disabled": self.learning_disabled,
        }


def rollout_seeds(seed: int, start_id: int, update: int, k: int, design: RolloutDesign) -> list[int]:
    """The patient seeds of update ``update``'s ``k`` roll-outs: one shared seed when paired."""
    if design.paired:
        return [walk_seed(seed, start_id, update)] * k
    return [walk_seed(seed, start_id, update, i + 1) for i in range(k)]


def evaluation_seeds(seed: int, start_id: int, design: RolloutDesign) -> list[int]:
    """The fixed seeds of a run's noise-free evaluations (update 0 is no roll-out's)."""
    return [walk_seed(seed, start_id, 0, j) for j in range(design.evaluation_walks)]


def learning_run(cfg: Config, start: str, seed: int, *, updates: int, mode: str = "sagittal",
                 design: RolloutDesign = RolloutDesign()) -> RunGenerator:
    """Learn from ``STARTS[start]`` for ``updates`` updates (a generator of walk batches, see the
    module docstring); returns the :class:`LearningRun`."""
    params = pi2_params(cfg.controller)
    theta0 = STARTS[start]
    start_id = sorted(STARTS).index(start)
    learner = Pi2Learner(params, np.array(theta0), np.random.default_rng(np.random.SeedSequence([seed, start_id, 1])))
    run = LearningRun(start=start, seed=seed, theta0=theta0)
    n = params.steps_per_rollout
    eval_seeds = evaluation_seeds(seed, start_id, design)

    def evaluation(theta: np.ndarray) -> list[WalkJob]:
        return [WalkJob(seed=s, cycles=n, theta=_theta(theta), mode=mode) for s in eval_seeds]

    def cost(result: dict[str, Any]) -> float:
        return rollout_cost(result, n, params.lambda1, params.lambda2)

    pending_eval = evaluation(learner.evaluation_theta())
    batch_summary: dict[str, Any] = {}
    for u in range(1, updates + 2):
        thetas = learner.ask_batch() if u <= updates else []
        seeds = rollout_seeds(seed, start_id, u, len(thetas), design)
        jobs = [WalkJob(seed=s, cycles=n, theta=_theta(t), mode=mode) for s, t in zip(seeds, thetas)]
        results = yield [*pending_eval, *jobs]
        evaluated, rollouts = results[: len(pending_eval)], results[len(pending_eval):]
        costs = [round(cost(r), 3) for r in evaluated]
        worst = min(evaluated, key=lambda r: (r["cycles_completed"], r["end"] == "walked"))
        run.updates.append(Update(
            index=len(run.updates), theta=batch_summary.get("theta", theta0),
            evaluation_theta=pending_eval[0].theta, evaluation_cost=round(float(np.mean(costs)), 3),
            evaluation_cycles=worst["cycles_completed"],
            evaluation_end="walked" if all(r["end"] == "walked" for r in evaluated) else worst["end"],
            evaluation_costs=costs,
            batch_mean_cost=batch_summary.get("mean_cost"), batch_mean_cycles=batch_summary.get("mean_cycles"),
            batch_falls=batch_summary.get("falls"), noise=batch_summary.get("noise"),
        ))
        if not jobs:
            break
        for k, r in enumerate(rollouts):
            run.rollouts.append({"update": u, "rollout": k + 1, **r})
        record = learner.tell_batch([(r["cycle_costs"][:n], r["fell"]) for r in rollouts])
        batch_summary = {
            "theta": _theta(learner.theta),
            "mean_cost": round(float(np.mean([cost(r) for r in rollouts])), 3),
            "mean_cycles": float(np.mean([r["cycles_completed"] for r in rollouts])),
            "falls": sum(r["fell"] for r in rollouts),
            "noise": None if record is None else tuple(round(v, 5) for v in record.noise),
        }
        if record is None:
            run.rejections = [r.reason for r in learner.rejections]
            if not learner.learning_enabled:
                run.learning_disabled = True
        pending_eval = evaluation(learner.evaluation_theta())
    return run


def _theta(t: Any) -> tuple[float, float]:
    return (round(float(t[0]), 6), round(float(t[1]), 6))
