"""Small vector helpers for the per-tick numerics (no PyBullet, so the world and the sensors share
them), cheaper than numpy's general versions on the tiny arrays of the model (3-vectors, a dozen
joints), with the same arithmetic.

``np.cross`` and ``np.clip`` spend most of their time on argument handling (axis moves,
broadcasting checks, dispatch) for arrays of a few elements; these do only the arithmetic, in
the same order, so their results are the same to the bit.
"""

from __future__ import annotations

import math

import numpy as np


_NEXT, _AFTER_NEXT = np.array([1, 2, 0]), np.array([2, 0, 1])  # component k's successors in a cross product


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of (..., 3) float arrays (broadcast): the same products and differences,
    ``a_{k+1} b_{k+2} - a_{k+2} b_{k+1}`` for every component k at once."""
    return a.take(_NEXT, axis=-1) * b.take(_AFTER_NEXT, axis=-1) - a.take(_AFTER_NEXT, axis=-1) * b.take(_NEXT, axis=-1)


def cross3(a, b) -> tuple[float, float, float]:
    """:func:`cross` of two 3-sequences of floats, in floats: the same products and differences."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def norm3(v) -> float:
    """``np.linalg.norm`` of a 3-vector (a sequence of floats or an array): the square root of
    numpy's ``v . v`` of it as a contiguous array (what ``norm`` computes, without its argument
    handling)."""
    v = np.array(v, dtype=float)
    return math.sqrt(v.dot(v))


def cross_z(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The z component of ``np.cross(a, b)`` alone: ``a_x b_y - a_y b_x``."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def clamp(x: float, lo: float, hi: float) -> float:
    """``float(np.clip(x, lo, hi))`` for a scalar: ``min(max(x, lo), hi)`` (nan stays nan)."""
    return float(min(max(x, lo), hi))


def rpy_from_matrix(rot: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (roll, pitch, yaw) of a rotation matrix; pitch > 0 is nose down about +y."""
    pitch = -np.arcsin(clamp(rot[2, 0], -1.0, 1.0))
    roll = np.arctan2(rot[2, 1], rot[2, 2])
    yaw = np.arctan2(rot[1, 0], rot[0, 0])
    return np.array([roll, pitch, yaw])


def minimum_jerk(a: float) -> float:
    """Minimum-jerk blend ``10 a^3 - 15 a^4 + 6 a^5`` from 0 to 1, clamped outside [0, 1]."""
    a = min(max(a, 0.0), 1.0)
    return a * a * a * (10 - 15 * a + 6 * a * a)
