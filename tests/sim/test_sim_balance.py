"""Contact-force distribution: NNLS against brute force, and the physics it must respect."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.balance import Contact, distribute, nnls, pyramid_edges


@given(st.integers(0, 10_000))
@settings(max_examples=60)
def test_nnls_is_optimal(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(12, 8))
    b = rng.normal(size=12)
    x = nnls(a, b)
    assert np.all(x >= 0)
    # KKT: gradient non-negative everywhere, zero on the positive entries.
    grad = a.T @ (a @ x - b)
    assert np.all(grad >= -1e-8)
    assert np.allclose(grad[x > 1e-9], 0.0, atol=1e-8)


def _stance(com_x: float) -> tuple[np.ndarray, list[Contact]]:
    com = np.array([com_x, 0.0, 0.9])
    contacts = [
        Contact("foot_l", 2, np.array([0.0, 0.1, 0.07]), 1e-4),
        Contact("foot_r", 5, np.array([0.0, -0.1, 0.07]), 1e-4),
        Contact("tip_l", 8, np.array([0.35, 0.3, 0.0]), 4e-4),
        Contact("tip_r", 11, np.array([0.35, -0.3, 0.0]), 4e-4),
    ]
    return com, contacts


def test_standing_weight_is_carried_and_the_forces_stay_in_their_cones():
    com, contacts = _stance(0.08)
    weight = np.array([0.0, 0.0, 900.0, 0.0, 0.0, 0.0])
    forces, residual = distribute(weight, com, contacts, mu=0.5, min_normal_n=10.0, weights=np.ones(6))
    assert residual < 1.0
    assert forces.sum(axis=0) == pytest.approx([0.0, 0.0, 900.0], abs=1.0)
    assert np.all(forces[:, 2] >= 10.0 - 1e-9)
    assert np.all(np.abs(forces[:, :2]).max(axis=1) <= 0.5 * forces[:, 2] + 1e-9)
    # The CoM sits ahead of the ankles: the sticks take a share by the lever rule.
    assert forces[2:, 2].sum() == pytest.approx(900.0 * 0.08 / 0.35, rel=0.05)


def test_a_com_behind_the_ankles_cannot_be_held_by_sticks_that_only_push():
    com, contacts = _stance(-0.05)
    weight = np.array([0.0, 0.0, 900.0, 0.0, 0.0, 0.0])
    _, residual = distribute(weight, com, contacts, mu=0.5, min_normal_n=10.0, weights=np.ones(6))
    assert residual > 20.0


def test_pyramid_edges():
    edges = pyramid_edges(0.5)
    assert edges.shape == (4, 3) and np.all(edges[:, 2] == 1.0)


def test_feet_without_frontal_joints_leave_the_lateral_force_to_the_sticks():
    com, contacts = _stance(0.08)
    contacts = [Contact(c.name, c.link, c.point, c.cost, lateral=not c.name.startswith("foot")) for c in contacts]
    push = np.array([0.0, 60.0, 900.0, 0.0, 0.0, 0.0])  # a sideways push on the CoM
    forces, residual = distribute(push, com, contacts, mu=0.5, min_normal_n=10.0, weights=np.ones(6))
    assert np.all(forces[:2, 1] == 0.0)
    assert forces[2:, 1].sum() == pytest.approx(60.0, abs=2.0)
    assert np.all(np.abs(forces[2:, 1]) <= 0.5 * forces[2:, 2] + 1e-9)
    assert pyramid_edges(0.5, lateral=False)[:, 1].tolist() == [0.0] * 4
