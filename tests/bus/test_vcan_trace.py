"""Interop over a real SocketCAN vcan0 with can-utils and cantools.

can-utils' canplayer plays a lock-step trace onto vcan0 while ``aider-exo trace record`` records
the bus (and its sidecar); then canplayer plays our recording while candump (``-L``) captures it:
candump sees the same frames with the same timing. Our replay sends the recording's controller frames (the role that drives
live nodes) while candump captures them. We decode candump's log, every value as sent, and
``cantools decode`` with our DBC agrees with our decode on every signal. The traffic is the
protocol's schedule made up from the DBC (no simulation in the sandbox, whose CPU is several
times slower; the same agreement on a recorded walking run is tests/bus/test_trace_walk.py). The
timing bounds are loose on purpose: the sandbox's one slow CPU runs everything at once.

Run through the vcan sandbox (``make test`` does: ``tools/vcan-run -- pytest -m vcan``).
"""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

from protocol.codec import Codec
from tests.support.capture import PROBE_ID, assert_cantools_agrees, candump, read_log
from tools.buscheck import expected_record
from tools.cli import main
from tools.trace.decode import TraceDecoder
from tools.trace.record import TraceWriter
from tools.trace.synthetic import lockstep_frames

pytestmark = pytest.mark.vcan

TICKS = 60  # 1.2 s, 1029 frames


def _relative(times):
    t = np.asarray(times, dtype=float)
    return t - t[0]


def _dumped(path):
    return [f for f in read_log(path) if f.arbitration_id != PROBE_ID]


def _same_frames(a, b):
    assert [(f.arbitration_id, f.data) for f in a] == [(f.arbitration_id, f.data) for f in b]


def _timing_error_s(a, b):
    return np.abs(_relative([f.timestamp for f in a]) - _relative([f.timestamp for f in b]))


def _assert_same_timing(a, b, p90_s=0.005, max_s=0.05):
    error = _timing_error_s(a, b)
    assert np.percentile(error, 90) < p90_s and error.max() < max_s, np.percentile(error, [50, 90, 100])


def test_record_canplayer_candump_replay_and_cantools_agree_over_vcan0(vcan0, tmp_path, capsys):
    codec = Codec()
    trace = tmp_path / "trace.log"
    writer = TraceWriter(trace)
    for frame in lockstep_frames(codec, TICKS, channel=vcan0):
        writer.write(frame.to_message())
    writer.close({})
    sent = read_log(trace)

    # 1. `aider-exo trace record` records vcan0 (kernel receive timestamps) while canplayer plays
    #    the trace (started once the recorder has had time to listen).
    recording = tmp_path / "recorded.log"
    player = subprocess.Popen(["sh", "-c", f"sleep 2; exec canplayer -I {trace}"])
    try:
        assert main(["trace", "record", str(recording), "--bus", "socketcan", "--channel", vcan0,
                     "--count", str(len(sent)), "--idle-timeout", "60", "--json"]) == 0
    finally:
        assert player.wait(timeout=120) == 0
    meta = json.loads(capsys.readouterr().out)
    assert meta["frames"] == len(sent) and meta["source"] == {"kind": "bus", "ended_by": "count"}
    assert meta["bus"] == {"interface": "socketcan", "channel": vcan0} and meta["parts"] == [recording.name]
    recorded = read_log(recording)
    _same_frames(recorded, sent)
    _assert_same_timing(recorded, sent)

    # 2. canplayer plays our recording; candump sees the same frames with the same timing.
    dump = tmp_path / "candump.log"
    with candump(vcan0, dump):
        subprocess.run(["canplayer", "-I", str(recording), f"{vcan0}={vcan0}"], check=True, timeout=120)
    dumped = _dumped(dump)
    _same_frames(dumped, recorded)
    _assert_same_timing(dumped, recorded)

    # 3. Our replay of the recording's controller frames (to drive live nodes), seen by candump.
    replayed = tmp_path / "replayed.log"
    with candump(vcan0, replayed):
        assert main(["trace", "replay", str(recording), "--bus", "socketcan", "--channel", vcan0,
                     "--role", "controller", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    controller_frames = [f for f in recorded if codec.catalog.by_id(f.arbitration_id).sender == "CONTROLLER"]
    assert result["sent"] == len(controller_frames) and result["send_failures"] == 0
    seen = _dumped(replayed)
    _same_frames(seen, controller_frames)
    _assert_same_timing(seen, controller_frames, p90_s=0.01, max_s=0.1)

    # 4. We decode candump's log: every frame checked and every value the one sent.
    rows = list(TraceDecoder(codec).rows(dumped))
    assert {r.status for r in rows} == {"ok"} and len(rows) == len(sent)
    tick = -1
    for row in rows:
        if row.spec.name == "SYNC":
            tick = row.values.tick
        else:
            for sig, got, want in zip(row.spec.signals, row.values, expected_record(row.spec, tick)):
                assert math.isclose(got, want, abs_tol=sig.scale / 2), (row.spec.name, sig.name)

    # 5. cantools' command line with our DBC agrees with our decode on every signal.
    lines = [line for line in dump.read_text().splitlines() if f" {PROBE_ID:03X}#" not in line]
    assert assert_cantools_agrees(rows, "\n".join(lines) + "\n") > 10 * TICKS
