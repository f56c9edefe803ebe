"""The patient's supports, as it judges them (pure numpy): where its CoM may rest while a stick is
in the air, and the support polygon of a swing."""

from __future__ import annotations

import math

import numpy as np

from config.hardware_schema import FootConfig
from sim.truth import convex_hull_2d, pivot_polygon, successors


def lift_window(ankles: np.ndarray, stays: np.ndarray, com_y: float, foot: FootConfig, *, shift_margin_m: float,
                balance_margin_m: float, max_stick_share: float) -> tuple[float, float]:
    """(lo, hi) of the CoM's x, at ``com_y``, where the body rests on the stance ankles ``ankles``
    (k, 2) and the planted tips that stay ``stays`` (m, 2): ahead of the ankles' midpoint by
    ``balance_margin_m``, inside the soles and the tips with ``shift_margin_m``, and with a single
    staying stick's share of the weight at most ``max_stick_share`` (lo > hi: no such place)."""
    balance = float(ankles[:, 0].mean()) + balance_margin_m
    poly = convex_hull_2d(pivot_polygon(ankles, stays, ankle_halfwidth=foot.half_width_m))
    far = max([ankles[:, 0].max(), *stays[:, 0]])
    # the patient judges its place on a grid of 81 points from behind its heels to the farthest
    # support: those at least shift_margin_m inside the polygon (a convex polygon shrunk by the
    # margin: an interval of the line)
    xs = np.linspace(float(ankles[:, 0].min()) - foot.heel_back_m, far, 81)
    inside_lo, inside_hi = window_on_line(poly, com_y, shift_margin_m)
    ok = (xs >= inside_lo) & (xs <= inside_hi)
    if len(stays) == 1 and len(ankles) == 2:
        # the arm that stays takes what the lift hands it: its share of the weight (the tip's
        # barycentric coordinate over the two ankles and the tip) at most its comfort
        a, b, tip = ankles[0], ankles[1], stays[0]
        edge = b - a
        share = (edge[0] * (com_y - a[1]) - edge[1] * (xs - a[0])) / (edge[0] * (tip[1] - a[1]) - edge[1] * (tip[0] - a[0]))
        ok &= share <= max_stick_share
    held = xs[ok]
    if not len(held):
        return math.inf, -math.inf
    return max(balance, float(held.min())), float(held.max())


def window_on_line(hull: np.ndarray, y: float, margin: float) -> tuple[float, float]:
    """(lo, hi) of the x on the line at ``y`` whose points lie at least ``margin`` (> 0) inside every
    edge of the counter-clockwise convex ``hull`` (m, 2): for a convex polygon the points whose
    :func:`sim.truth.stability_margin` is at least ``margin``. (inf, -inf): none (fewer than three
    vertices have no inside)."""
    if len(hull) < 3:
        return math.inf, -math.inf
    edge = successors(hull) - hull
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.hypot(edge[:, 0], edge[:, 1])[:, None]  # outward
    # inside by the margin: normal . ((x, y) - vertex) <= -margin, for every edge
    rhs = (normal * hull).sum(axis=1) - normal[:, 1] * y - margin
    nx = normal[:, 0]
    if (rhs[np.abs(nx) < 1e-12] < 0.0).any():
        return math.inf, -math.inf
    upper, lower = nx > 1e-12, nx < -1e-12
    lo = float((rhs[lower] / nx[lower]).max()) if lower.any() else -math.inf
    hi = float((rhs[upper] / nx[upper]).min()) if upper.any() else math.inf
    return (lo, hi) if lo <= hi else (math.inf, -math.inf)


def swing_support(ankle_xy: np.ndarray, foot: FootConfig, tips: np.ndarray) -> np.ndarray:
    """The points of the support polygon of a swing over the stance ankle ``ankle_xy``: its sole
    (heel to toe, across its width) and the stick tips ``tips`` (m, 2)."""
    x, y = ankle_xy
    sole = [(x + dx, y + dy) for dx in (-foot.heel_back_m, foot.toe_front_m) for dy in (-foot.half_width_m, foot.half_width_m)]
    return np.array(sole + [tuple(t) for t in tips])
