"""The bus check on the in-process virtual bus: clean runs pass, damaged frames are caught; the
listen-only check sends nothing; the HOLD check holds the emulated nodes; the sweep is refused on a
real bus."""

from __future__ import annotations

import contextlib
import threading
import time

import can
import pytest

import tools.buscheck
import tools.busmonitor
from config import default_config_path, load_config, with_overrides
from nodes.host import NodesHost, running_in_thread
from protocol.bus import open_bus
from protocol.busload import busiest_tick
from protocol.catalog import default_catalog
from protocol.clock import MonotonicClock
from protocol.codec import Codec
from protocol.enums import DriveState, NmtState
from tools.buscheck import NodesSide, ThreadPeer, run_controller, sweep_refusal
from tools.busmonitor import HoldCheck, hold_check, listen
from tools.cli import main
from tools.cli.buscheck import format_safe


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
    assert main(["buscheck", "--mode", "sweep", "--channel", "bc-alone", "--peer", "none", "--handshake-timeout", "0.2"]) == 1
    err = capsys.readouterr().err
    assert "no boot-up from HEARTBEAT_LH, HEARTBEAT_LK, HEARTBEAT_RH, HEARTBEAT_RK" in err and err.count("\n") == 1
    assert main(["buscheck", "--channel", "bc-alone", "--handshake-timeout", "0.2"]) == 1  # hold, the default
    err = capsys.readouterr().err
    assert "no heartbeat from LEFT_HIP, LEFT_KNEE, RIGHT_HIP, RIGHT_KNEE within 0.2 s" in err and err.count("\n") == 1


def test_cli_refuses_impossible_combinations(capsys):
    assert main(["buscheck", "--mode", "sweep", "--peer", "process"]) == 1
    assert "virtual bus lives inside one process" in capsys.readouterr().err
    assert main(["buscheck", "--mode", "sweep", "--candump", "x.log"]) == 1
    assert "--candump records a SocketCAN interface" in capsys.readouterr().err
    for mode in ("listen", "hold"):
        assert main(["buscheck", "--mode", mode, "--peer", "thread"]) == 1
        assert f"--peer belongs to --mode sweep (--mode {mode} checks real nodes)" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["buscheck", "--ticks", "0"])


def _no_bus(*_args, **_kwargs):
    raise AssertionError("the bus was opened")


@pytest.mark.parametrize("channel", ["can0", "can1"])
def test_the_sweep_is_refused_on_a_real_bus_without_the_flag_before_the_bus_opens(channel, monkeypatch, capsys):
    monkeypatch.setattr(tools.buscheck, "open_bus", _no_bus)
    monkeypatch.setattr(tools.busmonitor, "open_bus", _no_bus)
    for argv in (["--mode", "sweep"], ["--mode", "sweep", "--peer", "none", "--ticks", "5"]):
        assert main(["buscheck", "--bus", "socketcan", "--channel", channel, *argv]) == 1
        err = capsys.readouterr().err
        assert err.startswith("aider-exo: error: refused: the sweep commands every joint in TRACK over its full range") \
            and f"on socketcan:{channel} that moves the motors" in err and "--i-understand-motors-will-move" in err
        assert err.count("\n") == 1
    # With the flag it goes as far as opening the bus (here refused by the test itself).
    with pytest.raises(AssertionError, match="the bus was opened"):
        main(["buscheck", "--bus", "socketcan", "--channel", channel, "--mode", "sweep", "--peer", "none",
              "--i-understand-motors-will-move"])


def test_where_the_sweep_runs_without_the_flag():
    assert sweep_refusal("virtual", "anything", False) is None
    assert sweep_refusal("socketcan", "vcan0", False) is None
    assert sweep_refusal("socketcan", "vcan12", False) is None
    for interface, channel in (("socketcan", "can0"), ("socketcan", "slcan0"), ("socketcan", "vcan0x"), ("pcan", "PCAN_USBBUS1")):
        assert sweep_refusal(interface, channel, False), (interface, channel)
        assert sweep_refusal(interface, channel, True) is None


def test_listen_only_sends_nothing_and_hears_every_frame():
    """Beside a sweep on the same bus, a third bus counts every frame: exactly what the sweep's two
    sides sent, and what the listener heard; the listener sent none."""
    cfg = _cfg("bc-listen")
    box: dict = {}
    with open_bus(cfg.bus) as observer, open_bus(cfg.bus) as listener_bus:
        heard = threading.Thread(target=lambda: box.update(listen=listen(
            listener_bus, Codec(), MonotonicClock(), duration_s=2.0, max_delta_counter=2)))
        heard.start()
        sweep = _run(cfg, ticks=40, lockstep=False)
        heard.join()
        frames = 0
        while observer.recv(timeout=0.2) is not None:
            frames += 1
    heard = box["listen"]
    sent = sweep["controller"]["frames_sent"] + sweep["nodes"]["frames_sent"]
    assert frames == sent
    assert heard["frames_sent"] == 0
    assert heard["frames_received"] == sent
    assert heard["receiver"]["rejected"] == 0 and heard["receiver"]["lost"] == 0
    assert heard["messages"]["SYNC"]["frames"] == 40
    assert all(node["heartbeats"] for node in heard["nodes"].values())


def test_the_listen_only_bus_refuses_to_send():
    with open_bus(_cfg("bc-refuse").bus) as bus:
        quiet = tools.busmonitor.ListenOnlyBus(bus)
        with pytest.raises(tools.buscheck.BusCheckError, match="listen-only"):
            quiet.send(can.Message(arbitration_id=0x80, data=b"\0" * 5, is_extended_id=False))
        assert quiet.sends_refused == 1


@contextlib.contextmanager
def _rig(name: str, faults: dict | None = None):
    """The emulated nodes (lock-step, in a thread) and a bus for the check, opened first: the nodes
    boot once it listens, as boards powered after the checker starts."""
    overrides: dict = {"bus.channel": name, "sim.mode": "sagittal"}
    if faults:
        overrides["nodes.faults"] = faults
    cfg = with_overrides(load_config(default_config_path()), overrides)
    with open_bus(cfg.bus) as check_bus, open_bus(cfg.bus) as node_bus:
        host = NodesHost(cfg, node_bus, lockstep=True, seed=0)
        try:
            with running_in_thread(host):
                yield cfg, check_bus, host
        finally:
            host.close()


@contextlib.contextmanager
def _held(name: str, faults: dict | None = None, ticks: int = 60):
    """The HOLD check against the emulated nodes: the result and the host."""
    with _rig(name, faults) as (cfg, check_bus, host):
        yield _hold(cfg, check_bus, ticks), host


def _hold(cfg, bus, ticks):
    return hold_check(bus, cfg, MonotonicClock(), ticks=ticks, lockstep=True, tick_timeout_s=2.0,
                      handshake_timeout_s=10.0, fault_reset=False)


def _nmt_states(host, want, timeout_s=5.0):
    """The nodes' NMT states once they are ``want`` (the nodes' thread handles the last command)."""
    deadline = time.monotonic() + timeout_s
    while {port.firmware.state for port in host.ports.values()} != want and time.monotonic() < deadline:
        time.sleep(0.01)
    return {port.firmware.state for port in host.ports.values()}


def test_the_hold_check_holds_the_emulated_nodes_and_leaves_them_pre_operational():
    ticks = 60
    with _held("bc-hold", ticks=ticks) as (result, host):
        states = _nmt_states(host, {NmtState.PRE_OPERATIONAL})
    assert result["ok"], result["problems"]
    catalog = default_catalog()
    own = sum(1 for t in range(ticks) for m in catalog.cyclic_in_tick(t, "CONTROLLER") if m.family in ("SYNC", "JOINT_COMMAND", "CONTROLLER_HEARTBEAT"))
    assert result["frames_sent"] == own + 2  # + NMT START and ENTER_PRE_OPERATIONAL
    assert result["missing_frames"] == {}
    for name, node in result["nodes"].items():
        assert set(node["drive_states"]) == {"HOLD"}, name
        assert node["last_nmt_state"] == "OPERATIONAL"
    for family in ("JOINT_STATUS_LH", "JOINT_STATUS_LK", "JOINT_STATUS_RH", "JOINT_STATUS_RK"):
        lo, hi = result["messages"][family]["signals"]["position_rad"]
        assert hi - lo < 0.05, (family, lo, hi)  # held where it stood (within 3 degrees: the hold is a stiff spring under the load)
    assert states == {NmtState.PRE_OPERATIONAL}
    text = format_safe(result)
    assert f"HOLD for {ticks} ticks (lockstep): sent {result['frames_sent']} frames" in text
    assert text.count(" rad, drive {'HOLD': 60}") == 4 and text.endswith("result: OK\n")


def test_the_hold_check_reports_a_drive_fault():
    with _held("bc-hold-fault", {"f": {"kind": "drive_fault", "node": "RIGHT_KNEE", "start_tick": 20}}, ticks=40) as (result, _):
        pass
    assert not result["ok"]
    knee = result["nodes"]["RIGHT_KNEE"]
    assert knee["drive_states"]["FAULT"] >= 15 and knee["error_codes"]["OVER_CURRENT"] >= 15
    assert knee["emcy_total"] == 1
    assert any(p.startswith("RIGHT_KNEE: ") and "FAULT" in p for p in result["problems"])
    assert any("drive not in HOLD" in p for p in result["problems"])
    assert set(result["nodes"]["LEFT_HIP"]["drive_states"]) == {"HOLD"}


def test_an_interrupted_hold_check_leaves_the_nodes_pre_operational_and_holding(monkeypatch):
    collected = []
    original = HoldCheck._collect

    def interrupted(self, expected, deadline_ns):
        collected.append(1)
        if len(collected) == 20:
            raise KeyboardInterrupt  # the operator's Ctrl-C in the middle of the check
        original(self, expected, deadline_ns)

    monkeypatch.setattr(HoldCheck, "_collect", interrupted)
    with _rig("bc-hold-interrupted") as (cfg, check_bus, host):
        with pytest.raises(KeyboardInterrupt):
            _hold(cfg, check_bus, 60)
        states = _nmt_states(host, {NmtState.PRE_OPERATIONAL})
        drives = {port.firmware.drive_state for port in host.ports.values()}
    assert states == {NmtState.PRE_OPERATIONAL}
    assert drives == {DriveState.HOLD}  # no watchdog fault: the nodes were told the check ended
