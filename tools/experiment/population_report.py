"""The population experiment's outputs: ``summary.json``, ``patients.csv`` (a row per patient),
``gaits.csv`` (a row per patient and gait), two figures and ``report.md``. Written whole, as the
other experiments' are (:mod:`tools.experiment.report`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from tools.experiment.compare import ADAPTIVE
from tools.experiment.population import START, PopulationResults
from tools.experiment.report import _canvas, _csv, _save, _write


#: a gait's figures in gaits.csv (tools.experiment.compare.GaitStats.summary)
GAIT_COLUMNS = ("gait", "fixed_m", "walks", "cycles_asked", "stable_cycles_mean", "stable_cycles_min", "stable_cycles_max",
                "full_walks", "falls", "step_length_mean_m", "step_length_std_m", "stick_force_mean_n", "stick_force_std_n",
                "arm_torque_mean_nm", "arm_torque_std_nm")


def summary(res: PopulationResults) -> dict[str, Any]:
    plan = res.plan
    patients = [o.summary(plan.cycles) for o in res.outcomes]
    beat = [p["adaptive_beats_best_fixed"] for p in patients]
    reductions = [p["stick_force_reduction_pct"] for p in patients if p["stick_force_reduction_pct"] is not None]
    return {
        "experiment": "population", "seed": plan.seed, "patients": len(plan.patients), "start": START, "updates": plan.updates,
        "paired_rollouts": plan.design.paired, "evaluation_walks": plan.design.evaluation_walks,
        "cycles_per_rollout": plan.cycles, "compare_walks": plan.compare_walks, "mode": plan.mode,
        "walks_per_patient": plan.walks_per_patient(), "walks_run": res.walks_run, "walks_reused": res.walks_reused,
        "wall_time_s": round(res.wall_time_s, 1), "workers": plan.workers, "executor": plan.executor,
        "failed": [{"patient": f.name, "walk": f.walk, "error": f.error} for f in res.failed],
        "distribution": {
            "adaptive_beats_best_fixed": sum(beat),
            "adaptive_walks_every_walk": sum(p["adaptive_walks_every_walk"] for p in patients),
            "adaptive_below_fall_free_fixed": sum(p["adaptive_below_fall_free_fixed"] for p in patients),
            "no_fixed_length_without_falls": sum(p["best_fixed"] is None for p in patients),
            "stick_force_reduction_pct": _quartiles(reductions),
            "updates_to_converge": _quartiles([p["updates_to_converge"] for p in patients if p["updates_to_converge"] is not None]),
            "falls_by_gait": {g: sum(p["falls_by_gait"].get(g, 0) for p in patients) for g in _gaits(patients)},
        },
        "by_patient": patients,
    }


def _gaits(patients: list[dict[str, Any]]) -> list[str]:
    return [g["gait"] for g in patients[0]["gaits"]] if patients else []


def _quartiles(values: list[float]) -> dict[str, Any]:
    if not values:
        return {"n": 0}
    q = np.percentile(values, [0, 25, 50, 75, 100])
    return {"n": len(values), "min": round(float(q[0]), 2), "q1": round(float(q[1]), 2), "median": round(float(q[2]), 2),
            "q3": round(float(q[3]), 2), "max": round(float(q[4]), 2)}


def write_population(res: PopulationResults, out: Path) -> dict[str, Any]:
    """Every output of the population experiment under ``out``; returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    s = summary(res)
    _write(out / "summary.json", json.dumps(s, indent=2) + "\n")
    _write(out / "patients.csv", _csv([_patient_row(p) for p in s["by_patient"]]))
    _write(out / "gaits.csv", _csv([{"patient": p["patient"]["name"], **{k: g[k] for k in GAIT_COLUMNS}}
                                   for p in s["by_patient"] for g in p["gaits"]]))
    if s["by_patient"]:
        _figure_gaits(s, out / "population-gaits.png")
        _figure_theta(s, out / "population-theta.png")
    _write(out / "report.md", report(s))
    return s


def _patient_row(p: dict[str, Any]) -> dict[str, Any]:
    who = p["patient"]
    return {
        "patient": who["name"], "mass_kg": who["mass_kg"], "height_m": who["height_m"], "arm_strength": who["arm_strength"],
        "regime": who["placement"]["regime"], "spread_m": who["placement"]["spread_m"],
        "fit_length_error": who["fit"]["length_error_fraction"], "fit_mass_error_kg": who["fit"]["mass_error_kg"],
        "alpha": p["learned_theta"][0], "xhat_com": p["learned_theta"][1], "updates_to_converge": p["updates_to_converge"],
        "adaptive_stick_force_n": p["adaptive"]["stick_force_mean_n"], "adaptive_falls": p["adaptive"]["falls"],
        "best_fixed": p["best_fixed"], "best_fixed_stick_force_n": p["best_fixed_stick_force_n"],
        "stick_force_reduction_pct": p["stick_force_reduction_pct"], "adaptive_beats_best_fixed": p["adaptive_beats_best_fixed"],
        "adaptive_walks_every_walk": p["adaptive_walks_every_walk"], "adaptive_below_fall_free_fixed": p["adaptive_below_fall_free_fixed"],
        "comfortable_stick_force_n": who["comfortable_stick_force_n"], "above_comfort_pct": p["above_comfort_pct"],
    }


def _figure_gaits(s: dict[str, Any], path: Path) -> None:
    """Per gait, over the patients: the mean stick force (a box) and the falls (a bar)."""
    gaits = _gaits(s["by_patient"])
    labels = ["adaptive" if g == ADAPTIVE else f"{g} m" for g in gaits]
    forces = [[g["stick_force_mean_n"] for p in s["by_patient"] for g in p["gaits"] if g["gait"] == name
               and g["stick_force_mean_n"] is not None] for name in gaits]
    fig, ax = _canvas(1, 2, (12, 4.2))
    positions = np.arange(len(gaits))
    ax[0, 0].boxplot([f or [np.nan] for f in forces], positions=positions, widths=0.6)
    for i, f in enumerate(forces):
        ax[0, 0].scatter(np.full(len(f), i) + 0.15, f, s=10, color="tab:green" if gaits[i] == ADAPTIVE else "tab:gray", zorder=3)
    ax[0, 0].set(title="mean stick force per patient", ylabel="N")
    falls = [s["distribution"]["falls_by_gait"][g] for g in gaits]
    walks = s["compare_walks"] * len(s["by_patient"])
    ax[0, 1].bar(positions, falls, color=["tab:green" if g == ADAPTIVE else "tab:gray" for g in gaits])
    ax[0, 1].set(title=f"walks that fell, of {walks} per gait", ylabel="walks")
    for a in ax.flat:
        a.set_xticks(positions, labels, rotation=30)
        a.grid(alpha=0.3, axis="y")
    fig.suptitle(f"{s['patients']} virtual patients (seed {s['seed']}): the learned gait against fixed step lengths")
    _save(fig, path)


def _figure_theta(s: dict[str, Any], path: Path) -> None:
    """The learned theta against the patient's mass, height and placement spread."""
    people = s["by_patient"]
    fig, ax = _canvas(2, 3, (12, 6.5))
    beat = np.array([p["adaptive_beats_best_fixed"] for p in people])
    for col, (key, label) in enumerate((("mass_kg", "body mass, kg"), ("height_m", "height, m"), ("spread_m", "placement spread, m"))):
        x = np.array([p["patient"]["placement"]["spread_m"] if key == "spread_m" else p["patient"][key] for p in people])
        for row, (index, name) in enumerate(((0, "alpha"), (1, "X̂_CoM"))):
            y = np.array([p["learned_theta"][index] for p in people])
            a = ax[row, col]
            a.scatter(x[beat], y[beat], color="tab:green", label="beat the best fixed length")
            a.scatter(x[~beat], y[~beat], color="tab:red", marker="x", label="did not")
            a.set(xlabel=label, ylabel=f"learned {name}")
            a.grid(alpha=0.3)
    ax[0, 0].legend(fontsize=8)
    fig.suptitle("The learned theta against the patient")
    _save(fig, path)


def report(s: dict[str, Any]) -> str:
    d = s["distribution"]
    red = d["stick_force_reduction_pct"]
    lines = [
        f"# Population experiment: {s['patients']} virtual patients, seed {s['seed']}", "",
        f"Per patient: PI² from the paper's start {s['start']} ({s['updates']} updates of roll-outs of "
        f"{s['cycles_per_rollout']} gait cycles), then the learned gait against the fixed step lengths, "
        f"{s['compare_walks']} walks each. {s['walks_run']} walks run and {s['walks_reused']} reused in "
        f"{s['wall_time_s'] / 60:.1f} min on {s['workers']} workers ({s['executor']}).", "",
        f"* The learned gait beat the best fixed step length that never fell (less stick force, no more falls) "
        f"for **{d['adaptive_beats_best_fixed']} of {len(s['by_patient'])}** patients; "
        f"{d['no_fixed_length_without_falls']} had no fixed length without a fall.",
        f"* The learned gait walked {s['cycles_per_rollout']} of {s['cycles_per_rollout']} cycles in every comparison walk for "
        f"**{d['adaptive_walks_every_walk']} of {len(s['by_patient'])}** patients; its stick force was below every fixed "
        f"length that never fell (or none never fell) for **{d['adaptive_below_fall_free_fixed']} of {len(s['by_patient'])}**.",
        (f"* Stick force against that length, falls aside: median {red['median']} % less (quartiles {red['q1']} to {red['q3']} %, "
         f"{red['n']} patients)." if red["n"] else "* No patient had a fixed length to compare with."),
        "* Falls per gait, over all patients: " + ", ".join(
            f"{'adaptive' if g == ADAPTIVE else g + ' m'} {n}" for g, n in d["falls_by_gait"].items()) + ".", "",
        "| patient | kg | m | arms | placement | learned alpha, X̂ | adaptive N | best fixed | its N | less force | beat | falls adaptive |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in s["by_patient"]:
        who, a = p["patient"], p["adaptive"]
        lines.append(
            f"| {who['name']} | {who['mass_kg']} | {who['height_m']} | {who['arm_strength']} | {who['placement']['regime']} "
            f"{who['placement']['spread_m']} | {p['learned_theta'][0]:.2f}, {p['learned_theta'][1]:.3f} | {a['stick_force_mean_n']} "
            f"| {p['best_fixed'] or '–'} | {p['best_fixed_stick_force_n'] or '–'} | "
            f"{'–' if p['stick_force_reduction_pct'] is None else str(p['stick_force_reduction_pct']) + ' %'} | "
            f"{'yes' if p['adaptive_beats_best_fixed'] else 'no'} | {a['falls']} of {a['walks']} |")
    if s["failed"]:
        lines += ["", f"**{len(s['failed'])} patient(s) did not finish: a walk raised** (a software error, not a fall):"]
        lines += [f"* {f['patient']}: the walk {f['walk']}: {f['error']}" for f in s["failed"]]
    lines += ["", "![Stick force and falls per gait](population-gaits.png)", "",
              "![The learned theta against the patient](population-theta.png)", ""]
    return "\n".join(lines)
