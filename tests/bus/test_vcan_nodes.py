"""Over a real SocketCAN vcan0, in separate processes: ``aider-exo nodes`` (the console script) runs, can-utils'
``candump`` records boot-up, heartbeats and the per-SYNC status, and frames sent one by one with
``cansend`` (payloads made by our codec, CRCs and counters included) move a joint.

Run through the vcan sandbox (``make test`` does: ``tools/vcan-run -- pytest -m vcan``).
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from protocol.codec import Codec, Decoded
from protocol.e2e import Transmitter
from protocol.enums import DriveState, GaitState, JointMode, NmtCommand, NmtState
from tests.conftest import ROOT

pytestmark = pytest.mark.vcan

TICKS = 40


def _wait_for(predicate, timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_nodes_process_over_vcan0_seen_by_candump_and_driven_by_cansend(vcan0, tmp_path):
    for tool in ("candump", "cansend"):
        assert shutil.which(tool), f"{tool} (can-utils) is missing"
    log = tmp_path / "candump.log"
    dump = subprocess.Popen(["candump", "-L", vcan0], stdout=log.open("w"), stderr=subprocess.PIPE)
    nodes = subprocess.Popen(
        [str(Path(sys.executable).with_name("aider-exo")), "nodes", "--bus", "socketcan", "--channel", vcan0, "--lockstep", "--json", "--quiet", "--seed", "3"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    codec = Codec()
    tx = Transmitter(codec)

    def cansend(name: str, **values) -> None:
        spec = codec.spec(name)
        frame = f"{spec.frame_id:03X}#{tx.payload(spec, values).hex().upper()}"
        subprocess.run(["cansend", vcan0, frame], check=True, timeout=30)

    def recorded() -> list[can.Message]:
        return list(can.CanutilsLogReader(str(log)))

    try:
        _wait_for(lambda: len(recorded()) >= 4, 120, "the four boot-up messages")
        cansend("NMT_COMMAND", command=int(NmtCommand.START), node_id=0)
        knee_start = None
        for k in range(TICKS):
            cansend("SYNC", tick=k)
            if k % 5 == 0:
                cansend("CONTROLLER_HEARTBEAT", gait_state=int(GaitState.STAND))
            if k == 0:  # read where the knee is, then bend it 0.2 rad over 20 ticks
                _wait_for(lambda: any(m.arbitration_id == codec.spec("JOINT_STATUS_LK").frame_id for m in recorded()), 60, "the first status")
                first = next(m for m in recorded() if m.arbitration_id == codec.spec("JOINT_STATUS_LK").frame_id)
                knee_start = codec.decode(first.arbitration_id, first.data).values.position_rad
            target = knee_start + 0.2 * min(k / 20, 1.0)
            cansend("JOINT_COMMAND_LK", mode=int(JointMode.TRACK), position_setpoint_rad=round(target, 4),
                    velocity_ff_rad_s=0.0, torque_ff_Nm=0.0, torque_limit_Nm=100)
            for joint in ("LH", "RH", "RK"):
                cansend(f"JOINT_COMMAND_{joint}", mode=int(JointMode.HOLD), position_setpoint_rad=0.0,
                        velocity_ff_rad_s=0.0, torque_ff_Nm=0.0, torque_limit_Nm=80)
        status_id = codec.spec("JOINT_STATUS_LK").frame_id
        _wait_for(lambda: sum(m.arbitration_id == status_id for m in recorded()) >= TICKS, 60, "a status per SYNC")
    finally:
        nodes.send_signal(signal.SIGTERM)
        out, err = nodes.communicate(timeout=60)
        dump.send_signal(signal.SIGINT)
        dump.wait(timeout=30)
    assert nodes.returncode == 0, err
    final = json.loads(out)
    assert final["stopped_by"] == "SIGTERM" and final["syncs"] == TICKS and final["fall"] is None

    frames = [(m, codec.decode(m.arbitration_id, m.data)) for m in recorded()]
    ours = [(m, d) for m, d in frames if isinstance(d, Decoded) and d.message.sender != "CONTROLLER"]
    names = [d.name for _, d in ours]
    # Boot-up first, from every node.
    assert [(d.name, d.values.nmt_state) for _, d in ours[:4]] == [
        (f"HEARTBEAT_{j}", NmtState.BOOT_UP) for j in ("LH", "LK", "RH", "RK")
    ]
    # Heartbeats every 5 ticks in lock-step, operational after the start.
    beats = [d.values.nmt_state for _, d in ours[4:] if d.name == "HEARTBEAT_LK"]
    assert len(beats) == TICKS // 5 and set(beats) == {NmtState.OPERATIONAL}
    # One status and the sensors per SYNC.
    for name in ("JOINT_STATUS_LH", "JOINT_STATUS_LK", "JOINT_STATUS_RH", "JOINT_STATUS_RK", "STICK_LEFT", "PLANTAR_RIGHT", "TRUNK_IMU_ACCEL"):
        assert names.count(name) == TICKS, name
    # The knee followed the cansend commands.
    knee = [d.values for _, d in ours if d.name == "JOINT_STATUS_LK"]
    assert knee[-1].drive_state == DriveState.TRACK
    # (within 0.02 rad: the firmware's 3000 N.m/rad against the standing patient rebalancing over the bent leg)
    assert knee[-1].position_rad == pytest.approx(knee_start + 0.2, abs=0.02)
    assert final["nodes"]["LEFT_KNEE"]["error"] == "NONE" and final["receiver"]["rejected"] == 0
