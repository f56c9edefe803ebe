"""Ground-truth stability metrics for the Hybrid Human-Exoskeleton Agent (HHEA).

The HHEA (patient + leg exoskeleton + two crutches) is treated as a quadruped: the
crutch ("stick") tips are the front legs, the feet are the hind legs. The ankles are
passive pins, so balance is decided by the *pivot polygon* (the convex hull of the
ankle pivots of the feet in contact and the loaded stick tips), not only by the soles.

Pure numpy: functions over arrays, no pybullet, no I/O, no global state; inputs are
never modified. World frame: x forward (walking direction), y left, z up; metres and
radians. Polygons are arrays of shape ``(m, 2)``; functions that need a convex polygon
use the convex hull of the vertices they are given, so any vertex order is accepted.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

__all__ = [
    "convex_hull_2d",
    "support_polygon",
    "pivot_polygon",
    "polygon_area",
    "polygon_centroid",
    "stability_margin",
    "pivot_margin",
    "extent_on_line",
    "radial_ratio",
    "com_of_links",
    "FallCriteria",
    "detect_fall",
    "quat_to_rpy",
    "rpy_to_matrix",
]

# Relative tolerance: a hull whose area is below _REL_EPS * span**2 is treated as a segment.
_REL_EPS = 1e-12
# Below this cos(pitch), roll and yaw cannot be told apart (quat_to_rpy).
_GIMBAL_LOCK = 1e-8


def _points(a, name: str) -> np.ndarray:
    """``a`` as a new finite float array of shape (n, 2); an empty input gives (0, 2)."""
    arr = np.array(a, dtype=float)  # a copy: callers' arrays are never touched
    if arr.size == 0:
        return arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains a non-finite value")
    return arr


def _vec(a, n: int, name: str) -> np.ndarray:
    arr = np.array(a, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains a non-finite value")
    return arr


def _unit(heading) -> np.ndarray:
    h = _vec(heading, 2, "heading")
    norm = math.hypot(h[0], h[1])
    if norm == 0.0:
        raise ValueError("heading must be a non-zero vector")
    return h / norm


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def convex_hull_2d(points) -> np.ndarray:
    """Convex hull of planar points (Andrew's monotone chain).

    Parameters
    ----------
    points : array_like, shape (n, 2)
        Any points; duplicates and collinear points are allowed, ``n`` may be 0.

    Returns
    -------
    ndarray, shape (m, 2)
        The hull vertices in counter-clockwise order, starting at the lowest-x (then
        lowest-y) point, without repeated or collinear vertices. Degenerate inputs give
        what exists: ``m = 0`` (no points), ``m = 1`` (all points equal) or ``m = 2`` (all
        points collinear: the two end points). Such polygons have zero area.
    """
    return np.array(_hull(map(tuple, _points(points, "points").tolist())), dtype=float).reshape(-1, 2)


def _hull(points) -> list[tuple[float, float]]:
    """:func:`convex_hull_2d` of plain (x, y) tuples, as tuples: for the handful of contacts of a
    tick plain floats are the fast path."""
    pts = sorted(set(points))  # by x, then y
    if len(pts) <= 2:
        return pts

    def chain(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while len(out) >= 2 and _cross(out[-2], out[-1], p) <= 0.0:
                out.pop()
            out.append(p)
        return out

    lower, upper = chain(pts), chain(pts[::-1])
    return lower[:-1] + upper[:-1]


def support_polygon(contact_points_xy) -> np.ndarray:
    """Support polygon: the convex hull of the ground contact points.

    Parameters
    ----------
    contact_points_xy : array_like, shape (n, 2)
        Horizontal positions of all contacts (sole corners, loaded stick tips).

    Returns
    -------
    ndarray, shape (m, 2)
        Counter-clockwise hull vertices, see :func:`convex_hull_2d`.
    """
    return convex_hull_2d(contact_points_xy)


def pivot_polygon(ankle_xy, tip_xy, ankle_halfwidth: float = 0.0) -> np.ndarray:
    """Pivot polygon: the convex hull of the ankle pivots and the loaded stick tips.

    With passive (pinned) ankles the feet cannot resist a pitch moment, so the
    polygon runs through the ankle pivots instead of the sole corners.

    Parameters
    ----------
    ankle_xy : array_like, shape (k, 2)
        Horizontal ankle pivot positions of the feet in contact (k may be 0).
    tip_xy : array_like, shape (j, 2)
        Horizontal positions of the loaded stick tips (j may be 0).
    ankle_halfwidth : float, default 0.0
        Each ankle is widened to the segment ``ankle ± (0, ankle_halfwidth)`` (world y):
        the width of the foot still gives some roll support about a pitch pin.

    Returns
    -------
    ndarray, shape (m, 2)
        Counter-clockwise hull vertices, see :func:`convex_hull_2d`.
    """
    ankles, tips = _points(ankle_xy, "ankle_xy"), _points(tip_xy, "tip_xy")
    if not (math.isfinite(ankle_halfwidth) and ankle_halfwidth >= 0.0):
        raise ValueError(f"ankle_halfwidth must be finite and >= 0, got {ankle_halfwidth}")
    if ankle_halfwidth > 0.0:
        offset = np.array([0.0, ankle_halfwidth])
        ankles = np.concatenate([ankles - offset, ankles + offset])
    return convex_hull_2d(np.concatenate([ankles, tips]))


def polygon_area(polygon) -> float:
    """Area of the convex hull of ``polygon`` (shape (m, 2)); 0 for m < 3. Always >= 0."""
    return _hull_area(convex_hull_2d(polygon))


def successors(a: np.ndarray) -> np.ndarray:
    """Each vertex's successor around the polygon (``np.roll(a, -1, axis=0)``, without its
    argument handling)."""
    return np.concatenate((a[1:], a[:1]))


def _hull_area(hull: np.ndarray) -> float:
    """Shoelace area of a counter-clockwise hull (:func:`convex_hull_2d`'s output)."""
    if len(hull) < 3:
        return 0.0
    x, y = (hull - hull[0]).T
    return 0.5 * float(np.dot(x, successors(y)) - np.dot(successors(x), y))


def _is_degenerate(hull: np.ndarray) -> bool:
    if len(hull) < 3:
        return True
    span = float(np.ptp(hull, axis=0).max())
    return _hull_area(hull) <= _REL_EPS * span * span


def polygon_centroid(polygon) -> np.ndarray:
    """Area centroid, shape (2,), of the convex hull of ``polygon`` (shape (m, 2)).

    Raises
    ------
    ValueError
        If the hull has zero area (fewer than three non-collinear vertices).
    """
    hull = convex_hull_2d(polygon)
    if _is_degenerate(hull):
        raise ValueError("the centroid of a polygon with zero area is undefined")
    rel = hull - hull[0]  # relative coordinates keep the shoelace sums well conditioned
    nxt = successors(rel)
    w = rel[:, 0] * nxt[:, 1] - nxt[:, 0] * rel[:, 1]
    return hull[0] + ((rel + nxt) * w[:, None]).sum(axis=0) / (3.0 * w.sum())


def stability_margin(polygon, point) -> float:
    """Static stability margin (McGhee & Frank, 1968).

    Parameters
    ----------
    polygon : array_like, shape (m, 2)
        Vertices of the support (or pivot) polygon; their convex hull is used.
    point : array_like, shape (2,)
        Horizontal position of the centre of mass (or of any point).

    Returns
    -------
    float
        Inside the polygon: the distance to the nearest edge (positive). On an edge: 0.
        Outside: minus the Euclidean distance to the polygon. A degenerate polygon (a
        point or a segment, zero area) has no inside: minus the distance to it, never
        positive. An empty polygon (no support) gives ``-inf``.
    """
    hull, p = convex_hull_2d(polygon), _vec(point, 2, "point")
    if len(hull) == 0:
        return -math.inf
    return _margin(hull.tolist(), float(p[0]), float(p[1]), _is_degenerate(hull))


def pivot_margin(ankles_xy: list[tuple[float, float]], tips_xy: list[tuple[float, float]], ankle_halfwidth: float,
                 point: tuple[float, float]) -> float:
    """:func:`stability_margin` of ``point`` in :func:`pivot_polygon` ``(ankles_xy, tips_xy,
    ankle_halfwidth)``, all plain floats: the per-tick ground truth (a handful of vertices, where
    numpy's per-call cost dominates)."""
    verts = _hull([(x, y + s * ankle_halfwidth) for x, y in ankles_xy for s in (-1.0, 1.0)] + list(tips_xy))
    if not verts:
        return -math.inf
    degenerate = len(verts) < 3
    if not degenerate:
        xs, ys = [v[0] for v in verts], [v[1] for v in verts]
        span = max(max(xs) - min(xs), max(ys) - min(ys))
        x0, y0 = verts[0]
        area = 0.5 * sum((ax - x0) * (by - y0) - (bx - x0) * (ay - y0) for (ax, ay), (bx, by) in zip(verts, verts[1:] + verts[:1]))
        degenerate = area <= _REL_EPS * span * span
    return _margin(verts, float(point[0]), float(point[1]), degenerate)


def _margin(verts: list, px: float, py: float, degenerate: bool) -> float:
    """The signed distance of (px, py) to the closed polyline ``verts`` (a counter-clockwise hull):
    positive inside, never positive for a ``degenerate`` hull."""
    distance, inside = math.inf, True
    for (ax, ay), (bx, by) in zip(verts, verts[1:] + verts[:1]):
        ex, ey = bx - ax, by - ay
        len2 = ex * ex + ey * ey
        t = min(max(((px - ax) * ex + (py - ay) * ey) / len2, 0.0), 1.0) if len2 > 0.0 else 0.0
        distance = min(distance, math.hypot(ax + t * ex - px, ay + t * ey - py))
        inside = inside and ex * (py - ay) - ey * (px - ax) >= 0.0
    return -distance if degenerate or not inside else distance


def extent_on_line(polygon, point, heading=(1.0, 0.0)) -> tuple[float, float]:
    """(rear, front): where the line through ``point`` along ``heading`` enters and leaves the
    convex hull of ``polygon``, as positions along the heading; (nan, nan) where it misses it."""
    hull, p, h = convex_hull_2d(polygon), _vec(point, 2, "point"), _unit(heading)
    if len(hull) == 0:
        return math.nan, math.nan
    lateral = np.array([-h[1], h[0]])
    d = (hull - p) @ lateral  # signed lateral offset of each vertex from the line
    s = hull @ h  # position of each vertex along the heading
    d2, s2 = successors(d), successors(s)
    crossing = np.sign(d) * np.sign(d2) < 0.0  # signs, not d * d2: that product underflows for tiny offsets
    hits = np.concatenate([s[d == 0.0], (s + d / np.where(crossing, d - d2, 1.0) * (s2 - s))[crossing]])
    if len(hits) == 0:
        return math.nan, math.nan
    return float(hits.min()), float(hits.max())


def radial_ratio(polygon, point) -> float:
    """Radial position of a point relative to the polygon's area centroid.

    Parameters
    ----------
    polygon : array_like, shape (m, 2)
        Polygon vertices (any order); their convex hull is used.
    point : array_like, shape (2,)
        Horizontal position ``c``, typically the centre of mass.

    Returns
    -------
    float
        ``|c - g| / |b - g|`` where ``g`` is the area centroid and ``b`` the boundary point
        on the ray from ``g`` through ``c``: 0 at the centroid, < 1 inside, 1 on the
        boundary, > 1 outside. ``nan`` for a polygon with zero area.
    """
    hull, c = convex_hull_2d(polygon), _vec(point, 2, "point")
    if _is_degenerate(hull):
        return math.nan
    g = polygon_centroid(hull)
    r = math.hypot(*(c - g))
    if r == 0.0:
        return 0.0
    u = (c - g) / r
    edges = successors(hull) - hull
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)  # outward for a CCW polygon
    along = normals @ u
    slack = -((g - hull) * normals).sum(axis=1)  # > 0: g is strictly inside
    t = (slack[along > 0.0] / along[along > 0.0]).min()
    return r / float(t)


def com_of_links(masses, positions) -> np.ndarray:
    """Whole-body centre of mass.

    Parameters
    ----------
    masses : array_like, shape (n,)
        Link masses in kg, each >= 0, with a positive sum.
    positions : array_like, shape (n, 3)
        World positions of the link centres of mass.

    Returns
    -------
    ndarray, shape (3,)
        The mass-weighted mean position.
    """
    m, x = np.array(masses, dtype=float), np.array(positions, dtype=float)
    if m.ndim != 1 or x.shape != (len(m), 3):
        raise ValueError(f"masses (n,) and positions (n, 3) expected, got {m.shape} and {x.shape}")
    if not (np.isfinite(m).all() and np.isfinite(x).all()):
        raise ValueError("masses and positions must be finite")
    if (m < 0.0).any() or m.sum() <= 0.0:
        raise ValueError("masses must be >= 0 with a positive total")
    return m @ x / m.sum()


@dataclass(frozen=True)
class FallCriteria:
    """When the HHEA counts as fallen.

    Attributes
    ----------
    allowed_contacts : frozenset of str
        Link names that may touch the ground (feet, stick tips); any other is a fall.
    tilt_limit_rad : float
        A fall when ``|roll|`` or ``|pitch|`` of the trunk exceeds this (> 0).
    min_base_height_m : float or None, default None
        A fall when the base frame's height drops below this (the HHEA's base frame is midway
        between the hip joints: its hip height); None disables the check.
    """

    allowed_contacts: frozenset[str]
    tilt_limit_rad: float
    min_base_height_m: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "allowed_contacts", frozenset(self.allowed_contacts))
        if not (math.isfinite(self.tilt_limit_rad) and self.tilt_limit_rad > 0.0):
            raise ValueError(f"tilt_limit_rad must be finite and > 0, got {self.tilt_limit_rad}")
        if self.min_base_height_m is not None and not math.isfinite(self.min_base_height_m):
            raise ValueError(f"min_base_height_m must be finite or None, got {self.min_base_height_m}")

    def check(
        self,
        touching_links: Iterable[str],
        trunk_roll_rad: float,
        trunk_pitch_rad: float,
        base_height_m: float | None = None,
    ) -> str | None:
        """Why the HHEA has fallen, or None.

        Parameters
        ----------
        touching_links : iterable of str
            Names of the links touching the ground now.
        trunk_roll_rad, trunk_pitch_rad : float
            Trunk attitude (see :func:`quat_to_rpy`). A non-finite value counts as a fall.
        base_height_m : float or None
            The base frame's (hips') height; required when ``min_base_height_m`` is set.

        Returns
        -------
        str or None
            A short reason (forbidden contact first, then pitch, roll, height), or None.
        """
        forbidden = sorted(set(touching_links) - self.allowed_contacts)
        if forbidden:
            names = ", ".join(f"'{n}'" for n in forbidden)
            return f"link{'s' if len(forbidden) > 1 else ''} {names} touched the ground"
        for axis, angle in (("pitch", trunk_pitch_rad), ("roll", trunk_roll_rad)):
            if not abs(angle) <= self.tilt_limit_rad:  # also true for nan
                return f"trunk {axis} {angle:.2f} rad beyond {self.tilt_limit_rad:.2f}"
        if self.min_base_height_m is not None:
            if base_height_m is None:
                raise ValueError("base_height_m is required when min_base_height_m is set")
            if not base_height_m >= self.min_base_height_m:
                return f"hip height {base_height_m:.2f} m below {self.min_base_height_m:.2f}"
        return None

    @staticmethod
    def direction(trunk_roll_rad: float, trunk_pitch_rad: float, upright_pitch_rad: float = 0.0,
                  com_velocity_xy: tuple[float, float] | None = None, tilted_rad: float = 0.15) -> str:
        """Which way a fall goes: ``"lateral"``, ``"forward"`` or ``"backward"``. From the trunk's
        attitude when it is tilted (roll or pitch at least ``tilted_rad`` from upright, or not
        finite): lateral when the roll is the larger deviation, else forward (pitched nose-down
        past its upright lean) or backward. A trunk still upright (a body that sinks, as on legs
        that fold) falls the way its CoM moves, ``com_velocity_xy`` in the trunk's heading frame
        (x forward, y left), when it is given."""
        pitch = trunk_pitch_rad - upright_pitch_rad
        tilted = not (max(abs(trunk_roll_rad), abs(pitch)) < tilted_rad)  # also true for nan
        if not tilted and com_velocity_xy is not None:
            vx, vy = com_velocity_xy
            if abs(vy) > abs(vx):
                return "lateral"
            return "forward" if vx > 0 else "backward"
        if not abs(trunk_roll_rad) < abs(pitch):  # also true for nan
            return "lateral"
        return "forward" if pitch > 0 else "backward"


def detect_fall(
    touching_links: Iterable[str],
    allowed: Iterable[str],
    trunk_roll_rad: float,
    trunk_pitch_rad: float,
    tilt_limit_rad: float,
    base_height_m: float | None = None,
    min_base_height_m: float | None = None,
) -> str | None:
    """One-shot form of ``FallCriteria(allowed, tilt_limit_rad, min_base_height_m).check(...)``."""
    criteria = FallCriteria(frozenset(allowed), tilt_limit_rad, min_base_height_m)
    return criteria.check(touching_links, trunk_roll_rad, trunk_pitch_rad, base_height_m)


def quat_to_rpy(q) -> np.ndarray:
    """ZYX Euler angles of a quaternion.

    Parameters
    ----------
    q : array_like, shape (4,)
        Quaternion ``(x, y, z, w)`` (PyBullet order); normalised here, must be non-zero.

    Returns
    -------
    ndarray, shape (3,)
        ``(roll, pitch, yaw)`` with ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (intrinsic
        z-y'-x''; the same convention as ``pybullet.getEulerFromQuaternion``).
        roll, yaw in [-pi, pi], pitch in [-pi/2, pi/2]; at pitch = +-pi/2 (gimbal lock)
        yaw is reported as 0 and the rest of the rotation as roll. Pitch > 0 is a rotation about
        +y that turns +x towards -z: nose down, i.e. a forward lean of the trunk.
    """
    v = _vec(q, 4, "q")
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        raise ValueError("q must be a non-zero quaternion")
    x, y, z, w = v / norm
    r00, r10 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z)
    cos_pitch = math.hypot(r00, r10)
    pitch = math.atan2(-2.0 * (x * z - w * y), cos_pitch)  # better conditioned than asin near +-pi/2
    if cos_pitch > _GIMBAL_LOCK:
        roll = math.atan2(2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
        yaw = math.atan2(r10, r00)
    else:  # pitch = +-pi/2: only roll -+ yaw is defined; report it all as roll, yaw = 0
        roll = math.atan2(2.0 * (w * x - y * z), 1.0 - 2.0 * (x * x + z * z))
        yaw = 0.0
    return np.array([roll, pitch, yaw])


def rpy_to_matrix(rpy) -> np.ndarray:
    """Rotation matrix (body to world), shape (3, 3), of ZYX Euler angles.

    Parameters
    ----------
    rpy : array_like, shape (3,)
        ``(roll, pitch, yaw)`` in radians, as returned by :func:`quat_to_rpy`.

    Returns
    -------
    ndarray, shape (3, 3)
        ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``; its columns are the body axes in world frame.
    """
    roll, pitch, yaw = _vec(rpy, 3, "rpy")
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])
