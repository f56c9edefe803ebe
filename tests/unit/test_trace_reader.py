"""Reading traces: every format by suffix, and bad input as counted skips or one clear error."""

from __future__ import annotations

import io

import can
import pytest

from protocol.codec import Codec
from tools.cli import main
from tools.trace import TraceError
from tools.trace.reader import Frame, ReadReport, parse_candump_line, read_frames
from tools.trace.synthetic import lockstep_frames

FRAMES = lockstep_frames(Codec(), 6)


def _write(frames, path):
    with can.Logger(str(path)) as writer:
        for frame in frames:
            writer.on_message_received(frame.to_message())


def test_candump_lines_of_every_kind():
    assert parse_candump_line("(1.500000) can0 181#0102030405060708") == Frame(1.5, 0x181, bytes(range(1, 9)), "can0")
    assert parse_candump_line("(1.5) can0 181#01.02.03 T").is_rx is False
    ext = parse_candump_line("(2.0) vcan0 12345678#AB")
    assert ext.is_extended_id and ext.arbitration_id == 0x12345678 and ext.data == b"\xab"
    remote = parse_candump_line("(2.0) vcan0 123#R4")
    assert remote.is_remote_frame and len(remote.data) == 4
    fd = parse_candump_line("(2.0) vcan0 123##1" + "00" * 12)
    assert fd.is_fd and len(fd.data) == 12
    err = parse_candump_line("(3.0) vcan0 20000080#0000000000000000")
    assert err.is_error_frame
    assert parse_candump_line("(3.0) vcan0 123#1122_9").data == b"\x11\x22"  # len8_dlc
    assert parse_candump_line("") is None and parse_candump_line("# a comment") is None
    for bad in ("garbage", "(x) can0 123#00", "(1.0) can0 123", "(1.0) can0 12#00", "(1.0) can0 123#0G",
                "(1.0) can0 123#001", "(1.0) can0 123#" + "00" * 9, "(1.0) can0 ZZZ#00"):
        assert isinstance(parse_candump_line(bad), str), bad


def test_a_candump_log_with_garbage_and_a_truncated_last_line_is_read_with_counted_skips(tmp_path):
    path = tmp_path / "bad.log"
    good = [f"({f.timestamp:.6f}) vcan0 {f.arbitration_id:03X}#{f.data.hex().upper()}" for f in FRAMES]
    lines = good[:5] + ["this is not a frame", "", "# comment"] + good[5:] + [good[0][:20]]
    path.write_text("\n".join(lines))
    report = ReadReport()
    frames = list(read_frames([path], report))
    assert [(f.arbitration_id, f.data) for f in frames] == [(f.arbitration_id, f.data) for f in FRAMES]
    assert report.skipped == 2 and report.frames == len(FRAMES)
    nine = ReadReport()
    (tmp_path / "nine.log").write_text("(1.0) can0 181#" + "00" * 9 + "\n")
    assert list(read_frames([tmp_path / "nine.log"], nine)) == [] and "9 data bytes" in nine.examples[0]
    assert report.examples[0].startswith(f"{path}:6:") and "not a candump log line" in report.examples[0]
    assert any("skipped 2 line(s)" in w for w in report.warnings())


def test_timestamps_going_backwards_are_counted(tmp_path):
    path = tmp_path / "back.log"
    path.write_text("(2.0) can0 080#00\n(1.0) can0 080#00\n(3.0) can0 080#00\n(2.5) can0 080#00\n")
    report = ReadReport()
    assert len(list(read_frames([path], report))) == 4
    assert report.backwards == 2 and "2 timestamp(s) went backwards" in report.warnings()


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".trc", ".csv"])
def test_every_python_can_format_round_trips(tmp_path, suffix):
    path = tmp_path / f"trace{suffix}"
    _write(FRAMES, path)
    report = ReadReport()
    frames = list(read_frames([path], report))
    assert report.skipped == 0 and not report.problems
    assert [(f.arbitration_id, f.data) for f in frames] == [(f.arbitration_id, f.data) for f in FRAMES]
    tolerance = 1e-3 if suffix == ".trc" else 1e-5  # TRC keeps milliseconds
    relative = [f.timestamp - frames[0].timestamp for f in frames]
    expected = [f.timestamp - FRAMES[0].timestamp for f in FRAMES]
    assert all(abs(a - b) < tolerance for a, b in zip(relative, expected))


def test_several_files_are_read_in_the_order_given(tmp_path):
    a, b = tmp_path / "a.log", tmp_path / "b.asc"
    _write(FRAMES[:10], a)
    _write(FRAMES[10:], b)
    report = ReadReport()
    assert [f.data for f in read_frames([a, b], report)] == [f.data for f in FRAMES]
    assert report.files == [str(a), str(b)]


def test_garbage_inside_asc_trc_and_csv_files_is_a_counted_skip(tmp_path):
    for suffix, garbage in ((".asc", "   1.000000 1  181             Rx   d 8 ZZ 01 02 03 04 05 06 07\n"),
                            (".trc", "     99      10.000 DT  1      0181 Rx -  8    ZZ XX\n"),
                            (".csv", "1.0,0x181,0,0,0,8,not*base64\n")):
        path = tmp_path / f"g{suffix}"
        _write(FRAMES, path)
        lines = path.read_text().splitlines(keepends=True)
        lines.insert(len(lines) - 3, garbage)
        path.write_text("".join(lines))
        report = ReadReport()
        frames = list(read_frames([path], report))
        assert len(frames) == len(FRAMES), suffix
        assert report.skipped == 1, (suffix, report.examples)


def test_a_truncated_blf_keeps_what_it_holds_and_says_it_is_truncated(tmp_path):
    path = tmp_path / "cut.blf"
    _write(FRAMES, path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 40])
    report = ReadReport()
    frames = list(read_frames([path], report))  # never raises
    assert len(frames) < len(FRAMES)
    assert report.problems and "truncated" in report.problems[0]


def test_a_file_that_is_not_what_its_suffix_says_is_one_clear_error(tmp_path):
    path = tmp_path / "text.blf"
    path.write_text("hello")
    with pytest.raises(TraceError, match="not a valid .blf file"):
        list(read_frames([path], ReadReport()))


def test_missing_file_and_unknown_suffix_are_one_line_errors(tmp_path, capsys):
    assert main(["trace", "decode", str(tmp_path / "none.log")]) == 1
    assert "no such file" in capsys.readouterr().err
    (tmp_path / "x.pcap").write_text("")
    assert main(["trace", "stats", str(tmp_path / "x.pcap")]) == 1
    err = capsys.readouterr().err
    assert "unknown trace format '.pcap'" in err and "Traceback" not in err


def test_mf4_needs_asammdf_and_says_so(tmp_path):
    import importlib.util

    if importlib.util.find_spec("asammdf") is not None:
        pytest.skip("asammdf is installed here: .mf4 is read")
    path = tmp_path / "t.mf4"
    path.write_bytes(b"MDF     ")
    with pytest.raises(TraceError, match="needs asammdf"):
        list(read_frames([path], ReadReport()))


def test_standard_input_is_candump_log_format():
    report = ReadReport()
    stdin = io.StringIO("(1.0) can0 080#00\nnoise\n(1.1) can0 080#01\n")
    assert [f.data for f in read_frames(["-"], report, stdin)] == [b"\x00", b"\x01"]
    assert report.skipped == 1 and "<stdin>:2" in report.examples[0]


VALID = {}


def _valid(suffix, tmp_path):
    if suffix not in VALID:
        path = tmp_path / f"valid{suffix}"
        _write(FRAMES, path)
        VALID[suffix] = path.read_bytes()
    return VALID[suffix]


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".trc", ".csv"])
def test_random_bytes_and_cut_or_damaged_files_never_raise_past_a_one_line_error(tmp_path, suffix):
    """Any content under any suffix: frames, counted skips, reported problems or one TraceError."""
    import numpy as np

    rng = np.random.default_rng(11)
    valid = _valid(suffix, tmp_path)
    samples = [rng.bytes(int(rng.integers(0, 400))) for _ in range(15)]
    samples += [valid[: int(rng.integers(0, len(valid)))] for _ in range(15)]
    for _ in range(15):
        damaged = bytearray(valid)
        for i in rng.integers(0, len(damaged), 8):
            damaged[i] = int(rng.integers(0, 256))
        samples.append(bytes(damaged))
    for k, data in enumerate(samples):
        path = tmp_path / f"sample{k}{suffix}"
        path.write_bytes(data)
        report = ReadReport()
        try:
            frames = list(read_frames([path], report))
        except TraceError as exc:
            assert "\n" not in str(exc)
            continue
        assert report.frames == len(frames)
        assert all(isinstance(f.data, bytes) and isinstance(f.timestamp, float) for f in frames)
