"""The bus check on the in-process virtual bus: clean runs pass, damaged frames are caught."""

from __future__ import annotations

import pytest

from config import default_config_path, load_config, with_overrides
from protocol.busload import busiest_tick
from protocol.catalog import default_catalog
from tools.buscheck import NodesSide, ThreadPeer, run_controller
from tools.cli import main


def _cfg(name: str):
    return with_overrides(load_config(default_config_path()), {"bus.channel": name})


def _run(cfg, ticks=30, lockstep=True, timeout=0.5):
    return run_controller(
        cfg, ticks=ticks, lockstep=lockstep, tick_timeout_s=timeout, handshake_timeout_s=5,
        peer=ThreadPeer(cfg, idle_timeout_s=5), candump_path=None,
    )


def test_lockstep_check_is_clean_and_counts_every_frame():
    ticks = 30
    result = _run(_cfg("bc-clean"), ticks=ticks)
    assert result["ok"]
    catalog = default_catalog()
    node_frames = sum(1 for t in range(ticks) for m in catalog.cyclic_in_tick(t) if m.sender != "CONTROLLER")
    ctrl_frames = sum(1 for t in range(ticks) for m in catalog.cyclic_in_tick(t) if m.sender == "CONTROLLER")
    c, n = result["controller"], result["nodes"]
    assert n["frames_sent"] == node_frames + 4  # + the four boot-up heartbeats
    assert c["frames_received"] == node_frames + 4
    assert c["frames_sent"] == ctrl_frames + 2  # + NMT start and stop
    assert c["round_trip_us"]["samples"] == ticks
    assert len(busiest_tick(catalog).frames) == 18  # a heartbeat or a telemetry frame of the controller in every tick


def test_real_time_check_is_clean():
    assert _run(_cfg("bc-rt"), ticks=10, lockstep=False)["ok"]


def test_a_corrupted_frame_is_rejected_and_reported(monkeypatch):
    original = NodesSide._send

    def corrupting_send(self, spec, values):
        if spec.name == "JOINT_STATUS_LK" and self.report.ticks == 7:
            msg = self.tx.message(spec, values)
            msg.data[3] ^= 0x04
            self.bus.send(msg)
            self.report.sent += 1
            return
        original(self, spec, values)

    monkeypatch.setattr(NodesSide, "_send", corrupting_send)
    result = _run(_cfg("bc-bad"), ticks=12, timeout=0.2)
    assert not result["ok"]
    rx = result["controller"]["receiver"]
    assert rx["rejected_by_reason"] == {"bad_crc": 1}
    assert rx["rejected_by_id"] == {"0x182": 1}
    assert result["controller"]["missing_frames"] == 1


def test_a_wrong_value_is_a_mismatch(monkeypatch):
    import tools.buscheck as bc

    real = bc.expected_record

    def off_by_one_lsb(spec, tick):
        rec = real(spec, tick)
        if spec.name == "TRUNK_IMU_RATE" and tick == 3 and bc.threading.current_thread().name == "buscheck-nodes":
            return rec._replace(rate_y_rad_s=rec.rate_y_rad_s + (0.001 if rec.rate_y_rad_s < 17 else -0.001))
        return rec

    monkeypatch.setattr(bc, "expected_record", off_by_one_lsb)
    result = _run(_cfg("bc-mismatch"), ticks=6, timeout=0.2)
    assert not result["ok"]
    assert result["controller"]["value_mismatches"] == 1
    assert "TRUNK_IMU_RATE in tick 3" in result["controller"]["first_mismatch"]


def test_no_peer_fails_with_one_line(capsys):
    assert main(["buscheck", "--channel", "bc-alone", "--peer", "none", "--handshake-timeout", "0.2"]) == 1
    err = capsys.readouterr().err
    assert "no boot-up from HEARTBEAT_LH, HEARTBEAT_LK, HEARTBEAT_RH, HEARTBEAT_RK" in err and err.count("\n") == 1


def test_cli_refuses_impossible_combinations(capsys):
    assert main(["buscheck", "--peer", "process"]) == 1
    assert "virtual bus lives inside one process" in capsys.readouterr().err
    assert main(["buscheck", "--candump", "x.log"]) == 1
    assert "--candump records a SocketCAN interface" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["buscheck", "--ticks", "0"])


def test_a_bad_config_fails_before_the_bus_opens_naming_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("schema_version: 1\nbus:\n  interface: virtual\n  channel: x\n  bitrate_bit_s: 2000000\n"
                   "protocol:\n  max_delta_counter: 2\n")
    assert main(["buscheck", "--config", str(bad)]) == 1
    err = capsys.readouterr().err
    assert err == f"aider-exo: error: {bad}: bus.bitrate_bit_s: 2000000 is above the maximum 1000000\n"
