"""Walks through the whole pipeline as jobs: run in parallel worker processes, each result stored
once so an interrupted experiment resumes without redoing it.

A :class:`WalkJob` is one walk of the controller (a fixed step length, or the compensation with a
given theta), the CAN frames, the node boards and the simulation, in lock-step on its own virtual
bus and world (:func:`tools.pipeline.walk`): deterministic for its seed, so a result is a pure
function of the job, the configuration and the software. :class:`WalkPool` runs jobs in worker
processes and keeps each result as a JSON file named by that key in the experiment's cache
directory; a job whose file exists is not run again.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import math
import multiprocessing
import signal
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from config import AiderError, Config, config_hash
from config.files import write_text
from config.patient_schema import VirtualPatient

#: the stored result's format, part of every job's key: a result whose meaning changes gets a new
#: number, and the walks of an older format are run again (/4: X_CoM/X_SP is the compensation's,
#: over the stance ankle and the tips, and ``swing_x_ratio_planted`` the one over both feet; /3:
#: the patient's intention per swing and its clamped stick goals; /2: a walk ends at the
#: controller's HOLD, ``end`` "hold CAUSE"; /1 waited out the stall time and said "stalled")
RESULT_FORMAT = "aider-exo.walk-result/4"


class ExperimentError(AiderError):
    """An experiment that cannot run or resume (a bad option, an unreadable result file, ...)."""


def last_line(exc: BaseException) -> str:
    """A walk's error in one line: its message's last line (a remote traceback's), or its type."""
    text = str(exc).strip()
    return text.splitlines()[-1] if text else type(exc).__name__


@dataclass(frozen=True)
class WalkJob:
    """One walk: ``fixed_m`` (every step that long, no compensation), ``theta`` = (alpha,
    Xhat_CoM) of the compensation, or ``random_m`` = (min, max): every step's length drawn
    uniformly from it (seeded by ``seed``: what makes the model fall, :mod:`tools.experiment.falls`);
    ``seed`` is the patient's stick placement and sensor noise."""

    seed: int
    cycles: int
    fixed_m: float | None = None
    theta: tuple[float, float] | None = None
    mode: str = "sagittal"
    random_m: tuple[float, float] | None = None
    patient: VirtualPatient | None = None  # a virtual patient (tools.population); None: the configuration's own

    def __post_init__(self) -> None:
        if sum(x is not None for x in (self.fixed_m, self.theta, self.random_m)) != 1:
            raise ExperimentError("a walk job needs exactly one of fixed_m, theta and random_m")
        if self.random_m is not None and not 0 < self.random_m[0] <= self.random_m[1]:
            raise ExperimentError(f"random step lengths need 0 < min <= max, got {self.random_m}")

    @property
    def gait(self) -> str:
        if self.fixed_m is not None:
            return f"fixed {self.fixed_m:.2f} m"
        if self.random_m is not None:
            return f"random {self.random_m[0]:.2f}-{self.random_m[1]:.2f} m"
        return f"theta ({self.theta[0]:.3f}, {self.theta[1]:.3f})"

    def as_dict(self) -> dict[str, Any]:
        """The job as JSON-ready data (without ``patient`` when there is none: the keys of the walks
        stored before virtual patients stay valid)."""
        data = asdict(self)
        if data["patient"] is None:
            del data["patient"]
        return data

    def key(self, cfg_digest: str) -> str:
        """The name of this job's result: its fields, the configuration, the software version and the
        result's format."""
        text = json.dumps({"job": self.as_dict(), "config": cfg_digest, "software": _software_version(), "format": RESULT_FORMAT},
                          sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:24]


def _software_version() -> str:
    try:
        return metadata.version("aider-exo")
    except metadata.PackageNotFoundError:
        return "unknown"


def run_walk(cfg: Config, job: WalkJob) -> dict[str, Any]:
    """Walk ``job`` and return its result (JSON-ready). Upper-body torque and falls are the
    simulation's ground truth; stick forces and step lengths are what the controller measured."""
    from controller.factory import step_bounds
    from controller.policy import StepPolicy, cycle_costs
    from tools.experiment.falls import RandomLengths
    from tools.pipeline import walk

    if job.patient is not None:
        from tools.population import patient_config

        cfg = patient_config(cfg, job.patient)
    bounds = step_bounds(cfg.controller)
    if job.fixed_m is not None:
        policy = StepPolicy(bounds, fixed_m=job.fixed_m)
    elif job.random_m is not None:
        policy = RandomLengths(bounds, span=job.random_m, rng=np.random.default_rng(np.random.SeedSequence([job.seed, 1])))
    else:
        policy = StepPolicy(bounds, theta=job.theta)
    # the estimator's error against the ground truth is `aider-exo walk`'s to report, not the learner's
    outcome = walk(cfg, cycles=job.cycles, seed=job.seed, mode=job.mode, policy=policy, compare_ratio=False)
    landed = outcome.landed
    swings = [s for s in outcome.steps if s.swing_tick >= 0]
    forces = [s.mean_stick_force_n for s in landed]
    torques = outcome.arm_torques_nm
    complete = len(landed) >= 2 * job.cycles
    return {
        "format": RESULT_FORMAT,
        "job": job.as_dict(),
        "cycles_completed": outcome.cycles_completed,
        "steps_completed": len(landed),
        "complete": complete,
        # a walk that stalled, held or faulted without falling did not walk its cycles either: for the
        # learner it ends like a fall, after the cycles it completed
        "fell": not complete,
        "end": "walked" if complete else _end(outcome),
        "cycle_costs": cycle_costs(forces),
        "step_lengths_m": [round(s.length_m, 5) for s in landed],
        "step_x_ratio": [round(s.x_ratio, 5) for s in landed],
        "step_stick_force_n": [round(f, 4) for f in forces],
        "step_arm_torque_nm": [round(t, 4) for t in torques],
        # every step whose swing started, the last one too when it did not land: (length, X_CoM/X_SP at its start, landed)
        "swings": [[round(s.length_m, 5), round(s.x_ratio, 5), s.landed] for s in swings],
        # X_CoM/X_SP at each of those swings' start over both feet and both tips
        "swing_x_ratio_planted": [_round(s.x_ratio_planted, 5) for s in swings],
        # the simulated patient's intended stick placement (sim.patient.intention) before each of those swings
        "swing_intention_m": _swing_intentions(outcome.intentions_m, len(swings)),
        "stick_clamps": outcome.stick_clamps,
        "mean_stick_force_n": _round(outcome.mean_stick_force_n),  # the walk's own means (tools.pipeline.WalkOutcome)
        "mean_arm_torque_nm": _round(outcome.mean_arm_torque_nm),
        "sim_time_s": round(outcome.sim_time_s, 2),
        "wall_time_s": round(outcome.wall_time_s, 2),
    }


def _end(outcome: Any) -> str:
    """How a walk that did not complete its cycles ended: the fall's criterion, ``fault CAUSE``,
    ``hold CAUSE`` (the controller's protective stop) or ``stalled`` (no step landed in time)."""
    if outcome.fall_reason:
        return outcome.fall_reason
    if outcome.fault:
        return f"fault {outcome.fault}"
    return f"hold {outcome.hold}" if outcome.hold else "stalled"


def _swing_intentions(intentions_m: list[float], swings: int) -> list[float | None]:
    """The intention before each of the controller's ``swings``: the patient's steps in order, the
    one in the making for a swing the patient had not sensed yet when the walk ended."""
    if not intentions_m:
        return [None] * swings
    return [_round(intentions_m[min(i, len(intentions_m) - 1)], 5) for i in range(swings)]


def _round(value: float, digits: int = 4) -> float | None:
    return round(value, digits) if math.isfinite(value) else None


# -- the pool ---------------------------------------------------------------------------------

_worker_cfg: Config | None = None


def _init_worker(cfg: Config) -> None:
    global _worker_cfg
    _worker_cfg = cfg
    # A terminal's Ctrl-C (and a SIGTERM to the group) is the parent's to handle: it lets the walks
    # in progress finish and keeps them, rather than each worker dying in the middle of one.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def _run_in_worker(job: WalkJob) -> dict[str, Any]:
    assert _worker_cfg is not None
    return run_walk(_worker_cfg, job)


EXECUTORS = ("local", "ray")


class WalkPool:
    """Runs walk jobs in ``workers`` processes (0: in this process), or with ``executor="ray"`` as
    Ray tasks (:mod:`tools.experiment.cluster`: on the cluster at ``address``, or a local Ray
    instance of ``workers`` CPUs, this machine's when 0), storing every result under ``cache_dir``
    by its key. ``submit`` returns a future; a stored result resolves at once."""

    def __init__(self, cfg: Config, workers: int, cache_dir: Path | None,
                 on_done: Callable[[WalkJob, dict[str, Any], bool], None] | None = None, *,
                 executor: str = "local", address: str | None = None) -> None:
        if workers < 0:
            raise ExperimentError(f"workers must be >= 0, got {workers}")
        if executor not in EXECUTORS:
            raise ExperimentError(f"unknown executor {executor!r}: {' or '.join(EXECUTORS)}")
        if address is not None and executor != "ray":
            raise ExperimentError("an address is the Ray cluster's: give it with the ray executor")
        self.cfg = cfg
        self.digest = config_hash(cfg)
        self.cache_dir = cache_dir
        self.on_done = on_done
        self.ran = 0
        self.reused = 0
        if cache_dir is not None:
            cache_dir.mkdir(parents=True, exist_ok=True)
        self._executor: Any = None
        self._launch: Callable[[WalkJob], cf.Future] | None = None
        if executor == "ray":
            from tools.experiment.cluster import RayExecutor

            self._executor = RayExecutor(cfg, address=address, num_cpus=workers or None)
            self._launch = self._executor.submit
        elif workers > 0:
            self._executor = cf.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                    initializer=_init_worker, initargs=(cfg,))
            self._launch = lambda job: self._executor.submit(_run_in_worker, job)

    def __enter__(self) -> WalkPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> int:
        """Cancel the walks not started, wait for those in progress (their results are stored);
        returns how many finished while closing."""
        before = self.ran
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor, self._launch = None, None
        return self.ran - before

    def _path(self, job: WalkJob) -> Path | None:
        return None if self.cache_dir is None else self.cache_dir / f"{job.key(self.digest)}.json"

    def stored(self, job: WalkJob) -> dict[str, Any] | None:
        path = self._path(job)
        if path is None or not path.exists():
            return None
        try:
            result = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ExperimentError(f"{path}: unreadable walk result ({exc}); delete it to run that walk again") from None
        if not isinstance(result, dict) or result.get("format") != RESULT_FORMAT or result.get("job") != json.loads(json.dumps(job.as_dict())):
            raise ExperimentError(f"{path}: not the result of {job}; delete it to run that walk again")
        return result

    def submit(self, job: WalkJob) -> cf.Future:
        future: cf.Future = cf.Future()
        result = self.stored(job)
        if result is not None:
            self.reused += 1
            future.set_result(result)
            if self.on_done is not None:
                self.on_done(job, result, True)
            return future
        if self._launch is None:
            inner: cf.Future = cf.Future()
            inner.set_result(run_walk(self.cfg, job))
        else:
            inner = self._launch(job)

        def finished(f: cf.Future) -> None:
            if f.cancelled():  # the pool closed before it started
                future.cancel()
                return
            if f.exception() is not None:
                future.set_exception(f.exception())
                return
            result = f.result()
            self._store(job, result)
            self.ran += 1
            if self.on_done is not None:
                self.on_done(job, result, False)
            future.set_result(result)

        inner.add_done_callback(finished)
        return future

    def _store(self, job: WalkJob, result: dict[str, Any]) -> None:
        path = self._path(job)
        if path is None:
            return
        write_text(path, json.dumps(result) + "\n")  # a result is either whole or absent: an interrupted write is redone
