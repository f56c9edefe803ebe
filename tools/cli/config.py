"""``aider-exo config``: check a configuration file before it reaches a bus."""

from __future__ import annotations

import argparse
from pathlib import Path

from tools.cli.common import print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="check a configuration file (every key, range and cross-check)")
    csub = p.add_subparsers(dest="config_command", metavar="CONFIG_COMMAND", required=True)
    c = csub.add_parser("check", help="load FILE as aider-exo would; one line naming the file and key if it is wrong",
                        description="Loads FILE with every check the commands apply (types, ranges, choices, unknown keys, "
                                    "cross-field checks) and says which sections it has; a bad file is one line naming "
                                    "the file, the key and the problem, and exit status 1.")
    c.add_argument("file", type=Path, metavar="FILE", help="YAML configuration (config/default.yaml is the packaged one)")
    c.add_argument("--json", action="store_true", help="print the result as JSON")
    c.set_defaults(func=run_check)


def run_check(args: argparse.Namespace) -> int:
    from config import SCHEMA_VERSION, config_hash, load_config

    cfg = load_config(args.file)
    sections = {name: getattr(cfg, name) is not None for name in ("protocol", "controller", "sim", "nodes")}
    result = {"file": str(args.file), "valid": True, "schema_version": SCHEMA_VERSION, "hash": config_hash(cfg),
              "bus": f"{cfg.bus.interface}:{cfg.bus.channel}", "sections": sections}
    if args.json:
        print_json(result)
    else:
        present = ", ".join(name for name, there in sections.items() if there) or "none"
        print(f"{args.file}: valid (schema {SCHEMA_VERSION}, bus {result['bus']}; sections: {present}; hash {result['hash'][:12]})")
    return 0
