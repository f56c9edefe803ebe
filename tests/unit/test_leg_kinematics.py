"""Leg kinematics and the step-length compensation of the controller."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.compensation import CompensationError, StepBounds, compensated_step
from controller.kinematics import KinematicsError, Leg, forward, inverse, jacobian

LEG = Leg(thigh_m=0.429, shank_m=0.430, hip_min_rad=-0.5, hip_max_rad=2.0, knee_min_rad=0.0, knee_max_rad=2.0)


@given(hip=st.floats(-0.4, 1.5), knee=st.floats(0.01, 1.9))
def test_inverse_undoes_forward(hip, knee):
    x, z = forward(LEG, hip, knee)
    h2, k2 = inverse(LEG, x, z)
    assert (h2, k2) == pytest.approx((hip, knee), abs=1e-7)


def test_straight_leg_hangs_down_and_flexion_signs():
    assert forward(LEG, 0.0, 0.0) == pytest.approx((0.0, -0.859))
    x, _ = forward(LEG, 0.3, 0.0)
    assert x > 0  # hip flexion swings the foot forward
    x, _ = forward(LEG, 0.0, 0.5)
    assert x < 0  # knee flexion moves the foot back


@pytest.mark.parametrize("target, message", [
    ((0.0, -0.95), "outside the leg's reach"),
    ((0.0, 0.0), "outside the leg's reach"),
    ((float("nan"), -0.8), "is not finite"),
    ((-0.8, -0.3), "needs hip"),
])
def test_unreachable_targets_are_clear_errors(target, message):
    with pytest.raises(KinematicsError, match=message):
        inverse(LEG, *target)


def test_jacobian_matches_finite_differences():
    hip, knee, eps = 0.4, 0.6, 1e-6
    jac = jacobian(LEG, hip, knee)
    numeric = np.column_stack([
        (np.array(forward(LEG, hip + eps, knee)) - np.array(forward(LEG, hip - eps, knee))) / (2 * eps),
        (np.array(forward(LEG, hip, knee + eps)) - np.array(forward(LEG, hip, knee - eps))) / (2 * eps),
    ])
    assert jac == pytest.approx(numeric, abs=1e-6)


BOUNDS = StepBounds(init_m=0.15, min_m=0.08, max_m=0.25)


def test_compensation_follows_equation_8():
    goal = compensated_step(BOUNDS, alpha=-0.4, xhat_com=0.9, com_ratio=0.85)
    assert goal.length_m == pytest.approx(0.15 - 0.4 * 0.05) and not goal.clamped


def test_compensation_clamps_and_says_so():
    low = compensated_step(BOUNDS, alpha=-8.4, xhat_com=0.8, com_ratio=0.0)
    assert low.clamped and low.length_m == 0.08 and "below the minimum" in low.reason
    high = compensated_step(BOUNDS, alpha=-8.4, xhat_com=0.2, com_ratio=0.9)
    assert high.clamped and high.length_m == 0.25 and "above the maximum" in high.reason
    blind = compensated_step(BOUNDS, alpha=-8.4, xhat_com=0.8, com_ratio=math.nan)
    assert blind.clamped and blind.length_m == 0.15


@given(alpha=st.floats(-50, 50), xhat=st.floats(-2, 2), ratio=st.floats(-5, 5))
def test_compensated_step_always_within_bounds(alpha, xhat, ratio):
    goal = compensated_step(BOUNDS, alpha, xhat, ratio)
    assert BOUNDS.min_m <= goal.length_m <= BOUNDS.max_m


def test_bad_parameters_raise():
    with pytest.raises(CompensationError):
        compensated_step(BOUNDS, alpha=math.inf, xhat_com=0.8, com_ratio=0.5)
    with pytest.raises(CompensationError):
        StepBounds(init_m=0.3, min_m=0.08, max_m=0.25)
