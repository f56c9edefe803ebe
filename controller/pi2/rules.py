"""PI²'s costs and update rules (paper equations (10), (11); Theodorou et al. 2010; PI^BB, Stulp
and Sigaud) and the learner's validated settings, as pure functions of arrays."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.arrays import float_array


class LearnerError(ValueError):
    """Invalid input to the learner or to one of its numerical functions."""


def check_h(h: float) -> float:
    try:
        hf = float(h)
    except (TypeError, ValueError):
        raise LearnerError(f"h must be a number, got {h!r}") from None
    if not (math.isfinite(hf) and hf > 0.0):
        raise LearnerError(f"h must be finite and > 0, got {h!r}")
    return hf


def _column_weights(S: np.ndarray, h: float) -> np.ndarray:
    """Min-max normalised exponentiated weights of each column of ``S`` (shape (K, N)) -> (K, N).

    Non-finite entries get weight 0 when the column holds a finite one; an all-non-finite column
    gets uniform weights. Values are halved before differencing so that no subtraction overflows.
    """
    finite = np.isfinite(S)
    if finite.all():
        half = 0.5 * S
        lo = half.min(axis=0)
        span = half.max(axis=0) - lo
        x = (half - lo) / np.where(span > 0.0, span, 1.0)
        e = np.exp(-h * x)
    else:
        half = np.where(finite, 0.5 * S, 0.0)
        lo = np.where(finite, half, np.inf).min(axis=0)
        hi = np.where(finite, half, -np.inf).max(axis=0)
        any_finite = finite.any(axis=0)
        lo = np.where(any_finite, lo, 0.0)
        span = np.where(any_finite, hi - lo, 0.0)
        x = (half - lo) / np.where(span > 0.0, span, 1.0)
        e = np.where(finite, np.exp(-h * np.where(finite, x, 0.0)), 0.0)
        e[:, ~any_finite] = 1.0
    # The minimum of every column contributes exp(0) = 1: the sum is >= 1, never 0.
    return e / e.sum(axis=0)


def costs_to_weights(costs: Any, h: float = 10.0) -> np.ndarray:
    """Weights of roll-outs from their costs: min-max normalised exponentiation (dmpbbo's rule).

    ``P_k = exp(-h (J_k - min J) / (max J - min J))``, normalised to sum 1.

    Parameters
    ----------
    costs : array_like, shape (K,)
        One cost per roll-out, ``K >= 1``.
    h : float
        Sharpness, finite and > 0 (10 in the paper and in dmpbbo).

    Returns
    -------
    numpy.ndarray, shape (K,)
        Weights in [0, 1] summing to 1. Equal costs give uniform weights. A non-finite cost
        (NaN, +inf or -inf alike: it is treated as invalid, not as extreme) gets weight 0 when at
        least one finite cost exists, and the finite costs share the weight among themselves; when
        no cost is finite the weights are uniform. The result never contains NaN.

    Examples
    --------
    >>> costs_to_weights([1, 2, 3, 4]).round(6).tolist()
    [0.964328, 0.034401, 0.001227, 4.4e-05]
    """
    c = float_array(costs, "costs", LearnerError, ndim=1, finite=False)
    if c.size == 0:
        raise LearnerError("costs must hold at least one roll-out")
    return _column_weights(c[:, None], check_h(h))[:, 0]


def cost_to_go(step_costs: Any, terminal: Any) -> np.ndarray:
    """Cost-to-go of every roll-out from every step: ``S(k, i) = terminal_k + sum_{j >= i} q_{k,j}``.

    Parameters
    ----------
    step_costs : array_like, shape (K, N)
        Immediate cost of step ``i`` of roll-out ``k`` (0 for steps not completed).
    terminal : array_like, shape (K,)
        Terminal cost of each roll-out (the fall term ``lambda1 (N - m) / N``).

    Returns
    -------
    numpy.ndarray, shape (K, N)
        The terminal cost is added to every step's cost-to-go. Non-finite inputs propagate
        (NaN or inf) to the entries that sum them; :func:`costs_to_weights` gives those weight 0.
    """
    q = float_array(step_costs, "step_costs", LearnerError, ndim=2, finite=False)
    phi = float_array(terminal, "terminal", LearnerError, ndim=1, finite=False)
    if q.shape[0] != phi.shape[0]:
        raise LearnerError(f"step_costs has {q.shape[0]} roll-outs but terminal has {phi.shape[0]}")
    if q.shape[1] == 0:
        raise LearnerError("step_costs must hold at least one step")
    with np.errstate(over="ignore", invalid="ignore"):  # overflow gives inf/NaN, handled downstream
        return np.cumsum(q[:, ::-1], axis=1)[:, ::-1] + phi[:, None]


def pi2_update(eps: Any, step_costs: Any, terminal: Any, h: float = 10.0) -> np.ndarray:
    """One PI² parameter update for parameters held constant over each roll-out.

    Parameters
    ----------
    eps : array_like, shape (K, p)
        Exploration noise actually used by each roll-out (finite).
    step_costs : array_like, shape (K, N)
        Immediate cost of each step (0 for steps not completed).
    terminal : array_like, shape (K,)
        Terminal cost of each roll-out.
    h : float
        Sharpness of the per-step min-max normalised exponentiation (finite, > 0).

    Returns
    -------
    numpy.ndarray, shape (p,)
        ``dtheta = sum_i (N - i) sum_k P(i, k) eps_k / sum_i (N - i)``, ``i = 0 .. N-1``, with
        ``P(., i) = costs_to_weights(S(., i), h)``. It is a convex combination of the ``eps_k``:
        non-finite costs get weight 0 (see :func:`costs_to_weights`), so it is always finite.
    """
    e = float_array(eps, "eps", LearnerError, ndim=2, finite=False)
    S = cost_to_go(step_costs, terminal)
    K, N = S.shape
    if e.shape[0] != K:
        raise LearnerError(f"eps has {e.shape[0]} roll-outs but step_costs has {K}")
    if not np.isfinite(e).all():
        raise LearnerError("eps must be finite")
    P = _column_weights(S, check_h(h))  # (K, N)
    time_w = np.arange(N, 0, -1, dtype=float)  # N - i for i = 0 .. N-1
    rollout_w = P @ time_w / time_w.sum()  # (K,), sums to 1
    return rollout_w @ e


def effective_weights(step_costs: np.ndarray, terminal: np.ndarray, h: float) -> np.ndarray:
    """Weight each roll-out's eps receives in :func:`pi2_update` after time averaging, shape (K,)."""
    P = _column_weights(cost_to_go(step_costs, terminal), h)
    time_w = np.arange(P.shape[1], 0, -1, dtype=float)
    return P @ time_w / time_w.sum()


def pibb_update(thetas: Any, costs: Any, h: float = 10.0) -> np.ndarray:
    """One PI^BB update: the cost-weighted mean of the roll-outs' parameters.

    Parameters
    ----------
    thetas : array_like, shape (K, p)
        Parameters actually used by each roll-out (finite).
    costs : array_like, shape (K,)
        Total cost of each roll-out.
    h : float
        Sharpness (finite, > 0).

    Returns
    -------
    numpy.ndarray, shape (p,)
        ``sum_k P_k theta_k`` with ``P = costs_to_weights(costs, h)``.
    """
    t = float_array(thetas, "thetas", LearnerError, ndim=2, finite=False)
    c = float_array(costs, "costs", LearnerError, ndim=1, finite=False)
    if t.shape[0] != c.shape[0] or c.size == 0:
        raise LearnerError(f"thetas has {t.shape[0]} roll-outs but costs has {c.shape[0]}")
    if not np.isfinite(t).all():
        raise LearnerError("thetas must be finite")
    return costs_to_weights(c, h) @ t


def rollout_cost(step_forces: Any, steps_completed: int, N: int, lambda1: float, lambda2: float) -> float:
    """Roll-out cost of paper equation (11): ``lambda1 (N - m) / N + lambda2 sum_{i < m} r_i``.

    Parameters
    ----------
    step_forces : array_like, shape (n,), ``m <= n <= N``
        Immediate cost ``r_i`` (mean stick force) of each step; entries from index ``m`` on belong
        to steps not completed and are ignored (they may be NaN).
    steps_completed : int
        ``m``, the steps walked before the fall (``N`` without a fall), ``0 <= m <= N``.
    N : int
        Steps per roll-out, ``N >= 1``.
    lambda1, lambda2 : float
        Weights of the fall term and of the force term (finite, >= 0).

    Returns
    -------
    float
        The roll-out cost. Raises :class:`LearnerError` if a completed step's cost is not finite.
    """
    if isinstance(N, bool) or not isinstance(N, (int, np.integer)) or N < 1:
        raise LearnerError(f"N must be an integer >= 1, got {N!r}")
    m = steps_completed
    if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 0 <= m <= N:
        raise LearnerError(f"steps_completed must be an integer in [0, {N}], got {m!r}")
    for name, lam in (("lambda1", lambda1), ("lambda2", lambda2)):
        if not (isinstance(lam, (int, float, np.floating, np.integer)) and math.isfinite(lam) and lam >= 0):
            raise LearnerError(f"{name} must be finite and >= 0, got {lam!r}")
    r = float_array(step_forces, "step_forces", LearnerError, ndim=1, finite=False)
    if not m <= r.size <= N:
        raise LearnerError(f"step_forces must hold between {m} and {N} steps, got {r.size}")
    done = r[:m]
    if not np.isfinite(done).all():
        raise LearnerError("step_forces of completed steps must be finite")
    return float(lambda1 * (N - m) / N + lambda2 * done.sum())


# ---------------------------------------------------------------------------------------------
# Parameters and records
# ---------------------------------------------------------------------------------------------


def float_tuple(x: Any, name: str) -> tuple[float, ...]:
    try:
        t = tuple(float(v) for v in x)
    except (TypeError, ValueError):
        raise LearnerError(f"{name} must be a sequence of numbers, got {x!r}") from None
    if not t or not all(math.isfinite(v) for v in t):
        raise LearnerError(f"{name} must be a non-empty sequence of finite numbers, got {x!r}")
    return t


def is_int(x: Any) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


@dataclass(frozen=True)
class Pi2Params:
    """Settings of the learner (validated on construction; sequences are stored as tuples).

    ``p`` (the number of parameters) is ``len(noise_std)``; ``lower`` and ``upper`` have the same
    length. The exploration noise of a batch is ``noise_std * max(noise_decay ** n_updates,
    noise_floor)`` where ``n_updates`` counts the accepted updates so far.

    Costs are in the units of ``r`` (mean stick force per step). ``lambda1`` is the cost of a fall
    at the very first step; it should exceed the force cost of the steps a fall saves (about N times
    a typical step cost), or falling pays. It should not be far larger: the weights are min-max
    normalised, so one fallen roll-out with a huge cost squeezes the others' costs together and
    their weights towards uniform, and that batch makes little progress.

    No field has a default: the controller's come from its configuration
    (``controller.learning``, :func:`controller.factory.pi2_params`), a test's from the test.
    """

    rollouts_per_update: int  # K
    steps_per_rollout: int  # N
    h: float
    noise_std: tuple[float, ...]  # (sigma_alpha, sigma_xhat) at the start
    noise_decay: float  # factor per accepted update
    noise_floor: float  # fraction of noise_std kept at the end
    lower: tuple[float, ...]  # (alpha_min, xhat_min)
    upper: tuple[float, ...]  # (alpha_max, xhat_max)
    method: str  # "pi2" | "pibb"
    lambda1: float
    lambda2: float
    reuse_best: int  # best roll-outs of a batch carried into the next one
    max_consecutive_rejections: int  # rejected updates in a row that disable learning (F28)
    average_last: int  # evaluation theta: mean of the last M accepted updates (Polyak-Ruppert)

    def __post_init__(self) -> None:
        for name in ("noise_std", "lower", "upper"):
            object.__setattr__(self, name, float_tuple(getattr(self, name), name))
        for name in ("h", "noise_decay", "noise_floor", "lambda1", "lambda2"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise LearnerError(f"{name} must be a number, got {v!r}")
            object.__setattr__(self, name, float(v))
        K, N = self.rollouts_per_update, self.steps_per_rollout
        if not is_int(K) or K < 2:
            raise LearnerError(f"rollouts_per_update must be an integer >= 2, got {K!r}")
        if not is_int(N) or N < 1:
            raise LearnerError(f"steps_per_rollout must be an integer >= 1, got {N!r}")
        object.__setattr__(self, "rollouts_per_update", int(K))
        object.__setattr__(self, "steps_per_rollout", int(N))
        check_h(self.h)
        p = len(self.noise_std)
        if len(self.lower) != p or len(self.upper) != p:
            lengths = f"{p}, {len(self.lower)}, {len(self.upper)}"
            raise LearnerError(f"noise_std, lower and upper need the same length, got {lengths}")
        if not all(s > 0 for s in self.noise_std):
            raise LearnerError(f"noise_std must be > 0, got {self.noise_std}")
        if not all(lo < hi for lo, hi in zip(self.lower, self.upper)):
            raise LearnerError(f"lower must be below upper, got {self.lower} and {self.upper}")
        if not (math.isfinite(self.noise_decay) and 0.0 < self.noise_decay <= 1.0):
            raise LearnerError(f"noise_decay must be in (0, 1], got {self.noise_decay}")
        if not (math.isfinite(self.noise_floor) and 0.0 <= self.noise_floor <= 1.0):
            raise LearnerError(f"noise_floor must be in [0, 1], got {self.noise_floor}")
        if self.method not in ("pi2", "pibb"):
            raise LearnerError(f"method must be 'pi2' or 'pibb', got {self.method!r}")
        for name in ("lambda1", "lambda2"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise LearnerError(f"{name} must be finite and >= 0, got {v}")
        if not is_int(self.reuse_best) or not 0 <= self.reuse_best < K:
            raise LearnerError(f"reuse_best must be an integer in [0, {K - 1}], got {self.reuse_best!r}")
        object.__setattr__(self, "reuse_best", int(self.reuse_best))
        mcr = self.max_consecutive_rejections
        if not is_int(mcr) or mcr < 1:
            raise LearnerError(f"max_consecutive_rejections must be an integer >= 1, got {mcr!r}")
        object.__setattr__(self, "max_consecutive_rejections", int(mcr))
        if not is_int(self.average_last) or self.average_last < 1:
            raise LearnerError(f"average_last must be an integer >= 1, got {self.average_last!r}")
        object.__setattr__(self, "average_last", int(self.average_last))

    @property
    def n_params(self) -> int:
        return len(self.noise_std)
