"""The population experiment: for every virtual patient, online PI² from the paper's start A, then
the learned gait against the fixed step lengths, on that patient (docs/POPULATION.md).

Each patient is one run for :func:`tools.experiment.schedule.drive`: the learning run's walks, then
the comparison's, every walk carrying the patient (:attr:`tools.experiment.runner.WalkJob.patient`),
so every patient's walks run on the pool at once and each result is cached under its patient. Seeds
derive from the population's seed and the patient's index, as the learning experiment's do.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from config import Config, config_to_dict
from config.patient_schema import VirtualPatient
from protocol.clock import MonotonicClock
from tools.experiment.compare import ADAPTIVE, GaitStats, compare_jobs, comparison
from tools.experiment.learn import LearningRun, RolloutDesign, learning_run, walk_seed
from tools.experiment.runner import ExperimentError, WalkPool
from tools.experiment.schedule import Run, RunFailed, drive

START = "A"  # the paper's start the population learns from
CONVERGED_WITHIN = 0.05  # an update is converged when every later noise-free cost is within 5 % of the last


@dataclass
class PopulationPlan:
    cfg: Config
    out: Path
    patients: list[VirtualPatient]
    seed: int = 0
    updates: int = 15
    design: RolloutDesign = field(default_factory=RolloutDesign)
    compare_walks: int = 10
    mode: str | None = None  # None: the configuration's sim.mode
    workers: int = 2
    executor: str = "local"
    address: str | None = None

    def __post_init__(self) -> None:
        if self.mode is None:
            self.mode = self.cfg.sim.mode
        if not self.patients:
            raise ExperimentError("a population experiment needs at least one patient")
        names = [p.name for p in self.patients]
        if len(set(names)) != len(names):
            raise ExperimentError(f"two patients share a name: {sorted({n for n in names if names.count(n) > 1})}")
        if self.updates < 1 or self.compare_walks < 1:
            raise ExperimentError("updates and compare walks must be at least 1")

    @property
    def cycles(self) -> int:
        return self.cfg.controller.learning.steps_per_rollout

    def walks_per_patient(self) -> int:
        """Learning from START and the comparison: what ``experiment all`` plans for one start."""
        from tools.experiment.experiment import Plan

        return Plan(cfg=self.cfg, out=self.out, starts=[START], updates=self.updates, design=self.design,
                    compare=True, compare_walks=self.compare_walks).walks_planned()


@dataclass
class PatientOutcome:
    patient: VirtualPatient
    learning: LearningRun
    theta: tuple[float, float]
    gaits: list[GaitStats]

    def summary(self, cycles: int) -> dict[str, Any]:
        """The patient, what it learned, and its gaits: the adaptive one against the best fixed step
        length that never fell (the one with the least mean stick force)."""
        gaits = [g.summary(cycles) for g in self.gaits]
        adaptive = next(g for g in gaits if g["gait"] == ADAPTIVE)
        safe = [g for g in gaits if g["gait"] != ADAPTIVE and g["falls"] == 0 and g["stick_force_mean_n"] is not None]
        best = min(safe, key=lambda g: g["stick_force_mean_n"]) if safe else None
        force = adaptive["stick_force_mean_n"]
        reduction = (None if best is None or force is None
                     else round(100 * (best["stick_force_mean_n"] - force) / best["stick_force_mean_n"], 2))
        # below every fixed length that never fell (below the least of them), or none never fell
        below = force is not None and (best is None or force < best["stick_force_mean_n"])
        return {
            "patient": config_to_dict(self.patient),
            "learned_theta": list(self.theta),
            "updates_to_converge": updates_to_converge(self.learning),
            "final_evaluation_cycles": self.learning.final.evaluation_cycles,
            "adaptive": adaptive,
            "best_fixed": None if best is None else best["gait"],
            "best_fixed_stick_force_n": None if best is None else best["stick_force_mean_n"],
            "stick_force_reduction_pct": reduction,
            # beat: less stick force than the best fixed length that never fell, falling no more often
            "adaptive_beats_best_fixed": below and best is not None and adaptive["falls"] <= best["falls"],
            # every comparison walk of the learned gait walked every cycle asked
            "adaptive_walks_every_walk": adaptive["walks"] > 0 and adaptive["stable_cycles_min"] == cycles,
            "adaptive_below_fall_free_fixed": below,
            "falls_by_gait": {g["gait"]: g["falls"] for g in gaits},
            "above_comfort_pct": _above_comfort(adaptive, self.patient),
            "learning": self.learning.as_dict(),
            "gaits": gaits,
        }


def _above_comfort(adaptive: dict[str, Any], patient: VirtualPatient) -> float | None:
    force = adaptive["stick_force_mean_n"]
    return None if force is None else round(100 * (force - patient.comfortable_stick_force_n) / patient.comfortable_stick_force_n, 1)


def updates_to_converge(run: LearningRun, within: float = CONVERGED_WITHIN) -> int | None:
    """The first update from which every noise-free walk's cost stays within ``within`` of the
    last one's (None when the last one fell: nothing to converge to)."""
    costs = [u.evaluation_cost for u in run.updates]
    if not costs or run.final.evaluation_end != "walked":
        return None
    last = costs[-1]
    for index in range(len(costs)):
        if all(math.isclose(c, last, rel_tol=within) for c in costs[index:]):
            return run.updates[index].index
    return None


def with_patient(run: Run, patient: VirtualPatient) -> Run:
    """``run`` with every walk it asks for on ``patient``."""
    try:
        jobs = next(run)
        while True:
            results = yield [dataclasses.replace(j, patient=patient) for j in jobs]
            jobs = run.send(results)
    except StopIteration as stop:
        return stop.value


def patient_run(plan: PopulationPlan, index: int) -> Run:
    """Patient ``index`` of ``plan``: learning from start A, then the comparison at the learned theta."""
    patient = plan.patients[index]
    seed = walk_seed(plan.seed, 32, index)
    learned = yield from with_patient(learning_run(plan.cfg, START, seed, updates=plan.updates, mode=plan.mode, design=plan.design), patient)
    theta = learned.final.evaluation_theta
    jobs = compare_jobs(theta, seed=seed, walks=plan.compare_walks, cycles=plan.cycles, mode=plan.mode)
    gaits = yield from with_patient(comparison(jobs), patient)
    return PatientOutcome(patient, learned, theta, gaits)


@dataclass
class PopulationResults:
    plan: PopulationPlan
    outcomes: list[PatientOutcome] = field(default_factory=list)
    failed: list[RunFailed] = field(default_factory=list)  # patients one of whose walks raised
    walks_run: int = 0
    walks_reused: int = 0
    wall_time_s: float = 0.0


def run(plan: PopulationPlan, *, on_done: Callable | None = None, stop: Callable[[], bool] | None = None) -> PopulationResults:
    """Every patient of ``plan`` on one pool (results cached under ``plan.out/cache``)."""
    clock = MonotonicClock()
    t0 = clock.now_ns()
    results = PopulationResults(plan)
    with WalkPool(plan.cfg, plan.workers, plan.out / "cache", on_done=on_done,
                  executor=plan.executor, address=plan.address) as pool:
        runs = {p.name: patient_run(plan, i) for i, p in enumerate(plan.patients)}
        outcomes = drive(pool, runs, stop, keep_going=True)  # a walk that raises ends its patient's run only
        done = [outcomes[p.name] for p in plan.patients]
        results.outcomes = [o for o in done if isinstance(o, PatientOutcome)]
        results.failed = [o for o in done if isinstance(o, RunFailed)]
        results.walks_run, results.walks_reused = pool.ran, pool.reused
    results.wall_time_s = (clock.now_ns() - t0) / 1e9
    return results
