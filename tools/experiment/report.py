"""The experiments' outputs: CSV data, ``summary.json``, PNG figures in the paper's layout and a
Markdown report that sets our numbers beside the paper's. Every file is written whole (to a
temporary name, then renamed), so an interrupted run never leaves one looking complete."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from config.files import write_bytes
from controller.factory import step_bounds
from tools.experiment.compare import ADAPTIVE
from tools.experiment.experiment import (CHEAPER_FALLS_SHARE, FORCE_FALL_SHARE, LINE_AGREEMENT_M, LONG_FALL_CYCLES, LONG_FALL_SHARE,
                                         PAPER_BOTH_STICKS_N, X_MEDIAN_RANGE, X_SPREAD_RANGE, X_SPREAD_STD, Results,
                                         comparison_checks, learning_checks, step_line)
from tools.experiment.falls import swings

#: the paper's figures (section IV), for the report
PAPER = {
    "cost": "about 8000-9000 falling to about 3500 (Fig. 7a)",
    "optimum": "both starts converge to Xhat_CoM 0.80, alpha -8.4 in about 10 updates",
    "stable": "average stable steps per roll-out rise to 10 of 10 (Fig. 7b)",
    "torque": "the adaptive gait's upper-body torque lower than every fixed step length 0.10-0.20 m (Fig. 8)",
    "force": "the adaptive gait's stick pressure about as low as a fixed 0.20 m step, which falls within 6 of 10 steps (Fig. 12)",
    "pressure": "the pressure of the sticks 250-500 N on the real AIDER (Fig. 12a; Fig. 11 falls from about 450 to 300 N while learning)",
    "trend": "the stick pressure falls as the fixed step lengthens (Fig. 12)",
    "x": "Xhat_CoM starts at 0.6 and 0.9, its optimum 0.80 (Fig. 7)",
}
COLORS = {"A": "tab:blue", "B": "tab:orange"}


def _write(path: Path, text: str | bytes) -> None:
    write_bytes(path, text if isinstance(text, bytes) else text.encode())


def _csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    if rows:
        w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return buf.getvalue()


def summary(res: Results) -> dict[str, Any]:
    plan = res.plan
    n = plan.cycles
    out: dict[str, Any] = {
        "mode": plan.mode, "seeds": plan.seeds, "starts": {s: list(t) for s, t in
                                                            ((r.start, r.theta0) for r in res.learning)},
        "updates": plan.updates, "cycles_per_rollout": n,
        "rollouts_per_update": plan.cfg.controller.learning.rollouts_per_update,
        "paired_rollouts": plan.design.paired, "evaluation_walks": plan.design.evaluation_walks,
        "walks_run": res.walks_run, "walks_reused": res.walks_reused, "wall_time_s": round(res.wall_time_s, 1),
        "workers": plan.workers,
        "executor": plan.executor,
    }
    if res.learning:
        out["learning"] = {"runs": [r.as_dict() for r in res.learning], "checks": learning_checks(res.learning, n, step_bounds(plan.cfg.controller), plan.updates)}
    if res.comparison:
        out["comparison"] = {"theta": list(res.compare_theta) if res.compare_theta else None,
                             "gaits": [g.summary(n) for g in res.comparison],
                             "checks": comparison_checks(res.comparison, n)}
    return out


def write_all(res: Results, out: Path) -> dict[str, Any]:
    """Every output of ``res`` under ``out``; returns the summary (also ``summary.json``)."""
    out.mkdir(parents=True, exist_ok=True)
    s = summary(res)
    if res.learning:
        _write(out / "learning.csv", _csv([
            {"start": r.start, "seed": r.seed, "update": u.index, "alpha": u.theta[0], "xhat": u.theta[1],
             "eval_alpha": u.evaluation_theta[0], "eval_xhat": u.evaluation_theta[1], "eval_cost": u.evaluation_cost,
             "eval_cycles": u.evaluation_cycles, "eval_end": u.evaluation_end, "batch_mean_cost": u.batch_mean_cost,
             "batch_mean_cycles": u.batch_mean_cycles, "batch_falls": u.batch_falls}
            for r in res.learning for u in r.updates]))
        _write(out / "rollouts.csv", _csv([
            {"start": r.start, "seed": r.seed, "update": ro["update"], "rollout": ro["rollout"],
             "alpha": ro["job"]["theta"][0], "xhat": ro["job"]["theta"][1], "walk_seed": ro["job"]["seed"],
             "cycles": ro["cycles_completed"], "fell": ro["fell"], "end": ro["end"],
             "mean_stick_force_n": ro["mean_stick_force_n"], "mean_step_m": _mean(ro["step_lengths_m"])}
            for r in res.learning for ro in r.rollouts]))
        _write(out / "steps.csv", _csv([
            {"start": r.start, "seed": r.seed, "step": i, "update": update, "length_m": length, "x_ratio": x, "stick_force_n": f}
            for r in res.learning for i, (update, length, x, f) in enumerate(_learning_steps(r))]))
        _figure_learning(res, out / "fig7-learning.png")
        _figure_steps(res, out / "fig11-stick-force-while-learning.png")
    if res.comparison:
        _write(out / "compare.csv", _csv([
            {"gait": g.gait, "seed": w["job"]["seed"], "cycles": w["cycles_completed"], "fell": w["fell"], "end": w["end"],
             "mean_step_m": _mean(w["step_lengths_m"]), "mean_stick_force_n": w["mean_stick_force_n"],
             "mean_arm_torque_nm": w["mean_arm_torque_nm"]}
            for g in res.comparison for w in g.walks]))
        _figure_compare(res, out / "fig8-12-compare.png")
        _figure_lines(res, out / "step-lines.png")
    _write(out / "summary.json", json.dumps(s, indent=2) + "\n")
    _write(out / "report.md", report(s))
    return s


def write_falls(results: list[dict[str, Any]], out: Path) -> dict[str, Any]:
    """The random-length walks' outputs (:mod:`tools.experiment.falls`) under ``out``: falls.csv,
    falls.json, falls.png and falls.md; returns the summary."""
    from tools.experiment import falls

    out.mkdir(parents=True, exist_ok=True)
    s = falls.analyse(results)
    _write(out / "falls.csv", _csv(falls.csv_rows(results)))
    falls.figure(results, s, out / "falls.png", _canvas, _save)
    _write(out / "falls.json", json.dumps(s, indent=2) + "\n")
    _write(out / "falls.md", "# Random step lengths: where the walks end\n\n" + "\n".join(falls.report_lines(s)) + "\n")
    return s


def write_costmap(results: list[dict[str, Any]], out: Path, grid, walks: int, cfg, learning: dict[str, Any] | None) -> dict[str, Any]:
    """The cost map (:mod:`tools.experiment.costmap`) under ``out``: costmap.csv, costmap.json,
    costmap.png and costmap.md; returns the summary."""
    from tools.experiment import costmap

    out.mkdir(parents=True, exist_ok=True)
    s = costmap.analyse(results, grid, walks, cfg, learning)
    rows = [{"alpha": a, "xhat": x, "cost": c, "walked_full": f}
            for x, cost_row, full_row in zip(s["grid"]["xhat"], s["cost"], s["walked_full"])
            for a, c, f in zip(s["grid"]["alpha"], cost_row, full_row)]
    _write(out / "costmap.csv", _csv(rows))
    costmap.figure(s, out / "costmap.png", _canvas, _save)
    _write(out / "costmap.json", json.dumps(s, indent=2) + "\n")
    _write(out / "costmap.md", "# The noise-free cost of theta\n\n" + "\n".join(costmap.report_lines(s)) + "\n")
    return s


def write_intention(results: list[dict[str, Any]], out: Path, bins: int, by: str = "planted") -> dict[str, Any]:
    """The fixed lengths crossed with X_CoM/X_SP (:mod:`tools.experiment.intention`) under ``out``:
    intention.csv, intention.json, intention.png and intention.md; returns the summary."""
    from tools.experiment import intention

    out.mkdir(parents=True, exist_ok=True)
    s = intention.analyse(results, bins, by)
    _write(out / "intention.csv", _csv(intention.csv_rows(results)))
    intention.figure(results, s, out / "intention.png", _canvas, _save)
    _write(out / "intention.json", json.dumps(s, indent=2) + "\n")
    _write(out / "intention.md", "# Which step fits which intention\n\n" + "\n".join(intention.report_lines(s)) + "\n")
    return s


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 5) if values else None


def _learning_steps(r) -> list[tuple[int, float, float, float]]:
    return [(ro["update"], length, x, f) for ro in r.rollouts
            for length, x, f in zip(ro["step_lengths_m"], ro["step_x_ratio"], ro["step_stick_force_n"])]


# -- figures ----------------------------------------------------------------------------------


def _canvas(rows: int, cols: int, size: tuple[float, float]):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, cols, squeeze=False)


def _save(fig, path: Path) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    _write(path, buf.getvalue())


def _colormap(name: str, n: int):
    from matplotlib import colormaps

    return colormaps[name].resampled(n)


def _scalar_mappable(cmap, n: int):
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    return ScalarMappable(norm=Normalize(-0.5, n - 0.5), cmap=cmap)


def _by_start(res: Results) -> dict[str, list]:
    out: dict[str, list] = {}
    for r in res.learning:
        out.setdefault(r.start, []).append(r)
    return out


def _figure_learning(res: Results, path: Path) -> None:
    """Fig. 7: (a) noise-free cost per update, (b) average stable cycles per roll-out, and theta."""
    fig, ax = _canvas(2, 2, (11, 7.5))
    n = res.plan.cycles
    for start, runs in _by_start(res).items():
        c = COLORS.get(start)
        costs = np.array([[u.evaluation_cost for u in r.updates] for r in runs], dtype=float)
        stable = np.array([[u.batch_mean_cycles if u.batch_mean_cycles is not None else np.nan for u in r.updates] for r in runs])
        x = np.arange(costs.shape[1])
        for row in costs:
            ax[0, 0].plot(x, row, color=c, alpha=0.25, lw=1)
        ax[0, 0].plot(x, costs.mean(axis=0), color=c, lw=2, marker="o", ms=3, label=f"start {start} {runs[0].theta0}")
        for row in stable:
            ax[0, 1].plot(x[1:], row[1:], color=c, alpha=0.25, lw=1)
        ax[0, 1].plot(x[1:], stable[:, 1:].mean(axis=0), color=c, lw=2, marker="o", ms=3, label=f"start {start}")
        for r in runs:
            alpha = [u.evaluation_theta[0] for u in r.updates]
            xhat = [u.evaluation_theta[1] for u in r.updates]
            ax[1, 0].plot(x, alpha, color=c, lw=1.2)
            ax[1, 1].plot(x, xhat, color=c, lw=1.2)
    ax[0, 0].set(title="(a) noise-free roll-out cost", xlabel="update", ylabel="cost R (eq. 11)")
    ax[0, 1].set(title="(b) average stable gait cycles per roll-out", xlabel="update", ylabel=f"cycles of {n}", ylim=(0, n + 0.5))
    ax[1, 0].set(title="alpha (deployed theta)", xlabel="update", ylabel="alpha (m)")
    ax[1, 1].set(title="Xhat_CoM (deployed theta)", xlabel="update", ylabel="Xhat_CoM")
    for a in ax.flat:
        a.grid(alpha=0.3)
    ax[0, 0].legend()
    fig.suptitle(f"Online PI² from the paper's starts A and B ({res.plan.mode} mode, seeds {res.plan.seeds})")
    _save(fig, path)


def _figure_steps(res: Results, path: Path) -> None:
    """The analogue of the paper's Fig. 11: the mean stick force of every step while learning, one
    panel per start, each step coloured by its X_CoM/X_SP bin (bins of equal counts over every
    learning step), and a running mean per run."""
    from tools.experiment.intention import DEFAULT_BINS, bin_edges, bin_index

    by_start = _by_start(res)
    fig, ax = _canvas(len(by_start), 1, (11, 3.2 * len(by_start)))
    window = 50
    steps = {r.name: np.array(_learning_steps(r), dtype=float).reshape(-1, 4) for r in res.learning}
    x_all = np.concatenate([v[:, 2] for v in steps.values()])
    edges = bin_edges(x_all[np.isfinite(x_all)], DEFAULT_BINS)
    cmap = _colormap("viridis", DEFAULT_BINS)
    for a, (start, runs) in zip(ax[:, 0], by_start.items()):
        for r in runs:
            f, x = steps[r.name][:, 3], steps[r.name][:, 2]
            a.scatter(np.arange(len(f)), f, c=bin_index(edges, x), cmap=cmap, vmin=-0.5,
                      vmax=DEFAULT_BINS - 0.5, s=4, alpha=0.6, lw=0)
            if len(f) >= window:
                smooth = np.convolve(f, np.ones(window) / window, mode="valid")
                a.plot(np.arange(window - 1, len(f)), smooth, color=COLORS.get(start), lw=1.5, label=f"{r.name}: mean of the last {window}")
        a.set(title=f"start {start}: mean stick force of every step over the learning runs", ylabel="stick force (N)")
        a.grid(alpha=0.3)
        if a.get_legend_handles_labels()[0]:  # runs shorter than the window have no running mean
            a.legend(fontsize=8, loc="upper right")
    ax[-1, 0].set(xlabel="step (all roll-outs in order)")
    bar = fig.colorbar(_scalar_mappable(cmap, DEFAULT_BINS), ax=ax[:, 0], ticks=range(DEFAULT_BINS))
    bar.ax.set_yticklabels([f"{lo:.2f}-{hi:.2f}" for lo, hi in zip(edges, edges[1:])])
    bar.set_label("X_CoM/X_SP at the swing's start (bin)")
    _save(fig, path)


def _figure_lines(res: Results, path: Path) -> None:
    """Why the learned step is where it is: the learned step-length lines g(X) (each run's deployed
    theta, after the clamp) and the compared adaptive gait's own steps over the comparison's
    fixed-length walks binned by X_CoM/X_SP as ``experiment intention`` bins them."""
    from tools.experiment import intention

    fixed = [w for g in res.comparison if g.fixed_m is not None for w in g.walks]
    s = intention.analyse(fixed, intention.DEFAULT_BINS)
    if not s["swings"]:
        return
    bounds = step_bounds(res.plan.cfg.controller)
    x = np.linspace(s["best"][0]["from"], s["best"][-1]["to"], 100)
    adaptive = next(g for g in res.comparison if g.gait == ADAPTIVE)
    steps = np.array([(sw.x_ratio, sw.length_m) for sw in swings(adaptive.walks) if math.isfinite(sw.x_ratio)]).reshape(-1, 2)
    fig, ax = _canvas(1, 2, (14, 5))
    for a, (key, title, cmap, scale), letter in zip(ax[0], intention.GRIDS, "ab"):
        intention.draw_grid(fig, a, s, key, f"({letter}) fixed lengths: {title}; o: best step", cmap, scale)
        for r in res.learning:
            a.plot(x, step_line(bounds, r.final.evaluation_theta, x), color=COLORS.get(r.start), lw=1.5,
                   ls=("-", "--", ":", "-.")[r.seed % 4], label=f"learned {r.name}")
        a.scatter(steps[:, 0], steps[:, 1], s=8, c="tab:green", edgecolors="k", linewidths=0.3, label="the adaptive gait's steps")
        a.plot(x, step_line(bounds, res.compare_theta, x), color="tab:green", lw=2, label="the compared theta")
        a.set_xlim(x[0], x[-1])
    ax[0, 0].legend(fontsize=7, loc="lower right")
    th = res.compare_theta
    fig.suptitle(f"Step length against X_CoM/X_SP: learned lines over {len(fixed)} fixed-length walks "
                 f"(adaptive theta alpha {th[0]:.3f}, Xhat {th[1]:.3f})")
    _save(fig, path)


def _figure_compare(res: Results, path: Path) -> None:
    """Figs. 8 and 12: upper-body torque, stick force and stable cycles per gait (mean, spread over seeds)."""
    n = res.plan.cycles
    stats = [g.summary(n) for g in res.comparison]
    labels = [("adaptive" if s["gait"] == ADAPTIVE else f"{s['gait']} m") for s in stats]
    colors = ["tab:green" if s["gait"] == ADAPTIVE else "tab:gray" for s in stats]
    fig, ax = _canvas(1, 3, (14, 4.2))
    x = np.arange(len(stats))
    for a, key, title, unit in ((ax[0, 0], "arm_torque", "(Fig. 8) upper-body torque", "N·m"),
                                (ax[0, 1], "stick_force", "(Fig. 12) stick force", "N")):
        mean = [s[f"{key}_mean_{'nm' if key == 'arm_torque' else 'n'}"] or 0 for s in stats]
        std = [s[f"{key}_std_{'nm' if key == 'arm_torque' else 'n'}"] or 0 for s in stats]
        a.bar(x, mean, yerr=std, color=colors, capsize=3)
        a.set(title=title, ylabel=unit)
    walks = [np.array([w["cycles_completed"] for w in g.walks]) for g in res.comparison]
    ax[0, 2].bar(x, [w.mean() for w in walks], yerr=[w.std() for w in walks], color=colors, capsize=3)
    for i, w in enumerate(walks):
        ax[0, 2].scatter(np.full(len(w), i), w, color="k", s=8, zorder=3)
    ax[0, 2].set(title="stable gait cycles", ylabel=f"of {n}", ylim=(0, n + 0.5))
    for a in ax.flat:
        a.set_xticks(x, labels, rotation=30)
        a.grid(alpha=0.3, axis="y")
    th = res.compare_theta
    fig.suptitle(f"Adaptive gait (theta alpha {th[0]:.3f}, Xhat {th[1]:.3f}) against fixed step lengths, "
                 f"{len(walks[0])} seeds, mean and std")
    _save(fig, path)


# -- the report -------------------------------------------------------------------------------


def report(s: dict[str, Any]) -> str:
    """Markdown: our numbers beside the paper's."""
    lines = ["# The paper's experiments, reproduced", "",
             f"Mode {s['mode']}, seeds {s['seeds']}, {s['cycles_per_rollout']} gait cycles per roll-out, "
             f"an update every {s['rollouts_per_update']} roll-outs ({'paired: one patient seed' if s['paired_rollouts'] else 'unpaired: a seed each'}), "
             f"up to {s['updates']} updates, each evaluated noise-free over {s['evaluation_walks']} fixed seeds; "
             f"{s['walks_run']} walks run and {s['walks_reused']} reused in {s['wall_time_s'] / 60:.1f} min on {s['workers']} workers.", ""]
    if "learning" in s:
        checks = s["learning"]["checks"]
        lines += ["## Learning (Fig. 7)", "", "| run | start theta | cost at start | final cost | cut | 30 % cut at update | "
                  "final theta (alpha, Xhat) | final stable cycles | first full walk at update |", "|---|---|---|---|---|---|---|---|---|"]
        for r in s["learning"]["runs"]:
            c = checks["runs"][f"{r['start']}-s{r['seed']}"]
            lines.append(f"| {r['start']} seed {r['seed']} | ({r['theta0'][0]}, {r['theta0'][1]}) | {c['start_cost']:.0f} | "
                         f"{c['final_cost']:.0f} | {_pct(c['final_cut'])} | {c['cut_30_at_update'] or '-'} | "
                         f"({c['final_theta'][0]:.3f}, {c['final_theta'][1]:.3f}) | {c['final_cycles']} | {c['first_full_at_update'] or '-'} |")
        lines += ["", "| claim | paper | here |", "|---|---|---|",
                  f"| noise-free cost falls | {PAPER['cost']} | cut by 30 % or more by the last update: {_count(checks, 'cost_cut_30_percent')} |",
                  f"| A and B end at the same theta (within 10 %), or their step-length lines agree within "
                  f"{LINE_AGREEMENT_M} m at the 10th, 50th and 90th percentile of X_CoM/X_SP | {PAPER['optimum']} | {_seeds_same(checks)} |",
                  f"| stable steps reach 10 of 10 | {PAPER['stable']} | the last noise-free walk walks them all: {_count(checks, 'reaches_full_cycles')} |", ""]
    if "comparison" in s:
        c = s["comparison"]
        lines += ["## Adaptive against fixed step lengths (Figs. 8 and 12)", "",
                  f"Adaptive theta: alpha {c['theta'][0]:.3f}, Xhat_CoM {c['theta'][1]:.3f}.", "",
                  "| gait | mean step m | stable cycles (mean, min) | falls | stick force N, per stick (mean ± std) | both sticks N | upper-body torque N·m (mean ± std) |",
                  "|---|---|---|---|---|---|---|"]
        for g in c["gaits"]:
            lines.append(f"| {g['gait']} | {_f(g['step_length_mean_m'], 3)} | {g['stable_cycles_mean']:.1f}, {g['stable_cycles_min']} | "
                         f"{g['falls']}/{g['walks']} | {_f(g['stick_force_mean_n'], 1)} ± {_f(g['stick_force_std_n'], 1)} | "
                         f"{_f(g['both_sticks_force_mean_n'], 1)} ± {_f(g['both_sticks_force_std_n'], 1)} | "
                         f"{_f(g['arm_torque_mean_nm'], 1)} ± {_f(g['arm_torque_std_nm'], 1)} |")
        ch = c["checks"]
        adaptive = next(g for g in c["gaits"] if g["gait"] == ADAPTIVE)
        lines += ["", "| claim | paper | here |", "|---|---|---|",
                  f"| adaptive stick force below every fixed length that does not fall | {PAPER['force']} | "
                  f"{_yes(ch['adaptive_force_below_every_non_falling_fixed'])} (non-falling fixed: {', '.join(ch['non_falling_fixed']) or 'none'}) |",
                  f"| the adaptive gait's stick force, both sticks together, in {PAPER_BOTH_STICKS_N[0]:.0f}-{PAPER_BOTH_STICKS_N[1]:.0f} N | {PAPER['pressure']} | "
                  f"{_f(ch['adaptive_both_sticks_n'], 1)} N: {_yes(ch['adaptive_both_sticks_in_paper_range'])} |",
                  f"| the too-long fixed length falls within {LONG_FALL_CYCLES} cycles in {LONG_FALL_SHARE:.0%} of its walks, the adaptive walks 10 of 10 | {PAPER['force']} | "
                  f"{ch['longest_fixed']} m: {_yes(ch['longest_fixed_falls_within_6_cycles'])}; adaptive: {_yes(ch['adaptive_walks_full'])} |",
                  f"| among fixed lengths the stick force falls as the step lengthens, {ch['shortest_fixed']} m above {ch['longest_fixed']} m by {FORCE_FALL_SHARE:.0%} | {PAPER['trend']} | "
                  f"by {_pct(ch['fixed_force_fall'])}: {_yes(ch['fixed_force_falls_with_length'])} |",
                  f"| every fixed length cheaper than the adaptive gait falls in {CHEAPER_FALLS_SHARE:.0%} of its walks | {PAPER['force']} | "
                  f"{_yes(ch['every_cheaper_fixed_falls'])} (cheaper: {', '.join(ch['cheaper_fixed']) or 'none'}) |",
                  f"| upper-body torque | {PAPER['torque']} | {_yes(ch['adaptive_torque_below_every_fixed'])} |", "",
                  f"X_CoM/X_SP at the swings' start over every compared walk: median {_f(ch['x_ratio']['p50'], 3)}, {_spread(ch['x_ratio'])} "
                  f"(asked: median in {X_MEDIAN_RANGE[0]}-{X_MEDIAN_RANGE[1]}, {PAPER['x']}: {_yes(ch['x_ratio_median_in_paper_range'])}; "
                  f"sd >= {X_SPREAD_STD}, 10th-90th percentile range >= {X_SPREAD_RANGE}: {_yes(ch['x_ratio_spreads'])}); "
                  f"the adaptive step lengths {_f(adaptive['step_length_mean_m'], 3)} ± {_f(adaptive['step_length_std_m'], 4)} m.", ""]
    return "\n".join(lines)


def _spread(x: dict[str, Any]) -> str:
    if not x["swings"]:
        return "no swings"
    return f"sd {x['std']:.3f}, 10th-90th percentile {x['p10']:.3f}-{x['p90']:.3f} (range {x['range_p10_p90']:.3f}) over {x['swings']} swings"


def _count(checks: dict[str, Any], key: str) -> str:
    runs = checks["runs"].values()
    return f"{sum(r[key] for r in runs)} of {len(runs)} runs"


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _f(x: float | None, d: int) -> str:
    return "-" if x is None else f"{x:.{d}f}"


def _yes(b: bool) -> str:
    return "yes" if b else "no"


def _seeds_same(checks: dict[str, Any]) -> str:
    if not checks["seeds"]:
        return "(needs both starts)"
    return "; ".join(f"seed {k}: theta {_yes(v['same_within_10_percent'])} (differences {v['relative_difference']}), "
                     f"lines {_yes(v['lines']['agree'])} (at X {v['lines']['x_percentiles']}: A {v['lines']['length_A_m']} m, "
                     f"B {v['lines']['length_B_m']} m)" for k, v in checks["seeds"].items())
