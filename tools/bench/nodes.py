"""Nodes speed: lock-step ticks per second of the simulation plus the four node boards plus the
codec, against the bare simulation tick measured inside the same run.

A scripted controller on the in-process virtual bus sends what the main controller sends every
tick (SYNC, four joint commands, its heartbeat every fifth tick) and reads the nodes' frames back.
The nodes' work per tick (receive and check every frame, firmware, apply the commands, one 20 ms
physics tick with the patient and the sensors, encode and send 11-15 frames) is timed around the
host's poll; the simulation tick inside it (:meth:`sim.walk.Walker.tick`: patient, physics,
sensors) is timed on its own, so "bare simulation" and "everything else" come from one run.
"""

from __future__ import annotations

import argparse
import os
import platform
from typing import Any

from config import ConfigError, default_config_path, load_config, with_overrides
from protocol.bus import virtual_bus
from protocol.clock import TICK_S, MonotonicClock

GOAL_OVERHEAD_PERCENT = 25.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--ticks", type=int, default=500, help="lock-step ticks per model mode (default 500 = 10 s)")


def _run_mode(cfg: Any, mode: str, ticks: int) -> dict[str, Any]:
    from nodes.host import NodesHost
    from sim.plant import PlantTickTimer  # PyBullet loads only when this benchmark runs
    from protocol.codec import Codec, Decoded
    from protocol.e2e import Receiver, Transmitter
    from protocol.enums import GaitState, JointMode, NmtCommand

    clock = MonotonicClock()
    cfg = with_overrides(cfg, {"sim.mode": mode, "bus.interface": "virtual", "bus.channel": f"bench-nodes-{mode}"})
    codec = Codec()
    tx, rx = Transmitter(codec), Receiver(codec)
    with virtual_bus(cfg.bus.channel) as ctl, \
            virtual_bus(cfg.bus.channel) as node_bus:
        host = NodesHost(cfg, node_bus, lockstep=True, seed=0, clock=clock, codec=codec)
        try:
            sim = PlantTickTimer(host.plant, clock)
            host_ns = 0

            def poll() -> None:
                nonlocal host_ns
                start = clock.now_ns()
                host.poll(0.0)
                host_ns += clock.now_ns() - start

            host.boot()
            ctl.send(tx.message("NMT_COMMAND", {"command": int(NmtCommand.START), "node_id": 0}))
            poll()
            hold = (int(JointMode.HOLD), 0.0, 0.0, 0.0, 80.0)
            commands = [codec.spec(f"JOINT_COMMAND_{j}") for j in ("LH", "LK", "RH", "RK")]
            received = 0
            start = clock.now_ns()
            for k in range(ticks):
                ctl.send(tx.message("SYNC", (k,)))
                poll()
                while (msg := ctl.recv(timeout=0)) is not None:
                    received += type(rx.receive(msg)) is Decoded
                if k % 5 == 0:
                    ctl.send(tx.message("CONTROLLER_HEARTBEAT", (int(GaitState.STAND),)))
                for spec in commands:
                    ctl.send(tx.message(spec, hold))
                poll()
            total_ns = clock.now_ns() - start
            status = host.status()
        finally:
            host.close()
    simulated = ticks * TICK_S
    return {
        "mode": mode,
        "ticks": ticks,
        "frames_from_nodes": received,
        "rejected_by_nodes": status["receiver"]["rejected"],
        "fell": status["fall"] is not None,
        "ticks_per_s_nodes": round(ticks / (host_ns / 1e9), 1),
        "ticks_per_s_bare_sim": round(ticks / (sim.ns / 1e9), 1),
        "realtime_factor_nodes": round(simulated / (host_ns / 1e9), 2),
        "overhead_percent": round(100.0 * (host_ns - sim.ns) / sim.ns, 1),
        "us_per_tick_nodes_and_codec": round((host_ns - sim.ns) / 1e3 / ticks, 1),
        "us_per_tick_sim": round(sim.ns / 1e3 / ticks, 1),
        "us_per_tick_scripted_controller": round((total_ns - host_ns) / 1e3 / ticks, 1),
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.ticks <= 0:
        raise ConfigError("--ticks must be positive")
    cfg = load_config(args.config or default_config_path())
    if cfg.sim is None or cfg.nodes is None:
        raise ConfigError("sim and nodes sections required by the nodes benchmark", key="nodes")
    return {
        "benchmark": "nodes",
        "modes": [_run_mode(cfg, mode, args.ticks) for mode in ("full3d", "sagittal")],
        "goals": {"overhead_percent_max": GOAL_OVERHEAD_PERCENT},
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine()},
    }


def format_text(r: dict[str, Any]) -> str:
    lines = [
        "nodes benchmark: lock-step, four node boards + codec + simulation, against the simulation alone (same run)",
        f"{'mode':<10}{'ticks/s':>9}{'bare sim':>10}{'overhead':>10}{'nodes us':>10}{'sim us':>9}{'x real time':>13}",
    ]
    for m in r["modes"]:
        lines.append(
            f"{m['mode']:<10}{m['ticks_per_s_nodes']:>9.0f}{m['ticks_per_s_bare_sim']:>10.0f}{m['overhead_percent']:>9.1f}%"
            f"{m['us_per_tick_nodes_and_codec']:>10.0f}{m['us_per_tick_sim']:>9.0f}{m['realtime_factor_nodes']:>12.1f}x"
        )
    lines.append(f"goal: the nodes and the codec add at most {r['goals']['overhead_percent_max']:.0f} % to the simulation")
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    return [
        (f"{m['mode']}: the four boards and the codec over the simulation", f"{m['overhead_percent']:.1f} % "
         f"({m['us_per_tick_nodes_and_codec']:.0f} us a tick)", f"at most {r['goals']['overhead_percent_max']:.0f} %")
        for m in r["modes"]
    ]
