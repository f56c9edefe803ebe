"""The experiments (tools/experiment): learning through the whole pipeline, parallel workers that
give the same results as one process, resuming from stored walks, the paper's checks and the
outputs. Tiny settings (one gait cycle per roll-out, two roll-outs per update) keep it fast; the
full experiment is ``aider-exo experiment all``."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from config import default_config_path, load_config, with_overrides
from controller.compensation import StepBounds
from tests.conftest import ROOT
from tools.cli import main
from tools.experiment import experiment, runner
from tools.experiment.compare import GaitStats, compare_jobs
from tools.experiment.experiment import Plan, comparison_checks, learning_checks
from tools.experiment.learn import (STARTS, LearningRun, RolloutDesign, Update, evaluation_seeds, learning_run,
                                   rollout_cost, walk_seed)
from tools.experiment.report import summary
from tools.experiment.runner import ExperimentError, WalkJob, WalkPool
from tools.experiment.schedule import Interrupted

TINY = {"controller.learning.steps_per_rollout": 1, "controller.learning.rollouts_per_update": 2}
CFG = with_overrides(load_config(default_config_path()), TINY)
DESIGN = RolloutDesign(evaluation_walks=2)  # paired roll-outs; two evaluation walks per update


def _learn(out: Path, workers: int) -> experiment.Results:
    return experiment.run(Plan(cfg=CFG, out=out, seeds=[0], starts=["A", "B"], updates=1, design=DESIGN, workers=workers),
                          progress=False)


def _strip(summary: dict) -> dict:
    """A summary without what depends on how it ran (JSON form: tuples as lists)."""
    plain = json.loads(json.dumps(summary))
    return {k: v for k, v in plain.items() if k not in ("walks_run", "walks_reused", "wall_time_s", "workers")}


@pytest.fixture(scope="module")
def parallel(tmp_path_factory) -> tuple[Path, dict]:
    """``aider-exo experiment learn`` with two worker processes, as its own process (the pool's
    processes never run inside the test process)."""
    out = tmp_path_factory.mktemp("parallel")
    sets = [a for k, v in TINY.items() for a in ("--set", f"{k}={v}")]
    done = subprocess.run(
        [sys.executable, "-m", "tools.cli", "experiment", "learn", "--out", str(out), "--workers", "2", "--updates", "1",
         "--evaluation-walks", "2", *sets, "--json", "--quiet"],
        check=False, capture_output=True, text=True, timeout=600, cwd=ROOT,
    )
    assert done.returncode == 0, done.stderr
    return out, json.loads(done.stdout)


def test_learning_runs_the_planned_walks_and_updates(parallel):
    out, s = parallel
    assert s["walks_run"] == 2 * (1 * (2 + 2) + 2) and s["workers"] == 2
    assert s["paired_rollouts"] and s["evaluation_walks"] == 2
    for run in s["learning"]["runs"]:
        assert [u["index"] for u in run["updates"]] == [0, 1]
        assert run["updates"][0]["evaluation_theta"] == list(STARTS[run["start"]])
        # the update's batch: two roll-outs with exploration around the start
        assert run["updates"][1]["batch_mean_cycles"] is not None and run["updates"][1]["noise"] is not None
    with (out / "rollouts.csv").open() as f:
        rollouts = list(csv.DictReader(f))
    assert sorted(r["start"] for r in rollouts) == ["A", "A", "B", "B"]
    assert all((float(r["alpha"]), float(r["xhat"])) != STARTS[r["start"]] for r in rollouts)
    for name in ("summary.json", "report.md", "learning.csv", "rollouts.csv", "steps.csv", "fig7-learning.png",
                 "fig11-stick-force-while-learning.png"):
        assert (out / name).stat().st_size > 0, name
    assert json.loads((out / "summary.json").read_text()) == s
    assert "| A seed 0 |" in (out / "report.md").read_text()


def test_workers_give_the_results_of_one_process(parallel, tmp_path):
    _, s = parallel
    assert _strip(summary(_learn(tmp_path, workers=0))) == _strip(s)


def test_a_second_run_resumes_from_the_stored_walks(parallel):
    out, s = parallel
    stored = sorted((out / "cache").glob("*.json"))
    assert len(stored) == s["walks_run"]
    stored[0].unlink()  # as if the run had been interrupted before that walk finished
    again = _learn(out, workers=0)
    assert (again.walks_run, again.walks_reused) == (1, s["walks_run"] - 1)
    assert _strip(summary(again)) == _strip(s)


def test_a_stop_keeps_the_finished_walks_and_the_same_plan_resumes(tmp_path):
    plan = Plan(cfg=CFG, out=tmp_path, seeds=[0], starts=["A"], updates=2, workers=0)
    asked = []
    with pytest.raises(Interrupted, match="the same command resumes"):
        experiment.run(plan, progress=False, stop=lambda: bool(asked) or bool(asked.append(1)))  # stop at the second look
    stored = len(list((tmp_path / "cache").glob("*.json")))
    assert 1 <= stored < plan.walks_planned()
    again = experiment.run(plan, progress=False)
    assert again.walks_reused == stored and again.walks_run == plan.walks_planned() - stored


def test_a_damaged_stored_walk_is_a_one_line_error(tmp_path):
    pool = WalkPool(CFG, 0, tmp_path)
    job = WalkJob(seed=1, cycles=1, fixed_m=0.12)
    (tmp_path / f"{job.key(pool.digest)}.json").write_text("{not json")
    with pytest.raises(ExperimentError, match="unreadable walk result.*delete it"):
        pool.submit(job)


def test_walk_jobs_are_keyed_by_everything_that_changes_the_walk():
    a = WalkJob(seed=1, cycles=10, theta=(-1.0, 0.6))
    assert a.key("cfg") == WalkJob(seed=1, cycles=10, theta=(-1.0, 0.6)).key("cfg")
    others = [WalkJob(seed=2, cycles=10, theta=(-1.0, 0.6)), WalkJob(seed=1, cycles=9, theta=(-1.0, 0.6)),
              WalkJob(seed=1, cycles=10, theta=(-1.0, 0.61)), WalkJob(seed=1, cycles=10, fixed_m=0.12)]
    assert len({a.key("cfg"), a.key("cfg2"), *(o.key("cfg") for o in others)}) == 6
    with pytest.raises(ExperimentError, match="exactly one"):
        WalkJob(seed=1, cycles=1)


def test_the_result_format_is_part_of_a_walks_key(monkeypatch):
    """A result whose meaning changed (runner.RESULT_FORMAT) is not reused under the new one."""
    job = WalkJob(seed=1, cycles=1, fixed_m=0.12)
    old_key = job.key("cfg")
    monkeypatch.setattr(runner, "RESULT_FORMAT", "aider-exo.walk-result/0")
    assert job.key("cfg") != old_key


def test_rollout_cost_is_equation_11():
    walked = {"cycle_costs": [50.0, 60.0], "fell": False}
    fell = {"cycle_costs": [50.0], "fell": True}
    assert rollout_cost(walked, 2, 5000.0, 1.0) == 110.0
    assert rollout_cost(fell, 2, 5000.0, 1.0) == 2500.0 + 50.0
    assert walk_seed(0, 1, 2) == walk_seed(0, 1, 2) != walk_seed(0, 1, 3)


def _fake_walk(job: WalkJob) -> dict:
    """A walk's result made up from its job: fewer cycles and a higher cost the lower alpha."""
    cycles = 1 if job.theta[0] < -1.0 else 2
    return {"cycle_costs": [100.0 - 10 * job.theta[0]] * cycles, "fell": cycles < 2, "cycles_completed": cycles,
            "end": "walked" if cycles == 2 else "forward fall", "swings": []}


def _drive(design: RolloutDesign, updates: int = 2, walk=_fake_walk) -> tuple[list[list[WalkJob]], LearningRun]:
    """A learning run of 2-cycle roll-outs driven with ``walk``: every batch it asked for, and the run."""
    cfg = with_overrides(CFG, {"controller.learning.steps_per_rollout": 2, "controller.learning.rollouts_per_update": 3})
    gen, batches = learning_run(cfg, "A", 0, updates=updates, design=design), []
    jobs = next(gen)
    try:
        while True:
            batches.append(jobs)
            jobs = gen.send([walk(j) for j in jobs])
    except StopIteration as stop:
        return batches, stop.value


def test_paired_rollouts_share_an_update_seed_and_draw_a_new_one_each_update():
    batches, _ = _drive(RolloutDesign(paired=True, evaluation_walks=2))
    rollouts = [b[2:] for b in batches[:-1]]  # each batch: 2 evaluation walks, then the update's 3 roll-outs
    assert [len(r) for r in rollouts] == [3, 3] and len(batches[-1]) == 2
    for r in rollouts:
        assert len({j.seed for j in r}) == 1 and len({j.theta for j in r}) == 3  # one patient, three thetas
    assert rollouts[0][0].seed != rollouts[1][0].seed
    unpaired = [b[2:] for b in _drive(RolloutDesign(paired=False, evaluation_walks=2))[0][:-1]]
    assert all(len({j.seed for j in r}) == 3 for r in unpaired)
    assert {j.seed for r in unpaired for j in r}.isdisjoint({rollouts[0][0].seed, rollouts[1][0].seed})


def test_the_evaluation_walks_a_fixed_seed_set_and_averages_its_costs():
    batches, run = _drive(RolloutDesign(evaluation_walks=4))
    evaluations = [b[:4] for b in batches]
    seeds = [j.seed for j in evaluations[0]]
    assert len(set(seeds)) == 4 and all([j.seed for j in e] == seeds for e in evaluations)  # the same set every update
    assert all(len({j.theta for j in e}) == 1 for e in evaluations)
    assert not set(seeds) & {j.seed for b in batches for j in b[4:]}  # no roll-out walks an evaluation seed
    for u in run.updates:
        assert u.evaluation_costs == [u.evaluation_cost] * 4  # the fake walk's cost depends on theta only
    assert run.updates[0].evaluation_cost == 2 * (100.0 + 10.0)  # theta A: alpha -1.0, two cycles


def test_the_evaluation_reports_its_worst_walk():
    design = RolloutDesign(evaluation_walks=3)
    unlucky = evaluation_seeds(0, sorted(STARTS).index("A"), design)[1]

    def walk(job: WalkJob) -> dict:
        fell = {"cycle_costs": [110.0], "cycles_completed": 1, "end": "backward fall", "fell": True}
        return {**_fake_walk(job), **fell} if job.seed == unlucky else _fake_walk(job)

    _, run = _drive(design, updates=1, walk=walk)
    first = run.updates[0]
    assert (first.evaluation_cycles, first.evaluation_end) == (1, "backward fall")
    assert first.evaluation_costs[1] > first.evaluation_costs[0] == first.evaluation_costs[2]  # eq. (11): the fall's cost
    assert first.evaluation_cost == round(sum(first.evaluation_costs) / 3, 3)


def test_a_design_needs_an_evaluation_walk():
    with pytest.raises(ExperimentError, match="at least 1"):
        RolloutDesign(evaluation_walks=0)
    assert RolloutDesign(evaluation_walks=5).walks_per_run(updates=15, rollouts=5) == 15 * 10 + 5


BOUNDS = StepBounds(init_m=0.15, min_m=0.06, max_m=0.25)


def _run(start: str, seed: int, costs: list[float], cycles: list[int], final_theta: tuple[float, float],
         x_seen: tuple[float, ...] = (0.1, 0.2, 0.3)) -> LearningRun:
    run = LearningRun(start=start, seed=seed, theta0=STARTS[start])
    for i, (c, n) in enumerate(zip(costs, cycles)):
        run.updates.append(Update(index=i, theta=final_theta, evaluation_theta=final_theta if i else STARTS[start],
                                  evaluation_cost=c, evaluation_cycles=n, evaluation_end="walked" if n == 10 else "fell"))
        if i:
            run.rollouts.append({"update": i, "rollout": 1, "swings": [[0.1, x, True] for x in x_seen]})
    return run


def test_learning_checks_follow_the_done_when_rules():
    good = [_run("A", 0, [5600, 3000, 700], [0, 4, 10], (-0.50, 0.55)), _run("B", 0, [5500, 800, 650], [1, 10, 10], (-0.52, 0.56))]
    c = learning_checks(good, 10, BOUNDS)
    assert c["all_converge_together"] and c["all_reach_full_cycles"] and c["all_cut_cost_30_percent"]
    assert c["runs"]["A-s0"]["cut_30_at_update"] == 1 and c["runs"]["A-s0"]["first_full_at_update"] == 2
    apart = [good[0], _run("B", 0, [5500, 800, 650], [1, 10, 10], (-0.1, 0.9))]
    assert not learning_checks(apart, 10, BOUNDS)["all_converge_together"]
    flat = [_run("A", 0, [700, 690, 650], [10, 10, 10], (-0.5, 0.55))]
    assert not learning_checks(flat, 10, BOUNDS)["all_cut_cost_30_percent"]
    lost = [_run("A", 0, [5000, 1000, 3700], [0, 10, 3], (-0.5, 0.55))]  # cut once, lost again by the end
    c = learning_checks(lost, 10, BOUNDS)["runs"]["A-s0"]
    assert c["cut_30_at_update"] == 1 and not c["cost_cut_30_percent"] and not c["reaches_full_cycles"]


def test_a_and_b_apart_in_theta_agree_when_their_step_lines_do_where_they_walk():
    # theta 40 % apart in alpha, but the lines g(X) = 0.15 + alpha (Xhat - X) cross at X 0.2 with
    # slopes 0.04 m per unit ratio apart: 0.002 m apart at the ends of the X walked (0.15-0.25)
    a = _run("A", 0, [5600, 700], [0, 10], (-0.10, 0.40), x_seen=(0.15, 0.2, 0.25))
    b = _run("B", 0, [5500, 650], [0, 10], (-0.14, 0.3429), x_seen=(0.15, 0.2, 0.25))
    seed = learning_checks([a, b], 10, BOUNDS)["seeds"][0]
    assert not seed["same_within_10_percent"] and seed["lines"]["agree"] and seed["same_or_lines_agree"]
    assert seed["lines"]["x_percentiles"] == pytest.approx([0.15, 0.2, 0.25])
    assert max(seed["lines"]["difference_m"]) == pytest.approx(0.04 * 0.05, abs=1e-4)
    # the same lines over a wider X (0.15 either side of the crossing): 0.006 m apart ...
    wide = [_run(r.start, 0, [5600, 700], [0, 10], r.final.evaluation_theta, x_seen=(0.05, 0.2, 0.35)) for r in (a, b)]
    assert learning_checks(wide, 10, BOUNDS)["seeds"][0]["lines"]["agree"]
    # ... but not a pair 0.01 m apart at X 0.2 with slopes 0.5 and 0.3 m per unit ratio
    steep = [_run("A", 0, [5600, 700], [0, 10], (-0.5, 0.3), x_seen=(0.05, 0.2, 0.35)),
             _run("B", 0, [5500, 650], [0, 10], (-0.3, 0.3333), x_seen=(0.05, 0.2, 0.35))]
    assert not learning_checks(steep, 10, BOUNDS)["seeds"][0]["lines"]["agree"]
    # the lines are the steps as commanded: both clamped to the shortest step agree
    short = [_run("A", 0, [5600, 700], [0, 10], (-1.0, 0.6)), _run("B", 0, [5500, 650], [0, 10], (-0.4, 0.9))]
    assert learning_checks(short, 10, BOUNDS)["seeds"][0]["lines"]["length_A_m"] == [0.06, 0.06, 0.06]


def _walk(seed: int, cycles: int, force: float, fell: bool, x: tuple[float, ...] = (0.2,)) -> dict:
    return {"job": {"seed": seed}, "cycles_completed": cycles, "fell": fell, "end": "fell" if fell else "walked",
            "mean_stick_force_n": force, "mean_arm_torque_nm": 80.0, "step_lengths_m": [0.12],
            "swings": [[0.12, v, True] for v in x], "step_stick_force_n": [force] * len(x)}


def test_comparison_checks_follow_the_done_when_rules():
    def gaits(adaptive_force: float, long_cycles: int, long_falls: int = 3) -> list[GaitStats]:
        return [GaitStats("adaptive", (-0.5, 0.5), None, [_walk(s, 10, adaptive_force, False) for s in range(3)]),
                GaitStats("0.10", None, 0.10, [_walk(s, 10, 64.0, False) for s in range(3)]),
                GaitStats("0.12", None, 0.12, [_walk(s, 10, 58.0, False) for s in range(3)]),
                GaitStats("0.20", None, 0.20, [_walk(s, long_cycles, 50.0, s < long_falls) for s in range(3)])]

    c = comparison_checks(gaits(55.0, 2), 10)
    assert c["adaptive_force_below_every_non_falling_fixed"] and c["longest_fixed_falls_within_6_cycles"]
    assert not c["adaptive_torque_below_every_fixed"]  # 80 N.m for every gait: not below
    assert c["non_falling_fixed"] == ["0.10", "0.12"]
    assert c["cheaper_fixed"] == ["0.20"] and c["every_cheaper_fixed_falls"]
    assert not comparison_checks(gaits(59.0, 2), 10)["adaptive_force_below_every_non_falling_fixed"]
    # every fixed length falls (the noisy patient): none to beat on force, the adaptive walks on
    all_fall = [gaits(55.0, 2)[0], GaitStats("0.10", None, 0.10, [_walk(s, 3, 50.0, True) for s in range(3)])]
    c = comparison_checks(all_fall, 10)
    assert c["non_falling_fixed"] == [] and c["adaptive_force_below_every_non_falling_fixed"]
    assert not comparison_checks(gaits(55.0, 7), 10)["longest_fixed_falls_within_6_cycles"]
    # the longest length falls within 6 cycles in half of its walks or more (2 of 3 here, not 1 of 3)
    assert comparison_checks(gaits(55.0, 2, long_falls=2), 10)["longest_fixed_falls_within_6_cycles"]
    assert not comparison_checks(gaits(55.0, 2, long_falls=1), 10)["longest_fixed_falls_within_6_cycles"]
    # both sticks together: twice the per-stick mean, checked against the paper's 250-500 N
    c = comparison_checks(gaits(150.0, 2), 10)
    assert c["adaptive_both_sticks_n"] == 300.0 and c["adaptive_both_sticks_in_paper_range"]
    assert not comparison_checks(gaits(55.0, 2), 10)["adaptive_both_sticks_in_paper_range"]  # 110 N
    # the force falls with the length: 0.10 m at 64 N, 0.20 m at 50 N is 22 % less; 61 N at 0.20 m is not 10 %
    assert c["shortest_fixed"] == "0.10" and c["fixed_force_fall"] == round(1 - 50 / 64, 4) and c["fixed_force_falls_with_length"]
    flat = gaits(55.0, 2)[:-1] + [GaitStats("0.20", None, 0.20, [_walk(s, 2, 61.0, True) for s in range(3)])]
    assert not comparison_checks(flat, 10)["fixed_force_falls_with_length"]
    # a cheaper fixed length that falls in 0 of 3 walks (below 30 %) is one the adaptive gait should beat
    assert not comparison_checks(gaits(55.0, 2, long_falls=0), 10)["every_cheaper_fixed_falls"]
    assert comparison_checks(gaits(55.0, 2, long_falls=1), 10)["every_cheaper_fixed_falls"]  # 1 of 3: 33 %


def test_comparison_checks_how_far_x_com_spreads_over_every_compared_swing():
    narrow = comparison_checks([GaitStats("adaptive", (-0.5, 0.5), None, [_walk(0, 10, 55.0, False, (0.2, 0.25, 0.3))])], 10)
    assert narrow["x_ratio"]["swings"] == 3 and narrow["x_ratio"]["p50"] == 0.25 and not narrow["x_ratio_spreads"]
    x = tuple(np.linspace(0.05, 0.45, 41))  # uniform over 0.4: sd 0.118, 10th-90th percentile 0.09-0.41
    wide = comparison_checks([GaitStats("adaptive", (-0.5, 0.5), None, [_walk(0, 10, 55.0, False, x)]),
                              GaitStats("0.10", None, 0.10, [_walk(0, 10, 60.0, False, x)])], 10)
    assert wide["x_ratio"]["swings"] == 82 and wide["x_ratio"]["range_p10_p90"] == pytest.approx(0.32)
    assert wide["x_ratio_spreads"] and not wide["x_ratio_median_in_paper_range"]  # median 0.25
    paper = comparison_checks([GaitStats("adaptive", (-0.5, 0.5), None, [_walk(0, 10, 55.0, False, tuple(v + 0.5 for v in x))])], 10)
    assert paper["x_ratio"]["p50"] == pytest.approx(0.75) and paper["x_ratio_median_in_paper_range"]


def test_compare_walks_every_gait_on_the_same_seeds():
    jobs = compare_jobs((-0.5, 0.5), seed=0, walks=2, cycles=10, mode="sagittal")
    assert len(jobs) == 7 * 2
    by_gait: dict = {}
    for j in jobs:
        by_gait.setdefault((j.fixed_m, j.theta), []).append(j.seed)
    assert len({tuple(s) for s in by_gait.values()}) == 1


def test_the_comparison_walks_every_gait_through_the_pipeline(tmp_path):
    code = main(["experiment", "compare", "--out", str(tmp_path), "--workers", "0", "--walks", "1", "--theta", "-0.5", "0.4",
                 "--set", "controller.learning.steps_per_rollout=1", "--quiet", "--json"])
    assert code == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    gaits = s["comparison"]["gaits"]
    assert [g["gait"] for g in gaits] == ["adaptive", "0.10", "0.12", "0.14", "0.16", "0.18", "0.20"]
    assert all(g["walks"] == 1 for g in gaits) and s["comparison"]["theta"] == [-0.5, 0.4]
    spread = s["comparison"]["checks"]["x_ratio"]
    assert spread["swings"] >= 7 and 0.0 < spread["p10"] <= spread["p50"] <= spread["p90"] < 1.0
    for name in ("compare.csv", "fig8-12-compare.png", "step-lines.png", "report.md"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert "X_CoM/X_SP at the swings' start over every compared walk" in (tmp_path / "report.md").read_text()


def test_cli_errors_are_one_line(capsys, tmp_path):
    assert main(["experiment", "learn", "--out", str(tmp_path), "--workers", "-1"]) == 1
    assert capsys.readouterr().err.strip() == "aider-exo: error: --workers must be >= 0, got -1"
    assert main(["experiment", "learn", "--out", str(tmp_path), "--set", "controller.learning.noise_alpha=-3"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "controller.learning.noise_alpha" in err


# -- what makes the model fall (random step lengths) -------------------------------------------


def _walk_result(seed: int, swings: list[tuple[float, float, bool]], fell: bool, end: str = "walked",
                 force_n: float = 50.0, fixed_m: float | None = None) -> dict:
    return {"job": {"seed": seed, "fixed_m": fixed_m}, "swings": [list(s) for s in swings], "fell": fell, "end": end,
            "step_stick_force_n": [force_n for s in swings if s[2]], "swing_intention_m": [0.35] * len(swings)}


def test_falls_analysis_splits_the_ends_by_length_ratio_and_previous_step():
    from tools.experiment.falls import analyse, csv_rows

    results = [
        _walk_result(1, [(0.10, 0.40, True), (0.18, 0.50, True), (0.11, 0.45, False)], True, "hip height 0.52 m below 0.55"),
        _walk_result(2, [(0.13, 0.42, True), (0.15, 0.48, True)], False),
        _walk_result(3, [(0.17, 0.44, True)], True, "stalled"),  # ended between swings
    ]
    results.append(_walk_result(4, [], True, "hip height 0.50 m below 0.55"))  # ended before its first swing
    s = analyse(results)
    assert (s["walks"], s["walks_ended_early"], s["steps"], s["steps_ended"]) == (4, 3, 6, 1)
    assert (s["walks_ended_between_swings"], s["walks_ended_before_a_swing"]) == (1, 1)
    assert s["ends"] == {"hip height 0.52 m below 0.55": 1, "stalled": 1}  # the one before a swing has no step
    short = s["by_length"][0]  # 0.10 and 0.11: the 0.11 m step ended its walk
    assert (short["steps"], short["ended"], short["percent"]) == (2, 1, 50.0)
    longest = s["by_length"][-1]  # 0.17 (ended in the double support after it) and 0.18
    assert (longest["steps"], longest["ended"], longest["ended_after"], longest["percent_with_after"]) == (2, 0, 1, 50.0)
    assert short["below_median"]["ended"] == 0 and short["at_or_above_median"]["ended"] == 1
    after_long = s["by_previous_length"][-1]  # the step after the 0.18 m one ended the walk
    assert (after_long["steps"], after_long["ended"]) == (1, 1)
    rows = csv_rows(results)
    assert [r["previous_m"] for r in rows[:3]] == [None, 0.10, 0.18] and [r["ended"] for r in rows[:3]] == [False, False, True]
    assert [r["ended_after"] for r in rows] == [False] * 5 + [True] and rows[-1]["end"] == "stalled"


def test_falls_experiment_walks_random_lengths_through_the_pipeline(tmp_path):
    """``aider-exo experiment falls``: each step's length drawn from the span, every swing
    reported (the last one too when the walk ended in it), the outputs written."""
    code = main(["experiment", "falls", "--out", str(tmp_path), "--workers", "0", "--walks", "2", "--min", "0.10",
                 "--max", "0.13", "--set", "controller.learning.steps_per_rollout=2", "--quiet", "--json"])
    assert code == 0
    s = json.loads((tmp_path / "falls.json").read_text())
    assert s["walks"] == 2 and s["steps"] >= 2
    with (tmp_path / "falls.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == s["steps"] and all(0.10 <= float(r["length_m"]) <= 0.13 for r in rows)
    assert len({r["length_m"] for r in rows}) == len(rows)  # drawn, not fixed
    for name in ("falls.png", "falls.md"):
        assert (tmp_path / name).stat().st_size > 0
    assert main(["experiment", "falls", "--out", str(tmp_path), "--min", "0.01", "--quiet"]) == 1  # outside controller.step


def test_a_random_length_job_needs_a_valid_span():
    with pytest.raises(ExperimentError, match="exactly one"):
        WalkJob(seed=0, cycles=1, fixed_m=0.1, random_m=(0.1, 0.2))
    with pytest.raises(ExperimentError, match="min <= max"):
        WalkJob(seed=0, cycles=1, random_m=(0.2, 0.1))


# -- which step fits which intention (fixed lengths crossed with X_CoM/X_SP) ---------------------


def _cell(seed: int, length: float, x: float, force_n: float | None) -> dict:
    """Four swings of ``length`` starting at X_CoM/X_SP about ``x``: all landed at ``force_n``, or
    (``None``) the walk ended in the fourth."""
    xs = [x - 0.01, x, x + 0.01, x + 0.005]
    if force_n is None:
        return _walk_result(seed, [(length, v, i < 3) for i, v in enumerate(xs)], True, "hip height 0.5 m", 70.0, length)
    return _walk_result(seed, [(length, v, True) for v in xs], False, "walked", force_n, length)


def test_intention_analysis_finds_the_best_step_per_bin_and_whether_one_length_would_do():
    from tools.experiment.intention import analyse, lengths, report_lines

    assert lengths(0.06, 0.22, 0.02) == [0.06, 0.08, 0.1, 0.12, 0.14, 0.16, 0.18, 0.2, 0.22]
    # after a short placement (X low) only the short step stands; after a long one the long step costs least
    table = {0.08: (60.0, 70.0, 80.0), 0.12: (None, 60.0, 70.0), 0.16: (None, None, 60.0)}
    # three walks per cell: 12 swings, enough for a cell's figures (MIN_SWINGS)
    results = [_cell(10 * i + rep, length, x, f) for i, (length, forces) in enumerate(table.items())
               for x, f in zip((0.35, 0.45, 0.55), forces) for rep in range(3)]
    s = analyse(results, bins=3)
    assert s["swings"] == 108 and s["lengths_m"] == [0.08, 0.12, 0.16]
    assert [e["best_length_m"] for e in s["best"]] == [0.08, 0.12, 0.16]
    assert [e["best_stick_force_n"] for e in s["best"]] == [60.0, 60.0, 60.0]
    assert s["spearman_best_length"] == pytest.approx(1.0)
    assert s["lengths_fit_for_every_bin"] == []  # 0.08 never falls but costs 20 N more where X is high
    cell = next(c for c in s["cells"] if c["length_m"] == 0.12 and c["bin"] == 0)
    assert (cell["swings"], cell["falls"], cell["falls_per_step"]) == (12, 3, 0.25)
    assert "0.08 m (60.0 N)" in report_lines(s)[-1]
    # a patient whose every step fits one length: that length would do
    same = analyse([_cell(i, 0.12, x, 55.0) for i, x in enumerate((0.35, 0.45, 0.55) * 3)], bins=3)
    assert same["lengths_fit_for_every_bin"] == [0.12] and same["spearman_best_length"] is None


def test_intention_experiment_walks_fixed_lengths_with_a_varying_intention(tmp_path):
    code = main(["experiment", "intention", "--out", str(tmp_path), "--workers", "0", "--walks", "1", "--min", "0.10",
                 "--max", "0.12", "--bins", "2", "--set", "controller.learning.steps_per_rollout=1", "--quiet", "--json"])
    assert code == 0
    s = json.loads((tmp_path / "intention.json").read_text())
    assert s["walks"] == 2 and s["lengths_m"] == [0.1, 0.12] and len(s["cells"]) == 4
    with (tmp_path / "intention.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {float(r["length_m"]) for r in rows} == {0.10, 0.12}
    assert len({r["intention_m"] for r in rows}) > 1  # the noisy regime: each step its own intention
    # over the support that carries the swing (the compensation's) the CoM sits farther back than over all four contacts
    assert all(float(r["x_ratio"]) < float(r["x_ratio_planted"]) for r in rows)
    for name in ("intention.png", "intention.md"):
        assert (tmp_path / name).stat().st_size > 0
    assert main(["experiment", "intention", "--out", str(tmp_path), "--workers", "0", "--walks", "1", "--min", "0.10",
                 "--max", "0.12", "--bins", "2", "--set", "controller.learning.steps_per_rollout=1", "--quiet", "--json",
                 "--bin-by", "planted"]) == 0  # the same walks, from the cache
    planted = json.loads((tmp_path / "intention.json").read_text())
    assert s["bin_by"] == "stance" and planted["bin_by"] == "planted" and planted["swings"] == s["swings"]
    assert main(["experiment", "intention", "--out", str(tmp_path), "--every", "0", "--quiet"]) == 1
