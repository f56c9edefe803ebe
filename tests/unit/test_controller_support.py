"""The lift window's geometry (controller.support): where the CoM may be while a stick is in the air."""

import math

import pytest

from controller.support import lift_window, tip_share_limit

FEET = [(0.0, 0.1), (0.0, -0.1)]  # side by side, 0.2 m apart
TIP = (0.35, 0.3)  # the stick that stays, ahead on the left


def test_share_limit_is_the_lever_rule_with_feet_side_by_side():
    # the tip's share grows linearly from the feet's line (0) to the tip (1)
    assert tip_share_limit(FEET, TIP, 0.0, 0.27) == pytest.approx(0.27 * 0.35)
    assert tip_share_limit(FEET[::-1], TIP, 0.0, 0.27) == pytest.approx(0.27 * 0.35)  # order of the feet


def test_share_limit_is_the_barycentric_coordinate_with_staggered_feet():
    feet, tip, share = [(0.17, 0.1), (0.0, -0.1)], (0.5, -0.3), 0.27
    x = tip_share_limit(feet, tip, 0.0, share)
    # the barycentric coordinate of (x, 0) with respect to the tip, computed from areas
    (ax, ay), (bx, by) = feet

    def area(p, q, r):
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    assert area((ax, ay), (bx, by), (x, 0.0)) / area((ax, ay), (bx, by), tip) == pytest.approx(share)


def test_a_stick_behind_the_feet_sets_no_limit():
    # (the support is behind the feet: the geometric window, not the arm, bounds the CoM)
    assert tip_share_limit(FEET, (-0.1, 0.3), 0.0, 0.27) == math.inf


def test_the_window_ends_where_the_arm_that_stays_is_full():
    free = lift_window(FEET, [TIP], 0.0, 0.05, 0.03, 0.0)
    capped = lift_window(FEET, [TIP], 0.0, 0.05, 0.03, 0.0, share=0.15)
    assert capped[0] == free[0] == pytest.approx(0.03)  # the margin inside the feet's line
    assert capped[1] == pytest.approx(0.15 * 0.35)
    assert capped[1] < free[1]
    # an arm that holds nothing leaves no window
    assert lift_window(FEET, [TIP], 0.0, 0.05, 0.03, 0.0, share=-0.1) == (math.inf, -math.inf)
