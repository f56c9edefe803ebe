"""``aider-exo bench``: benchmarks that print figures, each beside its baseline in the same run."""

from __future__ import annotations

import argparse
import importlib

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


def run(args: argparse.Namespace) -> int:
    result = args.bench_module.run(args)
    if args.json:
        print_json(result)
    else:
        print(args.bench_module.format_text(result), end="")
    return 0
