"""``trace stats``: per-ID periods and errors, bus load and the tick seen from SYNC, on traces whose
figures are known from how they were made."""

from __future__ import annotations

import json

import pytest

from protocol.busload import mean_load_bits_per_s
from protocol.catalog import default_catalog
from protocol.clock import TICK_S
from protocol.codec import Codec
from tools.cli import main
from tools.trace.decode import TraceDecoder
from tools.trace.stats import collect
from tools.trace.synthetic import lockstep_frames

CODEC = Codec()
CATALOG = default_catalog()
TICKS = 100


def _stats(frames, bitrate=1_000_000):
    return collect(TraceDecoder(CODEC).rows(frames), CATALOG, bitrate)


def test_a_clean_lockstep_trace():
    frames = lockstep_frames(CODEC, TICKS, node_delay_s=0.002, command_delay_s=0.005)
    r = _stats(frames)
    assert r["frames"] == len(frames) and r["crc_errors"] == 0 and r["counter_errors"] == 0 and r["lost_by_counter"] == 0
    per_id = {e["message"]: e for e in r["per_id"]}
    assert per_id["SYNC"]["count"] == TICKS and per_id["SYNC"]["dbc_period_ms"] == 20
    assert per_id["JOINT_STATUS_LH"]["period_ms"]["mean"] == pytest.approx(20.0, abs=1e-3)
    assert per_id["JOINT_STATUS_LH"]["period_ms"]["jitter_std"] < 1e-3
    assert per_id["HEARTBEAT_LH"]["period_ms"]["mean"] == pytest.approx(100.0, abs=1e-3)
    tick = r["tick"]
    assert (tick["syncs"], tick["first_tick"], tick["last_tick"], tick["ticks_missed"]) == (TICKS, 0, TICKS - 1, 0)
    assert tick["period_ms"]["mean"] == pytest.approx(20.0, abs=1e-4)
    assert tick["sync_to_first_command_ms"]["p50"] == pytest.approx(5.0, abs=1e-3)
    assert 2.0 < tick["sync_to_last_node_frame_ms"]["p50"] < 5.0
    # Bus load over whole hyperperiods is the protocol's mean load (can-utils' frame lengths).
    duration = frames[-1].timestamp - frames[0].timestamp
    expected = mean_load_bits_per_s(CATALOG) * (TICKS * TICK_S) / duration / 1e6 * 100
    assert r["bus_load"]["mean_percent_worst"] == pytest.approx(expected, rel=0.02)
    assert r["bus_load"]["peak_20ms_window_percent_worst"] > r["bus_load"]["mean_percent_worst"] * 0.9


def test_missed_ticks_lost_frames_crc_errors_and_jitter_are_counted():
    frames = lockstep_frames(CODEC, TICKS)
    sync = CATALOG.by_name("SYNC").frame_id
    lh = CATALOG.by_name("JOINT_STATUS_LH").frame_id
    syncs = [i for i, f in enumerate(frames) if f.arbitration_id == sync]
    statuses = [i for i, f in enumerate(frames) if f.arbitration_id == lh]
    drop = {syncs[10], statuses[50]}
    corrupt = statuses[70]
    frames = [f._replace(data=bytes([f.data[0] ^ 1]) + f.data[1:]) if i == corrupt else f
              for i, f in enumerate(frames) if i not in drop]
    frames = [f._replace(timestamp=f.timestamp + 0.003) if f.arbitration_id == sync and i % 2 else f for i, f in enumerate(frames)]
    r = _stats(frames)
    tick = r["tick"]
    assert tick["ticks_missed"] == 1 and tick["syncs"] == TICKS - 1
    assert tick["period_error_ms"]["max"] > 2.0
    per_id = {e["message"]: e for e in r["per_id"]}
    # The corrupt frame is lost too: its counter is not trusted, so the next frame shows a gap of one.
    assert per_id["JOINT_STATUS_LH"]["lost_by_counter"] == 2 and per_id["JOINT_STATUS_LH"]["crc_errors"] == 1
    assert r["crc_errors"] == 1 and r["rejected_by_reason"] == {"bad_crc": 1}
    assert r["lost_by_counter"] == 3 and per_id["SYNC"]["lost_by_counter"] == 1  # and the dropped SYNC


def test_cli_stats_json_and_text(tmp_path, capsys):
    frames = lockstep_frames(CODEC, 30)
    log = tmp_path / "t.log"
    log.write_text("".join(f"({f.timestamp:.6f}) vcan0 {f.arbitration_id:03X}#{f.data.hex()}\n" for f in frames) + "junk\n")
    assert main(["trace", "stats", str(log), "--json", "--bitrate", "500000"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["frames"] == len(frames) and r["bus_load"]["bitrate_bit_s"] == 500_000
    assert r["input"]["skipped_lines"] == 1 and r["warnings"] and r["tick"]["syncs"] == 30
    assert main(["trace", "stats", str(log), "--message", "JOINT_STATUS_*"]) == 0
    out = capsys.readouterr()
    assert "JOINT_STATUS_RK" in out.out and "SYNC " not in out.out and "skipped 1 line" in out.err
