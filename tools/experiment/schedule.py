"""Many experiment runs' walks on one pool of workers.

A run is a generator that yields the list of walks it needs next and receives their results in
the same order (``results = yield jobs``) until it returns its outcome. :func:`drive` keeps every
run's current walks on the pool at once, so the workers stay busy while each run waits for its
own batch.
"""

from __future__ import annotations

import concurrent.futures as cf
from collections.abc import Generator
from typing import Any

from tools.experiment.runner import WalkJob, WalkPool

Run = Generator[list[WalkJob], list[dict[str, Any]], Any]


def drive(pool: WalkPool, runs: dict[str, Run]) -> dict[str, Any]:
    """Run every generator in ``runs`` to its end; returns their outcomes by name."""
    outcomes: dict[str, Any] = {}
    waiting: dict[str, tuple[Run, list[cf.Future]]] = {}

    def advance(name: str, run: Run, results: list[dict[str, Any]] | None) -> None:
        try:
            jobs = next(run) if results is None else run.send(results)
        except StopIteration as stop:
            outcomes[name] = stop.value
            return
        waiting[name] = (run, [pool.submit(j) for j in jobs])

    for name, run in runs.items():
        advance(name, run, None)
    while waiting:
        futures = [f for _, fs in waiting.values() for f in fs]
        cf.wait(futures, return_when=cf.FIRST_COMPLETED)
        for name, (run, fs) in list(waiting.items()):
            if all(f.done() for f in fs):
                del waiting[name]
                advance(name, run, [f.result() for f in fs])
    return outcomes
