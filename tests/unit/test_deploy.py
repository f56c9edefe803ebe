"""The deployment files agree with the code: every aider-exo command in the systemd units and in
docs/DEPLOY.md parses with today's command line, and the controller's unit keeps its state where
the learned parameters are looked for."""

from __future__ import annotations

import re
import shlex

import pytest

from tests.conftest import ROOT
from tests.support.deploy import aider_argv, unit
from tools.cli import build_parser

UNITS = sorted((ROOT / "tools" / "deploy").glob("*.service"))


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
    argv = aider_argv(command)
    build_parser().parse_args(argv)


def test_deploy_md_shows_the_bring_up_commands():
    modes = {shlex.split(c)[shlex.split(c).index("--mode") + 1] for c in _deploy_commands() if "--mode" in c}
    assert modes == {"listen", "hold"}  # the sweep is described, never shown as a command to paste


@pytest.mark.parametrize("path", UNITS, ids=[p.name for p in UNITS])
def test_the_units_commands_parse(path):
    service = unit(path)["Service"]
    for command in service.get("ExecStart", "").splitlines():
        argv = aider_argv(command)
        if argv is not None:
            build_parser().parse_args(argv)


def test_the_controller_unit_keeps_its_state_in_its_state_directory():
    service = unit(ROOT / "tools" / "deploy" / "aider-exo-controller.service")["Service"]
    assert service["WorkingDirectory"] == f"/var/lib/{service['StateDirectory']}"
    argv = aider_argv(service["ExecStart"])
    log = argv[argv.index("--log") + 1]
    assert log.startswith(f"/var/log/{service['LogsDirectory']}/")
    assert service["Type"] == "notify" and "WatchdogSec" in service


def _can_settings(line: str) -> dict[str, str]:
    """The settings of an ``ip link set DEV type can ...`` line (empty for any other line)."""
    words = shlex.split(line.split("#")[0])
    if "type" not in words or words[words.index("type") + 1:words.index("type") + 2] != ["can"]:
        return {}
    rest = words[words.index("type") + 2:]
    return dict(zip(rest[::2], rest[1::2]))


def test_the_can_unit_and_deploy_md_agree_on_bitrate_and_sample_point():
    """Every `ip link set ... type can` in docs/DEPLOY.md (the PEAK/Kvaser bring-up, the gs_usb
    drop-in, listen-only) and in the units sets the bitrate and sample point of aider-can0.service,
    which are the ones DEPLOY.md recommends in its text."""
    unit_lines = [line.removeprefix("ExecStart=") for path in UNITS for line in path.read_text().splitlines()
                  if line.startswith("ExecStart=")]
    unit = [s for s in map(_can_settings, unit_lines) if s]
    assert len(unit) == 1 and {"bitrate", "sample-point", "restart-ms"} <= unit[0].keys()
    bitrate, sample_point = unit[0]["bitrate"], unit[0]["sample-point"]
    text = (ROOT / "docs" / "DEPLOY.md").read_text()
    doc = [s for s in map(_can_settings, re.findall(r"ip link set \S+ type can[^\n`]*", text)) if s]
    assert len(doc) >= 4, doc  # the bitrate paragraph, gs_usb, its drop-in, listen-only, section 3
    assert all(s.get("bitrate") == bitrate and s.get("sample-point") == sample_point for s in doc), doc
    assert f"{float(sample_point) * 100:g} %" in text and int(bitrate) == 1_000_000 and "1 Mbit/s" in text
    assert "sample point" in (ROOT / "tools" / "deploy" / "aider-can0.service").read_text().splitlines()[0]


def test_deploy_md_quotes_the_bus_load_that_aider_exo_protocol_prints(capsys):
    from tools.cli import main

    assert main(["protocol"]) == 0
    out = capsys.readouterr().out
    load = dict(re.findall(r"at (\d+) kbit/s: ([\d.]+) % worst case", out))
    text = " ".join((ROOT / "docs" / "DEPLOY.md").read_text().split())
    quoted = re.search(r"busiest 20 ms tick takes ([\d.]+) % of it \(([\d.]+) % at 500 kbit/s", text)
    assert quoted, "DEPLOY.md's bitrate paragraph changed: update this test"
    assert (quoted.group(1), quoted.group(2)) == (load["1000"], load["500"]), "stale: copy `aider-exo protocol`'s figures"
