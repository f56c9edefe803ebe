"""Walks as Ray tasks: the experiments' executor on a Ray cluster (docs/CLUSTER.md).

:class:`RayExecutor` is what :class:`tools.experiment.runner.WalkPool` submits walks to with
``--executor ray``: each walk is a Ray task that runs :func:`tools.experiment.runner.run_walk` on a
worker of the cluster (or of a local Ray instance when no address is given), retried by Ray when
its worker process dies. The results come back to this process, which stores them in the walk
cache as the local pool does, so a run stopped on the cluster resumes on a laptop and the other
way round. At most as many walks as the cluster has CPUs are in Ray at once; the rest wait here,
so a stop cancels them without touching the walks in progress.
"""

from __future__ import annotations

import concurrent.futures as cf
import threading
from collections import deque
from typing import Any

from config import Config
from tools.experiment.runner import ExperimentError, WalkJob, last_line, run_walk

#: Ray's retries of a walk whose worker process died (a node lost, a process killed)
TASK_RETRIES = 3


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ExperimentError("--executor ray needs Ray: pip install 'aider-exo[cluster]'") from None
    return ray


def _walk_task(cfg: Config, job: WalkJob) -> dict[str, Any]:
    return run_walk(cfg, job)


class RayExecutor:
    """Walk jobs as Ray tasks on the cluster at ``address`` (None: a local Ray instance of
    ``num_cpus`` CPUs, this machine's when None); ``submit(job)`` returns a future of its result."""

    def __init__(self, cfg: Config, *, address: str | None = None, num_cpus: int | None = None) -> None:
        ray = _ray()
        self._ray = ray
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            try:
                ray.init(address=address, num_cpus=None if address else num_cpus, include_dashboard=False,
                         log_to_driver=False, logging_level="ERROR")
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise ExperimentError(f"cannot reach the Ray cluster at {address}: {exc}") from None
        self.capacity = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._cfg_ref = ray.put(cfg)  # once, not with every walk
        self._remote = ray.remote(num_cpus=1, max_retries=TASK_RETRIES)(_walk_task)
        self._lock = threading.Condition()
        self._waiting: deque[tuple[WalkJob, cf.Future]] = deque()
        self._in_flight = 0
        self._closed = False

    def submit(self, job: WalkJob) -> cf.Future:
        future: cf.Future = cf.Future()
        with self._lock:
            if self._closed:
                raise ExperimentError("the Ray executor is shut down")
            if self._in_flight < self.capacity:
                self._launch(job, future)
            else:
                self._waiting.append((job, future))
        return future

    def _launch(self, job: WalkJob, future: cf.Future) -> None:  # under the lock
        if not future.set_running_or_notify_cancel():
            return
        self._in_flight += 1
        ref = self._remote.remote(self._cfg_ref, job)
        ref.future().add_done_callback(lambda done: self._finished(job, future, done))

    def _finished(self, job: WalkJob, future: cf.Future, done: cf.Future) -> None:
        with self._lock:
            self._in_flight -= 1
            while self._waiting:
                next_job, next_future = self._waiting.popleft()
                if not next_future.cancelled():
                    self._launch(next_job, next_future)
                    break
            self._lock.notify_all()
        exc = done.exception()
        if exc is not None:
            future.set_exception(ExperimentError(f"the walk {job.gait}, seed {job.seed}, failed on the cluster: {last_line(exc)}"))
        else:
            future.set_result(done.result())

    def shutdown(self, wait: bool = True, cancel_futures: bool = True) -> None:
        """Cancel the walks not yet sent to Ray; with ``wait``, until those in Ray have finished."""
        with self._lock:
            self._closed = True
            if cancel_futures:
                while self._waiting:
                    self._waiting.popleft()[1].cancel()
            if wait:
                while self._in_flight or self._waiting:
                    self._lock.wait(0.5)
        if self._owns_ray:
            self._ray.shutdown()
