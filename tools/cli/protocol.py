"""``aider-exo protocol``: the message catalogue and its bus load, as text, JSON or Markdown."""

from __future__ import annotations

import argparse

from protocol.catalog import DBC_PATH, load_catalog
from protocol.docs import catalog_dict, catalog_text, markdown
from tools.cli.common import positive_int, print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("protocol", help="print the CAN message catalogue and the worst-case bus load")
    p.add_argument("--dbc", default=str(DBC_PATH), help="DBC file (default: the project's protocol/aider.dbc)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--json", action="store_true", help="machine-readable output")
    out.add_argument("--markdown", action="store_true", help="docs/PROTOCOL.md as generated from the DBC")
    p.add_argument(
        "--bitrate", type=positive_int, action="append", metavar="BIT_S",
        help="bitrate for the bus-load figures (repeatable; default 500000 and 1000000)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    catalog = load_catalog(args.dbc)
    bitrates = tuple(args.bitrate) if args.bitrate else (500_000, 1_000_000)
    if args.json:
        print_json(catalog_dict(catalog, bitrates))
    elif args.markdown:
        print(markdown(catalog), end="")
    else:
        print(catalog_text(catalog, bitrates), end="")
    return 0
