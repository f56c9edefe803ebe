"""PI² learning of the step-length compensation parameters (paper section III).

The learned parameters are ``theta = [alpha, Xhat_CoM]`` of the compensation
``g = g_init + alpha * (Xhat_CoM - X_CoM / X_SP)`` (see :mod:`controller.compensation`). They are
held constant over a roll-out of ``N`` steps (gait cycles); ``K`` roll-outs with
``theta + eps_k``, ``eps_k ~ N(0, diag(sigma^2))``, make one update.

Costs (paper equations (10), (11)):

- immediate cost of step ``i``: ``r_i``, the mean stick force over the step;
- roll-out cost ``R = lambda1 * (N - m) / N + lambda2 * sum_i r_i`` where the HHEA fell after ``m``
  of ``N`` steps (``m = N`` without a fall). The fall term is the terminal cost ``phi_k``.

PI² (Theodorou, Buchli, Schaal 2010, as the reference code implements it):

1. cost-to-go ``S(i, k) = phi_k + sum_{j >= i} q_{j,k}`` with ``q = lambda2 * r`` (steps not
   completed cost 0: the fall is paid through ``phi_k``);
2. ``P(i, k) = exp(-h (S(i,k) - min_l S(i,l)) / (max_l S(i,l) - min_l S(i,l)))`` normalised over
   ``k`` (uniform when ``max == min``);
3. ``dtheta_i = sum_k P(i, k) eps_k``;
4. ``dtheta = sum_i (N - i) dtheta_i / sum_i (N - i)``; ``theta <- theta + dtheta``.

PI^BB (Stulp and Sigaud, dmpbbo ``costs_to_weights``) is available as an option: one total cost
per roll-out, ``theta_new = sum_k P_k theta_k``.

The numerical core is pure: no I/O (except :meth:`Pi2Learner.save` / :meth:`Pi2Learner.load`), no
clock, no global random state (a ``numpy.random.Generator`` is injected), inputs are never mutated.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "LearnerError",
    "Pi2Learner",
    "Pi2Params",
    "Rejection",
    "UpdateRecord",
    "cost_to_go",
    "costs_to_weights",
    "pi2_update",
    "pibb_update",
    "rollout_cost",
]

STATE_FORMAT = "aider-exo.pi2"
STATE_VERSION = 1

# An update whose theta lies outside the bounds by at most this fraction of the range is rounding
# (a convex combination of in-bounds roll-outs cannot leave them) and is clipped; more is rejected.
_BOUNDS_RTOL = 1e-9


class LearnerError(ValueError):
    """Invalid input to the learner or to one of its numerical functions."""


# ---------------------------------------------------------------------------------------------
# Pure numerical functions
# ---------------------------------------------------------------------------------------------


def _as_float_array(x: Any, ndim: int, name: str) -> np.ndarray:
    try:
        a = np.asarray(x)
    except (TypeError, ValueError) as exc:
        raise LearnerError(f"{name} must be numeric: {exc}") from None
    if a.dtype.kind not in "iuf":
        raise LearnerError(f"{name} must hold numbers, got dtype {a.dtype}")
    a = a.astype(float, copy=False)
    if a.ndim != ndim:
        raise LearnerError(f"{name} must have {ndim} dimension(s), got shape {a.shape}")
    return a


def _check_h(h: float) -> float:
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
    c = _as_float_array(costs, 1, "costs")
    if c.size == 0:
        raise LearnerError("costs must hold at least one roll-out")
    return _column_weights(c[:, None], _check_h(h))[:, 0]


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
    q = _as_float_array(step_costs, 2, "step_costs")
    phi = _as_float_array(terminal, 1, "terminal")
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
    e = _as_float_array(eps, 2, "eps")
    S = cost_to_go(step_costs, terminal)
    K, N = S.shape
    if e.shape[0] != K:
        raise LearnerError(f"eps has {e.shape[0]} roll-outs but step_costs has {K}")
    if not np.isfinite(e).all():
        raise LearnerError("eps must be finite")
    P = _column_weights(S, _check_h(h))  # (K, N)
    time_w = np.arange(N, 0, -1, dtype=float)  # N - i for i = 0 .. N-1
    rollout_w = P @ time_w / time_w.sum()  # (K,), sums to 1
    return rollout_w @ e


def _effective_weights(step_costs: np.ndarray, terminal: np.ndarray, h: float) -> np.ndarray:
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
    t = _as_float_array(thetas, 2, "thetas")
    c = _as_float_array(costs, 1, "costs")
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
    r = _as_float_array(step_forces, 1, "step_forces")
    if not m <= r.size <= N:
        raise LearnerError(f"step_forces must hold between {m} and {N} steps, got {r.size}")
    done = r[:m]
    if not np.isfinite(done).all():
        raise LearnerError("step_forces of completed steps must be finite")
    return float(lambda1 * (N - m) / N + lambda2 * done.sum())


# ---------------------------------------------------------------------------------------------
# Parameters and records
# ---------------------------------------------------------------------------------------------


def _float_tuple(x: Any, name: str) -> tuple[float, ...]:
    try:
        t = tuple(float(v) for v in x)
    except (TypeError, ValueError):
        raise LearnerError(f"{name} must be a sequence of numbers, got {x!r}") from None
    if not t or not all(math.isfinite(v) for v in t):
        raise LearnerError(f"{name} must be a non-empty sequence of finite numbers, got {x!r}")
    return t


def _is_int(x: Any) -> bool:
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
            object.__setattr__(self, name, _float_tuple(getattr(self, name), name))
        for name in ("h", "noise_decay", "noise_floor", "lambda1", "lambda2"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise LearnerError(f"{name} must be a number, got {v!r}")
            object.__setattr__(self, name, float(v))
        K, N = self.rollouts_per_update, self.steps_per_rollout
        if not _is_int(K) or K < 2:
            raise LearnerError(f"rollouts_per_update must be an integer >= 2, got {K!r}")
        if not _is_int(N) or N < 1:
            raise LearnerError(f"steps_per_rollout must be an integer >= 1, got {N!r}")
        object.__setattr__(self, "rollouts_per_update", int(K))
        object.__setattr__(self, "steps_per_rollout", int(N))
        _check_h(self.h)
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
        if not _is_int(self.reuse_best) or not 0 <= self.reuse_best < K:
            raise LearnerError(f"reuse_best must be an integer in [0, {K - 1}], got {self.reuse_best!r}")
        object.__setattr__(self, "reuse_best", int(self.reuse_best))
        mcr = self.max_consecutive_rejections
        if not _is_int(mcr) or mcr < 1:
            raise LearnerError(f"max_consecutive_rejections must be an integer >= 1, got {mcr!r}")
        object.__setattr__(self, "max_consecutive_rejections", int(mcr))
        if not _is_int(self.average_last) or self.average_last < 1:
            raise LearnerError(f"average_last must be an integer >= 1, got {self.average_last!r}")
        object.__setattr__(self, "average_last", int(self.average_last))

    @property
    def n_params(self) -> int:
        return len(self.noise_std)


@dataclass(frozen=True)
class UpdateRecord:
    """One accepted update. Tuples have length p (parameters) or K (roll-outs)."""

    index: int  # 1 for the first accepted update
    theta_before: tuple[float, ...]  # (p,)
    theta: tuple[float, ...]  # (p,) after the update
    mean_cost: float  # mean roll-out cost R of the batch
    costs: tuple[float, ...]  # (K,) roll-out costs R
    weights: tuple[float, ...]  # (K,) weight of each roll-out in the update (time-averaged for PI²)
    noise: tuple[float, ...]  # (p,) exploration std of the batch
    falls: int  # roll-outs of the batch that fell


@dataclass(frozen=True)
class Rejection:
    """One rejected update: the learner kept ``theta``."""

    batch: int  # 1-based index of the batch among all attempted updates
    reason: str
    theta: tuple[float, ...]  # (p,) the theta kept


@dataclass(frozen=True)
class _Rollout:
    theta: np.ndarray  # (p,) parameters used
    eps: np.ndarray  # (p,) theta - learner theta at the time (after clipping)
    costs: tuple[float, ...]  # (m,) immediate costs r of the completed steps
    fell: bool


# ---------------------------------------------------------------------------------------------
# Learner
# ---------------------------------------------------------------------------------------------


class Pi2Learner:
    """Online PI² (or PI^BB) over roll-outs of ``N`` steps, with an ask/tell interface.

    Use in a real-time loop::

        theta = learner.ask()            # parameters for the current roll-out (same until it ends)
        ... walk one step with theta ...
        learner.tell_step(r)             # once per completed step
        record = learner.end_rollout(fell)   # after N steps, or at a fall
        if record is not None:           # an update was applied after K roll-outs
            ... one noise-free roll-out with learner.evaluation_theta() for the learning curve ...

    Behaviour:

    - ``ask()`` draws ``eps ~ N(0, diag(sigma^2))`` at the start of a roll-out and returns
      ``clip(theta + eps, lower, upper)``; the recorded eps is the clipped one actually used. Calls
      during the roll-out return the same vector. Nothing outside the bounds ever leaves.
    - ``end_rollout(fell=True)`` after ``m < N`` steps: the remaining steps are not completed and
      cost 0 each, the terminal cost ``lambda1 (N - m) / N`` applies. ``end_rollout(fell=False)``
      requires exactly N steps (use :meth:`abort_rollout` to discard an interrupted roll-out).
    - After K roll-outs the update runs (only ever between roll-outs). It is REJECTED if a step
      cost of the batch is NaN/inf (or the costs overflow when summed), or if the new theta is
      non-finite or outside the bounds (beyond rounding, which is clipped). A rejected batch is
      discarded, theta and the noise level stay, the rejection is recorded with its reason.
      After ``max_consecutive_rejections`` (3) rejections in a row learning is disabled:
      ``learning_enabled`` is False, ``ask()`` returns the last good theta without noise,
      ``tell_step``/``end_rollout`` are accepted and ignored, until :meth:`enable_learning`.
    - With ``reuse_best > 0`` the lowest-cost roll-outs of an accepted batch are carried into the
      next batch (their eps re-expressed relative to the new theta), so it needs fewer new ones.

    Parameters
    ----------
    params : Pi2Params
    theta0 : array_like, shape (p,)
        Initial parameters, inside ``[lower, upper]``.
    rng : numpy.random.Generator
        The only source of exploration noise.
    """

    def __init__(self, params: Pi2Params, theta0: Any, rng: np.random.Generator) -> None:
        if not isinstance(params, Pi2Params):
            raise LearnerError(f"params must be a Pi2Params, got {type(params).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise LearnerError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self._params = params
        self._rng = rng
        self._lower = np.array(params.lower)
        self._upper = np.array(params.upper)
        self._theta = self._checked_theta(theta0, "theta0")
        self._n_updates = 0
        self._n_batches = 0
        self._consecutive_rejections = 0
        self._learning_enabled = True
        self._batch: list[_Rollout] = []
        self._history: list[UpdateRecord] = []
        self._rejections: list[Rejection] = []
        self._current: tuple[np.ndarray, np.ndarray] | None = None  # (theta used, eps)
        self._current_costs: list[float] = []
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []  # roll-outs of ask_batch() awaiting tell_batch()

    def _checked_theta(self, theta: Any, name: str) -> np.ndarray:
        t = _as_float_array(theta, 1, name)
        if t.shape != self._lower.shape:
            raise LearnerError(f"{name} must have shape {self._lower.shape}, got {t.shape}")
        if not np.isfinite(t).all():
            raise LearnerError(f"{name} must be finite, got {t.tolist()}")
        if (t < self._lower).any() or (t > self._upper).any():
            raise LearnerError(f"{name} {t.tolist()} outside the bounds {self._params.lower} .. {self._params.upper}")
        return t.copy()

    # -- read-only views ----------------------------------------------------------------------

    @property
    def params(self) -> Pi2Params:
        return self._params

    @property
    def theta(self) -> np.ndarray:
        """Current (noise-free) parameters, shape (p,) (a copy)."""
        return self._theta.copy()

    def evaluation_theta(self) -> np.ndarray:
        """Noise-free parameters to evaluate (the learning curve) and to deploy, shape (p,).

        The mean of theta after the last ``average_last`` accepted updates (Polyak-Ruppert
        averaging): near the optimum the running theta wanders with the exploration noise, and the
        average settles closer to the optimum. Before the first update: the start theta.
        """
        recent = self._history[-self._params.average_last:]
        if not recent:
            return self._theta.copy()
        return np.clip(np.mean([r.theta for r in recent], axis=0), self._lower, self._upper)

    @property
    def noise_std(self) -> np.ndarray:
        """Exploration std of the current batch, shape (p,)."""
        p = self._params
        return np.array(p.noise_std) * max(p.noise_decay**self._n_updates, p.noise_floor)

    @property
    def history(self) -> list[UpdateRecord]:
        """Accepted updates, oldest first (a new list)."""
        return list(self._history)

    @property
    def rejections(self) -> list[Rejection]:
        """Rejected updates, oldest first (a new list)."""
        return list(self._rejections)

    @property
    def rejection_count(self) -> int:
        return len(self._rejections)

    @property
    def consecutive_rejections(self) -> int:
        return self._consecutive_rejections

    @property
    def learning_enabled(self) -> bool:
        return self._learning_enabled

    @property
    def n_updates(self) -> int:
        """Accepted updates so far."""
        return self._n_updates

    @property
    def in_rollout(self) -> bool:
        return self._current is not None

    @property
    def rollouts_in_batch(self) -> int:
        """Completed roll-outs waiting for the next update (including reused ones)."""
        return len(self._batch)

    # -- ask / tell -----------------------------------------------------------------------------

    def ask(self) -> np.ndarray:
        """Parameters for the current roll-out, shape (p,), always inside the bounds.

        Starts a roll-out (draws its noise) if none is running; otherwise returns the same vector.
        With learning disabled: the noise-free theta.
        """
        if not self._learning_enabled:
            return self._theta.copy()
        if self._current is None:
            eps = self._rng.normal(0.0, 1.0, size=self._theta.shape) * self.noise_std
            used = np.clip(self._theta + eps, self._lower, self._upper)
            self._current = (used, used - self._theta)
            self._current_costs = []
        return self._current[0].copy()

    def tell_step(self, cost: float) -> None:
        """Record the immediate cost ``r`` of one completed step of the current roll-out.

        A NaN/inf cost is recorded (not raised): it makes the batch's update rejected.
        """
        if not self._learning_enabled:
            return
        if self._current is None:
            raise LearnerError("tell_step() without a roll-out: call ask() first")
        if isinstance(cost, bool) or not isinstance(cost, (int, float, np.integer, np.floating)):
            raise LearnerError(f"step cost must be a number, got {cost!r}")
        if len(self._current_costs) >= self._params.steps_per_rollout:
            raise LearnerError(f"roll-out already has {self._params.steps_per_rollout} steps: call end_rollout()")
        self._current_costs.append(float(cost))

    def abort_rollout(self) -> None:
        """Discard the current roll-out (e.g. the walk was stopped); it never enters an update."""
        self._current = None
        self._current_costs = []

    def end_rollout(self, fell: bool) -> UpdateRecord | None:
        """End the current roll-out; after K roll-outs run the update.

        Returns
        -------
        UpdateRecord or None
            The record of the update if one was applied now (the caller then runs the noise-free
            evaluation roll-out); None otherwise (no update due, rejected, or learning disabled).
        """
        if not self._learning_enabled:
            return None
        if self._current is None:
            raise LearnerError("end_rollout() without a roll-out: call ask() first")
        if not isinstance(fell, (bool, np.bool_)):
            raise LearnerError(f"fell must be a bool, got {fell!r}")
        N = self._params.steps_per_rollout
        m = len(self._current_costs)
        if not fell and m != N:
            raise LearnerError(f"roll-out ended after {m} of {N} steps without a fall (abort_rollout() discards it)")
        used, eps = self._current
        self._batch.append(_Rollout(used, eps, tuple(self._current_costs), bool(fell)))
        self._current = None
        self._current_costs = []
        if len(self._batch) < self._params.rollouts_per_update:
            return None
        return self._update()

    def ask_batch(self) -> list[np.ndarray]:
        """Parameters of every roll-out the next update still needs (K minus the reused ones), for
        roll-outs run in parallel; each is ``ask()`` in turn, so the noise draws and the result are
        those of the same roll-outs run one after another. Report them with :meth:`tell_batch`.
        With learning disabled: an empty list."""
        if not self._learning_enabled:
            return []
        if self._current is not None:
            raise LearnerError("ask_batch() during a roll-out: end or abort it first")
        thetas = []
        for _ in range(self._params.rollouts_per_update - len(self._batch)):
            self._current = None
            thetas.append(self.ask())
            self._pending.append(self._current)
        self._current = None
        return thetas

    def tell_batch(self, rollouts: list[tuple[list[float], bool]]) -> UpdateRecord | None:
        """Results of the roll-outs of :meth:`ask_batch`, in its order: each the immediate costs of
        its completed steps and whether it fell. Runs the update as :meth:`end_rollout` does."""
        if len(rollouts) != len(self._pending):
            raise LearnerError(f"tell_batch() needs {len(self._pending)} roll-out result(s), got {len(rollouts)}")
        pending, self._pending = self._pending, []
        record = None
        for current, (costs, fell) in zip(pending, rollouts):
            self._current, self._current_costs = current, []
            for c in costs:
                self.tell_step(c)
            record = self.end_rollout(fell)
        return record

    def enable_learning(self) -> None:
        """Re-enable learning after it was disabled by rejections (resets the consecutive count)."""
        self._learning_enabled = True
        self._consecutive_rejections = 0

    # -- the update -----------------------------------------------------------------------------

    def _batch_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(thetas (K, p), eps (K, p), q = lambda2 r (K, N), phi (K,), R (K,)) of the batch."""
        p = self._params
        N = p.steps_per_rollout
        K = len(self._batch)
        r = np.zeros((K, N))
        phi = np.empty(K)
        for k, ro in enumerate(self._batch):
            r[k, : len(ro.costs)] = ro.costs
            phi[k] = p.lambda1 * (N - len(ro.costs)) / N
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is rejected by _update
            q = p.lambda2 * r
            R = phi + q.sum(axis=1)
        thetas = np.array([ro.theta for ro in self._batch])
        eps = np.array([ro.eps for ro in self._batch])
        return thetas, eps, q, phi, R

    def _reject(self, reason: str) -> None:
        self._rejections.append(Rejection(self._n_batches, reason, tuple(self._theta.tolist())))
        self._batch = []
        self._consecutive_rejections += 1
        if self._consecutive_rejections >= self._params.max_consecutive_rejections:
            self._learning_enabled = False

    def _update(self) -> UpdateRecord | None:
        p = self._params
        self._n_batches += 1
        for k, ro in enumerate(self._batch):
            for i, c in enumerate(ro.costs):
                if not math.isfinite(c):
                    self._reject(f"non-finite step cost {c} (roll-out {k + 1}, step {i + 1})")
                    return None
        thetas, eps, q, phi, R = self._batch_arrays()
        if not (np.isfinite(R).all() and np.isfinite(cost_to_go(q, phi)).all()):
            self._reject("roll-out costs overflow (step costs too large to sum)")
            return None
        if p.method == "pi2":
            weights = _effective_weights(q, phi, p.h)
            new = self._theta + pi2_update(eps, q, phi, p.h)
        else:
            weights = costs_to_weights(R, p.h)
            new = pibb_update(thetas, R, p.h)
        if not np.isfinite(new).all():
            self._reject(f"update gave a non-finite theta {new.tolist()}")
            return None
        tol = _BOUNDS_RTOL * (self._upper - self._lower)
        if (new < self._lower - tol).any() or (new > self._upper + tol).any():
            self._reject(f"update gave theta {new.tolist()} outside the bounds {p.lower} .. {p.upper}")
            return None
        new = np.clip(new, self._lower, self._upper)
        record = UpdateRecord(
            index=self._n_updates + 1,
            theta_before=tuple(self._theta.tolist()),
            theta=tuple(new.tolist()),
            mean_cost=float((R / len(R)).sum()),  # not R.mean(): finite costs near the float limit overflow their sum
            costs=tuple(R.tolist()),
            weights=tuple(weights.tolist()),
            noise=tuple(self.noise_std.tolist()),
            falls=sum(ro.fell for ro in self._batch),
        )
        keep: list[_Rollout] = []
        if p.reuse_best:
            for k in np.argsort(R, kind="stable")[: p.reuse_best]:
                ro = self._batch[k]
                keep.append(_Rollout(ro.theta, ro.theta - new, ro.costs, ro.fell))
        self._theta = new
        self._n_updates += 1
        self._consecutive_rejections = 0
        self._history.append(record)
        self._batch = keep
        return record

    # -- persistence ----------------------------------------------------------------------------

    def state_dict(self) -> dict:
        """Everything needed to resume, as JSON-ready builtins (a new dict).

        An unfinished roll-out is not included: after a restart the next ``ask()`` starts a fresh
        one. The generator's state is not included either (it is injected on restore). Non-finite
        step costs waiting in the batch are stored as the strings "nan", "inf", "-inf".
        """
        return {
            "format": STATE_FORMAT,
            "version": STATE_VERSION,
            "params": _params_to_dict(self._params),
            "theta": self._theta.tolist(),
            "n_updates": self._n_updates,
            "n_batches": self._n_batches,
            "consecutive_rejections": self._consecutive_rejections,
            "learning_enabled": self._learning_enabled,
            "batch": [
                {
                    "theta": ro.theta.tolist(),
                    "eps": ro.eps.tolist(),
                    "costs": [_enc(c) for c in ro.costs],
                    "fell": ro.fell,
                }
                for ro in self._batch
            ],
            "history": [asdict(h) for h in self._history],
            "rejections": [asdict(r) for r in self._rejections],
        }

    @classmethod
    def from_state_dict(cls, d: dict, rng: np.random.Generator) -> Pi2Learner:
        """Rebuild a learner from :meth:`state_dict` output; malformed input raises LearnerError."""
        if not isinstance(d, dict):
            raise LearnerError(f"state must be a dict, got {type(d).__name__}")
        if d.get("format") != STATE_FORMAT or d.get("version") != STATE_VERSION:
            found = f"format={d.get('format')!r} version={d.get('version')!r}"
            raise LearnerError(f"not a {STATE_FORMAT} v{STATE_VERSION} state: {found}")
        try:
            params = Pi2Params(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d["params"].items()})
            learner = cls(params, d["theta"], rng)
            n_up, n_b, cons = d["n_updates"], d["n_batches"], d["consecutive_rejections"]
            if not all(_is_int(v) and v >= 0 for v in (n_up, n_b, cons)) or n_up > n_b:
                raise LearnerError(f"bad counters n_updates={n_up!r} n_batches={n_b!r} consecutive={cons!r}")
            if not isinstance(d["learning_enabled"], bool):
                raise LearnerError("learning_enabled must be a bool")
            learner._n_updates, learner._n_batches, learner._consecutive_rejections = n_up, n_b, cons
            learner._learning_enabled = d["learning_enabled"]
            batch = []
            for ro in d["batch"]:
                theta = learner._checked_theta(ro["theta"], "batch theta")
                eps = _as_float_array(ro["eps"], 1, "batch eps")
                if eps.shape != theta.shape or not np.isfinite(eps).all():
                    raise LearnerError("batch eps must be finite with the shape of theta")
                costs = tuple(_dec(c) for c in ro["costs"])
                if not isinstance(ro["fell"], bool) or len(costs) > params.steps_per_rollout:
                    raise LearnerError("batch roll-out has a bad fall flag or too many steps")
                if not ro["fell"] and len(costs) != params.steps_per_rollout:
                    raise LearnerError("batch roll-out without a fall must have N steps")
                atol = 1e-9 * float(np.max(learner._upper - learner._lower))
                if not np.allclose(eps, theta - learner._theta, rtol=0.0, atol=atol):
                    raise LearnerError("batch eps does not match the roll-out's theta minus the learner's theta")
                batch.append(_Rollout(theta, eps, costs, ro["fell"]))
            if len(batch) >= params.rollouts_per_update:
                raise LearnerError(f"batch holds {len(batch)} roll-outs, an update was due")
            learner._batch = batch
            learner._history = [
                UpdateRecord(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in h.items()})
                for h in d["history"]
            ]
            learner._rejections = [Rejection(r["batch"], str(r["reason"]), tuple(r["theta"])) for r in d["rejections"]]
        except LearnerError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise LearnerError(f"malformed learner state: {type(exc).__name__}: {exc}") from None
        return learner

    def save(self, path: str | os.PathLike) -> None:
        """Write :meth:`state_dict` as JSON, atomically (temporary file in the same folder + os.replace)."""
        target = Path(path)
        text = json.dumps(self.state_dict(), indent=1, allow_nan=False)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, target)
        except BaseException:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            raise

    @classmethod
    def load(cls, path: str | os.PathLike, rng: np.random.Generator) -> Pi2Learner:
        """Read a learner written by :meth:`save`; unreadable or malformed files raise LearnerError."""
        try:
            d = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise LearnerError(f"cannot read learner state {path}: {exc}") from None
        return cls.from_state_dict(d, rng)


def _params_to_dict(p: Pi2Params) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(p).items()}


def _enc(x: float) -> float | str:
    return x if math.isfinite(x) else str(x)  # "nan", "inf", "-inf"


def _dec(x: Any) -> float:
    if isinstance(x, str):
        if x not in ("nan", "inf", "-inf"):
            raise LearnerError(f"bad step cost {x!r}")
        return float(x)
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise LearnerError(f"bad step cost {x!r}")
    return float(x)
