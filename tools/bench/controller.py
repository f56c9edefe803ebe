"""Controller speed while walking: its work per tick, the lock-step pipeline against the bare
physics and the bare simulation, and the real-time loop's wake-up lateness beside a plain sleep
loop, all in one run.

Every figure comes from a walk: the controller brings the nodes up, walks ``--cycles`` gait
cycles (sagittal mode, seed 0, the compensated step length) and the figures are taken over the
ticks in which it walks (DOUBLE_SUPPORT, SWING_LEFT, SWING_RIGHT), not the start-up and standing.

1. Lock-step, in process (:func:`tools.pipeline.drive`, as ``aider-exo walk``): the controller's loop
   (SYNC, reading and checking the nodes' frames, supervision, estimation, FSM, gait, envelope,
   encoding) against the four emulated nodes and the simulation. The controller's own work per
   tick excludes the time the nodes take; the pipeline's walking ticks per second are set beside
   the bare physics (PyBullet's step, :class:`sim.world.PhysicsTimer`) and the bare simulation
   tick (:class:`sim.plant.PlantTickTimer`), both timed over the same ticks; ``--repeats`` walks,
   each figure their median.
2. Real time: the controller's loop on absolute 20 ms deadlines walks ``--realtime-cycles`` with
   the nodes in real time in a thread of the same process (the nodes' physics competes with the
   loop for the interpreter lock, a harsher setting than the two processes of a deployment), then
   a plain ``sleep(deadline - now)`` loop as the baseline for as many ticks. Wake-up lateness:
   min, avg, p99, max; overruns of the controller loop and of the nodes' physics timer. Both loops
   run at normal priority (no real-time set-up), so the comparison is the loop's own cost.
"""

from __future__ import annotations

import argparse
import os
import platform
from typing import Any

import numpy as np

from config import ConfigError, default_config_path, load_config, with_overrides
from protocol.bus import virtual_bus
from protocol.clock import MonotonicClock
from protocol.enums import WALKING
from tools.bench import median_of_runs

# issue 29's goals
GOAL_WORK_P50_US = 120.0
GOAL_WORK_P99_US = 300.0
GOAL_PIPELINE_TO_PHYSICS = 0.5  # the lock-step pipeline's ticks per second over bare physics' ticks per second
MODE = "sagittal"  # the mode that walks (docs/SIM.md)
SEED = 0
WALKING_NAMES = tuple(s.name for s in WALKING)  # the states as the walks record them


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--cycles", type=int, default=2, help="gait cycles walked in lock-step (default 2)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="lock-step walks; their figures are the medians (default 3; the walks are the same)")
    parser.add_argument("--realtime-cycles", type=int, default=2,
                        help="gait cycles walked in real time (default 2, about 25 s; the plain sleep loop runs as long again)")
    parser.add_argument("--max-ticks", type=int,
                        help="end each walk after at most this many ticks (a short run; default: the walk's stall limit)")


def _percentiles(ns: np.ndarray) -> dict[str, float] | None:
    if ns.size == 0:
        return None
    us = ns / 1e3
    return {
        "p50": round(float(np.percentile(us, 50)), 1),
        "p99": round(float(np.percentile(us, 99)), 1),
        "max": round(float(us.max()), 1),
    }


def _walk_summary(outcome: Any, states: list[str]) -> dict[str, Any]:
    return {
        "cycles_completed": outcome.cycles_completed,
        "steps_completed": len(outcome.landed),
        "fall": outcome.fall_reason,
        "fault": outcome.fault,
        "hold": outcome.hold,
        "final_state": outcome.final_state,
        "ticks": len(states),
        "walking_ticks": sum(s in WALKING_NAMES for s in states),
    }


def _max_ticks(max_ticks: int | None, cycles: int) -> int:
    """Ticks a walk of ``cycles`` may take: the walk's own stall limit, or ``max_ticks`` if fewer."""
    from protocol.clock import TICK_MS
    from tools.pipeline import default_max_time_s

    limit = int(default_max_time_s(cycles) * 1000 / TICK_MS)
    return limit if max_ticks is None else min(limit, max_ticks)


def _lockstep(cfg: Any, cycles: int, max_ticks: int) -> dict[str, Any]:
    from controller.core import ControllerCore
    from controller.hardware import CanHardware
    from controller.loop import LockstepLoop
    from controller.session import Session
    from nodes.host import NodesHost
    from sim.plant import PlantTickTimer
    from sim.world import PhysicsTimer
    from tools.pipeline import WalkOutcome, drive, walk_config

    clock = MonotonicClock()
    cfg = walk_config(cfg, MODE, "bench-controller")
    states: list[str] = []
    end_ns: list[int] = []  # per tick: when it ended
    sim_ns: list[int] = []  # per tick: the bare simulation's time so far
    physics_ns: list[int] = []  # per tick: the bare physics' (PyBullet's step's) time so far
    with virtual_bus(cfg.bus.channel) as node_bus, \
            virtual_bus(cfg.bus.channel) as ctl_bus:
        host = NodesHost(cfg, node_bus, lockstep=True, seed=SEED, clock=clock)
        try:
            sim = PlantTickTimer(host.plant, clock)
            physics = PhysicsTimer(host.plant.patient.world, clock)
            host.boot()
            core = ControllerCore(cfg.controller)
            loop = LockstepLoop(core, CanHardware(cfg.controller, ctl_bus, pump=lambda: host.poll(0.0), clock=clock,
                                                  max_delta_counter=cfg.protocol.max_delta_counter))
            session = Session(loop)
            outcome = WalkOutcome(mode=MODE, seed=SEED, policy=core.policy.mode, steps=core.steps)

            def on_tick(result: Any, _session: Any) -> None:
                states.append(result.state.name)
                end_ns.append(clock.now_ns())
                sim_ns.append(sim.ns)
                physics_ns.append(physics.ns)

            start = clock.now_ns()
            drive(session, outcome, cycles=cycles, max_ticks=max_ticks, fallen=lambda: host.plant.patient.fall, on_tick=on_tick)
            physics_ticks = host.stats.physics_ticks
        finally:
            host.close()
    n = len(states)
    walking = np.array([s in WALKING_NAMES for s in states], dtype=bool)
    wall = np.diff(np.array([start, *end_ns], dtype=np.int64))  # each tick: controller + nodes + simulation
    sim_tick = np.diff(np.array([0, *sim_ns], dtype=np.int64))
    physics_tick = np.diff(np.array([0, *physics_ns], dtype=np.int64))
    work = loop.stats.work_ns[:n]
    walk_wall_s, walk_sim_s, walk_physics_s = (x[walking].sum() / 1e9 for x in (wall, sim_tick, physics_tick))
    walk_ticks = int(walking.sum())
    return {
        "walk": _walk_summary(outcome, states),
        "physics_ticks": physics_ticks,
        "controller_work_us": _percentiles(work[walking]),
        "controller_work_us_all_ticks": _percentiles(work),
        "controller_work_us_swing": _percentiles(work[np.array([s.startswith("SWING") for s in states], dtype=bool)]),
        "pipeline_ticks_per_s": round(walk_ticks / walk_wall_s, 1) if walk_ticks else None,
        "bare_sim_ticks_per_s": round(walk_ticks / walk_sim_s, 1) if walk_ticks else None,
        "pipeline_to_bare_sim": round(walk_sim_s / walk_wall_s, 3) if walk_ticks else None,
        "bare_physics_ticks_per_s": round(walk_ticks / walk_physics_s, 1) if walk_ticks else None,
        "pipeline_to_bare_physics": round(walk_physics_s / walk_wall_s, 3) if walk_ticks else None,
        "us_per_walking_tick": {
            "pipeline": round(walk_wall_s / walk_ticks * 1e6, 1) if walk_ticks else None,
            "simulation": round(walk_sim_s / walk_ticks * 1e6, 1) if walk_ticks else None,
            "physics": round(walk_physics_s / walk_ticks * 1e6, 1) if walk_ticks else None,
        },
    }


def _plain_sleep_loop(ticks: int) -> dict[str, Any]:
    from controller.timing import TickStats

    clock = MonotonicClock()
    stats = TickStats(20_000_000, capacity=ticks)
    deadline = clock.now_ns()
    for _ in range(ticks):
        deadline += 20_000_000
        clock.sleep_until(deadline)
        stats.record(max(0, clock.now_ns() - deadline), 0)
    return stats.summary()["wakeup_lateness"]


def _realtime(cfg: Any, cycles: int, max_ticks: int) -> dict[str, Any]:
    from controller.core import ControllerCore
    from controller.hardware import CanHardware
    from controller.loop import RealtimeLoop
    from controller.session import Session
    from controller.timing import TickStats
    from nodes.host import NodesHost, running_in_thread
    from tools.pipeline import WalkOutcome, drive, walk_config

    cfg = walk_config(cfg, MODE, "bench-controller-rt")
    states: list[str] = []
    with virtual_bus(cfg.bus.channel) as node_bus, \
            virtual_bus(cfg.bus.channel) as ctl_bus:
        host = NodesHost(cfg, node_bus, lockstep=False, seed=SEED)
        try:
            with running_in_thread(host):
                core = ControllerCore(cfg.controller)
                loop = RealtimeLoop(core, CanHardware(cfg.controller, ctl_bus, max_delta_counter=cfg.protocol.max_delta_counter))
                session = Session(loop)
                outcome = WalkOutcome(mode=MODE, seed=SEED, policy=core.policy.mode, steps=core.steps)
                drive(session, outcome, cycles=cycles, max_ticks=max_ticks, fallen=lambda: host.plant.patient.fall,
                      on_tick=lambda result, _session: states.append(result.state.name))
            nodes = host.status()
        finally:
            host.close()
    n = len(states)
    walking = np.array([s in WALKING_NAMES for s in states], dtype=bool)
    s = loop.stats.summary()
    return {
        "walk": _walk_summary(outcome, states),
        "wakeup_lateness": TickStats._summary(loop.stats.late_ns[:n][walking]),
        "wakeup_lateness_all_ticks": s["wakeup_lateness"],
        "controller_work": TickStats._summary(loop.stats.work_ns[:n][walking]),
        "overruns": s["overruns"],
        "skipped_ticks": s["skipped_ticks"],
        "timeouts": loop.hardware.counters.timeouts,
        "nodes_overruns": nodes["overruns"],
        "rejected": loop.hardware.rx.stats.rejected_total,
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if min(args.cycles, args.realtime_cycles, args.repeats) <= 0 or (args.max_ticks is not None and args.max_ticks <= 0):
        raise ConfigError("--cycles, --realtime-cycles, --repeats and --max-ticks must be positive")
    cfg = load_config(args.config or default_config_path())
    if cfg.sim is None or cfg.nodes is None or cfg.controller is None:
        raise ConfigError("controller, sim and nodes sections required by the controller benchmark", key="controller")
    cfg = with_overrides(cfg, {"sim.mode": MODE})
    lockstep = median_of_runs([_lockstep(cfg, args.cycles, _max_ticks(args.max_ticks, args.cycles)) for _ in range(args.repeats)])
    realtime = _realtime(cfg, args.realtime_cycles, _max_ticks(args.max_ticks, args.realtime_cycles))
    plain_ticks = realtime["walk"]["ticks"]
    return {
        "benchmark": "controller",
        "mode": MODE,
        "seed": SEED,
        "cycles_asked": {"lockstep": args.cycles, "realtime": args.realtime_cycles},
        "lockstep_repeats": args.repeats,
        "lockstep": lockstep,
        "realtime": realtime,
        "plain_sleep_loop": {"ticks": plain_ticks, "wakeup_lateness": _plain_sleep_loop(plain_ticks)},
        "goals": {"controller_work_p50_us_max": GOAL_WORK_P50_US, "controller_work_p99_us_max": GOAL_WORK_P99_US,
                  "pipeline_to_bare_physics_min": GOAL_PIPELINE_TO_PHYSICS},
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                    "load_avg_1min": round(os.getloadavg()[0], 2)},
    }


def _walked(w: dict[str, Any], asked: int) -> str:
    end = (f"fell ({w['fall']})" if w["fall"] else f"FAULT ({w['fault']})" if w["fault"]
           else f"HOLD ({w['hold']})" if w["hold"] else "no fall")
    return (f"{w['cycles_completed']} of {asked} gait cycles, {end}, {w['ticks']} ticks "
            f"of which {w['walking_ticks']} walking")


def _us(x: float | None) -> str:
    if x is None:
        return "n/a"
    return f"{x / 1000:.2f} ms" if x >= 1000 else f"{x:.0f} us"


def format_text(r: dict[str, Any]) -> str:
    ls, rt, plain = r["lockstep"], r["realtime"], r["plain_sleep_loop"]["wakeup_lateness"]
    w = ls["controller_work_us"] or {"p50": None, "p99": None, "max": None}
    swing = ls["controller_work_us_swing"] or {"p99": None}
    lat = rt["wakeup_lateness"]
    goals = r["goals"]
    per_tick = ls["us_per_walking_tick"]
    rows = [
        ("controller work per tick, p50", _us(w["p50"]), f"at most {_us(goals['controller_work_p50_us_max'])}"),
        ("controller work per tick, p99", _us(w["p99"]),
         f"at most {_us(goals['controller_work_p99_us_max'])} (swing ticks alone: {_us(swing['p99'])})"),
        ("controller work per tick, max", _us(w["max"]), ""),
        ("lock-step pipeline / bare physics", "n/a" if ls["pipeline_to_bare_physics"] is None else f"{ls['pipeline_to_bare_physics']:.2f}",
         f"at least {goals['pipeline_to_bare_physics_min']} ({ls['pipeline_ticks_per_s']} against {ls['bare_physics_ticks_per_s']} ticks/s)"),
        ("lock-step pipeline / bare simulation", "n/a" if ls["pipeline_to_bare_sim"] is None else f"{ls['pipeline_to_bare_sim']:.2f}",
         f"{ls['bare_sim_ticks_per_s']} ticks/s: physics, patient, sensors, joint loops"),
        ("walking tick: pipeline / simulation / physics", " / ".join(_us(per_tick[k]) for k in ("pipeline", "simulation", "physics")), ""),
        ("real-time wake-up lateness, p99", _us(lat["p99_us"]), f"plain sleep loop {_us(plain['p99_us'])}"),
        ("real-time wake-up lateness, max", _us(lat["max_us"]), f"plain sleep loop {_us(plain['max_us'])}"),
        ("real-time controller work, p99 / max", f"{_us(rt['controller_work']['p99_us'])} / {_us(rt['controller_work']['max_us'])}", ""),
    ]
    lines = [
        f"controller benchmark, walking ({r['mode']}, seed {r['seed']}; figures over the walking ticks)",
        f"  lock-step, in process: {_walked(ls['walk'], r['cycles_asked']['lockstep'])} (median of {r['lockstep_repeats']} walks)",
        f"  real time, nodes in a thread: {_walked(rt['walk'], r['cycles_asked']['realtime'])}",
        (f"    overruns: controller {rt['overruns']} ({rt['skipped_ticks']} ticks skipped), nodes' physics timer "
         f"{rt['nodes_overruns']}; ticks whose node status missed the read window {rt['timeouts']}"),
        f"{'figure':<46}{'measured':>22}  goal / baseline (same run)",
    ]
    lines += [f"{name:<46}{value:>22}  {note}".rstrip() for name, value, note in rows]
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    ls, rt, g = r["lockstep"], r["realtime"], r["goals"]
    w, lat, plain = ls["controller_work_us"], rt["wakeup_lateness"], r["plain_sleep_loop"]["wakeup_lateness"]
    return [
        ("controller work per tick (lock-step walk), p50 / p99 / max", f"{_us(w['p50'])} / {_us(w['p99'])} / {_us(w['max'])}",
         f"p50 at most {_us(g['controller_work_p50_us_max'])}, p99 at most {_us(g['controller_work_p99_us_max'])}"),
        ("lock-step pipeline / bare physics; / bare simulation",
         f"{ls['pipeline_to_bare_physics']:.2f}; {ls['pipeline_to_bare_sim']:.2f} ({ls['pipeline_ticks_per_s']:.0f} ticks/s)",
         f"at least {g['pipeline_to_bare_physics_min']} of bare physics ({ls['bare_physics_ticks_per_s']:.0f} ticks/s)"),
        ("real-time wake-up lateness, p99 / max", f"{_us(lat['p99_us'])} / {_us(lat['max_us'])}",
         f"plain sleep loop {_us(plain['p99_us'])} / {_us(plain['max_us'])}"),
        ("real-time controller work, p99 / max", f"{_us(rt['controller_work']['p99_us'])} / {_us(rt['controller_work']['max_us'])}",
         f"overruns {rt['overruns']}"),
    ]
