"""``trace resim`` on recordings of real-time sessions: wall-clock timestamps with jitter, no
sidecar, split over the session recorder's rotated files (``.log.part`` too), starting in the
middle of a session, a controller restarted within the recording, the files given out of order;
and a real-time walk (the controller's real-time loop, the emulated nodes on their own 20 ms timer
in a thread, the virtual bus) recorded by the session recorder itself."""

from __future__ import annotations

import json
import random
import threading

import pytest

from protocol.clock import TICK_S
from protocol.codec import Codec
from tools.cli import main
from tools.trace.reader import ReadReport, read_frames

TICKS = 250
EPOCH = 1_796_600_000.0  # a wall clock in December 2026


@pytest.fixture(scope="module")
def lockstep(tmp_path_factory):
    path = tmp_path_factory.mktemp("rt") / "walk.log"
    assert main(["trace", "record", str(path), "--walk", "1", "--max-time", str(TICKS * TICK_S), "--seed", "2"]) == 0
    return path


def _lines(path) -> list[str]:
    return [line for line in path.read_text().splitlines() if line.strip()]


def _wall_clock(lines: list[str], seed: int = 1, start: float = EPOCH) -> list[str]:
    """The lines on a wall clock, as candump on can0 gives them: an epoch start, each gap stretched
    or shrunk by up to 30 % and a few hundred microseconds of jitter (order kept)."""
    rng = random.Random(seed)
    out, last_in, t = [], None, start
    for line in lines:
        stamp, rest = line.split(" ", 1)
        now = float(stamp[1:-1])
        if last_in is not None:
            t += max(1e-6, (now - last_in) * rng.uniform(0.7, 1.3) + rng.uniform(0, 4e-4))
        last_in = now
        out.append(f"({t:.6f}) can0 {rest.split(' ', 1)[1]}")
    return out


def _split(folder, lines: list[str], parts: int, first_seq: int = 1) -> list:
    """``lines`` as the session recorder's rotated files (can0_<UTC>_<NNNNNN>.log), cut mid-tick."""
    size = len(lines) // parts + 3  # not a multiple of the frames a tick has
    files = []
    for i in range(parts):
        chunk = lines[i * size:(i + 1) * size] if i < parts - 1 else lines[i * size:]
        path = folder / f"can0_20261207T0600{i:02d}Z_{first_seq + i:06d}.log"
        path.write_text("\n".join(chunk) + "\n")
        files.append(path)
    return files


def _resim(capsys, files, *extra, code=0):
    assert main(["trace", "resim", *map(str, files), "--json", *extra]) == code
    return json.loads(capsys.readouterr().out)


def test_a_wall_clock_recording_in_three_rotated_files_is_reproduced(lockstep, tmp_path, capsys):
    files = _split(tmp_path, _wall_clock(_lines(lockstep)), 3)
    files[-1] = files[-1].rename(files[-1].with_name(files[-1].name + ".part"))  # still being written
    r = _resim(capsys, files)
    assert r["reproduced"] and r["ticks"] == TICKS and r["runs"] == 1 and r["request_walk_tick"] == "start"
    assert r["skipped"] == {"first_sync_tick": 0, "frames_before_first_sync": 0, "ticks_before_controller_start": 0}
    assert r["overruns"] == {"count": 0, "ticks_skipped": 0} and r["node_frames_rejected"] == 0
    assert any("the start assumed at the controller's start" in w for w in r["warnings"])
    assert r["input"]["timestamps_backwards"] == 0 and r["input"]["frames"] == len(_lines(lockstep))


def test_a_recording_that_starts_mid_session_skips_to_the_next_controller_start(lockstep, tmp_path, capsys):
    """The recorder started while a controller ran (mid-tick), which then restarted: the ticks
    before the restart are skipped and counted, the restarted controller is reproduced."""
    lines = _lines(lockstep)
    first = _wall_clock(lines[len(lines) // 2 + 5:], seed=3)  # from the middle of a tick
    second = _wall_clock(lines, seed=4, start=float(first[-1].split(")")[0][1:]) + 2.0)  # the restart
    files = _split(tmp_path, first + second, 3, first_seq=41)
    r = _resim(capsys, files)
    assert r["reproduced"] and r["runs"] == 1 and r["ticks"] == TICKS
    sk = r["skipped"]
    assert sk["first_sync_tick"] > 0 and sk["frames_before_first_sync"] > 0
    assert sk["ticks_before_controller_start"] == TICKS - sk["first_sync_tick"]
    assert main(["trace", "resim", *map(str, files)]) == 0
    assert f"the recording starts at tick {sk['first_sync_tick']} of a running controller" in capsys.readouterr().out
    # only the mid-session part: nothing to compare, one line says why
    only = _split(tmp_path / ".." / tmp_path.name, first, 1, first_seq=90)
    assert main(["trace", "resim", *map(str, only)]) == 1
    assert "no controller start in the recording" in capsys.readouterr().out


def test_two_controller_runs_in_one_recording_are_each_reproduced(lockstep, tmp_path, capsys):
    lines = _wall_clock(_lines(lockstep))
    again = _wall_clock(_lines(lockstep), seed=5, start=float(lines[-1].split(")")[0][1:]) + 5.0)
    r = _resim(capsys, _split(tmp_path, lines + again, 4))
    assert r["reproduced"] and r["runs"] == 2 and r["ticks"] == 2 * TICKS


def test_skipped_ticks_are_the_loops_overruns_and_files_out_of_order_are_refused(lockstep, tmp_path, capsys):
    files = _split(tmp_path, _wall_clock(_lines(lockstep)), 3)
    assert main(["trace", "resim", str(files[1]), str(files[0]), str(files[2])]) == 1
    err = capsys.readouterr().err
    assert "comes before" in err and "recording order" in err and len(err.strip().splitlines()) == 1
    r = _resim(capsys, [files[0], files[2]], code=1)  # a file missing: said, and the tick jump is an overrun
    assert any("000002 not given" in w for w in r["warnings"]) and r["overruns"]["count"] == 1


def _real_time_session(folder, channel: str, ticks: int):
    """The controller's real-time loop walking and the nodes in a thread on their own timer, every
    frame recorded by the session recorder (rotating every 60 kB); returns (loop, files)."""
    from config import default_config_path, load_config, with_overrides
    from controller.core import ControllerCore
    from controller.hardware import CanHardware
    from controller.loop import RealtimeLoop
    from nodes.host import NodesHost, running_in_thread
    from protocol.bus import virtual_bus
    from protocol.enums import GaitState
    from tools.trace.session import SessionRecorder, record_session

    cfg = with_overrides(load_config(default_config_path()),
                         {"bus.interface": "virtual", "bus.channel": channel, "sim.mode": "sagittal"})
    buses = [virtual_bus(channel) for _ in range(3)]
    rec_bus, node_bus, ctl_bus = buses
    recorder = SessionRecorder(folder, "can0", max_bytes=60_000)
    stop = threading.Event()
    thread = threading.Thread(target=record_session, args=(rec_bus, recorder), kwargs={"stop": stop.is_set, "poll_s": 0.05})
    thread.start()
    host = NodesHost(cfg, node_bus, lockstep=False, seed=4)
    try:
        with running_in_thread(host):
            core = ControllerCore(cfg.controller)
            loop = RealtimeLoop(core, CanHardware(cfg.controller, ctl_bus, max_delta_counter=cfg.protocol.max_delta_counter))
            core.request_walk()  # the operator's start, kept until it stands (as controller --walk)
            for _ in range(ticks):
                if loop.step().state == GaitState.FAULT:
                    break
    finally:
        host.close()
        stop.set()
        thread.join(timeout=30)
        for bus in buses:
            bus.shutdown()
    return loop, recorder.files


@pytest.mark.realtime
def test_a_real_time_walk_recorded_by_the_session_recorder_is_reproduced(tmp_path, capsys):
    """Reproduced with zero divergence, as a lock-step recording is. A run the machine stalled
    (an overrun) is re-simulated all the same: the skipped ticks are told to the controller."""
    loop, files = _real_time_session(tmp_path, "resim-realtime", 300)
    assert len(files) >= 3 and all(f.name.startswith("can0_") for f in files)
    frames = list(read_frames(files, ReadReport()))
    stamps = [f.timestamp for f in frames]
    assert stamps[0] > 1e9 and stamps == sorted(stamps)  # wall clock, in order
    sync_id = Codec().spec("SYNC").frame_id
    syncs = [f for f in frames if f.arbitration_id == sync_id]
    assert len(syncs) == loop.report.ticks
    r = _resim(capsys, files)
    assert r["reproduced"], (r["first_divergence"], loop.report.stalls, loop.report.events[-3:])
    assert r["ticks"] == loop.report.ticks and r["runs"] == 1 and r["request_walk_tick"] == "start"
    assert r["overruns"]["ticks_skipped"] == loop.stats.summary()["skipped_ticks"]
    assert r["final_state"] == loop.core.fsm.state.name
