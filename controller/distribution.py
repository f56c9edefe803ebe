"""The distribution of the stance legs' wrench over the soles' contacts (pure: no I/O; compiled:
protocol/compiled.py).

Each contact carries a minimum load plus non-negative loads on the two edges (+-friction, 1) of its
fore-aft friction pyramid; the loads that best give the wrench (fx, fz, mx, my), each regularised,
solve a non-negative least squares: Lawson and Hanson's active-set method on the normal equations,
each passive set's least squares by L D L^T (Bro and de Jong's fast NNLS). The normal equations
are positive definite by the regularisation, so no passive set is singular.
"""

from __future__ import annotations

import cython
import numpy as np

#: weights of the wrench rows of the distribution: force x, force z, moment x (roll), moment y (pitch)
ROW_WEIGHT_FX, ROW_WEIGHT_FZ, ROW_WEIGHT_MX, ROW_WEIGHT_MY = 1.0, 1.0, 2.0, 2.0
FOOT_COST = 1e-4  # regularisation of each pyramid edge's load


def nnls(gram: np.ndarray, c: np.ndarray, max_iter: int = 60) -> np.ndarray:
    """argmin ||A x - b|| subject to x >= 0, given the normal equations' ``gram`` = A^T A (positive
    definite) and ``c`` = A^T b: Lawson and Hanson's active-set method with each passive set's
    least squares solved by L D L^T (Bro and de Jong's fast NNLS)."""
    n = c.shape[0]
    if gram.shape != (n, n):
        raise ValueError(f"gram must be ({n}, {n}), got {gram.shape}")
    x = np.zeros(n)
    work = np.zeros((4, n))
    _nnls(np.ascontiguousarray(gram, dtype=np.float64), np.ascontiguousarray(c, dtype=np.float64), max_iter, x,
          work, np.zeros((n, n)), np.zeros((2, n), dtype=np.intc))
    return x


@cython.cfunc
@cython.boundscheck(False)
@cython.wraparound(False)
def _nnls(g: cython.double[:, ::1], c: cython.double[::1], max_iter: cython.int, x: cython.double[::1],
          work: cython.double[:, ::1], low: cython.double[:, ::1], flags: cython.int[:, ::1]) -> cython.void:
    """:func:`nnls` in place on ``x``, over scalars (compiled: protocol/compiled.py). ``work`` rows:
    the gradient w = c - G x, the passive set's solution z, the forward solve, the pivots D;
    ``low`` L; ``flags`` rows: passive (0/1), the passive set's indices."""
    n: cython.Py_ssize_t = c.shape[0]
    w: cython.double[::1] = work[0]
    z: cython.double[::1] = work[1]
    y: cython.double[::1] = work[2]
    d: cython.double[::1] = work[3]
    passive: cython.int[::1] = flags[0]
    idx: cython.int[::1] = flags[1]
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    k: cython.Py_ssize_t
    p: cython.Py_ssize_t
    best: cython.Py_ssize_t
    it: cython.int
    s: cython.double
    alpha: cython.double
    t: cython.double
    done: cython.bint
    for i in range(n):
        w[i] = c[i]  # x = 0
        passive[i] = 0
    for it in range(max_iter):
        best, s = -1, 1e-10
        for j in range(n):  # the most positive gradient outside the passive set (the first of equals)
            if not passive[j] and w[j] > s:
                best, s = j, w[j]
        if best < 0:
            break
        passive[best] = 1
        while True:
            p = 0
            for j in range(n):
                if passive[j]:
                    idx[p] = j
                    p += 1
            # G_PP = L D L^T, then L D L^T z_P = c_P
            for j in range(p):
                s = g[idx[j], idx[j]]
                for k in range(j):
                    s -= low[j, k] * low[j, k] * d[k]
                d[j] = s
                for i in range(j + 1, p):
                    s = g[idx[i], idx[j]]
                    for k in range(j):
                        s -= low[i, k] * low[j, k] * d[k]
                    low[i, j] = s / d[j]
            for i in range(p):
                s = c[idx[i]]
                for k in range(i):
                    s -= low[i, k] * y[k]
                y[i] = s
            for j in range(n):
                z[j] = 0.0
            for i in range(p - 1, -1, -1):
                s = y[i] / d[i]
                for k in range(i + 1, p):
                    s -= low[k, i] * z[idx[k]]
                z[idx[i]] = s
            done = True
            alpha = 1.0
            for k in range(p):
                j = idx[k]
                if z[j] <= 0.0:
                    done = False
                    # the step toward z that keeps x >= 0 (a variable at zero that z takes below: none)
                    t = x[j] / (x[j] - z[j]) if x[j] > z[j] else 0.0
                    if t < alpha:
                        alpha = t
            if done:
                for j in range(n):
                    x[j] = z[j]
                break
            for j in range(n):
                x[j] = x[j] + alpha * (z[j] - x[j])
                if passive[j] and not x[j] > 1e-12:
                    passive[j] = 0
                if not passive[j]:
                    x[j] = 0.0
        for i in range(n):  # w = c - G x
            s = c[i]
            for j in range(n):
                s -= g[i, j] * x[j]
            w[i] = s


class Buffers:
    """The arrays of :func:`distribute_into` for ``k`` contacts, made once (a tick allocates none)."""

    def __init__(self, k: int) -> None:
        n = 2 * k
        self.contacts, self.wrench, self.forces = np.zeros((k, 3)), np.zeros(4), np.zeros((k, 3))
        self.gram, self.rows, self.work, self.low = np.zeros((n, n)), np.zeros((4, n)), np.zeros((6, n)), np.zeros((n, n))
        self.flags = np.zeros((2, n), dtype=np.intc)


def distribute(wrench: np.ndarray, contacts: np.ndarray, friction: float, min_n: float) -> np.ndarray:
    """Forces (k, 3) at ``contacts`` (k, 3; relative to the CoM) that best give ``wrench``
    (fx, fz, mx, my): each ``min_n`` upward plus non-negative loads on the edges (+-friction, 1)
    of its fore-aft friction pyramid, each edge's load regularised at ``FOOT_COST``."""
    k = contacts.shape[0]
    n = 2 * k
    forces = np.zeros((k, 3))
    distribute_into(np.ascontiguousarray(wrench, dtype=np.float64), np.ascontiguousarray(contacts, dtype=np.float64),
                friction, min_n, np.zeros((n, n)), np.zeros((4, n)), np.zeros((6, n)), np.zeros((n, n)),
                np.zeros((2, n), dtype=np.intc), forces)
    return forces


@cython.ccall
@cython.boundscheck(False)
@cython.wraparound(False)
def distribute_into(wrench: cython.double[::1], contacts: cython.double[:, ::1], friction: cython.double, min_n: cython.double,
                gram: cython.double[:, ::1], rows: cython.double[:, ::1], work: cython.double[:, ::1],
                low: cython.double[:, ::1], flags: cython.int[:, ::1], forces: cython.double[:, ::1]) -> cython.void:
    """:func:`distribute` into arrays made once (:class:`Buffers`), over scalars: the wrench rows of the pyramid edges (weighted), their
    normal equations with the edges' regularisation, solved by :func:`nnls` (``work`` rows: its
    four, then the right-hand side c and the edges' loads)."""
    wfx: cython.double = ROW_WEIGHT_FX
    wfz: cython.double = ROW_WEIGHT_FZ
    wmx: cython.double = ROW_WEIGHT_MX
    wmy: cython.double = ROW_WEIGHT_MY
    cost: cython.double = FOOT_COST
    c: cython.double[::1] = work[4]
    lam: cython.double[::1] = work[5]
    k: cython.Py_ssize_t = contacts.shape[0]
    n: cython.Py_ssize_t = 2 * k
    i: cython.Py_ssize_t
    j: cython.Py_ssize_t
    r: cython.Py_ssize_t
    e: cython.Py_ssize_t
    fx: cython.double
    s: cython.double
    rx: cython.double
    ry: cython.double
    rz: cython.double
    base0: cython.double = 0.0
    base1: cython.double = 0.0
    base2: cython.double = 0.0
    base3: cython.double = 0.0
    rhs0: cython.double
    rhs1: cython.double
    rhs2: cython.double
    rhs3: cython.double
    for i in range(k):
        rx, ry, rz = contacts[i, 0], contacts[i, 1], contacts[i, 2]
        for e in range(2):
            fx = friction if e == 0 else -friction
            # the edge (fx, 0, 1): its force and its moment about the CoM, r x f
            rows[0, 2 * i + e] = wfx * fx
            rows[1, 2 * i + e] = wfz * 1.0
            rows[2, 2 * i + e] = wmx * (ry * 1.0 - rz * 0.0)
            rows[3, 2 * i + e] = wmy * (rz * fx - rx * 1.0)
        base1 += min_n  # each contact's minimum load, upward, and its moment
        base2 += ry * min_n - rz * 0.0
        base3 += rz * 0.0 - rx * min_n
    rhs0 = wfx * (wrench[0] - base0)
    rhs1 = wfz * (wrench[1] - base1)
    rhs2 = wmx * (wrench[2] - base2)
    rhs3 = wmy * (wrench[3] - base3)
    for i in range(n):
        for j in range(n):
            s = 0.0
            for r in range(4):
                s += rows[r, i] * rows[r, j]
            gram[i, j] = s + (cost if i == j else 0.0)
        c[i] = rows[0, i] * rhs0 + rows[1, i] * rhs1 + rows[2, i] * rhs2 + rows[3, i] * rhs3
    for i in range(n):
        lam[i] = 0.0
    _nnls(gram, c, 60, lam, work, low, flags)
    for i in range(k):
        forces[i, 0] = lam[2 * i] * friction - lam[2 * i + 1] * friction
        forces[i, 2] = min_n + lam[2 * i] + lam[2 * i + 1]
