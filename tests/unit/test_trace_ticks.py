"""``aider-exo trace ticks``: the controller's per-tick telemetry logs (tools/trace/ticks.py), on logs
written by controller.telemetry.TelemetryLog itself and by a real short controller run: the
summary, several files in order, a last line cut by a crash, the one-line errors, --json and the
figure."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from controller.telemetry import FIELDS, SCHEMA_VERSION, TelemetryLog
from tools.cli import main


def _record(tick: int, state: str = "DOUBLE_SUPPORT", **kw) -> dict:
    r = {k: None for k in FIELDS}
    r.update(tick=tick, state=state, q_rad=[0.1, 0.2, 0.3, 0.4], setpoint_rad=[0.1, 0.2, 0.3, 0.4],
             mode=["TRACK"] * 4, stick_force_n=[20.0, 30.0], x_ratio=0.5, gait="shift", events=[],
             work_us=100.0 + tick, lateness_us=float(tick % 7))
    r.update(kw)
    return r


def _write(path, records) -> None:
    log = TelemetryLog(path)
    for r in records:
        log.put(r)
    assert log.close()["error"] is None


def _session(tmp_path):
    """A log of 100 ticks: stand, a swing of step 0 (0.2 m) that lands, a fall."""
    recs = [_record(k, "STAND", gait=None) for k in range(10)]
    recs[9]["events"] = ["STAND -> DOUBLE_SUPPORT: start"]
    recs += [_record(k) for k in range(10, 40)]
    recs += [_record(k, "SWING_RIGHT", gait="swing", step=0, step_length_m=0.2) for k in range(40, 60)]
    recs[30]["events"] = ["DOUBLE_SUPPORT -> SWING_RIGHT: sticks loaded and ahead", "step 0 (r): 0.200 m at X_CoM/X_SP 0.30"]
    recs += [_record(k) for k in range(60, 90)]
    recs[50].update(step_cost_n=64.0, events=["SWING_RIGHT -> DOUBLE_SUPPORT: swing done"])
    recs += [_record(k, "FAULT", gait=None) for k in range(90, 100)]
    recs[80]["events"] = ["DOUBLE_SUPPORT -> FAULT: FALL(trunk tilt 0.70 rad)"]
    recs[85]["events"] = ["SUPPLY_LOW(21.50 V below 22 V for 50 ticks): warning"]
    path = tmp_path / "ctl.jsonl"
    _write(path, recs)
    return path


def _json(capsys, argv, code=0):
    assert main(argv) == code
    return json.loads(capsys.readouterr().out)


def test_summary_of_a_log_written_by_the_telemetry_writer(tmp_path, capsys):
    r = _json(capsys, ["trace", "ticks", str(_session(tmp_path)), "--json"])
    assert r["ticks"] == 100 and r["duration_s"] == pytest.approx(2.0)
    assert r["states"]["STAND"] == {"ticks": 10, "s": 0.2} and r["states"]["FAULT"]["ticks"] == 10
    assert list(r["states"]) == ["STAND", "DOUBLE_SUPPORT", "SWING_RIGHT", "FAULT"]
    assert r["gait"]["swing"]["ticks"] == 20 and r["gait"]["shift"]["ticks"] == 60
    assert r["steps"] == {"count": 1, "landed": 1, "length_m": {"min": 0.2, "mean": 0.2, "max": 0.2},
                          "cost_n": {"min": 64.0, "mean": 64.0, "max": 64.0}}
    assert r["falls"] == 1 and r["faults"] == 0 and r["events"]["fall"] == {"FALL": 1}
    assert r["events"]["warning"] == {"SUPPLY_LOW": 1} and r["events"]["step"] == {"step": 1}
    assert r["events"]["transition"]["STAND -> DOUBLE_SUPPORT"] == 1
    assert r["work_us"] == {"p50": 149.0, "p99": 198.0, "max": 199.0} and r["lateness_us"]["max"] == 6.0
    assert r["missing_ticks"] == 0 and r["truncated_lines"] == 0 and r["warnings"] == []
    assert main(["trace", "ticks", str(tmp_path / "ctl.jsonl")]) == 0
    text = capsys.readouterr().out
    assert "ticks: 100 records, 2.00 s" in text and "falls 1, faults 0" in text and "work: p50 149, p99 198, max 199 us" in text


def test_a_restarted_controllers_logs_are_read_in_order_and_a_crashed_last_line_is_counted(tmp_path, capsys):
    path = tmp_path / "ctl.jsonl"
    _write(path, [_record(k) for k in range(50)])
    with path.open("a") as f:  # the controller crashed while writing tick 50
        f.write(json.dumps({k: _record(50)[k] for k in FIELDS})[:40])
    second = TelemetryLog(path)  # restarted with the same --log: the first run's log is moved aside
    moved = second.previous
    for k in range(30):
        second.put(_record(k, "STAND" if k < 5 else "DOUBLE_SUPPORT"))
    second.close()
    assert moved is not None and moved.name.startswith("ctl.2")
    r = _json(capsys, ["trace", "ticks", str(moved), str(path), "--json"])
    assert r["ticks"] == 80 and r["duration_s"] == pytest.approx(1.6) and r["truncated_lines"] == 1
    assert [f["records"] for f in r["files"]] == [50, 30] and r["files"][1]["start_s"] == 1.0
    assert r["files"][0]["truncated_last_line"] and any("cut short" in w for w in r["warnings"])
    assert main(["trace", "ticks", str(moved), str(path)]) == 0
    out = capsys.readouterr()
    assert "skipped: 1 last line(s) cut short" in out.out and "cut short (the controller stopped" in out.err
    # --from/--to: controller time over both files
    r = _json(capsys, ["trace", "ticks", str(moved), str(path), "--from", "0.9", "--to", "1.1", "--json"])
    assert r["ticks"] == 11 and r["start_s"] == pytest.approx(0.9)  # both ends included


def test_dropped_records_are_counted_as_missing_ticks(tmp_path, capsys):
    path = tmp_path / "gaps.jsonl"
    _write(path, [_record(k) for k in (*range(10), *range(15, 20))])
    r = _json(capsys, ["trace", "ticks", str(path), "--json"])
    assert r["ticks"] == 15 and r["missing_ticks"] == 5 and r["files"][0]["missing_ticks"] == 5


@pytest.mark.parametrize("content, message", [
    ("", "the file is empty"),
    ("hello world\n", "not a controller telemetry log"),
    (json.dumps({"tick": 0, "state": "INIT"}) + "\n", "no schema line"),
    (json.dumps({"schema": "aider-exo controller telemetry", "version": SCHEMA_VERSION + 1, "fields": {}}) + "\n",
     f"schema version {SCHEMA_VERSION + 1} is newer"),
    ("\x00\x01\x02\xff" * 100, "not a controller telemetry log"),
])
def test_a_file_that_is_not_a_readable_log_is_one_line(tmp_path, capsys, content, message):
    path = tmp_path / "bad.jsonl"
    path.write_bytes(content.encode("latin-1") if "\x00" in content else content.encode())
    assert main(["trace", "ticks", str(path)]) == 1
    err = capsys.readouterr().err
    assert message in err and str(path) in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_missing_files_folders_bad_ranges_and_bad_lines(tmp_path, capsys):
    assert main(["trace", "ticks", str(tmp_path / "none.jsonl")]) == 1
    assert "no such file" in capsys.readouterr().err
    assert main(["trace", "ticks", str(tmp_path)]) == 1
    assert "is a folder" in capsys.readouterr().err
    path = tmp_path / "ctl.jsonl"
    _write(path, [_record(k) for k in range(10)])
    assert main(["trace", "ticks", str(path), "--from", "2", "--to", "1"]) == 1
    assert "before --from" in capsys.readouterr().err
    assert main(["trace", "ticks", str(path), "--from", "5"]) == 1
    assert "no tick between 5 s and the end" in capsys.readouterr().err
    with path.open("a") as f:
        f.write("not json\n[1, 2]\n")
    r = _json(capsys, ["trace", "ticks", str(path), "--json"])
    assert r["ticks"] == 10 and r["bad_lines"] == 2 and r["truncated_lines"] == 0


def test_plot_writes_a_png_and_never_over_its_input(tmp_path, capsys):
    log = _session(tmp_path)
    png = tmp_path / "ticks.png"
    r = _json(capsys, ["trace", "ticks", str(log), "--plot", str(png), "--json"])
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert r["plot"] == {"file": str(png), "panels": 5, "points": 100, "faults_marked": 1}
    before = log.read_bytes()
    assert main(["trace", "ticks", str(log), "--plot", str(log)]) == 1
    assert "it would be overwritten" in capsys.readouterr().err and log.read_bytes() == before
    assert list(tmp_path.glob(".*")) == []


def test_a_real_controller_runs_log(tmp_path):
    """``aider-exo controller`` on a virtual bus without nodes for 50 ticks, its log read back. Lock-step:
    in real time a machine busy with the other tests can skip ticks (an overrun), which the log then lacks."""
    log = tmp_path / "run.jsonl"
    run = subprocess.run([sys.executable, "-m", "tools.cli", "controller", "--bus", "virtual", "--channel", "ticks-test", "--lockstep",
                          "--ticks", "50", "--log", str(log), "--quiet"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    out = subprocess.run([sys.executable, "-m", "tools.cli", "trace", "ticks", str(log), "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert r["ticks"] == 50 and r["states"] == {"INIT": {"ticks": 50, "s": 1.0}} and r["missing_ticks"] == 0
    assert r["work_us"]["p50"] > 0 and r["work_us"]["max"] >= r["work_us"]["p99"] >= r["work_us"]["p50"]
    assert r["steps"]["count"] == 0 and r["falls"] == 0 and not math.isnan(r["duration_s"])
