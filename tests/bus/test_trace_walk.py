"""On a lock-step walking run recorded here (the controller, the node boards and the simulation in
this process): re-simulation reproduces it with zero divergence and names the first divergence
when a controller parameter changes; cantools' decode agrees with ours on every signal; stats and
plot read it. The run is recorded by the test, never a committed golden trace (the gait changes)."""

from __future__ import annotations

import json

import pytest

from protocol.catalog import default_catalog
from protocol.clock import TICK_S
from protocol.codec import Codec
from tests.support.capture import assert_cantools_agrees
from tools.cli import main
from tools.trace.decode import TraceDecoder
from tools.trace.reader import ReadReport, read_frames

TICKS = 300  # 6 s: stand-up, weight shift and lean


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    path = tmp_path_factory.mktemp("walk") / "walk.log"
    assert main(["trace", "record", str(path), "--walk", "1", "--max-time", str(TICKS * TICK_S), "--seed", "1"]) == 0
    return path


def _json(capsys, argv, code=0):
    assert main(argv) == code
    return json.loads(capsys.readouterr().out)


def test_resim_reproduces_the_recorded_run_with_zero_divergence(walk, capsys):
    r = _json(capsys, ["trace", "resim", str(walk), "--json"])
    assert r["reproduced"] and r["divergent_ticks"] == 0 and r["first_divergence"] is None
    assert r["ticks"] == TICKS and r["request_walk_tick"] == 0 and r["warnings"] == []
    assert r["frames_compared"] >= 4 * TICKS and r["signals_compared"] > 5000 and r["node_frames_rejected"] == 0
    assert r["final_state"] in ("DOUBLE_SUPPORT", "SWING_LEFT", "SWING_RIGHT")  # it walks


def test_resim_reports_the_first_divergence_when_a_controller_parameter_changes(walk, capsys):
    r = _json(capsys, ["trace", "resim", str(walk), "--json", "--set", "controller.gait.lean_speed_m_s=0.08"], code=1)
    first = r["first_divergence"]
    assert not r["reproduced"] and r["divergent_ticks"] > 0
    assert first["tick"] > 0 and first["message"].startswith("JOINT_COMMAND_")
    spec = default_catalog().by_name(first["message"])
    assert first["signal"] in [s.name for s in spec.signals] and first["unit"] == spec.signal(first["signal"]).unit
    assert first["recorded"] != first["resim"]
    assert main(["trace", "resim", str(walk), "--set", "controller.gait.lean_speed_m_s=0.08"]) == 1
    text = capsys.readouterr().out
    assert f"first divergence at tick {first['tick']}: {first['message']}.{first['signal']}: recorded" in text


def test_resim_reads_a_node_frame_sent_after_the_controllers_frames_of_its_tick_as_late(walk):
    """The loop sends its frames once its read has ended: a node's answer to SYNC(k) that comes
    after them was not read in tick k, but before SYNC(k+1), as a late answer. Moving one such
    answer there in the recorded walk makes tick k diverge (the joint's status is a tick old, so
    the tick's data is not fresh), and the frame is still fed, once; left before the controller's
    frames, the walk is reproduced."""
    from config import default_config_path, load_config
    from tools.trace.resim import resimulate, ticks_of

    codec = Codec()
    cfg = load_config(default_config_path())
    frames = list(read_frames([walk], ReadReport()))
    ticks = list(ticks_of(frames, codec))
    assert all(t.late_frames == [] for t in ticks)  # lock-step: every answer before the controller's frames
    k = ticks[TICKS // 2].number
    status = codec.spec("JOINT_STATUS_LK").frame_id
    sync_at = next(i for i, f in enumerate(frames) if f.arbitration_id == codec.spec("SYNC").frame_id
                   and codec.decode(f.arbitration_id, f.data).values.tick == k)
    moved = next(i for i in range(sync_at, len(frames)) if frames[i].arbitration_id == status)
    first_command = next(i for i in range(sync_at, len(frames)) if codec.catalog.by_id(frames[i].arbitration_id).sender == "CONTROLLER"
                         and frames[i].arbitration_id != frames[sync_at].arbitration_id)
    late = frames[:moved] + frames[moved + 1:first_command] + [frames[first_command], frames[moved]] + frames[first_command + 1:]

    def resim(trace):
        return resimulate(trace, cfg.controller, codec=codec, max_delta_counter=cfg.protocol.max_delta_counter,
                          request_walk_tick=0)

    assert resim(frames).divergent_ticks == 0
    r = resim(late)
    assert r.first is not None and r.first.tick == k and r.node_frames_fed == resim(frames).node_frames_fed
    assert [len(t.late_frames) for t in ticks_of(late, codec) if t.number == k] == [1]


def test_resim_without_the_operators_start_diverges_when_the_recording_starts_walking(walk, capsys):
    r = _json(capsys, ["trace", "resim", str(walk), "--json", "--no-request-walk"], code=1)
    assert r["first_divergence"]["message"].startswith("JOINT_COMMAND_") and r["final_state"] == "STAND"


def test_resim_of_a_trace_without_sync_says_there_is_nothing_to_compare(tmp_path, capsys):
    log = tmp_path / "nosync.log"
    log.write_text("(0.0) vcan0 181#0011223344556677\n")
    assert main(["trace", "resim", str(log)]) == 1
    out = capsys.readouterr()
    assert "nothing to compare" in out.out and "Traceback" not in out.err


def test_cantools_decode_agrees_with_ours_on_every_signal_of_the_walk(walk):
    rows = list(TraceDecoder(Codec()).rows(read_frames([walk], ReadReport())))
    assert {r.status for r in rows} == {"ok"}
    assert assert_cantools_agrees(rows, walk.read_text()) > 20 * TICKS


def test_stats_of_the_walk_show_the_lockstep_tick(walk, capsys):
    r = _json(capsys, ["trace", "stats", str(walk), "--json"])
    assert r["crc_errors"] == 0 and r["counter_errors"] == 0 and r["lost_by_counter"] == 0 and r["unknown_id_frames"] == 0
    assert r["tick"]["syncs"] == TICKS and r["tick"]["ticks_missed"] == 0
    assert r["tick"]["period_ms"]["mean"] == pytest.approx(20.0, abs=1e-3)
    assert r["bus_load"]["bitrate_bit_s"] == 1_000_000 and 5 < r["bus_load"]["mean_percent_worst"] < 15


def test_plot_of_the_walk_is_a_png_and_a_plot_of_nothing_is_no_file(walk, tmp_path, capsys):
    png = tmp_path / "joints.png"
    r = _json(capsys, ["trace", "plot", str(walk), "--signal", "JOINT_STATUS_*.position_rad",
                       "--signal", "STICK_*.force_N", "-o", str(png), "--json"])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and r["panels"] == 2 and len(r["signals"]) == 6
    assert r["points"] >= 6 * (TICKS - 2) and r["bad_frames"] == 0
    empty = tmp_path / "none.png"
    assert main(["trace", "plot", str(walk), "--signal", "position_rad", "--start", "100", "-o", str(empty)]) == 1
    assert "no values of the chosen signals" in capsys.readouterr().err and not empty.exists()
    assert list(tmp_path.glob(".*")) == []
