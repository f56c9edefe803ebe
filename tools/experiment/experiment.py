"""The experiments' orchestration: learning runs and the comparison on one pool, their checks
against the paper's claims, and the progress line."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from config import Config
from controller.compensation import StepBounds, compensated_step
from protocol.clock import Clock, MonotonicClock
from tools.experiment.compare import ADAPTIVE, FIXED_LENGTHS_M, GaitStats, compare_jobs, comparison
from tools.experiment.falls import swings
from tools.experiment.intention import quantiles
from tools.experiment.learn import STARTS, LearningRun, RolloutDesign, learning_run
from tools.experiment.runner import ExperimentError, WalkJob, WalkPool
from tools.experiment.schedule import Run, drive


@dataclass
class Plan:
    """What to run: learning from ``starts`` for every seed, and/or the comparison."""

    cfg: Config
    out: Path
    seeds: list[int] = field(default_factory=lambda: [0])
    starts: list[str] = field(default_factory=list)
    updates: int = 15
    design: RolloutDesign = field(default_factory=RolloutDesign)  # paired roll-outs, averaged evaluation
    compare: bool = False
    compare_theta: tuple[float, float] | None = None  # None with learning: the learned one
    compare_walks: int = 10
    mode: str | None = None  # None: the configuration's sim.mode
    workers: int = 2
    executor: str = "local"  # or "ray" (tools.experiment.cluster)
    address: str | None = None  # the Ray cluster's; None: a local Ray instance

    def __post_init__(self) -> None:
        if self.mode is None:
            self.mode = self.cfg.sim.mode
        for s in self.starts:
            if s not in STARTS:
                raise ExperimentError(f"unknown start {s!r}: the paper's are {', '.join(STARTS)}")
        if self.updates < 1:
            raise ExperimentError(f"updates must be >= 1, got {self.updates}")

    @property
    def cycles(self) -> int:
        return self.cfg.controller.learning.steps_per_rollout

    def walks_planned(self) -> int:
        k = self.cfg.controller.learning.rollouts_per_update
        learning = len(self.starts) * len(self.seeds) * self.design.walks_per_run(self.updates, k)
        return learning + (len(FIXED_LENGTHS_M) + 1) * self.compare_walks * (1 if self.compare else 0)


class Progress:
    """A progress bar of walks on stderr (rewritten in place on a terminal, a line every 5 % otherwise)."""

    def __init__(self, total: int, enabled: bool = True, clock: Clock | None = None) -> None:
        self.total, self.done, self.reused = total, 0, 0
        self.enabled = enabled
        self.clock = clock or MonotonicClock()
        self.t0 = self.clock.now_ns()
        self.tty = sys.stderr.isatty()
        self.last_shown = -1

    def __call__(self, job: WalkJob, result: dict[str, Any], reused: bool) -> None:
        self.done += 1
        self.reused += reused
        if not self.enabled:
            return
        frac = self.done / max(self.total, 1)
        ran = self.done - self.reused
        elapsed = (self.clock.now_ns() - self.t0) / 1e9
        eta = elapsed / ran * (self.total - self.done) if ran else math.nan
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        text = (f"experiment [{bar}] {self.done}/{self.total} walks ({self.reused} reused) "
                f"{elapsed / 60:4.1f} min" + (f", ~{eta / 60:.1f} min left" if math.isfinite(eta) else "")
                + f" | {job.gait} seed {job.seed}: {result['cycles_completed']} cycles, {result['end']}")
        if self.tty:
            print("\r" + text[:160].ljust(160), end="" if self.done < self.total else "\n", file=sys.stderr, flush=True)
        elif int(frac * 20) != self.last_shown or self.done == self.total:
            self.last_shown = int(frac * 20)
            print(text, file=sys.stderr, flush=True)


@dataclass
class Results:
    plan: Plan
    learning: list[LearningRun] = field(default_factory=list)
    comparison: list[GaitStats] = field(default_factory=list)
    compare_theta: tuple[float, float] | None = None
    walks_run: int = 0
    walks_reused: int = 0
    wall_time_s: float = 0.0


def run(plan: Plan, progress: bool = True, stop: Callable[[], bool] | None = None) -> Results:
    """Everything in ``plan`` on one pool of ``plan.workers`` processes (results cached under
    ``plan.out/cache``: a second call with the same plan runs nothing again). ``stop()`` true ends
    it early (:class:`tools.experiment.schedule.Interrupted`), keeping every finished walk."""
    clock = MonotonicClock()
    t0 = clock.now_ns()
    bar = Progress(plan.walks_planned(), enabled=progress, clock=clock)
    results = Results(plan)
    with WalkPool(plan.cfg, plan.workers, plan.out / "cache", on_done=bar, executor=plan.executor, address=plan.address) as pool:
        runs: dict[str, Run] = {
            f"{start}-s{seed}": learning_run(plan.cfg, start, seed, updates=plan.updates, mode=plan.mode, design=plan.design)
            for seed in plan.seeds for start in plan.starts
        }
        learned = drive(pool, runs, stop)
        results.learning = [learned[name] for name in runs]
        if plan.compare:
            if plan.compare_theta is None and not results.learning:
                raise ExperimentError("the comparison needs a theta: learn first, or give one")
            theta = plan.compare_theta or learned_theta(results.learning)
            results.compare_theta = theta
            jobs = compare_jobs(theta, seed=plan.seeds[0], walks=plan.compare_walks, cycles=plan.cycles, mode=plan.mode)
            results.comparison = drive(pool, {"compare": comparison(jobs)}, stop)["compare"]
        results.walks_run, results.walks_reused = pool.ran, pool.reused
    results.wall_time_s = (clock.now_ns() - t0) / 1e9
    return results


def learned_theta(runs: list[LearningRun]) -> tuple[float, float]:
    """The adaptive gait to compare: the deployed theta of the learning run whose last noise-free
    walk cost least."""
    best = min(runs, key=lambda r: r.final.evaluation_cost)
    return best.final.evaluation_theta


# -- the paper's claims, checked ----------------------------------------------------------------


#: the step-length lines of A and B are compared at these percentiles of the X_CoM/X_SP their
#: roll-outs saw over the last LINE_UPDATES updates (where the learned gait walks) ...
LINE_PERCENTILES = (10, 50, 90)
LINE_UPDATES = 5
#: ... and agree when every difference is at most this, m
LINE_AGREEMENT_M = 0.01


def step_line(bounds: StepBounds, theta: tuple[float, float], x: np.ndarray) -> np.ndarray:
    """The step lengths theta commands at X_CoM/X_SP ``x`` (equation (8), after the safety clamp)."""
    return np.array([compensated_step(bounds, theta[0], theta[1], float(v)).length_m for v in x])


def _x_seen(run: LearningRun, last: int) -> list[float]:
    first = max(u.index for u in run.updates) - last + 1
    return [x for ro in run.rollouts if ro["update"] >= first for _, x, _ in ro["swings"] if x is not None and math.isfinite(x)]


def _lines(a: LearningRun, b: LearningRun, bounds: StepBounds) -> dict[str, Any]:
    """Where A's and B's deployed step-length lines differ, at percentiles of the X they walked."""
    x = np.array(_x_seen(a, LINE_UPDATES) + _x_seen(b, LINE_UPDATES))
    if not len(x):
        return {"x_percentiles": None, "length_A_m": None, "length_B_m": None, "difference_m": None, "agree": False}
    at = np.percentile(x, LINE_PERCENTILES)
    ga, gb = step_line(bounds, a.final.evaluation_theta, at), step_line(bounds, b.final.evaluation_theta, at)
    diff = np.abs(ga - gb)
    return {"x_percentiles": np.round(at, 4).tolist(), "length_A_m": np.round(ga, 4).tolist(), "length_B_m": np.round(gb, 4).tolist(),
            "difference_m": np.round(diff, 4).tolist(), "agree": bool((diff <= LINE_AGREEMENT_M + 1e-9).all())}


def learning_checks(runs: list[LearningRun], n: int, bounds: StepBounds, max_updates: int = 15) -> dict[str, Any]:
    """Per seed: do A and B end within 10 % of each other (or else, do their step-length lines
    agree within LINE_AGREEMENT_M where they walked), reach N of N stable cycles, and cut the
    noise-free cost by 30 % within ``max_updates`` updates."""
    by_seed: dict[int, dict[str, LearningRun]] = {}
    for r in runs:
        by_seed.setdefault(r.seed, {})[r.start] = r
    per_run = {r.name: _run_check(r, n, max_updates) for r in runs}
    per_seed = {}
    for seed, starts in sorted(by_seed.items()):
        if {"A", "B"} <= set(starts):
            a, b = np.array(starts["A"].final.evaluation_theta), np.array(starts["B"].final.evaluation_theta)
            rel = np.abs(a - b) / np.maximum(np.abs((a + b) / 2), 1e-9)
            same = bool((rel <= 0.10).all())
            lines = _lines(starts["A"], starts["B"], bounds)
            per_seed[seed] = {"theta_A": a.tolist(), "theta_B": b.tolist(), "relative_difference": np.round(rel, 4).tolist(),
                              "same_within_10_percent": same, "lines": lines, "same_or_lines_agree": same or lines["agree"]}
    every = [c for c in per_run.values()]
    return {
        "runs": per_run,
        "seeds": per_seed,
        "all_converge_together": bool(per_seed) and all(s["same_or_lines_agree"] for s in per_seed.values()),
        "all_reach_full_cycles": bool(every) and all(c["reaches_full_cycles"] for c in every),
        "all_cut_cost_30_percent": bool(every) and all(c["cost_cut_30_percent"] for c in every),
    }


def _run_check(r: LearningRun, n: int, max_updates: int) -> dict[str, Any]:
    start_cost = r.updates[0].evaluation_cost
    within = r.updates[: max_updates + 1]
    best_cut = max((1 - u.evaluation_cost / start_cost) if start_cost > 0 else 0.0 for u in within)
    cut_at = next((u.index for u in within if start_cost > 0 and 1 - u.evaluation_cost / start_cost >= 0.30), None)
    full_at = next((u.index for u in within if u.evaluation_cycles >= n), None)
    final_cut = 1 - r.final.evaluation_cost / start_cost if start_cost > 0 else 0.0
    return {
        "start_cost": start_cost, "final_cost": r.final.evaluation_cost, "final_cut": round(final_cut, 4),
        # by the last update (at most max_updates): a cut reached once and lost again does not count
        "best_cut": round(best_cut, 4), "cost_cut_30_percent": final_cut >= 0.30 and len(r.updates) <= max_updates + 1,
        "cut_30_at_update": cut_at,
        "reaches_full_cycles": r.final.evaluation_cycles >= n, "first_full_at_update": full_at,
        "final_theta": list(r.final.evaluation_theta), "final_cycles": r.final.evaluation_cycles,
        "rejections": len(r.rejections), "learning_disabled": r.learning_disabled,
    }


#: the comparison's X_CoM/X_SP at the swings' start must spread this much (a patient whose
#: intention varies): a standard deviation and a 10th-to-90th percentile range of at least
X_SPREAD_STD = 0.08
X_SPREAD_RANGE = 0.25
#: ... about a median in the paper's range (its starts Xhat 0.6 and 0.9, its optimum 0.80)
X_MEDIAN_RANGE = (0.55, 0.90)
#: a fixed length cheaper than the adaptive gait must fall in at least this share of its walks
CHEAPER_FALLS_SHARE = 0.3
#: the paper's stick pressure, both sticks together, over a walk (Figs. 11 and 12a), N
PAPER_BOTH_STICKS_N = (250.0, 500.0)
#: among fixed lengths the stick force falls as the step lengthens: the shortest above the longest by
FORCE_FALL_SHARE = 0.10
#: the longest fixed length falls within LONG_FALL_CYCLES cycles in at least this share of its walks
LONG_FALL_SHARE = 0.5
LONG_FALL_CYCLES = 6


def comparison_checks(gaits: list[GaitStats], n: int) -> dict[str, Any]:
    """The adaptive gait walks N of N in every walk, its stick force (both sticks together) in the
    paper's range and below every fixed length that never falls, every fixed length cheaper than it
    falls in CHEAPER_FALLS_SHARE of its walks; among fixed lengths the force falls with the length
    (FORCE_FALL_SHARE), the longest falls within LONG_FALL_CYCLES cycles in LONG_FALL_SHARE of its
    walks; X_CoM/X_SP spreads (X_SPREAD_*) about a median in X_MEDIAN_RANGE."""
    s = {g.gait: g.summary(n) for g in gaits}
    adaptive = s.get(ADAPTIVE)
    if adaptive is None:
        return {}
    safe = [k for k, v in s.items() if k != ADAPTIVE and v["falls"] == 0]
    lower = all(adaptive["stick_force_mean_n"] < s[k]["stick_force_mean_n"] for k in safe)
    fixed = [k for k in s if k != ADAPTIVE]
    cheaper = [k for k in fixed if s[k]["stick_force_mean_n"] is not None and adaptive["stick_force_mean_n"] is not None
               and s[k]["stick_force_mean_n"] < adaptive["stick_force_mean_n"]]
    torque_lower = all(adaptive["arm_torque_mean_nm"] < s[k]["arm_torque_mean_nm"] for k in fixed)
    longest, shortest = max(fixed, key=float, default=None), min(fixed, key=float, default=None)
    long_falls = longest is not None and sum(c < LONG_FALL_CYCLES for c in s[longest]["cycles_at_fall"]) >= LONG_FALL_SHARE * s[longest]["walks"]
    short_force = None if shortest is None else s[shortest]["stick_force_mean_n"]
    long_force = None if longest is None else s[longest]["stick_force_mean_n"]
    force_fall = (None if short_force is None or long_force is None or not short_force
                  else round(1.0 - long_force / short_force, 4))
    both = adaptive["both_sticks_force_mean_n"]
    x = np.array([sw.x_ratio for sw in swings([w for g in gaits for w in g.walks]) if math.isfinite(sw.x_ratio)])
    spread = {"swings": len(x), **quantiles(x)}
    spread["range_p10_p90"] = None if not len(x) else round(spread["p90"] - spread["p10"], 4)
    return {
        "non_falling_fixed": safe,
        # where every fixed length falls the adaptive gait has none to beat on force: it holds
        # (the report names the non-falling fixed lengths, "none" there)
        "adaptive_force_below_every_non_falling_fixed": lower,
        "adaptive_walks_full": adaptive["falls"] == 0,
        "adaptive_both_sticks_n": both,
        "adaptive_both_sticks_in_paper_range": both is not None and PAPER_BOTH_STICKS_N[0] <= both <= PAPER_BOTH_STICKS_N[1],
        "cheaper_fixed": cheaper,
        "every_cheaper_fixed_falls": all(s[k]["falls"] >= CHEAPER_FALLS_SHARE * s[k]["walks"] for k in cheaper),
        "adaptive_torque_below_every_fixed": bool(fixed) and torque_lower,
        "shortest_fixed": shortest,
        "longest_fixed": longest,
        # 1 - F(longest) / F(shortest): how much less the longest fixed length costs than the shortest
        "fixed_force_fall": force_fall,
        "fixed_force_falls_with_length": force_fall is not None and force_fall >= FORCE_FALL_SHARE,
        "longest_fixed_falls_within_6_cycles": bool(long_falls),
        "x_ratio": spread,
        "x_ratio_median_in_paper_range": bool(len(x)) and X_MEDIAN_RANGE[0] <= spread["p50"] <= X_MEDIAN_RANGE[1],
        "x_ratio_spreads": bool(len(x)) and spread["std"] >= X_SPREAD_STD and spread["range_p10_p90"] >= X_SPREAD_RANGE,
    }
