"""Simulation speed: the full HHEA (joint loops, sensors, patient and exoskeleton control) against
the bare physics step of the same model, measured in the same run, in both model modes.

The HHEA stands balanced on its feet and sticks for the whole run, so every 20 ms tick does the
work of a walk (whole-body kinematics, sensors, the contact-force distribution, joint commands)
without a fall cutting the run short. PyBullet's ``stepSimulation`` is timed inside the same loop,
so "bare physics" and "everything else" come from one run on one world.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
from typing import Any

import numpy as np

from config import ConfigError, default_config_path, load_config
from protocol.clock import TICK_MS, MonotonicClock
from tools.bench import median_of_runs

GOAL_REALTIME = 10.0
GOAL_OVERHEAD_PERCENT = 60.0  # issue 29


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per mode and repeat (default 10)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per mode; the figures are their medians (default 3)")


def _run_mode(cfg: Any, mode: str, seconds: float) -> dict[str, Any]:
    from sim.walk import Walker, gait_settings, initial_pose  # PyBullet loads only when this benchmark runs
    from sim.world import PhysicsTimer, World

    clock = MonotonicClock()
    sim_cfg = dataclasses.replace(cfg, mode=mode)
    with World(sim_cfg) as world:
        world.place(initial_pose(sim_cfg))
        walker = Walker(world, sim_cfg, gait_settings(sim_cfg, settle_s=seconds + 1.0), np.random.default_rng(0))
        physics = PhysicsTimer(world, clock)
        start = clock.now_ns()
        result = walker.run(max_steps=1, max_time_s=seconds)
        total_ns = clock.now_ns() - start
    physics_ns = physics.ns
    simulated = result.duration_s
    physics_s, total_s = physics_ns / 1e9, total_ns / 1e9
    return {
        "mode": mode,
        "simulated_s": round(simulated, 2),
        "fell": result.fell,
        "physics_steps": int(round(simulated * sim_cfg.physics.rate_hz)),
        "wall_s": round(total_s, 3),
        "realtime_factor_full": round(simulated / total_s, 2),
        "realtime_factor_bare_physics": round(simulated / physics_s, 2),
        "overhead_percent": round(100.0 * (total_s - physics_s) / physics_s, 1),
        "us_per_tick_full": round(total_ns / 1e3 / (simulated * 1000.0 / TICK_MS), 1),
        "us_per_tick_physics": round(physics_ns / 1e3 / (simulated * 1000.0 / TICK_MS), 1),
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if not args.seconds > 0 or args.repeats <= 0:
        raise ConfigError("--seconds and --repeats must be positive")
    cfg = load_config(args.config or default_config_path())
    if cfg.sim is None:
        raise ConfigError("sim: section required by the simulation benchmark", key="sim")
    modes = []
    for mode in ("full3d", "sagittal"):
        runs = [_run_mode(cfg.sim, mode, args.seconds) for _ in range(args.repeats)]
        modes.append(median_of_runs(runs) | {"overhead_percent_runs": [r["overhead_percent"] for r in runs]})
    return {
        "benchmark": "sim",
        "physics_rate_hz": cfg.sim.physics.rate_hz,
        "tick_hz": 1000.0 / TICK_MS,
        "repeats": args.repeats,
        "modes": modes,
        "goals": {"realtime_factor_min": GOAL_REALTIME, "overhead_percent_max": GOAL_OVERHEAD_PERCENT},
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine()},
    }


def format_text(r: dict[str, Any]) -> str:
    lines = [
        f"simulation benchmark: physics {r['physics_rate_hz']} Hz, bus tick {r['tick_hz']:g} Hz, one core, median of {r['repeats']} runs",
        f"{'mode':<10}{'sim s':>7}{'x real time':>13}{'bare physics':>14}{'overhead':>10}{'us/tick':>9}",
    ]
    for m in r["modes"]:
        lines.append(
            f"{m['mode']:<10}{m['simulated_s']:>7.1f}{m['realtime_factor_full']:>12.1f}x{m['realtime_factor_bare_physics']:>13.1f}x"
            f"{m['overhead_percent']:>9.0f}%{m['us_per_tick_full']:>9.0f}"
        )
    g = r["goals"]
    lines.append(f"goals: at least {g['realtime_factor_min']:.0f}x real time; sensors, patient and interface at most "
                 f"{g['overhead_percent_max']:.0f} % on top of the bare physics")
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    g = r["goals"]
    return [
        (f"{m['mode']}: full simulation, x real time; bare physics; overhead", f"{m['realtime_factor_full']:.1f}x; "
         f"{m['realtime_factor_bare_physics']:.1f}x; {m['overhead_percent']:.0f} %",
         f"at least {g['realtime_factor_min']:.0f}x; overhead at most {g['overhead_percent_max']:.0f} %")
        for m in r["modes"]
    ]
