"""The deployment files agree with the code: every aider-exo command in the systemd units and in
docs/DEPLOY.md parses with today's command line, and the controller's unit keeps its state where
the learned parameters are looked for."""

from __future__ import annotations

import configparser
import re
import shlex

import pytest

from tests.conftest import ROOT
from tools.cli import build_parser

UNITS = sorted((ROOT / "tools" / "deploy").glob("*.service"))


def _unit(path):
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read_string("\n".join(line for line in path.read_text().splitlines() if not line.startswith("#")))
    return parser


def _aider_argv(command: str) -> list[str] | None:
    words = shlex.split(command)
    for stop in (">", ">>", "<", "|", "&&"):  # the shell's part of the line
        if stop in words:
            words = words[:words.index(stop)]
    for i, word in enumerate(words):
        if word.endswith("aider-exo"):
            return words[i + 1:]
    return None


def _deploy_commands() -> list[str]:
    text = (ROOT / "docs" / "DEPLOY.md").read_text()
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("#")[0].strip()
            if re.match(r"(\S*/)?aider-exo\s", line):
                commands.append(line)
    return commands


@pytest.mark.parametrize("command", _deploy_commands())
def test_every_command_in_deploy_md_parses(command):
    argv = _aider_argv(command)
    build_parser().parse_args(argv)


def test_deploy_md_shows_the_bring_up_commands():
    modes = {shlex.split(c)[shlex.split(c).index("--mode") + 1] for c in _deploy_commands() if "--mode" in c}
    assert modes == {"listen", "hold"}  # the sweep is described, never shown as a command to paste


@pytest.mark.parametrize("path", UNITS, ids=[p.name for p in UNITS])
def test_the_units_commands_parse(path):
    service = _unit(path)["Service"]
    for command in service.get("ExecStart", "").splitlines():
        argv = _aider_argv(command)
        if argv is not None:
            build_parser().parse_args(argv)


def test_the_controller_unit_keeps_its_state_in_its_state_directory():
    service = _unit(ROOT / "tools" / "deploy" / "aider-exo-controller.service")["Service"]
    assert service["WorkingDirectory"] == f"/var/lib/{service['StateDirectory']}"
    argv = _aider_argv(service["ExecStart"])
    log = argv[argv.index("--log") + 1]
    assert log.startswith(f"/var/log/{service['LogsDirectory']}/")
    assert service["Type"] == "notify" and "WatchdogSec" in service
