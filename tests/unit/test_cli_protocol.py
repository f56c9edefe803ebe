"""``aider-exo protocol``: catalogue, bus load, generated docs; one-line errors."""

from __future__ import annotations

import json

from protocol.catalog import default_catalog
from protocol.docs import markdown
from tests.conftest import ROOT
from tools.cli import main


def test_protocol_json_has_catalogue_and_load(capsys):
    assert main(["protocol", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["messages"]) == 28
    sync = next(m for m in data["messages"] if m["name"] == "SYNC")
    assert sync["id_hex"] == "0x080" and sync["period_ms"] == 20 and sync["sender"] == "CONTROLLER"
    assert [s["name"] for s in sync["signals"]] == ["tick"]
    status = next(m for m in data["messages"] if m["name"] == "JOINT_STATUS_LH")
    pos = next(s for s in status["signals"] if s["name"] == "position_rad")
    assert pos["unit"] == "rad" and pos["min"] == -3.1416 and pos["max"] == 3.1416
    load = data["bus_load"]["bitrates"]
    assert load["500000"]["busiest_tick_percent_worst"] <= 25.0
    assert load["1000000"]["busiest_tick_percent_worst"] <= 12.5


def test_protocol_text(capsys):
    assert main(["protocol", "--bitrate", "250000"]) == 0
    out = capsys.readouterr().out
    assert "0x181 JOINT_STATUS_LH" in out and "at 250 kbit/s" in out


def test_docs_protocol_md_is_generated_from_the_dbc():
    committed = (ROOT / "docs" / "PROTOCOL.md").read_text()
    assert committed == markdown(default_catalog()), "docs/PROTOCOL.md is stale: run `make docs`"


def test_bad_dbc_is_one_line_error(tmp_path, capsys):
    bad = tmp_path / "x.dbc"
    bad.write_text("nonsense")
    assert main(["protocol", "--dbc", str(bad)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("aider-exo: error: ") and err.count("\n") == 1


def test_stop_signals_record_sigint_and_sigterm_and_restore_the_handlers():
    import os
    import signal

    from tools.cli.common import StopSignals

    before = signal.getsignal(signal.SIGTERM)
    with StopSignals() as stop:
        assert not stop.requested and stop.name is None
        os.kill(os.getpid(), signal.SIGTERM)  # recorded, not fatal
        assert stop.requested and stop.name == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) is before
