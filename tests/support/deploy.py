"""The deployment files as the tests read them: systemd units and the commands in them."""

from __future__ import annotations

import configparser
import shlex
from pathlib import Path


def unit(path: Path) -> configparser.ConfigParser:
    """A systemd unit file parsed (comments dropped, keys as written)."""
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read_string("\n".join(line for line in path.read_text().splitlines() if not line.startswith("#")))
    return parser


def aider_argv(command: str) -> list[str] | None:
    """The arguments of the aider-exo command in a shell line (None: no aider-exo in it)."""
    words = shlex.split(command)
    for stop in (">", ">>", "<", "|", "&&"):  # the shell's part of the line
        if stop in words:
            words = words[:words.index(stop)]
    for i, word in enumerate(words):
        if word.endswith("aider-exo"):
            return words[i + 1:]
    return None
