"""Process-level faults over a real SocketCAN vcan0 (issue 9, item 4; docs/FAULTS.md F1, F20, F22, I4).

``aider-exo nodes`` and ``aider-exo controller`` run as separate processes in the sagittal mode
while ``candump -L`` records every case; ticks are read from the capture (a SYNC carries the
controller's tick, the nodes' frames of that tick follow it; the nodes' heartbeats, one node per
tick in the DBC's phase, number the nodes' own ticks) and from the processes' JSON summaries.
Every walk runs in lock-step (a controller tick waits for the nodes' frames), so no stall of the
machine can disrupt one: each case runs once. No assertion is on a wall-clock duration except the
one marked in ``test_killed_controller_nodes_quick_stop_and_hold``, which is time-based by nature.

* F1: SIGKILL the nodes process mid-swing; the controller latches FAULT with NODE_LOST (or
  SENSOR_LOST of a sensor whose frame of the last tick the kill cut off) within 4 ticks of the
  last node frame and sends only HOLD commands from then on.
* F20: SIGKILL the controller mid-swing; the lock-step boards (``--silence``) take their own clock
  once it has been silent for ``SILENCE_S``, and every node sends EMCY 0x8250 (command timeout)
  within 4 of its own ticks, quick-stops and stays; the HHEA stays upright.
* F22/I4: a controller restarted against those latched nodes starts and stays in FAULT (150
  ticks, no TRACK command, no walking); with ``--reset`` (the operator's reset) it clears the
  nodes, waits out the FSM's 25 healthy ticks and stands to the end, and still does not walk.
* Lock-step walks of 3 gait cycles while cangen (can-utils) floods vcan0 as a third process:
  - frames that cannot be ours (random standard IDs and data at a length none of our messages
    has, random extended frames, random remote frames): the walk completes with no FAULT or HOLD,
    no exception, no fall, nothing of ours lost; both receivers count every foreign frame by reason;
  - cangen's fully random frames (random IDs, lengths and data), some of which carry our IDs at
    our lengths with a wrong CRC: no exception, no fall, and either the walk completes or the
    controller latches FAULT for the frames' integrity (docs/FAULTS.md F7/F8: 2 in 5 ticks, which
    those frames are) and holds. Nothing else is accepted.

Run through the vcan sandbox (``make test`` does: ``tools/vcan-run -- pytest -m vcan``).
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
from collections import Counter
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import can
import pytest
import yaml

from config import default_config_path, load_config, with_overrides
from config.loader import config_to_dict
from controller.faults import FaultKind
from controller.fsm import OPERATOR_RESET
from protocol.clock import TICK_S, MonotonicClock
from protocol.codec import Codec, Decoded
from protocol.e2e import Receiver
from protocol.enums import DriveState, EmcyCode, GaitState, JointMode, NmtCommand, NmtState, NodeError
from tests.conftest import ROOT
from tests.support.capture import PROBE_ID, candump, decode_capture, recorded
from tests.support.processes import AIDER, fsm_transitions

pytestmark = pytest.mark.vcan

CODEC = Codec()
CATALOG = CODEC.catalog
NODES = CATALOG.joint_nodes  # left hip, left knee, right hip, right knee
SYNC_ID = CODEC.spec("SYNC").frame_id
CONTROLLER_HEARTBEAT_ID = CODEC.spec("CONTROLLER_HEARTBEAT").frame_id
EMCY_IDS = {CATALOG.message("EMCY", n).frame_id: n for n in NODES}
#: the nodes' heartbeats: frame ID -> tick phase (one heartbeat per node every 5 of their own ticks)
HEARTBEAT_PHASE = {m.frame_id: m.tick_phase for m in CATALOG.messages if m.family == "HEARTBEAT" and m.sender in NODES}
HEARTBEAT_PERIOD = CODEC.spec("HEARTBEAT_LH").period_ticks
SWINGS = (GaitState.SWING_LEFT, GaitState.SWING_RIGHT)
COMMAND_TIMEOUT_TICKS = load_config(default_config_path()).nodes.command_timeout_ticks  # 3
BOUND_TICKS = 4  # docs/FAULTS.md F1 (detected and reacted to within 4 ticks) and issue 9's bound for F20


# Both in real time unless ``--lockstep`` is among ``extra``.
def _nodes(vcan0: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [AIDER, "nodes", "--bus", "socketcan", "--channel", vcan0, "--mode", "sagittal", "--json", "--quiet", *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


def _controller(vcan0: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [AIDER, "controller", "--bus", "socketcan", "--channel", vcan0, "--json", "--quiet", *extra],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


def _summary(proc: subprocess.Popen, timeout_s: float = 300) -> dict:
    """The JSON summary of a process that exits cleanly (a hang guard only)."""
    out, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, err
    assert "Traceback" not in err, err
    return json.loads(out)


def _stop(proc: subprocess.Popen) -> dict:
    proc.send_signal(signal.SIGTERM)
    return _summary(proc)


def _reap(*procs: subprocess.Popen) -> None:
    """After a failure: what still runs is killed (the processes this test started, by their handles)."""
    for p in procs:
        if p is not None and p.poll() is None:
            p.kill()
            p.communicate(timeout=60)


class _Tail:
    """candump's log as it grows: the classic standard frames of the complete lines written so far."""

    def __init__(self, path: Path) -> None:
        self.path, self.pos, self.rest = path, 0, b""

    def read(self) -> list[tuple[float, int, bytes]]:
        with self.path.open("rb") as f:
            f.seek(self.pos)
            chunk = f.read()
        self.pos += len(chunk)
        lines = (self.rest + chunk).split(b"\n")
        self.rest = lines.pop()
        out = []
        for line in lines:
            parts = line.split()
            if len(parts) != 3:
                continue
            ident, _, payload = parts[2].partition(b"#")
            if len(ident) != 3 or payload[:1] in (b"#", b"R"):
                continue  # extended, CAN FD or remote: never ours
            out.append((float(parts[0][1:-1]), int(ident, 16), bytes.fromhex(payload.decode())))
        return out


def _wait(tail: _Tail, done: Callable[[int, bytes], bool], what: str, alive: tuple[subprocess.Popen, ...],
          timeout_s: float = 300, timeout: type[Exception] = AssertionError) -> None:
    """Read the growing capture until ``done(frame_id, data)`` is true for a frame (a hang guard
    and the processes in ``alive`` still running, else the test fails with ``what``; ``timeout``
    is raised when it takes longer than ``timeout_s``)."""
    clock = MonotonicClock()
    deadline = clock.now_ns() + int(timeout_s * 1e9)
    while True:
        for _, frame_id, data in tail.read():
            if done(frame_id, data):
                return
        for p in alive:
            assert p.poll() is None, f"waiting for {what}: {p.args[1]} exited: {p.communicate()[1][-2000:]}"
        if clock.now_ns() >= deadline:
            raise timeout(f"waiting for {what}: not within {timeout_s} s")
        clock.sleep_until(clock.now_ns() + 50_000_000)


def _gait_state(frame_id: int, data: bytes) -> GaitState | None:
    if frame_id != CONTROLLER_HEARTBEAT_ID:
        return None
    d = CODEC.decode(frame_id, data)
    return GaitState(d.values.gait_state) if isinstance(d, Decoded) else None


class _NotWalking(Exception):
    """The walk held or faulted before the fault was injected."""


class _Swings:
    """True once the controller's heartbeat has entered its ``n``-th swing."""

    def __init__(self, n: int) -> None:
        self.n, self.seen, self.previous = n, 0, None

    def __call__(self, frame_id: int, data: bytes) -> bool:
        state = _gait_state(frame_id, data)
        if state is not None:
            if state in (GaitState.HOLD, GaitState.FAULT):
                raise _NotWalking(f"the controller went to {state.name} at swing {self.seen}")
            if state in SWINGS and state != self.previous:
                self.seen += 1
            self.previous = state
        return self.seen >= self.n


class _Count:
    """True after ``n`` frames with one of ``ids`` (SYNCs count controller ticks, the nodes' heartbeats their own ticks)."""

    def __init__(self, ids: set[int], n: int) -> None:
        self.ids, self.n, self.seen = ids, n, 0

    def __call__(self, frame_id: int, _data: bytes) -> bool:
        self.seen += frame_id in self.ids
        return self.seen >= self.n


def _boot(vcan0: str, log: Path, *extra: str) -> subprocess.Popen:
    """The nodes process, once its four boot-ups are in the capture."""
    nodes = _nodes(vcan0, *extra)
    clock = MonotonicClock()
    deadline = clock.now_ns() + 120_000_000_000  # a hang guard only
    while (booted := recorded(log)) < 4 and nodes.poll() is None and clock.now_ns() < deadline:
        clock.sleep_until(clock.now_ns() + 100_000_000)
    if booted < 4:
        _reap(nodes)
        pytest.fail(f"the nodes did not boot (exit status {nodes.poll()})")
    return nodes


def _sync_ticks(decoded: list[Decoded | None]) -> list[int]:
    """Per frame of the capture, the tick of the SYNC before it (-1 before the first)."""
    tick, out = -1, []
    for d in decoded:
        if d is not None and d.name == "SYNC":
            tick = d.values.tick
        out.append(tick)
    return out


SECOND_SWING_S = 300  # a hang guard: the second swing came 10-25 s after the controller's start in the sandbox
#: the nodes' ``--silence`` in the crash scenario: lock-step boards whose controller sent no SYNC for
#: this long run on their own clock. A lock-step tick took up to 0.6 s in the sandbox with the host busy.
SILENCE_S = 5.0


def _why(ctl: subprocess.Popen) -> list[str]:
    """The controller's transitions into HOLD or FAULT, from its summary at SIGTERM."""
    ctl.send_signal(signal.SIGTERM)
    out, _ = ctl.communicate(timeout=120)
    try:
        return [e for e in json.loads(out)["events"] if "-> HOLD" in e or "-> FAULT" in e]
    except (ValueError, KeyError):
        return [f"no summary (exit status {ctl.returncode})"]


def _steady_patient_config(folder: Path) -> Path:
    """The default configuration with the steady patient (one stick placement every step), as a
    file for the nodes process."""
    cfg = with_overrides(load_config(default_config_path()), {"sim.patient.intention.regime": "steady"})
    path = folder / "steady-patient.yaml"
    path.write_text(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), encoding="utf-8")
    return path


@contextmanager
def _mid_swing(vcan0: str, tmp: Path, name: str, nodes_extra: tuple[str, ...] = ()):
    """candump recording ``<tmp>/<name>.log``, ``aider-exo nodes --lockstep`` booted and
    ``aider-exo controller --lockstep --walk`` until 0.6 s into the second swing (of 1.2 s); yields
    (nodes, controller, tail of the capture, its path) there. In lock-step a controller tick waits
    for the nodes' frames, so no stall of the machine can disrupt the walk: one attempt, and a HOLD
    or FAULT before that point fails. candump stops at the end of the block; the processes are the
    caller's (killed here on an error).

    0.6 s, not 0.3: at 0.3 s the patient, held by the quick stop, sometimes stood off its sticks
    (5-35 N) and I4 rightly refused the F22 test's reset (killed 2-8 ticks into a swing; 10-55 ticks
    in, the sticks carried 80-220 N). The steady patient (one stick placement every step): these
    tests are of the fault protocol; held mid-swing, the noisy one (the default) stood with one
    stick at 6-8 N in 2 of about 9 runs."""
    log = tmp / f"{name}.log"
    nodes = ctl = None
    try:
        with candump(vcan0, log):
            nodes = _boot(vcan0, log, "--lockstep", "--config", str(_steady_patient_config(tmp)), *nodes_extra)
            ctl = _controller(vcan0, "--walk", "--lockstep")
            tail = _Tail(log)
            try:
                _wait(tail, _Swings(2), "the second swing", (nodes, ctl), SECOND_SWING_S)
            except _NotWalking as e:
                pytest.fail(f"the lock-step walk stopped before the fault: {e}: {_why(ctl)}")
            _wait(tail, _Count({SYNC_ID}, 30), "0.6 s into the swing", (nodes, ctl))
            yield nodes, ctl, tail, log
    except BaseException:
        _reap(nodes, ctl)
        raise


# -- F1: the nodes process killed ---------------------------------------------------------------------


def test_killed_nodes_process_faults_the_controller_within_4_ticks_and_it_holds(vcan0, tmp_path):
    """F1, in lock-step (a controller tick waits for the nodes' frames, so no stall of the machine
    can disrupt the walk before the kill; the fault is counted in ticks either way): the nodes
    process killed mid-swing, FAULT (NODE_LOST) within 4 ticks, HOLD commands from then on."""
    with _mid_swing(vcan0, tmp_path, "candump") as (nodes, ctl, tail, log):
        nodes.kill()  # SIGKILL
        nodes.communicate(timeout=60)
        _wait(tail, lambda i, d: _gait_state(i, d) == GaitState.FAULT, "the controller's FAULT", (ctl,))
        _wait(tail, _Count({SYNC_ID}, 50), "50 ticks in FAULT", (ctl,))
        summary = _stop(ctl)
    assert nodes.returncode == -signal.SIGKILL

    decoded, _ = decode_capture(log)  # no CRC, counter or length error, no frame lost
    ticks = _sync_ticks(decoded)
    node_frames = [i for i, d in enumerate(decoded) if d.message.sender in NODES]
    last_node_tick = ticks[node_frames[-1]]  # the SYNC after which no node frame came
    transitions = fsm_transitions(summary["events"])
    faults = [t for t in transitions if t[2] == "FAULT"]
    assert faults, summary["events"][-5:]
    fault_tick, source, _, cause = faults[0]
    print(f"\nF1: last node frame after SYNC {last_node_tick}, {source} -> FAULT at tick {fault_tick} "
          f"({fault_tick - last_node_tick} ticks): {cause}")
    if FaultKind.of(cause) is FaultKind.SENSOR_LOST:
        # The kill split the last tick's frames: a sensor frame of that tick never came, so that
        # sensor had been silent a tick longer than its node when the 3-tick budget ran out
        # (seen once: PLANTAR_RIGHT, with its node's status of that tick sent).
        sensor = cause.partition("(")[2].rstrip(")").partition(":")[0]
        last_sensor_tick = max(t for t, d in zip(ticks, decoded) if d.name == sensor)
        assert last_sensor_tick < last_node_tick, (cause, last_sensor_tick, last_node_tick)
    else:
        assert FaultKind.of(cause) is FaultKind.NODE_LOST, cause
    assert 0 < fault_tick - last_node_tick <= BOUND_TICKS
    assert source in ("SWING_LEFT", "SWING_RIGHT"), source  # killed mid-swing
    # From walking straight to FAULT (no HOLD first, nothing after: FAULT is latched).
    assert transitions[-1] == faults[0] and len(faults) == 1, transitions[-3:]
    assert summary["final_state"] == "FAULT" and summary["stopped_by"] == "SIGTERM"

    # The joint commands: the gait's (TRACK) before the fault, HOLD from the FAULT tick on, four a tick.
    commands = [(t, JointMode(d.values.mode)) for t, d in zip(ticks, decoded) if d.message.family == "JOINT_COMMAND"]
    assert JointMode.TRACK in {m for t, m in commands if t < fault_tick}
    after = [(t, m) for t, m in commands if t >= fault_tick]
    assert {m for _, m in after} == {JointMode.HOLD}, Counter(m.name for _, m in after)
    syncs_after = sum(d.name == "SYNC" and d.values.tick >= fault_tick for d in decoded)
    assert syncs_after >= 50 and len(after) == 4 * syncs_after
    states = {GaitState(d.values.gait_state) for t, d in zip(ticks, decoded) if d.name == "CONTROLLER_HEARTBEAT" and t >= fault_tick}
    assert states == {GaitState.FAULT}


# -- F20 and F22: the controller killed, then restarted -------------------------------------------------


def _own_ticks(msgs: list[can.Message], last_sync: int, tick: int) -> dict[int, int]:
    """The nodes' own tick of each of their heartbeats after the controller fell silent (index ->
    tick). The lock-step boards take their own clock ``SILENCE_S`` after the last SYNC (frame
    ``last_sync``, of ``tick``), at that tick + 1, and send one heartbeat per tick in the DBC's phase
    (left hip at ticks 1 mod 5, ..., none at 0 mod 5), so consecutive heartbeats number the ticks
    between them; the timestamps only choose among ticks a heartbeat period apart (an overrun
    skips ticks)."""
    out: dict[int, int] = {}
    prev_ts = None
    for i in range(last_sync + 1, len(msgs)):
        m = msgs[i]
        phase = HEARTBEAT_PHASE.get(m.arbitration_id)
        if phase is None or m.is_extended_id or m.timestamp - msgs[last_sync].timestamp < SILENCE_S / 2:
            continue  # not a heartbeat, or the last SYNC's own (lock-step)
        k = (phase - tick) % HEARTBEAT_PERIOD or HEARTBEAT_PERIOD
        if prev_ts is not None:  # the silence before the first is not the boards' time
            elapsed = (m.timestamp - prev_ts) / TICK_S
            k += HEARTBEAT_PERIOD * max(0, round((elapsed - k) / HEARTBEAT_PERIOD))
        tick += k
        out[i] = tick
        prev_ts = m.timestamp
    return out


HEARTBEAT_LAG = 0.15  # ticks: a node's heartbeat goes out after its tick's physics step (about 3 ms in)


def _tick_at(index: int, msgs: list[can.Message], own: dict[int, int]) -> int:
    """The nodes' own tick in progress when frame ``index`` was on the bus: the tick of the heartbeat
    before it, plus the ticks begun since by the time elapsed (the fifth tick of each heartbeat
    period has no heartbeat). An EMCY goes out right after its tick's heartbeat: the same tick."""
    before = max(i for i in own if i < index)
    elapsed = (msgs[index].timestamp - msgs[before].timestamp) / TICK_S
    return own[before] + math.floor(elapsed + HEARTBEAT_LAG)


@pytest.fixture(scope="module")
def crash():
    """The F20/F22 scenario, run once by the first test that asks (with the vcan0 fixture's gate),
    all in lock-step: nodes (``--silence``) and controller walking, the controller SIGKILLed
    mid-swing, the nodes left alone until they have run 2.5 s on their own clock, a controller
    started again against them for 150 ticks without and then with ``--reset``, the nodes stopped;
    candump records each phase."""
    cache: dict = {}

    def run(vcan0: str, tmp: Path) -> dict:
        if "error" in cache:
            pytest.fail(cache["error"])  # not run again for the next test
        if cache:
            return cache
        try:
            scenario(vcan0, tmp)
        except BaseException as e:
            cache.clear()
            cache["error"] = f"the scenario failed: {e!r}"[:2000]
            raise
        return cache

    def scenario(vcan0: str, tmp: Path) -> None:
        truth = tmp / "truth.jsonl"
        logs = {phase: tmp / f"{phase}.log" for phase in ("restart", "reset")}
        nodes = ctl = None
        try:
            nodes_extra = ("--truth", str(truth), "--silence", str(SILENCE_S))
            with _mid_swing(vcan0, tmp, "kill", nodes_extra) as (nodes, ctl, tail, logs["kill"]):
                ctl.kill()  # SIGKILL
                ctl.communicate(timeout=60)
                cache["killed_rc"] = ctl.returncode
                _wait(tail, _Count(set(EMCY_IDS), 4), "the nodes' EMCYs", (nodes,), timeout_s=120)
                # 2.5 s of the nodes alone on their own clock (4 heartbeats per 5 ticks)
                _wait(tail, _Count(set(HEARTBEAT_PHASE), 100), "2.5 s of quick stop", (nodes,), timeout_s=120)
            for phase, extra in (("restart", ()), ("reset", ("--reset",))):
                with candump(vcan0, logs[phase]):
                    ctl = _controller(vcan0, "--lockstep", "--ticks", "150", *extra)
                    cache[phase] = _summary(ctl)
            cache["nodes"] = _stop(nodes)
        finally:
            _reap(nodes, ctl)
        cache["logs"] = logs
        cache["truth"] = [json.loads(line) for line in truth.read_text().splitlines()]

    return run


def test_killed_controller_nodes_quick_stop_and_hold(vcan0, tmp_path_factory, crash):
    """F20: every node sends EMCY 0x8250 within 4 of its own ticks after the controller's last
    frame, quick-stops and stays; the HHEA stays upright. The lock-step boards' own clock starts
    ``SILENCE_S`` after the last SYNC (``--silence``), at the tick after it."""
    r = crash(vcan0, tmp_path_factory.mktemp("crash"))
    assert r["killed_rc"] == -signal.SIGKILL
    msgs = [m for m in can.CanutilsLogReader(str(r["logs"]["kill"])) if m.arbitration_id != PROBE_ID]
    decoded, _ = decode_capture(r["logs"]["kill"])  # no CRC, counter or length error, no frame lost
    assert len(decoded) == len(msgs)
    last_ctl = max(i for i, d in enumerate(decoded) if d.message.sender == "CONTROLLER")
    last_state = next(GaitState(d.values.gait_state) for d in reversed(decoded[:last_ctl + 1]) if d.name == "CONTROLLER_HEARTBEAT")
    assert last_state in SWINGS, last_state  # killed mid-swing
    emcys = [(i, d) for i, d in enumerate(decoded) if d.message.family == "EMCY"]
    assert {d.message.sender for _, d in emcys} == set(NODES)  # one each, all after the kill
    assert all(i > last_ctl for i, _ in emcys)
    assert len(emcys) == len(NODES), [(d.name, hex(d.values.emcy_code)) for _, d in emcys]
    last_sync = max(i for i, d in enumerate(decoded) if d.name == "SYNC")
    last_tick = decoded[last_sync].values.tick  # the nodes' last tick in lock-step
    own = _own_ticks(msgs, last_sync, last_tick)
    ran, phases = set(own.values()), set(HEARTBEAT_PHASE.values())
    figures = []
    for i, d in emcys:
        assert d.values.emcy_code == EmcyCode.COMMAND_TIMEOUT and d.values.error_register == 0x11, d
        # Tick-based: the nodes' own ticks after the last SYNC's to the EMCY's, numbered by their
        # heartbeats (3 without a command; 4 when the next tick's commands came before the kill,
        # the last frames). A tick the nodes skipped (an overrun re-aligns their timer) runs no
        # watchdog and sends no heartbeat: one whose heartbeat is missing is not counted.
        span = range(last_tick + 1, _tick_at(i, msgs, own) + 1)
        skipped = [t for t in span if t % HEARTBEAT_PERIOD in phases and t not in ran]
        node_ticks = len(span) - len(skipped)
        # Time-based by nature (the boards' own timer): the EMCY's time after the boards took their
        # own clock (the silence after the last SYNC) in ticks of 20 ms, in the guest; one tick of
        # slack for the scheduling of three processes on its one CPU.
        dt = msgs[i].timestamp - msgs[last_sync].timestamp - SILENCE_S
        figures.append((d.message.sender, node_ticks, len(skipped), round(dt * 1000, 1)))
        assert 0 < node_ticks <= BOUND_TICKS, figures
        assert 0 < dt and math.ceil(dt / TICK_S) <= BOUND_TICKS + 1, figures
        assert d.values.detail == COMMAND_TIMEOUT_TICKS, d  # the node's own count of ticks without a command
    print(f"\nF20: EMCY 0x8250 after the last SYNC (node, own ticks, skipped, ms after the {SILENCE_S} s silence): {figures}")
    # After the EMCY the nodes run on (heartbeats, OPERATIONAL) and send nothing else: no SYNC comes.
    after = decoded[emcys[-1][0] + 1:]
    assert after and {d.message.family for d in after} == {"HEARTBEAT"}, Counter(d.name for d in after)
    assert {NmtState(d.values.nmt_state) for d in after} == {NmtState.OPERATIONAL}
    assert sum(d.message.family == "HEARTBEAT" for d in after) >= 100  # 2.5 s of their ticks

    # Quick stop and stay: the restarted controller's first statuses (the nodes alone for 2.5 s and
    # its start-up) show every drive in FAULT (COMMAND_TIMEOUT) and the joints near where they were
    # at the last status before the kill (mid-swing: the joints moved on until the quick stop
    # latched them, 3-4 ticks later; 0.001-0.049 rad measured), then held through its 150 ticks.
    before = {d.message.sender: d.values for d in decoded[:last_ctl] if d.message.family == "JOINT_STATUS"}
    restart, _ = decode_capture(r["logs"]["restart"])
    held: dict[str, list] = {}
    for d in restart:
        if d.message.family == "JOINT_STATUS":
            held.setdefault(d.message.sender, []).append(d.values)
    assert set(held) == set(NODES)
    first = {n: v[0] for n, v in held.items()}
    drift = {n: round(abs(first[n].position_rad - before[n].position_rad), 4) for n in NODES}
    spread = {n: round(max(x.position_rad for x in v) - min(x.position_rad for x in v), 4) for n, v in held.items()}
    print(f"F20: joints after the quick stop against the last status before the kill (rad): {drift}; "
          f"their spread over the next 150 ticks: {spread}")
    assert {DriveState(v.drive_state) for v in first.values()} == {DriveState.FAULT}
    assert {NodeError(v.error_code) for v in first.values()} == {NodeError.COMMAND_TIMEOUT}
    assert max(drift.values()) < 0.1, drift
    assert max(spread.values()) < 0.01, spread
    imu = next(d.values for d in restart if d.name == "TRUNK_IMU_ORIENTATION")
    assert abs(imu.roll_rad) < 0.2 and abs(imu.pitch_rad) < 0.2, imu
    # The simulation's ground truth: no fall at any SYNC, the first one 2.5 s after the kill
    # included, nor at the end.
    assert r["truth"] and all(t["fall"] is None for t in r["truth"]), next(t for t in r["truth"] if t["fall"])
    assert r["nodes"]["fall"] is None and r["nodes"]["stopped_by"] == "SIGTERM"


def _commands(decoded: list[Decoded]) -> Counter:
    return Counter(JointMode(d.values.mode).name for d in decoded if d.message.family == "JOINT_COMMAND")


def test_restarted_controller_starts_and_stays_in_fault_without_an_operator_reset(vcan0, tmp_path_factory, crash):
    """F22/I4: against the latched nodes, 150 ticks in FAULT, no TRACK command, no reset sent."""
    r = crash(vcan0, tmp_path_factory.mktemp("crash"))
    s = r["restart"]
    transitions = fsm_transitions(s["events"])
    print(f"\nF22 without reset: {transitions}, commands {dict(_commands(decode_capture(r['logs']['restart'])[0]))}")
    assert s["ticks"] == 150 and s["final_state"] == "FAULT" and s["resets"] == []
    assert len(transitions) == 1, transitions
    tick, source, target, cause = transitions[0]
    assert (source, target) == ("INIT", "FAULT") and FaultKind.of(cause) is FaultKind.DRIVE_FAULT, transitions
    assert tick <= 5  # at its first statuses
    assert s["steps"] == []
    decoded, _ = decode_capture(r["logs"]["restart"])
    assert set(_commands(decoded)) == {"HOLD"}
    nmt = [NmtCommand(d.values.command) for d in decoded if d.name == "NMT_COMMAND"]
    assert NmtCommand.FAULT_RESET not in nmt, nmt
    assert {GaitState(d.values.gait_state) for d in decoded if d.name == "CONTROLLER_HEARTBEAT"} <= {GaitState.INIT, GaitState.FAULT}
    # The nodes stay latched: every status shows the drive in FAULT.
    assert {DriveState(d.values.drive_state) for d in decoded if d.message.family == "JOINT_STATUS"} == {DriveState.FAULT}


def test_restarted_controller_leaves_fault_only_on_the_operators_reset_and_does_not_walk(vcan0, tmp_path_factory, crash):
    """F22/I4 with ``--reset``: FAULT_RESET clears the nodes, the FSM stands after 25 healthy ticks
    on a second reset request, and without --walk it stands to the end."""
    r = crash(vcan0, tmp_path_factory.mktemp("crash"))
    s = r["reset"]
    transitions = fsm_transitions(s["events"])
    decoded, _ = decode_capture(r["logs"]["reset"])
    print(f"\nF22 with --reset: resets at ticks {s['resets']}, {transitions}, commands {dict(_commands(decoded))}")
    assert s["ticks"] == 150
    sticks = [(d.name, round(d.values[0])) for d in decoded if d.message.family == "STICK"][-4:]  # force first
    ticks = _sync_ticks(decoded)
    emcys = [(t, d.message.sender, EmcyCode(d.values.emcy_code).name) for t, d in zip(ticks, decoded) if d.message.family == "EMCY"]
    # Then STAND to the end (in lock-step no stall of the machine can stop a frame).
    assert [(a, b) for _, a, b, _ in transitions] == [("INIT", "FAULT"), ("FAULT", "STAND")], (
        transitions, s["resets"], f"last stick forces {sticks} (I4 resets only with both sticks loaded)",
        f"EMCYs (SYNC tick, node, code) {emcys}", f"fault causes {s['fault_causes']}")
    assert s["final_state"] == "STAND"
    assert FaultKind.of(transitions[0][3]) is FaultKind.DRIVE_FAULT and transitions[1][3] == OPERATOR_RESET
    assert len(s["resets"]) == 2, s["resets"]  # the nodes' FAULT_RESET, then the FSM's reset once they were healthy
    first_reset, fsm_reset = s["resets"]
    assert transitions[1][0] == fsm_reset  # FAULT left in the tick of the reset, not before
    assert fsm_reset - first_reset >= 25  # I4: the nodes healthy for 25 ticks first
    assert s["steps"] == [] and set(_commands(decoded)) == {"HOLD"}  # never walks on its own

    resets = [t for t, d in zip(ticks, decoded) if d.name == "NMT_COMMAND" and d.values.command == NmtCommand.FAULT_RESET]
    assert resets == s["resets"]
    # Each node answers the first FAULT_RESET with EMCY NO_ERROR at once, and reports its drive out
    # of FAULT from the next tick on. In the capture that answer follows the reset's tick's SYNC, or
    # the next one: in lock-step the controller sends that SYNC as soon as its tick is written, and
    # the nodes read the reset before it but may send their answer after it is on the bus.
    cleared = [(t, d.message.sender) for t, d in zip(ticks, decoded)
               if d.message.family == "EMCY" and d.values.emcy_code == EmcyCode.NO_ERROR]
    assert sorted(n for _, n in cleared) == sorted(NODES)
    assert all(first_reset <= t <= first_reset + 1 for t, _ in cleared), (first_reset, cleared)
    drive = {(d.message.sender, DriveState(d.values.drive_state)) for t, d in zip(ticks, decoded)
             if d.message.family == "JOINT_STATUS" and t > first_reset}
    assert {state for _, state in drive} == {DriveState.HOLD}
    states = [GaitState(d.values.gait_state) for t, d in zip(ticks, decoded)
              if d.name == "CONTROLLER_HEARTBEAT" and t > fsm_reset]
    assert states and set(states) == {GaitState.STAND}


# -- a flood of foreign frames ------------------------------------------------------------------------

FLOOD_CYCLES = 3
FOREIGN_DLC = 6  # no message of ours is 6 bytes long: a standard frame of this length is never one of ours
assert FOREIGN_DLC not in {m.dlc for m in CATALOG.messages}
# The rates: cangen -g 1 (about 700 frames/s in the guest) with the other two made the nodes' socket
# drop frames (controller frames lost) and the controller's bounded drain (200 frames a tick) miss
# its nodes' frames whenever the guest slowed down (lock-step ticks of 0.1-0.6 s when the host is
# busy): NODE_LOST. -g 3 leaves room for that.
FOREIGN = (
    # cangen (can-utils): random standard IDs with random data every 3 ms, random extended frames
    # (random lengths and data) every 10 ms, random standard remote frames every 20 ms.
    ["cangen", "-g", "3", "-I", "r", "-L", str(FOREIGN_DLC), "-D", "r"],
    ["cangen", "-g", "10", "-e", "-I", "r", "-L", "r", "-D", "r"],
    ["cangen", "-g", "20", "-R", "-I", "r"],
)
RANDOM = (["cangen", "-g", "3", "-I", "r", "-L", "r", "-D", "r"],)  # every length: some hit our IDs with our lengths


def _is_probe(m: can.Message) -> bool:
    return m.arbitration_id == PROBE_ID and not m.is_extended_id and bytes(m.data) in (b"", b"\xff")


def _flooded_walk(vcan0: str, log: Path, floods: tuple[list[str], ...]) -> tuple[dict, dict, list[can.Message]]:
    """``aider-exo nodes --lockstep`` booted, cangen started, ``aider-exo controller --lockstep
    --cycles 3``; cangen stopped once the controller has exited, then the nodes. Returns both
    summaries and the capture (probes left out)."""
    nodes = ctl = None
    gens: list[subprocess.Popen] = []
    with candump(vcan0, log):
        try:
            nodes = _boot(vcan0, log, "--lockstep")
            gens = [subprocess.Popen([*cmd, vcan0], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                    for cmd in floods]
            ctl = _controller(vcan0, "--lockstep", "--cycles", str(FLOOD_CYCLES))
            summary = _summary(ctl, timeout_s=900)  # a hang guard only
            for g in gens:
                assert g.poll() is None, g.communicate()[1]  # it flooded for the whole walk
                g.send_signal(signal.SIGINT)
                g.communicate(timeout=30)
            final = _stop(nodes)
        finally:
            _reap(nodes, ctl, *gens)
    return summary, final, [m for m in can.CanutilsLogReader(str(log)) if not _is_probe(m)]


def _flood_per_tick(results: list) -> list[int]:
    """The frames our receiver rejects (the flood's, and any of ours it damaged) between consecutive SYNCs."""
    counts, n, started = [], 0, False
    for r in results:
        if isinstance(r, Decoded) and r.name == "SYNC":
            if started:
                counts.append(n)
            started, n = True, 0
        elif not isinstance(r, Decoded):
            n += 1
    return counts


def _flood_figures(summary: dict, final: dict, msgs: list[can.Message], flood: int, per_tick: list[int]) -> str:
    span = msgs[-1].timestamp - msgs[0].timestamp
    kinds = Counter("fd" if m.is_fd else "remote" if m.is_remote_frame else "extended" if m.is_extended_id else "standard"
                    for m in msgs)
    return (f"{flood} foreign frames of {len(msgs)} in {span:.0f} s; kinds on the bus {dict(kinds)}; per tick of the walk "
            f"mean {sum(per_tick) / len(per_tick):.1f}, none in {per_tick.count(0)} of {len(per_tick)}; {summary['ticks']} ticks, "
            f"timeouts {summary['timeouts']}; controller rx {summary['receiver']['rejected_by_reason']} lost "
            f"{summary['receiver']['lost']}; nodes rx {final['receiver']['rejected_by_reason']} lost {final['receiver']['lost']}")


def _check_walked(summary: dict, final: dict) -> None:
    events = summary["events"]
    assert not any("FAULT" in e or "HOLD" in e for e in events), (
        [e for e in events if "FAULT" in e or "HOLD" in e][:3], summary["timeouts"], summary["stalls"], final["stalls"])
    assert summary["steps_completed"] == 2 * FLOOD_CYCLES, (summary["steps_completed"], events[-5:])
    assert summary["final_state"] not in ("FAULT", "HOLD") and summary["send_failures"] == 0
    assert {n["error"] for n in final["nodes"].values()} == {"NONE"}


def test_cangen_flood_of_foreign_frames_during_a_lockstep_walk_is_counted_and_ignored(vcan0, tmp_path):
    """Frames that cannot be ours (unknown IDs; our IDs at a length none of ours has; extended;
    remote): the walk of 3 cycles as without them, and every one counted by reason."""
    summary, final, msgs = _flooded_walk(vcan0, tmp_path / "candump.log", FOREIGN)
    ours = summary["frames_sent"] + final["frames_sent"]
    rx = Receiver(CODEC)
    results = [rx.receive(m) for m in msgs]
    flood = len(msgs) - ours
    per_tick = _flood_per_tick(results)
    print(f"\nforeign flood: {_flood_figures(summary, final, msgs, flood, per_tick)}")
    # The walk: all its cycles, no FAULT or HOLD, no fall, no exception (clean exits, checked).
    _check_walked(summary, final)
    # (A lock-step tick may time out when the guest stalls and the drain's bound of 200 frames a
    # tick is reached before the nodes' frames: they count late, as F2/F4 allow; not a fault.)
    assert final["fall"] is None
    # On the bus every frame of ours decodes, in sequence (nothing lost to the flood), every tick once.
    assert rx.stats.accepted == ours and rx.stats.lost == 0 and rx.stats.rejected_total == flood
    syncs = [r.values.tick for r in results if isinstance(r, Decoded) and r.name == "SYNC"]
    assert syncs == list(range(summary["ticks"]))
    assert per_tick.count(0) <= 0.1 * len(per_tick)  # foreign frames in 90 % of the ticks at least: the whole walk
    # The nodes saw the whole flood (from before the controller's start to after its end) and
    # counted every frame; the controller every frame from its first SYNC on, at least.
    assert abs(final["receiver"]["rejected"] - flood) <= 0.01 * flood and final["receiver"]["lost"] == 0, (  # candump may miss a few
        final["receiver"], flood)
    first_sync = next(i for i, r in enumerate(results) if isinstance(r, Decoded) and r.name == "SYNC")
    last_ctl = max(i for i, r in enumerate(results) if isinstance(r, Decoded) and r.message.sender == "CONTROLLER")
    during = sum(not isinstance(r, Decoded) for r in results[first_sync:last_ctl])
    assert 0.99 * during <= summary["receiver"]["rejected"] <= 1.01 * flood and summary["receiver"]["lost"] == 0
    for who, by_reason in (("controller", summary["receiver"]["rejected_by_reason"]), ("nodes", final["receiver"]["rejected_by_reason"])):
        assert set(by_reason) == {"unknown_id", "wrong_dlc", "not_classic_frame", "remote_frame"}, (who, by_reason)


def test_cangen_random_flood_colliding_with_our_ids_during_a_lockstep_walk(vcan0, tmp_path):
    """cangen's random IDs, lengths and data: some frames carry our IDs at our lengths with a wrong
    CRC (or, one in 256, a right one). No exception, no fall; the walk completes, or the
    controller latches FAULT for the frames' integrity (docs/FAULTS.md F7/F8: 2 in 5 ticks) and holds."""
    summary, final, msgs = _flooded_walk(vcan0, tmp_path / "candump.log", RANDOM)
    ours = summary["frames_sent"] + final["frames_sent"]
    rx = Receiver(CODEC)
    results = [rx.receive(m) for m in msgs]
    flood = len(msgs) - ours
    collisions = Counter(r.reason.value for r in results if not isinstance(r, Decoded) and r.message is not None)
    per_tick = _flood_per_tick(results)
    print(f"\nrandom flood: {_flood_figures(summary, final, msgs, flood, per_tick)}; on our IDs {dict(collisions)}")
    assert final["fall"] is None
    assert per_tick.count(0) <= 0.1 * len(per_tick) and collisions["bad_crc"] > 0
    for who, rxd in (("controller", summary["receiver"]), ("nodes", final["receiver"])):
        assert rxd["rejected_by_reason"].get("unknown_id", 0) > 0 and rxd["rejected_by_reason"].get("bad_crc", 0) > 0, (who, rxd)
    faults = [t for t in fsm_transitions(summary["events"]) if t[2] in ("FAULT", "HOLD")]
    if not faults:
        _check_walked(summary, final)
        return
    tick, _, target, cause = faults[0]
    assert target == "FAULT" and FaultKind.of(cause) is FaultKind.FRAME_INTEGRITY, faults
    assert summary["final_state"] == "FAULT"
    ticks = _sync_ticks([r if isinstance(r, Decoded) else None for r in results])
    # The controller counts a frame in the tick whose drain reads it: one that arrived after its
    # last read of tick k-1 (after SYNC k-1 in the capture) counts in tick k. So its window of 5
    # ticks reaches one SYNC further back in the capture.
    hits = [t for t, r in zip(ticks, results) if not isinstance(r, Decoded) and r.message is not None
            and r.message.sender in NODES and r.reason.value in ("bad_crc", "wrong_sequence") and tick - 6 < t <= tick]
    assert len(hits) >= 2, (tick, hits)
    after = {JointMode(r.values.mode) for t, r in zip(ticks, results)
             if isinstance(r, Decoded) and r.message.family == "JOINT_COMMAND" and t >= tick}
    assert after <= {JointMode.HOLD}, after
