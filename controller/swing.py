"""The swing generator from the configuration: demonstration, fitted DMP weights and their cache.

The DMP is fitted once to the demonstration at ``swing.demonstration_step_m`` (near the shortest
steps: longer goals keep the demonstrated shape, shorter ones make the foot dip backward first) and the weights are kept in
``config/swing_weights.json`` with the hash of the demonstration and the DMP settings they came
from. Loading checks both, so a changed configuration can never run with stale weights;
``aider-exo dmp fit`` refits and rewrites the file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from config.controller_schema import ControllerConfig
from config.files import write_text
from config.errors import AiderError
from controller.demonstration import demonstration_hash, swing_demonstration
from controller.dmp_model import DmpParams, DmpWeights, fit

WEIGHTS_PATH = Path(__file__).resolve().parents[1] / "config" / "swing_weights.json"
FORMAT = 1


class SwingWeightsError(AiderError):
    """The cached weights are missing, unreadable or do not belong to the configuration."""


def dmp_params(cfg: ControllerConfig) -> DmpParams:
    s = cfg.swing
    return DmpParams(n_basis=s.n_basis, stiffness=s.stiffness, alpha_s=s.alpha_s, regularisation=s.regularisation)


def demonstration(cfg: ControllerConfig) -> tuple[np.ndarray, np.ndarray]:
    """The demonstration the weights are fitted to: (times (m,), ankle x and z from the start (m, 2))."""
    return swing_demonstration(step_m=cfg.swing.demonstration_step_m, lift_m=cfg.swing.clearance_m, duration_s=cfg.swing.demonstration_duration_s)


def _identity(cfg: ControllerConfig) -> dict[str, Any]:
    times, xz = demonstration(cfg)
    p = dmp_params(cfg)
    return {
        "format": FORMAT,
        "demonstration_sha256": demonstration_hash(times, xz),
        "dmp": {"n_basis": p.n_basis, "stiffness": p.stiffness, "alpha_s": p.alpha_s, "regularisation": p.regularisation},
    }


def fit_swing(cfg: ControllerConfig) -> DmpWeights:
    times, xz = demonstration(cfg)
    return fit(times, xz, dmp_params(cfg))


def save_swing(cfg: ControllerConfig, weights: DmpWeights, path: Path = WEIGHTS_PATH) -> Path:
    """Write the weights with the identity of what they were fitted to (atomically)."""
    data = dict(_identity(cfg), tau_s=weights.tau_s, x0=weights.x0.tolist(), g=weights.g.tolist(),
                weights=weights.weights.tolist())
    write_text(path, json.dumps(data, indent=1) + "\n")
    return path


def load_swing(cfg: ControllerConfig, path: Path = WEIGHTS_PATH) -> DmpWeights:
    """The cached weights; :class:`SwingWeightsError` (one line, with the fix) if they do not fit ``cfg``."""
    fix = "run `aider-exo dmp fit` to refit them"
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise SwingWeightsError(f"{path}: no fitted swing weights; {fix}") from None
    except (OSError, ValueError) as exc:
        raise SwingWeightsError(f"{path}: unreadable swing weights ({exc}); {fix}") from None
    expected = _identity(cfg)
    for key, value in expected.items():
        if data.get(key) != value:
            raise SwingWeightsError(f"{path}: weights were fitted for another {key.replace('_', ' ')}; {fix}")
    try:
        return DmpWeights(np.array(data["weights"]), np.array(data["x0"]), np.array(data["g"]), float(data["tau_s"]), dmp_params(cfg))
    except (KeyError, TypeError, ValueError) as exc:
        raise SwingWeightsError(f"{path}: malformed swing weights ({exc}); {fix}") from None
