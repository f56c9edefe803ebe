"""Where each step's length comes from (controller/policy.py) and how the policies are built from
the configuration and the learned files (controller/factory.py ``step_policy``): the fixed,
compensated and learning policies; per-step and per-gait-cycle cost bookkeeping into PI²; a
roll-out that ends after N cycles, at a fall, or is dropped."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from config import default_config_path, load_config, with_overrides
from config.errors import AiderError
from controller import factory
from controller.compensation import StepBounds
from controller.learned import LearnedError, load_learned, save_learned
from controller.pi2 import UpdateRecord, learner_state
from controller.policy import PolicyError, StepPolicy, StepRecord

BASE = load_config(default_config_path())
N_CYCLES, K_ROLLOUTS = 2, 2
SMALL = with_overrides(BASE, {"controller.learning.steps_per_rollout": N_CYCLES,
                              "controller.learning.rollouts_per_update": K_ROLLOUTS})
BOUNDS = factory.step_bounds(BASE.controller)


def step(index: int, *tick_forces: tuple[float, float], landed: bool = True) -> StepRecord:
    """A step whose ticks saw these (left, right) stick forces."""
    s = StepRecord(index=index, leg="rl"[index % 2], start_tick=0, landed=landed)
    for f in tick_forces:
        s.add(np.array(f, dtype=float))
    return s


class Updates:
    """on_update spy: the learner and the record of every call."""

    def __init__(self) -> None:
        self.calls: list[UpdateRecord | None] = []

    def __call__(self, learner, record) -> None:
        self.calls.append(record)


def learning_policy(seed: int = 0, cfg=SMALL):
    spy = Updates()
    policy = StepPolicy(factory.step_bounds(cfg.controller), learner=factory.learner(cfg.controller, np.random.default_rng(seed)),
                        on_update=spy)
    return policy, spy


def walk_cycle(policy: StepPolicy, first: int, forces_a: float, forces_b: float, x_ratio: float = 0.45):
    """Two swings (each with its goal asked at its start) that land with these mean stick forces."""
    thetas = []
    for i, f in enumerate((forces_a, forces_b)):
        _, theta = policy.goal(x_ratio)
        thetas.append(theta)
        policy.landed(step(first + i, (f, f)))
    return thetas


# -- StepRecord ----------------------------------------------------------------------------------


def test_a_steps_cost_is_the_mean_over_its_ticks_of_the_two_sticks_mean_force():
    s = step(0, (10.0, 30.0), (20.0, 40.0), (0.0, 0.0))
    assert s.samples == 3 and s.mean_stick_force_n == pytest.approx((20.0 + 30.0 + 0.0) / 3)
    assert math.isnan(step(1).mean_stick_force_n)  # no tick: no cost
    d = step(1).as_dict()
    assert d["mean_stick_force_n"] is None and d["length_m"] is None  # JSON-safe: nan -> null
    json.dumps(d, allow_nan=False)


# -- fixed and compensated -------------------------------------------------------------------------


def test_a_fixed_policy_gives_its_length_whatever_the_com():
    policy = StepPolicy(BOUNDS, fixed_m=0.12)
    assert policy.mode == "fixed" and policy.current_theta() is None
    for x in (-0.5, 0.0, 0.3, 0.9, 2.0, math.nan):
        goal, theta = policy.goal(x)
        assert (goal.length_m, goal.clamped, theta) == (0.12, False, None)
    policy.landed(step(0, (50.0, 50.0)))  # nothing to learn
    assert policy.cycle_costs == []


@pytest.mark.parametrize("length", [BOUNDS.min_m - 0.01, BOUNDS.max_m + 0.01, 1.0])
def test_a_fixed_step_outside_the_safe_range_is_refused(length):
    with pytest.raises(PolicyError, match="controller.step"):
        StepPolicy(BOUNDS, fixed_m=length)


def test_the_bounds_of_the_safe_range_are_allowed_as_fixed_steps():
    for length in (BOUNDS.min_m, BOUNDS.max_m):
        assert StepPolicy(BOUNDS, fixed_m=length).goal(0.5)[0].length_m == length


def test_a_fixed_step_cannot_be_learned():
    with pytest.raises(PolicyError):
        StepPolicy(BOUNDS, fixed_m=0.12, learner=factory.learner(BASE.controller, np.random.default_rng(0)))


def test_the_compensated_policy_is_equation_8_clamped_to_the_safe_range():
    alpha, xhat = -0.1, 0.55  # 0.095 .. 0.195 m over the support: inside the safe range
    policy = StepPolicy(BOUNDS, theta=(alpha, xhat))
    assert policy.mode == "compensated" and policy.current_theta() == (alpha, xhat)
    lengths = []
    for x in np.linspace(0.0, 1.0, 11):
        goal, theta = policy.goal(float(x))
        assert theta == (alpha, xhat)
        assert goal.length_m == pytest.approx(BOUNDS.init_m + alpha * (xhat - x)) and not goal.clamped
        lengths.append(goal.length_m)
    assert lengths == sorted(lengths)  # alpha < 0: the farther ahead the CoM, the longer the step
    steep = StepPolicy(BOUNDS, theta=(-10.0, 0.5))
    assert steep.goal(1.0)[0].length_m == BOUNDS.max_m and steep.goal(1.0)[0].clamped
    assert steep.goal(0.0)[0].length_m == BOUNDS.min_m and steep.goal(0.0)[0].clamped
    assert steep.goal(math.nan)[0].length_m == BOUNDS.init_m  # no estimate: the uncompensated step


# -- learning ----------------------------------------------------------------------------------


def test_every_second_landed_step_closes_a_gait_cycle_costing_the_mean_of_the_two_steps():
    policy, spy = learning_policy()
    assert policy.mode == "learning"
    policy.goal(0.45)
    policy.landed(step(0, (10.0, 30.0), (20.0, 40.0)))  # ticks 20 N and 30 N: the step 25 N
    assert policy.cycle_costs == []  # half a cycle
    policy.goal(0.45)
    policy.landed(step(1, (50.0, 50.0)))
    # the mean of the steps' means (25 and 50), not of the cycle's ticks (33.3)
    assert policy.cycle_costs == [pytest.approx(37.5)]
    assert spy.calls == [] and policy.learner.in_rollout
    walk_cycle(policy, 2, 70.0, 80.0)  # the N-th cycle ends the roll-out
    assert spy.calls == [None]  # after every roll-out; no update before K of them
    assert policy.cycle_costs == [] and not policy.learner.in_rollout
    batch = learner_state(policy.learner)["batch"]
    assert len(batch) == 1 and batch[0]["costs"] == [pytest.approx(37.5), pytest.approx(75.0)] and not batch[0]["fell"]


def test_a_rollout_keeps_its_theta_and_k_rollouts_make_an_update_of_their_cycle_costs():
    policy, spy = learning_policy(seed=5)
    c = SMALL.controller.learning
    thetas, sums = [], []
    for r in range(K_ROLLOUTS):
        used = []
        forces = [(60.0 + 10 * r, 64.0), (58.0, 50.0 + 5 * r)]
        for k, (a, b) in enumerate(forces):
            used += walk_cycle(policy, 4 * r + 2 * k, a, b)
        assert len(set(used)) == 1  # one theta for the whole roll-out
        theta = used[0]
        assert all(lo <= v <= hi for v, lo, hi in zip(theta, (c.alpha_min, c.xhat_min), (c.alpha_max, c.xhat_max)))
        thetas.append(theta)
        sums.append(sum((a + b) / 2 for a, b in forces))
    assert thetas[0] != thetas[1]  # each roll-out explores anew
    assert spy.calls[0] is None and isinstance(spy.calls[1], UpdateRecord) and len(spy.calls) == K_ROLLOUTS
    record = spy.calls[1]
    assert record.costs == pytest.approx([c.force_cost * s for s in sums])
    assert policy.learner.n_updates == 1 and policy.learner.rollouts_in_batch == 0


def test_the_learning_goal_is_the_compensation_with_the_rollouts_theta():
    policy, _ = learning_policy(seed=2)
    for x in (0.2, 0.45, 0.7):
        goal, (alpha, xhat) = policy.goal(x)
        expected = min(max(BOUNDS.init_m + alpha * (xhat - x), BOUNDS.min_m), BOUNDS.max_m)
        assert goal.length_m == pytest.approx(expected)


def test_a_fall_ends_the_rollout_with_the_fall_flag_and_drops_the_half_cycle():
    policy, spy = learning_policy()
    walk_cycle(policy, 0, 60.0, 62.0)  # one of the two cycles
    policy.goal(0.45)
    policy.landed(step(2, (90.0, 90.0)))  # half of the next
    policy.goal(0.45)
    policy.fell()
    assert spy.calls == [None]
    assert not policy.learner.in_rollout and policy.cycle_costs == []
    batch = learner_state(policy.learner)["batch"]
    assert len(batch) == 1 and batch[0]["fell"] is True and batch[0]["costs"] == [pytest.approx(61.0)]
    policy.fell()  # no roll-out running: nothing to end
    assert spy.calls == [None]
    walk_cycle(policy, 0, 40.0, 40.0)  # the next roll-out starts with a whole cycle (no stale half)
    assert policy.cycle_costs == [pytest.approx(40.0)]


def test_a_fall_in_the_kth_rollout_still_makes_the_update_with_its_terminal_cost():
    policy, spy = learning_policy(seed=1)
    walk_cycle(policy, 0, 60.0, 60.0)
    walk_cycle(policy, 2, 60.0, 60.0)
    policy.goal(0.45)
    policy.fell()  # in the first step of the second roll-out
    record = spy.calls[-1]
    c = SMALL.controller.learning
    assert isinstance(record, UpdateRecord) and record.falls == 1
    assert record.costs == pytest.approx([c.force_cost * 120.0, c.fall_cost])  # no cycle completed: the whole terminal cost


def test_abandon_drops_the_rollout_it_never_enters_an_update():
    policy, spy = learning_policy()
    walk_cycle(policy, 0, 60.0, 62.0)
    policy.goal(0.45)
    policy.landed(step(2, (90.0, 90.0)))
    policy.abandon()
    assert spy.calls == [] and not policy.learner.in_rollout
    assert policy.cycle_costs == [] and policy.learner.rollouts_in_batch == 0
    walk_cycle(policy, 3, 30.0, 50.0)  # a fresh cycle: the dropped half does not pair with the next step
    assert policy.cycle_costs == [pytest.approx(40.0)]


def test_fixed_and_compensated_policies_ignore_falls_and_stops():
    for policy in (StepPolicy(BOUNDS, fixed_m=0.1), StepPolicy(BOUNDS, theta=(-0.2, 0.55))):
        policy.landed(step(0, (1.0, 1.0)))
        policy.fell()
        policy.abandon()
        assert policy.cycle_costs == [] and policy.learner is None


# -- step_policy: the policies from the configuration and the learned files ------------------------------


def test_step_policy_fixed():
    policy, saver = factory.step_policy(BASE.controller, fixed_m=0.11)
    assert policy.mode == "fixed" and saver is None and policy.goal(0.9)[0].length_m == 0.11


def test_step_policy_fixed_outside_the_safe_range_is_a_project_error():
    with pytest.raises(AiderError, match=r"controller\.step"):
        factory.step_policy(BASE.controller, fixed_m=factory.step_bounds(BASE.controller).max_m * 2)


def test_step_policy_fixed_and_learning_together_is_an_error(tmp_path):
    with pytest.raises(LearnedError, match="--fixed-step or --learn") as info:
        factory.step_policy(BASE.controller, fixed_m=0.12, learn=True, patient="p", learned_dir=str(tmp_path))
    assert "\n" not in str(info.value)
    assert list(tmp_path.iterdir()) == []  # no saver, no file


def test_step_policy_compensated_from_the_configuration(tmp_path):
    policy, saver = factory.step_policy(BASE.controller)
    c = BASE.controller.compensation
    assert policy.mode == "compensated" and saver is None and policy.theta == (c.alpha, c.xhat_com)
    # a patient without a file is an error naming the path looked in (never the defaults), and gets no file
    with pytest.raises(LearnedError, match=f"{tmp_path / 'new.json'}: no such learned file"):
        factory.step_policy(BASE.controller, patient="new", learned_dir=str(tmp_path))
    assert list(tmp_path.iterdir()) == []


def test_step_policy_compensated_from_the_patients_file(tmp_path):
    save_learned(tmp_path, "anna", (-4.5, 0.75), None)
    policy, saver = factory.step_policy(BASE.controller, patient="anna", learned_dir=str(tmp_path))
    assert policy.mode == "compensated" and saver is None and policy.theta == (-4.5, 0.75)


def test_step_policy_uses_the_configured_patients_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))  # controller.learned_dir is under the user's home
    save_learned(Path(os.path.expanduser(BASE.controller.learned_dir)), "anna", (-2.0, 0.65), None)
    policy, _ = factory.step_policy(BASE.controller, patient="anna")
    assert policy.theta == (-2.0, 0.65)


@pytest.mark.parametrize("learn", [False, True])
def test_step_policy_never_falls_back_to_the_defaults_on_a_bad_file(tmp_path, learn):
    path = tmp_path / "anna.json"
    path.write_text('{"format": "something else"}')
    with pytest.raises(LearnedError) as info:
        factory.step_policy(BASE.controller, learn=learn, patient="anna", learned_dir=str(tmp_path))
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_step_policy_refuses_a_theta_outside_the_learning_bounds(tmp_path):
    c = BASE.controller.learning
    save_learned(tmp_path, "anna", (c.alpha_max + 3.0, 0.5), None)
    with pytest.raises(LearnedError, match="outside the bounds") as info:
        factory.step_policy(BASE.controller, patient="anna", learned_dir=str(tmp_path))
    assert str(tmp_path / "anna.json") in str(info.value)


def test_step_policy_learning_without_a_patient_starts_at_the_configured_theta():
    policy, saver = factory.step_policy(SMALL.controller, learn=True, rng=np.random.default_rng(0))
    c = SMALL.controller.learning
    assert policy.mode == "learning" and saver is None
    assert policy.learner.theta.tolist() == [c.initial_alpha, c.initial_xhat] and policy.learner.n_updates == 0
    assert policy.learner.params.steps_per_rollout == N_CYCLES and policy.learner.params.rollouts_per_update == K_ROLLOUTS


def test_step_policy_learning_writes_the_patients_file_and_resumes_from_it(tmp_path):
    policy, saver = factory.step_policy(SMALL.controller, learn=True, patient="anna", learned_dir=str(tmp_path),
                                        rng=np.random.default_rng(0))
    try:
        assert saver is not None and saver.path == tmp_path / "anna.json"
        for r in range(K_ROLLOUTS):
            for k in range(N_CYCLES):
                walk_cycle(policy, 4 * r + 2 * k, 60.0 - 5 * r, 62.0 + k)
        assert policy.learner.n_updates == 1
    finally:
        saver.close()
    assert saver.errors == [] and saver.writes >= 1
    record = load_learned(tmp_path, "anna")
    assert record.theta == pytest.approx(tuple(policy.learner.evaluation_theta()))
    # the next start resumes the learner ...
    again, saver2 = factory.step_policy(SMALL.controller, learn=True, patient="anna", learned_dir=str(tmp_path),
                                        rng=np.random.default_rng(1))
    saver2.close()
    assert again.learner.n_updates == 1 and again.learner.theta.tolist() == policy.learner.theta.tolist()
    # ... and walking without learning uses the learned theta
    walking, _ = factory.step_policy(SMALL.controller, patient="anna", learned_dir=str(tmp_path))
    assert walking.mode == "compensated" and walking.theta == record.theta


def test_step_policy_learning_with_a_corrupt_learner_state_names_the_file(tmp_path):
    path = tmp_path / "anna.json"
    save_learned(tmp_path, "anna", (-1.0, 0.6), None)
    data = json.loads(path.read_text())
    data["learner"] = {"format": "not a learner"}
    path.write_text(json.dumps(data))
    with pytest.raises(LearnedError) as info:
        factory.step_policy(SMALL.controller, learn=True, patient="anna", learned_dir=str(tmp_path))
    assert str(path) in str(info.value)


def test_step_policy_refuses_a_bad_patient_name(tmp_path):
    with pytest.raises(LearnedError, match="patient name"):
        factory.step_policy(BASE.controller, learn=True, patient="../../etc/passwd", learned_dir=str(tmp_path))


def test_a_step_bounds_object_is_what_the_policy_checks_against():
    narrow = StepBounds(init_m=0.1, min_m=0.09, max_m=0.11)
    assert StepPolicy(narrow, fixed_m=0.1).fixed_m == 0.1
    with pytest.raises(PolicyError):
        StepPolicy(narrow, fixed_m=0.12)


def test_the_step_bounds_and_the_swing_duration_scale_with_the_leg_length():
    legs = BASE.controller.legs
    tall = dataclasses.replace(BASE.controller, legs=dataclasses.replace(
        legs, thigh_m=2 * legs.thigh_m, shank_m=2 * legs.shank_m, ankle_height_m=2 * legs.ankle_height_m))
    ref, twice = factory.step_bounds(BASE.controller), factory.step_bounds(tall)
    for name in ("init_m", "min_m", "max_m"):
        assert getattr(twice, name) == pytest.approx(2 * getattr(ref, name), abs=1e-4)
    assert (ref.init_m, ref.min_m, ref.max_m) == (0.15, 0.06, 0.25)  # the reference patient's, to 0.1 mm
    # the swing's duration at the same Froude number: sqrt(2) times as long
    assert factory.swing_duration_s(tall) == pytest.approx(math.sqrt(2) * factory.swing_duration_s(BASE.controller), abs=1e-3)
    assert factory.swing_duration_s(BASE.controller) == 1.2
