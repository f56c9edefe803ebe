"""Where a walk's time goes, twice over the same lock-step walk (the controller, the four
emulated nodes, the simulation; as ``bench controller`` walks it):

1. unprofiled, the wall time of the pipeline's main functions per tick (:data:`TIMED`, each
   wrapped by a clock read; inclusive of what it calls; about 0.2 us per call added), the
   figures to trust for how many microseconds a part costs;
2. under Python's cProfile, every function ranked by its own time, and that time summed by part
   of the system: where to look inside a part.

PyBullet's step is its own entry (``physics_step``, :class:`sim.world.PhysicsTimer`); PyBullet's other C functions are called
through ``functools.partial``, which cProfile attributes to their Python caller. cProfile adds a
cost to every Python call, so Python's share is larger here than in the unprofiled walk: rank
with this, measure with ``bench sim`` and ``bench controller``.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import importlib
import pstats
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from config import ConfigError, default_config_path, load_config, with_overrides
from protocol.clock import MonotonicClock

#: parts of the system by where a function is defined (first match wins)
PARTS = (
    ("physics (PyBullet step)", "sim/world.py:physics_step"),
    ("simulation", "/sim/"),
    ("nodes", "/nodes/"),
    ("protocol", "/protocol/"),
    ("controller", "/controller/"),
    ("pipeline and benchmark", "/tools/"),
    ("numpy and scipy", "numpy"),
    ("numpy and scipy", "scipy"),
    ("python-can", "/can/"),
)


#: (depth, module, class.function) timed per tick without the profiler; a deeper entry is part of
#: the entry above it (inclusive times: a parent's is more than its children's sum)
TIMED = (
    (0, "nodes.host", "NodesHost.on_sync"),
    (1, "sim.walk", "Walker.tick"),
    (2, "sim.world", "World.step"),
    (3, "sim.world", "PhysicsTimer.physics_step"),
    (3, "sim.world", "World.read_joints"),
    (3, "sim.world", "World._hold_to_plane"),
    (2, "sim.patient", "Patient.balance"),
    (3, "sim.patient", "distribute"),
    (2, "sim.sensors", "Sensors.read"),
    (2, "sim.kinematics", "Kinematics.update"),
    (2, "sim.patient", "Patient.update"),
    (2, "sim.patient", "Patient.support_margin"),
    (2, "sim.walk", "Walker._fall_reason"),
    (1, "nodes.host", "NodesHost._report"),
    (1, "nodes.host", "NodesHost._apply"),
    (0, "controller.cansystem", "CanSystem.snapshot"),
    (1, "controller.cansystem", "CanSystem._measurements"),
    (0, "controller.core", "ControllerCore.update"),
    (1, "controller.estimator", "StateEstimator.update"),
    (1, "controller.core", "ControllerCore._command"),
    (1, "controller.gait", "GaitPlanner.double_support"),
    (1, "controller.gait", "GaitPlanner.swing"),
    (0, "protocol.e2e", "Receiver.receive"),
    (0, "controller.cansystem", "CanSystem.accept"),
    (0, "controller.hardware", "CanHardware._send"),
)


@contextlib.contextmanager
def _timed(clock: Any) -> Iterator[dict[str, int]]:
    """Wrap every :data:`TIMED` function (on its class or module) with a clock read; yields the
    nanoseconds spent in each by name, and restores the functions after."""
    spent: dict[str, int] = {}
    restore = []
    for _, module_name, name in TIMED:
        owner: Any = importlib.import_module(module_name)
        *path, attr = name.split(".")
        for part in path:
            owner = getattr(owner, part)
        inner = owner.__dict__[attr]
        spent[name] = 0

        def timed(*args: Any, _inner: Any = inner, _name: str = name, **kwargs: Any) -> Any:
            start = clock.now_ns()
            try:
                return _inner(*args, **kwargs)
            finally:
                spent[_name] += clock.now_ns() - start

        setattr(owner, attr, timed)
        restore.append((owner, attr, inner))
    try:
        yield spent
    finally:
        for owner, attr, inner in restore:
            setattr(owner, attr, inner)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML configuration (default: the packaged one)")
    parser.add_argument("--cycles", type=int, default=10, help="gait cycles walked (default 10)")
    parser.add_argument("--top", type=int, default=25, help="functions listed (default 25)")
    parser.add_argument("--out", help="also write the raw profile here (pstats format, for snakeviz or pstats)")


def _part(filename: str, name: str) -> str:
    where = f"{filename}:{name}"
    for part, marker in PARTS:
        if marker in where:
            return part
    return "Python built-ins and standard library"


def _label(filename: str, line: int, name: str) -> str:
    root = str(Path(__file__).resolve().parents[2]) + "/"
    if filename.startswith(root):
        return f"{filename.removeprefix(root)}:{line}({name})"
    if "site-packages/" in filename:
        return f"{filename.split('site-packages/', 1)[1]}:{line}({name})"
    return f"{filename}:{line}({name})" if filename != "~" else name


def run(args: argparse.Namespace) -> dict[str, Any]:
    from tools.bench.controller import MODE, SEED, _lockstep, _max_ticks

    if args.cycles <= 0 or args.top <= 0:
        raise ConfigError("--cycles and --top must be positive")
    cfg = load_config(args.config or default_config_path())
    if cfg.sim is None or cfg.nodes is None or cfg.controller is None:
        raise ConfigError("controller, sim and nodes sections required by the profile", key="controller")
    cfg = with_overrides(cfg, {"sim.mode": MODE})
    max_ticks = _max_ticks(None, args.cycles)  # the walk's own stall limit
    with _timed(MonotonicClock()) as spent:
        timed_walk = _lockstep(cfg, args.cycles, max_ticks)
    timed_ticks = timed_walk["walk"]["ticks"]
    pipeline_us = timed_walk["us_per_walking_tick"]["pipeline"]
    profiler = cProfile.Profile()
    profiler.enable()
    walk = _lockstep(cfg, args.cycles, max_ticks)
    profiler.disable()
    if args.out:
        profiler.dump_stats(args.out)
    stats = pstats.Stats(profiler).stats  # (file, line, name) -> (primitive calls, calls, own time, cumulative, callers)
    total = sum(own for _, _, own, _, _ in stats.values())
    rows = sorted(stats.items(), key=lambda kv: -kv[1][2])
    parts: dict[str, float] = {}
    for (filename, _, name), (_, _, own, _, _) in rows:
        part = _part(filename, name)
        parts[part] = parts.get(part, 0.0) + own
    ticks = walk["walk"]["ticks"]
    return {
        "benchmark": "profile",
        "mode": MODE,
        "seed": SEED,
        "walk": walk["walk"],
        "timed": {
            "ticks": timed_ticks,
            "pipeline_us_per_walking_tick": pipeline_us,
            "parts": [{"depth": depth, "function": name, "us_per_tick": round(spent[name] / timed_ticks / 1e3, 1)}
                      for depth, _, name in TIMED],
        },
        "profiled_s": round(total, 3),
        "us_per_tick": round(total / ticks * 1e6, 1) if ticks else None,
        "parts": [{"part": p, "own_s": round(t, 3), "share": round(t / total, 4)} for p, t in sorted(parts.items(), key=lambda kv: -kv[1])],
        "functions": [
            {"function": _label(f, line, name), "calls": calls, "own_s": round(own, 4), "share": round(own / total, 4),
             "cumulative_s": round(cum, 4)}
            for (f, line, name), (_, calls, own, cum, _) in rows[: args.top]
        ],
    }


def format_text(r: dict[str, Any]) -> str:
    w, t = r["walk"], r["timed"]
    lines = [
        f"wall time per tick, unprofiled ({t['ticks']} ticks; the pipeline {t['pipeline_us_per_walking_tick']:.0f} us per walking tick "
        "with these timers), inclusive:",
    ]
    lines += [f"  {'  ' * p['depth']}{p['function']:<{40 - 2 * p['depth']}}{p['us_per_tick']:8.1f} us" for p in t["parts"]]
    lines += [
        f"profile of a lock-step walk ({r['mode']}, seed {r['seed']}): {w['cycles_completed']} gait cycles, {w['ticks']} ticks, "
        f"{r['profiled_s']:.2f} s under cProfile ({r['us_per_tick']:.0f} us per tick; unprofiled figures: bench controller)",
        "own time by part of the system:",
    ]
    lines += [f"  {p['share'] * 100:5.1f} %  {p['own_s']:7.2f} s  {p['part']}" for p in r["parts"]]
    lines.append(f"functions by own time (top {len(r['functions'])}):")
    lines.append(f"  {'share':>7}  {'own s':>7}  {'calls':>8}  function")
    lines += [f"  {f['share'] * 100:5.1f} %  {f['own_s']:7.3f}  {f['calls']:>8}  {f['function']}" for f in r["functions"]]
    return "\n".join(lines) + "\n"


def table_rows(r: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The summary table's rows (docs/PERFORMANCE.md): figure, measured, goal or baseline."""
    physics = next(p for p in r["parts"] if p["part"].startswith("physics"))
    return [
        ("pipeline per walking tick, unprofiled (with the timers)", f"{r['timed']['pipeline_us_per_walking_tick']:.0f} us",
         f"{r['timed']['ticks']} ticks"),
        ("PyBullet's step, share of the profiled walk's own time", f"{physics['share'] * 100:.1f} %", "the rest is Python"),
    ]
