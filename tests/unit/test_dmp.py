"""The discrete DMP (Pastor et al. 2009 form) and the swing demonstration it imitates.

No wall-clock assertions: the per-tick cost is measured apart from the tests.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.demonstration import (
    ADVANCE,
    LIFT_RAMP,
    advance_profile,
    DemonstrationError,
    demonstration_hash,
    lift_profile,
    swing_demonstration,
)
from controller.dmp import Dmp, reference_rollout
from controller.dmp_model import DmpError, DmpParams, DmpWeights, basis, fit, forcing, phase

DT_S = 0.02  # one controller tick
TAU_S = 1.2
STEP_M = 0.15


@cache
def swing_weights() -> DmpWeights:
    """The DMP fitted to the demonstration scaled to a 0.15 m swing (x forward, z up)."""
    return fit(*swing_demonstration(step_m=STEP_M, duration_s=TAU_S))


def run(dmp: Dmp, duration_s: float, dt_s: float = DT_S) -> np.ndarray:
    """Positions, shape (k + 1, d), of a roll-out from the DMP's current state."""
    return dmp.rollout(dt_s, duration_s)[1]


def second_difference(positions: np.ndarray, dt_s: float = DT_S) -> np.ndarray:
    """Finite-difference acceleration, shape (k - 1, d)."""
    return np.diff(positions, 2, axis=0) / dt_s**2


# --- the demonstration ----------------------------------------------------------------------------


def test_demonstration_shape_and_profile():
    times, xz = swing_demonstration(step_m=0.3, lift_m=0.1, duration_s=1.2, samples=241, ankle_height_m=0.08)
    assert times.shape == (241,) and xz.shape == (241, 2)
    assert times[0] == 0.0 and times[-1] == pytest.approx(1.2)
    assert xz[0] == pytest.approx([0.0, 0.08]) and xz[-1] == pytest.approx([0.3, 0.08])  # z: start == goal
    assert np.all(np.diff(xz[:, 0]) >= 0.0)  # the ankle only moves forward
    u = times / 1.2
    top = (u >= LIFT_RAMP) & (u <= 1.0 - LIFT_RAMP)
    assert xz[top, 1] == pytest.approx(0.18, abs=1e-9)  # level at full lift in mid-swing
    assert xz[:, 1].max() == pytest.approx(0.18, abs=1e-9)
    assert np.all(xz[u <= ADVANCE[0], 0] == 0.0) and np.all(xz[u >= ADVANCE[1], 0] == pytest.approx(0.3))
    # the foot advances only once lifted, and is over its goal before it comes down to the floor
    lift = xz[:, 1] - 0.08
    assert np.all(lift[(xz[:, 0] > 0.0) & (u < 0.5)] > 0.2 * 0.1)  # lifted 20 % before it moves forward
    assert np.all(lift[(xz[:, 0] > 0.1 * 0.3) & (xz[:, 0] < 0.99 * 0.3)] >= 0.5 * 0.1)  # then at least half up
    velocity = np.gradient(xz, times, axis=0, edge_order=2)
    assert np.abs(velocity[[0, -1]]).max() < 2e-3  # at rest at both ends (one-sided differences over 5 ms; peak speed ~1 m/s)


def test_demonstration_hash_is_a_stable_identifier():
    times, xz = swing_demonstration()
    same = demonstration_hash(*swing_demonstration())
    assert demonstration_hash(times, xz) == same and len(same) == 64
    assert demonstration_hash(times, np.asfortranarray(xz)) == same  # memory layout does not matter
    assert demonstration_hash(*swing_demonstration(step_m=0.31)) != same
    nudged = xz.copy()
    nudged[100, 1] = np.nextafter(nudged[100, 1], 1.0)  # the last bit, as numpy versions and CPUs differ
    assert demonstration_hash(times, nudged) == same
    nudged[100, 1] += 1e-9  # a nanometre: another demonstration
    assert demonstration_hash(times, nudged) != same


@pytest.mark.parametrize("kwargs, message", [
    ({"step_m": -0.1}, "need step_m > 0"),
    ({"lift_m": math.nan}, "lift_m must be a finite number"),
    ({"duration_s": 0.0}, "need step_m > 0"),
    ({"samples": 2}, "samples must be an integer >= 3"),
    ({"samples": 10.0}, "samples must be an integer >= 3"),
])
def test_demonstration_rejects_bad_parameters(kwargs, message):
    with pytest.raises(DemonstrationError, match=message) as info:
        swing_demonstration(**kwargs)
    assert isinstance(info.value, DmpError) and "\n" not in str(info.value)


# --- basis and forcing ----------------------------------------------------------------------------


def test_basis_centres_and_overlap():
    params = DmpParams()
    centres, widths = basis(params)
    assert centres.shape == widths.shape == (25,)
    assert centres[0] == 1.0 and centres[-1] == pytest.approx(0.01)
    # centres are the phase at equally spaced times
    assert centres == pytest.approx(phase(np.linspace(0.0, 1.0, 25), 1.0, params.alpha_s))
    overlap = np.exp(-widths[:-1] * (centres[1:] - centres[:-1]) ** 2)
    assert overlap == pytest.approx(np.full(24, 0.8))
    assert widths[-1] == widths[-2]


def test_forcing_matches_its_definition_and_vectorises():
    rng = np.random.default_rng(7)
    centres, widths = basis(DmpParams())
    weights = rng.normal(size=(2, 25))
    s_values = np.array([1.0, 0.6, 0.2, 0.05, 0.01, 0.0])
    many = forcing(s_values, weights, centres, widths)
    assert many.shape == (6, 2)
    for s, row in zip(s_values, many):
        psi = [math.exp(-h * (s - c) ** 2) for c, h in zip(centres, widths)]
        expected = [sum(w * p for w, p in zip(wd, psi)) * s / sum(psi) for wd in weights]
        one = forcing(s, weights, centres, widths)
        assert one.shape == (2,)
        assert one == pytest.approx(expected, abs=1e-12) and row == pytest.approx(expected, abs=1e-12)
    assert forcing(0.0, weights, centres, widths) == pytest.approx([0.0, 0.0])  # gated by s


# --- imitation, convergence, temporal scaling ---------------------------------------------------


def test_reproduces_the_demonstration_within_1_mm():
    weights = swing_weights()
    assert weights.tau_s == pytest.approx(TAU_S) and weights.x0 == pytest.approx([0.0, 0.0])
    assert weights.g == pytest.approx([STEP_M, 0.0])
    _, demo_at_ticks = swing_demonstration(step_m=STEP_M, duration_s=TAU_S, samples=61)  # 20 ms apart
    positions = run(Dmp(weights), TAU_S)
    assert positions.shape == (61, 2)
    assert np.abs(positions - demo_at_ticks).max() < 1e-3


def test_converges_to_the_goal():
    dmp = Dmp(swing_weights())
    positions = run(dmp, 1.5 * TAU_S)
    assert np.abs(positions[-1] - [STEP_M, 0.0]).max() < 1e-3
    assert np.abs(dmp.velocity).max() < 1e-2  # m/s: all but at rest (the descent ends steeply)
    run(dmp, 1.5 * TAU_S)
    assert np.abs(dmp.x - [STEP_M, 0.0]).max() < 1e-5 and np.abs(dmp.velocity).max() < 1e-4


def test_done_once_tau_has_elapsed():
    dmp = Dmp(swing_weights())
    run(dmp, TAU_S - DT_S)
    assert not dmp.done
    dmp.step(DT_S)
    assert dmp.done and dmp.s == pytest.approx(0.01, rel=1e-6) and dmp.elapsed_s == pytest.approx(TAU_S)
    dmp.reset()
    assert not dmp.done and dmp.s == 1.0 and dmp.elapsed_s == 0.0


@pytest.mark.parametrize("x0, goal, tau_s", [(0.0, 1.0, 1.0), (0.3, -0.2, 0.7), (-1.0, -0.5, 2.0)])
def test_without_forcing_a_step_is_critically_damped(x0, goal, tau_s):
    zero = DmpWeights(weights=np.zeros((1, 25)), x0=[x0], g=[goal], tau_s=tau_s, params=DmpParams())
    dmp = Dmp(zero)
    x = run(dmp, 4.0 * tau_s)[:, 0]
    direction = math.copysign(1.0, goal - x0)
    assert np.all(direction * np.diff(x) >= -1e-12)  # monotone
    assert np.all(direction * (x - goal) <= 1e-9)  # no overshoot
    assert x[-1] == pytest.approx(goal, abs=1e-4 * abs(goal - x0))


def test_halving_tau_replays_the_movement_twice_as_fast():
    weights = swing_weights()
    slow, fast = Dmp(weights), Dmp(weights)
    slow.reset(tau_s=TAU_S)
    fast.reset(tau_s=TAU_S / 2)
    x_slow = run(slow, 1.5 * TAU_S)
    x_fast = run(fast, 0.75 * TAU_S)
    # x(t; tau / 2) against x(2 t; tau)
    assert np.abs(x_fast - x_slow[::2]).max() < 1e-4


def test_step_is_rk4_over_x_v_s_and_the_goal():
    weights = fit(*swing_demonstration(step_m=0.2, duration_s=1.0),
                  DmpParams(n_basis=12, damping=18.0, goal_alpha=8.0))
    x0, goal, tau = np.array([0.01, 0.02]), np.array([0.18, -0.01]), 0.9
    dmp = Dmp(weights)
    dmp.reset(x0, goal, tau)
    ours = [dmp.x]
    for tick in range(40):
        if tick == 17:
            dmp.set_goal([0.12, 0.03])
        ours.append(dmp.step(0.025, substeps=7))
    oracle = reference_rollout(weights, x0, goal, tau, 0.025, 7, 40, goal_change=(17, [0.12, 0.03]))
    assert np.abs(np.array(ours) - oracle).max() < 1e-12


# --- online goal changes --------------------------------------------------------------------------


@pytest.mark.parametrize("new_step_m", [0.10, 0.20])
def test_goal_change_mid_swing_moves_the_landing_point_smoothly(new_step_m):
    weights = swing_weights()
    unperturbed = run(Dmp(weights), 1.5 * TAU_S)
    dmp = Dmp(weights)
    before = run(dmp, TAU_S / 2)
    dmp.set_goal([new_step_m, 0.0])
    assert dmp.goal == pytest.approx([new_step_m, 0.0])
    assert dmp.filtered_goal == pytest.approx([STEP_M, 0.0])  # enters the equations from the next step
    after = run(dmp, TAU_S)
    positions = np.vstack([before, after[1:]])
    assert positions.shape == unperturbed.shape
    assert abs(positions[-1, 0] - new_step_m) < 2e-3  # landing point moved to the new goal
    assert np.abs(positions[:, 1] - unperturbed[:, 1]).max() < 1e-12  # z untouched
    # no jump: the first tick after the change barely differs, and the acceleration stays bounded
    change = len(before) - 1
    assert abs(positions[change + 1, 0] - unperturbed[change + 1, 0]) < 1e-4
    accel = np.abs(second_difference(positions)[:, 0]).max()
    assert accel <= 3.0 * np.abs(second_difference(unperturbed)[:, 0]).max()
    assert np.all(np.isfinite(positions))


@pytest.mark.parametrize("step_m", [0.15, 0.175, 0.20, 0.25])
def test_goals_at_or_beyond_the_demonstrated_step_keep_its_shape(step_m):
    # The Pastor form does not scale the shape: a longer goal than the demonstrated one comes out
    # as the same lift with a longer advance (which is why the swing is demonstrated near the
    # shortest steps, config swing.demonstration_step_m).
    dmp = Dmp(swing_weights())
    dmp.reset(goal=[step_m, 0.0])
    x = run(dmp, 1.5 * TAU_S)[:, 0]
    assert x.max() - step_m < 1e-3  # overshoot
    assert -np.diff(x).min() < 1e-4  # no backward motion


@pytest.mark.parametrize("step_m", [0.10, 0.125])
def test_shorter_goals_dip_backward_first_by_a_fraction_of_the_difference(step_m):
    # ... and far shorter goals make the ankle dip backwards and overshoot (movement_primitives #70).
    dmp = Dmp(swing_weights())
    dmp.reset(goal=[step_m, 0.0])
    x = run(dmp, 1.5 * TAU_S)[:, 0]
    assert 0.0 < -x.min() < 0.3 * (STEP_M - step_m)
    assert x.max() - step_m < 0.1 * (STEP_M - step_m)


def test_reset_sets_the_goal_at_once():
    dmp = Dmp(swing_weights())
    run(dmp, 0.3)
    dmp.reset(x0=[0.0, 0.0], goal=[0.2, 0.0])
    assert dmp.filtered_goal == pytest.approx([0.2, 0.0]) and dmp.x == pytest.approx([0.0, 0.0])
    assert dmp.v == pytest.approx([0.0, 0.0])


# --- z: start equal to goal ------------------------------------------------------------------------


def test_lift_with_start_equal_to_goal_is_learnt_and_stays_finite():
    times, xz = swing_demonstration(step_m=STEP_M, duration_s=TAU_S)
    weights = fit(times, xz[:, 1:])  # z only: 1-D, start == goal
    assert weights.x0 == weights.g
    assert np.all(np.isfinite(weights.weights)) and np.abs(weights.weights).max() < 50.0  # the Ijspeert form: ~1e34
    dmp = Dmp(weights)
    positions = run(dmp, 1.5 * TAU_S)
    assert np.all(np.isfinite(positions))
    assert np.abs(positions[:61, 0] - xz[::4, 1]).max() < 1e-3
    assert positions[:61, 0].max() == pytest.approx(0.10, abs=1e-3)
    flat = fit(times, np.zeros((len(times), 1)))  # nothing to learn
    assert np.abs(flat.weights).max() < 1e-9
    assert np.abs(run(Dmp(flat), TAU_S)).max() < 1e-9


# --- inputs ------------------------------------------------------------------------------------


def test_inputs_are_not_modified():
    times, xz = swing_demonstration()
    times.setflags(write=False)
    xz.setflags(write=False)  # any in-place write would raise
    weights = fit(times, xz)
    assert not weights.weights.flags.writeable
    goal = np.array([0.25, 0.0])
    dmp = Dmp(weights)
    dmp.reset(x0=np.zeros(2), goal=goal, tau_s=1.0)
    goal[0] = 99.0  # the DMP keeps its own copy
    assert dmp.goal == pytest.approx([0.25, 0.0])
    x = dmp.step(DT_S)
    x[0] = 99.0
    assert dmp.x[0] != 99.0


def _params(**kwargs):
    return lambda: DmpParams(**kwargs)


_T = np.linspace(0.0, 1.0, 5)
_X = np.zeros((5, 2))


def _with(array, index, value):
    array = np.array(array, dtype=float)
    array[index] = value
    return array


def _dmp():
    return Dmp(swing_weights())


@pytest.mark.parametrize("call, message", [
    (lambda: fit([0.0], [[0.0, 0.0]]), "a demonstration needs at least 3 samples"),
    (lambda: fit([0.0, 1.0], [[0.0], [1.0]]), "a demonstration needs at least 3 samples"),
    (lambda: fit(_T[::-1], _X), "time must increase"),
    (lambda: fit(_with(_T, 2, _T[1]), _X), "time must increase"),
    (lambda: fit(_with(_T, 2, math.nan), _X), "times_s contains non-finite values"),
    (lambda: fit(_T, _with(_X, (3, 1), math.nan)), "trajectory contains non-finite values"),
    (lambda: fit(_T, _with(_X, (3, 0), math.inf)), "trajectory contains non-finite values"),
    (lambda: fit(_T, np.zeros(5)), r"trajectory must have 2 dimension\(s\)"),
    (lambda: fit(_T, np.zeros((4, 2))), "trajectory has 4 samples but times_s has 5"),
    (lambda: fit(_T.reshape(5, 1), _X), r"times_s must have 1 dimension\(s\)"),
    (lambda: fit(["a", "b", "c"], np.zeros((3, 1))), "times_s must be numeric"),
    (lambda: fit(_T, _X, params="fast"), "params must be a DmpParams"),
    (_params(n_basis=1), "n_basis must be an integer >= 2"),
    (_params(n_basis=2.5), "n_basis must be an integer >= 2"),
    (_params(stiffness=-1.0), "stiffness must be finite and > 0"),
    (_params(damping=-2.0), "damping must be finite and >= 0"),
    (_params(alpha_s=math.nan), "alpha_s must be finite and > 0"),
    (_params(regularisation=-1e-3), "regularisation must be finite and >= 0"),
    (_params(goal_alpha=0.0), "goal_alpha must be finite and > 0"),
    (lambda: DmpWeights(np.zeros((2, 5)), [0, 0], [1, 1], 1.0, DmpParams()), r"weights must have shape \(d >= 1, 25\)"),
    (lambda: DmpWeights(np.zeros((2, 25)), [0, 0, 0], [1, 1], 1.0, DmpParams()), r"x0 must have shape \(2,\)"),
    (lambda: DmpWeights(np.zeros((2, 25)), [0, 0], [1, 1], -1.0, DmpParams()), "tau_s must be finite and > 0"),
    (lambda: Dmp("weights"), "weights must be a DmpWeights"),
    (lambda: _dmp().reset(tau_s=-1.2), "tau_s must be finite and > 0"),
    (lambda: _dmp().reset(tau_s=0.0), "tau_s must be finite and > 0"),
    (lambda: _dmp().reset(goal=[0.1, 0.0, 0.0]), r"goal must have shape \(2,\)"),
    (lambda: _dmp().reset(x0=[math.nan, 0.0]), "x0 contains non-finite values"),
    (lambda: _dmp().set_goal([0.1, math.nan]), "goal contains non-finite values"),
    (lambda: _dmp().set_goal(0.1), r"goal must have shape \(2,\)"),
    (lambda: _dmp().step(-0.02), "dt_s must be finite and > 0"),
    (lambda: _dmp().step(0.0), "dt_s must be finite and > 0"),
    (lambda: _dmp().step(math.nan), "dt_s must be finite and > 0"),
    (lambda: _dmp().step(0.02, substeps=0), "substeps must be a positive integer"),
    (lambda: _dmp().step(0.02, substeps=2.0), "substeps must be a positive integer"),
    (lambda: _dmp().step(1.0, substeps=1), "too long for a stable RK4"),
    (lambda: _dmp().rollout(0.02, -1.0), "duration_s must be finite and > 0"),
    (lambda: forcing(1.5, np.zeros((2, 25)), *basis(DmpParams())), r"phase s must lie in \[0, 1\]"),
    (lambda: forcing(0.5, np.zeros((2, 24)), *basis(DmpParams())), r"centres must have shape \(24,\)"),
])
def test_bad_inputs_raise_one_line_dmp_errors(call, message):
    with pytest.raises(DmpError, match=message) as info:
        call()
    assert isinstance(info.value, ValueError) and "\n" not in str(info.value)


def test_a_failed_step_leaves_the_state_alone():
    dmp = _dmp()
    dmp.step(DT_S)
    x, s = dmp.x, dmp.s
    with pytest.raises(DmpError):
        dmp.step(-DT_S)
    assert dmp.x == pytest.approx(x) and dmp.s == s
    assert dmp.step(DT_S).shape == (2,)  # and it goes on


# --- properties over random goals and durations -----------------------------------------------------


@given(step_m=st.floats(0.05, 0.30), tau_s=st.floats(0.8, 2.0))
def test_random_goals_and_durations_end_at_the_goal(step_m, tau_s):
    dmp = Dmp(swing_weights())
    dmp.reset(x0=[0.0, 0.0], goal=[step_m, 0.0], tau_s=tau_s)
    positions = run(dmp, 1.5 * tau_s)
    assert np.all(np.isfinite(positions))
    assert np.abs(positions[-1] - [step_m, 0.0]).max() < 2e-3


@given(
    step_m=st.floats(0.05, 0.40),
    lift_m=st.floats(0.0, 0.15),
    duration_s=st.floats(0.6, 2.0),
    samples=st.integers(61, 400),
)
def test_any_demonstrated_swing_is_reproduced_within_1_mm(step_m, lift_m, duration_s, samples):
    times, xz = swing_demonstration(step_m, lift_m, duration_s, samples)
    dmp = Dmp(fit(times, xz))
    ticks_s, positions = dmp.rollout(DT_S, duration_s)
    inside = ticks_s <= duration_s
    u = ticks_s[inside] / duration_s
    demo = np.column_stack([step_m * advance_profile(u), lift_m * lift_profile(u)])
    assert np.abs(positions[inside] - demo).max() < 1e-3
