"""``aider-exo record`` over a real SocketCAN vcan0, candump (can-utils) as the independent witness.

canplayer plays the protocol's lock-step schedule (made up from the DBC, as tests/bus/test_vcan_trace.py
does) onto vcan0 while the recorder runs as its own process with a small ``--max-bytes`` and
``candump -L`` captures beside it: every frame candump saw is in exactly one finished file, in
order, with the same kernel timestamp to the microsecond or near it. Then a tiny disk (the free
space simulated through ``AIDER_RECORD_TEST_FREE_BYTES``, which the recorder probes in place of
``shutil.disk_usage``): the recorder stops by itself with exit status 3 and one line, its last
file finished and valid.

Run through the vcan sandbox (``make test`` does: ``tools/vcan-run -- pytest -m vcan``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.clock import MonotonicClock
from protocol.codec import Codec
from tests.conftest import ROOT
from tests.support.capture import PROBE_ID, candump, read_log
from tools.cli.record import FAKE_FREE_ENV
from tools.trace.record import TraceWriter
from tools.trace.session import EXIT_DISK_FLOOR, session_files
from tools.trace.synthetic import lockstep_frames

pytestmark = pytest.mark.vcan


def _trace(path: Path, ticks: int, channel: str) -> list:
    writer = TraceWriter(path)
    for frame in lockstep_frames(Codec(), ticks, channel=channel):
        writer.write(frame.to_message())
    writer.close({})
    return read_log(path)


def _start_recorder(channel: str, folder: Path, *extra: str, env: dict | None = None) -> subprocess.Popen:
    """The recorder as its own process, returned once it says it listens."""
    proc = subprocess.Popen([sys.executable, "-m", "tools.cli", "record", "--channel", channel, "--dir", str(folder),
                             "--json", "--status-every", "1", *extra],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, **(env or {})})
    line = proc.stderr.readline()
    if not line.startswith("record: recording"):
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the recorder did not start: {line}{err}")
    return proc


def _holds(folder: Path, text: str) -> bool:
    """Whether a file of ``folder`` (finished or ``.part``) holds ``text``; a file renamed while read is skipped."""
    for path in folder.iterdir():
        try:
            if text in path.read_text():
                return True
        except FileNotFoundError:
            continue
    return False


def _read_all(paths) -> list:
    """The frames of ``paths`` in order, each file read whole (no skipped line, no problem)."""
    return [f for p in paths for f in read_log(p)]


def _key(f):
    return f.arbitration_id, bytes(f.data)


def test_every_frame_candump_saw_is_in_exactly_one_rotated_file(vcan0, tmp_path):
    sent = _trace(tmp_path / "trace.log", 60, vcan0)  # 1029 frames, about 40 kB of log lines
    folder = tmp_path / "rec"
    folder.mkdir()
    recorder = _start_recorder(vcan0, folder, "--max-bytes", "6000", "--keep", "100", "--min-free-mb", "1")
    try:
        dump = tmp_path / "candump.log"
        with candump(vcan0, dump):
            subprocess.run(["canplayer", "-I", str(tmp_path / "trace.log")], check=True, timeout=120)
        # the recorder has written candump's last probe (flushed into its .part file after each batch)
        clock = MonotonicClock()
        deadline = clock.now_ns() + 30_000_000_000
        while not _holds(folder, f"{PROBE_ID:03X}#FF"):
            assert clock.now_ns() < deadline and recorder.poll() is None, "the recorder did not catch up"
            clock.sleep_until(clock.now_ns() + 50_000_000)
        recorder.send_signal(signal.SIGTERM)
        out, err = recorder.communicate(timeout=60)
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
    assert recorder.returncode == 0, err
    summary = json.loads(out)
    assert summary["stopped_by"] == "SIGTERM" and summary["current"] is None
    files = [p for _, p in session_files(folder, vcan0)]
    assert [p.name for p in files] == summary["files"] and len(files) >= 4  # at least 3 rotations
    assert not list(folder.glob("*.part")) and all(p.stat().st_size <= 6000 for p in files)

    recorded = [f for f in _read_all(files) if f.arbitration_id != PROBE_ID]  # each file whole, read in order
    dumped = [f for f in read_log(dump) if f.arbitration_id != PROBE_ID]
    assert [_key(f) for f in dumped] == [_key(f) for f in sent]  # the witness saw the whole trace
    assert [_key(f) for f in recorded] == [_key(f) for f in dumped]  # each exactly once, in order
    offsets = [abs(a.timestamp - b.timestamp) for a, b in zip(recorded, dumped)]
    assert max(offsets) < 0.001, max(offsets)  # both are the kernel's receive timestamps
    assert summary["frames"] == len(_read_all(files))


def test_a_tiny_disk_stops_the_recorder_with_a_valid_last_file(vcan0, tmp_path):
    sent = _trace(tmp_path / "trace.log", 150, vcan0)  # 3 s of traffic, about 100 kB of lines
    folder = tmp_path / "rec"
    folder.mkdir()
    # 8 kB above a floor of 1 MB: met within the first second or two of traffic
    recorder = _start_recorder(vcan0, folder, "--max-bytes", "5000", "--min-free-mb", "1",
                               env={FAKE_FREE_ENV: str(1_000_000 + 8_000)})
    try:
        subprocess.run(["canplayer", "-I", str(tmp_path / "trace.log")], check=True, timeout=120)
        out, err = recorder.communicate(timeout=60)
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
    assert recorder.returncode == EXIT_DISK_FLOOR, err
    stops = [line for line in err.splitlines() if not line.startswith("record: ")]  # not the status lines
    assert len(stops) == 1 and stops[0].startswith("aider-exo: record: stopped:") and "below the floor" in stops[0], err
    summary = json.loads(out)
    assert summary["stopped_by"] == "disk_floor" and summary["current"] is None
    files = [p for _, p in session_files(folder, vcan0)]
    assert [p.name for p in files] == summary["files"] and files and not list(folder.glob("*.part"))
    recorded = _read_all(files)
    assert 8_000 <= summary["bytes"] and 0 < len(recorded) < len(sent)
    assert [_key(f) for f in recorded] == [_key(f) for f in sent[:len(recorded)]]  # a prefix, in order
