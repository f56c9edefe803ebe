"""The adaptive gait against fixed step lengths (paper Figs. 8 and 12).

Every gait walks the same patient seeds (paired: the same stick-placement noise for each), ``N``
gait cycles per walk. Per gait: stable gait cycles of ``N``, falls, the mean stick force (per stick,
and both sticks together) and the mean upper-body torque of the completed steps (the simulation's ground truth of the patient's
arm torques, summed over the six arm joints), as the mean and spread over the seeds.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

import numpy as np

from tools.experiment.learn import walk_seed
from tools.experiment.runner import WalkJob

#: the paper's fixed step lengths (Figs. 8 and 12)
FIXED_LENGTHS_M = (0.10, 0.12, 0.14, 0.16, 0.18, 0.20)
ADAPTIVE = "adaptive"


def gait_label(job: WalkJob) -> str:
    return ADAPTIVE if job.theta is not None else f"{job.fixed_m:.2f}"


@dataclass
class GaitStats:
    gait: str
    theta: tuple[float, float] | None
    fixed_m: float | None
    walks: list[dict[str, Any]]

    def summary(self, cycles: int) -> dict[str, Any]:
        done = [w["cycles_completed"] for w in self.walks]
        force = [w["mean_stick_force_n"] for w in self.walks if w["mean_stick_force_n"] is not None]
        torque = [w["mean_arm_torque_nm"] for w in self.walks if w["mean_arm_torque_nm"] is not None]
        lengths = [x for w in self.walks for x in w["step_lengths_m"]]
        first_falls = [w["cycles_completed"] for w in self.walks if w["fell"]]
        mean, std = _stat(force, np.mean), _stat(force, np.std)
        return {
            "gait": self.gait, "theta": None if self.theta is None else list(self.theta), "fixed_m": self.fixed_m,
            "walks": len(self.walks), "cycles_asked": cycles,
            "stable_cycles_mean": round(float(np.mean(done)), 3), "stable_cycles_min": int(min(done)),
            "stable_cycles_max": int(max(done)), "full_walks": sum(not w["fell"] for w in self.walks),
            "falls": sum(w["fell"] for w in self.walks),
            "ends": sorted({w["end"] for w in self.walks if w["fell"]}),
            "cycles_at_fall": first_falls,
            "step_length_mean_m": _stat(lengths, np.mean), "step_length_std_m": _stat(lengths, np.std),
            "stick_force_mean_n": mean, "stick_force_std_n": std,
            # both sticks together (the quantity of equation (10) summed over the two sticks): twice the per-stick mean
            "both_sticks_force_mean_n": None if mean is None else 2.0 * mean, "both_sticks_force_std_n": None if std is None else 2.0 * std,
            "arm_torque_mean_nm": _stat(torque, np.mean), "arm_torque_std_nm": _stat(torque, np.std),
            "seeds": [w["job"]["seed"] for w in self.walks],
        }


def _stat(values: list[float], f: Any) -> float | None:
    return round(float(f(values)), 4) if values else None


def compare_jobs(theta: tuple[float, float], *, seed: int, walks: int, cycles: int, mode: str,
                 lengths: tuple[float, ...] = FIXED_LENGTHS_M) -> list[WalkJob]:
    seeds = [walk_seed(seed, 100, i) for i in range(walks)]
    gaits: list[dict[str, Any]] = [{"theta": theta}] + [{"fixed_m": m} for m in lengths]
    return [WalkJob(seed=s, cycles=cycles, mode=mode, **g) for g in gaits for s in seeds]


def comparison(jobs: list[WalkJob]) -> Generator[list[WalkJob], list[dict[str, Any]], list[GaitStats]]:
    """One batch of every job (a run for :func:`tools.experiment.schedule.drive`); returns the
    walks grouped by gait, adaptive first."""
    results = yield jobs
    groups: dict[str, GaitStats] = {}
    for job, r in zip(jobs, results):
        label = gait_label(job)
        groups.setdefault(label, GaitStats(label, job.theta, job.fixed_m, [])).walks.append(r)
    return list(groups.values())
