"""The experiments' Ray executor (tools/experiment/cluster.py) on a local Ray instance of 2 CPUs:
the same walks give the same results as the local pool, field for field; a Ray worker killed in
the middle of a walk is retried and the results are still the same; without Ray the executor
says which extra to install."""

from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path

import pytest

from config import default_config_path, load_config
from protocol.clock import MonotonicClock
from tools.experiment.runner import ExperimentError, WalkJob, WalkPool

ray = pytest.importorskip("ray", reason="the cluster extra is not installed (pip install -e '.[cluster]')")

CFG = load_config(default_config_path())
JOBS = [WalkJob(seed=s, cycles=1, fixed_m=0.12) for s in range(3)] + [WalkJob(seed=0, cycles=1, theta=(-0.6, 0.24))]


def _comparable(result: dict) -> dict:
    return {k: v for k, v in result.items() if k != "wall_time_s"}  # the one field that is the machine's


def _walk_all(pool: WalkPool) -> list[dict]:
    return [f.result() for f in [pool.submit(j) for j in JOBS]]


@pytest.fixture(scope="module")
def local_results():
    with WalkPool(CFG, 0, None) as pool:
        return _walk_all(pool)


def _ray_task_pids() -> list[int]:
    """Ray worker processes running a walk now."""
    pids = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if cmdline.read_bytes().startswith(b"ray::_walk_task"):  # Ray titles a worker after its task
                pids.append(int(cmdline.parent.name))
        except OSError:
            continue
    return pids


def test_ray_gives_the_local_pools_results_field_for_field(local_results, tmp_path):
    with WalkPool(CFG, 2, tmp_path / "cache", executor="ray") as pool:
        results = _walk_all(pool)
        assert pool.ran == len(JOBS)
    assert [_comparable(r) for r in results] == [_comparable(r) for r in local_results]
    # the cache is the local pool's: the same jobs resume from it without Ray
    with WalkPool(CFG, 0, tmp_path / "cache") as pool:
        assert _walk_all(pool) == json.loads(json.dumps(results)) and pool.reused == len(JOBS) and pool.ran == 0


def test_without_ray_the_executor_names_the_extra(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("no ray here")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(ExperimentError, match=r"pip install 'aider-exo\[cluster\]'"):
        WalkPool(CFG, 2, None, executor="ray")


def test_an_address_needs_the_ray_executor_and_an_unknown_executor_is_refused():
    with pytest.raises(ExperimentError, match="address is the Ray cluster's"):
        WalkPool(CFG, 2, None, address="auto")
    with pytest.raises(ExperimentError, match="unknown executor 'dask'"):
        WalkPool(CFG, 2, None, executor="dask")


def test_the_executor_benchmark_times_both_on_the_same_plan(capsys):
    from tools.cli import main

    assert main(["bench", "executor", "--walks", "2", "--cycles", "1", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["same_results"] is True and r["local"]["walks"] == r["ray"]["walks"] == 2
    assert all(r[k]["seconds_after_startup"] <= r[k]["seconds_with_startup"] for k in ("local", "ray"))
    rows = r["sizing"]["populations"]
    assert [row["patients"] for row in rows] == [20, 100, 1000] and rows[2]["walks"] == 1000 * r["sizing"]["walks_per_patient"]


# -- a small population plan: 2 patients, one update of 2 roll-outs of 1 cycle, 1 walk per gait ----

SMALL = ["--patients", "2", "--seed", "0", "--updates", "1", "--walks", "1", "--set", "controller.learning.steps_per_rollout=1",
         "--set", "controller.learning.rollouts_per_update=2", "--json", "--quiet"]
#: what differs between two runs of the same plan: the machine's time, and the executor named
RUN_FIELDS = ("wall_time_s", "executor")


def _population(out: Path, *extra: str) -> dict:
    import contextlib
    import io

    from tools.cli import main

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(["experiment", "population", *SMALL, "--out", str(out), *extra]) == 0
    summary = json.loads(printed.getvalue())
    return {k: v for k, v in summary.items() if k not in RUN_FIELDS}


@pytest.fixture(scope="module")
def local_population(tmp_path_factory):
    return _population(tmp_path_factory.mktemp("local-population"))


def test_a_population_on_ray_is_the_local_populations_field_for_field(local_population, tmp_path):
    local = local_population
    ray_run = _population(tmp_path / "ray", "--executor", "ray")
    assert local["walks_run"] == ray_run["walks_run"] == 2 * local["walks_per_patient"]
    assert ray_run == local
    patients = {p["patient"]["name"] for p in local["by_patient"]}
    assert patients == {"pop0-0000", "pop0-0001"}


def test_a_ray_worker_killed_in_a_walk_is_retried_and_the_population_is_the_same(local_population, tmp_path):
    killed: list[int] = []

    def kill_one() -> None:
        clock = MonotonicClock()
        deadline = clock.now_ns() + 120_000_000_000  # a hang guard only
        while not killed and clock.now_ns() < deadline:
            pids = _ray_task_pids()
            if pids:
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])
                return
            clock.sleep_until(clock.now_ns() + 20_000_000)

    killer = threading.Thread(target=kill_one, daemon=True)
    killer.start()
    ray_run = _population(tmp_path / "ray", "--executor", "ray")
    killer.join(timeout=5)
    assert killed, "no Ray worker was seen running a walk"
    assert ray_run == local_population
