"""The distribution of the stance legs' wrench over the soles (controller/distribution.py): its solver and its distribution."""

import numpy as np
import pytest
from scipy.optimize import nnls as reference_nnls

from controller.distribution import distribute, nnls


@pytest.mark.parametrize("seed", range(40))
def test_nnls_finds_scipys_optimum(seed):
    """From the normal equations of a full-rank A (as the distribution's, whose regularisation
    makes it so), the optimum scipy finds from A itself."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 9))
    a = rng.normal(size=(int(rng.integers(n, 13)), n))
    b = rng.normal(size=len(a))
    x = nnls(a.T @ a, a.T @ b)
    want, _ = reference_nnls(a, b)
    assert (x >= 0.0).all()
    assert np.linalg.norm(a @ x - b) == pytest.approx(np.linalg.norm(a @ want - b), rel=1e-9, abs=1e-12)


def _wrench_of(forces, contacts):
    """(fx, fz, mx, my) the contact forces give about the CoM."""
    moments = np.cross(contacts, forces).sum(axis=0)
    total = forces.sum(axis=0)
    return np.array([total[0], total[2], moments[0], moments[1]])


TWO_SOLES = np.array([[0.05, 0.10 + s * 0.045, -0.9] for s in (1.0, -1.0)] + [[-0.05, -0.10 + s * 0.045, -0.9] for s in (1.0, -1.0)])


def test_a_wrench_the_soles_can_give_is_given_with_every_load_within_its_pyramid():
    wrench = np.array([30.0, 700.0, 5.0, -10.0])
    forces = distribute(wrench, TWO_SOLES, friction=0.25, min_n=8.0)
    # the fit is exact but for the edges' regularisation (FOOT_COST), weighed against the rows
    assert _wrench_of(forces, TWO_SOLES) == pytest.approx(wrench, abs=5.0)
    assert (forces[:, 1] == 0.0).all()  # fore-aft pyramids: no sideways force
    assert (forces[:, 2] >= 8.0 - 1e-9).all()  # every foot contact carries its minimum and pushes
    assert (np.abs(forces[:, 0]) <= 0.25 * (forces[:, 2] - 8.0) + 1e-9).all()


def test_a_pull_is_not_asked_of_the_floor():
    # the wrench asks the feet to pull the body down: they give their minimum loads and no less
    forces = distribute(np.array([0.0, -200.0, 0.0, 0.0]), TWO_SOLES, friction=0.25, min_n=8.0)
    assert forces[:, 2] == pytest.approx(np.full(4, 8.0))


def test_a_pitch_moment_beyond_the_soles_loads_the_front_and_leaves_the_rear_its_minimum():
    # nose down far more than the feet 0.1 m apart can give: the rear contacts keep their minimum
    # (a foot cannot pull), and the front ones carry the rest, short of the moment asked
    wrench = np.array([0.0, 700.0, 0.0, -400.0])
    forces = distribute(wrench, TWO_SOLES, friction=0.25, min_n=8.0)
    rear = TWO_SOLES[:, 0] < 0.0
    assert forces[rear, 2] == pytest.approx(np.full(2, 8.0), abs=1e-6)
    got = _wrench_of(forces, TWO_SOLES)
    assert -400.0 < got[3] < 0.0 and got[1] > 700.0 - 1.0
