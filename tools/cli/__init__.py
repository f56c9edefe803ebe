"""``aider-exo``: one entry point, one module per subcommand.

Each subcommand module defines ``add_parser(subparsers)`` (which sets ``func`` on its parser) and
has no side effects at import. Project errors (:class:`config.AiderError`) and OS errors print as one line
(``aider-exo: error: ...``) and exit 1; ``--debug`` shows the traceback instead. Every usage error is
one line too (``aider-exo CMD: error: ... (see ... --help)``, exit 2).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from typing import Sequence

from config.errors import AiderError

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
    "record": "tools.cli.record",
    "experiment": "tools.cli.experiment",
    "soak": "tools.cli.soak",
    "view": "tools.cli.view",
    "population": "tools.cli.population",
    "config": "tools.cli.config",
}


#: top-level module of an optional dependency -> the extra of pyproject.toml that installs it. The core
#: (`pip install .`: the controller, the protocol, the configuration, the node firmware) needs none of
#: them; a command that does exits 1 with one line naming the extra (docs/DEPLOY.md).
EXTRAS = {
    "pybullet": "sim",
    "scipy": "sim",
    "PIL": "sim",
    "matplotlib": "sim",
    "aiohttp": "view",
    "ray": "cluster",
}


def _command(parser: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The command line's (sub)command as its parser names it: ``aider-exo sim walk``."""
    while True:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        chosen = getattr(args, subs[0].dest, None) if subs else None
        if chosen not in (subs[0].choices if subs else {}):
            return parser.prog
        parser = subs[0].choices[chosen]


def _missing_extra(exc: ModuleNotFoundError, command: str) -> AiderError | None:
    """The one-line error for a command that imported a module of an extra that is not installed."""
    module = (exc.name or "").split(".")[0]
    extra = EXTRAS.get(module)
    if extra is None:
        return None
    return AiderError(f"'{command}' needs the {extra} extra ({module} is not installed): pip install 'aider-exo[{extra}]'")


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("aider-exo")
    except metadata.PackageNotFoundError:  # run from a checkout that is not installed
        return "unknown (not installed)"


class _VersionAction(argparse.Action):
    """``--version``: the version, and how each of the per-tick numerics' modules runs (compiled,
    or interpreted and why: protocol/compiled.py)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from protocol.compiled import report

        modules = report()
        compiled = sum(how == "compiled" for how in modules.values())
        lines = [f"{parser.prog} {_version()}", f"compiled numerics: {compiled} of {len(modules)} modules"]
        lines += [f"  {name}: {how}" for name, how in modules.items() if how != "compiled"]
        print("\n".join(lines))
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    from tools.cli.common import OneLineParser

    parser = OneLineParser(  # every parser error one line (subparsers inherit the class)
        prog="aider-exo",
        description="Walking-assistance exoskeleton controller after Chen et al., ICMA 2017.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")
    parser.add_argument("--version", action=_VersionAction, help="show the version and which numerics run compiled, and exit")
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
    except ModuleNotFoundError as exc:  # an optional dependency (EXTRAS) the command needs: one line
        error = _missing_extra(exc, _command(parser, args))
        if error is None or args.debug:
            raise
        print(f"aider-exo: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("aider-exo: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`aider-exo protocol --json | head`): stop quietly.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except OSError as exc:  # a file or device the OS refused, not handled where it was opened: still one line
        if args.debug:
            raise
        where = f"{os.fsdecode(exc.filename)}: " if exc.filename is not None else ""
        print(f"aider-exo: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
