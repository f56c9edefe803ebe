"""The controller's numerical core per call: one DMP tick, one leg inverse kinematics, one PI² update.

* DMP: one 20 ms tick of the 2-D swing DMP with RK4 substeps, over whole swings; beside it, in the
  same run, ``controller.dmp.reference_rollout``: the plain substep-by-substep RK4 of the same
  equations (the oracle of the tests, and the baseline the precomputed tick map replaces);
* IK: ``controller.kinematics.inverse`` on reachable swing-ankle targets;
* PI²: ``pi2_update`` for K = 5 roll-outs of N = 10 steps.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
from typing import Any, Callable

import numpy as np

from config import ConfigError, default_config_path, load_config
from protocol.clock import TICK_S, MonotonicClock

GOALS_US = {"dmp_tick": 30.0, "ik": 10.0, "pi2_update": 200.0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats (default 5)")


def _per_call_us(fn: Callable[[], None], calls: int, repeats: int) -> dict[str, float]:
    clock = MonotonicClock()
    fn()
    samples = []
    for _ in range(repeats):
        start = clock.now_ns()
        for _ in range(calls):
            fn()
        samples.append((clock.now_ns() - start) / 1000 / calls)
    return {"median": round(statistics.median(samples), 2), "best": round(min(samples), 2)}


def run(args: argparse.Namespace) -> dict[str, Any]:
    from controller.dmp import Dmp, reference_rollout
    from controller.factory import leg as make_leg, swing_duration_s
    from controller.kinematics import forward, inverse
    from controller.pi2 import pi2_update
    from controller.swing import load_swing

    if args.repeats < 1:
        raise ConfigError("--repeats must be positive")
    cfg = load_config(args.config or default_config_path()).controller
    if cfg is None:
        raise ConfigError("section required by the algorithm benchmark", key="controller")
    weights = load_swing(cfg)
    tau, dt, substeps = swing_duration_s(cfg), TICK_S, cfg.swing.substeps
    ticks_per_swing = int(math.ceil(tau / dt))
    dmp = Dmp(weights)
    goal = np.array([0.15, 0.0])

    def dmp_swing() -> None:
        dmp.reset(x0=np.zeros(2), goal=goal, tau_s=tau)
        for _ in range(ticks_per_swing):
            dmp.step(dt, substeps)

    def naive_swing() -> None:
        reference_rollout(weights, np.zeros(2), goal, tau, dt, substeps, ticks_per_swing)

    leg = make_leg(cfg)
    rng = np.random.default_rng(0)
    # Reachable swing-ankle targets: forward kinematics of joint angles a swing uses.
    targets = [forward(leg, float(h), float(k)) for h, k in zip(rng.uniform(-0.3, 0.6, 256), rng.uniform(0.05, 1.0, 256))]
    counter = [0]

    def ik() -> None:
        counter[0] = (counter[0] + 1) & 255
        inverse(leg, *targets[counter[0]])

    eps = rng.normal(0.0, [2.0, 0.06], size=(5, 2))
    step_costs = rng.uniform(50.0, 300.0, size=(5, 10))
    terminal = np.array([0.0, 0.0, 3000.0, 0.0, 6000.0])

    def pi2() -> None:
        pi2_update(eps, step_costs, terminal, 10.0)

    dmp_t = _per_call_us(dmp_swing, 20, args.repeats)
    naive_t = _per_call_us(naive_swing, 3, args.repeats)
    results = {
        "dmp_tick_us": {k: round(v / ticks_per_swing, 2) for k, v in dmp_t.items()},
        "dmp_tick_naive_rk4_us": {k: round(v / ticks_per_swing, 2) for k, v in naive_t.items()},
        "ik_us": _per_call_us(ik, 2000, args.repeats),
        "pi2_update_us": _per_call_us(pi2, 500, args.repeats),
    }
    return {
        "benchmark": "algorithms",
        "dmp": {"dimensions": 2, "basis_functions": weights.weights.shape[1], "tick_s": dt, "rk4_substeps": substeps},
        "pi2": {"rollouts": 5, "steps": 10, "parameters": 2},
        "results": results,
        "goals_us": GOALS_US,
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine()},
    }


def format_text(r: dict[str, Any]) -> str:
    res, goals = r["results"], r["goals_us"]
    d = r["dmp"]
    lines = [
        "algorithm benchmark, median (best) us per call",
        f"DMP tick ({d['dimensions']}-D, {d['basis_functions']} basis functions, {d['tick_s'] * 1000:.0f} ms, {d['rk4_substeps']} RK4 substeps): "
        f"{res['dmp_tick_us']['median']:.1f} ({res['dmp_tick_us']['best']:.1f})   goal {goals['dmp_tick']:.0f}; "
        f"naive RK4 baseline {res['dmp_tick_naive_rk4_us']['median']:.0f}",
        f"leg inverse kinematics: {res['ik_us']['median']:.2f} ({res['ik_us']['best']:.2f})   goal {goals['ik']:.0f}",
        f"PI² update (K = 5, N = 10): {res['pi2_update_us']['median']:.1f} ({res['pi2_update_us']['best']:.1f})   goal {goals['pi2_update']:.0f}",
    ]
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    res, g = r["results"], r["goals_us"]
    return [(
        "DMP tick, leg IK, PI² update",
        f"{res['dmp_tick_us']['median']:.1f}, {res['ik_us']['median']:.2f}, {res['pi2_update_us']['median']:.1f} us",
        f"at most {g['dmp_tick']:.0f}, {g['ik']:.0f}, {g['pi2_update']:.0f} us (plain RK4 DMP tick {res['dmp_tick_naive_rk4_us']['median']:.0f} us)",
    )]
