"""Ground-truth stability metrics (sim/truth.py): hulls, margins, ratios, CoM, falls, attitudes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from protocol.geometry import fore_aft_ratio
from sim.truth import (
    FallCriteria,
    com_of_links,
    convex_hull_2d,
    detect_fall,
    pivot_margin,
    pivot_polygon,
    polygon_area,
    polygon_centroid,
    quat_to_rpy,
    radial_ratio,
    rpy_to_matrix,
    stability_margin,
    support_polygon,
)

UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])

coord = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
xy = st.tuples(coord, coord)
point_sets = st.lists(xy, min_size=3, max_size=12)
# Multiples of 1/64 (with many ties): every cross product is exact, so hull checks can be strict.
grid = st.integers(-64, 64).map(lambda i: i / 64)
grid_sets = st.lists(st.tuples(grid, grid), min_size=3, max_size=16)


def frozen(a) -> np.ndarray:
    """A read-only copy: a function that tried to modify its input would raise."""
    arr = np.array(a, dtype=float)
    arr.flags.writeable = False
    return arr


def convex_polygon(points) -> np.ndarray:
    hull = convex_hull_2d(points)
    assume(len(hull) >= 3 and polygon_area(hull) > 1e-3)
    return hull


def ray_cast_inside(poly: np.ndarray, p) -> bool:
    """Independent even-odd point-in-polygon test."""
    x, y = p
    inside = False
    for (x1, y1), (x2, y2) in zip(poly, np.roll(poly, -1, axis=0)):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


# --- convex hull ---------------------------------------------------------------------------


def test_hull_of_square_drops_interior_duplicate_and_collinear_points():
    pts = np.vstack([UNIT_SQUARE, UNIT_SQUARE[::-1], [[0.5, 0.5], [0.2, 0.7], [0.5, 0.0], [1.0, 0.5]]])
    hull = convex_hull_2d(frozen(pts))
    assert hull.tolist() == [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]  # CCW
    assert polygon_area(hull) == pytest.approx(1.0)
    assert support_polygon(pts).tolist() == hull.tolist()


@pytest.mark.parametrize(
    ("points", "expected"),
    [
        ([], []),
        ([[0.3, 0.4]], [[0.3, 0.4]]),
        ([[0.3, 0.4], [0.3, 0.4]], [[0.3, 0.4]]),
        ([[1.0, 1.0], [0.0, 0.0]], [[0.0, 0.0], [1.0, 1.0]]),
        ([[2.0, 2.0], [0.0, 0.0], [1.0, 1.0], [1.0, 1.0]], [[0.0, 0.0], [2.0, 2.0]]),
    ],
)
def test_hull_degenerate_inputs_return_what_exists(points, expected):
    hull = convex_hull_2d(points)
    assert hull.shape == (len(expected), 2)
    assert hull.tolist() == expected
    assert polygon_area(hull) == 0.0


@pytest.mark.parametrize("bad", [[[1.0, 2.0, 3.0]], [[math.nan, 0.0]], [1.0, 2.0]])
def test_hull_rejects_bad_shapes_and_non_finite_points(bad):
    with pytest.raises(ValueError):
        convex_hull_2d(bad)


@given(grid_sets, st.randoms(use_true_random=False))
def test_hull_is_ccw_contains_all_points_and_ignores_order(points, rnd):
    hull = convex_hull_2d(points)
    pts = np.array(points)
    assert {tuple(v) for v in hull} <= {tuple(p) for p in pts}
    shuffled = list(points)
    rnd.shuffle(shuffled)
    assert convex_hull_2d(shuffled).tolist() == hull.tolist()
    if len(hull) >= 3:
        a, b, c = hull, np.roll(hull, -1, axis=0), np.roll(hull, -2, axis=0)
        turns = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        assert (turns > 0).all()  # strictly left turns: counter-clockwise, no collinear vertices
        assert all(stability_margin(hull, p) >= -1e-9 for p in pts)


@given(point_sets)
def test_hull_contains_every_input_point(points):
    hull = convex_hull_2d(points)
    assert all(stability_margin(hull, p) >= -1e-12 for p in points)


# --- static stability margin ---------------------------------------------------------------


def test_margin_of_unit_square():
    assert stability_margin(UNIT_SQUARE, (0.5, 0.5)) == pytest.approx(0.5)
    assert stability_margin(UNIT_SQUARE, (0.9, 0.5)) == pytest.approx(0.1)
    assert stability_margin(UNIT_SQUARE, (1.0, 0.3)) == pytest.approx(0.0, abs=1e-15)
    assert stability_margin(UNIT_SQUARE, (0.0, 0.0)) == pytest.approx(0.0, abs=1e-15)
    assert stability_margin(UNIT_SQUARE, (1.25, 0.5)) == pytest.approx(-0.25)
    assert stability_margin(UNIT_SQUARE, (2.0, 2.0)) == pytest.approx(-math.sqrt(2.0))  # to the corner
    assert stability_margin(UNIT_SQUARE[::-1], (0.5, 0.5)) == pytest.approx(0.5)  # any vertex order


@given(st.floats(1e-6, 10.0), st.floats(0.0, 1.0))
def test_margin_outside_at_distance_d_is_minus_d(d, t):
    assert stability_margin(UNIT_SQUARE, (t, -d)) == pytest.approx(-d)


def test_margin_of_degenerate_polygons_is_never_positive():
    assert stability_margin([[0.0, 0.0]], (3.0, 4.0)) == pytest.approx(-5.0)
    segment = [[0.0, 0.0], [2.0, 0.0]]
    assert stability_margin(segment, (1.0, 0.5)) == pytest.approx(-0.5)
    assert stability_margin(segment, (1.0, 0.0)) == 0.0
    assert stability_margin([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], (1.0, -0.1)) == pytest.approx(-0.1)
    assert stability_margin([], (0.0, 0.0)) == -math.inf


@given(point_sets, xy)
def test_margin_sign_agrees_with_ray_casting_and_is_bounded_by_vertex_distance(points, p):
    poly = convex_polygon(points)
    margin = stability_margin(frozen(poly), frozen(p))
    assume(abs(margin) > 1e-9)
    assert (margin > 0) == ray_cast_inside(poly, p)
    assert abs(margin) <= np.hypot(*(poly - p).T).min() + 1e-12


@given(point_sets, st.lists(xy, max_size=4), xy)
def test_margin_grows_with_support(points, extra, p):
    """Adding contacts can only enlarge the polygon (pivot polygon <= sole polygon)."""
    small = convex_polygon(points)
    big = convex_hull_2d(np.vstack([small, np.array(extra).reshape(-1, 2)]))
    assert stability_margin(big, p) >= stability_margin(small, p) - 1e-12


# --- the fore-aft ratio (protocol.geometry) on the truth's polygons, and the radial ratio ------------------------------------------------------------


@given(point_sets, st.lists(st.floats(0.01, 1.0), min_size=12, max_size=12))
def test_ratios_lie_in_unit_interval_for_inside_points(points, weights):
    """A point inside by construction (positive weights of every vertex): a random point and
    ``assume`` filtered out so many that Hypothesis's health check failed now and then."""
    poly = convex_polygon(points)
    w = np.array(weights[: len(poly)])
    p = tuple(w @ np.asarray(poly) / w.sum()) if len(poly) else (0.0, 0.0)
    assume(stability_margin(poly, p) > 1e-9)  # a polygon of no area has no inside
    assert 0.0 <= fore_aft_ratio(p[0], [v[0] for v in poly], 0.0) <= 1.0
    assert radial_ratio(poly, p) < 1.0


@given(point_sets, xy)
def test_radial_ratio_is_one_exactly_where_margin_is_zero(points, p):
    poly = convex_polygon(points)
    margin, ratio = stability_margin(poly, p), radial_ratio(poly, p)
    assume(abs(margin) > 1e-9)
    assert (ratio < 1.0) == (margin > 0.0)
    # scaling the offset from the centroid scales the ratio: the boundary point is where it is 1
    g = polygon_centroid(poly)
    boundary = g + (np.asarray(p) - g) / ratio
    assert stability_margin(poly, boundary) == pytest.approx(0.0, abs=1e-9)


def test_radial_ratio_on_unit_square():
    assert polygon_centroid(UNIT_SQUARE) == pytest.approx([0.5, 0.5])
    assert radial_ratio(UNIT_SQUARE, (0.5, 0.5)) == 0.0
    assert radial_ratio(UNIT_SQUARE, (1.0, 0.5)) == pytest.approx(1.0)
    assert radial_ratio(UNIT_SQUARE, (1.0, 1.0)) == pytest.approx(1.0)
    assert radial_ratio(UNIT_SQUARE, (0.75, 0.5)) == pytest.approx(0.5)
    assert radial_ratio(UNIT_SQUARE, (0.5, 2.0)) == pytest.approx(3.0)
    assert math.isnan(radial_ratio([[0.0, 0.0], [1.0, 1.0]], (0.5, 0.5)))
    with pytest.raises(ValueError):
        polygon_centroid([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])


# --- the HHEA examples from our notes ------------------------------------------------------

TIPS = np.array([[0.746, 0.227], [0.746, -0.227]])


def test_quadruple_support_com_near_heels_has_fore_aft_ratio_about_0_18():
    soles = [[-0.18, 0.15], [0.09, 0.15], [-0.18, -0.15], [0.09, -0.15]]
    polygon = support_polygon(np.vstack([soles, TIPS]))
    com = (-0.01, 0.0)
    assert fore_aft_ratio(com[0], polygon[:, 0].tolist(), 0.0) == pytest.approx(0.17 / 0.926)
    assert fore_aft_ratio(com[0], polygon[:, 0].tolist(), 0.0) == pytest.approx(0.18, abs=0.01)
    assert stability_margin(polygon, com) > 0.0


def test_triple_support_without_weight_shift_is_unstable():
    right_sole = [[-0.18, -0.1], [0.09, -0.1], [-0.18, -0.2], [0.09, -0.2]]
    com = (-0.02, 0.0)
    assert stability_margin(support_polygon(np.vstack([right_sole, TIPS])), com) < 0.0
    pivots = pivot_polygon([[-0.1, -0.15]], TIPS, ankle_halfwidth=0.05)
    assert stability_margin(pivots, com) < stability_margin(support_polygon(np.vstack([right_sole, TIPS])), com)


def test_pivot_polygon_widens_ankles_laterally():
    assert pivot_polygon([[0.0, 0.0]], [], ankle_halfwidth=0.05).tolist() == [[0.0, -0.05], [0.0, 0.05]]
    poly = pivot_polygon(frozen([[0.0, 0.1], [0.0, -0.1]]), frozen(TIPS))
    assert sorted(map(tuple, poly)) == sorted(map(tuple, np.vstack([[[0.0, 0.1], [0.0, -0.1]], TIPS])))
    assert len(pivot_polygon([], [])) == 0
    with pytest.raises(ValueError):
        pivot_polygon([[0.0, 0.0]], TIPS, ankle_halfwidth=-0.01)


# --- centre of mass ------------------------------------------------------------------------


def test_com_of_links():
    com = com_of_links(frozen([1.0, 3.0]), frozen([[0.0, 0.0, 0.0], [4.0, 0.0, 1.0]]))
    assert com == pytest.approx([3.0, 0.0, 0.75])
    assert com_of_links([2.0, 0.0], [[1.0, 2.0, 3.0], [9.0, 9.0, 9.0]]) == pytest.approx([1.0, 2.0, 3.0])
    for masses, positions in [([0.0], [[0, 0, 0]]), ([-1.0, 2.0], [[0, 0, 0]] * 2), ([1.0], [[0, 0]])]:
        with pytest.raises(ValueError):
            com_of_links(masses, positions)


# --- fall detection ------------------------------------------------------------------------

CRITERIA = FallCriteria(frozenset({"foot_l", "foot_r", "tip_l", "tip_r"}), tilt_limit_rad=0.8, min_base_height_m=0.5)


@pytest.mark.parametrize(
    ("touching", "roll", "pitch", "height", "reason"),
    [
        ({"foot_l", "tip_r"}, 0.1, -0.3, 0.9, None),
        ([], 0.0, 0.0, 0.9, None),
        (["foot_l", "thigh_l"], 0.0, 0.0, 0.9, "link 'thigh_l' touched the ground"),
        (["thigh_l", "head"], 0.0, 0.0, 0.9, "links 'head', 'thigh_l' touched the ground"),
        ([], 0.0, 0.93, 0.9, "trunk pitch 0.93 rad beyond 0.80"),
        ([], -0.85, 0.0, 0.9, "trunk roll -0.85 rad beyond 0.80"),
        ([], math.nan, 0.0, 0.9, "trunk roll nan rad beyond 0.80"),
        ([], 0.0, 0.0, 0.41, "hip height 0.41 m below 0.50"),
        (["shank_r"], 0.0, 1.2, 0.2, "link 'shank_r' touched the ground"),  # contacts are reported first
    ],
)
def test_fall_criteria(touching, roll, pitch, height, reason):
    assert CRITERIA.check(touching, roll, pitch, height) == reason
    assert detect_fall(touching, CRITERIA.allowed_contacts, roll, pitch, 0.8, height, 0.5) == reason


@pytest.mark.parametrize(
    ("roll", "pitch", "upright", "direction"),
    [
        (0.85, 0.1, 0.1, "lateral"),
        (-0.3, 0.1, 0.1, "lateral"),  # a sideways lean with the trunk at its upright pitch
        (0.1, 0.93, 0.1, "forward"),  # pitch > 0 is nose down
        (0.1, -0.6, 0.1, "backward"),
        (0.5, 0.9, 0.1, "forward"),  # pitched 0.8 past upright, rolled 0.5
        (0.5, 0.5, 0.1, "lateral"),  # rolled 0.5, pitched 0.4 past upright
        (math.nan, 0.0, 0.0, "lateral"),
    ],
)
def test_fall_direction_is_the_larger_deviation_from_upright(roll, pitch, upright, direction):
    assert FallCriteria.direction(roll, pitch, upright) == direction


@pytest.mark.parametrize(
    ("roll", "pitch", "velocity", "direction"),
    [
        (0.02, 0.11, (0.6, 0.05), "forward"),  # upright, sinking while the CoM runs forward
        (0.02, 0.09, (-0.3, 0.1), "backward"),
        (-0.05, 0.10, (0.1, -0.4), "lateral"),
        (0.6, 0.1, (0.8, 0.0), "lateral"),  # tilted: the attitude decides, not the CoM's motion
    ],
)
def test_an_upright_trunk_falls_the_way_its_com_moves(roll, pitch, velocity, direction):
    assert FallCriteria.direction(roll, pitch, 0.1, velocity) == direction


def test_fall_criteria_validation():
    with pytest.raises(ValueError, match="base_height_m"):
        CRITERIA.check([], 0.0, 0.0)
    assert FallCriteria({"foot_l"}, 0.5).check(["foot_l"], 0.0, 0.4) is None  # no height check
    assert isinstance(FallCriteria(["a"], 0.5).allowed_contacts, frozenset)
    with pytest.raises(ValueError):
        FallCriteria(frozenset(), 0.0)
    with pytest.raises(AttributeError):
        CRITERIA.tilt_limit_rad = 1.0  # frozen


# --- attitude ------------------------------------------------------------------------------


def quat_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def axis_quat(axis: int, angle: float) -> np.ndarray:
    q = np.zeros(4)
    q[axis], q[3] = math.sin(angle / 2), math.cos(angle / 2)
    return q


def quat_matrix(q) -> np.ndarray:
    x, y, z, w = np.asarray(q) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


angle = st.floats(-math.pi + 1e-6, math.pi - 1e-6)


@given(angle, st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3), angle, st.sampled_from([1.0, -1.0, 2.5]))
def test_quat_to_rpy_round_trips_with_rpy_to_matrix(roll, pitch, yaw, scale):
    q = scale * quat_mul(axis_quat(2, yaw), quat_mul(axis_quat(1, pitch), axis_quat(0, roll)))  # ZYX
    rpy = quat_to_rpy(frozen(q))
    assert rpy == pytest.approx([roll, pitch, yaw], abs=1e-9)
    assert rpy_to_matrix(rpy) == pytest.approx(quat_matrix(q), abs=1e-9)


@given(st.tuples(coord, coord, coord, coord))
def test_rpy_to_matrix_reproduces_any_rotation(q):
    assume(np.linalg.norm(q) > 0.1)
    assert rpy_to_matrix(quat_to_rpy(q)) == pytest.approx(quat_matrix(q), abs=1e-6)


def test_positive_pitch_is_nose_down():
    rpy = quat_to_rpy(axis_quat(1, 0.3))
    assert rpy == pytest.approx([0.0, 0.3, 0.0])
    forward = rpy_to_matrix(rpy)[:, 0]  # body x axis in the world
    assert forward[2] < 0.0 and forward[0] > 0.0
    with pytest.raises(ValueError):
        quat_to_rpy([0.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_gimbal_lock_puts_the_rotation_into_roll(sign):
    q = quat_mul(axis_quat(2, 0.4), axis_quat(1, sign * math.pi / 2))
    roll, pitch, yaw = quat_to_rpy(q)
    assert (pitch, yaw) == (pytest.approx(sign * math.pi / 2), 0.0)
    assert rpy_to_matrix((roll, pitch, yaw)) == pytest.approx(quat_matrix(q), abs=1e-12)


def test_agrees_with_pybullet_conventions():
    p = pytest.importorskip("pybullet")
    rng = np.random.default_rng(7)
    for rpy in rng.uniform([-3, -1.5, -3], [3, 1.5, 3], size=(50, 3)):
        q = p.getQuaternionFromEuler(rpy.tolist())
        assert quat_to_rpy(q) == pytest.approx(p.getEulerFromQuaternion(q), abs=1e-9)
        assert rpy_to_matrix(rpy).ravel() == pytest.approx(p.getMatrixFromQuaternion(q), abs=1e-9)


def test_the_pivot_margin_of_plain_floats_is_the_stability_margin_of_the_pivot_polygon():
    """The per-tick ground truth (:func:`pivot_margin`) is the margin of :func:`pivot_polygon`."""
    rng = np.random.default_rng(4)
    for _ in range(300):
        ankles = [tuple(rng.uniform(-0.3, 0.3, 2)) for _ in range(rng.integers(0, 3))]
        tips = [tuple(rng.uniform(-0.6, 0.6, 2)) for _ in range(rng.integers(0, 3))]
        point = tuple(rng.uniform(-0.5, 0.5, 2))
        want = stability_margin(pivot_polygon(np.array(ankles).reshape(-1, 2), np.array(tips).reshape(-1, 2), ankle_halfwidth=0.045), point)
        assert pivot_margin(ankles, tips, 0.045, point) == pytest.approx(want, abs=1e-12)
