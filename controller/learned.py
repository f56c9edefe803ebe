"""The learned step-length compensation of each patient: ``<learned_dir>/<name>.json``.

A learned file holds the theta = (alpha, Xhat_CoM) to walk with (the learner's evaluation theta:
the mean of its last updates) and the whole learner state, so that learning resumes where it
stopped. Theta means something only with the X_CoM/X_SP it was learned on, so the file names it
(``x_ratio``): a file of another one (version 1: over both feet) is refused, to be relearned.
It is written atomically after every update; a file that cannot be read, does not parse
or holds parameters out of their bounds is a :class:`LearnedError` naming the file, never a
silent fallback to the defaults.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from config.files import OutputError, write_text
from config.errors import AiderError
from controller.pi2 import LearnerError, Pi2Learner, learner_from_state, learner_state

FORMAT = "aider-exo patient"
VERSION = 3
#: the X_CoM/X_SP that theta maps to a step length (controller.estimator.StateEstimator.stance_ratio)
X_RATIO = "stance sole and stick tips"
#: what the theta of an older version's file was learned on
_OLD_RATIOS = {1: "both feet", 2: "the stance ankle and the stick tips"}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class LearnedError(AiderError):
    """A patient name or file that cannot be used (one line, naming the file)."""


@dataclass(frozen=True)
class LearnedRecord:
    name: str
    theta: tuple[float, float]  # (alpha, Xhat_CoM) to walk with
    learner_state: dict[str, Any] | None


def learned_path(directory: str | os.PathLike[str], name: str) -> Path:
    if not isinstance(name, str) or not _NAME.fullmatch(name):  # fullmatch: '$' would let a trailing newline through
        raise LearnedError(f"patient name {name!r}: use 1-64 letters, digits, '_', '-' or '.', starting with a letter or digit")
    return Path(directory) / f"{name}.json"


def load_learned(
    directory: str | os.PathLike[str], name: str, *, lower: tuple[float, float] | None = None,
    upper: tuple[float, float] | None = None,
) -> LearnedRecord | None:
    """The patient's record, or None if the patient has no file yet; ``lower``/``upper``: the
    bounds of theta = (alpha, Xhat_CoM) (``controller.learning``), a theta outside them an error."""
    path = learned_path(directory, name)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, RecursionError) as exc:  # RecursionError: JSON nested too deep
        raise LearnedError(f"{path}: cannot read the learned file ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise LearnedError(f"{path}: not an {FORMAT!r} file")
    old = data.get("version")
    if isinstance(old, int) and old in _OLD_RATIOS:
        raise LearnedError(f"{path}: theta learned on X_CoM/X_SP over {_OLD_RATIOS[old]} (version {old}); this controller's "
                           f"is over the {X_RATIO}: relearn the patient")
    if data.get("version") != VERSION or data.get("x_ratio") != X_RATIO:
        raise LearnedError(f"{path}: not an {FORMAT!r} file of version {VERSION} with x_ratio {X_RATIO!r}")
    theta = data.get("theta")
    if not (isinstance(theta, list) and len(theta) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in theta)):
        raise LearnedError(f"{path}: theta must be two finite numbers (alpha, Xhat_CoM), got {theta!r}")
    if lower is not None and upper is not None and not all(lo <= v <= hi for v, lo, hi in zip(theta, lower, upper)):
        raise LearnedError(f"{path}: theta {theta} outside the bounds {list(lower)} .. {list(upper)} (controller.learning)")
    learner = data.get("learner")
    if learner is not None and not isinstance(learner, dict):
        raise LearnedError(f"{path}: learner must be an object or null")
    return LearnedRecord(name, (float(theta[0]), float(theta[1])), learner)


def restore_learner(record: LearnedRecord, rng: np.random.Generator, path: str | os.PathLike[str]) -> Pi2Learner | None:
    """The learner stored in ``record`` (None if it has none)."""
    if record.learner_state is None:
        return None
    try:
        return learner_from_state(record.learner_state, rng)
    except LearnerError as exc:
        raise LearnedError(f"{path}: {exc}") from None


def save_learned(directory: str | os.PathLike[str], name: str, theta: Any, learner: Pi2Learner | None) -> Path:
    """Write the patient's learned file atomically (the folder is created if needed)."""
    path = learned_path(directory, name)
    _write(path, [float(v) for v in np.asarray(theta, dtype=float).reshape(2)], learner_state(learner) if learner else None, name)
    return path


def _write(path: Path, theta: list[float], learner_state: dict[str, Any] | None, name: str) -> None:
    data = {"format": FORMAT, "version": VERSION, "patient": name, "x_ratio": X_RATIO, "theta": theta, "learner": learner_state}
    text = json.dumps(data, indent=1, allow_nan=False)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, text + "\n")
    except OSError as exc:
        raise LearnedError(f"{path}: cannot write the learned file ({exc})") from None
    except OutputError as exc:
        raise LearnedError(f"cannot write the learned file: {exc}") from None


class LearnedSaver:
    """Writes a patient's learned file off the tick: :meth:`submit` hands the newest state to a writer
    thread (a newer state replaces one not yet written), :meth:`close` writes what is pending and
    stops it. A write error is kept (``errors``) and reported by the caller, never raised into the
    tick."""

    def __init__(self, directory: str | os.PathLike[str], name: str) -> None:
        import threading

        self.directory, self.name = directory, name
        self.path = learned_path(directory, name)
        self.errors: list[str] = []
        self.writes = 0
        self._pending: tuple[list[float], dict[str, Any] | None] | None = None
        self._cond = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name=f"patient-{name}", daemon=True)
        self._thread.start()

    def submit(self, theta: Any, learner: Pi2Learner | None) -> None:
        state = learner_state(learner) if learner is not None else None  # a snapshot, taken now
        with self._cond:
            self._pending = ([float(v) for v in np.asarray(theta, dtype=float).reshape(2)], state)
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._closing:
                    self._cond.wait()
                if self._pending is None:
                    return
                theta, state = self._pending
                self._pending = None
            try:
                _write(self.path, theta, state, self.name)
                self.writes += 1
            except LearnedError as exc:
                self.errors.append(str(exc))

    def close(self) -> None:
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join()
