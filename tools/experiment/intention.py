"""Which step fits which intention: fixed step lengths crossed with where the CoM sits at the swing's start.

The paper's compensation ``g = g_init + alpha (Xhat_CoM - X_CoM/X_SP)`` is worth having only if
the step that fits depends on X_CoM/X_SP, which the patient's intention (where it places the
sticks, and how far it leans toward them) moves from step to step. This experiment asks the
model: for each fixed step length, the same patients (walk seeds) with an intention that varies
(``sim.patient.intention``); every swing is put in a bin of X_CoM/X_SP at its start, or of the
intention itself (:data:`BIN_BY`; bins of equal counts over all swings), and per cell (length, bin) it gives the falls per step (the walk
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

#: a cell needs this many swings for its best-step and force figures (three fall-free swings say little)
MIN_SWINGS = 10
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


def quantiles(x: np.ndarray) -> dict[str, float | None]:
    """Mean, standard deviation and 10th, 50th and 90th percentile of ``x`` (None each when empty)."""
    if not len(x):
        return {"mean": None, "std": None, "p10": None, "p50": None, "p90": None}
    p10, p50, p90 = np.percentile(x, [10, 50, 90])
    return {"mean": round(float(x.mean()), 4), "std": round(float(x.std()), 4),
            "p10": round(float(p10), 4), "p50": round(float(p50), 4), "p90": round(float(p90), 4)}


#: what the swings are binned by: X_CoM/X_SP at the swing's start as the compensation reads it
#: (``stance``: over the support that carries the swing, the stance ankle and both tips), over
#: both ankles and both tips (``planted``), or the patient's intention itself (``intention``: what
#: the controller cannot see, the physics alone)
BIN_BY = {"planted": "X_CoM/X_SP (planted)", "stance": "X_CoM/X_SP (stance)", "intention": "intended placement (m)"}


def _value(s: Swing, by: str) -> float:
    return {"stance": s.x_ratio, "planted": s.x_ratio_planted, "intention": s.intention_m}[by]


#: X_CoM/X_SP bins of the heat maps (equal counts), unless told otherwise
DEFAULT_BINS = 4


def bin_edges(v: np.ndarray, bins: int) -> np.ndarray:
    """The edges of ``bins`` bins of equal counts over ``v`` (all zero when it is empty)."""
    return np.percentile(v, np.linspace(0, 100, bins + 1)) if len(v) else np.zeros(bins + 1)


def bin_index(edges: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The bin (0 .. len(edges) - 2) of each value of ``v``; values beyond the edges go to the end bins."""
    return np.clip(np.searchsorted(edges, v, side="right") - 1, 0, len(edges) - 2)


def analyse(results: list[dict[str, Any]], bins: int, by: str = "stance") -> dict[str, Any]:
    """The grid of falls and forces by (fixed length, bin of ``by``), the best step per bin and
    the checks of the module doc."""
    every = swings(results)
    rows = [s for s in every if math.isfinite(_value(s, by))]
    v = np.array([_value(s, by) for s in rows])
    edges = bin_edges(v, bins)
    lengths_m = sorted({r["job"]["fixed_m"] for r in results})
    bin_of = {id(s): int(b) for s, b in zip(rows, bin_index(edges, v))}

    cells = []
    for length in lengths_m:
        for b in range(bins):
            cell = [s for s in rows if s.length_m == length and bin_of[id(s)] == b]
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
        in_bin = [x for s, x in zip(rows, v) if bin_of[id(s)] == b]
        top = min(ok, key=lambda c: c["stick_force_n"]) if ok else None
        best.append({"bin": b, "from": round(float(edges[b]), 4), "to": round(float(edges[b + 1]), 4),
                     "median": round(float(np.median(in_bin)), 4) if in_bin else None,
                     "best_length_m": top["length_m"] if top else None, "best_stick_force_n": top["stick_force_n"] if top else None})
    # a fixed length that would do in every bin: no fall anywhere, and within NEAR_N of each bin's best
    sufficient = []
    for length in lengths_m:
        own = [grid[(length, b)] for b in range(bins)]
        fall_free = all(c["falls"] == 0 for c in own)
        near = all(e["best_stick_force_n"] is None or (own[e["bin"]]["stick_force_n"] is not None
                   and own[e["bin"]]["stick_force_n"] <= e["best_stick_force_n"] + NEAR_N) for e in best)
        if fall_free and near:
            sufficient.append(length)
    clamps: dict[str, int] = {}
    for r in results:
        for reason, n in (r.get("stick_clamps") or {}).items():
            clamps[reason] = clamps.get(reason, 0) + n
    return {
        "walks": len(results), "walks_per_length": len(results) // max(len(lengths_m), 1), "lengths_m": lengths_m,
        "bins": bins, "bin_by": by, "swings": len(rows), "clamped_stick_goals": clamps,
        # every swing's X_CoM/X_SP both ways and intention, and how well each ratio follows the intention
        **{f"{key}_spread": quantiles(np.array([x for s in every if math.isfinite(x := _value(s, key))])) for key in BIN_BY},
        "spearman_intention": {key: _spearman([(s.intention_m, _value(s, key)) for s in every
                                               if math.isfinite(s.intention_m) and math.isfinite(_value(s, key))])
                               for key in ("planted", "stance")},
        "cells": cells, "best": best,
        "spearman_best_length": _spearman([(e["median"], e["best_length_m"]) for e in best if e["best_length_m"] is not None]),
        "lengths_fit_for_every_bin": sufficient,
    }


def _spearman(pairs: list[tuple[float, float]]) -> float | None:
    """Spearman's rank correlation of the pairs (None for fewer than 3, or a constant side)."""
    if len(pairs) < 3 or any(len(set(side)) < 2 for side in zip(*pairs)):
        return None
    return round(float(spearmanr(*zip(*pairs)).statistic), 3)


def csv_rows(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{"walk_seed": s.walk_seed, "step": s.index, "length_m": s.length_m, "x_ratio": s.x_ratio,
             "x_ratio_planted": s.x_ratio_planted, "intention_m": s.intention_m, "stick_force_n": s.stick_force_n, "ended": s.ended,
             "ended_after": s.ended_after, "end": s.end} for s in swings(results)]


#: the heat maps: (cell key, title, colour map, scale to the shown unit)
GRIDS = (("falls_per_step", "falls per step (%)", "Reds", 100.0), ("stick_force_n", "mean stick force (N)", "viridis", 1.0))


def draw_grid(fig, axis, s: dict[str, Any], key: str, title: str, cmap: str, scale: float) -> None:
    """One of :data:`GRIDS` of the summary ``s`` on ``axis`` in real units (X_CoM/X_SP bins as wide
    as they are, step lengths in m, so lines g(X) can be drawn over it), the best step of each bin
    circled."""
    lengths_m, bins = s["lengths_m"], s["bins"]
    grid = {(e["length_m"], e["bin"]): e for e in s["cells"]}
    m = np.array([[np.nan if grid[(length, j)][key] is None else scale * grid[(length, j)][key] for j in range(bins)]
                  for length in lengths_m])
    x_edges = [e["from"] for e in s["best"]] + [s["best"][-1]["to"]]
    half = (lengths_m[1] - lengths_m[0]) / 2 if len(lengths_m) > 1 else 0.01
    y_edges = [v - half for v in lengths_m] + [lengths_m[-1] + half]
    image = axis.pcolormesh(x_edges, y_edges, np.ma.masked_invalid(m), cmap=cmap)
    fig.colorbar(image, ax=axis)
    centres = [(a + b) / 2 for a, b in zip(x_edges, x_edges[1:])]
    for i, length in enumerate(lengths_m):
        for j in range(bins):
            if np.isfinite(m[i, j]):
                axis.text(centres[j], length, f"{m[i, j]:.0f}", ha="center", va="center", fontsize=7,
                          color="w" if key == "stick_force_n" else "k")
    marks = [(centres[e["bin"]], e["best_length_m"]) for e in s["best"] if e["best_length_m"] is not None]
    if marks:  # the best step of a bin: fall-free, least force
        axis.plot(*zip(*marks), "o", mfc="none", mec="tab:cyan", mew=2, ms=14)
    axis.set_yticks(lengths_m, [f"{v:.2f}" for v in lengths_m])
    axis.set(xlabel=f"{BIN_BY[s['bin_by']]} at the swing's start (bins)", ylabel="step length (m)", title=title)


def figure(results: list[dict[str, Any]], s: dict[str, Any], path, canvas, save) -> None:
    """(a) falls per step and (b) mean stick force per (fixed length, bin), the best step of each
    bin marked; (c) X_CoM/X_SP at each swing's start, both ways, against the patient's intention."""
    fig, ax = canvas(1, 3, (15, 4.8))
    a, b, c = ax[0]
    for axis, (key, title, cmap, scale), letter in zip((a, b), GRIDS, "ab"):
        draw_grid(fig, axis, s, key, f"({letter}) {title}; o: best step", cmap, scale)
    rows = [r for r in swings(results) if math.isfinite(r.intention_m)]
    for key, colour in (("planted", "tab:blue"), ("stance", "tab:green")):
        pts = [(r.intention_m, _value(r, key), r.ended or r.ended_after) for r in rows if math.isfinite(_value(r, key))]
        c.scatter([p[0] for p in pts if not p[2]], [p[1] for p in pts if not p[2]], s=6, c=colour, alpha=0.4, label=BIN_BY[key])
        c.scatter([p[0] for p in pts if p[2]], [p[1] for p in pts if p[2]], s=25, c=colour, marker="x")
    c.set(xlabel="intended stick placement (m)", ylabel="X_CoM/X_SP at the swing's start",
          title="(c) does the CoM follow the intention? (x: a fall)")
    c.legend(loc="best", fontsize=8)
    save(fig, path)


def report_lines(s: dict[str, Any]) -> list[str]:
    def spread(key: str) -> str:
        q = s[f"{key}_spread"]
        return f"sd {_f(q['std'])}, 10th-90th percentile {_f(q['p10'])}-{_f(q['p90'])}"

    follow = s["spearman_intention"]
    lines = [
        f"{s['walks']} walks ({s['walks_per_length']} per length), {s['swings']} swings binned by {BIN_BY[s['bin_by']]}; "
        f"stick goals clamped: {s['clamped_stick_goals'] or 'none'}",
        f"intention: {spread('intention')} m; X_CoM/X_SP at the swing's start, planted: {spread('planted')} "
        f"(Spearman with the intention {_f(follow['planted'])}); stance: {spread('stance')} ({_f(follow['stance'])})",
        f"best step per bin: Spearman {_f(s['spearman_best_length'])} with the bins; fixed lengths fall-free and within "
        f"{NEAR_N:.0f} N of the best in every bin: {', '.join(f'{v:.2f}' for v in s['lengths_fit_for_every_bin']) or 'none'}",
        "",
        "| length m | " + " | ".join(f"{e['from']:.2f}-{e['to']:.2f}: falls/steps, force N" for e in s["best"]) + " |",
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
