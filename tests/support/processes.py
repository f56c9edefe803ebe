"""The controller's and the nodes' processes as the tests run them, and what their summaries say."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import can

from controller.faults import FaultKind
from protocol.clock import TICK_MS, MonotonicClock
from tests.conftest import ROOT, udp_group
from tests.support.capture import PROBE_ID, candump, recorded
from tools.pipeline import default_max_time_s

#: the aider-exo command of this environment
AIDER = str(Path(sys.executable).with_name("aider-exo"))


def fsm_transitions(events: list[str]) -> list[tuple[int, str, str, str]]:
    """The FSM's transitions in a summary's events: (tick, source, target, cause)."""
    out = []
    for e in events:
        head, _, rest = e.partition(": ")
        if " -> " in rest:
            states, _, cause = rest.partition(": ")
            source, _, target = states.partition(" -> ")
            out.append((int(head.removeprefix("tick ")), source, target, cause))
    return out


def stall_can_explain(cause: str) -> bool:
    """Whether a printed cause is a fault of a kind that a stall of this machine can explain."""
    kind = FaultKind.of(cause)
    return kind is not None and kind.stall_can_explain


@contextmanager
def udp_record(channel: str, path: Path) -> Iterator[None]:
    """What candump does on vcan0, for a UDP multicast ``channel`` (group:port): every frame on it
    from the block's start until its end, in candump's ``-L`` format, by a listener thread of this
    process (joined to the group before the block starts; the file flushed per frame). At the end
    a probe frame from another socket must come through, so every frame sent before it is in."""
    from protocol.bus import UdpBus

    group, port = udp_group(channel)
    done = threading.Event()
    with UdpBus(group, port) as listener, UdpBus(group, port) as probe, path.open("w") as out:
        writer = can.CanutilsLogWriter(out, channel=channel)

        def run() -> None:
            while True:
                msg = listener.recv(timeout=0.1)
                if msg is None:
                    if done.is_set():
                        return
                    continue
                writer.on_message_received(msg)
                out.flush()
                if msg.arbitration_id == PROBE_ID:
                    done.set()

        thread = threading.Thread(target=run, name="udp-record", daemon=True)
        thread.start()
        try:
            yield
        finally:
            probe.send(can.Message(arbitration_id=PROBE_ID, data=b"\xff", is_extended_id=False))
            thread.join(timeout=30)
    assert not thread.is_alive() and done.is_set(), "the UDP recorder did not catch up"


def recording(interface: str, channel: str, log: Path):
    return candump(channel, log) if interface == "socketcan" else udp_record(channel, log)


def walk_two_processes(interface: str, channel: str, log: Path, cycles: int, *, lockstep: bool,
                        config: Path | None = None) -> tuple[dict, dict]:
    """``aider-exo nodes`` and ``aider-exo controller --cycles N`` on ``interface`` (socketcan or
    udp_multicast) and ``channel``, recorded (candump, or :func:`udp_record`); checks both exit
    cleanly and returns their JSON summaries."""
    mode = ["--lockstep"] if lockstep else []
    bus = ["--bus", interface, "--channel", channel] + (["--config", str(config)] if config else [])
    with recording(interface, channel, log):
        nodes = subprocess.Popen(
            [AIDER, "nodes", *bus, *mode, "--mode", "sagittal", "--json", "--quiet"],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        try:
            # The nodes first (their four boot-ups on the bus, seen by candump), then the controller.
            clock = MonotonicClock()
            deadline = clock.now_ns() + 120_000_000_000  # a hang guard only
            while (booted := recorded(log)) < 4 and nodes.poll() is None and clock.now_ns() < deadline:
                clock.sleep_until(clock.now_ns() + 100_000_000)
            assert booted >= 4, f"the nodes did not boot (exit status {nodes.poll()})"
            # Real time: a walk that stalls ends at the walk command's limit (lock-step: the hang guard).
            limit = [] if lockstep else ["--ticks", str(int(default_max_time_s(cycles) * 1000 / TICK_MS))]
            ctl = subprocess.run(
                [AIDER, "controller", *bus, *mode, "--cycles", str(cycles),
                 *limit, "--json", "--quiet"],
                check=False, cwd=ROOT, capture_output=True, text=True, timeout=900,  # a hang guard only (the walk took 166-299 s in the sandbox)
            )
        finally:
            nodes.send_signal(signal.SIGTERM)
            nodes_out, nodes_err = nodes.communicate(timeout=120)
    assert ctl.returncode == 0, ctl.stderr
    assert nodes.returncode == 0, nodes_err
    return json.loads(ctl.stdout), json.loads(nodes_out)
