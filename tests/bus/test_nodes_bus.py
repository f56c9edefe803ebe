"""The emulated nodes on the virtual bus, driven by scripted CAN frames written here (no controller).

Each test plays the controller by hand: it sends NMT, SYNC, joint commands and heartbeats through
our codec on a python-can virtual bus, lets the lock-step host handle them, and checks what comes
back on the bus, decoded by an independent receiver.
"""

from __future__ import annotations

import dataclasses

import can
import numpy as np
import pytest

from config import default_config_path, load_config, with_overrides
from nodes.host import NodesHost
from protocol.bus import virtual_bus
from protocol.codec import Codec, Decoded, RejectReason, Rejection
from protocol.e2e import Receiver, Transmitter
from protocol.enums import DriveState, EmcyCode, GaitState, JointMode, NmtCommand, NmtState, NodeError

BASE = load_config(default_config_path())
JOINTS = ("LH", "LK", "RH", "RK")
NODE_IDS = {"LEFT_HIP": 1, "LEFT_KNEE": 2, "RIGHT_HIP": 3, "RIGHT_KNEE": 4}


class ScriptedController:
    """The controller's side of the bus, by hand."""

    def __init__(self, channel: str, faults: dict | None = None, seed: int = 1) -> None:
        overrides = {"bus.channel": channel}
        if faults:
            overrides["nodes.faults"] = faults
        cfg = with_overrides(BASE, overrides)
        self.bus = virtual_bus(channel)
        self.node_bus = virtual_bus(channel)
        self.codec = Codec()
        self.tx = Transmitter(self.codec)
        self.rx = Receiver(self.codec, max_delta_counter=1)
        try:
            self.host = NodesHost(cfg, self.node_bus, lockstep=True, seed=seed)
        except Exception:
            self.node_bus.shutdown()
            self.bus.shutdown()
            raise
        self.tick = -1
        self.gait_state = GaitState.STAND  # what this controller's heartbeat says
        self.host.boot()
        self.boot_frames = self.frames()

    def close(self) -> None:
        self.host.close()
        self.node_bus.shutdown()
        self.bus.shutdown()

    def send(self, name: str, **values) -> None:
        self.bus.send(self.tx.message(name, values))
        self.host.poll(0.0)

    def send_raw(self, frame_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
        self.host.poll(0.0)

    def frames(self) -> list[tuple[can.Message, Decoded | Rejection]]:
        out = []
        while (msg := self.bus.recv(timeout=0)) is not None:
            out.append((msg, self.rx.receive(msg)))
        return out

    def nmt(self, command: NmtCommand, node_id: int = 0) -> list:
        self.send("NMT_COMMAND", command=int(command), node_id=node_id)
        return self.frames()

    def command(self, joint: str, mode: JointMode, position: float = 0.0, torque_limit: float = 100.0) -> None:
        self.send(f"JOINT_COMMAND_{joint}", mode=int(mode), position_setpoint_rad=round(position, 4),
                  velocity_ff_rad_s=0.0, torque_ff_Nm=0.0, torque_limit_Nm=torque_limit)

    def sync(self, *, commands: bool = True, heartbeat: bool = True, track: dict | None = None) -> dict:
        """SYNC of the next tick; returns what came back (name -> list of results). Then, as a
        controller does, its heartbeat (every 5th tick) and one command per joint (hold, or track
        the positions in ``track``)."""
        self.tick += 1
        self.send("SYNC", tick=self.tick)
        got: dict[str, list] = {}
        for msg, result in self.frames():  # by message name, accepted or not
            got.setdefault(self.codec.spec(msg.arbitration_id).name, []).append((msg, result))
        if heartbeat and self.tick % 5 == 0:
            self.send("CONTROLLER_HEARTBEAT", gait_state=int(self.gait_state))
        if commands:
            for j in JOINTS:
                if track and j in track:
                    self.command(j, JointMode.TRACK, track[j])
                else:
                    self.command(j, JointMode.HOLD, 0.0, 80.0)
        return got

    def start(self) -> None:
        self.nmt(NmtCommand.START)


@pytest.fixture
def ctl(request):
    c = ScriptedController(f"nodes-{request.node.name}")
    yield c
    c.close()


def values(got: dict, name: str):
    """The values of the frames of ``name`` that the controller's receiver accepted."""
    return [r.values for _, r in got.get(name, []) if isinstance(r, Decoded)]


def stateless(got: dict, name: str):
    """The values of every frame of ``name`` whose CRC and ranges are good, whatever its counter
    (as a receiver sees a node that has just rebooted)."""
    return [d.values for d in (Codec().decode(m.arbitration_id, m.data) for m, _ in got.get(name, [])) if isinstance(d, Decoded)]


def test_boot_up_then_pre_operational_heartbeats_then_operational(ctl):
    boot = [r.values.nmt_state for _, r in ctl.boot_frames]
    assert sorted(r.name for _, r in ctl.boot_frames) == ["HEARTBEAT_LH", "HEARTBEAT_LK", "HEARTBEAT_RH", "HEARTBEAT_RK"]
    assert boot == [NmtState.BOOT_UP] * 4
    beats: dict[str, list[int]] = {}
    for k in range(10):
        got = ctl.sync(commands=False)
        assert not any(n.startswith("JOINT_STATUS") for n in got), "no status before START"
        for name, results in got.items():
            if name.startswith("HEARTBEAT"):
                beats.setdefault(name, []).extend(k for _ in results)
                assert all(v.nmt_state == NmtState.PRE_OPERATIONAL for v in values(got, name))
    # Every 100 ms (5 ticks), each node in its own tick phase (1..4).
    assert beats == {"HEARTBEAT_LH": [1, 6], "HEARTBEAT_LK": [2, 7], "HEARTBEAT_RH": [3, 8], "HEARTBEAT_RK": [4, 9]}
    ctl.start()
    states = {}
    for _ in range(5):
        got = ctl.sync()
        for name in got:
            if name.startswith("HEARTBEAT"):
                states[name] = values(got, name)[-1].nmt_state
    assert set(states.values()) == {NmtState.OPERATIONAL} and len(states) == 4


def test_one_status_per_sync_with_consecutive_counters_and_good_crcs(ctl):
    ctl.start()
    per_tick = []
    for _ in range(40):
        got = ctl.sync()
        per_tick.append({n: len(r) for n, r in got.items() if not n.startswith("HEARTBEAT")})
    expected = {f"JOINT_STATUS_{j}": 1 for j in JOINTS} | {
        "STICK_LEFT": 1, "STICK_RIGHT": 1, "PLANTAR_LEFT": 1, "PLANTAR_RIGHT": 1,
        "TRUNK_IMU_ORIENTATION": 1, "TRUNK_IMU_RATE": 1, "TRUNK_IMU_ACCEL": 1,
    }
    assert all(t == expected for t in per_tick)
    # max_delta_counter=1: any lost, repeated or out-of-order counter, or bad CRC, would be rejected.
    assert ctl.rx.stats.rejected_total == 0 and ctl.rx.stats.lost == 0
    assert ctl.rx.stats.accepted == 40 * 11 + 4 * 8 + 4  # statuses, heartbeats, boot-ups


def test_standing_sensors_are_plausible(ctl):
    ctl.start()
    for _ in range(30):
        got = ctl.sync()
    sticks = sum(v.force_N for n in ("STICK_LEFT", "STICK_RIGHT") for v in values(got, n))
    plantar = sum(v.heel_force_N + v.toe_force_N for n in ("PLANTAR_LEFT", "PLANTAR_RIGHT") for v in values(got, n))
    weight = ctl.host.plant.world.total_mass * 9.81
    assert 0.9 * weight < sticks + plantar < 1.1 * weight
    accel = values(got, "TRUNK_IMU_ACCEL")[0]
    assert np.linalg.norm([accel.specific_force_x_m_s2, accel.specific_force_y_m_s2, accel.specific_force_z_m_s2]) == pytest.approx(9.81, abs=0.3)
    assert values(got, "JOINT_STATUS_LK")[0].drive_state == DriveState.HOLD


def test_a_sensor_beyond_its_full_scale_saturates_and_a_non_finite_one_is_not_sent(ctl):
    ctl.start()
    ctl.sync()
    physics = ctl.host.plant.patient.tick

    def overloaded(reading):  # the left stick pressed beyond the sensor's 2000 N, the right one's value lost
        return dataclasses.replace(physics(reading), stick_force_n=np.array([5000.0, np.nan]))

    ctl.host.plant.patient.tick = overloaded
    got = ctl.sync()
    assert [v.force_N for v in values(got, "STICK_LEFT")] == [2000.0]
    assert "STICK_RIGHT" not in got  # the controller sees it missing
    saturated = ctl.host.stats.saturated
    assert saturated["STICK_LEFT.force_N"] == 1
    assert saturated["STICK_RIGHT: STICK_RIGHT.force_N: nan is outside [-100, 2000] N"] == 1
    assert values(got, "PLANTAR_LEFT") and values(got, "JOINT_STATUS_LH")  # the other frames as ever


def test_a_commanded_joint_motion_shows_up_in_the_encoder(ctl):
    ctl.start()
    got = ctl.sync()
    q0 = values(got, "JOINT_STATUS_LK")[0].position_rad
    seen = []
    for k in range(40):
        target = q0 + 0.15 * min(k / 20, 1.0)
        got = ctl.sync(track={"LK": target})
        status = values(got, "JOINT_STATUS_LK")[0]
        seen.append(status.position_rad)
    assert status.drive_state == DriveState.TRACK
    assert seen[-1] == pytest.approx(q0 + 0.15, abs=0.01)
    assert seen[-1] == pytest.approx(ctl.host.plant.world.q[ctl.host.plant.world.joint_index["knee_l"]], abs=4e-4)  # encoder resolution
    # it moved the way it was told (then gives 1-3 mrad a tick, within the firmware's stiffness, while the
    # standing patient rebalances over the bent leg)
    assert all(b >= a - 3e-3 for a, b in zip(seen, seen[1:]))


def test_watchdog_quick_stops_within_4_ticks_of_the_last_command_sends_emcy_and_holds(ctl):
    ctl.start()
    for _ in range(10):
        ctl.sync()
    last_command_tick = ctl.tick  # the commands sent after this SYNC are the last
    q = ctl.host.plant.world.q[ctl.host.plant.world._exo_idx].copy()
    fault_tick, emcys = None, []
    for _ in range(30):
        got = ctl.sync(commands=False)
        emcys += [(ctl.tick, n, v.emcy_code) for n in got if n.startswith("EMCY") for v in values(got, n)]
        states = {j: values(got, f"JOINT_STATUS_{j}")[0].drive_state for j in JOINTS}
        if fault_tick is None and all(s == DriveState.FAULT for s in states.values()):
            fault_tick = ctl.tick
    assert fault_tick is not None and fault_tick - last_command_tick <= 4
    assert sorted(n for _, n, _ in emcys) == ["EMCY_LH", "EMCY_LK", "EMCY_RH", "EMCY_RK"]  # exactly one each
    assert all(code == EmcyCode.COMMAND_TIMEOUT and t == fault_tick for t, _, code in emcys)
    assert values(got, "JOINT_STATUS_RK")[0].error_code == NodeError.COMMAND_TIMEOUT
    # Quick stop and stay: the joints hold where they were, and the HHEA still stands.
    assert np.abs(ctl.host.plant.world.q[ctl.host.plant.world._exo_idx] - q).max() < 0.02
    assert ctl.host.plant.patient.fall is None


def test_lost_controller_heartbeat_faults_the_nodes(ctl):
    ctl.start()
    for _ in range(30):
        got = ctl.sync(heartbeat=False)
    assert values(got, "JOINT_STATUS_LH")[0].error_code == NodeError.HEARTBEAT_LOST


def test_fault_reset_brings_the_nodes_back_under_command(ctl):
    ctl.start()
    for _ in range(3):
        ctl.sync()
    for _ in range(6):
        ctl.sync(commands=False)
    assert values(ctl.sync(), "JOINT_STATUS_LH")[0].drive_state == DriveState.FAULT
    frames = ctl.nmt(NmtCommand.FAULT_RESET)
    assert sorted((r.name, r.values.emcy_code) for _, r in frames) == [
        (f"EMCY_{j}", EmcyCode.NO_ERROR) for j in JOINTS
    ]
    got = ctl.sync()
    assert values(got, "JOINT_STATUS_LH")[0].drive_state == DriveState.HOLD
    q0 = values(got, "JOINT_STATUS_LK")[0].position_rad
    for _ in range(20):
        got = ctl.sync(track={"LK": q0 + 0.05})
    status = values(got, "JOINT_STATUS_LK")[0]
    assert status.drive_state == DriveState.TRACK and status.error_code == NodeError.NONE
    assert status.position_rad == pytest.approx(q0 + 0.05, abs=0.01)


def test_reset_of_one_node_reboots_it_alone(ctl):
    ctl.start()
    ctl.sync()
    frames = ctl.nmt(NmtCommand.RESET_NODE, node_id=NODE_IDS["RIGHT_KNEE"])
    decoded = [ctl.codec.decode(m.arbitration_id, m.data) for m, _ in frames]
    assert [(d.name, d.values.nmt_state, d.counter) for d in decoded] == [("HEARTBEAT_RK", NmtState.BOOT_UP, 0)]
    got = ctl.sync()
    assert "JOINT_STATUS_RK" not in got and "JOINT_STATUS_LK" in got


def test_commands_beyond_the_joint_limits_are_clamped_and_reported(ctl):
    ctl.start()
    ctl.sync()
    ctl.command("LK", JointMode.TRACK, 2.5)  # knee limit 2.0 rad; the protocol allows up to pi
    got = ctl.sync(commands=False)
    assert [v.emcy_code for v in values(got, "EMCY_LK")] == [EmcyCode.POSITION_LIMIT]
    assert values(got, "EMCY_LK")[0].error_register == 0
    assert ctl.host.plant.world.exo.target[1] == pytest.approx(2.0)
    assert ctl.host.ports["LEFT_KNEE"].firmware.clamped == 1


def test_invalid_command_frames_are_counted_and_ignored(ctl):
    ctl.start()
    got = ctl.sync()
    q0 = values(got, "JOINT_STATUS_LH")[0].position_rad
    spec = ctl.codec.spec("JOINT_COMMAND_LH")
    good = ctl.tx.payload(spec, (int(JointMode.TRACK), round(q0 + 0.3, 4), 0.0, 0.0, 100.0))
    before = ctl.host.rx.stats.rejected_total
    ctl.send_raw(spec.frame_id, bytes([good[0] ^ 0xFF]) + good[1:])  # CRC
    ctl.send_raw(spec.frame_id, good[:5])  # DLC
    ctl.send_raw(spec.frame_id, good)  # fine, but then the same counter again:
    ctl.send_raw(spec.frame_id, good)
    reasons = ctl.host.rx.stats.rejected
    assert ctl.host.rx.stats.rejected_total - before == 3
    assert reasons[RejectReason.BAD_CRC] == 1 and reasons[RejectReason.WRONG_DLC] == 1 and reasons[RejectReason.REPEATED] == 1
    assert ctl.host.ports["LEFT_HIP"].firmware.pending.position_rad == pytest.approx(q0 + 0.3, abs=1e-4)


# -- injected faults, each visible on the bus ------------------------------------------------------

def run_with(request, faults: dict, ticks: int = 20, **sync) -> tuple[ScriptedController, list[dict]]:
    c = ScriptedController(f"nodes-{request.node.name}", faults=faults)
    request.addfinalizer(c.close)
    c.start()
    return c, [c.sync(**sync) for _ in range(ticks)]


def test_fault_drop(request):
    _, ticks = run_with(request, {"d": {"kind": "drop", "node": "LEFT_KNEE", "message": "JOINT_STATUS_LK", "start_tick": 5, "end_tick": 8}})
    present = [k for k, got in enumerate(ticks) if "JOINT_STATUS_LK" in got]
    assert present == [k for k in range(20) if not 5 <= k < 8]
    assert all("PLANTAR_LEFT" in got for got in ticks)


def test_fault_delay(request):
    c, ticks = run_with(request, {"d": {"kind": "delay", "node": "LEFT_HIP", "message": "STICK_LEFT", "start_tick": 5, "end_tick": 6, "delay_ticks": 2}})
    counts = [len(got.get("STICK_LEFT", [])) for got in ticks]
    assert counts[4:8] == [1, 0, 1, 2]  # tick 5's frame arrives with tick 7's, out of sequence
    assert c.rx.stats.rejected[RejectReason.WRONG_SEQUENCE] >= 1


def test_fault_duplicate(request):
    c, ticks = run_with(request, {"d": {"kind": "duplicate", "node": "RIGHT_HIP", "message": "JOINT_STATUS_RH", "start_tick": 5, "end_tick": 6}})
    (m1, r1), (m2, r2) = ticks[5]["JOINT_STATUS_RH"]
    assert m1.data == m2.data and isinstance(r1, Decoded) and r2.reason == RejectReason.REPEATED
    assert c.rx.stats.rejected[RejectReason.REPEATED] == 1


def test_fault_corrupt(request):
    c, _ = run_with(request, {"d": {"kind": "corrupt", "node": "RIGHT_KNEE", "message": "PLANTAR_RIGHT", "start_tick": 5, "end_tick": 7}})
    assert c.rx.stats.rejected[RejectReason.BAD_CRC] == 2


def test_fault_sensor_out_of_range(request):
    c, ticks = run_with(request, {"d": {"kind": "out_of_range", "node": "LEFT_HIP", "message": "JOINT_STATUS_LH", "signal": "position_rad", "value": 3.2, "start_tick": 5, "end_tick": 6}})
    assert values(ticks[5], "JOINT_STATUS_LH") == [] and len(values(ticks[6], "JOINT_STATUS_LH")) == 1
    assert c.rx.stats.rejected[RejectReason.OUT_OF_RANGE] == 1 and c.rx.stats.rejected[RejectReason.BAD_CRC] == 0


def test_fault_sensor_value_is_sent_under_a_good_crc(request):
    c, ticks = run_with(request, {"d": {"kind": "sensor_value", "node": "LEFT_HIP", "message": "STICK_LEFT", "signal": "force_N", "value": 0.0, "start_tick": 5, "end_tick": 8}})
    forces = [values(got, "STICK_LEFT")[0].force_N for got in ticks]
    assert forces[5:8] == [0.0, 0.0, 0.0] and forces[4] > 20.0 and forces[8] > 20.0  # the standing patient leans on it
    assert c.rx.stats.rejected_total == 0


def test_fault_sensor_value_beyond_the_range_names_the_key():
    from nodes.faults import FaultConfigError

    with pytest.raises(FaultConfigError, match=r"nodes.faults.x.value: 5000.0 must lie within STICK_LEFT.force_N's range"):
        ScriptedController("nodes-badvalue", faults={"x": {"kind": "sensor_value", "node": "LEFT_HIP", "message": "STICK_LEFT", "signal": "force_N", "value": 5000.0, "start_tick": 1}})


def test_fault_freeze_resends_stale_frames_and_stops_applying_commands(request):
    c, ticks = run_with(request, {"d": {"kind": "freeze", "node": "LEFT_KNEE", "start_tick": 5, "end_tick": 10}}, ticks=5)
    last = ticks[-1]["JOINT_STATUS_LK"][0][0].data
    heartbeat = ticks[2]["HEARTBEAT_LK"][0][0].data
    q_before = c.host.plant.world.exo.target[1]
    frozen = [c.sync(track={"LK": 0.6}) for _ in range(5)]
    for got in frozen:  # the tick-4 frame again, and again: same counter, same CRC
        (msg, result), = got["JOINT_STATUS_LK"]
        assert msg.data == last and isinstance(result, Rejection) and result.reason == RejectReason.REPEATED
        if c.tick % 5 == 2:  # its heartbeat is frozen too: tick 2's bytes again
            assert [m.data for m, _ in got["HEARTBEAT_LK"]] == [heartbeat]
    assert c.rx.stats.rejected[RejectReason.REPEATED] == 5 * 2 + 1  # status and plantar, ticks 5..9; a heartbeat
    assert c.host.plant.world.exo.target[1] == q_before  # the 0.6 rad commands were not applied
    after = c.sync(track={"LK": 0.6})
    assert len(values(after, "JOINT_STATUS_LK")) == 1  # counters resume where they stopped


def test_fault_stuck_encoder(request):
    c, ticks = run_with(request, {"d": {"kind": "stuck_encoder", "node": "RIGHT_KNEE", "start_tick": 5}}, ticks=5)
    q0 = values(ticks[-1], "JOINT_STATUS_RK")[0].position_rad
    for _ in range(25):
        got = c.sync(track={"RK": q0 + 0.1})
    assert values(got, "JOINT_STATUS_RK")[0].position_rad == pytest.approx(q0, abs=2e-3)  # the encoder says it did not move
    assert c.host.plant.world.q[c.host.plant.world.joint_index["knee_r"]] == pytest.approx(q0 + 0.1, abs=0.02)  # the joint did


def test_fault_reboot(request):
    c, ticks = run_with(request, {"d": {"kind": "reboot", "node": "LEFT_HIP", "start_tick": 5}}, ticks=10)
    assert [v.nmt_state for v in stateless(ticks[5], "HEARTBEAT_LH")] == [NmtState.BOOT_UP]
    assert all("JOINT_STATUS_LH" not in got for got in ticks[5:]) and all("JOINT_STATUS_LK" in got for got in ticks[5:])
    assert [v.nmt_state for v in stateless(ticks[6], "HEARTBEAT_LH")] == [NmtState.PRE_OPERATIONAL]


def test_fault_supply_ramp_lowers_the_heartbeats_voltage(request):
    c, ticks = run_with(request, {"d": {"kind": "supply_ramp", "node": "RIGHT_KNEE", "value": 5.0, "start_tick": 4, "end_tick": 40}}, ticks=45)
    volts = {k: values(got, "HEARTBEAT_RK")[0].supply_voltage_V for k, got in enumerate(ticks) if "HEARTBEAT_RK" in got}
    nominal = BASE.nodes.supply_voltage_v
    # 5 V a second is 0.1 V a tick, from tick 4; the nominal again from end_tick (another battery)
    assert volts[4] == pytest.approx(nominal, abs=0.02) and volts[9] == pytest.approx(nominal - 0.5, abs=0.02)
    assert volts[39] == pytest.approx(nominal - 3.5, abs=0.02) and volts[44] == pytest.approx(nominal, abs=0.02)
    assert all(v.supply_voltage_V == pytest.approx(nominal, abs=0.02) for got in ticks for v in values(got, "HEARTBEAT_LH"))


def test_fault_drive(request):
    c, ticks = run_with(request, {"d": {"kind": "drive_fault", "node": "RIGHT_HIP", "start_tick": 5}}, ticks=12)
    assert [v.emcy_code for v in values(ticks[5], "EMCY_RH")] == [EmcyCode.OVER_CURRENT]
    status = values(ticks[-1], "JOINT_STATUS_RH")[0]
    assert status.drive_state == DriveState.FAULT and status.error_code == NodeError.OVER_CURRENT
    assert values(ticks[-1], "JOINT_STATUS_LH")[0].drive_state == DriveState.HOLD


def test_fault_configuration_errors_name_the_key():
    from nodes.faults import FaultConfigError

    with pytest.raises(FaultConfigError, match=r"nodes.faults.x.message: STICK_LEFT is sent by LEFT_HIP, not LEFT_KNEE"):
        ScriptedController("nodes-badfault", faults={"x": {"kind": "drop", "node": "LEFT_KNEE", "message": "STICK_LEFT", "start_tick": 1}})


def test_the_nodes_benchmark_pipeline_exchanges_every_frame():
    """``aider-exo bench nodes`` measures a real exchange (figures are printed, never asserted)."""
    import argparse

    from tools.bench import nodes as bench

    result = bench.run(argparse.Namespace(config=None, ticks=10))
    for mode in result["modes"]:
        assert mode["rejected_by_nodes"] == 0 and not mode["fell"]
        # 4 boot-ups, 11 status and sensor frames per tick, the heartbeats of ticks 1..4 and 6..9
        assert mode["frames_from_nodes"] == 4 + 10 * 11 + 8
    assert set(bench.format_text(result).splitlines()[1].split()) >= {"ticks/s", "overhead"}


def test_real_time_mode_paces_physics_by_the_clock_and_samples_at_sync():
    from protocol.clock import ManualClock

    clock = ManualClock()
    cfg = with_overrides(BASE, {"bus.channel": "nodes-realtime"})
    with virtual_bus("nodes-realtime") as ctl_bus, \
            virtual_bus("nodes-realtime") as node_bus:
        host = NodesHost(cfg, node_bus, lockstep=False, seed=1, clock=clock)
        try:
            tx, rx = Transmitter(host.codec), Receiver(Codec())
            host.boot()
            host.poll(0.0)
            assert host.stats.physics_ticks == 1  # tick 0 is due at start
            clock.advance(10_000_000)  # half a tick: nothing due
            host.poll(0.0)
            assert host.stats.physics_ticks == 1
            clock.advance(10_000_000)
            host.poll(0.0)
            assert host.stats.physics_ticks == 2
            # A SYNC samples the newest state; it does not advance the physics.
            ctl_bus.send(tx.message("NMT_COMMAND", {"command": int(NmtCommand.START), "node_id": 0}))
            ctl_bus.send(tx.message("SYNC", {"tick": 7}))
            host.poll(0.0)
            assert host.stats.physics_ticks == 2 and host.stats.syncs == 1
            names = []
            while (m := ctl_bus.recv(timeout=0)) is not None:
                r = rx.receive(m)
                names.append(r.name)
            assert names.count("JOINT_STATUS_LK") == 1 and "TRUNK_IMU_RATE" in names
            # Five ticks late at once: one tick runs and the rest are skipped, counted as an overrun.
            clock.advance(5 * 20_000_000)
            host.poll(0.0)
            assert host.stats.physics_ticks == 3 and host.stats.overruns == 1
        finally:
            host.close()


def test_real_time_physics_locks_to_half_a_period_after_the_sync():
    """The boards' cycle follows the SYNC (CiA 402's cyclic synchronous modes): the first SYNC moves
    the physics tick to half a period after it, later ones pull by an eighth of their error (a
    SYNC read late moves the phase little), and without SYNCs the ticks keep their period."""
    from nodes.host import SYNC_PHASE_NS
    from protocol.clock import ManualClock

    ms = 1_000_000
    clock = ManualClock()
    cfg = with_overrides(BASE, {"bus.channel": "nodes-phase"})
    with virtual_bus("nodes-phase") as ctl_bus, virtual_bus("nodes-phase") as node_bus:
        host = NodesHost(cfg, node_bus, lockstep=False, seed=1, clock=clock)
        tx = Transmitter(host.codec)
        ticks: list[int] = []
        physics = host._physics_tick

        def timed() -> None:
            ticks.append(clock.now_ns() - host.start_ns)
            physics()

        host._physics_tick = timed

        def run_until(t_ns: int) -> None:  # the nodes' loop, polled every 0.1 ms up to t_ns
            while clock.now_ns() - host.start_ns < t_ns:
                clock.advance(100_000)
                host.poll(0.0)

        try:
            host.boot()
            host.poll(0.0)
            ctl_bus.send(tx.message("NMT_COMMAND", {"command": int(NmtCommand.START), "node_id": 0}))
            run_until(3 * ms)
            ctl_bus.send(tx.message("SYNC", {"tick": 0}))  # SYNCs at 3, 23, 43, ... ms
            host.poll(0.0)
            run_until(67 * ms)
            assert ticks == [0, 3 * ms + SYNC_PHASE_NS, 23 * ms + SYNC_PHASE_NS, 43 * ms + SYNC_PHASE_NS]
            ctl_bus.send(tx.message("SYNC", {"tick": 3}))  # the SYNC of 63 ms, read 4 ms late
            host.poll(0.0)
            run_until(120 * ms)
            assert ticks[4:] == [73 * ms + ms // 2, 93 * ms + ms // 2, 113 * ms + ms // 2]  # pulled by 0.5 ms, not 4
        finally:
            host.close()


def test_real_time_frames_are_read_between_ticks_that_all_overrun():
    """A board's CAN receive is interrupt-driven: physics slower than the 20 ms tick (as inside the
    vcan sandbox) must neither starve the commands, which would trip the command watchdog, nor keep
    ``poll`` from returning to the caller."""
    from protocol.clock import ManualClock

    clock = ManualClock()
    cfg = with_overrides(BASE, {"bus.channel": "nodes-overrun"})
    with virtual_bus("nodes-overrun") as ctl_bus, virtual_bus("nodes-overrun") as node_bus:
        host = NodesHost(cfg, node_bus, lockstep=False, seed=1, clock=clock)
        physics = host._physics_tick

        def overrunning() -> None:
            physics()
            clock.advance(45_000_000)  # more than two periods: every tick is an overrun

        host._physics_tick = overrunning
        try:
            tx, rx = Transmitter(host.codec), Receiver(Codec())
            host.boot()
            ctl_bus.send(tx.message("NMT_COMMAND", {"command": int(NmtCommand.START), "node_id": 0}))
            emcys = []
            for tick in range(20):
                # What the controller sent while the nodes were busy with the last physics tick.
                ctl_bus.send(tx.message("SYNC", {"tick": tick}))
                for j in JOINTS:
                    ctl_bus.send(tx.message(f"JOINT_COMMAND_{j}", {
                        "mode": int(JointMode.HOLD), "position_setpoint_rad": 0.0, "velocity_ff_rad_s": 0.0,
                        "torque_ff_Nm": 0.0, "torque_limit_Nm": 80.0}))
                ctl_bus.send(tx.message("CONTROLLER_HEARTBEAT", {"gait_state": int(GaitState.STAND)}))
                host.poll(0.0)
                while (m := ctl_bus.recv(timeout=0)) is not None:
                    r = rx.receive(m)
                    if isinstance(r, Decoded) and r.name.startswith("EMCY"):
                        emcys.append((tick, r.name, r.values.emcy_code))
            assert host.stats.overruns >= 15 and host.stats.syncs == 20
            assert emcys == []
            assert {p.firmware.drive_state for p in host.ports.values()} != {DriveState.FAULT}
        finally:
            host.close()


@pytest.mark.parametrize("signame", ["SIGINT", "SIGTERM"])
def test_the_nodes_process_reports_status_and_exits_cleanly_on_a_signal(signame):
    import json
    import signal
    import subprocess
    import sys

    from tests.conftest import ROOT

    proc = subprocess.Popen(
        [sys.executable, "-m", "nodes", "--json", "--channel", f"nodes-signal-{signame}"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        for line in proc.stderr:  # the first one-line status means it is up
            if line.startswith("nodes realtime"):
                break
        proc.send_signal(getattr(signal, signame))
        out, _ = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0
    final = json.loads(out)
    assert final["stopped_by"] == signame and final["mode"] == "realtime"
    assert {n["nmt"] for n in final["nodes"].values()} == {"PRE_OPERATIONAL"} and final["fall"] is None


def test_any_controller_frame_sequence_is_handled_without_an_exception():
    """Valid frames with random values (NMT commands to any node id, SYNC ticks jumping around,
    commands far outside the joints' limits, heartbeats with any gait state), mixed with random
    bytes under our IDs: the nodes never raise, and every joint command stays within its limits."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from tests.support.strategies import record

    codec = Codec()
    specs = [m for m in codec.catalog.messages if m.sender == "CONTROLLER"]
    frame = st.one_of(
        st.sampled_from(specs).flatmap(lambda s: st.tuples(st.just(s), record(s))),
        st.tuples(st.sampled_from(specs), st.binary(min_size=0, max_size=8)),
    )
    ctl = ScriptedController("nodes-fuzz")
    try:
        exo = ctl.host.plant.world.exo

        @given(st.lists(frame, min_size=1, max_size=30))
        @settings(max_examples=60, suppress_health_check=[HealthCheck.too_slow])
        def run(frames):
            for spec, payload in frames:
                if isinstance(payload, bytes):
                    ctl.send_raw(spec.frame_id, payload)
                else:
                    ctl.send(spec.name, **payload._asdict())
            ctl.frames()
            assert all(exo.lower <= exo.target) and all(exo.target <= exo.upper)

        run()
    finally:
        ctl.close()
    assert ctl.host.rx.stats.rejected_total > 0  # the random bytes were counted, not raised


def test_a_fault_naming_an_unknown_message_names_the_key():
    from nodes.faults import FaultConfigError

    with pytest.raises(FaultConfigError, match=r"nodes.faults.y.message: unknown message 'STICK_MIDDLE'"):
        ScriptedController("nodes-badfault2", faults={"y": {"kind": "drop", "node": "LEFT_HIP", "message": "STICK_MIDDLE", "start_tick": 1}})


def test_the_status_says_where_the_patient_is_in_its_gait(ctl):
    """Standing, the patient settles; once the controller's heartbeat says it walks, it shifts its
    CoM before the first stick lifts, and the status gives the margin that decides the lift (a walk
    that makes no progress then says whom it waits for)."""
    ctl.start()
    for _ in range(10):
        ctl.sync()
    standing = ctl.host.status()["patient"]
    assert standing["phase"] == "settle" and "lift_window_m" not in standing
    ctl.gait_state = GaitState.DOUBLE_SUPPORT
    walker, shifting = ctl.host.plant.patient, []
    for _ in range(60):
        ctl.sync()
        patient = walker.patient
        window = [round(v, 4) for v in patient.lift_window(patient._lifting())] if patient.phase.value == "shift" else None
        shifting.append((ctl.host.status()["patient"], window))
    shifting = [(p, window) for p, window in shifting if p["phase"] == "shift"]
    assert shifting, "the patient never began its weight shift"
    # the four-point gait: the front foot's stick (both for the two-stick patterns)
    assert len(shifting[0][0]["sticks_to_move"]) == (1 if walker.patient.p.stick_mode == "four_point" else 2)
    assert [p["phase_s"] for p, _ in shifting] == sorted(p["phase_s"] for p, _ in shifting)
    assert all(p["lift_window_m"] == window for p, window in shifting)


def test_a_fall_is_reported_with_the_sync_tick_and_time_it_happened(ctl):
    """Drives that let go (DISABLE) drop the HHEA; the status says when it first fell, and that
    stays as the run goes on."""
    ctl.start()
    for _ in range(5):
        ctl.sync()
    assert ctl.host.status()["fall_at"] is None
    fell_at = None
    for _ in range(150):
        ctl.sync(commands=False)
        for j in JOINTS:
            ctl.command(j, JointMode.DISABLE, 0.0, 0.0)
        if fell_at is None and ctl.host.plant.patient.fall:
            fell_at = (ctl.tick, round(ctl.host.plant.patient.t, 3))
    status = ctl.host.status()
    assert status["fall"] and fell_at is not None, status["fall"]
    assert status["fall_at"] == {"sync_tick": fell_at[0], "sim_time_s": fell_at[1]}
    assert status["fall_at"]["sync_tick"] < ctl.tick


def test_lockstep_boards_take_their_own_clock_when_the_controller_falls_silent():
    """``silence_s``: lock-step boards whose controller sends no SYNC for that long run on their own
    20 ms timer from the last SYNC's tick (a crashed controller: the command watchdog quick-stops
    them after ``command_timeout_ticks`` of their own ticks), and the next SYNC leads again. Without
    it they wait for the SYNC however long it takes."""
    from nodes.host import NodesError
    from protocol.clock import ManualClock

    ms = 1_000_000
    cfg = with_overrides(BASE, {"bus.channel": "nodes-silence"})
    with pytest.raises(NodesError, match="lock-step only"):
        NodesHost(cfg, None, lockstep=False, silence_s=1.0)
    for silence_s in (None, 1.0):
        clock = ManualClock()
        with virtual_bus("nodes-silence") as ctl_bus, virtual_bus("nodes-silence") as node_bus:
            host = NodesHost(cfg, node_bus, lockstep=True, seed=1, clock=clock, silence_s=silence_s)
            tx, rx = Transmitter(host.codec), Receiver(Codec())

            def heard() -> list[tuple[int, str, int]]:  # (ms since the last SYNC, message, EMCY code or -1)
                out = []
                while (m := ctl_bus.recv(timeout=0)) is not None:
                    r = rx.receive(m)
                    if isinstance(r, Decoded):
                        out.append((round((clock.now_ns() - sync_ns) / ms), r.name, r.values.emcy_code if r.name.startswith("EMCY") else -1))
                return out

            try:
                host.boot()
                ctl_bus.send(tx.message("NMT_COMMAND", {"command": int(NmtCommand.START), "node_id": 0}))
                for tick in range(5):
                    clock.advance(20 * ms)
                    for j in JOINTS:
                        ctl_bus.send(tx.message(f"JOINT_COMMAND_{j}", {
                            "mode": int(JointMode.HOLD), "position_setpoint_rad": 0.0, "velocity_ff_rad_s": 0.0,
                            "torque_ff_Nm": 0.0, "torque_limit_Nm": 80.0}))
                    ctl_bus.send(tx.message("CONTROLLER_HEARTBEAT", {"gait_state": int(GaitState.STAND)}))
                    ctl_bus.send(tx.message("SYNC", {"tick": tick}))
                    host.poll(0.0)
                sync_ns = clock.now_ns()
                heard()
                assert host.stats.physics_ticks == 5
                frames = []
                for _ in range(3000):  # 3 s of silence, polled every millisecond
                    clock.advance(ms)
                    host.poll(0.0)
                    frames += heard()
                if silence_s is None:
                    assert frames == [] and host.stats.physics_ticks == 5 and not host.own_clock
                    continue
                # Own ticks 5, 6, 7, ... from 1 s on, one each 20 ms; the watchdog's third tick without a command.
                assert host.own_clock and host.stats.silences == 1
                assert host.stats.physics_ticks == 5 + 101  # own ticks 5..105, at 1000..3000 ms
                emcys = [(t, name) for t, name, code in frames if code == EmcyCode.COMMAND_TIMEOUT]
                assert sorted(name for _, name in emcys) == sorted(f"EMCY_{j}" for j in JOINTS)
                assert {t for t, _ in emcys} == {1040}, emcys  # tick 7: the third without a command
                heartbeats = [t for t, name, _ in frames if name.startswith("HEARTBEAT")]
                assert heartbeats[0] == 1020 and len(heartbeats) == 80  # one node per tick, none in ticks 0 mod 5
                # A SYNC again: it leads (one physics tick), the drives report the quick stop, and no
                # tick of the boards' own comes without a SYNC.
                ctl_bus.send(tx.message("SYNC", {"tick": 0}))
                host.poll(0.0)
                assert not host.own_clock and host.stats.physics_ticks == 107
                statuses = [r for r in (rx.receive(m) for m in _drain(ctl_bus)) if isinstance(r, Decoded) and r.name.startswith("JOINT_STATUS")]
                assert len(statuses) == 4 and {DriveState(r.values.drive_state) for r in statuses} == {DriveState.FAULT}
                for _ in range(500):
                    clock.advance(ms)
                    host.poll(0.0)
                assert host.stats.physics_ticks == 107 and host.status()["silences"] == 1
            finally:
                host.close()


def _drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(timeout=0)) is not None:
        out.append(m)
    return out
