"""Bus check, the full-range sweep: the whole protocol of every tick between a controller and the four nodes.

A conformance tool for the protocol's implementations (``vcan0`` in the tests, the in-process
virtual bus, or a bench of bare motor boards with nothing attached: it moves the motors, so
:func:`sweep_refusal` refuses it on any other bus unless the operator confirms). The safe checks
of a real bus, listen-only and HOLD-only, are in :mod:`tools.busmonitor`. The *controller* side sends what the main controller
sends (SYNC, four joint commands, its heartbeat, NMT commands); the *nodes* side answers every
SYNC with every frame the four node boards send in that tick, after a CANopen-style boot-up
handshake. Every signal carries a value that both sides compute from the tick number
(:func:`protocol.synthetic.sweep_record`), which walks each signal over its whole range, so the
receiving side checks not only CRCs and counters but every decoded value.

Reported: frames sent and received, rejections by reason, lost frames, value mismatches, and
the round trip from SYNC to the last node frame of the tick (p50, p99, max). With ``candump``
(can-utils) as an independent recorder, the recorded log is decoded again afterwards.
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from config import Config
from config.errors import AiderError
from protocol.bus import RECEIVE_BUFFER_BYTES, open_bus
from protocol.catalog import MessageSpec
from protocol.clock import TICK_MS, TICK_NS, Clock, MonotonicClock, TickTimer
from protocol.codec import Codec, Decoded
from protocol.e2e import Receiver, Transmitter
from protocol.enums import GaitState, NmtCommand, NmtState
from protocol.synthetic import sweep_record

CONTROLLER = "CONTROLLER"
SWEEP_FLAG = "--i-understand-motors-will-move"


class BusCheckError(AiderError):
    """The check could not run (peer missing, handshake timeout, recorder failed, refused)."""


def is_vcan(interface: str, channel: str) -> bool:
    return interface == "socketcan" and re.fullmatch(r"vcan\d+", channel) is not None


def sweep_refusal(interface: str, channel: str, confirmed: bool) -> str | None:
    """Why the full-range sweep must not run on this bus, or None. It runs on the in-process
    virtual bus and on vcan* without more; on anything else (can0, a USB adapter) only when the
    operator has said that the motors may move."""
    if confirmed or interface == "virtual" or is_vcan(interface, channel):
        return None
    return (
        f"refused: the sweep commands every joint in TRACK over its full range (setpoints over +-pi, full torque); "
        f"on {interface}:{channel} that moves the motors. Check a real bus with --mode listen or --mode hold, or, "
        f"with no one in the exoskeleton and every joint free to turn, pass {SWEEP_FLAG}"
    )


def expected_record(spec: MessageSpec, tick: int) -> Any:
    """What ``spec`` carries in ``tick`` during a bus check (heartbeats report real states)."""
    if spec.family == "HEARTBEAT":  # its other signals (the supply voltage) swept like any sensor's
        return sweep_record(spec, tick)._replace(nmt_state=int(NmtState.OPERATIONAL))
    if spec.family == "CONTROLLER_HEARTBEAT":
        return spec.record(gait_state=int(GaitState.INIT))
    if spec.name == "SYNC":
        return spec.record(tick=tick)
    return sweep_record(spec, tick)


@dataclass
class SideReport:
    """What one side saw."""

    role: str
    ticks: int = 0
    sent: int = 0
    received: int = 0
    mismatches: int = 0
    late: int = 0
    missing: int = 0
    first_mismatch: str | None = None
    round_trip_us: list[float] = field(default_factory=list)

    def mismatch(self, text: str) -> None:
        self.mismatches += 1
        if self.first_mismatch is None:
            self.first_mismatch = text

    def as_dict(self, receiver: Receiver) -> dict[str, Any]:
        out: dict[str, Any] = {
            "role": self.role,
            "ticks": self.ticks,
            "frames_sent": self.sent,
            "frames_received": self.received,
            "value_mismatches": self.mismatches,
            "first_mismatch": self.first_mismatch,
            "late_frames": self.late,
            "missing_frames": self.missing,
            "receiver": receiver.stats.as_dict(),
        }
        if self.round_trip_us:
            rtt = np.asarray(self.round_trip_us)
            out["round_trip_us"] = {
                "p50": round(float(np.percentile(rtt, 50)), 1),
                "p99": round(float(np.percentile(rtt, 99)), 1),
                "max": round(float(rtt.max()), 1),
                "samples": int(rtt.size),
            }
        return out


def _matches(decoded: Decoded, tick: int) -> bool:
    return decoded.values == expected_record(decoded.message, tick)


class NodesSide:
    """The four node boards' traffic: boot-up, then per SYNC every node frame of that tick."""

    def __init__(self, bus: can.BusABC, codec: Codec, max_delta_counter: int, clock: Clock) -> None:
        self.bus, self.codec, self.clock = bus, codec, clock
        self.tx = Transmitter(codec)
        self.rx = Receiver(codec, max_delta_counter=max_delta_counter)
        self.report = SideReport("nodes")
        self.nodes = [n for n in codec.catalog.nodes if n != CONTROLLER]
        self.state = NmtState.PRE_OPERATIONAL

    def _send(self, spec: MessageSpec, values: Any) -> None:
        self.bus.send(self.tx.message(spec, values))
        self.report.sent += 1

    def boot(self) -> None:
        for node in self.nodes:
            spec = next(m for m in self.codec.catalog.sent_by(node) if m.family == "HEARTBEAT")
            self._send(spec, sweep_record(spec, 0)._replace(nmt_state=int(NmtState.BOOT_UP)))

    def run(self, idle_timeout_s: float) -> dict[str, Any]:
        self.boot()
        last_sync: int | None = None
        while True:
            msg = self.bus.recv(timeout=idle_timeout_s)
            if msg is None:
                raise BusCheckError(f"nodes side: no frame from the controller for {idle_timeout_s:g} s")
            result = self.rx.receive(msg)
            if not isinstance(result, Decoded):
                continue
            spec = result.message
            if spec.sender != CONTROLLER:
                continue
            self.report.received += 1
            if spec.name == "NMT_COMMAND":
                command = result.values.command
                if command == NmtCommand.START:
                    self.state = NmtState.OPERATIONAL
                elif command == NmtCommand.STOP:
                    return self.report.as_dict(self.rx)
                continue
            if spec.name == "SYNC":
                last_sync = tick = result.values.tick
                self.report.ticks += 1
                for out in self.codec.catalog.cyclic_in_tick(tick):
                    if out.sender != CONTROLLER:
                        self._send(out, expected_record(out, tick))
                continue
            if last_sync is None or not _matches(result, last_sync):
                self.report.mismatch(f"{spec.name} after SYNC {last_sync}: {result.values}")


class ControllerSide:
    """The main controller's traffic, paced in real time (``period_ns``) or in lock-step (None)."""

    def __init__(
        self, bus: can.BusABC, codec: Codec, max_delta_counter: int, clock: Clock, period_ns: int | None,
        tick_timeout_s: float,
    ) -> None:
        self.bus, self.codec, self.clock = bus, codec, clock
        self.period_ns = period_ns
        self.tick_timeout_ns = int(tick_timeout_s * 1e9)
        self.tx = Transmitter(codec)
        self.rx = Receiver(codec, max_delta_counter=max_delta_counter)
        self.report = SideReport("controller")
        self.catalog = codec.catalog

    def _send(self, spec: MessageSpec, values: Any) -> None:
        self.bus.send(self.tx.message(spec, values))
        self.report.sent += 1

    def handshake(self, timeout_s: float) -> None:
        """Wait for the boot-up heartbeat of every node, then start them all."""
        waiting = {m.frame_id for m in self.catalog.messages if m.family == "HEARTBEAT"}
        deadline = self.clock.now_ns() + int(timeout_s * 1e9)
        while waiting:
            remaining = (deadline - self.clock.now_ns()) / 1e9
            msg = self.bus.recv(timeout=max(remaining, 0)) if remaining > 0 else None
            if msg is None:
                names = sorted(self.codec.spec(i).name for i in waiting)
                raise BusCheckError(f"no boot-up from {', '.join(names)} within {timeout_s:g} s: is the nodes side running on this bus?")
            result = self.rx.receive(msg)
            if isinstance(result, Decoded) and result.message.family == "HEARTBEAT":
                if result.values.nmt_state == NmtState.BOOT_UP:
                    waiting.discard(result.message.frame_id)
                    self.report.received += 1
        nmt = self.catalog.by_name("NMT_COMMAND")
        self._send(nmt, nmt.record(command=int(NmtCommand.START), node_id=0))

    def run(self, ticks: int) -> dict[str, Any]:
        timer = TickTimer(self.clock, self.period_ns) if self.period_ns else None
        for n in range(ticks):
            tick = timer.wait() if timer else n
            self.report.ticks += 1
            sent_at = self.clock.now_ns()
            expected = {m.frame_id for m in self.catalog.cyclic_in_tick(tick) if m.sender != CONTROLLER}
            for spec in self.catalog.cyclic_in_tick(tick, CONTROLLER):
                self._send(spec, expected_record(spec, tick))
            deadline = sent_at + (self.tick_timeout_ns if timer is None else min(self.tick_timeout_ns, self.period_ns))
            while expected:
                remaining = (deadline - self.clock.now_ns()) / 1e9
                msg = self.bus.recv(timeout=remaining) if remaining > 0 else None
                if msg is None:
                    break
                result = self.rx.receive(msg)
                if not isinstance(result, Decoded) or result.message.sender == CONTROLLER:
                    continue
                self.report.received += 1
                fid = result.message.frame_id
                if fid in expected and _matches(result, tick):
                    expected.discard(fid)
                    if not expected:
                        self.report.round_trip_us.append((self.clock.now_ns() - sent_at) / 1000)
                elif _matches(result, tick - 1):
                    self.report.late += 1
                else:
                    self.report.mismatch(f"{result.message.name} in tick {tick}: {result.values}")
            self.report.missing += len(expected)
        nmt = self.catalog.by_name("NMT_COMMAND")
        self._send(nmt, nmt.record(command=int(NmtCommand.STOP), node_id=0))
        return self.report.as_dict(self.rx)


# -- the independent recorder -------------------------------------------------------------------


class Candump:
    """``candump -L CHANNEL > FILE`` (can-utils) running beside the check."""

    def __init__(self, channel: str, path: Path) -> None:
        exe = shutil.which("candump")
        if exe is None:
            raise BusCheckError("candump not found: install can-utils (apt-get install can-utils)")
        self.path = path
        self._file = path.open("wb")
        # With our sockets' receive buffer: the kernel's default let candump drop frames of a flood.
        self._proc = subprocess.Popen([exe, "-L", "-r", str(RECEIVE_BUFFER_BYTES), channel], stdout=self._file,
                                      stderr=subprocess.PIPE)

    def stop(self, clock: Clock, settle_s: float = 0.3) -> None:
        clock.sleep_until(clock.now_ns() + int(settle_s * 1e9))  # let the last frames reach the recorder
        self._proc.send_signal(signal.SIGINT)
        try:
            _, err = self._proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            _, err = self._proc.communicate()
        self._file.close()
        if self._proc.returncode not in (0, -signal.SIGINT, 130):
            raise BusCheckError(f"candump failed ({self._proc.returncode}): {err.decode(errors='replace').strip()}")


def decode_candump_log(path: Path, codec: Codec, max_delta_counter: int) -> dict[str, Any]:
    """Decode a ``candump -L`` log with our receiver (counter checks per message)."""
    receiver = Receiver(codec, max_delta_counter=max_delta_counter)
    frames = 0
    by_message: dict[str, int] = {}
    for msg in can.CanutilsLogReader(str(path)):
        frames += 1
        result = receiver.receive(msg)
        if isinstance(result, Decoded):
            by_message[result.name] = by_message.get(result.name, 0) + 1
    return {"file": str(path), "frames": frames, "receiver": receiver.stats.as_dict(), "by_message": by_message}


# -- composition ---------------------------------------------------------------------------------


def run_nodes(cfg: Config, idle_timeout_s: float) -> dict[str, Any]:
    codec = Codec()
    with open_bus(cfg.bus) as bus:
        return NodesSide(bus, codec, cfg.protocol.max_delta_counter, MonotonicClock()).run(idle_timeout_s)


def is_clean(result: dict[str, Any]) -> bool:
    """No rejection, loss, mismatch or missing frame anywhere in a bus-check result."""
    sides = [result["controller"]] + ([result["nodes"]] if "nodes" in result else [])
    for side in sides:
        rx = side["receiver"]
        if rx["rejected"] or rx["lost"] or side["value_mismatches"] or side.get("missing_frames"):
            return False
    if "candump" in result:
        rx = result["candump"]["receiver"]
        if rx["rejected"] or rx["lost"]:
            return False
    return True


class Peer:
    """The nodes side started beside the controller side: ``start()``, then ``wait()`` or ``stop()``."""

    def start(self) -> None:
        raise NotImplementedError

    def wait(self) -> dict[str, Any]:
        raise NotImplementedError

    def stop(self) -> None:
        """Give up on the peer (after a failure on the controller side)."""


class ThreadPeer(Peer):
    """Nodes side in a thread of this process (the only way to share an in-process virtual bus)."""

    def __init__(self, cfg: Config, idle_timeout_s: float) -> None:
        self.cfg, self.idle_timeout_s = cfg, idle_timeout_s
        self._box: dict[str, Any] = {}
        self._thread = threading.Thread(target=self._target, name="buscheck-nodes", daemon=True)

    def _target(self) -> None:
        try:
            self._box["result"] = run_nodes(self.cfg, self.idle_timeout_s)
        except Exception as exc:  # handed to the waiting side
            self._box["error"] = exc

    def start(self) -> None:
        self._thread.start()

    def wait(self) -> dict[str, Any]:
        self._thread.join(timeout=self.idle_timeout_s + 5)
        if "error" in self._box:
            raise BusCheckError(f"nodes side failed: {self._box['error']}")
        if "result" not in self._box:
            raise BusCheckError("nodes side did not finish")
        return self._box["result"]


class ProcessPeer(Peer):
    """Nodes side as a separate OS process (``aider-exo buscheck --role nodes --json``)."""

    def __init__(self, argv: list[str], timeout_s: float) -> None:
        self.argv, self.timeout_s = argv, timeout_s
        self._proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "tools.cli", *self.argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )

    def wait(self) -> dict[str, Any]:
        assert self._proc is not None
        try:
            out, err = self._proc.communicate(timeout=self.timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            out, err = self._proc.communicate()
        if self._proc.returncode != 0:
            raise BusCheckError(f"nodes process exited {self._proc.returncode}: {err.decode(errors='replace').strip()}")
        result = json.loads(out)
        result["pid"] = self._proc.pid
        return result

    def stop(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.communicate()


def run_controller(
    cfg: Config,
    *,
    ticks: int,
    lockstep: bool,
    tick_timeout_s: float,
    handshake_timeout_s: float,
    peer: Peer | None,
    candump_path: Path | None,
) -> dict[str, Any]:
    """Run the controller side (with the nodes side as ``peer``, if given) and report."""
    codec = Codec()
    clock = MonotonicClock()
    recorder = Candump(cfg.bus.channel, candump_path) if candump_path else None
    peer_result: dict[str, Any] | None = None
    try:
        with open_bus(cfg.bus) as bus:
            if recorder:
                clock.sleep_until(clock.now_ns() + 200_000_000)  # candump must listen before the first frame
            side = ControllerSide(
                bus, codec, cfg.protocol.max_delta_counter, clock,
                None if lockstep else TICK_NS, tick_timeout_s,
            )
            if peer:
                peer.start()
            try:
                side.handshake(handshake_timeout_s)
                report = side.run(ticks)
                if peer:
                    peer_result = peer.wait()
            except BaseException:
                if peer:
                    peer.stop()
                raise
    finally:
        if recorder:
            recorder.stop(clock)
    result: dict[str, Any] = {
        "bus": {"interface": cfg.bus.interface, "channel": cfg.bus.channel},
        "mode": "lockstep" if lockstep else f"real time, {TICK_MS} ms ticks",
        "controller": report,
    }
    if peer_result is not None:
        result["nodes"] = peer_result
    if recorder:
        result["candump"] = decode_candump_log(recorder.path, codec, cfg.protocol.max_delta_counter)
    result["ok"] = is_clean(result)
    return result
