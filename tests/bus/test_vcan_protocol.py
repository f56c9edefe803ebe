"""Over a real SocketCAN vcan0: two processes exchange every frame of the protocol while can-utils'
candump records them; our decoder and cantools' command line agree on every value of that log.

Run through the vcan sandbox (``make test`` does: ``tools/vcan-run -- pytest -m vcan``).
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time

import can
import pytest

from protocol.catalog import DBC_PATH, default_catalog
from protocol.codec import Codec, Decoded
from protocol.e2e import Receiver
from tests.conftest import ROOT

pytestmark = pytest.mark.vcan

TICKS = 60


def _parse_cantools_line(line: str) -> tuple[int, str, dict[str, str]]:
    head, _, body = line.partition(" :: ")
    frame_id = int(head.split()[2].split("#")[0], 16)
    match = re.fullmatch(r"(\w+)\((.*)\)", body.strip())
    assert match, f"cantools could not decode: {line!r}"
    signals = {}
    for item in match.group(2).split(", "):
        name, _, value = item.partition(": ")
        signals[name] = value.split(" ")[0]  # drop the unit
    return frame_id, match.group(1), signals


def test_two_processes_exchange_a_full_protocol_over_vcan0_recorded_by_candump(vcan0, tmp_path):
    log = tmp_path / "candump.log"
    cmd = [
        sys.executable, "-m", "tools.cli", "buscheck", "--mode", "sweep", "--bus", "socketcan", "--channel", vcan0, "--ticks", str(TICKS), "--lockstep",
        "--candump", str(log), "--json",
    ]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    result = json.loads(proc.stdout)
    assert result["ok"], result

    # Two separate OS processes: this subprocess (controller side) and the nodes process it started.
    assert result["nodes"]["pid"] not in (os.getpid(), None)
    assert result["nodes"]["ticks"] == TICKS == result["controller"]["ticks"]

    catalog = default_catalog()
    expected = sum(len(catalog.cyclic_in_tick(t)) for t in range(TICKS)) + 4 + 2  # + boot-ups, NMT start/stop
    recorded = result["candump"]
    assert recorded["frames"] == expected
    assert recorded["receiver"]["rejected"] == 0 and recorded["receiver"]["lost"] == 0
    assert set(recorded["by_message"]) == {m.name for m in catalog.messages if m.is_cyclic} | {"NMT_COMMAND"}

    # Our decoder, reading candump's log again here, and `cantools decode` agree on every signal.
    codec = Codec(catalog)
    receiver = Receiver(codec)
    ours = []
    for msg in can.CanutilsLogReader(str(log)):
        decoded = receiver.receive(msg)
        assert isinstance(decoded, Decoded), decoded
        ours.append(decoded)
    assert receiver.stats.rejected_total == 0 and len(ours) == expected

    theirs = subprocess.run(
        [sys.executable, "-m", "cantools", "decode", "--single-line", str(DBC_PATH)],
        input=log.read_text(), capture_output=True, text=True, timeout=600, check=True,
    ).stdout.splitlines()
    assert len(theirs) == expected
    compared = 0
    for decoded, line in zip(ours, theirs):
        frame_id, name, signals = _parse_cantools_line(line)
        assert (frame_id, name) == (decoded.message.frame_id, decoded.name)
        assert int(signals.pop("e2e_counter")) == decoded.counter
        signals.pop("e2e_crc")
        values = codec.as_dict(decoded, choices=True)
        assert set(signals) == set(values)
        for key, text in signals.items():
            value = values[key]
            if isinstance(value, str):
                assert text == value, (name, key)
            else:
                assert math.isclose(float(text), value, rel_tol=0, abs_tol=1e-9), (name, key, text, value)
            compared += 1
    assert compared > 1000


def _aider(vcan0: str, *argv: str) -> list[str]:
    return [sys.executable, "-m", "tools.cli", argv[0], "--bus", "socketcan", "--channel", vcan0, *argv[1:]]


def test_listen_only_sends_nothing_beside_a_sweep_recorded_by_candump(vcan0, tmp_path):
    """buscheck --mode listen, its own process, hears a sweep between two other processes: it
    decodes every frame candump recorded, and candump recorded exactly what the sweep sent."""
    listener = subprocess.Popen(_aider(vcan0, "buscheck", "--mode", "listen", "--duration", "25", "--json"),
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(4)  # the listener's start-up (imports, socket) in the sandbox
        sweep = subprocess.run(_aider(vcan0, "buscheck", "--mode", "sweep", "--ticks", str(TICKS), "--lockstep",
                                      "--candump", str(tmp_path / "candump.log"), "--json"),
                               cwd=ROOT, capture_output=True, text=True, timeout=600)
        out, err = listener.communicate(timeout=120)
    finally:
        listener.kill()
    assert sweep.returncode == 0, sweep.stderr
    swept = json.loads(sweep.stdout)
    assert listener.returncode in (0, 1), err  # 1: the sweep's values include faults, as every value does
    heard = json.loads(out)
    sent = swept["controller"]["frames_sent"] + swept["nodes"]["frames_sent"]
    assert swept["candump"]["frames"] == sent  # nobody else sent: the listener sent nothing
    assert heard["frames_sent"] == 0
    assert heard["frames_received"] == sent
    assert heard["receiver"]["rejected"] == 0 and heard["receiver"]["lost"] == 0
    assert heard["messages"]["SYNC"]["frames"] == TICKS


def test_the_hold_check_holds_the_emulated_nodes_over_vcan0(vcan0):
    """buscheck --mode hold against `aider-exo nodes` (the node firmware and the simulated HHEA) as
    two processes: every node answers every SYNC, every drive holds, the joints stay put."""
    ticks = 100
    check = subprocess.Popen(_aider(vcan0, "buscheck", "--mode", "hold", "--lockstep", "--ticks", str(ticks), "--json"),
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    nodes = None
    try:
        time.sleep(4)  # the check listens first: the boards' boot-ups are what it waits for
        nodes = subprocess.Popen(_aider(vcan0, "nodes", "--lockstep", "--mode", "sagittal", "--quiet"),
                                 cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        out, err = check.communicate(timeout=300)
    finally:
        check.kill()
        if nodes is not None:
            nodes.send_signal(signal.SIGINT)
            nodes.communicate(timeout=60)
    result = json.loads(out)
    assert result["ok"], (result["problems"], err)
    assert result["missing_frames"] == {}
    for name, node in result["nodes"].items():
        assert set(node["drive_states"]) == {"HOLD"}, name
    for name, seen in result["messages"].items():
        if name.startswith("JOINT_STATUS_"):
            lo, hi = seen["signals"]["position_rad"]
            assert hi - lo < 0.05, (name, lo, hi)


def test_our_sockets_take_a_receive_buffer_of_about_1100_frames(vcan0):
    """A process not run for a moment during a flood must not lose frames to the kernel's default
    buffer (212992 bytes, about 230 frames): our sockets ask for RECEIVE_BUFFER_BYTES (the kernel
    reports twice what it grants)."""
    import socket

    from config import default_config_path, load_config, with_overrides
    from protocol.bus import RECEIVE_BUFFER_BYTES, open_bus

    cfg = with_overrides(load_config(default_config_path()), {"bus.interface": "socketcan", "bus.channel": vcan0})
    bus = open_bus(cfg.bus)
    try:
        granted = bus.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    finally:
        bus.shutdown()
    expected = RECEIVE_BUFFER_BYTES if os.geteuid() == 0 else min(RECEIVE_BUFFER_BYTES, int(open("/proc/sys/net/core/rmem_max").read()))
    assert granted >= 2 * expected, granted
