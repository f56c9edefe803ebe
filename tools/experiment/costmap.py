"""The noise-free cost of theta over a grid: the landscape PI² learns on.

Every theta = (alpha, Xhat_CoM) of an ``n`` by ``n`` grid walks the same ``W`` patient seeds
(common random numbers, as the learning run's averaged evaluation: the costs differ by theta, not
by the patient's luck); its cost is the mean of equation (11) over them. The map gives its minimum,
the set of theta within ``WITHIN`` of it (how flat the valley is: where the noise of one walk
cannot tell theta apart) and, drawn on it, the deployed theta of learning runs update by update
(from a ``summary.json`` of ``aider-exo experiment learn`` or ``all``); each run's end walks the
same seeds, so whether A and B ended in the valley is measured, not interpolated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.factory import pi2_params
from tools.experiment.learn import STARTS, rollout_cost, walk_seed
from tools.experiment.runner import ExperimentError, WalkJob

#: the grid's default spans: the paper's starts A and B inside, with room around them
ALPHA_SPAN = (-1.6, 0.0)
XHAT_SPAN = (0.4, 1.0)
#: theta within this share of the map's minimum cost are in its valley
WITHIN = 0.03
#: A's and B's step-length lines must agree within this at the median X when both end in the valley, m
VALLEY_LINE_AGREEMENT_M = 0.02


@dataclass(frozen=True)
class Grid:
    alphas: tuple[float, ...]
    xhats: tuple[float, ...]

    @classmethod
    def spanning(cls, n: int, alpha: tuple[float, float], xhat: tuple[float, float]) -> Grid:
        if n < 2:
            raise ExperimentError(f"--grid must be at least 2, got {n}")
        for name, (lo, hi) in (("--alpha", alpha), ("--xhat", xhat)):
            if not lo < hi:
                raise ExperimentError(f"{name} needs LO < HI, got {lo} {hi}")
        return cls(tuple(np.round(np.linspace(*alpha, n), 6).tolist()), tuple(np.round(np.linspace(*xhat, n), 6).tolist()))

    def thetas(self) -> list[tuple[float, float]]:
        """Every grid point, Xhat_CoM row by row."""
        return [(a, x) for x in self.xhats for a in self.alphas]


def check_span(grid: Grid, cfg) -> None:
    """The grid within the learner's bounds (``controller.learning``): a theta it cannot reach is no answer."""
    p = cfg.controller.learning
    if not (p.alpha_min <= grid.alphas[0] and grid.alphas[-1] <= p.alpha_max):
        raise ExperimentError(f"--alpha must lie within controller.learning's [{p.alpha_min}, {p.alpha_max}]")
    if not (p.xhat_min <= grid.xhats[0] and grid.xhats[-1] <= p.xhat_max):
        raise ExperimentError(f"--xhat must lie within controller.learning's [{p.xhat_min}, {p.xhat_max}]")


def map_seeds(seed: int, walks: int) -> list[int]:
    return [walk_seed(seed, 300, j) for j in range(walks)]


def learned_ends(learning: dict[str, Any] | None) -> list[tuple[float, float]]:
    """The deployed theta each learning run of ``learning`` ended at, in its order."""
    return [tuple(r["updates"][-1]["evaluation_theta"]) for r in (learning or {}).get("runs", [])]


def costmap_jobs(grid: Grid, *, seed: int, walks: int, cycles: int, mode: str,
                 ends: list[tuple[float, float]] = ()) -> list[WalkJob]:
    """Every grid point, then every learning run's end (``ends``), on the same ``walks`` seeds."""
    seeds = map_seeds(seed, walks)
    return [WalkJob(seed=s, cycles=cycles, theta=theta, mode=mode) for theta in [*grid.thetas(), *ends] for s in seeds]


def analyse(results: list[dict[str, Any]], grid: Grid, walks: int, cfg, learning: dict[str, Any] | None = None) -> dict[str, Any]:
    """The map from the walks of :func:`costmap_jobs` (in its order, the ends of ``learning``'s
    runs after the grid), and where ``learning`` (the ``learning`` part of an experiment's
    summary.json) ended on it."""
    params = pi2_params(cfg.controller)
    n = params.steps_per_rollout

    def cost(rs: list[dict[str, Any]]) -> float:
        return float(np.mean([rollout_cost(r, n, params.lambda1, params.lambda2) for r in rs]))

    thetas = grid.thetas()
    per_theta = [results[k * walks:(k + 1) * walks] for k in range(len(thetas) + len(learned_ends(learning)))]
    on_grid, at_ends = per_theta[:len(thetas)], per_theta[len(thetas):]
    grid_cost = np.array([cost(rs) for rs in on_grid])
    full = np.array([sum(r["cycles_completed"] >= n for r in rs) for rs in on_grid])
    shape = (len(grid.xhats), len(grid.alphas))
    best = int(np.argmin(grid_cost))
    limit = (1 + WITHIN) * float(grid_cost[best])
    return {
        "grid": {"alpha": list(grid.alphas), "xhat": list(grid.xhats)}, "walks_per_theta": walks, "cycles": n,
        "cost": np.round(grid_cost.reshape(shape), 3).tolist(), "walked_full": full.reshape(shape).tolist(),
        "minimum": {"theta": list(thetas[best]), "cost": round(float(grid_cost[best]), 3)},
        "within": WITHIN, "valley": [list(t) for t, c in zip(thetas, grid_cost) if c <= limit],
        "valley_cost_limit": round(limit, 3), "starts": {k: list(v) for k, v in STARTS.items()},
        "learning": _learning_on_map(learning, [cost(rs) for rs in at_ends], [sum(r["cycles_completed"] >= n for r in rs) for rs in at_ends],
                                     limit) if learning else None,
    }


def _learning_on_map(learning: dict[str, Any], end_costs: list[float], end_full: list[int], limit: float) -> dict[str, Any]:
    """Each run's path and its end, walked on the map's seeds; per seed with both starts, which of
    the issue's two agreements held (the same theta or lines, or both ends in the valley with lines
    agreeing at the median X within VALLEY_LINE_AGREEMENT_M)."""
    runs = []
    for r, end, cost, full in zip(learning["runs"], learned_ends(learning), end_costs, end_full):
        runs.append({"run": f"{r['start']}-s{r['seed']}", "start": r["start"], "seed": r["seed"],
                     "path": [u["evaluation_theta"] for u in r["updates"]], "end": list(end),
                     "cost_at_end": round(cost, 3), "walked_full_at_end": full, "in_valley": cost <= limit})
    seeds = {}
    for seed, lines in learning.get("checks", {}).get("seeds", {}).items():
        ends = {r["start"]: r for r in runs if str(r["seed"]) == str(seed)}
        diff = lines["lines"]["difference_m"]
        median_diff = None if diff is None else diff[1]
        both_in = {"A", "B"} <= set(ends) and ends["A"]["in_valley"] and ends["B"]["in_valley"]
        valley_agrees = bool(both_in and median_diff is not None and median_diff <= VALLEY_LINE_AGREEMENT_M + 1e-9)
        seeds[str(seed)] = {"same_or_lines_agree": lines["same_or_lines_agree"], "both_in_valley": both_in,
                            "median_line_difference_m": median_diff, "valley_agreement": valley_agrees,
                            "held": "theta or lines" if lines["same_or_lines_agree"] else "valley" if valley_agrees else "neither"}
    return {"runs": runs, "seeds": seeds}


HELD = {"theta or lines": "end at the same theta, or their step-length lines agree",
        "valley": "both end in the valley, their lines agreeing at the median X",
        "neither": "agree neither way"}


def figure(s: dict[str, Any], path, canvas, save) -> None:
    """The map as a heat map (log colour scale), its minimum and valley marked, the learning runs'
    deployed theta update by update drawn on it."""
    from matplotlib.colors import LogNorm

    fig, ax = canvas(1, 1, (7.5, 6))
    a = ax[0][0]
    alphas, xhats, costs = np.array(s["grid"]["alpha"]), np.array(s["grid"]["xhat"]), np.array(s["cost"])
    mesh = a.pcolormesh(alphas, xhats, costs, shading="nearest", cmap="viridis_r", norm=LogNorm(vmin=costs.min(), vmax=costs.max()))
    fig.colorbar(mesh, ax=a, label=f"mean cost, equation (11), over {s['walks_per_theta']} walks")
    valley = np.array(s["valley"])
    a.scatter(valley[:, 0], valley[:, 1], s=90, facecolors="none", edgecolors="white", linewidths=1.5,
              label=f"within {s['within'] * 100:.0f} % of the minimum")
    a.scatter(*s["minimum"]["theta"], marker="*", s=220, c="white", edgecolors="black", label="minimum")
    for name, theta in s["starts"].items():
        a.annotate(name, theta, color="white", fontsize=11, fontweight="bold", ha="center", va="center")
    for r, color in zip((s["learning"] or {}).get("runs", []), ("tab:red", "tab:orange", "tab:pink", "tab:brown")):
        walked = np.array(r["path"])
        a.plot(walked[:, 0], walked[:, 1], "-o", ms=3, c=color, label=f"learning {r['run']}")
        a.scatter(*r["end"], marker="s", s=60, c=color, edgecolors="black")
    a.set(xlabel="alpha (m)", ylabel="Xhat_CoM", title="Noise-free cost of theta, and the learning runs on it")
    a.legend(loc="best", fontsize=8)
    save(fig, path)


def report_lines(s: dict[str, Any]) -> list[str]:
    m = s["minimum"]
    lines = [f"{len(s['grid']['alpha'])} x {len(s['grid']['xhat'])} theta, {s['walks_per_theta']} paired walks each "
             f"({s['cycles']} gait cycles): minimum {m['cost']:.0f} at (alpha {m['theta'][0]:.3f}, Xhat {m['theta'][1]:.3f}); "
             f"{len(s['valley'])} theta within {s['within'] * 100:.0f} % of it (cost at most {s['valley_cost_limit']:.0f}).", "",
             "| Xhat \\ alpha | " + " | ".join(f"{a:.2f}" for a in s["grid"]["alpha"]) + " |",
             "|---|" + "---|" * len(s["grid"]["alpha"])]
    valley = {tuple(t) for t in s["valley"]}
    for x, row, full in zip(s["grid"]["xhat"], s["cost"], s["walked_full"]):
        cells = [f"{'**' if (a, x) in valley else ''}{c:.0f}{'**' if (a, x) in valley else ''} ({f}/{s['walks_per_theta']})"
                 for a, c, f in zip(s["grid"]["alpha"], row, full)]
        lines.append(f"| {x:.2f} | " + " | ".join(cells) + " |")
    lines += ["", "Each cell: mean cost (walks of the full cycles); bold: within the valley."]
    if s["learning"]:
        lines += ["", f"| learning run | end theta (alpha, Xhat) | its cost on the map's seeds (full walks of {s['walks_per_theta']}) "
                      "| in the valley |", "|---|---|---|---|"]
        for r in s["learning"]["runs"]:
            lines.append(f"| {r['run']} | ({r['end'][0]:.3f}, {r['end'][1]:.3f}) | {r['cost_at_end']:.0f} ({r['walked_full_at_end']}) "
                         f"| {'yes' if r['in_valley'] else 'no'} |")
        for seed, c in s["learning"]["seeds"].items():
            diff = "-" if c["median_line_difference_m"] is None else f"{c['median_line_difference_m']:.3f} m"
            lines += ["", f"Seed {seed}: A and B {HELD[c['held']]} (their lines apart at the median X by {diff}; "
                          f"both in the valley: {'yes' if c['both_in_valley'] else 'no'})."]
    return lines
