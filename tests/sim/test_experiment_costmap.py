"""``aider-exo experiment costmap``: the noise-free cost over a grid of theta, its valley, and
where learning runs ended on it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from config import default_config_path, load_config, with_overrides
from tools.cli import main
from tools.experiment import costmap
from tools.experiment.runner import ExperimentError

CFG = with_overrides(load_config(default_config_path()), {"controller.learning.steps_per_rollout": 2})
GRID = costmap.Grid.spanning(3, (-1.0, 0.0), (0.5, 0.9))


def _walk(theta: tuple[float, float], seed: int) -> dict:
    """A made-up walk whose cost is least at (-0.5, 0.7) and varies by seed the same for every theta."""
    force = 100.0 + 40.0 * abs(theta[0] + 0.5) + 100.0 * abs(theta[1] - 0.7) + seed % 7
    return {"cycle_costs": [force, force], "fell": False, "cycles_completed": 2, "end": "walked"}


def _results(walks: int, learning: dict | None = None) -> list[dict]:
    jobs = costmap.costmap_jobs(GRID, seed=0, walks=walks, cycles=2, mode="full3d", ends=costmap.learned_ends(learning))
    return [_walk(j.theta, j.seed) for j in jobs]


def test_every_theta_and_every_learned_end_walk_the_same_seeds():
    jobs = costmap.costmap_jobs(GRID, seed=0, walks=3, cycles=2, mode="full3d", ends=[(-0.3, 0.55)])
    assert len(jobs) == (9 + 1) * 3 and {j.theta for j in jobs[-3:]} == {(-0.3, 0.55)}
    by_theta = {}
    for j in jobs:
        by_theta.setdefault(j.theta, []).append(j.seed)
    assert len(by_theta) == 10 and all(seeds == costmap.map_seeds(0, 3) for seeds in by_theta.values())
    assert len(set(costmap.map_seeds(0, 3))) == 3


def test_the_map_finds_its_minimum_and_the_valley_within_3_percent():
    s = costmap.analyse(_results(2), GRID, 2, CFG)
    assert s["minimum"]["theta"] == [-0.5, 0.7]
    cost = np.array(s["cost"])
    assert cost.shape == (3, 3) and cost[1, 1] == cost.min()
    limit = 1.03 * cost.min()
    assert s["valley"] == [[a, x] for x in GRID.xhats for a in GRID.alphas if cost[GRID.xhats.index(x), GRID.alphas.index(a)] <= limit]
    assert [-0.5, 0.7] in s["valley"] and [-1.0, 0.5] not in s["valley"]
    assert s["walked_full"] == [[2] * 3] * 3


def _learning(end_a: tuple[float, float], end_b: tuple[float, float], median_diff: float, agree: bool) -> dict:
    runs = [{"start": s, "seed": 0, "updates": [{"evaluation_theta": list(t0)}, {"evaluation_theta": list(end)}]}
            for s, t0, end in (("A", (-1.0, 0.6), end_a), ("B", (-0.4, 0.9), end_b))]
    return {"runs": runs, "checks": {"seeds": {"0": {"same_or_lines_agree": agree,
                                                     "lines": {"difference_m": [0.05, median_diff, 0.05]}}}}}


def _analyse(learning: dict) -> dict:
    return costmap.analyse(_results(1, learning), GRID, 1, CFG, learning)


def test_the_report_says_where_a_and_b_ended_and_which_agreement_held():
    s = _analyse(_learning((-0.5, 0.7), (-0.48, 0.705), 0.015, agree=False))
    runs = {r["run"]: r for r in s["learning"]["runs"]}
    assert runs["A-s0"]["in_valley"] and runs["B-s0"]["in_valley"]
    assert runs["A-s0"]["path"] == [[-1.0, 0.6], [-0.5, 0.7]]
    assert runs["B-s0"]["cost_at_end"] == _walk((-0.48, 0.705), costmap.map_seeds(0, 1)[0])["cycle_costs"][0] * 2  # walked, not interpolated
    assert s["learning"]["seeds"]["0"]["held"] == "valley"
    text = "\n".join(costmap.report_lines(s))
    assert "both end in the valley" in text and "| A-s0 | (-0.500, 0.700)" in text
    assert _analyse(_learning((-0.5, 0.7), (-1.0, 0.5), 0.015, agree=False))["learning"]["seeds"]["0"]["held"] == "neither"  # B outside
    assert _analyse(_learning((-0.5, 0.7), (-0.48, 0.705), 0.03, agree=False))["learning"]["seeds"]["0"]["held"] == "neither"  # lines apart
    assert _analyse(_learning((-1.0, 0.5), (-1.0, 0.5), 0.0, agree=True))["learning"]["seeds"]["0"]["held"] == "theta or lines"


def test_a_bad_grid_is_a_one_line_error():
    with pytest.raises(ExperimentError, match="at least 2"):
        costmap.Grid.spanning(1, (-1.0, 0.0), (0.5, 0.9))
    with pytest.raises(ExperimentError, match="LO < HI"):
        costmap.Grid.spanning(3, (0.0, -1.0), (0.5, 0.9))
    with pytest.raises(ExperimentError, match="controller.learning"):
        costmap.check_span(costmap.Grid.spanning(3, (-1.0, 1.0), (0.5, 0.9)), CFG)


def test_costmap_walks_a_tiny_grid_through_the_pipeline(tmp_path, capsys):
    sets = ["--set", "controller.learning.steps_per_rollout=1"]
    assert main(["experiment", "costmap", "--out", str(tmp_path), "--grid", "2", "--walks", "1", "--workers", "0",
                 "--quiet", "--json", *sets]) == 0
    s = json.loads(capsys.readouterr().out)
    assert len(s["cost"]) == 2 and all(c > 0 for row in s["cost"] for c in row) and s["learning"] is None
    for name in ("costmap.csv", "costmap.json", "costmap.md", "costmap.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert main(["experiment", "costmap", "--out", str(tmp_path), "--learning", str(tmp_path / "costmap.json"), *sets]) == 1
    assert "has no learning runs" in capsys.readouterr().err
