"""Quasi-static whole-body balance by contact-force distribution (pure: no I/O; compiled:
protocol/compiled.py).

A desired wrench at the centre of mass is distributed over the loaded contacts: feet act at their
ankle pins (a passive pitch ankle transmits force but no moment about its axis; the caller gives
each foot two contacts across the sole, so the sole carries a roll moment), stick tips at the
tip. Each contact force lies in a linearised friction cone (non-negative combinations of four
pyramid edges) above a minimum normal load, so a contact can push but never pull. A stick is a
strut: its force lies in a narrow pyramid about the line from its tip to the shoulder, so the
arm carries it along its length. The distribution is a non-negative least-squares fit; when the
CoM lies outside the support polygon no admissible distribution produces the wrench and the
residual says so: that is how the HHEA falls.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cython
import numpy as np
from scipy.optimize import nnls as _scipy_nnls

from sim.linalg import cross3, norm3


def nnls(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ||a x - b|| subject to x >= 0 (SciPy's Lawson-Hanson active-set solver)."""
    return _scipy_nnls(a, b, maxiter=10 * a.shape[1])[0]


@dataclass(frozen=True)
class Contact:
    """A support point: ``link`` is the joint index of its link, ``point`` its world position.

    ``axis`` (a unit vector, the direction the contact pushes the body along) makes it a strut:
    its force lies in a pyramid of half-width ``spread`` about the axis instead of the friction
    pyramid about the vertical."""

    name: str
    link: int
    point: np.ndarray
    cost: float  # relative effort of loading it (arms cost more than legs)
    lateral: bool = True  # False: no force across the walking direction (a leg without frontal-plane joints)
    axis: np.ndarray | None = None
    spread: float = 0.0
    min_n: float | None = None  # its own minimum normal load (default: the distribution's)


@functools.lru_cache(maxsize=16)
def pyramid_edges(mu: float, lateral: bool = True) -> np.ndarray:
    """(4, 3) unit-normal-load edges of a friction pyramid with coefficient ``mu``; without
    ``lateral`` the pyramid is flattened to the x-z plane. Constant for its arguments: one
    read-only array per (mu, lateral)."""
    mu_y = mu if lateral else 0.0
    edges = np.array([[mu, 0, 1], [-mu, 0, 1], [0, mu_y, 1], [0, -mu_y, 1]], dtype=float)
    edges.flags.writeable = False
    return edges


def strut_edges(axis: np.ndarray, spread: float) -> np.ndarray:
    """(4, 3) edges of a pyramid of half-width ``spread`` about ``axis`` (pointing up), each scaled
    to a unit vertical component like :func:`pyramid_edges`, so an edge's amount is its load.

    In plain floats (a handful of 3-vectors, where numpy's per-call cost dominates), with the
    arithmetic of the numpy expressions: ``across = a x up / |a x up|``, ``up = across x a``, the
    edges ``a + spread across``, ``a - spread across`` (the same as ``a + (-spread) across``),
    ``a +- spread up``, each divided by its z."""
    a = np.asarray(axis, dtype=float)
    a = (a / np.linalg.norm(a)).tolist()
    across = cross3(a, (0.0, 0.0, 1.0))
    norm = norm3(across)
    across = tuple(c / norm for c in across) if norm > 1e-9 else (1.0, 0.0, 0.0)
    up = cross3(across, a)
    ax, ay, az = a
    edges = []
    for dx, dy, dz in (across, up):
        for s in (spread, -spread):
            x, y, z = ax + s * dx, ay + s * dy, az + s * dz
            edges.append((x / z, y / z, z / z))
    return np.array(edges)


@functools.lru_cache(maxsize=64)
def _stacked_edges(mu: float, laterals: tuple[bool, ...]) -> np.ndarray:
    """(k, 4, 3) friction-pyramid edges of k contacts, read-only (a handful of combinations occur)."""
    edges = np.stack([pyramid_edges(mu, lateral) for lateral in laterals])
    edges.flags.writeable = False
    return edges


def distribute(
    wrench: np.ndarray,
    com: np.ndarray,
    contacts: Sequence[Contact],
    *,
    mu: float,
    min_normal_n: float,
    weights: np.ndarray,
    known_moment: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Contact forces (k, 3) that best produce ``wrench`` = (force, moment about the CoM).

    ``known_moment`` is a moment the body receives anyway (the passive ankle springs), which the
    contact forces need not supply. Returns the forces and the weighted residual norm of the fit.

    Each contact carries its minimum normal load ``f0`` plus non-negative amounts ``lam`` of its
    four pyramid edges; the least-squares system stacks the weighted wrench rows over the
    regularisation (each edge's amount at the square root of its contact's cost).
    """
    if known_moment is not None:
        wrench = wrench.copy()
        wrench[3:] -= known_moment
    k = len(contacts)
    if k == 0:
        return np.zeros((0, 3)), float(np.linalg.norm(weights * wrench))
    edges = _stacked_edges(mu, tuple(c.lateral for c in contacts))  # (k, 4, 3)
    struts = [i for i, c in enumerate(contacts) if c.axis is not None]
    if struts:
        edges = edges.copy()
        for i in struts:
            edges[i] = strut_edges(contacts[i].axis, contacts[i].spread)
    flat = np.array(edges.reshape(-1, 3))  # (4k, 3), writable (the cached pyramids are not): a typed buffer
    r = np.ascontiguousarray(np.array([c.point for c in contacts]) - com, dtype=np.float64)  # (k, 3)
    n = 4 * k
    # the minimum loads: min_normal_n along each contact's base direction (vertical, or its strut's
    # axis scaled to a unit vertical component)
    f0 = np.zeros((k, 3))
    for i, c in enumerate(contacts):
        load = min_normal_n if c.min_n is None else c.min_n
        if c.axis is None:
            f0[i, 2] = load * 1.0
        else:
            f0[i] = load * (c.axis / c.axis[2])
    lhs, rhs = np.zeros((6 + n, n)), np.zeros(6 + n)
    _system(flat, r, np.ascontiguousarray(weights, dtype=np.float64), np.array([math.sqrt(c.cost) for c in contacts]),
            f0, np.ascontiguousarray(wrench, dtype=np.float64), lhs, rhs)
    lam = nnls(lhs, rhs)
    forces = np.empty((k, 3))
    _forces(lam, flat, f0, forces)
    miss = lhs[:6] @ lam - rhs[:6]
    residual = math.sqrt(miss.dot(miss))  # np.linalg.norm(miss), without its argument handling
    return forces, residual


@dataclass(frozen=True)
class WrenchGains:
    """Spring-damper of the CoM and trunk posture, as in the balance controllers of legged robots."""

    fore_aft_n_m: float = 1500.0
    fore_aft_ns_m: float = 500.0
    lateral_n_m: float = 1000.0
    lateral_ns_m: float = 400.0
    height_n_m: float = 3000.0
    height_ns_m: float = 600.0
    tilt_nm_rad: float = 1500.0
    tilt_nms_rad: float = 150.0
    yaw_nms_rad: float = 50.0


def desired_wrench(
    mass_kg: float,
    com: np.ndarray,
    com_velocity: np.ndarray,
    com_target_xy: np.ndarray,
    hip_height: float,
    hip_height_target: float,
    hip_vz: float,
    trunk_rpy: np.ndarray,
    trunk_rate: np.ndarray,
    trunk_target_rp: np.ndarray,
    gains: WrenchGains,
    gravity: float = 9.81,
) -> np.ndarray:
    """(6,) force and moment about the CoM that pull the HHEA toward its CoM and posture targets."""
    g = gains
    return np.array([
        # the force
        g.fore_aft_n_m * (com_target_xy[0] - com[0]) - g.fore_aft_ns_m * com_velocity[0],
        g.lateral_n_m * (com_target_xy[1] - com[1]) - g.lateral_ns_m * com_velocity[1],
        mass_kg * gravity + g.height_n_m * (hip_height_target - hip_height) - g.height_ns_m * hip_vz,
        # the moment
        g.tilt_nm_rad * (trunk_target_rp[0] - trunk_rpy[0]) - g.tilt_nms_rad * trunk_rate[0],
        g.tilt_nm_rad * (trunk_target_rp[1] - trunk_rpy[1]) - g.tilt_nms_rad * trunk_rate[1],
        -g.yaw_nms_rad * trunk_rate[2],
    ])


@cython.cfunc
@cython.boundscheck(False)
@cython.wraparound(False)
@cython.locals(k=cython.Py_ssize_t, c=cython.Py_ssize_t, e=cython.Py_ssize_t, j=cython.Py_ssize_t, r0=cython.double, r1=cython.double, r2=cython.double, f0x=cython.double,
               f0y=cython.double, f0z=cython.double, fx=cython.double, fy=cython.double, fz=cython.double,
               b0=cython.double, b1=cython.double, b2=cython.double, b3=cython.double, b4=cython.double,
               b5=cython.double)
def _system(flat: cython.double[:, ::1], r: cython.double[:, ::1], weights: cython.double[::1], root_costs: cython.double[::1],
            f0: cython.double[:, ::1], wrench: cython.double[::1], lhs: cython.double[:, ::1], rhs: cython.double[::1]) -> cython.void:
    """:func:`distribute`'s least-squares system over scalars: the weighted wrench rows of every
    edge (its force, its moment about the CoM r x f), the edges' regularisation, and the wrench less
    what the minimum loads give; numpy's arithmetic (its cross product's products and differences,
    its sums from the first row on)."""
    k = r.shape[0]
    for c in range(k):
        r0, r1, r2 = r[c, 0], r[c, 1], r[c, 2]
        for e in range(4):
            j = 4 * c + e
            fx, fy, fz = flat[j, 0], flat[j, 1], flat[j, 2]
            lhs[0, j], lhs[1, j], lhs[2, j] = fx * weights[0], fy * weights[1], fz * weights[2]
            lhs[3, j] = (r1 * fz - r2 * fy) * weights[3]
            lhs[4, j] = (r2 * fx - r0 * fz) * weights[4]
            lhs[5, j] = (r0 * fy - r1 * fx) * weights[5]
            lhs[6 + j, j] = root_costs[c]
        f0x, f0y, f0z = f0[c, 0], f0[c, 1], f0[c, 2]
        if c == 0:
            b0, b1, b2 = f0x, f0y, f0z
            b3, b4, b5 = r1 * f0z - r2 * f0y, r2 * f0x - r0 * f0z, r0 * f0y - r1 * f0x
        else:
            b0, b1, b2 = b0 + f0x, b1 + f0y, b2 + f0z
            b3, b4, b5 = b3 + (r1 * f0z - r2 * f0y), b4 + (r2 * f0x - r0 * f0z), b5 + (r0 * f0y - r1 * f0x)
    rhs[0], rhs[1], rhs[2] = weights[0] * (wrench[0] - b0), weights[1] * (wrench[1] - b1), weights[2] * (wrench[2] - b2)
    rhs[3], rhs[4], rhs[5] = weights[3] * (wrench[3] - b3), weights[4] * (wrench[4] - b4), weights[5] * (wrench[5] - b5)


@cython.cfunc
@cython.boundscheck(False)
@cython.wraparound(False)
@cython.locals(k=cython.Py_ssize_t, c=cython.Py_ssize_t, d=cython.Py_ssize_t, s=cython.double)
def _forces(lam: cython.double[::1], flat: cython.double[:, ::1], f0: cython.double[:, ::1], forces: cython.double[:, ::1]) -> cython.void:
    """Each contact's force: its edges' loads times the edges, summed in order, plus its minimum load."""
    k = f0.shape[0]
    for c in range(k):
        for d in range(3):
            s = lam[4 * c] * flat[4 * c, d]
            s += lam[4 * c + 1] * flat[4 * c + 1, d]
            s += lam[4 * c + 2] * flat[4 * c + 2, d]
            s += lam[4 * c + 3] * flat[4 * c + 3, d]
            forces[c, d] = s + f0[c, d]
