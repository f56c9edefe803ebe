"""``trace record``: any writer by suffix, rotation by size and by trace time, partial files that
never look complete, the metadata sidecar, and recording a live (virtual) bus."""

from __future__ import annotations

import threading

import can
import pytest

from protocol.clock import MonotonicClock
from protocol.codec import Codec
from tools.cli import main
from tools.trace import TraceError
from tools.trace.files import read_sidecar, sidecar_path
from tools.trace.reader import ReadReport, read_frames
from tools.trace.record import TraceWriter, check_writable, record_bus
from tools.trace.synthetic import lockstep_frames

FRAMES = lockstep_frames(Codec(), 50)  # 1 s of trace time


def _read(paths):
    report = ReadReport()
    frames = list(read_frames(paths, report))
    assert report.skipped == 0 and not report.problems
    return frames


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".trc", ".csv"])
def test_every_format_is_written_whole_and_renamed_when_complete(tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    writer = TraceWriter(path)
    for frame in FRAMES[:100]:
        writer.write(frame.to_message())
    assert (tmp_path / f"run.partial{suffix}").exists() and not path.exists()
    meta = writer.close({})
    assert path.exists() and not (tmp_path / f"run.partial{suffix}").exists()
    assert [f.data for f in _read([path])] == [f.data for f in FRAMES[:100]]
    assert meta["frames"] == 100 and meta["parts"] == [path.name]
    assert read_sidecar(path)["first_timestamp"] == FRAMES[0].timestamp


def test_rotation_by_trace_time_and_by_size(tmp_path):
    writer = TraceWriter(tmp_path / "t.log", rotate_s=0.25)
    for frame in FRAMES:
        writer.write(frame.to_message())
    meta = writer.close({})
    assert meta["parts"] == ["t_000.log", "t_001.log", "t_002.log", "t_003.log"]
    parts = [tmp_path / p for p in meta["parts"]]
    assert read_sidecar(parts[2])["parts"] == meta["parts"]  # a part finds the recording's sidecar
    assert [f.data for f in _read(parts)] == [f.data for f in FRAMES]
    assert all(f.timestamp - _read([p])[0].timestamp < 0.25 for p in parts for f in _read([p]))
    writer = TraceWriter(tmp_path / "s.asc", rotate_bytes=20_000)
    for frame in FRAMES:
        writer.write(frame.to_message())
    meta = writer.close({})
    assert len(meta["parts"]) > 2 and sum(len(_read([tmp_path / p])) for p in meta["parts"]) == len(FRAMES)
    assert all((tmp_path / p).stat().st_size < 25_000 for p in meta["parts"])


def test_an_aborted_recording_keeps_its_partial_name(tmp_path):
    writer = TraceWriter(tmp_path / "cut.blf")
    for frame in FRAMES[:10]:
        writer.write(frame.to_message())
    writer.abort()
    assert not (tmp_path / "cut.blf").exists() and (tmp_path / "cut.partial.blf").exists()
    assert not sidecar_path(tmp_path / "cut.blf").exists()


def test_outputs_that_cannot_be_written_are_refused_with_one_line(tmp_path):
    (tmp_path / "old.log").write_text("")
    with pytest.raises(TraceError, match="exists"):
        check_writable(tmp_path / "old.log", overwrite=False)
    with pytest.raises(TraceError, match="cannot record to '.pcap'"):
        check_writable(tmp_path / "x.pcap", overwrite=False)
    with pytest.raises(TraceError, match="no such folder"):
        check_writable(tmp_path / "none" / "x.log", overwrite=False)
    import importlib.util

    if importlib.util.find_spec("asammdf") is None:
        with pytest.raises(TraceError, match="recording .mf4 needs asammdf"):
            check_writable(tmp_path / "x.mf4", overwrite=False)


def test_recording_a_live_bus_until_a_count(tmp_path):
    channel = "trace-record-test"
    sent = FRAMES[:200]
    with can.Bus(interface="virtual", channel=channel, ignore_config=True) as listen, \
            can.Bus(interface="virtual", channel=channel, ignore_config=True) as talk:
        writer = TraceWriter(tmp_path / "live.log")
        sender = threading.Thread(target=lambda: [talk.send(f.to_message()) for f in sent])
        sender.start()
        ended = record_bus(listen, writer, MonotonicClock(), count=len(sent), idle_timeout_s=30)
        sender.join()
        writer.close({})
    assert ended == "count"
    assert [(f.arbitration_id, f.data) for f in _read([tmp_path / "live.log"])] == [(f.arbitration_id, f.data) for f in sent]


def test_recording_ends_on_idle_and_on_stop(tmp_path):
    with can.Bus(interface="virtual", channel="trace-idle", ignore_config=True) as bus:
        writer = TraceWriter(tmp_path / "idle.log")
        assert record_bus(bus, writer, MonotonicClock(), idle_timeout_s=0.05, poll_s=0.01) == "idle"
        assert record_bus(bus, writer, MonotonicClock(), stop=lambda: True) == "stopped"
        assert writer.close({})["parts"] == []  # nothing received: no file, no sidecar
    assert list(tmp_path.iterdir()) == []


def test_cli_refuses_a_virtual_bus_without_walk(tmp_path, capsys):
    assert main(["trace", "record", str(tmp_path / "x.log")]) == 1
    assert "virtual bus lives inside one process" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_sidecar_of_a_walk_recording(walk_log):
    meta = read_sidecar(walk_log)
    assert meta["seed"] == 3 and meta["bitrate_bit_s"] == 1_000_000 and len(meta["config_sha256"]) == 64
    assert meta["software_version"].startswith("0.") and meta["dbc"]["protocol_version"] == 3
    assert meta["source"]["kind"] == "walk" and meta["source"]["operator"] == {"request_walk_tick": 0}
    assert meta["frames"] == len(_read([walk_log]))


@pytest.fixture(scope="module")
def walk_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("walk") / "walk.log"
    assert main(["trace", "record", str(path), "--walk", "1", "--max-time", "1", "--seed", "3", "--json"]) == 0
    return path


def test_a_bus_that_fails_ends_the_recording_with_what_it_holds(tmp_path):
    class FailingBus:
        def __init__(self):
            self.left = list(FRAMES[:5])

        def recv(self, timeout):
            if not self.left:
                raise can.CanOperationError("Network is down")
            return self.left.pop(0).to_message()

    writer = TraceWriter(tmp_path / "down.log")
    ended = record_bus(FailingBus(), writer, MonotonicClock())
    assert ended == "bus error: Network is down"
    assert writer.close({})["frames"] == 5 and len(_read([tmp_path / "down.log"])) == 5
