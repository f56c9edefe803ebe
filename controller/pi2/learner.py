"""The online learner: PI² (or PI^BB) over roll-outs of ``N`` steps with an ask/tell interface
(:class:`Pi2Learner`), and its records of accepted and rejected updates."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.arrays import float_array
from controller.pi2.rules import (
    LearnerError, Pi2Params, cost_to_go, costs_to_weights, effective_weights, pi2_update, pibb_update,
)

# An update whose theta lies outside the bounds by at most this fraction of the range is rounding
# (a convex combination of in-bounds roll-outs cannot leave them) and is clipped; more is rejected.
_BOUNDS_RTOL = 1e-9


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
class Rollout:
    theta: np.ndarray  # (p,) parameters used
    eps: np.ndarray  # (p,) theta - learner theta at the time (after clipping)
    costs: tuple[float, ...]  # (m,) immediate costs r of the completed steps
    fell: bool


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
        self._batch: list[Rollout] = []
        self._history: list[UpdateRecord] = []
        self._rejections: list[Rejection] = []
        self._current: tuple[np.ndarray, np.ndarray] | None = None  # (theta used, eps)
        self._current_costs: list[float] = []
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []  # roll-outs of ask_batch() awaiting tell_batch()

    def _checked_theta(self, theta: Any, name: str) -> np.ndarray:
        t = float_array(theta, name, LearnerError, ndim=1, finite=False)
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
        self._batch.append(Rollout(used, eps, tuple(self._current_costs), bool(fell)))
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
            weights = effective_weights(q, phi, p.h)
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
        keep: list[Rollout] = []
        if p.reuse_best:
            for k in np.argsort(R, kind="stable")[: p.reuse_best]:
                ro = self._batch[k]
                keep.append(Rollout(ro.theta, ro.theta - new, ro.costs, ro.fell))
        self._theta = new
        self._n_updates += 1
        self._consecutive_rejections = 0
        self._history.append(record)
        self._batch = keep
        return record
