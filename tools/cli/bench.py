"""``aider-exo bench``: benchmarks that print figures, each beside its baseline in the same run."""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from tools.cli.common import print_json

#: benchmark name -> module under tools.bench with ``add_arguments(parser)`` and ``run(args) -> dict``
BENCHMARKS = {
    "codec": "tools.bench.codec",
    "sim": "tools.bench.sim",
    "algorithms": "tools.bench.algorithms",
    "nodes": "tools.bench.nodes",
    "controller": "tools.bench.controller",
    "trace": "tools.bench.trace",
    "profile": "tools.bench.profile",
    "view": "tools.bench.view",
    "executor": "tools.bench.executor",
}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its figures")
    bench_sub = p.add_subparsers(dest="benchmark", metavar="BENCHMARK", required=True)
    for name, module_name in BENCHMARKS.items():
        module = importlib.import_module(module_name)
        bp = bench_sub.add_parser(name, help=module.__doc__.strip().splitlines()[0])
        bp.add_argument("--json", action="store_true", help="machine-readable output")
        module.add_arguments(bp)
        bp.set_defaults(func=run, bench_module=module)
    every = bench_sub.add_parser("all", help="run every benchmark, each its own process, into DIR/NAME.json (make perf)")
    every.add_argument("--out", type=Path, default=Path("docs/perf"), metavar="DIR", help="results directory (default docs/perf)")
    every.add_argument("--only", nargs="+", choices=list(BENCHMARKS), metavar="NAME", help="these benchmarks only")
    every.add_argument("--json", action="store_true", help="the seconds each benchmark took, as JSON")
    every.set_defaults(func=run_all)
    table = bench_sub.add_parser("table", help="the figures of DIR/*.json as one table (docs/PERFORMANCE.md's)")
    table.add_argument("results", type=Path, metavar="DIR", help="what `bench all --out DIR` wrote")
    table.add_argument("--update", type=Path, metavar="FILE", help="rewrite the table between FILE's bench-table markers")
    table.add_argument("--json", action="store_true", help="the rows as JSON")
    table.set_defaults(func=run_table)


def run(args: argparse.Namespace) -> int:
    result = args.bench_module.run(args)
    if args.json:
        print_json(result)
    else:
        print(args.bench_module.format_text(result), end="")
    return 0


def run_all(args: argparse.Namespace) -> int:
    from tools.bench.summary import run_all as run_every

    seconds = run_every(args.out, args.only or list(BENCHMARKS), lambda line: print(line, file=sys.stderr, flush=True))
    if args.json:
        print_json({"out": str(args.out), "seconds": seconds})
    else:
        print(f"{len(seconds)} benchmarks in {sum(seconds.values()):.0f} s into {args.out}: "
              + ", ".join(f"{name} {s:.0f} s" for name, s in seconds.items()))
    return 0


def run_table(args: argparse.Namespace) -> int:
    from tools.bench.summary import render, rows, update

    if args.json:
        print_json(rows(args.results, BENCHMARKS))
        return 0
    table = render(args.results, BENCHMARKS)
    if args.update:
        changed = update(args.update, table)
        print(f"{args.update}: {'table updated' if changed else 'table already up to date'}")
    else:
        print(table, end="")
    return 0
