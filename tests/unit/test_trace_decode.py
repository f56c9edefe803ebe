"""Decoding traces with the DBC: values and units, errors marked, selections, output formats, bad
input (another bus, the wrong DBC, a read that fails half-way) without a traceback or a partial file."""

from __future__ import annotations

import csv
import io
import json
import math

import can
import pytest

from protocol.catalog import DBC_PATH, default_catalog
from protocol.codec import Codec
from tools.buscheck import expected_record
from tools.cli import main
from tools.trace import TraceError
from tools.trace.decode import Formatter, Selection, TraceDecoder, write_csv, write_jsonl, write_table
from tools.trace.reader import Frame
from tools.trace.synthetic import lockstep_frames

CODEC = Codec()
CATALOG = default_catalog()
FRAMES = lockstep_frames(CODEC, 20)


def _rows(frames, selection=None):
    decoder = TraceDecoder(CODEC)
    return list(decoder.rows(frames, selection.compile(CATALOG) if selection else None)), decoder


def _log(frames, path):
    path.write_text("".join(f"({f.timestamp:.6f}) vcan0 {f.arbitration_id:03X}#{f.data.hex().upper()}\n" for f in frames))
    return path


def test_every_frame_decodes_to_the_values_sent():
    rows, decoder = _rows(FRAMES)
    assert len(rows) == len(FRAMES) and {r.status for r in rows} == {"ok"}
    sync_ticks = [r.values.tick for r in rows if r.spec.name == "SYNC"]
    assert sync_ticks == list(range(20))
    tick = -1
    for row in rows:
        if row.spec.name == "SYNC":
            tick = row.values.tick
            continue
        sent = expected_record(row.spec, tick)
        for sig, got, want in zip(row.spec.signals, row.values, sent):
            assert math.isclose(got, want, abs_tol=sig.scale / 2), (row.spec.name, sig.name)
    assert rows[0].time_s == 0.0 and rows[-1].time_s == pytest.approx(FRAMES[-1].timestamp - FRAMES[0].timestamp)


def _bad_trace():
    frames = list(FRAMES[:60])
    status = next(i for i, f in enumerate(frames) if CATALOG.by_id(f.arbitration_id).name == "JOINT_STATUS_LH")
    bad_crc = frames[status]._replace(data=bytes([frames[status].data[0] ^ 0xFF]) + frames[status].data[1:])
    frames[status] = bad_crc
    duplicate_at = next(i for i, f in enumerate(frames) if CATALOG.by_id(f.arbitration_id).name == "STICK_LEFT")
    frames.insert(duplicate_at + 1, frames[duplicate_at])
    trunk = [i for i, f in enumerate(frames) if CATALOG.by_id(f.arbitration_id).name == "TRUNK_IMU_RATE"]
    del frames[trunk[1]]  # the next one follows a lost frame
    frames.append(Frame(frames[-1].timestamp + 0.001, 0x7FF, b"\x01\x02\x03", "vcan0"))
    frames.append(Frame(frames[-1].timestamp + 0.001, 0x080, b"\x01\x02", "vcan0"))  # SYNC, 2 bytes
    return frames


def test_crc_and_counter_errors_lost_frames_and_unknown_ids_are_marked():
    rows, decoder = _rows(_bad_trace())
    by_status = {}
    for row in rows:
        by_status.setdefault(row.status, []).append(row)
    assert by_status["bad_crc"][0].spec.name == "JOINT_STATUS_LH" and by_status["bad_crc"][0].values is None
    repeated = by_status["repeated_counter"][0]
    assert repeated.spec.name == "STICK_LEFT" and repeated.values is not None  # a good CRC: its values are shown
    lost = [r for r in rows if r.lost_before]
    assert [(r.spec.name, r.lost_before) for r in lost] == [("TRUNK_IMU_RATE", 1)]
    assert by_status["unknown_id"][0].frame.arbitration_id == 0x7FF and by_status["unknown_id"][0].spec is None
    assert by_status["wrong_dlc"][0].spec.name == "SYNC"
    out = io.StringIO()
    write_table(rows, Formatter(CATALOG, None), out)
    text = out.getvalue()
    assert "!BAD_CRC" in text and "!REPEATED_COUNTER" in text and "(lost 1)" in text
    assert "7FF  ?" in text and "[3] 01 02 03" in text
    assert "position_rad=" in text and " rad" in text and "drive_state=" in text


def test_selection_by_node_message_signal_and_time():
    rows, _ = _rows(FRAMES, Selection(nodes=("left_hip",)))
    names = {r.spec.name for r in rows}
    assert "JOINT_COMMAND_LH" in names and "JOINT_STATUS_LH" in names and "STICK_LEFT" in names
    assert all(r.spec.sender == "LEFT_HIP" or r.spec.receivers == ("LEFT_HIP",) for r in rows)
    rows, _ = _rows(FRAMES, Selection(messages=("joint_status_*", "0x080")))
    assert {r.spec.name for r in rows} == {"JOINT_STATUS_LH", "JOINT_STATUS_LK", "JOINT_STATUS_RH", "JOINT_STATUS_RK", "SYNC"}
    selection = Selection(signals=("JOINT_*_LH.position*",)).compile(CATALOG)
    rows, _ = _rows(FRAMES, Selection(signals=("JOINT_*_LH.position*",)))
    assert {r.spec.name for r in rows} == {"JOINT_STATUS_LH", "JOINT_COMMAND_LH"}
    shown = [sig.name for sig, _ in Formatter(CATALOG, selection).signals(rows[0])]
    assert shown in (["position_rad"], ["position_setpoint_rad"])
    rows, _ = _rows(FRAMES, Selection(start_s=0.1, end_s=0.2))
    assert rows and all(0.1 <= r.time_s <= 0.2 for r in rows)
    rows, _ = _rows(FRAMES, Selection(senders=("CONTROLLER",)))
    assert {r.spec.sender for r in rows} == {"CONTROLLER"}


def test_a_filter_never_changes_the_counter_checks():
    """Frames not shown still go through the receiver: a message shown alone is checked as in the whole trace."""
    frames = _bad_trace()
    alone, _ = _rows(frames, Selection(messages=("TRUNK_IMU_RATE",)))
    whole, _ = _rows(frames)
    assert [(r.status, r.lost_before) for r in alone] == [(r.status, r.lost_before) for r in whole if r.spec and r.spec.name == "TRUNK_IMU_RATE"]


@pytest.mark.parametrize("kwargs, message", [
    ({"nodes": ("LEFT_ELBOW",)}, "no node 'LEFT_ELBOW'"),
    ({"messages": ("NOPE*",)}, r"no message matches 'NOPE\*'"),
    ({"signals": ("nothing",)}, "no signal matches 'nothing'"),
    ({"start_s": 2.0, "end_s": 1.0}, "ends"),
])
def test_names_the_dbc_lacks_are_one_clear_error(kwargs, message):
    with pytest.raises(TraceError, match=message):
        Selection(**kwargs).compile(CATALOG)


def test_an_id_the_dbc_lacks_can_still_be_selected_raw():
    rows, _ = _rows(_bad_trace(), Selection(messages=("0x7ff",)))
    assert [r.frame.arbitration_id for r in rows] == [0x7FF]


def test_csv_has_one_row_per_signal_with_units_and_jsonl_one_object_per_frame():
    rows, _ = _rows(FRAMES[:30])
    fmt = Formatter(CATALOG, None)
    out = io.StringIO()
    write_csv(rows, fmt, out)
    table = list(csv.DictReader(io.StringIO(out.getvalue())))
    assert len(table) == sum(max(1, len(r.spec.signals)) for r in rows)
    position = next(t for t in table if t["signal"] == "position_rad")
    assert position["unit"] == "rad" and position["message"].startswith("JOINT_STATUS") and position["status"] == "ok"
    out = io.StringIO()
    write_jsonl(rows, fmt, out, catalog=CATALOG)
    lines = [json.loads(line) for line in out.getvalue().splitlines()]
    assert lines[0]["schema"] == "aider-exo trace decode 1"
    assert lines[0]["units"]["JOINT_STATUS_LH"]["position_rad"] == "rad"
    assert len(lines) == 31 and lines[1]["message"] == "SYNC" and lines[1]["signals"] == {"tick": 0}
    labels = next(line for line in lines[1:] if line["message"] == "JOINT_STATUS_LH")["signals"]
    assert isinstance(labels["drive_state"], str)
    out = io.StringIO()
    write_jsonl(rows, Formatter(CATALOG, None, labels=False), out, catalog=CATALOG)
    numeric = [json.loads(line) for line in out.getvalue().splitlines()]
    assert isinstance(next(line for line in numeric[1:] if line["message"] == "JOINT_STATUS_LH")["signals"]["drive_state"], int)


def test_cli_decode_to_a_file_and_errors_only(tmp_path, capsys):
    log = _log(_bad_trace(), tmp_path / "bad.log")
    out = tmp_path / "out.csv"
    assert main(["trace", "decode", str(log), "--format", "csv", "-o", str(out)]) == 0
    assert out.read_text().startswith("time_s,timestamp,frame_id")
    assert list(tmp_path.glob(".*")) == []  # no temporary file left
    assert main(["trace", "decode", str(log), "--errors-only"]) == 0
    text = capsys.readouterr().out.splitlines()
    assert len(text) == 1 + 5  # header; bad CRC, repeated, lost-before, unknown ID, wrong DLC


def test_a_read_that_fails_half_way_leaves_no_output_file(tmp_path, capsys):
    good = _log(FRAMES, tmp_path / "good.log")
    broken = tmp_path / "broken.blf"
    broken.write_bytes(b"not a blf at all")
    out = tmp_path / "decoded.jsonl"
    assert main(["trace", "decode", str(good), str(broken), "--json", "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "broken.blf: not a valid .blf file" in err and "Traceback" not in err
    assert not out.exists() and list(tmp_path.glob(".*")) == []


def test_a_trace_of_another_bus_says_so(tmp_path, capsys):
    other = tmp_path / "other.log"
    other.write_text("".join(f"({i / 100:.6f}) can1 7E{i % 8}#0011223344\n" for i in range(50)))
    assert main(["trace", "decode", str(other)]) == 0
    captured = capsys.readouterr()
    assert "none of the 50 frames has an ID of" in captured.err and "another bus" in captured.err
    assert captured.out.count("  ?  ") == 50


def test_the_wrong_dbc_says_so(tmp_path, capsys):
    log = _log(FRAMES, tmp_path / "run.log")
    # The same layout with other Data IDs (another protocol version): every CRC fails.
    text = DBC_PATH.read_text()
    shifted = "\n".join(
        line.replace(f' {line.split()[-1]}', f" {int(line.split()[-1].rstrip(';')) + 7};")
        if line.startswith('BA_ "AiderDataId" BO_') else line for line in text.splitlines())
    other_version = tmp_path / "v2.dbc"
    other_version.write_text(shifted)
    assert main(["trace", "stats", str(log), "--dbc", str(other_version)]) == 0
    assert "fail their CRC: the wrong DBC, or another protocol version?" in capsys.readouterr().err
    # A DBC of another bus, without the protocol's end-to-end signals: one line, no traceback.
    foreign = tmp_path / "foreign.dbc"
    foreign.write_text('VERSION ""\n\nBU_: A\n\nBO_ 100 M: 8 A\n SG_ s : 0|8@1+ (1,0) [0|255] "" A\n')
    assert main(["trace", "decode", str(log), "--dbc", str(foreign)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("aider-exo: error: ") and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_a_recording_made_with_another_dbc_says_so(tmp_path, capsys):
    log = _log(FRAMES, tmp_path / "old.log")
    meta = {"schema": "aider-exo trace metadata 1", "dbc": {"sha256": "0" * 64, "protocol_version": 0}}
    (tmp_path / "old.log.meta.json").write_text(json.dumps(meta))
    assert main(["trace", "stats", str(log)]) == 0
    assert "recorded with another DBC (protocol version 0" in capsys.readouterr().err
    (tmp_path / "old.log.meta.json").write_text("{not json")
    assert main(["trace", "decode", str(log)]) == 1
    assert "unreadable metadata sidecar" in capsys.readouterr().err


def test_stdin_is_decoded_as_it_streams(monkeypatch, capsys):
    lines = "".join(f"({f.timestamp:.6f}) vcan0 {f.arbitration_id:03X}#{f.data.hex()}\n" for f in FRAMES[:5])
    monkeypatch.setattr("sys.stdin", io.StringIO(lines))
    assert main(["trace", "decode", "-", "--message", "SYNC"]) == 0
    assert "SYNC" in capsys.readouterr().out


def test_our_decode_agrees_with_cantools_on_every_signal():
    import cantools

    db = cantools.database.load_file(str(DBC_PATH))
    rows, _ = _rows(FRAMES)
    for row in rows:
        theirs = db.decode_message(row.frame.arbitration_id, row.frame.data, decode_choices=False)
        for sig, value in zip(row.spec.signals, row.values):
            assert theirs[sig.name] == pytest.approx(value, abs=1e-9)
        assert theirs["e2e_counter"] == row.counter


def test_python_can_message_and_frame_agree():
    msg = can.Message(timestamp=1.0, arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False)
    frame = Frame.from_message(msg)
    assert frame.to_message().equals(msg, timestamp_delta=None) and frame.data == b"\x01\x02"


@pytest.mark.parametrize("labels", [True, False])
def test_the_compiled_lines_say_what_the_general_path_says_for_every_message(labels):
    """Each format's per-message template (the fast path) against the values of Formatter.signals."""
    import numpy as np

    from protocol.e2e import Transmitter
    from protocol.synthetic import random_record

    rng = np.random.default_rng(7)
    tx = Transmitter(CODEC)
    frames = [Frame(0.5 + i * 0.001, m.frame_id, tx.payload(m, random_record(m, rng)), "vcan0")
              for i, m in enumerate(CATALOG.messages * 3)]
    rows, _ = _rows(frames)
    for selection in (None, Selection(signals=("*_rad", "tick", "mode")).compile(CATALOG)):
        fmt = Formatter(CATALOG, selection, labels=labels)
        for row in rows:
            assert row.status == "ok"
            expected = fmt.signals(row)
            obj = json.loads(fmt.line("jsonl", row))
            assert obj["message"] == row.spec.name and obj["counter"] == row.counter and obj["t"] == round(row.time_s, 6)
            assert list(obj["signals"].items()) == [(sig.name, value) for sig, value in expected]
            cells = list(csv.reader(io.StringIO(fmt.line("csv", row))))
            assert [(c[8], c[9], c[10]) for c in cells if c[8]] == [(s.name, str(v) if isinstance(v, str) else c[9], s.unit)
                                                                     for (s, v), c in zip(expected, cells)]
            assert all(float(c[9]) == pytest.approx(v) for (s, v), c in zip(expected, cells) if not isinstance(v, str))
            text = fmt.line("table", row)
            for sig, value in expected:
                assert f"{sig.name}={value if isinstance(value, str) else ''}" in text
