"""Many experiment runs' walks on one pool of workers.

A run is a generator that yields the list of walks it needs next and receives their results in
the same order (``results = yield jobs``) until it returns its outcome. :func:`drive` keeps every
run's current walks on the pool at once, so the workers stay busy while each run waits for its
own batch.
"""

from __future__ import annotations

import concurrent.futures as cf
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

from tools.experiment.runner import ExperimentError, WalkJob, WalkPool, last_line

Run = Generator[list[WalkJob], list[dict[str, Any]], Any]


class Interrupted(ExperimentError):
    """A stop was asked (SIGINT, SIGTERM): the walks in progress finished and were kept."""


@dataclass(frozen=True)
class RunFailed:
    """The outcome of a run one of whose walks raised (with ``keep_going``): which walk, and why."""

    name: str
    walk: str  # the walk's gait and seed
    error: str


def drive(pool: WalkPool, runs: dict[str, Run], stop: Callable[[], bool] | None = None, *,
          keep_going: bool = False) -> dict[str, Any]:
    """Run every generator in ``runs`` to its end; returns their outcomes by name. When ``stop()``
    turns true, no new walk starts, the pool finishes (and stores) those in progress and
    :class:`Interrupted` is raised. A walk that raises ends the experiment with its error, or with
    ``keep_going`` only its own run, whose outcome is then a :class:`RunFailed`."""
    outcomes: dict[str, Any] = {}
    waiting: dict[str, tuple[Run, list[WalkJob], list[cf.Future]]] = {}

    def advance(name: str, run: Run, results: list[dict[str, Any]] | None) -> None:
        try:
            jobs = next(run) if results is None else run.send(results)
        except StopIteration as stop:
            outcomes[name] = stop.value
            return
        waiting[name] = (run, jobs, [pool.submit(j) for j in jobs])

    def failed(name: str, run: Run, jobs: list[WalkJob], fs: list[cf.Future]) -> bool:
        bad = next(((j, f.exception()) for j, f in zip(jobs, fs) if f.exception() is not None), None)
        if bad is None:
            return False
        job, exc = bad
        if not keep_going:
            raise exc
        run.close()
        outcomes[name] = RunFailed(name, f"{job.gait}, seed {job.seed}", last_line(exc))
        return True

    for name, run in runs.items():
        advance(name, run, None)
    while waiting:
        # only the walks still running: wait() returns at once when any future given is done
        running = [f for _, _, fs in waiting.values() for f in fs if not f.done()]
        if running:
            cf.wait(running, timeout=0.5, return_when=cf.FIRST_COMPLETED)
        if stop is not None and stop():
            finished = pool.close()
            raise Interrupted(f"interrupted: {finished} walk(s) in progress finished; every finished walk is kept "
                              f"under {pool.cache_dir}, and the same command resumes from them")
        for name, (run, jobs, fs) in list(waiting.items()):
            if all(f.done() for f in fs):
                del waiting[name]
                if not failed(name, run, jobs, fs):
                    advance(name, run, [f.result() for f in fs])
    return outcomes


def batch(jobs: list[WalkJob]) -> Run:
    """A run of one batch: every job at once, its outcome their results (in order)."""
    results = yield jobs
    return results
