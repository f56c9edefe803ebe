"""What makes the model fall: walks whose every step length is drawn at random.

The paper's compensation ``g = g_init + alpha (Xhat_CoM - X_CoM/X_SP)`` can only help if where the
CoM sits in the support at a swing's start (X_CoM/X_SP) tells which step is safe. This experiment
asks the model directly: walks of ``N`` gait cycles whose steps are drawn uniformly from
``[min, max]`` (no compensation; each walk its own patient and length seed), and for every step
whose swing started, whether the walk ended in it (a fall, a fault or a HOLD before it landed)
or in the double support after its landing (before the next swing). The end rate is then split
by the step's own length, by X_CoM/X_SP at its start (below or above the median of its length
band) and by the length of the step before it.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.compensation import StepGoal
from controller.policy import StepPolicy
from tools.experiment.learn import walk_seed
from tools.experiment.runner import WalkJob

#: length bands (m) of the tables
BANDS = ((0.0, 0.12), (0.12, 0.14), (0.14, 0.16), (0.16, 1.0))


@dataclass
class RandomLengths(StepPolicy):
    """Every swing's length drawn uniformly from ``span`` (no compensation)."""

    span: tuple[float, float] = (0.0, 0.0)
    rng: np.random.Generator | None = None

    @property
    def mode(self) -> str:
        return "random"

    def goal(self, x_ratio: float) -> tuple[StepGoal, None]:
        assert self.rng is not None
        length = float(self.rng.uniform(*self.span))
        return StepGoal(length, length, False), None


def falls_jobs(*, seed: int, walks: int, span: tuple[float, float], cycles: int, mode: str) -> list[WalkJob]:
    return [WalkJob(seed=walk_seed(seed, 200, i), cycles=cycles, random_m=span, mode=mode) for i in range(walks)]


@dataclass(frozen=True)
class Swing:
    walk_seed: int
    index: int  # in its walk
    length_m: float
    x_ratio: float  # X_CoM/X_SP at the swing's start, the compensation's input (stance ankle and tips)
    previous_m: float | None  # the step before it (None: the first)
    ended: bool  # the walk ended in this step, before it landed
    ended_after: bool  # the walk ended in the double support after this step landed
    end: str  # how the walk ended (for the step it ended in or after)
    stick_force_n: float  # the landed step's mean stick force (nan: it did not land)
    intention_m: float  # the patient's intended stick placement before this swing (nan: unknown)
    x_ratio_planted: float  # the same over both ankles and both tips (nan: unknown)


def swings(results: list[dict[str, Any]]) -> list[Swing]:
    """Every swing of ``results`` (walk results of :func:`tools.experiment.runner.run_walk`)."""
    out = []
    for r in results:
        rows, forces = r["swings"], r["step_stick_force_n"]
        intentions = r.get("swing_intention_m") or [None] * len(rows)
        planted = r.get("swing_x_ratio_planted") or [None] * len(rows)
        # A walk that ended with every swing landed ended in double support: after its last step.
        after_last = bool(r["fell"] and rows and rows[-1][2])
        for i, ((length, ratio, landed), intention, ratio_planted) in enumerate(zip(rows, intentions, planted)):
            ended = not landed and r["fell"]
            after = after_last and i == len(rows) - 1
            force = forces[i] if landed and i < len(forces) else math.nan
            out.append(Swing(r["job"]["seed"], i, length, ratio, rows[i - 1][0] if i else None, ended, after,
                             r["end"] if ended or after else "", force, _nan(intention), _nan(ratio_planted)))
    return out


def _nan(value: float | None) -> float:
    return math.nan if value is None else value


def _rate(rows: list[Swing]) -> dict[str, Any]:
    n = len(rows)
    ended, after = sum(s.ended for s in rows), sum(s.ended_after for s in rows)
    return {"steps": n, "ended": ended, "percent": round(100.0 * ended / n, 2) if n else None, "ended_after": after,
            "percent_with_after": round(100.0 * (ended + after) / n, 2) if n else None}


def _band(lo: float, hi: float) -> str:
    return f"{lo:.2f}-{hi:.2f}" if hi < 1.0 else f">= {lo:.2f}"


def analyse(results: list[dict[str, Any]]) -> dict[str, Any]:
    """The end rate per step by its length, by X_CoM/X_SP within its length band, and by the
    length of the step before it; each rate of the ends in the steps' swings, and with the ends
    in the double support after them."""
    rows = swings(results)
    by_length, by_previous = [], []
    for lo, hi in BANDS:
        band = [s for s in rows if lo <= s.length_m < hi]
        entry = {"band_m": _band(lo, hi), **_rate(band)}
        ratios = [s.x_ratio for s in band if np.isfinite(s.x_ratio)]
        if ratios:
            median = float(np.median(ratios))
            entry["x_ratio_median"] = round(median, 4)
            entry["x_ratio_std"] = round(float(np.std(ratios)), 4)
            entry["below_median"] = _rate([s for s in band if s.x_ratio < median])
            entry["at_or_above_median"] = _rate([s for s in band if s.x_ratio >= median])
        by_length.append(entry)
        by_previous.append({"band_m": _band(lo, hi),
                            **_rate([s for s in rows if s.previous_m is not None and lo <= s.previous_m < hi])})
    ends = dict(Counter(s.end for s in rows if s.ended or s.ended_after))
    after = sum(s.ended_after for s in rows)
    return {
        "walks": len(results), "walks_ended_early": sum(r["fell"] for r in results),
        "steps": len(rows), "steps_ended": sum(s.ended for s in rows),
        "walks_ended_between_swings": after,  # in the double support after a landed step
        # in double support before the first swing: no step to blame
        "walks_ended_before_a_swing": sum(r["fell"] for r in results) - sum(s.ended for s in rows) - after,
        "ends": ends, "by_length": by_length, "by_previous_length": by_previous,
    }


def csv_rows(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{"walk_seed": s.walk_seed, "step": s.index, "length_m": s.length_m, "x_ratio": s.x_ratio,
             "previous_m": s.previous_m, "ended": s.ended, "ended_after": s.ended_after, "end": s.end}
            for s in swings(results)]


def figure(results: list[dict[str, Any]], s: dict[str, Any], path, canvas, save) -> None:
    """(a) each step's length against X_CoM/X_SP at its start, the steps a walk ended in (or in
    the double support after) marked; (b) the end rate by the step's own length, with the ends
    after it, and by the length of the step before it (``s``: :func:`analyse` of ``results``)."""
    rows = swings(results)
    fig, ax = canvas(1, 2, (11, 4.5))
    a, b = ax[0]
    ok = [s for s in rows if not s.ended and not s.ended_after and np.isfinite(s.x_ratio)]
    bad = [s for s in rows if s.ended and np.isfinite(s.x_ratio)]
    after = [s for s in rows if s.ended_after and np.isfinite(s.x_ratio)]
    a.scatter([s.length_m for s in ok], [s.x_ratio for s in ok], s=8, c="tab:gray", alpha=0.5, label="landed, walked on")
    a.scatter([s.length_m for s in bad], [s.x_ratio for s in bad], s=30, c="tab:red", marker="x", label="the walk ended in its swing")
    a.scatter([s.length_m for s in after], [s.x_ratio for s in after], s=30, c="tab:orange", marker="+",
              label="ended in the double support after it")
    a.set(xlabel="step length (m)", ylabel="X_CoM/X_SP at the swing's start", title="(a) every step of the random-length walks")
    a.legend(loc="best", fontsize=8)
    x = np.arange(len(BANDS))
    own = [e["percent"] or 0.0 for e in s["by_length"]]
    with_after = [e["percent_with_after"] or 0.0 for e in s["by_length"]]
    prev = [e["percent"] or 0.0 for e in s["by_previous_length"]]
    b.bar(x - 0.27, own, 0.27, label="in its swing, by its length")
    b.bar(x, with_after, 0.27, label="in its swing or the double support after")
    b.bar(x + 0.27, prev, 0.27, label="in its swing, by the length of the step before")
    b.set_xticks(x, [e["band_m"] for e in s["by_length"]])
    b.set(xlabel="length band (m)", ylabel="steps the walk ended in (%)", title="(b) where walks end")
    b.legend(loc="best", fontsize=8)
    save(fig, path)


def report_lines(s: dict[str, Any]) -> list[str]:
    lines = [
        f"{s['walks']} walks, {s['walks_ended_early']} ended early: {s['steps_ended']} in a swing, "
        f"{s['walks_ended_between_swings']} in the double support after a step, {s['walks_ended_before_a_swing']} "
        f"before the first swing; {s['steps']} swings",
        "",
        "| length band m | swings | ended % in the swing | with the double support after | X_CoM/X_SP median (sd) "
        "| ended % (with after) below / at or above the median | ended % in the swing after a step of this band |",
        "|---|---|---|---|---|---|---|",
    ]
    for own, prev in zip(s["by_length"], s["by_previous_length"]):
        lo, hi = own.get("below_median", {}), own.get("at_or_above_median", {})
        med = f"{own['x_ratio_median']:.3f} ({own['x_ratio_std']:.3f})" if "x_ratio_median" in own else "-"
        lines.append(f"| {own['band_m']} | {own['steps']} | {_p(own['percent'])} | {_p(own['percent_with_after'])} | {med} "
                     f"| {_p(lo.get('percent'))} ({_p(lo.get('percent_with_after'))}) / {_p(hi.get('percent'))} "
                     f"({_p(hi.get('percent_with_after'))}) | {_p(prev['percent'])} ({prev['steps']}) |")
    return lines


def _p(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"
