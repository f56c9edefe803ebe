"""Fixed-step-length sweeps of the scripted gait: cycles walked, falls, stick force, arm torque.

Each (step length, seed) pair is one episode in its own world; episodes run in parallel
processes (each its own physics client). Results are deterministic for a seed.
"""

from __future__ import annotations

import dataclasses
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable

import numpy as np

from config.sim_schema import SimConfig
from sim.pace import default_max_time_s
from sim.walk import WalkResult, gait_settings, walk


def episode_summary(r: WalkResult) -> dict[str, Any]:
    landed = [s for s in r.steps if s.landed]
    return {
        "step_length_m": r.step_length_m,
        "seed": r.seed,
        "steps_completed": r.steps_completed,
        "cycles_completed": r.cycles_completed,
        "fell": r.fell,
        "fall_reason": r.fall_reason,
        "fall_phase": r.fall_phase,
        "fall_step": r.fall_step,
        "fall_margin_m": r.fall_margin_m,
        "simulated_s": round(r.duration_s, 2),
        "mean_stick_force_n": round(float(np.mean([s.mean_stick_force_n for s in landed])), 1) if landed else None,
        "mean_arm_torque_nm": round(float(np.mean([s.mean_arm_torque_nm for s in landed])), 1) if landed else None,
    }


def _episode(args: tuple[SimConfig, float, int, int]) -> dict[str, Any]:
    cfg, length, seed, steps = args
    return episode_summary(walk(cfg, gait_settings(cfg, step_length_m=length), seed=seed, max_steps=steps,
                                max_time_s=default_max_time_s(steps // 2)))


def run_sweep(
    cfg: SimConfig,
    lengths: list[float],
    seeds: list[int],
    cycles: int,
    *,
    processes: int = 2,
    progress: Callable[[dict[str, Any], int, int], None] | None = None,
) -> dict[str, Any]:
    jobs = [(cfg, length, seed, 2 * cycles) for length in lengths for seed in seeds]
    episodes: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=processes) as pool:
        for i, result in enumerate(pool.map(_episode, jobs), start=1):
            episodes.append(result)
            if progress:
                progress(result, i, len(jobs))
    table = []
    for length in lengths:
        rows = [e for e in episodes if e["step_length_m"] == length]
        forces = [e["mean_stick_force_n"] for e in rows if e["mean_stick_force_n"] is not None]
        torques = [e["mean_arm_torque_nm"] for e in rows if e["mean_arm_torque_nm"] is not None]
        table.append({
            "step_length_m": length,
            "episodes": len(rows),
            "cycles_walked_mean": round(float(np.mean([e["cycles_completed"] for e in rows])), 2),
            "cycles_walked_min": min(e["cycles_completed"] for e in rows),
            "full_walks": sum(e["cycles_completed"] >= cycles for e in rows),
            "falls": sum(e["fell"] for e in rows),
            "stalls": sum(not e["fell"] and e["cycles_completed"] < cycles for e in rows),
            "fall_phases": sorted({e["fall_phase"] for e in rows if e["fell"]}),
            "fall_margin_m_mean": round(float(np.mean([e["fall_margin_m"] for e in rows if e["fell"]])), 3)
            if any(e["fell"] for e in rows) else None,
            "mean_stick_force_n": round(float(np.mean(forces)), 1) if forces else None,
            "mean_arm_torque_nm": round(float(np.mean(torques)), 1) if torques else None,
        })
    return {"mode": cfg.mode, "cycles_per_episode": cycles, "table": table, "episodes": episodes}


def with_mode(cfg: SimConfig, mode: str) -> SimConfig:
    return dataclasses.replace(cfg, mode=mode)


