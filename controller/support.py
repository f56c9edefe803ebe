"""Support-polygon geometry of the gait's weight shift (pure, plain floats).

Before the patient lifts a stick the CoM must rest on what stays: the two feet (each passive ankle
a pivot widened by half the sole across) and the other stick's tip. :func:`lift_window` gives the
interval of the CoM's fore-aft place, at its lateral place, where it does, with a margin inside
every edge, and ahead of the ankles' midpoint (behind it the body rocks backward off its passive
ankles, and a stick only pushes).
"""

from __future__ import annotations

import math

Point = tuple[float, float]


def convex_hull(points: list[Point]) -> list[Point]:
    """The convex hull, counter-clockwise, without collinear points (Andrew's monotone chain)."""
    pts = sorted(set(points))
    if len(pts) < 3:
        return pts

    def half(seq: list[Point]) -> list[Point]:
        out: list[Point] = []
        for p in seq:
            while len(out) >= 2 and (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1]) - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0]) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return lower[:-1] + upper[:-1]


def window_on_line(hull: list[Point], y: float, margin: float) -> tuple[float, float]:
    """(lo, hi) of the x on the line at ``y`` that lie at least ``margin`` inside every edge of the
    counter-clockwise ``hull``; (inf, -inf) when no point does."""
    if len(hull) < 3:
        return math.inf, -math.inf
    lo, hi = -math.inf, math.inf
    for (x0, y0), (x1, y1) in zip(hull, hull[1:] + hull[:1]):
        length = math.hypot(x1 - x0, y1 - y0)
        nx, ny = (y1 - y0) / length, (x0 - x1) / length  # outward normal
        rhs = nx * x0 + ny * y0 - ny * y - margin  # inside: nx * x <= rhs
        if abs(nx) < 1e-12:
            if rhs < 0.0:
                return math.inf, -math.inf
        elif nx > 0.0:
            hi = min(hi, rhs / nx)
        else:
            lo = max(lo, rhs / nx)
    return (lo, hi) if lo <= hi else (math.inf, -math.inf)


def tip_share_limit(ankles: list[Point], tip: Point, com_y: float, share: float) -> float:
    """The farthest x on the line at ``com_y`` where the one stick that stays, at ``tip``, carries
    at most ``share`` of the weight with the two ``ankles``: the tip's barycentric coordinate in
    the triangle (ankles, tip) is linear in the CoM, 0 on the feet's line and 1 at the tip."""
    (x0, y0), (x1, y1) = ankles
    nx, ny = y0 - y1, x1 - x0  # normal of the feet's line ...
    if nx * (tip[0] - x0) + ny * (tip[1] - y0) < 0.0:
        nx, ny = -nx, -ny  # ... toward the tip
    if nx <= 1e-9:
        return math.inf
    # nx (x - x0) + ny (com_y - y0) <= share (nx (tip_x - x0) + ny (tip_y - y0))
    reach = nx * (tip[0] - x0) + ny * (tip[1] - y0)
    return x0 + (share * reach - ny * (com_y - y0)) / nx


def lift_window(ankles: list[Point], tips: list[Point], com_y: float, half_width: float, margin: float,
                balance_margin: float, share: float = 1.0) -> tuple[float, float]:
    """Where the CoM may be while a stick is in the air: on the support of both ``ankles`` (each
    widened by ``half_width`` across) and the ``tips`` that stay, ``margin`` inside its edges,
    ``balance_margin`` ahead of the ankles' midpoint, and (one stick staying) where that stick
    carries at most ``share`` of the weight (:func:`tip_share_limit`: the arm that is left holds
    what the lift hands it). (inf, -inf): nowhere."""
    pivots = [(x, y + s * half_width) for x, y in ankles for s in (1.0, -1.0)] + list(tips)
    lo, hi = window_on_line(convex_hull(pivots), com_y, margin)
    lo = max(lo, sum(x for x, _ in ankles) / len(ankles) + balance_margin)
    if len(tips) == 1 and len(ankles) == 2:
        hi = min(hi, tip_share_limit(ankles, tips[0], com_y, share))
    return (lo, hi) if lo <= hi else (math.inf, -math.inf)
