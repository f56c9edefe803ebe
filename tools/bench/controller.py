"""Controller speed: its work per tick, the lock-step pipeline against the bare simulation, and the
real-time loop's wake-up lateness beside a plain sleep loop, all in one run.

1. Lock-step, in process: the controller's loop (SYNC, reading and checking the nodes' frames,
   supervision, estimation, FSM, envelope, encoding) against the four emulated nodes and the
   simulation. The controller's own work per tick excludes the time the nodes take; the pipeline's
   ticks per second are set beside the bare simulation tick timed inside the same run.
2. Real time: the controller's loop on absolute 20 ms deadlines with the nodes in a thread of the
   same process (so the nodes' physics competes with the loop for the interpreter lock, a harsher
   setting than the two processes of a deployment), and a plain ``sleep(deadline - now)`` loop as
   the baseline, one after the other in this run. Wake-up lateness: min, avg, p99, max.
"""

from __future__ import annotations

import argparse
import os
import platform
from typing import Any

import numpy as np

from config import ConfigError, default_config_path, load_config, with_overrides
from protocol.clock import MonotonicClock

GOAL_WORK_P99_US = 1000.0
GOAL_PIPELINE_RATIO = 0.7


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--ticks", type=int, default=500, help="lock-step ticks (default 500 = 10 s simulated)")
    parser.add_argument("--realtime-ticks", type=int, default=250, help="real-time ticks for each loop (default 250 = 5 s)")


def _lockstep(cfg: Any, ticks: int) -> dict[str, Any]:
    import can

    from controller.core import ControllerCore
    from controller.loop import LockstepLoop
    from nodes.host import NodesHost, SimTickTimer

    clock = MonotonicClock()
    cfg = with_overrides(cfg, {"bus.interface": "virtual", "bus.channel": "bench-controller"})
    with can.Bus(interface="virtual", channel=cfg.bus.channel, ignore_config=True) as node_bus, \
            can.Bus(interface="virtual", channel=cfg.bus.channel, ignore_config=True) as ctl_bus:
        host = NodesHost(cfg, node_bus, lockstep=True, seed=0, clock=clock)
        try:
            sim = SimTickTimer(host, clock)
            host.boot()
            loop = LockstepLoop(ControllerCore(cfg.controller), ctl_bus, pump=lambda: host.poll(0.0), clock=clock)
            start = clock.now_ns()
            for _ in range(ticks):
                result = loop.step()
            total_ns = clock.now_ns() - start
        finally:
            host.close()
    n = min(loop.stats.count, loop.stats.work_ns.size)
    work_us = loop.stats.work_ns[:n] / 1e3
    physics_ticks = host.stats.physics_ticks
    return {
        "ticks": ticks,
        "final_state": result.state.name,
        "controller_work_us": {
            "p50": round(float(np.percentile(work_us, 50)), 1),
            "p99": round(float(np.percentile(work_us, 99)), 1),
            "max": round(float(work_us.max()), 1),
        },
        "pipeline_ticks_per_s": round(ticks / (total_ns / 1e9), 1),
        "bare_sim_ticks_per_s": round(physics_ticks / (sim.ns / 1e9), 1),
        "pipeline_to_bare_sim": round((ticks / total_ns) / (physics_ticks / sim.ns), 3),
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


def _realtime(cfg: Any, ticks: int) -> dict[str, Any]:
    import can

    from controller.core import ControllerCore
    from controller.loop import RealtimeLoop
    from nodes.host import NodesHost, running_in_thread

    cfg = with_overrides(cfg, {"bus.interface": "virtual", "bus.channel": "bench-controller-rt"})
    with can.Bus(interface="virtual", channel=cfg.bus.channel, ignore_config=True) as node_bus, \
            can.Bus(interface="virtual", channel=cfg.bus.channel, ignore_config=True) as ctl_bus:
        host = NodesHost(cfg, node_bus, lockstep=False, seed=0)
        try:
            with running_in_thread(host):
                loop = RealtimeLoop(ControllerCore(cfg.controller), ctl_bus)
                for _ in range(ticks):
                    result = loop.step()
        finally:
            host.close()
    s = loop.stats.summary()
    return {
        "ticks": ticks,
        "final_state": result.state.name,
        "wakeup_lateness": s["wakeup_lateness"],
        "controller_work": s["work"],
        "overruns": s["overruns"],
        "skipped_ticks": s["skipped_ticks"],
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.ticks <= 0 or args.realtime_ticks <= 0:
        raise ConfigError("--ticks and --realtime-ticks must be positive")
    cfg = load_config(args.config or default_config_path())
    if cfg.sim is None or cfg.nodes is None or cfg.controller is None:
        raise ConfigError("controller, sim and nodes sections required by the controller benchmark", key="controller")
    return {
        "benchmark": "controller",
        "lockstep": _lockstep(cfg, args.ticks),
        "realtime": _realtime(cfg, args.realtime_ticks),
        "plain_sleep_loop": {"ticks": args.realtime_ticks, "wakeup_lateness": _plain_sleep_loop(args.realtime_ticks)},
        "goals": {"controller_work_p99_us_max": GOAL_WORK_P99_US, "pipeline_to_bare_sim_min": GOAL_PIPELINE_RATIO},
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine()},
    }


def format_text(r: dict[str, Any]) -> str:
    ls, rt, plain = r["lockstep"], r["realtime"], r["plain_sleep_loop"]["wakeup_lateness"]
    w = ls["controller_work_us"]
    lat = rt["wakeup_lateness"]
    return "\n".join([
        f"controller benchmark ({ls['ticks']} lock-step ticks, {rt['ticks']} real-time ticks; final state {ls['final_state']})",
        f"controller work per tick: p50 {w['p50']:.0f} us, p99 {w['p99']:.0f} us, max {w['max']:.0f} us "
        f"(goal: p99 at most {r['goals']['controller_work_p99_us_max']:.0f} us)",
        f"lock-step pipeline {ls['pipeline_ticks_per_s']:.0f} ticks/s, bare simulation {ls['bare_sim_ticks_per_s']:.0f} ticks/s: "
        f"{ls['pipeline_to_bare_sim']:.2f} of it (goal at least {r['goals']['pipeline_to_bare_sim_min']})",
        f"real-time wake-up lateness: controller loop p99 {lat['p99_us']:.0f} us, max {lat['max_us']:.0f} us "
        f"(overruns {rt['overruns']}); plain sleep loop p99 {plain['p99_us']:.0f} us, max {plain['max_us']:.0f} us",
    ]) + "\n"
