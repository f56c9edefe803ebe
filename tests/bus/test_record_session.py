"""``aider-exo record``, the session recorder (tools/trace/session.py, tools/cli/record.py), on the
virtual bus and a manual clock: rotation by size and by age, names never reused, ``.part`` until
finished, ``--keep``, the free-disk floor through an injected probe, every frame in exactly one
file in order, the exit statuses and the one-line errors. The same over a real vcan0 with candump
as the witness: tests/bus/test_vcan_record.py."""

from __future__ import annotations

import json
import os
import signal
import threading

import can
import pytest

from protocol.bus import virtual_bus
from protocol.clock import ManualClock
from tools.cli import main
from tools.cli.record import FAKE_FREE_ENV
from tools.trace.reader import ReadReport, parse_candump_line, read_frames
from tools.trace.session import (EXIT_BUS_ERROR, EXIT_DISK_FLOOR, NAME_RE, SessionRecorder, candump_line,
                                 record_session, session_files)

WALL = 1_780_000_000.0  # a fixed wall clock for the names
UTC = "20260528T202640Z"  # its UTC time as the names give it


def _msg(i: int, t: float = 1000.0) -> can.Message:
    return can.Message(timestamp=t + i * 0.001, arbitration_id=0x100 + i % 0x500, is_extended_id=False,
                       data=i.to_bytes(4, "little"))


def _frames(paths):
    report = ReadReport()
    frames = list(read_frames(paths, report))
    assert report.skipped == 0 and not report.problems, report
    return frames


def _finished(folder, channel="vcan0"):
    return [p for _, p in session_files(folder, channel)]


def _assert_all_once_in_order(paths, sent):
    got = [(f.arbitration_id, bytes(f.data)) for f in _frames(paths)]
    assert got == [(m.arbitration_id, bytes(m.data)) for m in sent]


def _recorder(tmp_path, **kw):
    kw.setdefault("clock", ManualClock())
    return SessionRecorder(tmp_path, "vcan0", wall=lambda: WALL, **kw)


def test_lines_are_candumps_and_read_back():
    frames = [
        can.Message(timestamp=1.5, arbitration_id=0x123, data=b"\x01\xab", is_extended_id=False),
        can.Message(timestamp=2.0, arbitration_id=0x1ABCDEF0, data=b"", is_extended_id=True),
        can.Message(timestamp=2.5, arbitration_id=0x7FF, is_remote_frame=True, dlc=3, is_extended_id=False),
        can.Message(timestamp=3.0, arbitration_id=0x4, is_error_frame=True, data=bytes(8), is_extended_id=True),
        can.Message(timestamp=3.5, arbitration_id=0x55, is_fd=True, bitrate_switch=True, data=bytes(range(12)), is_extended_id=False),
    ]
    assert candump_line(frames[0], "can0") == "(1.500000) can0 123#01AB\n"
    assert candump_line(frames[2], "can0") == "(2.500000) can0 7FF#R3\n"
    assert candump_line(frames[3], "can0") == "(3.000000) can0 20000004#0000000000000000\n"
    for msg in frames:
        back = parse_candump_line(candump_line(msg, "can0"))
        assert (back.arbitration_id, back.is_extended_id, back.is_remote_frame, back.is_error_frame, back.is_fd) == (
            msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.is_error_frame, msg.is_fd)
        assert back.timestamp == msg.timestamp and (msg.is_remote_frame or back.data == bytes(msg.data))


def test_size_rotation_keeps_every_file_under_the_limit_and_every_frame_once_in_order(tmp_path):
    rec = _recorder(tmp_path, max_bytes=500)
    sent = [_msg(i) for i in range(200)]
    for start in range(0, 200, 7):  # batches of 7
        assert rec.write(sent[start:start + 7])
    assert rec.current.name.endswith(".log.part") and rec.current.exists()
    rec.finish()
    files = _finished(tmp_path)
    assert files == rec.files and len(files) >= 10
    assert all(0 < p.stat().st_size <= 500 for p in files)
    assert not list(tmp_path.glob("*.part"))
    _assert_all_once_in_order(files, sent)
    seqs = [int(NAME_RE.fullmatch(p.name)["seq"]) for p in files]
    assert seqs == list(range(1, len(files) + 1))
    assert all(p.name.startswith(f"vcan0_{UTC}_") for p in files)
    assert rec.frames == 200 and rec.bytes == sum(p.stat().st_size for p in files)


def test_age_rotation_also_on_a_quiet_bus(tmp_path):
    clock = ManualClock()
    rec = _recorder(tmp_path, max_seconds=2.0, clock=clock)
    sent = [_msg(i) for i in range(30)]
    for i, msg in enumerate(sent):
        rec.write([msg])
        clock.advance(250_000_000)  # 4 frames a second: 8 per file
    assert [len(_frames([p])) for p in rec.files] == [8, 8, 8]
    clock.advance(2_000_000_000)
    rec.rotate_if_old()  # no frame: the file is finished all the same
    assert rec.current is None and len(rec.files) == 4
    _assert_all_once_in_order(rec.files, sent)


def test_the_part_file_holds_what_was_written_and_is_renamed_when_finished(tmp_path):
    rec = _recorder(tmp_path)
    rec.write([_msg(i) for i in range(5)])
    part = rec.current
    assert part.name.endswith(".log.part") and not rec.files
    assert len(part.read_text().splitlines()) == 5  # flushed after the batch
    final = rec.finish()
    assert not part.exists() and final == part.with_name(part.name[:-len(".part")])
    assert len(_frames([final])) == 5


def test_no_name_is_ever_reused(tmp_path):
    old = tmp_path / "vcan0_20200101T000000Z_000007.log"
    old.write_text("(1.0) vcan0 123#00\n")
    crashed = tmp_path / "vcan0_20200101T000000Z_000008.log.part"  # a killed run's file
    crashed.write_text("(1.0) vcan0 123#01\n")
    other = tmp_path / "can1_20200101T000000Z_000050.log"  # another channel's numbers are its own
    other.write_text("")
    in_the_way = tmp_path / f"vcan0_{UTC}_000009.log"  # put there by hand, the next name
    rec = _recorder(tmp_path, max_bytes=100)
    in_the_way.write_text("mine\n")
    sent = [_msg(i) for i in range(10)]
    rec.write(sent)
    rec.finish()
    seqs = [int(NAME_RE.fullmatch(p.name)["seq"]) for p in rec.files]
    assert seqs[0] == 10 and seqs == sorted(set(seqs))
    assert old.read_text() == "(1.0) vcan0 123#00\n" and crashed.read_text() == "(1.0) vcan0 123#01\n"
    assert in_the_way.read_text() == "mine\n"
    _assert_all_once_in_order(rec.files, sent)
    # a second run in the same second goes on from the highest number
    rec2 = _recorder(tmp_path)
    rec2.write([_msg(99)])
    assert int(NAME_RE.fullmatch(rec2.finish().name)["seq"]) == seqs[-1] + 1


def test_keep_removes_the_oldest_finished_files_only(tmp_path):
    earlier = tmp_path / "vcan0_20200101T000000Z_000001.log"
    earlier.write_text("")
    foreign = tmp_path / "notes.txt"
    foreign.write_text("x")
    rec = _recorder(tmp_path, max_bytes=300, keep=3)
    sent = [_msg(i) for i in range(100)]
    for msg in sent:
        rec.write([msg])
    assert rec.current is not None  # the file being written is not counted
    rec.finish()
    kept = _finished(tmp_path)
    assert kept == rec.files[-3:] and len(rec.files) > 5
    assert earlier in rec.deleted and not earlier.exists() and foreign.exists()
    assert [(f.arbitration_id, bytes(f.data)) for f in _frames(kept)] == [
        (m.arbitration_id, bytes(m.data)) for m in sent[-sum(len(_frames([p])) for p in kept):]]


def test_disk_floor_finishes_the_file_and_stops_probing_at_most_once_a_second(tmp_path):
    clock = ManualClock()
    probes = []
    free = {"bytes": 10_000}

    def probe(folder):
        probes.append(clock.now_ns())
        assert folder == tmp_path
        return free["bytes"]

    rec = _recorder(tmp_path, min_free_bytes=5_000, free_bytes=probe, clock=clock, max_bytes=400)
    sent = [_msg(i) for i in range(40)]
    for i, msg in enumerate(sent[:20]):
        assert rec.write([msg])
        clock.advance(100_000_000)
    free["bytes"] = 4_000  # the disk fills; noticed at the next probe, within a second
    written = 20
    while rec.write([sent[written]]):
        written += 1
        clock.advance(100_000_000)
    assert written < 30 and rec.unwritten == 1
    assert all(b - a >= 1_000_000_000 for a, b in zip(probes, probes[1:]))
    assert rec.current is None and not list(tmp_path.glob("*.part"))
    _assert_all_once_in_order(rec.files, sent[:written])


def test_record_session_over_a_virtual_bus_every_frame_once_in_order(tmp_path):
    sent = [_msg(i) for i in range(3000)]
    done = threading.Event()
    with virtual_bus("rec-test-order") as tap, virtual_bus("rec-test-order") as tx:
        def send():
            for msg in sent:
                tx.send(msg)
            done.set()
        rec = SessionRecorder(tmp_path, "vcan0", max_bytes=4000, keep=None)
        sender = threading.Thread(target=send)
        sender.start()
        reason, status, _ = record_session(tap, rec, stop=done.is_set, poll_s=0.01, batch_max=64)
        sender.join()
    assert (reason, status) == ("signal", 0)
    assert len(rec.files) >= 20 and not list(tmp_path.glob("*.part"))
    _assert_all_once_in_order(rec.files, sent)


class _FailingBus:
    def __init__(self, frames):
        self.frames = list(frames)

    def recv(self, timeout=None):
        if self.frames:
            return self.frames.pop(0)
        raise can.CanOperationError("Error receiving: Network is down [Error Code 100]")


def test_a_failing_interface_finishes_the_file_with_exit_status_4(tmp_path):
    sent = [_msg(i) for i in range(10)]
    rec = SessionRecorder(tmp_path, "can0")
    reason, status, detail = record_session(_FailingBus(sent), rec, stop=lambda: False)
    assert (reason, status) == ("bus_error", EXIT_BUS_ERROR) and "Network is down" in detail
    assert len(rec.files) == 1 and not list(tmp_path.glob("*.part"))
    _assert_all_once_in_order(rec.files, sent)


# -- the command line ---------------------------------------------------------------------------


def _run_cli(argv, channel, frames, *, then_signal=True):
    """``main(argv)`` (a --bus virtual recorder on ``channel``) while a thread sends ``frames``
    once it listens, then SIGTERM to this process."""
    import can.interfaces.virtual as virtual

    def send():
        with virtual_bus(channel) as tx:
            while len(virtual.channels.get(channel, ())) < 2:  # the recorder's bus is open
                threading.Event().wait(0.01)
            for msg in frames:
                tx.send(msg)
        if then_signal:
            os.kill(os.getpid(), signal.SIGTERM)

    sender = threading.Thread(target=send)
    sender.start()
    try:
        return main(argv)
    finally:
        sender.join()


def test_cli_records_until_sigterm_and_prints_a_json_summary(tmp_path, capsys):
    sent = [_msg(i) for i in range(500)]
    status = _run_cli(["record", "--bus", "virtual", "--channel", "rec-cli-1", "--dir", str(tmp_path),
                       "--max-bytes", "2k", "--keep", "4", "--json", "--min-free-mb", "0"], "rec-cli-1", sent)
    out = capsys.readouterr()
    assert status == 0
    summary = json.loads(out.out)
    assert summary["stopped_by"] == "SIGTERM" and summary["exit_status"] == 0
    assert summary["frames"] == 500 and summary["frames_not_written"] == 0 and summary["current"] is None
    kept = _finished(tmp_path, "rec-cli-1")
    assert [p.name for p in kept] == summary["files"][-4:] and len(summary["deleted"]) == len(summary["files"]) - 4
    assert out.err.startswith("record: recording virtual:rec-cli-1 into")


def test_cli_disk_floor_exit_status_3_one_line_and_a_valid_last_file(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(FAKE_FREE_ENV, str(1_000_000 + 3_000))  # 3 kB above the floor of 1 MB
    sent = [_msg(i) for i in range(400)]  # 12 kB in one burst: the floor is met at the next probe
    import can.interfaces.virtual as virtual

    done = threading.Event()

    def send():
        with virtual_bus("rec-cli-2") as tx:
            while len(virtual.channels.get("rec-cli-2", ())) < 2:
                threading.Event().wait(0.01)
            for i, msg in enumerate(sent):
                tx.send(msg)
                if i % 50 == 49:
                    threading.Event().wait(0.3)  # 400 frames over about 2.4 s
        done.set()

    sender = threading.Thread(target=send)
    sender.start()
    try:
        status = main(["record", "--bus", "virtual", "--channel", "rec-cli-2", "--dir", str(tmp_path),
                       "--min-free-mb", "1", "--max-bytes", "1000", "--json", "--quiet"])
    finally:
        sender.join()
    out = capsys.readouterr()
    assert status == EXIT_DISK_FLOOR
    summary = json.loads(out.out)
    assert summary["stopped_by"] == "disk_floor" and summary["current"] is None and summary["frames_not_written"] > 0
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("aider-exo: record: stopped:") and "below the floor" in lines[0]
    files = _finished(tmp_path, "rec-cli-2")
    assert [p.name for p in files] == summary["files"] and not list(tmp_path.glob("*.part"))
    assert 3_000 <= summary["bytes"] < 12_000
    _assert_all_once_in_order(files, sent[:summary["frames"]])


@pytest.mark.parametrize("argv, message", [
    (["--max-bytes", "-5"], "--max-bytes: -5 is not a positive whole number"),
    (["--max-bytes", "ten"], "--max-bytes: 'ten' is not a whole number"),
    (["--max-seconds", "0"], "--max-seconds: 0 is not a positive finite number"),
    (["--keep", "0"], "--keep: 0 is not a positive whole number"),
    (["--min-free-mb", "-1"], "--min-free-mb: -1 is not a non-negative finite number"),
    (["--status-every", "nan"], "--status-every: nan is not a positive finite number"),
])
def test_bad_numbers_are_one_line_errors(tmp_path, capsys, argv, message):
    assert main(["record", "--channel", "vcan0", "--dir", str(tmp_path), *argv]) == 1
    err = capsys.readouterr().err
    assert err == f"aider-exo: error: {message}\n"


def test_bad_folders_and_channels_are_one_line_errors(tmp_path, capsys):
    assert main(["record", "--channel", "vcan0", "--dir", str(tmp_path / "missing")]) == 1
    assert capsys.readouterr().err == f"aider-exo: error: {tmp_path / 'missing'}: no such folder (create it, or give --dir an existing one)\n"
    (tmp_path / "file").write_text("")
    assert main(["record", "--channel", "vcan0", "--dir", str(tmp_path / "file")]) == 1
    assert capsys.readouterr().err == f"aider-exo: error: {tmp_path / 'file'}: not a folder\n"
    assert main(["record", "--channel", "nosuchcan9", "--dir", str(tmp_path), "--min-free-mb", "0"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("aider-exo: error: cannot open socketcan channel 'nosuchcan9'") and err.count("\n") == 1
    if os.getuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert main(["record", "--channel", "vcan0", "--dir", str(locked)]) == 1
        assert "not writable" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.log*"))


def test_the_recorder_unit_writes_into_its_logs_directory_and_is_not_restarted_at_the_disk_floor():
    from tests.conftest import ROOT
    from tests.support.deploy import aider_argv, unit

    unit = unit(ROOT / "tools" / "deploy" / "aider-exo-record.service")
    service = unit["Service"]
    argv = aider_argv(service["ExecStart"])
    assert argv[0] == "record" and argv[argv.index("--dir") + 1] == f"/var/log/{service['LogsDirectory']}"
    assert service["RestartPreventExitStatus"] == str(EXIT_DISK_FLOOR) and service["Restart"] == "on-failure"
    assert service["Type"] == "notify" and "aider-exo-controller.service" in unit["Unit"]["Before"]
    assert "--quiet" not in argv  # its finished-file lines go to the journal
