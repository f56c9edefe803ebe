"""Experiment executors: walks per second over the same plan with the local process pool and with a
local Ray instance, side by side in one run.

The plan is ``--walks`` walks of ``--cycles`` gait cycles each (default 10: a roll-out of the
paper's learning, the real length of an experiment's walk), fixed step length 0.12 m, seeds 0..N-1,
no cache. Each executor gets ``--workers`` processes (the local pool) or CPUs (the local Ray
instance), fresh. Two times each: from the pool's creation to the last result (its start-up
included: Ray starts its services, the pool its processes) and from the first walk's submission
(start-up excluded). Ray's overhead is its extra time over the local pool's, in per cent of the
local pool's. The results of both must be the same walk for walk (checked).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from typing import Any

from config import ConfigError, default_config_path, load_config
from protocol.clock import MonotonicClock

GOAL_RAY_OVERHEAD_PERCENT = 10.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--walks", type=int, default=6, help="walks in the plan (default 6)")
    parser.add_argument("--cycles", type=int, default=10, help="gait cycles per walk (default 10, a roll-out's)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes, or the Ray instance's CPUs (default 2)")


def _timed(cfg: Any, jobs: list, workers: int, executor: str) -> dict[str, Any]:
    from tools.experiment.runner import WalkPool

    clock = MonotonicClock()
    t0 = clock.now_ns()
    with WalkPool(cfg, workers, None, executor=executor) as pool:
        t1 = clock.now_ns()
        results = [f.result() for f in [pool.submit(j) for j in jobs]]
        t2 = clock.now_ns()
    total_s, steady_s = (t2 - t0) / 1e9, (t2 - t1) / 1e9
    return {
        "executor": executor, "walks": len(results),
        "seconds_with_startup": round(total_s, 2), "seconds_after_startup": round(steady_s, 2),
        "walks_per_s_with_startup": round(len(results) / total_s, 4), "walks_per_s_after_startup": round(len(results) / steady_s, 4),
        "walk_seconds_summed": round(sum(r["wall_time_s"] for r in results), 2),
        "results": [{k: v for k, v in r.items() if k != "wall_time_s"} for r in results],
    }


#: the population sizes docs/CLUSTER.md sizes a cluster for, and the cores of the clusters it shows
POPULATIONS = (20, 100, 1000)
CLUSTER_CORES = (2, 32, 256)


def sizing(cfg: Any, walk_core_s: float) -> dict[str, Any]:
    """Core-hours (and hours on clusters of ``CLUSTER_CORES`` cores) of a population experiment
    whose walks each cost ``walk_core_s`` seconds of one core: per patient, learning from the
    paper's start A and the comparison against the fixed step lengths (``Plan.walks_planned``)."""
    from pathlib import Path

    from tools.experiment.experiment import Plan

    per_patient = Plan(cfg=cfg, out=Path("."), starts=["A"], compare=True).walks_planned()
    rows = []
    for patients in POPULATIONS:
        core_h = patients * per_patient * walk_core_s / 3600
        rows.append({"patients": patients, "walks": patients * per_patient, "core_hours": round(core_h, 1),
                     "hours_on": {str(c): round(core_h / c, 2) for c in CLUSTER_CORES}})
    return {"walks_per_patient": per_patient, "walk_core_seconds": round(walk_core_s, 2),
            "walks_per_core_hour": round(3600 / walk_core_s), "populations": rows}


def run(args: argparse.Namespace) -> dict[str, Any]:
    if min(args.walks, args.cycles, args.workers) <= 0:
        raise ConfigError("--walks, --cycles and --workers must be positive")
    from tools.experiment.cluster import _ray
    from tools.experiment.runner import WalkJob

    _ray()  # the cluster extra, or a one-line error before anything runs
    cfg = load_config(args.config or default_config_path())
    jobs = [WalkJob(seed=s, cycles=args.cycles, fixed_m=0.12) for s in range(args.walks)]
    runs = {}
    for executor in ("local", "ray"):
        print(f"bench executor: {args.walks} walks of {args.cycles} gait cycles on {executor} ({args.workers} workers)",
              file=sys.stderr, flush=True)
        runs[executor] = _timed(cfg, jobs, args.workers, executor)
    local, ray = runs["local"], runs["ray"]
    same = local.pop("results") == ray.pop("results")
    overhead = {key: round(100 * (ray[key] - local[key]) / local[key], 1) for key in ("seconds_with_startup", "seconds_after_startup")}
    return {
        "benchmark": "executor", "walks": args.walks, "cycles": args.cycles, "workers": args.workers,
        "sizing": sizing(cfg, local["walk_seconds_summed"] / local["walks"]),
        "local": local, "ray": ray, "same_results": same,
        "ray_overhead_percent": {"with_startup": overhead["seconds_with_startup"], "after_startup": overhead["seconds_after_startup"]},
        "goals": {"ray_overhead_percent_max": GOAL_RAY_OVERHEAD_PERCENT},
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(),
                    "processor": platform.processor() or platform.machine(), "load_avg_1min": round(os.getloadavg()[0], 2)},
    }


def format_text(r: dict[str, Any]) -> str:
    local, ray, over = r["local"], r["ray"], r["ray_overhead_percent"]
    lines = [
        f"executor benchmark: {r['walks']} walks of {r['cycles']} gait cycles, {r['workers']} workers; "
        f"the same results: {'yes' if r['same_results'] else 'NO'}",
        f"{'':<28}{'local pool':>14}{'Ray (local)':>14}{'Ray overhead':>14}  goal",
        f"{'seconds, start-up included':<28}{local['seconds_with_startup']:>14}{ray['seconds_with_startup']:>14}{over['with_startup']:>13}%",
        f"{'seconds after start-up':<28}{local['seconds_after_startup']:>14}{ray['seconds_after_startup']:>14}{over['after_startup']:>13}%"
        f"  at most {r['goals']['ray_overhead_percent_max']:.0f} %",
        f"{'walks per second':<28}{local['walks_per_s_after_startup']:>14}{ray['walks_per_s_after_startup']:>14}",
    ]
    z = r["sizing"]
    lines.append(f"sizing: {z['walk_core_seconds']} core-seconds a walk ({z['walks_per_core_hour']} walks per core-hour), "
                 f"{z['walks_per_patient']} walks a patient (learning from start A, the comparison)")
    lines.append(f"{'patients':>10}{'walks':>10}{'core-hours':>12}" + "".join(f"{f'h on {c} cores':>16}" for c in CLUSTER_CORES))
    for row in z["populations"]:
        lines.append(f"{row['patients']:>10}{row['walks']:>10}{row['core_hours']:>12}"
                     + "".join(f"{row['hours_on'][str(c)]:>16}" for c in CLUSTER_CORES))
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    lo, ray, over = r["local"], r["ray"], r["ray_overhead_percent"]
    return [
        (f"{r['walks']} walks of {r['cycles']} cycles on {r['workers']} workers, local pool / Ray, after Ray's start-up",
         f"{lo['seconds_after_startup']:.2f} / {ray['seconds_after_startup']:.2f} s ({over['after_startup']:+.1f} %)",
         f"Ray at most {r['goals']['ray_overhead_percent_max']:.0f} % over the local pool"),
        ("the same, with Ray's start-up", f"{lo['seconds_with_startup']:.2f} / {ray['seconds_with_startup']:.2f} s "
         f"({over['with_startup']:+.1f} %)", ""),
        ("one walk of 10 cycles", f"{r['sizing']['walk_core_seconds']:.2f} core-s", f"{r['sizing']['walks_per_core_hour']} walks per core-hour"),
    ]
