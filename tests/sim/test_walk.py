"""The whole pipeline walking (tools/pipeline.py, tools/cli/walk.py): the main controller, the
four emulated node boards and the simulated HHEA in one process, lock-step on the virtual bus.

Only what the design promises is asserted (the gait is still being tuned): cycles walked without
a fall, no rejected frame, the estimate's X_CoM/X_SP error within the goal, determinism for a
seed, a fixed step policy's one length, a learning update and its learned file, the CLI's summary,
its one-line errors, and the telemetry log. Each walk is 1-2 gait cycles (a few seconds)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math

import numpy as np
import pytest

from config import default_config_path, load_config, with_overrides
from controller import factory
from controller.learned import load_learned, restore_learner
from controller.policy import StepRecord
from controller.telemetry import FIELDS, SCHEMA_VERSION, TelemetryLog, read_log
from protocol.enums import SWINGS, WALKING
from tools.cli import main
from tools.pipeline import WalkOutcome, walk

BASE = with_overrides(load_config(default_config_path()), {"sim.mode": "sagittal"})
WALKING_NAMES = {s.name for s in WALKING}
GOAL_RATIO_MAE = 0.05  # issue 6: the estimated X_CoM/X_SP against the ground truth


def as_records(steps: list[StepRecord]) -> list[str]:
    """Every field of every step, exactly (repr keeps nan comparable)."""
    return [repr(dataclasses.astuple(s)) for s in steps]


def assert_walked(outcome: WalkOutcome, cycles: int) -> None:
    assert not outcome.fell, f"fell: {outcome.fall_reason}"
    assert outcome.fault is None and not outcome.stalled, (outcome.fault, outcome.final_state)
    assert outcome.cycles_completed == cycles and len(outcome.landed) == 2 * cycles
    assert outcome.receiver["rejected"] == 0 and outcome.receiver["lost"] == 0


@pytest.fixture(scope="module")
def walked(tmp_path_factory):
    """Two gait cycles, seed 0, compensated step length, with the telemetry log on."""
    path = tmp_path_factory.mktemp("walk") / "walk.jsonl"
    log = TelemetryLog(path)
    try:
        outcome = walk(BASE, cycles=2, seed=0, mode="sagittal", telemetry=log)
    finally:
        report = log.close()
    return outcome, path, report


@pytest.fixture(scope="module")
def one_cycle():
    """One gait cycle, seed 0, without telemetry."""
    return walk(BASE, cycles=1, seed=0, mode="sagittal")


# -- walking -----------------------------------------------------------------------------------


def test_two_gait_cycles_walk_without_a_fall_and_estimate_the_com_ratio_within_the_goal(walked):
    outcome, _, _ = walked
    assert_walked(outcome, 2)
    assert outcome.policy == "compensated" and outcome.mode == "sagittal" and outcome.final_state in WALKING_NAMES
    assert len(outcome.ratio_errors) > 100 and outcome.ratio_mae <= GOAL_RATIO_MAE
    c = BASE.controller
    bounds = factory.step_bounds(c)
    assert outcome.theta == (c.compensation.alpha, c.compensation.xhat_com)
    steps = outcome.steps
    assert all(a.leg != b.leg for a, b in itertools.pairwise(steps))  # the legs take turns
    for prev, s in zip([None, *steps], steps):
        assert s.landed and bounds.min_m <= s.length_m <= bounds.max_m
        assert s.start_tick < s.swing_tick < s.end_tick  # from the last landing: stick moves, lean, then the swing
        if prev is not None:
            assert s.start_tick == prev.end_tick  # a step runs from the previous landing to its own
        assert s.theta == outcome.theta and math.isfinite(s.x_ratio)
        # the step is equation (8) of X_CoM/X_SP over the support of the swing (the stance sole and
        # the tips): the CoM sits farther back in it than between the rear foot and the tips
        assert s.requested_m == pytest.approx(bounds.init_m + c.compensation.alpha * (c.compensation.xhat_com - s.x_ratio))
        assert 0.0 < s.x_ratio < s.x_ratio_planted
        assert s.samples > 0 and s.mean_stick_force_n > 0.0
    assert outcome.mean_stick_force_n == pytest.approx(np.mean([s.mean_stick_force_n for s in steps]))
    summary = outcome.summary()
    json.dumps(summary, allow_nan=False)
    assert summary["cycles_completed"] == 2 and summary["steps_completed"] == 4 and summary["falls"] == 0


def test_three_gait_cycles_in_3d_walk_onto_the_sticks_in_the_papers_regime():
    """Lock-step, in the default mode: the four-point patient in 3-D walks its cycles leaning onto its
    sticks as the paper's does (both sticks together 250-500 N, Figs. 11-12; X_CoM/X_SP at the
    swings' start past the middle of the swing's support)."""
    outcome = walk(BASE, cycles=3, seed=0, mode="full3d")
    assert_walked(outcome, 3)
    assert outcome.ratio_mae <= GOAL_RATIO_MAE
    assert 250.0 <= 2 * outcome.mean_stick_force_n <= 500.0
    assert 0.5 <= float(np.median([s.x_ratio for s in outcome.landed])) <= 0.9


def test_a_walk_is_deterministic_for_its_seed(walked, one_cycle):
    outcome, _, _ = walked
    # The same seed: the same walk, step for step and tick for tick (here: the one-cycle walk is
    # the first cycle of the two-cycle one, which also had the telemetry on; its last step has no
    # next swing, so no length as placed).
    first = [outcome.steps[0], dataclasses.replace(outcome.steps[1], placed_m=math.nan)]
    assert as_records(one_cycle.steps) == as_records(first)
    assert one_cycle.ratio_errors == outcome.ratio_errors[: len(one_cycle.ratio_errors)]
    assert one_cycle.ticks == outcome.steps[1].end_tick + 1


def test_two_walks_with_one_seed_are_identical_and_another_seed_differs(one_cycle):
    # the second walk without the ground-truth comparison (as the experiment walks): the same walk
    again = walk(BASE, cycles=1, seed=0, mode="sagittal", compare_ratio=False)
    assert as_records(again.steps) == as_records(one_cycle.steps) and again.ticks == one_cycle.ticks
    assert one_cycle.ratio_errors and not again.ratio_errors
    other = walk(BASE, cycles=1, seed=1, mode="sagittal")
    assert as_records(other.steps) != as_records(one_cycle.steps)
    assert other.ratio_errors != one_cycle.ratio_errors


def test_a_fixed_step_policy_commands_the_same_length_every_step():
    policy, _ = factory.step_policy(BASE.controller, fixed_m=0.12)
    commanded = []

    def on_tick(result, session, host):
        if result.state in SWINGS:
            commanded.append(session.core.gait.step_length_m)  # what the gait planner's swing goes to

    outcome = walk(BASE, cycles=1, seed=0, mode="sagittal", policy=policy, on_tick=on_tick)
    assert outcome.policy == "fixed" and outcome.theta is None
    assert len(outcome.landed) >= 1 and commanded
    assert set(commanded) == {0.12}
    for s in outcome.steps:
        assert (s.length_m, s.requested_m, s.clamped, s.theta) == (0.12, 0.12, False, None)


def test_a_step_as_placed_is_the_feet_spacing_measured_when_the_next_swing_starts():
    """The commanded length is where the swing aims; ``placed_m`` is where the foot stood once the
    double support after it was over, from the sensors: it matches the simulation's ankles."""
    policy, _ = factory.step_policy(BASE.controller, fixed_m=0.12)
    truth = {}  # swing-start tick -> the simulated ankles' fore-aft distance, by leg

    def on_tick(result, session, host):
        steps = session.core.steps
        if result.state in SWINGS and steps and steps[-1].swing_tick == result.tick:
            x = {side: float(host.plant.patient.ankle_xy(side)[0]) for side in "lr"}
            truth[result.tick] = {"l": x["l"] - x["r"], "r": x["r"] - x["l"]}

    steady = with_overrides(BASE, {"sim.patient.intention.regime": "steady"})  # one fixed length fits a steady patient
    outcome = walk(steady, cycles=2, seed=0, mode="sagittal", policy=policy, on_tick=on_tick)
    steps = outcome.landed
    assert len(steps) == 4 and math.isnan(steps[-1].placed_m)  # no swing after the last one
    for step, following in itertools.pairwise(steps):
        assert step.placed_m == pytest.approx(truth[following.swing_tick][step.leg], abs=0.005)
        assert 0.0 < step.placed_m < 0.12 + 0.03
    placed = outcome.summary()["placed_step_m"]
    assert placed["mean"] == pytest.approx(np.mean([s.placed_m for s in steps[:-1]]), abs=1e-4)
    assert placed["min"] <= placed["mean"] <= placed["max"]


def test_the_learning_policy_updates_within_a_short_walk_and_its_patient_file_loads_back(tmp_path):
    # One gait cycle per roll-out, an update every two. The start theta is the configured
    # compensation and the exploration small, so that the walk is an ordinary one: what is tested
    # is the plumbing (costs to PI², the update, the file), not what is learned.
    c = BASE.controller.compensation
    cfg = with_overrides(BASE, {
        "controller.learning.steps_per_rollout": 1, "controller.learning.rollouts_per_update": 2,
        "controller.learning.initial_alpha": c.alpha, "controller.learning.initial_xhat": c.xhat_com,
        "controller.learning.noise_alpha": 0.1, "controller.learning.noise_xhat": 0.01,
    })
    policy, saver = factory.step_policy(cfg.controller, learn=True, patient="pat", learned_dir=str(tmp_path),
                                        rng=np.random.default_rng(0))
    try:
        outcome = walk(cfg, cycles=2, seed=0, mode="sagittal", policy=policy)
    finally:
        saver.close()
    assert_walked(outcome, 2)
    learner = policy.learner
    assert outcome.policy == "learning" and learner.n_updates == 1
    steps = outcome.steps
    assert steps[0].theta == steps[1].theta != steps[2].theta == steps[3].theta  # one theta per roll-out
    cycle_costs = [(steps[2 * k].mean_stick_force_n + steps[2 * k + 1].mean_stick_force_n) / 2 for k in range(2)]
    update = learner.history[0]
    assert update.costs == pytest.approx([cfg.controller.learning.force_cost * cost for cost in cycle_costs])
    assert update.falls == 0
    assert outcome.theta == tuple(learner.evaluation_theta())
    json.dumps(outcome.summary(), allow_nan=False)
    # the learned file, written by the saver's thread, loads back
    assert saver.errors == [] and saver.writes >= 1
    record = load_learned(tmp_path, "pat")
    assert record.theta == pytest.approx(outcome.theta)
    restored = restore_learner(record, np.random.default_rng(0), saver.path)
    assert restored.n_updates == 1 and restored.theta.tolist() == learner.theta.tolist()


def test_a_walk_that_runs_out_of_time_is_a_stall_not_a_fall():
    outcome = walk(BASE, cycles=1, seed=0, mode="sagittal", max_time_s=1.0)
    assert outcome.stalled and not outcome.fell and outcome.landed == []
    assert outcome.ticks == 50  # 1 s of 20 ms ticks
    summary = outcome.summary()
    json.dumps(summary, allow_nan=False)  # no step: nulls, not NaN
    assert summary["mean_stick_force_n"] is None and summary["step_length_m"]["mean"] is None
    # whom the walk waits for: the patient moves its sticks (seed 0: 0.4 s after its 0.6 s settle)
    assert summary["patient"] == outcome.patient and outcome.patient["phase"] == "sticks"


def test_a_stalled_walk_says_where_the_patient_stood(capsys):
    """Stopped 0.1 s into the first weight shift (seed 0, lock-step: the same figures every run),
    the patient says where its CoM is against the window its first stick lift waits for."""
    assert main(["walk", "--steps", "1", "--max-time", "0.7", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert ("no fall (stalled: the patient in its shift for 0.1 s, CoM at 0.0614 m, "
            "a stick may lift with it between 0.0144 and 0.1022 m)") in out


def test_a_walk_that_the_controller_holds_ends_there_with_the_cause():
    """A HOLD is latched until an operator's reset: the walk ends the tick it comes (not after the
    stall time, which would report it as a stall), and says why."""
    from tools.experiment.runner import WalkJob, run_walk

    # the left stick reads 0 N from early in the first swing (ticks 214-266, seed 0) on: a slipped crutch (F19)
    slipped = {"kind": "sensor_value", "node": "LEFT_HIP", "start_tick": 226, "message": "STICK_LEFT", "signal": "force_N", "value": 0.0}
    cfg = with_overrides(BASE, {"nodes.faults": {"slip": slipped}})
    outcome = walk(cfg, cycles=2, seed=0, mode="sagittal")
    unloaded = "STICK_UNLOADED(left stick: below 2 N for 10 ticks in the swing)"
    assert outcome.final_state == "HOLD" and outcome.hold == unloaded
    assert not outcome.stalled and not outcome.fell and outcome.fault is None
    assert len(outcome.landed) == 1 and outcome.ticks == outcome.landed[0].end_tick + 2  # the tick after the landing
    assert outcome.summary()["hold"] == outcome.hold
    result = run_walk(cfg, WalkJob(seed=0, cycles=2, fixed_m=0.12))
    assert result["end"] == f"hold {unloaded}" and result["fell"] and not result["complete"]


def test_a_walk_without_a_landing_for_stall_s_is_a_stall():
    outcome = walk(BASE, cycles=1, seed=0, mode="sagittal", stall_s=1.5)
    assert outcome.stalled and not outcome.fell and outcome.landed == []
    assert outcome.ticks == 76  # 1.5 s of 20 ms ticks after the first


def test_walk_outcome_counts_landed_steps_only():
    def s(i, landed, force):
        r = StepRecord(index=i, leg="rl"[i % 2], start_tick=10 * i, swing_tick=10 * i + 5, end_tick=10 * i + 9,
                       length_m=0.1 + 0.01 * i, landed=landed)
        r.add(np.array([force, force]))
        return r

    o = WalkOutcome(mode="sagittal", seed=0, policy="fixed", steps=[s(0, True, 10.0), s(1, True, 30.0), s(2, True, 50.0), s(3, False, 1e3)],
                    ratio_errors=[0.01, 0.03])
    assert o.cycles_completed == 1 and len(o.landed) == 3
    assert o.mean_stick_force_n == pytest.approx(30.0) and o.ratio_mae == pytest.approx(0.02)
    summary = o.summary()
    assert summary["steps_completed"] == 3 and summary["step_length_m"]["max"] == pytest.approx(0.12)
    assert len(summary["steps"]) == 4


# -- telemetry ---------------------------------------------------------------------------------


def test_the_telemetry_log_has_its_schema_and_the_gait_fields_filled_during_swings(walked):
    outcome, path, report = walked
    assert report["error"] is None and report["dropped"] == 0 and report["written"] == outcome.ticks
    schema, records = read_log(path)
    assert schema["version"] == SCHEMA_VERSION and list(schema["fields"]) == list(FIELDS)
    assert {"gait", "step", "step_length_m", "step_cost_n", "theta"} <= set(schema["fields"])
    assert [r["tick"] for r in records] == list(range(outcome.ticks))
    assert all(list(r) == list(FIELDS) for r in records)
    by_tick = {r["tick"]: r for r in records}
    for r in records:
        assert r["gait"] in (None, "shift", "lean", "swing")
        if r["state"] not in WALKING_NAMES:
            assert r["gait"] is None and r["step"] is None
        if r["state"] not in {s.name for s in SWINGS}:
            assert r["step"] is None and r["step_length_m"] is None and r["theta"] is None
    for s in outcome.steps:
        swing = [by_tick[t] for t in range(s.swing_tick, s.end_tick)]
        assert {r["state"] for r in swing} == {"SWING_LEFT" if s.leg == "l" else "SWING_RIGHT"}
        assert {r["step"] for r in swing} == {s.index}
        assert all(r["step_length_m"] == pytest.approx(s.length_m) for r in swing)
        assert all(r["theta"] == pytest.approx(list(s.theta)) for r in swing)
        # the swing's first tick still ran the lean (the swing starts from its result); then the swing
        assert all(r["gait"] == "swing" for r in swing[1:])
        landing = by_tick[s.end_tick]
        assert landing["step_cost_n"] == pytest.approx(s.mean_stick_force_n)
    costs = [r["tick"] for r in records if r["step_cost_n"] is not None]
    assert costs == [s.end_tick for s in outcome.landed]  # a cost only in the tick its step landed


# -- the CLI -----------------------------------------------------------------------------------

SUMMARY_FIELDS = {
    "mode", "seed", "policy", "theta", "cycles_asked", "cycles_completed", "steps_completed", "falls", "fall_reason",
    "fault", "hold", "stalled", "final_state", "patient", "mean_stick_force_n", "mean_arm_torque_nm", "step_length_m", "placed_step_m", "x_ratio_mae", "x_ratio_samples",
    "sim_time_s", "wall_time_s", "ticks", "receiver", "timing", "steps", "bus", "telemetry",
}


def test_aider_exo_walk_prints_its_summary_as_json(capsys, tmp_path):
    log = tmp_path / "walk.jsonl"
    rc = main(["walk", "--steps", "1", "--json", "--quiet", "--log", str(log)])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert err == ""  # --quiet: no status line
    s = json.loads(out)
    assert SUMMARY_FIELDS <= set(s)
    assert s["cycles_asked"] == 1 and s["cycles_completed"] == 1 and s["steps_completed"] == 2
    assert s["falls"] == 0 and s["fall_reason"] is None and not s["stalled"]
    assert 0 < s["mean_arm_torque_nm"] < 2 * (80 + 60 + 60)  # six arm joints, each within its strength
    assert s["mode"] == "full3d" and s["seed"] == 0 and s["policy"] == "compensated" and s["bus"] == "virtual (in-process)"
    assert s["mean_stick_force_n"] > 0 and s["x_ratio_mae"] <= GOAL_RATIO_MAE and s["x_ratio_samples"] > 0
    assert s["receiver"]["rejected"] == 0 and s["receiver"]["lost"] == 0
    assert len(s["steps"]) == 2 and all(step["landed"] for step in s["steps"])
    assert s["step_length_m"]["min"] <= s["step_length_m"]["mean"] <= s["step_length_m"]["max"]
    assert s["telemetry"]["written"] == s["ticks"] and s["telemetry"]["error"] is None
    schema, records = read_log(log)
    assert list(schema["fields"]) == list(FIELDS) and len(records) == s["ticks"]


def one_line_error(capsys, argv) -> str:
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == 1, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("aider-exo: error: "), err
    return lines[0]


@pytest.mark.parametrize("length", ["0.5", "0.01"])
def test_a_fixed_step_outside_the_bounds_is_a_one_line_error(capsys, length):
    assert "controller.step" in one_line_error(capsys, ["walk", "--steps", "1", "--fixed-step", length])


def test_render_with_socketcan_is_a_one_line_error(capsys, tmp_path):
    line = one_line_error(capsys, ["walk", "--steps", "1", "--bus", "socketcan", "--channel", "vcan0", "--render", str(tmp_path / "r")])
    assert "--render" in line
    assert not (tmp_path / "r").exists()


def test_an_unknown_patient_file_format_is_a_one_line_error_naming_the_file(capsys, tmp_path):
    path = tmp_path / "anna.json"
    path.write_text(json.dumps({"format": "another tool's file", "version": 7, "theta": [1, 2]}))
    for extra in ([], ["--learn"]):
        line = one_line_error(capsys, ["walk", "--steps", "1", "--patient", "anna", "--learned-dir", str(tmp_path), *extra])
        assert str(path) in line


def test_fixed_step_with_learn_and_a_bad_patient_name_are_one_line_errors(capsys, tmp_path):
    one_line_error(capsys, ["walk", "--steps", "1", "--fixed-step", "0.12", "--learn"])
    assert "patient name" in one_line_error(capsys, ["walk", "--learn", "--patient", "../x", "--learned-dir", str(tmp_path)])
    assert list(tmp_path.iterdir()) == []


def test_the_controllers_new_flags_fail_before_the_bus_opens(capsys, tmp_path):
    # (--lockstep --ticks 3: were a check missing, the run would end after three ticks instead of hanging)
    base = ["controller", "--lockstep", "--ticks", "3", "--quiet"]
    assert "controller.step" in one_line_error(capsys, [*base, "--fixed-step", "0.5"])
    one_line_error(capsys, [*base, "--fixed-step", "0.12", "--learn"])
    (tmp_path / "anna.json").write_text("{ not json")
    assert str(tmp_path / "anna.json") in one_line_error(capsys, [*base, "--patient", "anna", "--learned-dir", str(tmp_path)])
    assert "patient name" in one_line_error(capsys, [*base, "--learn", "--patient", "a/b", "--learned-dir", str(tmp_path)])


@pytest.mark.parametrize("command", [["walk", "--steps", "1"], ["controller", "--lockstep", "--ticks", "3"]])
def test_a_log_that_cannot_be_written_is_a_one_line_error(capsys, tmp_path, command):
    path = tmp_path / "no-such-folder" / "walk.jsonl"
    line = one_line_error(capsys, [*command, "--quiet", "--log", str(path)])
    assert str(path) in line and "telemetry" in line
