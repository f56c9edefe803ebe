"""Per-tick telemetry: the schema line, the records, and a writer that never blocks the tick."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from controller.telemetry import SCHEMA_VERSION, FIELDS, TelemetryLog, read_log


def record(tick: int) -> dict:
    r = {k: None for k in FIELDS}
    r.update(tick=tick, state="STAND", q_rad=np.array([0.1, 0.2, 0.3, 0.4]), x_ratio=math.nan, events=[], work_us=12.5)
    return r


def test_records_follow_the_schema_line(tmp_path):
    log = TelemetryLog(tmp_path / "t.jsonl")
    for k in range(50):
        log.put(record(k))
    report = log.close()
    assert report == {"path": str(tmp_path / "t.jsonl"), "written": 50, "dropped": 0, "error": None, "previous": None}
    schema, records = read_log(tmp_path / "t.jsonl")
    assert schema["version"] == SCHEMA_VERSION and list(schema["fields"]) == list(FIELDS)
    assert [r["tick"] for r in records] == list(range(50))
    assert records[0]["q_rad"] == [0.1, 0.2, 0.3, 0.4] and records[0]["x_ratio"] is None  # nan -> null
    assert all(list(r) == list(FIELDS) for r in records)


def test_a_record_with_other_fields_is_refused(tmp_path):
    log = TelemetryLog(tmp_path / "t.jsonl")
    try:
        with pytest.raises(ValueError, match="extra"):
            log.put({**record(0), "extra": 1})
    finally:
        log.close()


def test_a_stalled_writer_drops_the_oldest_and_never_blocks_the_tick(tmp_path):
    log = TelemetryLog(tmp_path / "t.jsonl", capacity=10)
    release = threading.Event()
    real_write = log._file.write

    def slow_write(text):
        release.wait(30)  # the disk hangs
        return real_write(text)

    log._file.write = slow_write
    for k in range(200):  # the tick goes on regardless
        log.put(record(k))
    release.set()
    report = log.close()
    assert report["dropped"] >= 200 - 10 - 1 and report["written"] + report["dropped"] == 200
    _, records = read_log(tmp_path / "t.jsonl")
    assert records[-1]["tick"] == 199  # the newest survive


def test_a_failing_disk_is_reported_not_raised(tmp_path):
    log = TelemetryLog(tmp_path / "t.jsonl")

    def full(_text):
        raise OSError(28, "No space left on device")

    log._file.write = full
    for k in range(20):
        log.put(record(k))
    report = log.close()
    assert report["written"] == 0 and report["dropped"] == 20 and "No space left" in report["error"]


def test_a_restart_with_the_same_log_keeps_the_first_runs_lines(tmp_path):
    import os

    path = tmp_path / "t.jsonl"
    first = TelemetryLog(path)
    for k in range(5):
        first.put(record(k))
    first.close()
    os.utime(path, (1_796_621_000, 1_796_621_000))  # 2026-12-07T05:23:20Z
    before = path.read_bytes()
    second = TelemetryLog(path)  # the controller restarted with the same --log
    second.put(record(100))
    report = second.close()
    moved = tmp_path / "t.20261207T052320Z.jsonl"
    assert second.previous == moved and report["previous"] == str(moved)
    assert moved.read_bytes() == before  # the crashed run's log, whole
    assert [r["tick"] for r in read_log(path)[1]] == [100]
    # a third run whose previous log has the same modification time: a -1 name, nothing overwritten
    os.utime(path, (1_796_621_000, 1_796_621_000))
    third = TelemetryLog(path)
    third.close()
    assert third.previous == tmp_path / "t.20261207T052320Z-1.jsonl"
    assert moved.read_bytes() == before and [r["tick"] for r in read_log(third.previous)[1]] == [100]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.20261207T052320Z-1.jsonl", "t.20261207T052320Z.jsonl", "t.jsonl"]


def test_an_empty_log_is_simply_reused(tmp_path):
    (tmp_path / "t.jsonl").write_text("")
    log = TelemetryLog(tmp_path / "t.jsonl")
    log.close()
    assert log.previous is None and [p.name for p in tmp_path.iterdir()] == ["t.jsonl"]
