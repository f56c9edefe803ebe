"""The soak: long lock-step walking under seeded random faults, with the invariants checked on every
tick and the process's memory watched (issue 9; docs/FAULTS.md section 5).

Walking goes on in episodes (a fresh world each, as the experiments do), each on
:class:`~tools.safety.rig.FaultRig`: the operator starts the walk; faults come at random, on
average ``faults_per_min`` per simulated minute, drawn from the bus faults (drop, delay,
duplicate, reorder, corrupt, truncate, error frames, send failures) and the node faults (freeze,
drive fault, reboot, stuck encoder), each for a few ticks on one node; after a HOLD or FAULT the
operator resets every ``reset_after_ticks`` (the FSM decides whether it may leave: I4 wants the
nodes healthy and both sticks loaded), then starts the walk again. An episode ends at a fall, or
after ``episode_ticks``.

Memory: resident set size (after ``malloc_trim``, with a fixed mmap threshold:
:func:`steady_allocator`) and the number of Python objects tracked by the garbage collector,
measured after the first ``WARM_UP`` episodes (imports, caches, the first worlds) and at the end,
both after a full collection. The soak passes with no invariant broken, resident memory grown by
at most ``max_rss_growth`` and the object count by at most ``max_object_growth``.
"""

from __future__ import annotations

import ctypes
import gc
import os
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from config import Config
from protocol.catalog import default_catalog
from protocol.clock import TICK_MS
from protocol.enums import GaitState
from protocol.faultbus import BusFault
from tools.safety.rig import FaultRig

BUS_KINDS = ("drop", "delay", "duplicate", "reorder", "corrupt", "truncate", "error_frame", "send_failure")
NODE_KINDS = ("freeze", "drive_fault", "reboot", "stuck_encoder")
TICKS_PER_MIN = 60_000 // TICK_MS
WARM_UP = 2  # episodes before the memory baseline
M_MMAP_THRESHOLD = -3  # mallopt's parameter number (malloc.h)


def _libc() -> ctypes.CDLL | None:
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:  # not glibc: RSS is measured as it is
        return None


def steady_allocator() -> None:
    """glibc's malloc with a fixed mmap threshold (128 KiB), so that a large block freed goes back
    to the system instead of raising the threshold and fragmenting the heap: PyBullet allocates
    large blocks per world, and without this the resident size of a process making and closing
    worlds swings by 16 MiB from one episode to the next without any leak (measured)."""
    libc = _libc()
    if libc is not None:
        libc.mallopt(M_MMAP_THRESHOLD, 128 * 1024)


def rss_bytes() -> int:
    """Resident set size of this process (Linux /proc), after handing free heap back to the system."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)
    with open("/proc/self/statm", encoding="ascii") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def tracked_objects() -> int:
    gc.collect()
    return len(gc.get_objects())


@dataclass
class SoakReport:
    minutes: float  # simulated
    seed: int
    ticks: int = 0
    episodes: int = 0
    steps_landed: int = 0
    falls: int = 0
    faults: Counter[str] = field(default_factory=Counter)  # injected, by kind
    stops: Counter[str] = field(default_factory=Counter)  # entries into HOLD / FAULT, by cause kind
    resets_left_fault: int = 0
    violations: list[str] = field(default_factory=list)
    rss_by_episode: list[int] = field(default_factory=list)  # after each episode
    rss_start: int = 0
    rss_end: int = 0
    objects_start: int = 0
    objects_end: int = 0
    max_rss_growth: float = 0.05
    max_object_growth: float = 0.01

    @property
    def rss_growth(self) -> float:
        return (self.rss_end - self.rss_start) / self.rss_start if self.rss_start else 0.0

    @property
    def object_growth(self) -> float:
        return (self.objects_end - self.objects_start) / self.objects_start if self.objects_start else 0.0

    @property
    def passed(self) -> bool:
        return (not self.violations and self.rss_growth <= self.max_rss_growth
                and self.object_growth <= self.max_object_growth)

    def as_dict(self) -> dict[str, Any]:
        return {
            "passed": self.passed,
            "simulated_minutes": round(self.ticks / TICKS_PER_MIN, 2),
            "mode": "sagittal",
            "seed": self.seed,
            "ticks": self.ticks,
            "episodes": self.episodes,
            "steps_landed": self.steps_landed,
            "falls": self.falls,
            "faults_injected": dict(sorted(self.faults.items())),
            "stops": dict(sorted(self.stops.items())),
            "resets_that_left_fault": self.resets_left_fault,
            "invariant_violations": len(self.violations),
            "first_violations": self.violations[:10],
            "rss_mib": {"start": round(self.rss_start / 2**20, 1), "end": round(self.rss_end / 2**20, 1),
                        "growth": round(self.rss_growth, 4), "limit": self.max_rss_growth,
                        "by_episode": [round(r / 2**20, 1) for r in self.rss_by_episode]},
            "objects": {"start": self.objects_start, "end": self.objects_end,
                        "growth": round(self.object_growth, 4), "limit": self.max_object_growth},
        }


class _Faults:
    """Random faults for one episode (see the module doc)."""

    def __init__(self, rng: np.random.Generator, per_min: float) -> None:
        self.rng, self.p = rng, per_min / TICKS_PER_MIN
        catalog = default_catalog()
        self.nodes = catalog.joint_nodes
        self.node_frames = {n: frozenset(m.frame_id for m in catalog.sent_by(n)) for n in self.nodes}
        self.controller_frames = frozenset(m.frame_id for m in catalog.sent_by("CONTROLLER"))

    def maybe(self, rig: FaultRig, counts: Counter[str]) -> None:
        rng = self.rng
        if rng.random() >= self.p:
            return
        t0, ticks = rig.tick + 1, int(rng.integers(1, 11))
        node = self.nodes[int(rng.integers(len(self.nodes)))]
        if rng.random() < 0.7:
            kind = BUS_KINDS[int(rng.integers(len(BUS_KINDS)))]
            tx = kind == "send_failure"
            rig.inject_bus(BusFault(
                kind, "tx" if tx else "rx", frame_ids=self.controller_frames if tx else self.node_frames[node],
                start_tick=t0, end_tick=t0 + ticks, probability=float(rng.choice([1.0, 0.5, 0.1])),
                delay_ticks=int(rng.integers(1, 6)), bits=int(rng.integers(1, 4)),
            ))
        else:
            kind = NODE_KINDS[int(rng.integers(len(NODE_KINDS)))]
            rig.inject_node(kind, node, start_tick=t0, end_tick=t0 + ticks)
        counts[kind] += 1


def soak(
    cfg: Config, *, minutes: float, seed: int = 0, faults_per_min: float = 6.0, episode_ticks: int = 1500,
    reset_after_ticks: int = 50, progress: Callable[[SoakReport], None] | None = None,
) -> SoakReport:
    steady_allocator()
    report = SoakReport(minutes=minutes, seed=seed)
    target = int(minutes * TICKS_PER_MIN)
    seeds = np.random.SeedSequence(seed)
    while report.ticks < target:
        episode_seed = int(seeds.spawn(1)[0].generate_state(1)[0])
        _episode(cfg, episode_seed, min(episode_ticks, target - report.ticks), faults_per_min, reset_after_ticks, report)
        report.episodes += 1
        report.rss_by_episode.append(rss_bytes())
        if report.episodes == WARM_UP:
            report.rss_start, report.objects_start = rss_bytes(), tracked_objects()
        if progress is not None:
            progress(report)
    report.rss_end, report.objects_end = rss_bytes(), tracked_objects()
    if report.episodes <= WARM_UP:  # too short to compare anything: the end is the baseline
        report.rss_start, report.objects_start = report.rss_end, report.objects_end
    return report


def _episode(cfg: Config, seed: int, ticks: int, faults_per_min: float, reset_after: int, report: SoakReport) -> None:
    faults = _Faults(np.random.default_rng(seed), faults_per_min)
    with FaultRig(cfg, seed=seed % 2**31, tick_timeout_s=0.005, keep_results=False) as rig:
        rig.operator.start()
        stopped_at: int | None = None
        for _ in range(ticks):
            faults.maybe(rig, report.faults)
            before = rig.state
            rig.step()
            state = rig.state
            if state in (GaitState.HOLD, GaitState.FAULT):
                if before not in (GaitState.HOLD, GaitState.FAULT):
                    stopped_at = rig.tick
                    report.stops[rig.core.fsm.transitions[-1].fault.kind.name] += 1
                elif stopped_at is not None and rig.tick - stopped_at >= reset_after and rig.tick % reset_after == 0:
                    rig.operator.reset()  # the operator, after a while; the FSM decides
            elif before == GaitState.FAULT:
                report.resets_left_fault += 1
                rig.operator.start()
            elif before == GaitState.HOLD:
                rig.operator.start()
            if rig.host.plant.patient.fall is not None:
                report.falls += 1
                break
        report.ticks += rig.oracle.ticks
        report.steps_landed += sum(s.landed for s in rig.core.steps)
        report.violations += [f"episode {report.episodes} (seed {seed}): {v}" for v in rig.oracle.violations]
