"""The geometry the controller and the simulation share (protocol/geometry.py)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.geometry import fore_aft_ratio, leg_forward, leg_inverse

THIGH, SHANK = 0.429, 0.430


def test_the_ratio_is_the_coms_place_between_the_rear_and_the_front_of_the_support():
    xs = [0.0, 1.0, 0.4]
    assert fore_aft_ratio(0.0, xs, 0.1) == 0.0
    assert fore_aft_ratio(1.0, xs, 0.1) == 1.0
    assert fore_aft_ratio(0.5, xs, 0.1) == 0.5
    assert fore_aft_ratio(-0.5, xs, 0.1) == -0.5  # behind the support
    assert fore_aft_ratio(1.25, [0.5, 1.5], 0.1) == 0.75


def test_no_support_or_one_shorter_than_the_least_extent_says_nothing_fore_aft():
    assert math.isnan(fore_aft_ratio(0.0, [], 0.1))
    assert math.isnan(fore_aft_ratio(0.0, [0.2, 0.25], 0.1))
    assert math.isnan(fore_aft_ratio(0.0, [0.2, 0.2], 0.0))  # no extent at all, even with no least one
    assert fore_aft_ratio(0.25, [0.25, 0.5], 0.25) == 0.0  # exactly the least extent


@given(st.floats(-0.6, 1.4), st.floats(0.05, 2.4))
def test_an_ankle_within_reach_comes_back_from_its_joint_angles(hip, knee):
    x, z = leg_forward(THIGH, SHANK, hip, knee)
    h, k = leg_inverse(THIGH, SHANK, x, z)
    assert (h, k) == (pytest.approx(hip, abs=1e-9), pytest.approx(knee, abs=1e-9))


def test_the_straight_leg_hangs_down_and_a_point_out_of_reach_is_an_error():
    assert leg_forward(THIGH, SHANK, 0.0, 0.0) == pytest.approx((0.0, -(THIGH + SHANK)))
    assert leg_inverse(THIGH, SHANK, 0.0, -(THIGH + SHANK)) == pytest.approx((0.0, 0.0))  # at full reach: rounding, not out of it
    with pytest.raises(ValueError, match="outside the leg's reach"):
        leg_inverse(THIGH, SHANK, 0.0, -1.0)
    with pytest.raises(ValueError, match="not finite"):
        leg_inverse(THIGH, SHANK, math.nan, -0.5)
