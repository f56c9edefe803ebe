"""Which step fits which intention: fixed step lengths crossed with where the CoM sits at the swing's start.

The paper's compensation ``g = g_init + alpha (Xhat_CoM - X_CoM/X_SP)`` is worth having only if
the step that fits depends on X_CoM/X_SP, which the patient's intention (where it places the
sticks, and how far it leans toward them) moves from step to step. This experiment asks the
model: for each fixed step length, the same patients (walk seeds) with an intention that varies
(``sim.patient.intention``); every swing is put in a bin of X_CoM/X_SP at its start (bins of
equal counts over all swings), and per cell (length, bin) it gives the falls per step (the walk
ended in the swing or in the double support after it) and the landed steps' mean stick force.
The best step of a bin is the fall-free length with the lowest force. What the paper's Figs. 4
and 5 say, the model should show: the best step rises with X_CoM/X_SP, and no one fixed length
is both fall-free and near the best force in every bin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.stats import spearmanr

from tools.experiment.falls import Swing, swings
from tools.experiment.learn import walk_seed
from tools.experiment.runner import WalkJob

#: a cell needs this many swings for its best-step and force figures
MIN_SWINGS = 3
#: "near the best force": within this of the bin's best
NEAR_N = 3.0


def lengths(lo: float, hi: float, step: float) -> list[float]:
    """The fixed step lengths from ``lo`` to ``hi`` (inclusive) every ``step``, m."""
    n = int(round((hi - lo) / step))
    return [round(lo + i * step, 4) for i in range(n + 1)]


def intention_jobs(*, seed: int, walks: int, lengths_m: Sequence[float], cycles: int, mode: str) -> list[WalkJob]:
    """``walks`` patients (the same seeds for every length) at each fixed length."""
    return [WalkJob(seed=walk_seed(seed, 300, i), cycles=cycles, fixed_m=length, mode=mode)
            for length in lengths_m for i in range(walks)]


def _falls(rows: list[Swing]) -> int:
    return sum(s.ended or s.ended_after for s in rows)


def _quantiles(x: np.ndarray) -> dict[str, float | None]:
    if not len(x):
        return {"mean": None, "std": None, "p10": None, "p50": None, "p90": None}
    p10, p50, p90 = np.percentile(x, [10, 50, 90])
    return {"mean": round(float(x.mean()), 4), "std": round(float(x.std()), 4),
            "p10": round(float(p10), 4), "p50": round(float(p50), 4), "p90": round(float(p90), 4)}


def analyse(results: list[dict[str, Any]], bins: int) -> dict[str, Any]:
    """The grid of falls and forces by (fixed length, X_CoM/X_SP bin), the best step per bin and
    the checks of the module doc."""
    rows = [s for s in swings(results) if math.isfinite(s.x_ratio)]
    x = np.array([s.x_ratio for s in rows])
    edges = np.percentile(x, np.linspace(0, 100, bins + 1)) if len(x) else np.zeros(bins + 1)
    lengths_m = sorted({r["job"]["fixed_m"] for r in results})

    def bin_of(s: Swing) -> int:
        return int(np.clip(np.searchsorted(edges, s.x_ratio, side="right") - 1, 0, bins - 1))

    cells = []
    for length in lengths_m:
        for b in range(bins):
            cell = [s for s in rows if s.length_m == length and bin_of(s) == b]
            forces = [s.stick_force_n for s in cell if math.isfinite(s.stick_force_n)]
            cells.append({
                "length_m": length, "bin": b, "swings": len(cell), "falls": _falls(cell),
                "falls_per_step": round(_falls(cell) / len(cell), 4) if cell else None,
                "stick_force_n": round(float(np.mean(forces)), 3) if len(forces) >= MIN_SWINGS else None,
            })
    grid = {(c["length_m"], c["bin"]): c for c in cells}
    best = []
    for b in range(bins):
        ok = [grid[(length, b)] for length in lengths_m
              if grid[(length, b)]["swings"] >= MIN_SWINGS and grid[(length, b)]["falls"] == 0
              and grid[(length, b)]["stick_force_n"] is not None]
        in_bin = [s.x_ratio for s in rows if bin_of(s) == b]
        top = min(ok, key=lambda c: c["stick_force_n"]) if ok else None
        best.append({"bin": b, "x_ratio_from": round(float(edges[b]), 4), "x_ratio_to": round(float(edges[b + 1]), 4),
                     "x_ratio_median": round(float(np.median(in_bin)), 4) if len(in_bin) else None,
                     "best_length_m": top["length_m"] if top else None, "best_stick_force_n": top["stick_force_n"] if top else None})
    rho = _spearman([(e["x_ratio_median"], e["best_length_m"]) for e in best if e["best_length_m"] is not None])
    # a fixed length that would do in every bin: no fall anywhere, and within NEAR_N of each bin's best
    sufficient = []
    for length in lengths_m:
        own = [grid[(length, b)] for b in range(bins)]
        fall_free = all(c["falls"] == 0 for c in own)
        near = all(e["best_stick_force_n"] is None or (own[e["bin"]]["stick_force_n"] is not None
                   and own[e["bin"]]["stick_force_n"] <= e["best_stick_force_n"] + NEAR_N) for e in best)
        if fall_free and near:
            sufficient.append(length)
    intentions = np.array([s.intention_m for s in rows if math.isfinite(s.intention_m)])
    follow = _spearman([(s.intention_m, s.x_ratio) for s in rows if math.isfinite(s.intention_m)])
    clamps: dict[str, int] = {}
    for r in results:
        for reason, n in (r.get("stick_clamps") or {}).items():
            clamps[reason] = clamps.get(reason, 0) + n
    return {
        "walks": len(results), "walks_per_length": len(results) // max(len(lengths_m), 1), "lengths_m": lengths_m,
        "bins": bins, "swings": len(rows), "x_ratio": _quantiles(x), "intention_m": _quantiles(intentions),
        "spearman_intention_x_ratio": follow,
        "stick_clamps": clamps, "cells": cells, "best": best,
        "spearman_best_length_x_ratio": rho,
        "lengths_fit_for_every_bin": sufficient,
    }


def _spearman(pairs: list[tuple[float, float]]) -> float | None:
    """Spearman's rank correlation of the pairs (None for fewer than 3, or a constant side)."""
    if len(pairs) < 3 or any(len(set(side)) < 2 for side in zip(*pairs)):
        return None
    return round(float(spearmanr(*zip(*pairs)).statistic), 3)


def csv_rows(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{"walk_seed": s.walk_seed, "step": s.index, "length_m": s.length_m, "x_ratio": s.x_ratio,
             "intention_m": s.intention_m, "stick_force_n": s.stick_force_n, "ended": s.ended,
             "ended_after": s.ended_after, "end": s.end} for s in swings(results)]


def figure(results: list[dict[str, Any]], s: dict[str, Any], path, canvas, save) -> None:
    """(a) falls per step and (b) mean stick force per (fixed length, X_CoM/X_SP bin), the best
    step of each bin marked; (c) X_CoM/X_SP at each swing's start against the patient's intention."""
    fig, ax = canvas(1, 3, (15, 4.8))
    a, b, c = ax[0]
    lengths_m, bins = s["lengths_m"], s["bins"]
    grid = {(e["length_m"], e["bin"]): e for e in s["cells"]}
    labels = [f"{e['x_ratio_from']:.2f}-{e['x_ratio_to']:.2f}" for e in s["best"]]
    for axis, key, title, cmap, scale in ((a, "falls_per_step", "(a) falls per step (%)", "Reds", 100.0),
                                          (b, "stick_force_n", "(b) mean stick force (N)", "viridis", 1.0)):
        m = np.array([[np.nan if grid[(length, j)][key] is None else scale * grid[(length, j)][key] for j in range(bins)]
                      for length in lengths_m])
        image = axis.imshow(m, origin="lower", aspect="auto", cmap=cmap)
        fig.colorbar(image, ax=axis)
        for i, length in enumerate(lengths_m):
            for j in range(bins):
                if np.isfinite(m[i, j]):
                    axis.text(j, i, f"{m[i, j]:.0f}", ha="center", va="center", fontsize=7, color="w" if key == "stick_force_n" else "k")
        marks = [(e["bin"], lengths_m.index(e["best_length_m"])) for e in s["best"] if e["best_length_m"] is not None]
        if marks:
            axis.plot(*zip(*marks), "o", mfc="none", mec="tab:cyan", mew=2, ms=14, label="best step (fall-free, least force)")
            axis.legend(loc="upper left", fontsize=7)
        axis.set_xticks(range(bins), labels, fontsize=8)
        axis.set_yticks(range(len(lengths_m)), [f"{v:.2f}" for v in lengths_m])
        axis.set(xlabel="X_CoM/X_SP at the swing's start (bin)", ylabel="fixed step length (m)", title=title)
    rows = [r for r in swings(results) if math.isfinite(r.x_ratio) and math.isfinite(r.intention_m)]
    bad = [r for r in rows if r.ended or r.ended_after]
    good = [r for r in rows if not (r.ended or r.ended_after)]
    c.scatter([r.intention_m for r in good], [r.x_ratio for r in good], s=6, c="tab:gray", alpha=0.5, label="walked on")
    c.scatter([r.intention_m for r in bad], [r.x_ratio for r in bad], s=25, c="tab:red", marker="x", label="the walk ended in or after it")
    c.set(xlabel="intended stick placement ahead of the CoM (m)", ylabel="X_CoM/X_SP at the swing's start",
          title="(c) does the lean follow the intention?")
    c.legend(loc="best", fontsize=8)
    save(fig, path)


def report_lines(s: dict[str, Any]) -> list[str]:
    x, it = s["x_ratio"], s["intention_m"]
    rho = s["spearman_best_length_x_ratio"]
    lines = [
        f"{s['walks']} walks ({s['walks_per_length']} per length), {s['swings']} swings with X_CoM/X_SP; "
        f"stick goals clamped: {s['stick_clamps'] or 'none'}",
        f"X_CoM/X_SP at the swing's start: sd {_f(x['std'])}, 10th-90th percentile {_f(x['p10'])}-{_f(x['p90'])}; "
        f"intention sd {_f(it['std'])} m; Spearman(intention, X_CoM/X_SP) {_f(s['spearman_intention_x_ratio'])}",
        f"best step per bin against X_CoM/X_SP: Spearman {_f(rho)}; fixed lengths fall-free and within {NEAR_N:.0f} N "
        f"of the best in every bin: {', '.join(f'{v:.2f}' for v in s['lengths_fit_for_every_bin']) or 'none'}",
        "",
        "| length m | " + " | ".join(f"X {e['x_ratio_from']:.2f}-{e['x_ratio_to']:.2f}: falls/steps, force N"
                                     for e in s["best"]) + " |",
        "|---|" + "---|" * s["bins"],
    ]
    grid = {(c["length_m"], c["bin"]): c for c in s["cells"]}
    for length in s["lengths_m"]:
        cells = [grid[(length, b)] for b in range(s["bins"])]
        lines.append(f"| {length:.2f} | " + " | ".join(
            f"{c['falls']}/{c['swings']}, {_f(c['stick_force_n'], 1)}" for c in cells) + " |")
    lines.append("| best | " + " | ".join(
        "-" if e["best_length_m"] is None else f"{e['best_length_m']:.2f} m ({e['best_stick_force_n']:.1f} N)"
        for e in s["best"]) + " |")
    return lines


def _f(v: float | None, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}f}"
