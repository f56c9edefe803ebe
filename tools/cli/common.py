"""Options shared by subcommands: configuration file and bus overrides, JSON output."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path
from collections.abc import Callable
from typing import Any, NoReturn

from config import Config, ConfigError, default_config_path, load_config, with_overrides


class OneLineParser(argparse.ArgumentParser):
    """A parser whose every error is one line on stderr, ``aider-exo CMD: error: ... (see --help)``,
    with exit status 2 (argparse's own prints the usage block first). Subparsers inherit the class."""

    def error(self, message: str) -> NoReturn:
        text = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def non_empty(text: str) -> str:
    """An argparse type: a value that is not empty (nor only blanks)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must not be empty")
    return text


def add_config_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", metavar="FILE", help="YAML configuration (default: the packaged config/default.yaml)")
    parser.add_argument("--bus", choices=("socketcan", "virtual", "udp_multicast"), help="override bus.interface")
    parser.add_argument("--channel", type=non_empty,
                        help="override bus.channel (vcan0, can0, a virtual bus name, or a multicast group[:port])")


def config_path(args: argparse.Namespace) -> Path:
    """The configuration file the command reads: ``--config``, or the packaged default."""
    return Path(args.config) if getattr(args, "config", None) else default_config_path()


def learned_folder(args: argparse.Namespace, cfg: Config) -> Path:
    """Where ``--patient NAME`` is looked for: ``--learned-dir`` (relative: to the working
    directory), else ``controller.learned_dir`` (relative: to the configuration file's folder)."""
    if getattr(args, "learned_dir", None):
        return Path(args.learned_dir).absolute()
    configured = Path(cfg.controller.learned_dir).expanduser()
    return configured if configured.is_absolute() else config_path(args).absolute().parent / configured


def add_mode_option(parser: argparse.ArgumentParser, what: str = "the simulation's mode") -> None:
    """``--mode``: one spelling and one default (the config's ``sim.mode``) for every command that simulates."""
    parser.add_argument("--mode", choices=("sagittal", "full3d"),
                        help=f"{what} (default: sim.mode of the config, full3d in config/default.yaml; "
                             "sagittal: the same model held to the walking plane, docs/SIM.md)")


def sim_mode(args: argparse.Namespace, cfg: Config) -> str:
    """``--mode``, or the config's ``sim.mode``."""
    if args.mode:
        return args.mode
    if cfg.sim is None:
        raise ConfigError(f"missing section (aider-exo {args.command} simulates)", key="sim")
    return cfg.sim.mode


def load_cli_config(args: argparse.Namespace, *, needs: tuple[str, ...] = ()) -> Config:
    """The configuration named by ``--config`` with ``--bus``/``--channel`` applied (validated);
    an optional section the command ``needs`` that the file lacks is an error naming file and key,
    raised before anything is opened."""
    path = config_path(args)
    cfg = load_config(path)
    for section in needs:
        if getattr(cfg, section) is None:
            raise ConfigError(f"missing section (aider-exo {args.command} needs it)", key=section, source=str(path))
    overrides: dict[str, Any] = {}
    if args.bus:
        overrides["bus.interface"] = args.bus
    if args.channel:
        overrides["bus.channel"] = args.channel
    return with_overrides(cfg, overrides) if overrides else cfg


def print_json(data: Any) -> None:
    json.dump(data, sys.stdout, indent=2, sort_keys=False)
    sys.stdout.write("\n")


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{value} is not positive")
    return value


SEED_MAX = 2**32 - 1


def bounded(cast: Callable[[str], float], lo: float, hi: float, what: str, unit: str = "") -> Callable[[str], Any]:
    """An argparse type: a number (``cast``: int or float) in lo..hi; ``what`` names it (its
    ``__name__``, shown by argparse) and ``unit`` follows the bounds in the message."""

    def parse(text: str) -> Any:
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if cast is int else 'a number'}") from None
        if not lo <= value <= hi:  # NaN fails too
            raise argparse.ArgumentTypeError(f"{value} is outside {lo}..{hi}{unit}")
        return value

    parse.__name__ = what
    return parse


#: a seed: numpy's seeds are unsigned 32-bit
seed_type = bounded(int, 0, SEED_MAX, "seed")
#: a TCP port (0: any free one)
port = bounded(int, 0, 65535, "port")


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text} is not a positive finite number")
    return value


class StopSignals:
    """While in the ``with`` block, SIGINT and SIGTERM only record that a stop was asked
    (``requested``), so a loop can end its tick and close its bus cleanly; the previous handlers
    come back at exit."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def _handler(self, signum: int, _frame: Any) -> None:
        self.signum = signum

    @property
    def requested(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str | None:
        """SIGINT or SIGTERM, once one arrived."""
        return signal.Signals(self.signum).name if self.signum is not None else None

    def __enter__(self) -> StopSignals:
        self._previous = {s: signal.signal(s, self._handler) for s in (signal.SIGINT, signal.SIGTERM)}
        return self

    def __exit__(self, *exc: object) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
