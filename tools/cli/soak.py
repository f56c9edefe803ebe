"""aider-exo soak: long lock-step walking under seeded random faults, invariants on every tick.

The controller, the node boards and the simulated HHEA (sagittal mode) in lock-step on the
in-process bus, in episodes of a fresh world, with seeded random bus and node faults; the operator
resets after each HOLD or FAULT and walks on. Checks docs/FAULTS.md's invariants I1-I7 on every tick
and the process's resident memory and object count between the first episode and the end. Exit
status 1 when an invariant broke or memory grew beyond its limit (docs/SAFETY.md).
"""

from __future__ import annotations

import argparse
import sys

from tools.cli.common import add_config_options, load_cli_config, positive_float, print_json, seed_type


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "soak",
        help="walk for a long time under random faults, checking the safety invariants and memory",
        description=__doc__,
    )
    add_config_options(p)
    p.add_argument("--minutes", type=positive_float, default=30.0, help="simulated minutes of walking (default 30)")
    p.add_argument("--seed", type=seed_type, default=0, help="seed of the faults, the patient and the sensors (default 0)")
    p.add_argument("--faults-per-min", type=positive_float, default=6.0,
                   help="random faults per simulated minute, on average (default 6)")
    p.add_argument("--json", action="store_true", help="machine-readable report on stdout")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def _progress(report, target_min: float, clock, t0: int) -> None:
    from tools.safety.soak import TICKS_PER_MIN

    done = report.ticks / TICKS_PER_MIN
    elapsed = (clock.now_ns() - t0) / 1e9
    print(f"soak: {done:5.1f}/{target_min:g} simulated min, {report.episodes} episodes, {sum(report.faults.values())} faults, "
          f"{sum(report.stops.values())} stops, {report.falls} falls, {len(report.violations)} violations, {elapsed:.0f} s",
          file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    from protocol.clock import MonotonicClock
    from tools.safety.soak import soak

    cfg = load_cli_config(args, needs=("controller", "sim", "nodes"))
    clock = MonotonicClock()
    t0 = clock.now_ns()
    report = soak(cfg, minutes=args.minutes, seed=args.seed, faults_per_min=args.faults_per_min,
                  progress=None if args.quiet else lambda r: _progress(r, args.minutes, clock, t0))
    out = report.as_dict()
    out["wall_time_s"] = round((clock.now_ns() - t0) / 1e9, 1)
    if args.json:
        print_json(out)
    else:
        verdict = "passed" if report.passed else "FAILED"
        print(f"soak {verdict}: {out['simulated_minutes']} simulated min in {out['wall_time_s']} s, {report.episodes} episodes, "
              f"{report.steps_landed} steps, {sum(report.faults.values())} faults -> {sum(report.stops.values())} stops, "
              f"{report.falls} falls, {len(report.violations)} invariant violations; resident memory "
              f"{out['rss_mib']['start']} -> {out['rss_mib']['end']} MiB ({report.rss_growth:+.1%}), objects "
              f"{report.objects_start} -> {report.objects_end} ({report.object_growth:+.2%})")
        for v in report.violations[:10]:
            print(f"  {v}")
    return 0 if report.passed else 1
