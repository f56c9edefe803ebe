"""Bad input through the real CLI (issue 48): every case exits non-zero with exactly one line on
stderr, no traceback, and leaves every file that was in its folder as it was.

Each case runs ``python -m tools.cli`` as a subprocess in its own copy of a folder holding a tiny
recorded trace (``c.log``), an empty file, random bytes, a BLF renamed ``.asc``, configurations
good and bad; the cases run in parallel and all fail before any physics starts.
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from tests.conftest import ROOT

DEFAULT_YAML = ROOT / "config" / "default.yaml"


def run_cli(args: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "100"}
    return subprocess.run([sys.executable, "-m", "tools.cli", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def snapshot(folder: Path) -> dict[str, str]:
    """Every path under ``folder`` with its content's hash (folders: "dir")."""
    out = {}
    for p in sorted(folder.rglob("*")):
        out[str(p.relative_to(folder))] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """The inputs every case finds in its folder."""
    folder = tmp_path_factory.mktemp("inputs")
    result = run_cli(["trace", "record", "--walk", "1", "--max-time", "2", "c.log"], folder)
    assert result.returncode == 0, result.stderr
    (folder / "e.log").write_bytes(b"")
    (folder / "r.log").write_bytes(os.urandom(4096))
    import can

    with can.BLFWriter(str(folder / "b.blf")) as blf:
        for k in range(20):
            blf.on_message_received(can.Message(timestamp=k * 0.02, arbitration_id=0x80, data=b"\x00" * 2, is_extended_id=False))
    (folder / "b.blf").rename(folder / "b.asc")  # a BLF under another suffix
    (folder / "dir.log").mkdir()
    (folder / "f.txt").write_text("a file, not a folder\n")
    shutil.copy(DEFAULT_YAML, folder / "good.yaml")
    (folder / "syntax.yaml").write_text("bus:\n  interface: virtual\n  channel: [unclosed\n")
    (folder / "unknown.yaml").write_text(DEFAULT_YAML.read_text().replace("bus:\n", "bus:\n  colour: blue\n", 1))
    (folder / "bad.yaml").write_text("bus: 3\n")
    return folder


#: (id, argv); every case must fail with one line. Traces: c.log (good), e.log (empty), r.log (random
#: bytes), b.asc (a BLF renamed), dir.log (a folder).
CASES: list[tuple[str, list[str]]] = [
    # a recording must never be destroyed
    ("decode-over-its-input", ["trace", "decode", "c.log", "-o", "c.log"]),
    ("decode-csv-over-its-input-spelt-otherwise", ["trace", "decode", "c.log", "--format", "csv", "-o", "./sub/../c.log"]),
    ("decode-over-its-input-by-hard-link", ["trace", "decode", "c.log", "-o", "hard.log"]),
    ("plot-over-its-input", ["trace", "plot", "c.log", "--signal", "*position*", "-o", "c.log"]),
    ("plot-into-proc", ["trace", "plot", "c.log", "--signal", "*position*", "-o", "/proc/x.png"]),
    ("plot-into-missing-folder", ["trace", "plot", "c.log", "--signal", "*position*", "-o", "nope/x.png"]),
    ("decode-into-missing-folder", ["trace", "decode", "c.log", "-o", "nope/x.csv"]),
    ("decode-into-a-folder", ["trace", "decode", "c.log", "-o", "dir.log"]),
    ("decode-over-the-config", ["trace", "decode", "c.log", "--config", "good.yaml", "-o", "good.yaml"]),
    # unreadable input
    ("decode-empty", ["trace", "decode", "e.log"]),
    ("stats-empty", ["trace", "stats", "e.log"]),
    ("decode-random", ["trace", "decode", "r.log"]),
    ("stats-random", ["trace", "stats", "r.log", "--json"]),
    ("decode-blf-as-asc", ["trace", "decode", "b.asc"]),
    ("stats-blf-as-asc", ["trace", "stats", "b.asc"]),
    ("plot-empty", ["trace", "plot", "e.log", "--signal", "*", "-o", "p.png"]),
    ("view-trace-empty", ["view", "--trace", "e.log"]),
    ("view-trace-random", ["view", "--trace", "r.log"]),
    ("view-trace-blf-as-asc", ["view", "--trace", "b.asc"]),
    ("decode-missing", ["trace", "decode", "missing.log"]),
    ("decode-folder", ["trace", "decode", "dir.log"]),
    ("decode-unknown-format", ["trace", "decode", "f.txt"]),
    ("decode-missing-dbc", ["trace", "decode", "c.log", "--dbc", "missing.dbc"]),
    ("plot-bad-signal", ["trace", "plot", "c.log", "--signal", "NOPE", "-o", "p.png"]),
    ("plot-without-signal", ["trace", "plot", "c.log", "-o", "p.png"]),
    ("decode-bad-start", ["trace", "decode", "c.log", "--start", "abc"]),
    # seeds
    ("walk-negative-seed", ["walk", "--seed", "-1"]),
    ("walk-huge-seed", ["walk", "--seed", str(2**32)]),
    ("record-negative-seed", ["trace", "record", "--walk", "1", "--seed", "-1", "x.log"]),
    ("population-negative-seed", ["population", "draw", "--patients", "1", "--seed", "-1", "--out", "pp"]),
    ("nodes-negative-seed", ["nodes", "--seed", "-1"]),
    ("sim-walk-negative-seed", ["sim", "walk", "--seed", "-1"]),
    ("sim-render-negative-seed", ["sim", "render", "--seed", "-5"]),
    ("experiment-negative-seed", ["experiment", "compare", "--seed", "-1"]),
    ("soak-negative-seed", ["soak", "--seed", "-2"]),
    # outputs that cannot be written
    ("population-out-is-a-file", ["population", "draw", "--patients", "1", "--out", "f.txt"]),
    ("view-screenshot-missing-folder", ["view", "--trace", "c.log", "--screenshot", "nope/x.png"]),
    ("walk-render-missing-folder", ["walk", "--steps", "1", "--render", "nope/sub"]),
    ("walk-render-is-a-file", ["walk", "--steps", "1", "--render", "f.txt"]),
    ("walk-log-missing-folder", ["walk", "--steps", "1", "--log", "nope/t.jsonl"]),
    ("nodes-truth-missing-folder", ["nodes", "--truth", "nope/t.jsonl"]),
    ("controller-log-into-proc", ["controller", "--ticks", "1", "--log", "/proc/x.jsonl"]),
    ("controller-log-missing-folder", ["controller", "--ticks", "1", "--log", "nope/t.jsonl"]),
    ("controller-log-over-its-config", ["controller", "--ticks", "1", "--config", "good.yaml", "--log", "good.yaml"]),
    ("dmp-fit-missing-folder", ["dmp", "fit", "--out", "nope/w.json"]),
    ("experiment-out-is-a-file", ["experiment", "compare", "--walks", "1", "--out", "f.txt"]),
    # ports, channels, lengths
    ("view-port-too-big", ["view", "--port", "99999"]),
    ("view-port-negative", ["view", "--port", "-1"]),
    ("walk-view-port", ["walk", "--view", "--view-port", "70000"]),
    ("walk-empty-channel", ["walk", "--channel", ""]),
    ("controller-blank-channel", ["controller", "--channel", " "]),
    ("sim-walk-negative-length", ["sim", "walk", "--length", "-0.2"]),
    ("sim-walk-long-length", ["sim", "walk", "--length", "3"]),
    ("sim-walk-zero-max-time", ["sim", "walk", "--max-time", "0"]),
    # patients
    ("walk-unknown-patient", ["walk", "--patient", "nobody"]),
    ("controller-unknown-patient", ["controller", "--patient", "nobody"]),
    ("walk-bad-patient-name", ["walk", "--patient", "../x"]),
    ("walk-missing-virtual-patient", ["walk", "--virtual-patient", "missing.yaml"]),
    # configuration
    ("config-missing", ["walk", "--config", "missing.yaml"]),
    ("config-is-a-folder", ["walk", "--config", "dir.log"]),
    ("config-yaml-syntax", ["walk", "--config", "syntax.yaml"]),
    ("config-unknown-key", ["walk", "--config", "unknown.yaml"]),
    ("config-check-bad", ["config", "check", "bad.yaml"]),
    ("config-check-json-bad", ["config", "check", "--json", "bad.yaml"]),
    # arguments
    ("walk-steps-zero", ["walk", "--steps", "0"]),
    ("walk-steps-abc", ["walk", "--steps", "abc"]),
    ("walk-negative-pace", ["walk", "--pace", "-1"]),
    ("experiment-walks-zero", ["experiment", "compare", "--walks", "0"]),
    ("population-zero-patients", ["population", "draw", "--patients", "0", "--out", "pp"]),
    ("unknown-command", ["bogus"]),
    ("unknown-option", ["walk", "--bogus"]),
    ("trace-without-action", ["trace"]),
]


def _setup(case: str, folder: Path) -> None:
    if case == "decode-over-its-input-by-hard-link":
        os.link(folder / "c.log", folder / "hard.log")
    if case == "decode-csv-over-its-input-spelt-otherwise":
        (folder / "sub").mkdir()


def _run_case(case: str, argv: list[str], template: Path, root: Path) -> tuple[str, list[str], subprocess.CompletedProcess, dict, dict]:
    folder = root / case
    shutil.copytree(template, folder)
    _setup(case, folder)
    before = snapshot(folder)
    result = run_cli(argv, folder)
    return case, argv, result, before, snapshot(folder)


def test_bad_input_is_one_line_a_non_zero_exit_and_changes_nothing(template, tmp_path):
    assert len(CASES) >= 40 and len({c for c, _ in CASES}) == len(CASES)
    with concurrent.futures.ThreadPoolExecutor(max_workers=4) as pool:
        outcomes = list(pool.map(lambda c: _run_case(*c, template, tmp_path), CASES))
    failures = []
    for case, argv, result, before, after in outcomes:
        lines = result.stderr.splitlines()
        problems = []
        if result.returncode == 0:
            problems.append("exit 0")
        if len(lines) != 1 or not lines[0].strip():
            problems.append(f"{len(lines)} stderr lines")
        if "Traceback" in result.stderr + result.stdout:
            problems.append("a traceback")
        if before != after:
            changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
            problems.append(f"files changed: {changed}")
        if problems:
            failures.append(f"{case} (aider-exo {' '.join(argv)}): {', '.join(problems)}; stderr: {result.stderr.strip()[-400:]!r}")
    assert not failures, "\n".join(failures)
    by_case = {case: result for case, _, result, _, _ in outcomes}
    # what the lines say
    assert "is the input" in by_case["decode-over-its-input"].stderr
    assert "is the input" in by_case["decode-over-its-input-by-hard-link"].stderr
    assert "the file is empty" in by_case["decode-empty"].stderr and "e.log" in by_case["decode-empty"].stderr
    assert "no CAN frame" in by_case["view-trace-blf-as-asc"].stderr
    assert "nobody.json: no such learned file" in by_case["walk-unknown-patient"].stderr
    assert "--channel" in by_case["walk-empty-channel"].stderr
    assert "nope" in by_case["walk-render-missing-folder"].stderr
    for case in ("walk-steps-abc", "unknown-command", "view-port-too-big", "walk-negative-seed"):
        assert by_case[case].returncode == 2 and "(see aider-exo" in by_case[case].stderr and "usage:" not in by_case[case].stderr
    report = json.loads(by_case["config-check-json-bad"].stdout)  # --json: the error on stdout too
    assert report["valid"] is False and "bad.yaml" in report["error"] and report["key"] == "schema_version"


def test_decode_over_its_own_input_leaves_it_byte_identical(template, tmp_path):
    trace = tmp_path / "c.log"
    shutil.copy(template / "c.log", trace)
    before = trace.read_bytes()
    for fmt in ("table", "csv", "jsonl"):
        result = run_cli(["trace", "decode", str(trace), "--format", fmt, "-o", str(trace)], tmp_path)
        assert result.returncode != 0 and "is the input" in result.stderr
        assert trace.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.log"]  # no temporary file left either


def test_a_controller_restarted_with_the_same_log_keeps_the_first_runs_lines(tmp_path):
    first = run_cli(["controller", "--ticks", "5", "--log", "t.jsonl", "--quiet"], tmp_path)
    assert first.returncode == 0, first.stderr
    first_log = (tmp_path / "t.jsonl").read_bytes()
    assert len(first_log.splitlines()) == 6  # the schema and 5 ticks
    again = run_cli(["controller", "--ticks", "3", "--log", "t.jsonl", "--quiet", "--json"], tmp_path)
    assert again.returncode == 0, again.stderr
    moved = [p for p in tmp_path.iterdir() if p.name != "t.jsonl"]
    assert len(moved) == 1 and moved[0].name.startswith("t.") and moved[0].name.endswith("Z.jsonl")
    assert moved[0].read_bytes() == first_log  # the first run's lines, whole
    assert len((tmp_path / "t.jsonl").read_bytes().splitlines()) == 4
    assert f"was moved to {moved[0].name}" in again.stderr and len(again.stderr.splitlines()) == 1
    assert json.loads(again.stdout)["telemetry"]["previous"] == moved[0].name


def test_the_patient_file_is_looked_for_beside_the_configuration(tmp_path):
    """controller.learned_dir (relative) is resolved against the configuration file's folder, not the
    working directory; the error names the path looked in."""
    (tmp_path / "site").mkdir()
    text = re.sub(r"(?m)^  learned_dir: .*$", "  learned_dir: patients", Path(DEFAULT_YAML).read_text())
    (tmp_path / "site" / "exo.yaml").write_text(text)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result = run_cli(["walk", "--config", str(tmp_path / "site" / "exo.yaml"), "--patient", "anna"], elsewhere)
    assert result.returncode == 1
    assert result.stderr.strip() == (f"aider-exo: error: {tmp_path / 'site' / 'patients' / 'anna.json'}: no such learned file "
                                     "(--patient anna); check the name and the folder (--learned-dir, controller.learned_dir), "
                                     "or create it with --learn")
