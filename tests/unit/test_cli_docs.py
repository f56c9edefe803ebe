"""The command line's own documentation: ``--version``, ``aider-exo config check``, and every
document that any command's ``--help`` cites exists in the repository."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tools.cli import build_parser, main


def _parsers(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """``parser`` and every subcommand's parser under it."""
    found = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found += _parsers(sub)
    return found


def test_every_document_a_help_cites_is_in_the_repository():
    cited = set()
    for parser in _parsers(build_parser()):
        cited |= set(re.findall(r"[\w./-]*[A-Z][\w-]*\.md\b", parser.format_help()))
    assert cited, "no --help cites a document (the pattern is wrong)"
    missing = sorted(doc for doc in cited if not (ROOT / doc).exists() and not (ROOT / "docs" / Path(doc).name).exists())
    assert not missing, missing


def test_version_names_the_installed_distribution(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    # then how the per-tick numerics run: compiled, or interpreted and why (one line each)
    assert done.value.code == 0 and re.fullmatch(r"aider-exo \d+\.\d+\.\d+\S*\ncompiled numerics: \d+ of \d+ modules\n(  \S+: .+\n)*",
                                                 capsys.readouterr().out)


def test_config_check_accepts_the_packaged_file_and_names_the_key_of_a_bad_one(tmp_path, capsys):
    assert main(["config", "check", str(ROOT / "config" / "default.yaml"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["valid"] and result["sections"] == {"protocol": True, "hardware": True, "controller": True, "sim": True, "nodes": True}
    # the step bounds and the swing's duration, scaled with the leg length in the file, in metres and seconds
    assert result["step_m"] == {"leg_length": 0.927, "init": 0.15, "min": 0.06, "max": 0.25} and result["swing_s"] == 1.2
    bad = tmp_path / "bad.yaml"
    bad.write_text((ROOT / "config" / "default.yaml").read_text().replace("bitrate_bit_s: 1_000_000", "bitrate_bit_s: -5", 1))
    assert main(["config", "check", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"aider-exo: error: {bad}") and "bus.bitrate_bit_s" in err and "\n" not in err
