"""Re-simulation: the node frames of a recorded lock-step run fed into a fresh controller, tick by
tick, and the frames it would send compared with the ones the recorded controller sent.

The trace is cut at its SYNC frames: the node frames after SYNC(k) (and, for the first tick, the
boot-ups before it) up to the controller's first frame of the tick are what
:class:`controller.hardware.CanHardware` read in tick ``k``: the loop sends its frames once its read
has ended, so a node frame after them came too late for the tick's read, and the loop read it
before it sent SYNC(k+1), as a late answer (``queued``; :meth:`CanHardware._read_queued`), which
is how they are fed here. (In a lock-step run every node frame of a SYNC comes before the
controller's; a frame that comes after the read ended but before the controller sends, in a real-
time run, is taken for the tick's: the wire does not show where a read ended.) A
:class:`controller.hardware.ReplayHardware` reads them (through the receiver with the configured
``max_delta_counter``) into the tick's snapshot in a :class:`controller.session.Session` of its own,
and what the session writes, the controller's heartbeat and telemetry on the DBC's schedule among
them, is what the loop sent. Both sides are compared
on the wire's grid (the new values encoded and decoded with the DBC), message by message and
signal by signal; the first divergence names the tick, the message, the signal and both values.
This is how a controller change is regression-tested against recorded sessions: the recorded
run must be reproduced with zero divergence by the controller that recorded it.

The operator's start (:meth:`Operator.start`) is not on the bus: the recording's sidecar gives its
tick (``aider-exo trace record --walk`` writes it), or the caller does (``"start"``: at each
controller start, as ``aider-exo controller --walk`` asks it: kept until the controller stands).

A recording of a real-time session (the session recorder on ``can0``, ``candump -L``) is read the
same way: only the SYNC frames' tick numbers cut it, never the timestamps, so wall-clock time and
jitter do not matter, and node answers that came after the controller's frames are the late
answers above. What differs is handled so: a tick number that jumps (the real-time loop overran
and skipped ticks) is told to the core as the loop does (:meth:`Session.skipped`); a tick
number that goes back (to 0: the controller was restarted) starts a fresh controller; a recording
that starts while a controller runs (its first SYNC's tick is not 0) cannot be re-simulated from
there, since a fresh controller does not have the running one's state (its FSM, the nodes' states,
the estimator): those ticks, and the frames before the first SYNC, are skipped and counted up to
the next controller start. The frames between a controller's last frame and a restarted one's
SYNC(0) are the new controller's first read, as the frames before a recording's first SYNC(0) are.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from protocol.codec import Codec, Decoded
from protocol.enums import GaitState
from protocol.errors import EncodeError
from tools.trace.decode import decimals
from tools.trace.reader import Frame

MAX_LISTED = 10


@dataclass
class Divergence:
    tick: int
    message: str
    signal: str | None  # None: the message itself is missing or extra
    recorded: Any
    resim: Any
    unit: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"tick": self.tick, "message": self.message, "signal": self.signal, "recorded": self.recorded,
                "resim": self.resim, "unit": self.unit}

    def text(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        where = f"{self.message}.{self.signal}" if self.signal else self.message
        return f"tick {self.tick}: {where}: recorded {self.recorded}{unit}, resim {self.resim}{unit}"


@dataclass
class ResimReport:
    ticks: int = 0
    frames_compared: int = 0
    signals_compared: int = 0
    divergent_ticks: int = 0
    divergences: list[Divergence] = field(default_factory=list)  # the first MAX_LISTED
    node_frames_fed: int = 0
    node_frames_rejected: int = 0
    final_state: str | None = None
    runs: int = 0  # controller starts re-simulated (a restart in the recording starts a fresh controller)
    first_sync_tick: int | None = None
    skipped_frames: int = 0  # frames before the first SYNC of a recording that starts mid-session
    skipped_ticks: int = 0  # ticks of a controller whose start is not in the recording
    overruns: int = 0  # tick numbers that jumped (the real-time loop skipped ticks), told to the core
    ticks_jumped: int = 0  # the ticks they skipped

    @property
    def first(self) -> Divergence | None:
        return self.divergences[0] if self.divergences else None

    def as_dict(self) -> dict[str, Any]:
        return {
            "ticks": self.ticks, "frames_compared": self.frames_compared, "signals_compared": self.signals_compared,
            "divergent_ticks": self.divergent_ticks, "reproduced": self.ticks > 0 and self.divergent_ticks == 0,
            "first_divergence": self.first.as_dict() if self.first else None,
            "divergences": [d.as_dict() for d in self.divergences],
            "node_frames_fed": self.node_frames_fed, "node_frames_rejected": self.node_frames_rejected,
            "final_state": self.final_state, "runs": self.runs,
            "skipped": {"first_sync_tick": self.first_sync_tick, "frames_before_first_sync": self.skipped_frames,
                        "ticks_before_controller_start": self.skipped_ticks},
            "overruns": {"count": self.overruns, "ticks_skipped": self.ticks_jumped},
        }


@dataclass
class Tick:
    number: int
    node_frames: list[Frame]  # before the controller's first frame of the tick: read in the tick
    controller_frames: list[Frame]
    late_frames: list[Frame] = field(default_factory=list)  # after it: read before the next SYNC
    preamble: int = 0  # the first tick: how many of node_frames came before its SYNC


def ticks_of(frames: Iterable[Frame], codec: Codec) -> Iterator[Tick]:
    """The trace cut at its SYNCs; frames before the first SYNC belong to the first tick (the
    first ``preamble`` of its node frames)."""
    sync = codec.spec("SYNC")
    controller = sync.sender
    current: Tick | None = None
    before: list[Frame] = []
    for frame in frames:
        spec = codec.catalog.by_id(frame.arbitration_id) if not frame.is_extended_id else None
        if spec is sync:
            decoded = codec.decode(frame.arbitration_id, frame.data)
            if type(decoded) is not Decoded:
                continue  # a SYNC that fails its check was not acted on by the nodes either
            if current is not None:
                yield current
            current = Tick(decoded.values.tick, before, [], preamble=len(before))
            before = []
        elif current is None:
            before.append(frame)
        elif spec is not None and spec.sender == controller:
            current.controller_frames.append(frame)
        elif current.controller_frames:
            current.late_frames.append(frame)
        else:
            current.node_frames.append(frame)
    if current is not None:
        yield current


def _quantized(codec: Codec, name: str, values: tuple) -> tuple | str:
    """``values`` as they would be on the wire (encoded and decoded), or why they cannot be."""
    spec = codec.spec(name)
    try:
        decoded = codec.decode(spec.frame_id, codec.encode(spec, values, 0))
    except EncodeError as exc:
        return f"unencodable ({exc})"
    return tuple(decoded.values) if type(decoded) is Decoded else f"undecodable ({decoded.detail})"


def _compare(codec: Codec, tick: int, recorded: list[tuple[str, Any]], resim: list[tuple[str, tuple]],
             report: ResimReport) -> list[Divergence]:
    found: list[Divergence] = []
    for i in range(max(len(recorded), len(resim))):
        rec = recorded[i] if i < len(recorded) else None
        new = resim[i] if i < len(resim) else None
        if rec is None or new is None or rec[0] != new[0]:
            found.append(Divergence(tick, (rec or new)[0], None, rec[0] if rec else "(none)", new[0] if new else "(none)"))
            break  # the sequences no longer line up
        report.frames_compared += 1
        spec = codec.spec(rec[0])
        values = _quantized(codec, new[0], new[1])
        if isinstance(values, str):
            found.append(Divergence(tick, rec[0], None, "sent", values))
            continue
        for sig, a, b in zip(spec.signals, rec[1], values):
            report.signals_compared += 1
            if a != b:
                digits = decimals(sig)
                found.append(Divergence(tick, rec[0], sig.name, round(a, digits), round(b, digits), sig.unit))
    return found


def resimulate(frames: Iterable[Frame], controller_cfg: Any, *, codec: Codec, max_delta_counter: int,
               request_walk_tick: int | str | None) -> ResimReport:
    """Feed a fresh :class:`ControllerCore` the recorded node frames and compare (see the module
    doc). ``request_walk_tick``: the tick of the operator's start (in each controller run),
    ``"start"`` for each run's first tick, or None."""
    from controller.core import ControllerCore
    from controller.hardware import ReplayHardware
    from controller.loop import LockstepLoop
    from controller.session import Session

    report = ResimReport()
    session: Session | None = None
    hardware: ReplayHardware | None = None
    last_tick: int | None = None

    def count_fed() -> None:  # a run's frames, as its hardware counted them
        if hardware is not None:
            report.node_frames_fed += hardware.frames_fed
            report.node_frames_rejected += hardware.frames_rejected

    late: list[Frame] = []
    preamble: list[Frame] = []
    for tick in ticks_of(frames, codec):
        k = tick.number
        if report.first_sync_tick is None:
            report.first_sync_tick = k
        first = last_tick is None
        if first and k != 0:  # the recording starts while a controller runs: up to its next start
            report.skipped_frames = tick.preamble
        started = (first and k == 0) or (not first and k < last_tick)  # a controller's start (or restart)
        if started:  # a fresh controller and hardware, as the restarted process
            count_fed()
            hardware = ReplayHardware(controller_cfg, codec=codec, max_delta_counter=max_delta_counter)
            session = Session(LockstepLoop(ControllerCore(controller_cfg, policy=None), hardware, first_tick=k))
            report.runs += 1
            # what came after the last controller's frames, before this SYNC(0): the restarted
            # controller's preamble, as the frames before the recording's first SYNC(0) are
            preamble, late = late, []
        elif session is not None and k > last_tick + 1:  # the real-time loop overran: ticks skipped
            report.overruns += 1
            report.ticks_jumped += k - last_tick - 1
            session.skipped(k, k - last_tick - 1)
        last_tick = k
        if session is None:
            report.skipped_ticks += 1
            late = tick.late_frames  # the next controller start's preamble, if it follows
            continue
        if (request_walk_tick == "start" and started) or (isinstance(request_walk_tick, int) and k == request_walk_tick):
            session.operator.start()
        hardware.feed(late, [*preamble, *tick.node_frames] if started else tick.node_frames)
        result = session.step()
        late = tick.late_frames
        sent = hardware.written
        recorded = []
        for frame in tick.controller_frames:
            decoded = codec.decode(frame.arbitration_id, frame.data)
            recorded.append((decoded.name, tuple(decoded.values)) if type(decoded) is Decoded
                            else (f"0x{frame.arbitration_id:03X} ({decoded.reason.value})", ()))
        found = _compare(codec, k, recorded, sent, report)
        if found:
            report.divergent_ticks += 1
            report.divergences += found[: MAX_LISTED - len(report.divergences)]
        report.ticks += 1
        report.final_state = result.state.name
    count_fed()
    return report


def walked(frames: Iterable[Frame], codec: Codec) -> bool:
    """Whether the recorded controller's heartbeat ever says it walked (the operator started it)."""
    heartbeat = codec.spec("CONTROLLER_HEARTBEAT")
    walking = {int(GaitState.DOUBLE_SUPPORT), int(GaitState.SWING_LEFT), int(GaitState.SWING_RIGHT), int(GaitState.STOP)}
    for frame in frames:
        if frame.arbitration_id == heartbeat.frame_id and not frame.is_extended_id:
            decoded = codec.decode(frame.arbitration_id, frame.data)
            if type(decoded) is Decoded and int(decoded.values[0]) in walking:
                return True
    return False


def format_text(r: dict[str, Any]) -> str:
    lines = [f"resim: {r['ticks']} ticks, {r['frames_compared']} controller frames and {r['signals_compared']} signals "
             f"compared; {r['node_frames_fed']} node frames fed ({r['node_frames_rejected']} rejected by the receiver); "
             f"final state {r['final_state']}"]
    skipped, overruns = r.get("skipped") or {}, r.get("overruns") or {}
    if skipped.get("ticks_before_controller_start"):
        lines.append(f"skipped: the recording starts at tick {skipped['first_sync_tick']} of a running controller: "
                     f"{skipped['frames_before_first_sync']} frame(s) before its first SYNC and "
                     f"{skipped['ticks_before_controller_start']} tick(s) up to the next controller start not re-simulated")
    if r.get("runs", 0) > 1:
        lines.append(f"controller starts: {r['runs']} (each re-simulated by a fresh controller)")
    if overruns.get("count"):
        lines.append(f"overruns: the tick number jumped {overruns['count']} time(s), {overruns['ticks_skipped']} tick(s) "
                     "skipped (told to the controller as its loop did)")
    if r["reproduced"]:
        lines.append("result: reproduced, zero divergence")
    elif r["ticks"] == 0 and skipped.get("ticks_before_controller_start"):
        lines.append("result: nothing to compare (no controller start in the recording: a fresh controller cannot "
                     "take over a running one's state; give the files from the controller's start, SYNC tick 0)")
    elif r["ticks"] == 0:
        lines.append("result: nothing to compare (no SYNC in the trace)")
    else:
        first = Divergence(**r["first_divergence"])
        lines.append(f"result: DIVERGED in {r['divergent_ticks']} of {r['ticks']} ticks; first divergence at {first.text()}")
        lines += [f"  {Divergence(**d).text()}" for d in r["divergences"][1:]]
    return "\n".join(lines) + "\n"
