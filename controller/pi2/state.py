"""A learner's state as JSON-ready builtins, to resume learning after a restart (the patient's
file keeps it: :mod:`controller.learned`)."""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import numpy as np

from controller.arrays import float_array
from controller.pi2.learner import Pi2Learner, Rejection, Rollout, UpdateRecord
from controller.pi2.rules import LearnerError, Pi2Params, is_int

STATE_FORMAT = "aider-exo.pi2"
STATE_VERSION = 1


def learner_state(learner: Pi2Learner) -> dict:
    """Everything needed to resume, as JSON-ready builtins (a new dict).

    An unfinished roll-out is not included: after a restart the next ``ask()`` starts a fresh
    one. The generator's state is not included either (it is injected on restore). Non-finite
    step costs waiting in the batch are stored as the strings "nan", "inf", "-inf".
    """
    return {
        "format": STATE_FORMAT,
        "version": STATE_VERSION,
        "params": _params_to_dict(learner._params),
        "theta": learner._theta.tolist(),
        "n_updates": learner._n_updates,
        "n_batches": learner._n_batches,
        "consecutive_rejections": learner._consecutive_rejections,
        "learning_enabled": learner._learning_enabled,
        "batch": [
            {
                "theta": ro.theta.tolist(),
                "eps": ro.eps.tolist(),
                "costs": [_enc(c) for c in ro.costs],
                "fell": ro.fell,
            }
            for ro in learner._batch
        ],
        "history": [asdict(h) for h in learner._history],
        "rejections": [asdict(r) for r in learner._rejections],
    }

def learner_from_state(d: dict, rng: np.random.Generator) -> Pi2Learner:
    """Rebuild a learner from :func:`learner_state`'s output; malformed input raises LearnerError."""
    if not isinstance(d, dict):
        raise LearnerError(f"state must be a dict, got {type(d).__name__}")
    if d.get("format") != STATE_FORMAT or d.get("version") != STATE_VERSION:
        found = f"format={d.get('format')!r} version={d.get('version')!r}"
        raise LearnerError(f"not a {STATE_FORMAT} v{STATE_VERSION} state: {found}")
    try:
        params = Pi2Params(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d["params"].items()})
        learner = Pi2Learner(params, d["theta"], rng)
        n_up, n_b, cons = d["n_updates"], d["n_batches"], d["consecutive_rejections"]
        if not all(is_int(v) and v >= 0 for v in (n_up, n_b, cons)) or n_up > n_b:
            raise LearnerError(f"bad counters n_updates={n_up!r} n_batches={n_b!r} consecutive={cons!r}")
        if not isinstance(d["learning_enabled"], bool):
            raise LearnerError("learning_enabled must be a bool")
        learner._n_updates, learner._n_batches, learner._consecutive_rejections = n_up, n_b, cons
        learner._learning_enabled = d["learning_enabled"]
        batch = []
        for ro in d["batch"]:
            theta = learner._checked_theta(ro["theta"], "batch theta")
            eps = float_array(ro["eps"], "batch eps", LearnerError, ndim=1, finite=False)
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
            batch.append(Rollout(theta, eps, costs, ro["fell"]))
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
