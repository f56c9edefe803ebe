"""The node-board firmware state machine, tick by tick (no bus, no physics)."""

from __future__ import annotations

import pytest

from nodes.firmware import JointLimits, NodeFirmware
from protocol.commands import JointCommand
from protocol.enums import DriveState, EmcyCode, JointMode, NmtCommand, NmtState, NodeError

LIMITS = JointLimits(lower_rad=-0.5, upper_rad=2.0, velocity_rad_s=6.0, torque_nm=100.0)
TRACK = (int(JointMode.TRACK), 0.3, 0.0, 5.0, 100.0)


def firmware(timeout_ticks: int = 3, heartbeat_ms: int = 300) -> NodeFirmware:
    return NodeFirmware("LEFT_KNEE", LIMITS, command_timeout_ticks=timeout_ticks, heartbeat_timeout_ms=heartbeat_ms)


def tick(fw: NodeFirmware, k: int, *, command=None, heartbeat: bool = True) -> JointCommand:
    """One lock-step tick: frames of the previous tick arrive, then the SYNC of tick ``k``."""
    if command is not None:
        fw.on_command(*command)
    if heartbeat:
        fw.on_controller_heartbeat(k * 20.0)
    fw.on_tick(k * 20.0)
    return fw.on_sync()


def test_boots_pre_operational_holding_and_ignores_commands_until_started():
    fw = firmware()
    assert fw.state == NmtState.PRE_OPERATIONAL and fw.boot_up_pending
    assert tick(fw, 0, command=TRACK).mode == JointMode.HOLD
    assert fw.ignored == 1 and fw.drive_state == DriveState.HOLD
    fw.on_nmt(NmtCommand.START, 20.0)
    assert fw.state == NmtState.OPERATIONAL
    assert tick(fw, 1, command=TRACK) == JointCommand(JointMode.TRACK, 0.3, 0.0, 5.0, 100.0)
    assert fw.drive_state == DriveState.TRACK
    fw.on_nmt(NmtCommand.STOP, 40.0)
    assert fw.state == NmtState.STOPPED and tick(fw, 2, command=TRACK).mode == JointMode.HOLD


@pytest.mark.parametrize("timeout", [1, 3, 5])
def test_command_watchdog_quick_stops_after_the_configured_ticks_and_latches(timeout):
    fw = firmware(timeout_ticks=timeout)
    fw.on_nmt(NmtCommand.START, 0.0)
    for k in range(1, 6):
        tick(fw, k, command=TRACK)
    assert not fw.latched
    for k in range(6, 6 + timeout - 1):
        assert tick(fw, k).mode == JointMode.TRACK  # still the last command
    assert tick(fw, 6 + timeout - 1).mode == JointMode.QUICK_STOP
    assert fw.drive_state == DriveState.FAULT and fw.error == NodeError.COMMAND_TIMEOUT
    assert [e.code for e in fw.emcy] == [EmcyCode.COMMAND_TIMEOUT]
    # Latched: new commands do not bring the drive back.
    for k in range(20, 25):
        assert tick(fw, k, command=TRACK).mode == JointMode.QUICK_STOP
    assert len(fw.emcy) == 1


def test_lost_controller_heartbeat_is_a_fault_even_with_commands():
    fw = firmware(heartbeat_ms=300)
    fw.on_nmt(NmtCommand.START, 0.0)
    for k in range(1, 15):
        tick(fw, k, command=TRACK, heartbeat=(k == 1))
    assert not fw.latched  # 13 ticks = 260 ms since the heartbeat
    tick(fw, 15, command=TRACK, heartbeat=False)
    tick(fw, 16, command=TRACK, heartbeat=False)  # 300 ms: not yet beyond
    assert not fw.latched
    tick(fw, 17, command=TRACK, heartbeat=False)
    assert fw.latched and fw.error == NodeError.HEARTBEAT_LOST
    assert fw.emcy[-1].code == EmcyCode.HEARTBEAT_LOST


def test_fault_reset_clears_the_latch_and_the_drive_holds_until_the_next_command():
    fw = firmware()
    fw.on_nmt(NmtCommand.START, 0.0)
    fw.raise_fault(NodeError.OVER_CURRENT, EmcyCode.OVER_CURRENT, 0x03, 7)
    fw.raise_fault(NodeError.ENCODER_FAULT, EmcyCode.ENCODER, 0x01)  # not re-announced
    assert [e.code for e in fw.emcy] == [EmcyCode.OVER_CURRENT] and fw.error == NodeError.OVER_CURRENT
    fw.emcy.clear()
    fw.on_nmt(NmtCommand.FAULT_RESET, 100.0)
    assert not fw.latched and fw.error == NodeError.NONE
    assert [e.code for e in fw.emcy] == [EmcyCode.NO_ERROR]
    assert tick(fw, 6).mode == JointMode.HOLD
    assert tick(fw, 7, command=TRACK).mode == JointMode.TRACK


def test_a_fault_reset_without_a_fault_does_nothing():
    fw = firmware()
    fw.on_nmt(NmtCommand.FAULT_RESET, 0.0)
    assert fw.emcy == []


def test_commands_beyond_the_limits_are_clamped_and_reported_once_per_run():
    fw = firmware()
    fw.on_nmt(NmtCommand.START, 0.0)
    out = tick(fw, 1, command=(int(JointMode.TRACK), 2.5, 9.0, -300.0, 250.0))
    assert out == JointCommand(JointMode.TRACK, 2.0, 6.0, -100.0, 100.0)
    tick(fw, 2, command=(int(JointMode.TRACK), 2.4, 0.0, 0.0, 50.0))
    assert fw.clamped == 2 and [e.code for e in fw.emcy] == [EmcyCode.POSITION_LIMIT]
    assert fw.emcy[0].error_register == 0  # a warning, not a fault
    tick(fw, 3, command=TRACK)
    tick(fw, 4, command=(int(JointMode.TRACK), 0.3, 0.0, 0.0, 500.0))
    assert [e.code for e in fw.emcy] == [EmcyCode.POSITION_LIMIT, EmcyCode.INVALID_COMMAND]
    assert not fw.latched


def test_reset_node_reboots():
    fw = firmware()
    fw.on_nmt(NmtCommand.START, 0.0)
    fw.raise_fault(NodeError.OVER_CURRENT, EmcyCode.OVER_CURRENT, 0x03)
    fw.boot_up_pending = False
    fw.on_nmt(NmtCommand.RESET_NODE, 10.0)
    assert fw.state == NmtState.PRE_OPERATIONAL and fw.boot_up_pending and not fw.latched and fw.boots == 2
