"""``aider-exo``: one entry point, one module per subcommand.

Each subcommand module defines ``add_parser(subparsers)`` (which sets ``func`` on its parser) and
has no side effects at import. Project errors (:class:`config.AiderError`) print as one line
(``aider-exo: error: ...``) and exit 1; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import Sequence

from config.loader import AiderError

#: subcommand name -> module under tools.cli
SUBCOMMANDS = {
    "protocol": "tools.cli.protocol",
    "buscheck": "tools.cli.buscheck",
    "bench": "tools.cli.bench",
    "sim": "tools.cli.sim",
    "dmp": "tools.cli.dmp",
    "nodes": "tools.cli.nodes",
    "controller": "tools.cli.controller",
    "walk": "tools.cli.walk",
    "trace": "tools.cli.trace",
    "experiment": "tools.cli.experiment",
    "soak": "tools.cli.soak",
    "view": "tools.cli.view",
    "population": "tools.cli.population",
    "config": "tools.cli.config",
}


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("aider-exo")
    except metadata.PackageNotFoundError:  # run from a checkout that is not installed
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="aider-exo",
        description="Walking-assistance exoskeleton controller after Chen et al., ICMA 2017.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in SUBCOMMANDS.values():
        importlib.import_module(module).add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except AiderError as exc:
        if args.debug:
            raise
        print(f"aider-exo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("aider-exo: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`aider-exo protocol --json | head`): stop quietly.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
