"""The patient's support geometry (sim/support.py)."""

import math

import numpy as np
import pytest

from sim.support import window_on_line
from sim.truth import convex_hull_2d, stability_margin


@pytest.mark.parametrize("seed", range(10))
def test_the_window_on_a_line_is_where_the_stability_margin_reaches_the_margin(seed):
    """For a convex polygon the points of a line at least ``margin`` inside every edge are those
    whose stability margin is at least ``margin``: the window's ends have it, a step beyond them
    does not."""
    rng = np.random.default_rng(seed)
    for _ in range(50):
        hull = convex_hull_2d(rng.uniform(-0.5, 0.5, size=(rng.integers(3, 7), 2)))
        y, margin = rng.uniform(-0.3, 0.3), rng.uniform(0.005, 0.05)
        lo, hi = window_on_line(hull, y, margin)
        if lo > hi:  # nowhere: no point of the line is that far inside
            xs = np.linspace(-0.6, 0.6, 241)
            assert all(stability_margin(hull, (x, y)) < margin + 1e-9 for x in xs)
            continue
        for x in (lo, hi, 0.5 * (lo + hi)):
            assert stability_margin(hull, (x, y)) >= margin - 1e-9
        for x in (lo - 1e-4, hi + 1e-4):
            assert stability_margin(hull, (x, y)) < margin


def test_a_segment_has_no_window():
    assert window_on_line(np.array([[0.0, 0.0], [1.0, 0.0]]), 0.0, 0.01) == (math.inf, -math.inf)
