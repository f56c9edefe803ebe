"""PI² / PI^BB learning of theta = [alpha, Xhat_CoM] (controller.pi2)."""

from __future__ import annotations

import ast
import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import controller.pi2.learner as learner_module
from controller.pi2 import (
    LearnerError,
    Pi2Learner,
    Pi2Params,
    cost_to_go,
    costs_to_weights,
    learner_from_state,
    learner_state,
    pi2_update,
    pibb_update,
    rollout_cost,
)
from tests.conftest import ROOT


#: The learner's settings for the toy task of this file (a quadratic cost with its optimum at the
#: paper's alpha -8.4, Xhat 0.80 and a fall past a boundary; starts A and B of the paper's Table II,
#: K = 5, N = 10). Tuned on it: from 100 seeds per start, 198 of 200 runs had the evaluated theta
#: within 5 % of each optimum value (|alpha - alpha*| <= 0.42, |Xhat - Xhat*| <= 0.04) from at most
#: 15 updates on; without the averaging over the last 5 updates about 6 % miss it.
TOY = dict(rollouts_per_update=5, steps_per_rollout=10, h=10.0, noise_std=(5.0, 0.15), noise_decay=0.8, noise_floor=0.1,
           lower=(-20.0, 0.0), upper=(0.0, 1.5), method="pi2", lambda1=5000.0, lambda2=1.0, reuse_best=0,
           max_consecutive_rejections=3, average_last=5)


def toy(**changes) -> Pi2Params:
    """:data:`TOY` with ``changes``."""
    return Pi2Params(**{**TOY, **changes})


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


# ---------------------------------------------------------------------------------------------
# Pure functions
# ---------------------------------------------------------------------------------------------


def test_costs_to_weights_matches_dmpbbo_example():
    w = costs_to_weights([1.0, 2.0, 3.0, 4.0], h=10.0)
    assert w.shape == (4,)
    np.testing.assert_allclose(w, [0.964328, 0.034401, 0.001227, 0.000044], atol=5e-7)
    assert w.round(6).tolist() == [0.964328, 0.034401, 0.001227, 0.000044]


def test_costs_to_weights_non_finite_rules():
    # A non-finite cost (NaN, +inf, -inf alike) gets weight 0 if a finite one exists ...
    np.testing.assert_array_equal(costs_to_weights([math.nan, 1.0, 1.0]), [0.0, 0.5, 0.5])
    np.testing.assert_array_equal(costs_to_weights([-math.inf, 2.0]), [0.0, 1.0])
    # ... and with no finite cost the weights are uniform.
    np.testing.assert_array_equal(costs_to_weights([math.nan, math.inf, -math.inf]), [1 / 3] * 3)
    # Extreme but finite costs do not overflow the min-max normalisation.
    w = costs_to_weights([1e308, -1e308, 0.0])
    assert np.isfinite(w).all() and w.argmax() == 1 and math.isclose(w.sum(), 1.0)


def test_cost_to_go_adds_terminal_to_every_step():
    S = cost_to_go([[1.0, 3.0], [2.0, 0.0]], [10.0, 0.0])
    np.testing.assert_array_equal(S, [[14.0, 13.0], [2.0, 0.0]])


def test_pi2_update_worked_by_hand():
    # K = 3 roll-outs, N = 2 steps, p = 2 parameters.
    eps = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 2.0]])
    q = np.array([[1.0, 3.0], [2.0, 0.0], [0.0, 1.0]])  # immediate costs q[k, i]
    phi = np.array([0.0, 1.0, 0.0])  # terminal cost (roll-out 2 "fell" late)
    # Cost-to-go S[k, i] = phi_k + sum_{j >= i} q[k, j]:
    #   k=0: 0+1+3 = 4, 0+3 = 3;   k=1: 1+2+0 = 3, 1+0 = 1;   k=2: 0+0+1 = 1, 0+1 = 1
    S = cost_to_go(q, phi)
    np.testing.assert_array_equal(S, [[4.0, 3.0], [3.0, 1.0], [1.0, 1.0]])
    # Step 0: S = (4, 3, 1), min 1, max 4 -> x = (1, 2/3, 0) -> exp(-10 x) = (e^-10, e^-20/3, 1)
    #   e^-10 = 4.539993e-05, e^-20/3 = 1.272634e-03, sum 1.001318034
    #   P0 = (4.534017e-05, 1.270959e-03, 9.986837e-01)
    e10, e20_3 = math.exp(-10.0), math.exp(-20.0 / 3.0)
    P0 = np.array([e10, e20_3, 1.0]) / (1.0 + e10 + e20_3)
    np.testing.assert_allclose(P0, [4.534017e-05, 1.270959e-03, 9.986837e-01], rtol=1e-6)
    # Step 1: S = (3, 1, 1), min 1, max 3 -> x = (1, 0, 0) -> (e^-10, 1, 1) / (2 + e^-10)
    #   P1 = (2.269945e-05, 0.4999887, 0.4999887)
    P1 = np.array([e10, 1.0, 1.0]) / (2.0 + e10)
    np.testing.assert_allclose(P1, [2.269945e-05, 0.4999887, 0.4999887], rtol=1e-6)
    # Per-step updates dtheta_i = sum_k P(i, k) eps_k:
    #   dtheta_0 = (P0[0] - P0[2], P0[1] + 2 P0[2]) = (-0.9986384, 1.9986384)
    #   dtheta_1 = (P1[0] - P1[2], P1[1] + 2 P1[2]) = (-0.4999660, 1.4999660)
    # Time averaging with weights N - i = (2, 1):
    #   dtheta = (2 dtheta_0 + dtheta_1) / 3 = (-0.8324142, 1.8324142)
    d0, d1 = P0 @ eps, P1 @ eps
    np.testing.assert_allclose(d0, [-0.9986384, 1.9986384], rtol=1e-6)
    np.testing.assert_allclose(d1, [-0.4999660, 1.4999660], rtol=1e-6)
    dtheta = pi2_update(eps, q, phi, h=10.0)
    assert dtheta.shape == (2,)
    np.testing.assert_allclose(dtheta, (2 * d0 + d1) / 3, rtol=1e-12)
    np.testing.assert_allclose(dtheta, [-0.8324142, 1.8324142], rtol=1e-6)
    # PI^BB sees only the totals S[:, 0] = (4, 3, 1): it follows roll-out 2 almost alone, while PI²
    # also credits roll-out 1, which is as good as roll-out 2 from step 1 on.
    pibb = pibb_update(eps, S[:, 0], h=10.0)
    np.testing.assert_allclose(pibb, d0, rtol=1e-12)
    assert not np.allclose(pibb, dtheta)


def test_pi2_equals_pibb_when_rankings_agree_over_steps():
    # Parameters constant over a roll-out and the same ranking at every step: PI² reduces to PI^BB.
    eps = np.array([[0.5, -0.1], [-0.2, 0.3], [0.1, 0.1]])
    q = np.array([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [3.0, 3.0, 3.0]])
    phi = np.zeros(3)
    np.testing.assert_allclose(pi2_update(eps, q, phi), pibb_update(eps, q.sum(axis=1)), rtol=1e-12)


def test_rollout_cost():
    r = [100.0, 200.0, 300.0, 400.0]
    assert rollout_cost(r, 4, 4, 1000.0, 1.0) == pytest.approx(1000.0)
    # Fell after 2 of 4 steps: lambda1 * 2/4 + lambda2 * (100 + 200); later entries are ignored.
    assert rollout_cost([100.0, 200.0, math.nan], 2, 4, 1000.0, 2.0) == pytest.approx(500.0 + 600.0)
    assert rollout_cost([], 0, 10, 1000.0, 1.0) == pytest.approx(1000.0)
    with pytest.raises(LearnerError):
        rollout_cost([1.0, math.nan], 2, 2, 1.0, 1.0)
    with pytest.raises(LearnerError):
        rollout_cost([1.0], 2, 2, 1.0, 1.0)
    with pytest.raises(LearnerError):
        rollout_cost([1.0, 1.0], 2, 2, -1.0, 1.0)


@pytest.mark.parametrize(
    "call",
    [
        lambda: costs_to_weights([]),
        lambda: costs_to_weights([[1.0, 2.0]]),
        lambda: costs_to_weights([1.0, 2.0], h=0.0),
        lambda: costs_to_weights([1.0, 2.0], h=math.inf),
        lambda: costs_to_weights(["a", "b"]),
        lambda: costs_to_weights([None, 1.0]),
        lambda: cost_to_go(np.ones((2, 3)), np.ones(3)),
        lambda: pi2_update(np.ones((2, 2)), np.ones((3, 2)), np.ones(3)),
        lambda: pi2_update(np.array([[math.nan, 0.0], [0.0, 0.0]]), np.ones((2, 2)), np.ones(2)),
        lambda: pibb_update(np.ones((2, 2)), np.ones(3)),
    ],
)
def test_pure_functions_reject_invalid_input(call):
    with pytest.raises(LearnerError) as info:
        call()
    assert "\n" not in str(info.value)


def test_pure_functions_do_not_mutate_inputs():
    eps = np.array([[1.0, 2.0], [3.0, 4.0]])
    q = np.array([[1.0, math.nan], [2.0, 3.0]])
    phi = np.array([0.0, 1.0])
    copies = [a.copy() for a in (eps, q, phi)]
    pi2_update(eps, q, phi)
    pibb_update(eps, phi)
    costs_to_weights(q[:, 1])
    cost_to_go(q, phi)
    for a, c in zip((eps, q, phi), copies):
        np.testing.assert_array_equal(a, c)


cost_values = st.floats(allow_nan=True, allow_infinity=True)


@given(st.lists(cost_values, min_size=1, max_size=12), st.floats(0.01, 100.0))
def test_weights_are_a_distribution(costs, h):
    w = costs_to_weights(costs, h)
    assert w.shape == (len(costs),)
    assert np.isfinite(w).all()
    assert (w >= 0.0).all() and (w <= 1.0).all()
    assert math.isclose(w.sum(), 1.0, rel_tol=1e-12)
    finite = np.isfinite(np.array(costs, dtype=float))
    if finite.any():
        assert (w[~finite] == 0.0).all()
        # the lowest finite cost always gets the largest weight
        c = np.where(finite, np.array(costs, dtype=float), np.inf)
        assert w[int(np.argmin(c))] == w.max()


@given(st.floats(allow_nan=True, allow_infinity=True), st.integers(1, 10))
def test_equal_costs_give_uniform_weights(c, K):
    np.testing.assert_allclose(costs_to_weights([c] * K), np.full(K, 1.0 / K), rtol=1e-15)


@given(st.data())
def test_pi2_update_is_a_convex_combination_of_eps(data):
    K = data.draw(st.integers(2, 6))
    N = data.draw(st.integers(1, 6))
    eps = np.array(data.draw(st.lists(st.lists(st.floats(-1e6, 1e6), min_size=2, max_size=2), min_size=K, max_size=K)))
    q = np.array(data.draw(st.lists(st.lists(cost_values, min_size=N, max_size=N), min_size=K, max_size=K)))
    phi = np.array(data.draw(st.lists(cost_values, min_size=K, max_size=K)))
    d = pi2_update(eps, q, phi, 10.0)
    assert d.shape == (2,) and np.isfinite(d).all()
    slack = 1e-9 * (1.0 + np.abs(eps).max())
    assert (d >= eps.min(axis=0) - slack).all() and (d <= eps.max(axis=0) + slack).all()


# ---------------------------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs",
    [
        {"rollouts_per_update": 1},
        {"rollouts_per_update": 2.5},
        {"steps_per_rollout": 0},
        {"h": 0.0},
        {"h": math.nan},
        {"noise_std": (0.0, 0.1)},
        {"noise_std": (1.0, -0.1)},
        {"noise_std": (1.0, math.inf)},
        {"noise_std": (1.0,)},
        {"noise_decay": 0.0},
        {"noise_decay": 1.5},
        {"noise_floor": -0.1},
        {"lower": (0.0, 0.0), "upper": (0.0, 1.5)},
        {"lower": (-20.0, 1.0), "upper": (0.0, 0.5)},
        {"method": "cma"},
        {"lambda1": -1.0},
        {"lambda2": math.nan},
        {"reuse_best": 5},
        {"reuse_best": -1},
        {"max_consecutive_rejections": 0},
    ],
)
def test_params_validation(kwargs):
    with pytest.raises(LearnerError) as info:
        toy(**kwargs)
    assert "\n" not in str(info.value)


def test_params_sequences_become_tuples_and_no_field_has_a_default():
    p = toy(noise_std=[1.0, 0.05], lower=[-20, 0], upper=[0, 1.5])
    assert p.noise_std == (1.0, 0.05) and p.lower == (-20.0, 0.0) and p.upper == (0.0, 1.5)
    assert p.n_params == 2
    with pytest.raises(TypeError):  # the configuration (or the test) gives every value
        Pi2Params(rollouts_per_update=5)


def test_the_controllers_learner_takes_every_setting_from_its_configuration():
    import dataclasses

    from config import default_config_path, load_config
    from controller.factory import pi2_params

    cfg = load_config(default_config_path()).controller
    changed = dataclasses.replace(cfg, learning=dataclasses.replace(cfg.learning, reuse_best=2, max_consecutive_rejections=7))
    p = pi2_params(changed)
    assert (p.reuse_best, p.max_consecutive_rejections) == (2, 7)
    assert p.noise_std == (cfg.learning.noise_alpha, cfg.learning.noise_xhat)


# ---------------------------------------------------------------------------------------------
# Learner: ask / tell
# ---------------------------------------------------------------------------------------------

A = (-1.0, 0.6)  # paper Table II start A: (alpha, Xhat_CoM)
B = (-0.4, 0.9)  # start B


def walk(learner: Pi2Learner, costs, fell: bool = False):
    learner.ask()
    for c in costs:
        learner.tell_step(c)
    return learner.end_rollout(fell)


def test_learner_rejects_bad_construction():
    with pytest.raises(LearnerError):
        Pi2Learner(toy(), (1.0, 0.5), rng())  # alpha above its upper bound 0
    with pytest.raises(LearnerError):
        Pi2Learner(toy(), (-1.0, math.nan), rng())
    with pytest.raises(LearnerError):
        Pi2Learner(toy(), (-1.0, 0.5, 0.0), rng())
    with pytest.raises(LearnerError):
        Pi2Learner(toy(), A, np.random.RandomState(0))  # legacy global-style generator


def test_ask_is_constant_within_a_rollout_and_eps_is_the_clipped_one():
    p = toy(rollouts_per_update=2, steps_per_rollout=3, noise_std=(50.0, 5.0))
    L = Pi2Learner(p, B, rng(1))
    th = L.ask()
    assert (th >= p.lower).all() and (th <= p.upper).all()
    L.tell_step(1.0)
    np.testing.assert_array_equal(L.ask(), th)
    L.tell_step(1.0)
    L.tell_step(1.0)
    L.end_rollout(False)
    np.testing.assert_array_equal(learner_state(L)["batch"][0]["eps"], th - np.array(B))  # the clipped eps
    np.testing.assert_array_equal(L.theta, B)  # no update after one of two roll-outs


def test_update_after_k_rollouts_only_and_never_mid_rollout():
    p = toy(rollouts_per_update=3, steps_per_rollout=2)
    L = Pi2Learner(p, A, rng(2))
    for k in range(3):
        L.ask()
        L.tell_step(float(k))
        np.testing.assert_array_equal(L.theta, A)  # no update while walking
        L.tell_step(float(k))
        rec = L.end_rollout(False)
        assert (rec is None) == (k < 2)
    assert L.n_updates == 1 and L.rollouts_in_batch == 0
    assert rec.theta == tuple(L.theta.tolist()) and rec.theta_before == A
    assert len(rec.costs) == 3 and len(rec.weights) == 3 and math.isclose(sum(rec.weights), 1.0)
    assert rec.mean_cost == pytest.approx(np.mean([0.0, 2.0, 4.0]))
    np.testing.assert_array_equal(L.evaluation_theta(), L.theta)
    assert len(L.history) == 1 and L.history[0] == rec


def test_order_errors():
    p = toy(rollouts_per_update=2, steps_per_rollout=2)
    L = Pi2Learner(p, A, rng())
    with pytest.raises(LearnerError):
        L.tell_step(1.0)
    with pytest.raises(LearnerError):
        L.end_rollout(False)
    L.ask()
    L.tell_step(1.0)
    with pytest.raises(LearnerError):
        L.end_rollout(False)  # 1 of 2 steps and no fall
    with pytest.raises(LearnerError):
        L.tell_step("1.0")
    L.tell_step(1.0)
    with pytest.raises(LearnerError):
        L.tell_step(1.0)  # a third step
    L.abort_rollout()
    assert not L.in_rollout and L.rollouts_in_batch == 0


def test_fall_applies_the_terminal_cost_and_stops_the_rollout():
    p = toy(rollouts_per_update=2, steps_per_rollout=10, lambda1=1000.0, lambda2=2.0)
    L = Pi2Learner(p, A, rng(3))
    walk(L, [5.0] * 3, fell=True)
    rec = walk(L, [5.0] * 10)
    assert rec.falls == 1
    assert rec.costs[0] == pytest.approx(rollout_cost([5.0] * 3, 3, 10, 1000.0, 2.0)) == pytest.approx(730.0)
    assert rec.costs[1] == pytest.approx(100.0)
    # the roll-out that walked on gets (almost) all the weight, at every step
    assert rec.weights[1] > 0.999


def test_pibb_method_uses_total_costs():
    p = toy(rollouts_per_update=3, steps_per_rollout=2, method="pibb")
    L = Pi2Learner(p, A, rng(4))
    thetas = []
    for costs in ([3.0, 0.0], [2.0, 2.0], [1.0, 5.0]):
        thetas.append(L.ask())
        for c in costs:
            L.tell_step(c)
        rec = L.end_rollout(False)
    np.testing.assert_allclose(L.theta, pibb_update(np.array(thetas), [3.0, 4.0, 6.0]), rtol=1e-12)
    np.testing.assert_allclose(rec.weights, costs_to_weights([3.0, 4.0, 6.0]))


def test_noise_decays_per_accepted_update_to_its_floor():
    p = toy(rollouts_per_update=2, steps_per_rollout=1, noise_std=(1.0, 0.1), noise_decay=0.5, noise_floor=0.2)
    L = Pi2Learner(p, A, rng())
    expected = [1.0, 0.5, 0.25, 0.2, 0.2]
    for e in expected:
        np.testing.assert_allclose(L.noise_std, [e, e * 0.1])
        walk(L, [1.0])
        rec = walk(L, [2.0])
        np.testing.assert_allclose(rec.noise, [e, e * 0.1])


def test_reuse_best_carries_rollouts_into_the_next_batch():
    p = toy(rollouts_per_update=3, steps_per_rollout=1, reuse_best=1)
    L = Pi2Learner(p, A, rng(5))
    used = []
    for c in (3.0, 1.0, 2.0):
        used.append(L.ask())
        L.tell_step(c)
        L.end_rollout(False)
    assert L.n_updates == 1 and L.rollouts_in_batch == 1
    kept = learner_state(L)["batch"][0]
    np.testing.assert_array_equal(kept["theta"], used[1])  # the cheapest
    np.testing.assert_allclose(kept["eps"], used[1] - L.theta)  # re-expressed around the new theta
    walk(L, [1.0])
    assert L.rollouts_in_batch == 2
    walk(L, [1.0])
    assert L.n_updates == 2


# ---------------------------------------------------------------------------------------------
# Rejections
# ---------------------------------------------------------------------------------------------


def test_non_finite_step_cost_rejects_the_update_and_three_disable_learning():
    p = toy(rollouts_per_update=2, steps_per_rollout=2)
    L = Pi2Learner(p, A, rng(6))
    for n in (1, 2, 3):
        assert walk(L, [1.0, math.nan]) is None
        assert walk(L, [1.0, 1.0]) is None
        assert L.rejection_count == n and L.consecutive_rejections == n
        np.testing.assert_array_equal(L.theta, A)
        assert L.n_updates == 0 and L.rollouts_in_batch == 0
        assert L.learning_enabled == (n < 3)
    assert L.rejections[0].reason.startswith("non-finite step cost nan (roll-out 1, step 2)")
    assert L.rejections[0].batch == 1 and L.rejections[2].batch == 3
    # Disabled: ask() gives the last good theta without noise; tell/end are accepted and ignored.
    np.testing.assert_array_equal(L.ask(), A)
    L.tell_step(1.0)
    assert L.end_rollout(False) is None
    L.enable_learning()
    assert L.learning_enabled and L.consecutive_rejections == 0 and L.rejection_count == 3
    walk(L, [1.0, 1.0])
    assert walk(L, [2.0, 2.0]) is not None


def test_an_accepted_update_resets_the_consecutive_count():
    p = toy(rollouts_per_update=2, steps_per_rollout=1)
    L = Pi2Learner(p, A, rng(7))
    walk(L, [math.inf])
    walk(L, [1.0])
    walk(L, [math.nan])
    walk(L, [1.0])
    assert L.consecutive_rejections == 2
    walk(L, [1.0])
    walk(L, [2.0])
    assert L.consecutive_rejections == 0 and L.rejection_count == 2 and L.n_updates == 1


def test_overflowing_rollout_cost_is_rejected():
    p = toy(rollouts_per_update=2, steps_per_rollout=2)
    L = Pi2Learner(p, A, rng())
    walk(L, [1e308, 1e308])
    walk(L, [1.0, 1.0])
    assert L.rejection_count == 1 and "overflow" in L.rejections[0].reason
    json.dumps(learner_state(L), allow_nan=False)


@pytest.mark.parametrize(
    ("bad", "reason"),
    [(np.array([math.inf, 0.0]), "non-finite"), (np.array([100.0, 0.0]), "outside the bounds")],
)
def test_bad_update_result_is_rejected(monkeypatch, bad, reason):
    monkeypatch.setattr(learner_module, "pi2_update", lambda *a, **k: bad)
    L = Pi2Learner(toy(rollouts_per_update=2, steps_per_rollout=1), A, rng())
    walk(L, [1.0])
    assert walk(L, [2.0]) is None
    assert L.rejection_count == 1 and reason in L.rejections[0].reason
    np.testing.assert_array_equal(L.theta, A)


def test_rounding_just_past_a_bound_is_clipped_not_rejected(monkeypatch):
    # theta at alpha = 0 (its upper bound); an update a rounding error past it stays at the bound.
    monkeypatch.setattr(learner_module, "pi2_update", lambda *a, **k: np.array([1e-15, 0.0]))
    L = Pi2Learner(toy(rollouts_per_update=2, steps_per_rollout=1), (0.0, 0.5), rng())
    walk(L, [1.0])
    assert walk(L, [2.0]) is not None
    assert L.theta[0] == 0.0


# ---------------------------------------------------------------------------------------------
# Invariants of the learner under arbitrary use (Hypothesis)
# ---------------------------------------------------------------------------------------------


@st.composite
def learner_setups(draw):
    lo = [draw(st.floats(-100.0, 100.0)), draw(st.floats(-5.0, 5.0))]
    width = [draw(st.floats(1e-3, 50.0)), draw(st.floats(1e-3, 5.0))]
    hi = [lo[0] + width[0], lo[1] + width[1]]
    K = draw(st.integers(2, 5))
    params = toy(
        rollouts_per_update=K,
        steps_per_rollout=draw(st.integers(1, 4)),
        noise_std=(draw(st.floats(1e-6, 1e3)), draw(st.floats(1e-6, 1e2))),
        noise_decay=draw(st.floats(0.1, 1.0)),
        noise_floor=draw(st.floats(0.0, 1.0)),
        lower=tuple(lo),
        upper=tuple(hi),
        method=draw(st.sampled_from(["pi2", "pibb"])),
        lambda1=draw(st.floats(0.0, 1e6)),
        lambda2=draw(st.floats(0.0, 1e3)),
        reuse_best=draw(st.integers(0, K - 1)),
    )
    theta0 = [draw(st.floats(lo[i], hi[i])) for i in range(2)]
    return params, theta0


@given(learner_setups(), st.data())
def test_learner_bounds_and_finiteness_always_hold(setup, data):
    params, theta0 = setup
    L = Pi2Learner(params, theta0, rng(data.draw(st.integers(0, 2**32 - 1))))
    lo, hi = np.array(params.lower), np.array(params.upper)
    N = params.steps_per_rollout
    for _ in range(data.draw(st.integers(1, 12))):
        th = L.ask()
        assert th.shape == (2,) and np.isfinite(th).all()
        assert (th >= lo).all() and (th <= hi).all()
        fell = data.draw(st.booleans())
        m = data.draw(st.integers(0, N)) if fell else N
        for _ in range(m):
            L.tell_step(data.draw(cost_values))
            np.testing.assert_array_equal(L.ask(), th)
        L.end_rollout(fell)
        t = L.theta
        assert np.isfinite(t).all() and (t >= lo).all() and (t <= hi).all()
    for rec in L.history:
        assert math.isfinite(rec.mean_cost) and math.isclose(sum(rec.weights), 1.0, rel_tol=1e-9)
    json.dumps(learner_state(L), allow_nan=False)  # always strict JSON


# ---------------------------------------------------------------------------------------------
# Persistence
# ---------------------------------------------------------------------------------------------


def _partly_trained(seed: int = 8) -> Pi2Learner:
    p = toy(rollouts_per_update=3, steps_per_rollout=4, reuse_best=1)
    L = Pi2Learner(p, A, rng(seed))
    for k in range(7):  # updates after roll-outs 3, 5, 7; the best of the last batch is kept
        walk(L, [10.0 + k, 5.0, 1.0, 2.0])
    walk(L, [1.0, math.nan], fell=True)  # waits in the batch, non-finite
    return L


def test_state_dict_round_trip_and_same_continuation():
    L = _partly_trained()
    d = learner_state(L)
    L2 = learner_from_state(json.loads(json.dumps(d)), rng(99))
    assert learner_state(L2) == d
    assert L2.history == L.history and L2.rejections == L.rejections
    np.testing.assert_array_equal(L2.theta, L.theta)
    # Same generator -> the restored learner continues exactly like one restored from the dict.
    L = learner_from_state(d, rng(5))
    L2 = learner_from_state(json.loads(json.dumps(d)), rng(5))
    for _ in range(4):
        np.testing.assert_array_equal(L.ask(), L2.ask())
        assert walk(L, [1.0] * 4) == walk(L2, [1.0] * 4)


def test_unfinished_rollout_is_not_saved():
    L = Pi2Learner(toy(rollouts_per_update=2, steps_per_rollout=3), A, rng())
    L.ask()
    L.tell_step(1.0)
    L2 = learner_from_state(learner_state(L), rng())
    assert not L2.in_rollout and L2.rollouts_in_batch == 0


@pytest.mark.parametrize(
    "corrupt",
    [
        lambda d: d.update(version=2),
        lambda d: d.update(theta=[5.0, 0.5]),
        lambda d: d.pop("history"),
        lambda d: d["params"].update(h=-1.0),
        lambda d: d["params"].update(colour="red"),
        lambda d: d["batch"][0].update(eps=[9.0, 9.0]),
        lambda d: d["batch"][0].update(costs=["NaN?"]),
        lambda d: d.update(n_updates=-1),
        lambda d: d.update(learning_enabled="yes"),
    ],
)
def test_malformed_state_raises_learner_error(corrupt):
    d = learner_state(_partly_trained())
    corrupt(d)
    with pytest.raises(LearnerError) as info:
        learner_from_state(d, rng())
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------------------------------------
# Toy task with a known optimum (the paper's): convergence from starts A and B
# ---------------------------------------------------------------------------------------------

OPT = np.array([-8.4, 0.80])  # (alpha*, Xhat*)
# Convergence: every parameter within 5 % of the optimum's own value, i.e.
# |alpha - alpha*| <= 0.42 and |Xhat - Xhat*| <= 0.04 (the evaluated theta: the mean of the last
# updates, see Pi2Learner.evaluation_theta).
TOL = 0.05 * np.abs(OPT)
MAX_UPDATES = 15


def toy_step_cost(theta: np.ndarray) -> float:
    """Noise-free immediate cost of one step: a quadratic bowl around the optimum."""
    return 100.0 * ((theta[0] - OPT[0]) / 10.0) ** 2 + 100.0 * ((theta[1] - OPT[1]) / 0.3) ** 2


def toy_steps(theta: np.ndarray, N: int) -> int:
    """Steps walked: the HHEA falls after 3 steps past the safe region."""
    return 3 if (theta[1] > 1.05 or theta[0] > -0.2) else N


def run_toy(theta0, seed: int):
    """15 updates of 5 roll-outs of 10 steps; returns the theta and noise-free cost after each."""
    params = toy()
    learner = Pi2Learner(params, theta0, np.random.default_rng(seed))
    noise = np.random.default_rng(seed + 1000)  # the step costs' measurement noise
    thetas, curve = [], [toy_step_cost(np.array(theta0)) * params.steps_per_rollout]
    while learner.n_updates < MAX_UPDATES:
        th = learner.ask()
        m = toy_steps(th, params.steps_per_rollout)
        for _ in range(m):
            learner.tell_step(toy_step_cost(th) + noise.normal(0.0, 0.5))
        if learner.end_rollout(fell=m < params.steps_per_rollout) is not None:
            ev = learner.evaluation_theta()  # the noise-free roll-out of the learning curve
            thetas.append(ev)
            m = toy_steps(ev, params.steps_per_rollout)
            N, lam1, lam2 = params.steps_per_rollout, params.lambda1, params.lambda2
            curve.append(rollout_cost([toy_step_cost(ev)] * m, m, N, lam1, lam2))
    assert learner.rejection_count == 0
    return np.array(thetas), np.array(curve)


def updates_to_converge(thetas: np.ndarray) -> int | None:
    """First update after which theta stays within TOL of the optimum up to the last one."""
    inside = np.all(np.abs(thetas - OPT) <= TOL, axis=1)
    for u in range(len(inside)):
        if inside[u:].all():
            return u + 1
    return None


@pytest.mark.parametrize("start", [A, B], ids=["A", "B"])
def test_toy_task_converges_from_the_papers_starts(start):
    needed = {}
    for seed in range(10):
        thetas, curve = run_toy(start, seed)
        needed[seed] = updates_to_converge(thetas)
        # learning curve (noise-free roll-outs): cost down by more than 90 %, all N steps walked
        assert curve[-1] < 0.1 * curve[0], f"seed {seed}: cost {curve[0]:.0f} -> {curve[-1]:.1f}"
        assert toy_steps(thetas[-1], 10) == 10
    assert all(n is not None and n <= MAX_UPDATES for n in needed.values()), f"updates needed per seed: {needed}"


# ---------------------------------------------------------------------------------------------
# Style rules
# ---------------------------------------------------------------------------------------------


def test_module_imports_nothing_it_must_not():
    """The learner is pure: no clock, no global random state, no file or socket."""
    for path in (ROOT / "controller" / "pi2").glob("*.py"):
        tree = ast.parse(path.read_text())
        names = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                names.add((node.module or "").split(".")[0])
        assert not names & {"sim", "nodes", "time", "random", "datetime", "os", "socket", "tempfile"}, path
        src = path.read_text()
        assert "np.random.seed" not in src and "np.random.normal" not in src and "open(" not in src, path


def test_batch_interface_equals_rollouts_one_after_another():
    """ask_batch/tell_batch (roll-outs run in parallel) draw the same noise and give the same
    updates as ask/tell/end_rollout in turn, falls and reused roll-outs included."""
    p = toy(reuse_best=2)
    seq, par = Pi2Learner(p, A, rng(7)), Pi2Learner(p, A, rng(7))

    def walk(theta: np.ndarray, k: int) -> tuple[list[float], bool]:
        costs = [float(abs(theta[0] + 8.4) + abs(theta[1] - 0.8) * 10 + i) for i in range(p.steps_per_rollout)]
        return (costs[:3], True) if k == 1 else (costs, False)

    for _update in range(4):
        thetas = par.ask_batch()
        assert len(thetas) == p.rollouts_per_update - par.rollouts_in_batch
        results = [walk(t, k) for k, t in enumerate(thetas)]
        record_par = par.tell_batch(results)
        record_seq = None
        for k in range(len(thetas)):
            theta = seq.ask()
            np.testing.assert_array_equal(theta, thetas[k])
            for c in results[k][0]:
                seq.tell_step(c)
            record_seq = seq.end_rollout(results[k][1])
        assert record_par == record_seq is not None
    np.testing.assert_array_equal(par.theta, seq.theta)


def test_tell_batch_needs_every_result():
    L = Pi2Learner(toy(), A, rng(1))
    L.ask_batch()
    with pytest.raises(LearnerError, match="needs 5"):
        L.tell_batch([([1.0] * 10, False)])
    L.ask()
    with pytest.raises(LearnerError, match="during a roll-out"):
        L.ask_batch()
