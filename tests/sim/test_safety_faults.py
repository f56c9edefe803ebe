"""The fault table of docs/FAULTS.md, one case per row that applies (docs/SAFETY.md lists every row).

Each case walks the HHEA through the whole pipeline (controller, CAN frames on the in-process bus,
node boards, simulation; tools/safety/rig.py) to a point of the gait (mid-swing or mid-stance),
injects its fault at the bus (``FaultBus``, layer BW), in the node boards (layer NE) or in the
controller (layer MP) from tick ``t0``, and checks: the tick the controller detected it (the FSM's
entry into HOLD or FAULT) against the row's budget D from ``t0``, the tick from which the four
joint commands on the bus are HOLD against R, the FSM state and cause, exactly one record of the
entry, and the invariants I1-I7 on every tick of the run (tools/safety/oracle.py). Budgets come
from the configuration, not from literals (``controller.safety``).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass

import can
import numpy as np
import pybullet
import pytest

from config import default_config_path, load_config
from controller.faults import FaultKind as K
from protocol.codec import Codec, RejectReason
from protocol.enums import GaitState
from protocol.faultbus import BusFault
from tools.safety.rig import FaultRig

CFG = load_config(default_config_path())
SAFETY = CFG.controller.safety
CATALOG = Codec().catalog
LOST = SAFETY.lost_ticks
NODE_FRAMES = {n: frozenset(m.frame_id for m in CATALOG.sent_by(n)) for n in CATALOG.joint_nodes}
STATUS = {n: CATALOG.message("JOINT_STATUS", n).frame_id for n in CATALOG.joint_nodes}
ALL_NODE_FRAMES = frozenset().union(*NODE_FRAMES.values())


def at(phase: str, seed: int = 3) -> FaultRig:
    """A rig walking, stopped at ``phase``: mid-swing (a few ticks into the first swing) or
    mid-stance (ten ticks into the double support after its landing)."""
    rig = FaultRig(CFG, seed=seed)
    rig.walk_to(GaitState.SWING_RIGHT)
    if phase == "swing":
        rig.run(3)
    else:
        assert rig.run_until(lambda r: r.state == GaitState.DOUBLE_SUPPORT, 300), rig.state
        rig.run(10)
    return rig


def stops_from(rig: FaultRig, t0: int):
    return [s for s in rig.oracle.stops if s.tick >= t0]


def expect_stop(rig: FaultRig, t0: int, state: GaitState, kind: K | None, detect: int, react: int = 1, *,
                subject: str | None = None, detail: str | None = None):
    """Exactly one entry into ``state`` since ``t0``, its fault of ``kind`` (any, for None; about
    ``subject`` and with a ``detail`` matching that regular expression, where given), within
    ``detect`` ticks of ``t0``, and four HOLD commands on the bus within ``react`` ticks of it; no
    invariant broken."""
    stops = stops_from(rig, t0)
    assert len(stops) == 1, stops
    stop = stops[0]
    fault = stop.cause
    assert stop.state == state and kind in (None, fault.kind), stop
    assert subject in (None, fault.subject) and (detail is None or re.fullmatch(detail, fault.detail)), stop
    assert stop.tick - t0 <= detect, (stop, t0)
    assert stop.hold_on_bus_tick is not None and stop.hold_on_bus_tick - stop.tick <= react, stop
    assert rig.state == state
    assert rig.oracle.violations == []
    return stop


#: ticks from mid-stance in which the next step lands: a double support takes 4-7 s (the lean's end
#: varies from seed to seed and with anything that changes the trajectory) and the swing about 1 s
NEXT_LANDING_TICKS = 450


def expect_walking_on(rig: FaultRig, t0: int) -> None:
    """No HOLD or FAULT since ``t0``, a step landed since, and no invariant broken."""
    assert stops_from(rig, t0) == [], stops_from(rig, t0)
    assert any(s.landed and s.end_tick >= t0 for s in rig.core.steps), [(s.index, s.end_tick) for s in rig.core.steps]
    assert rig.oracle.violations == []


def test_the_oracle_flags_a_step_aimed_beyond_the_placement_offset():
    """I3 also bounds the swing's aim (the length plus the foot placement's offset): a step record
    that aims farther, or at NaN, is a violation; the rig's own steps are not."""
    from tools.safety.oracle import Oracle

    with at("swing") as rig:
        assert rig.oracle.violations == [] and rig.core.steps
        step = rig.core.steps[-1]
        assert abs(step.aimed_m - step.length_m) <= CFG.controller.gait.max_aim_offset_m
        result = rig.step()
        for aimed in (step.length_m + CFG.controller.gait.max_aim_offset_m + 0.01, float("nan")):
            step.aimed_m = aimed
            fresh = Oracle(rig.core, rig.hardware)  # one that has not seen the step yet
            fresh.check(result, [])
            assert any("I3" in v and "aimed at" in v for v in fresh.violations), fresh.violations


@dataclass(frozen=True)
class Case:
    row: str
    phase: str
    inject: Callable[[FaultRig, int], None]
    state: GaitState
    kind: K
    detect: int  # D: ticks from t0 (the first faulty tick) to the entry into HOLD or FAULT
    react: int = 1  # R: ticks from the entry to four HOLD commands on the bus
    ticks: int = 20
    subject: str | None = None  # what the fault is about, where the case knows it
    detail: str | None = None  # a regular expression the fault's detail matches

    @property
    def id(self) -> str:
        return f"{self.row}-{self.phase}-{self.kind.name}"


def silence(node: str) -> Callable[[FaultRig, int], None]:
    """Every frame of ``node`` lost from t0 (its board dead; the nodes' process hosts all four)."""
    return lambda rig, t0: rig.inject_bus(BusFault("drop", frame_ids=NODE_FRAMES[node], start_tick=t0, name=f"dead {node}"))


def kill_nodes(rig: FaultRig, t0: int) -> None:
    rig.nodes_running = False


def burst(k: int, node: str = "RIGHT_KNEE") -> Callable[[FaultRig, int], None]:
    return lambda rig, t0: rig.inject_bus(BusFault("drop", frame_ids={STATUS[node]}, start_tick=t0, burst=k, times=1))


def delay(d: int, node: str = "LEFT_HIP") -> Callable[[FaultRig, int], None]:
    return lambda rig, t0: rig.inject_bus(BusFault("delay", frame_ids=NODE_FRAMES[node], start_tick=t0, delay_ticks=d))


def bus_rule(kind: str, ids: frozenset[int], times: int | None = None, **kw) -> Callable[[FaultRig, int], None]:
    return lambda rig, t0: rig.inject_bus(BusFault(kind, frame_ids=ids, start_tick=t0, times=times, **kw))


def node_fault(kind: str, node: str, **values) -> Callable[[FaultRig, int], None]:
    return lambda rig, t0: rig.inject_node(kind, node, start_tick=t0, **values)


def send_failures(rig: FaultRig, t0: int) -> None:
    """Every command and heartbeat send fails for two ticks (the SYNCs go out, so the nodes' frames
    keep coming and the send failures alone are the cause)."""
    ids = frozenset(m.frame_id for m in CATALOG.sent_by("CONTROLLER") if m.name != "SYNC")
    rig.inject_bus(BusFault("send_failure", "tx", frame_ids=ids, start_tick=t0, end_tick=t0 + 2, name="bus-off"))


def overruns(skipped: list[int]) -> Callable[[FaultRig, int], None]:
    """The real-time loop's report of overruns into the next ticks (what RealtimeLoop.step does)."""
    def inject(rig: FaultRig, t0: int) -> None:
        original = rig.loop.step

        def step():
            k = rig.tick + 1
            if k - t0 < len(skipped) and skipped[k - t0]:
                rig.core.overran(k, skipped[k - t0])
            return original()

        rig.loop.step = step
    return inject


FAULT, HOLD = GaitState.FAULT, GaitState.HOLD
CASES = [
    # F1: a node gone (the whole nodes process, or one board): no valid status for lost_ticks ticks.
    Case("F1", "swing", kill_nodes, FAULT, K.NODE_LOST, detect=LOST - 1),
    Case("F1", "stance", kill_nodes, FAULT, K.NODE_LOST, detect=LOST - 1),
    Case("F1", "swing", silence("LEFT_KNEE"), FAULT, K.NODE_LOST, subject="LEFT_KNEE", detect=LOST - 1),
    Case("F1", "stance", silence("RIGHT_HIP"), FAULT, K.NODE_LOST, subject="RIGHT_HIP", detect=LOST - 1),
    # F3: a burst of k >= lost_ticks lost statuses of one node: FAULT at the tick of the 3rd miss, whatever k.
    *[Case("F3", "swing", burst(k), FAULT, K.NODE_LOST, subject="RIGHT_KNEE", detect=LOST - 1) for k in (3, 5, 10)],
    # F4: frames late by d >= lost_ticks ticks count as missing: the node is lost.
    *[Case("F4", "stance", delay(d), FAULT, K.NODE_LOST, subject="LEFT_HIP", detect=LOST - 1) for d in (3, 5)],
    # F6, F7, F8: two damaged, reordered or masqueraded frames within the integrity window.
    Case("F6", "swing", bus_rule("reorder", frozenset({STATUS["LEFT_HIP"], STATUS["RIGHT_HIP"]}), times=2), FAULT,
         K.FRAME_INTEGRITY, detect=2),
    Case("F7", "swing", bus_rule("corrupt", frozenset({STATUS["LEFT_KNEE"]}), times=2), FAULT, K.FRAME_INTEGRITY, detect=1),
    Case("F7", "stance", bus_rule("corrupt", ALL_NODE_FRAMES, times=2, bits=3), FAULT, K.FRAME_INTEGRITY, detect=1),
    Case("F8", "stance", bus_rule("masquerade", frozenset({STATUS["LEFT_HIP"]}), times=2, to_id=STATUS["LEFT_KNEE"]), FAULT,
         K.FRAME_INTEGRITY, detect=1),
    # F9: a frozen application re-sends its last frames: repeated counters, lost after lost_ticks.
    Case("F9", "swing", node_fault("freeze", "RIGHT_HIP"), FAULT, K.NODE_LOST, subject="RIGHT_HIP", detect=LOST - 1),
    # F10: frames of the wrong length count as missing (the F2 path): lost after lost_ticks.
    Case("F10", "stance", bus_rule("truncate", frozenset({STATUS["LEFT_KNEE"]})), FAULT, K.NODE_LOST, subject="LEFT_KNEE", detect=LOST - 1),
    # F12, F13: sends failing (after one retry) in send_failure_ticks ticks in a row.
    Case("F12", "swing", send_failures, FAULT, K.BUS_SEND_FAILED, detect=SAFETY.send_failure_ticks),
    # F14: an encoder stuck while its joint moves. Mid-swing the swing knee moves fast: its setpoint
    # stands stuck_motion_rad beyond the frozen reading within 2 ticks. The stance hip moves slowly
    # and back and forth mid-swing (0.003-0.01 rad a tick): 4 ticks.
    Case("F14", "swing", node_fault("stuck_encoder", "RIGHT_KNEE"), FAULT, K.ENCODER_STUCK, subject="knee_r",
         detect=SAFETY.stuck_ticks + 2),
    Case("F14", "swing", node_fault("stuck_encoder", "LEFT_HIP"), FAULT, K.ENCODER_STUCK, subject="hip_l",
         detect=SAFETY.stuck_ticks + 4),
    # F15: a sensor value out of its range on every frame: the frame is invalid, missing, then lost.
    Case("F15", "stance", node_fault("out_of_range", "LEFT_HIP", message="STICK_LEFT", signal="force_N", value=-500.0), FAULT,
         K.SENSOR_LOST, subject="STICK_LEFT", detect=LOST - 1),
    # F23, F24: a node reboots; a drive faults (its EMCY): FAULT within a tick.
    # (A rebooted node's boot-up heartbeat has counter 0: the receiver takes it as a restart of
    # every counter of that node, whatever the jump, and the boot-up itself is the detection.)
    Case("F23", "swing", node_fault("reboot", "LEFT_KNEE"), FAULT, K.NODE_REBOOTED, subject="LEFT_KNEE", detect=1),
    Case("F24", "stance", node_fault("drive_fault", "RIGHT_KNEE"), FAULT, K.EMCY, subject="RIGHT_KNEE", detail="0x2310", detect=0),
    # F25: overruns reported by the real-time loop: 3 within the window, or one beyond overrun_max_ticks: HOLD.
    Case("F25", "stance", overruns([1, 0, 1, 0, 1]), HOLD, K.OVERRUN, detect=4, react=0),
    Case("F25", "swing", overruns([SAFETY.overrun_max_ticks + 7]), HOLD, K.OVERRUN, detect=0, react=0),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_fault_row(case: Case):
    with at(case.phase) as rig:
        t0 = rig.tick + 1
        case.inject(rig, t0)
        rig.run(case.ticks)
        expect_stop(rig, t0, case.state, case.kind, case.detect, case.react, subject=case.subject, detail=case.detail)


# -- rows whose fault is tolerated -----------------------------------------------------------------


def test_F2_random_loss_is_ridden_out_with_last_values():
    """2 % of the nodes' frames lost at random: single losses use the last value (age 1), no
    step starts on stale data (I2, by the oracle), the walk goes on; a FAULT comes only from a
    message that really lost its last lost_ticks frames in a row (the F1 path)."""
    with at("stance") as rig:
        t0 = rig.tick + 1
        rig.inject_bus(BusFault("drop", frame_ids=ALL_NODE_FRAMES, start_tick=t0, probability=0.02, name="loss"))
        rig.run(400)
        assert rig.bus.injected["loss:drop"] > 50 and rig.hardware.rx.stats.lost > 50
        dropped = {(tick, fid) for tick, kind, fid in rig.bus.log if kind == "drop"}
        for stop in stops_from(rig, t0):
            kind, what = stop.cause.kind, stop.cause.subject
            assert kind in (K.NODE_LOST, K.SENSOR_LOST), stop
            fid = STATUS[what] if kind is K.NODE_LOST else CATALOG.by_name(what).frame_id
            assert all((t, fid) in dropped for t in range(stop.tick - LOST + 1, stop.tick + 1)), stop
        assert any(s.landed and s.end_tick >= t0 for s in rig.core.steps)
        assert rig.oracle.violations == []


@pytest.mark.parametrize("k", [1, 2])
def test_F3_a_short_burst_is_tolerated_and_starts_no_step_on_stale_data(k):
    with at("stance") as rig:
        t0 = rig.tick + 1
        burst(k)(rig, t0)
        rig.run(NEXT_LANDING_TICKS)
        expect_walking_on(rig, t0)


@pytest.mark.parametrize("d", [1, 2])
def test_F4_frames_late_by_one_or_two_ticks_are_old_data_and_start_no_step(d):
    """Frames of one node all late by d < lost_ticks: the controller knows them for the tick they
    were sent for (from their counters), holds on (age <= 2) but starts no step, and never
    applies an old frame after a newer one."""
    with at("stance") as rig:
        t0 = rig.tick + 1
        swings_before = len(rig.core.steps)
        delay(d)(rig, t0)
        rig.run(200)
        assert stops_from(rig, t0) == [] and rig.oracle.violations == []
        assert len(rig.core.steps) == swings_before  # no step on old data
        assert rig.tick - rig.hardware.nodes["LEFT_HIP"].status_tick == d



def _fresh_ticks(rig: FaultRig, ticks: int) -> np.ndarray:
    """Per joint, in how many of ``ticks`` ticks the controller's measured position is nearer the
    nodes' state of that tick than that of the tick before (a swing moves every joint)."""
    fresh = np.zeros(4, dtype=int)
    for _ in range(ticks):
        before = rig.host.plant.reading.joint_position_rad.copy()
        result = rig.step()
        now, measured = rig.host.plant.reading.joint_position_rad, np.array(result.measurements.joint_position_rad)
        fresh += np.abs(measured - now) < np.abs(measured - before)
    return fresh


@pytest.mark.parametrize("late", [("LEFT_KNEE", "RIGHT_HIP", "RIGHT_KNEE"), tuple(CATALOG.joint_nodes)])
def test_F4_nodes_whose_first_answers_came_late_are_not_read_a_tick_old_ever_after(late):
    """As across processes (a tick's read ends once the frames it waits for are in): nodes whose
    per-SYNC frames came a tick late for their first 5 ticks. The controller learns a frame's
    on-time counter from the first one it sees; learnt from a late one, every later answer read
    first in the next tick counted as on time, while the tick's own answers waited for the next
    tick: the controller ran on one-tick-old data of those nodes for the whole walk, with no fault
    and no count (the vcan sandbox's real-time walks: at every stick placement the right stick's
    load came a tick after the left's). Frames already queued when a tick's SYNC goes out answer an
    earlier SYNC, and say so: the swing's measurements are each tick's own."""
    with FaultRig(CFG, seed=3, answering=True) as rig:
        ids = frozenset().union(*(rig.hardware.per_sync[n] for n in late))  # the frames the loop waits for
        rig.inject_bus(BusFault("delay", frame_ids=ids, start_tick=-1, end_tick=5))
        rig.walk_to(GaitState.SWING_RIGHT)
        fresh = _fresh_ticks(rig, 20)
        assert rig.state == GaitState.SWING_RIGHT and rig.oracle.violations == []
    assert fresh.min() >= 17, f"ticks of 20 in which each joint's measurement was that tick's: {fresh.tolist()}"
def test_F5_duplicates_are_discarded_and_the_walk_goes_on():
    with at("stance") as rig:
        t0 = rig.tick + 1
        rig.inject_bus(BusFault("duplicate", frame_ids=ALL_NODE_FRAMES, start_tick=t0, end_tick=t0 + 300))
        rig.run(NEXT_LANDING_TICKS)
        assert rig.hardware.rx.stats.rejected[RejectReason.REPEATED] > 1000
        expect_walking_on(rig, t0)


@pytest.mark.parametrize("kind", ["reorder", "corrupt"])
def test_F6_F7_a_single_bad_frame_is_discarded_without_a_fault(kind):
    with at("swing") as rig:
        t0 = rig.tick + 1
        rig.inject_bus(BusFault(kind, frame_ids={STATUS["LEFT_HIP"]}, start_tick=t0, times=1))
        rig.run(NEXT_LANDING_TICKS)
        assert rig.hardware.rx.stats.rejected_total == 1
        expect_walking_on(rig, t0)


def test_F10_foreign_frames_are_counted_and_ignored():
    """Unknown IDs, extended and remote frames, random payloads on other IDs: all counted, none
    reaches the controller, the walk goes on."""
    with at("stance") as rig:
        t0 = rig.tick + 1
        rng = np.random.default_rng(5)
        ours = {m.frame_id for m in CATALOG.messages}
        foreign = [i for i in range(0x800) if i not in ours]
        with rig.foreign() as intruder:
            for _ in range(300):
                for _ in range(5):
                    n = int(rng.integers(0, 9))
                    intruder.send(can.Message(arbitration_id=int(rng.choice(foreign)), data=rng.bytes(n), is_extended_id=False))
                intruder.send(can.Message(arbitration_id=int(rng.integers(0, 2**29)), data=rng.bytes(8), is_extended_id=True))
                rig.step()
        assert rig.hardware.rx.stats.rejected_total >= 1800
        expect_walking_on(rig, t0)


def test_F11_an_error_frame_lets_no_step_start_within_the_window():
    with at("stance") as rig:
        window = SAFETY.integrity_window_ticks
        starts = []
        for _ in range(400):  # an error frame every 2 windows
            if rig.tick % (2 * window) == 0:
                rig.inject_bus(BusFault("error_frame", start_tick=rig.tick + 1, times=1, burst=3))
            rig.step()
            if rig.results[-1].landed is None and rig.core.steps and rig.core.steps[-1].swing_tick == rig.tick:
                starts.append(rig.tick)
        assert starts, "no step started at all"
        assert all((t - 1) % (2 * window) >= window for t in starts), starts  # error frames come at ticks 1 mod 2w
        assert stops_from(rig, 0) == [] and rig.oracle.violations == []


def test_F13_a_send_failing_once_is_retried_within_the_tick():
    with at("swing") as rig:
        t0 = rig.tick + 1
        rig.inject_bus(BusFault("send_failure", "tx", start_tick=t0, times=3, name="enobufs"))
        rig.run(200)
        assert rig.hardware.counters.send_failures == 3  # each retried once, successfully
        expect_walking_on(rig, t0)


def test_F25_one_overrun_is_only_counted():
    with at("stance") as rig:
        t0 = rig.tick + 1
        overruns([1])(rig, t0)
        rig.run(NEXT_LANDING_TICKS)
        expect_walking_on(rig, t0)


def test_F25_overruns_before_the_nodes_are_up_are_not_budgeted():
    """In INIT nothing is commanded and a process's first ticks are its slowest: overruns there,
    even one far beyond the budget, are the loop's statistics only, not a protective stop."""
    from controller.cansystem import CanSystem
    from controller.core import ControllerCore

    core = ControllerCore(CFG.controller)
    for k in (1, 2, 3):
        core.overran(k, SAFETY.overrun_max_ticks + 7)
    assert core.update(CanSystem(CFG.controller).snapshot(4)).state == GaitState.INIT  # no node heard yet


# -- rows checked at the controller (layer MP) ------------------------------------------------------


def test_F14_a_knee_reading_held_at_a_swing_start_is_no_fault_until_the_setpoint_leaves_it():
    """A loaded knee keeps its reading for the first ticks of a swing while its setpoint closes the
    gap the load held it at (real time: up to 4 ticks, once 5 in CI, ENCODER_STUCK of a sound knee
    under the rule that counted a moving setpoint). Held 7 ticks from the swing's start the walk
    goes on; held for good it is ENCODER_STUCK within ``stuck_ticks`` ticks of the knee's setpoint
    on the bus leaving the frozen reading by ``stuck_motion_rad`` more than the gap it froze at."""
    with FaultRig(CFG, seed=3) as rig:
        rig.walk_to(GaitState.SWING_RIGHT)
        t0 = rig.tick
        rig.inject_node("stuck_encoder", "RIGHT_KNEE", start_tick=t0, end_tick=t0 + 7)
        rig.run(NEXT_LANDING_TICKS)
        expect_walking_on(rig, t0)
    with FaultRig(CFG, seed=3) as rig:
        rig.walk_to(GaitState.SWING_RIGHT)
        t0 = rig.tick
        rig.inject_node("stuck_encoder", "RIGHT_KNEE", start_tick=t0, end_tick=None)
        sent = [result.commands.joints[3].position_rad for result in rig.run(2 * SAFETY.stuck_ticks + 10)]  # the right knee's, from t0 + 1
        frozen = rig.host.ports["RIGHT_KNEE"].stuck_position
        away = [abs(q - frozen) - abs(sent[0] - frozen) for q in sent]
        left = next((t0 + 1 + i for i, d in enumerate(away) if d >= SAFETY.stuck_motion_rad), None)  # the setpoint left it
        assert left is not None
        expect_stop(rig, t0, FAULT, K.ENCODER_STUCK, detect=left - t0 + SAFETY.stuck_ticks, subject="knee_r")


def test_F16_a_measured_joint_beyond_its_limit_is_a_fault():
    """A joint encoder reading beyond the joint's range by more than the envelope's allowance
    (a valid frame, the value in the DBC's range): FAULT. (Commands beyond: test_controller_envelope.)"""
    with at("stance") as rig:
        t0 = rig.tick + 1
        excess = CFG.controller.envelope.position_excess_rad
        rig.inject_node("stuck_encoder", "LEFT_KNEE", start_tick=t0)  # then its reading is forced beyond the limit
        port = rig.host.ports["LEFT_KNEE"]
        original = rig.host._report

        def report(tick):
            if tick >= t0:
                port.stuck_position = CFG.hardware.joints.knee.upper_rad + 2 * excess
            original(tick)

        rig.host._report = report
        rig.run(10)
        expect_stop(rig, t0, FAULT, K.JOINT_LIMIT, detect=0, subject="LEFT_KNEE")


def test_F17_a_setpoint_jump_is_clamped_on_the_bus_and_faults():
    with at("swing") as rig:
        t0 = rig.tick + 1
        gait = rig.core.gait
        original = gait.swing

        def swing(est, m):
            out = original(est, m)
            if rig.tick == t0:
                gait.targets[1] += 3 * CFG.controller.envelope.max_step_rad
            return out

        gait.swing = swing
        rig.run(10)
        expect_stop(rig, t0, FAULT, K.ENVELOPE, detect=1, detail=r"knee_l: setpoint step .*")  # I1 held on the bus (oracle)


def test_F19_a_stick_unloaded_in_a_swing_holds_once_the_swing_has_landed():
    """The left stick's force reads 0 N from early in a swing on (a slipped or lifted crutch): the
    swing goes on to its landing, and the tick after the landing is a HOLD (no step starts on one
    stick anyway, I2, checked by the oracle)."""
    with at("swing") as rig:
        t0 = rig.tick + 1
        rig.inject_node("sensor_value", "LEFT_HIP", start_tick=t0, message="STICK_LEFT", signal="force_N", value=0.0)
        assert rig.run_until(lambda r: r.state not in (GaitState.SWING_LEFT, GaitState.SWING_RIGHT), 200)
        step = rig.core.steps[-1]
        assert rig.state == GaitState.DOUBLE_SUPPORT and step.landed, (rig.state, step)
        assert step.end_tick - t0 > SAFETY.stick_unloaded_ticks  # detected mid-swing, acted on after the landing
        rig.run(10)
        stop = expect_stop(rig, t0, HOLD, K.STICK_UNLOADED, detect=200, react=0, subject="left stick",
                           detail="below 2 N for 10 ticks in the swing")
        assert stop.tick == step.end_tick + 1


def test_F19_a_stick_unloaded_for_less_than_the_budget_in_a_swing_is_tolerated():
    """Healthy swings unload a stick for up to 6 ticks (docs/SAFETY.md); one unloaded for
    ``stick_unloaded_ticks`` - 1 ticks is not a slip."""
    with at("swing") as rig:
        t0 = rig.tick + 1
        rig.inject_node("sensor_value", "LEFT_HIP", start_tick=t0, end_tick=t0 + SAFETY.stick_unloaded_ticks - 1,
                        message="STICK_LEFT", signal="force_N", value=0.0)
        assert rig.run_until(lambda r: r.state == GaitState.SWING_LEFT, 600), rig.state  # the next step starts
        expect_walking_on(rig, t0)


def supply_ramp(rig: FaultRig, t0: int, volts_per_s: float = 20.0) -> None:
    """The battery runs down: every node reports its supply falling by ``volts_per_s`` from t0."""
    for node in CATALOG.joint_nodes:
        rig.inject_node("supply_ramp", node, start_tick=t0, value=volts_per_s)


def test_F29_a_critical_supply_warns_then_holds_in_double_support_and_no_step_starts_again():
    with at("stance") as rig:
        t0 = rig.tick + 1
        supply_ramp(rig, t0)
        events = [e for r in rig.run(60) for e in r.events]
        stop = expect_stop(rig, t0, HOLD, K.SUPPLY_CRITICAL, detect=25, react=0, detail=r"\d+\.\d+ V below 21 V for 5 ticks")
        warning = [e for e in events if e.startswith("SUPPLY_LOW")]
        assert len(warning) == 1 and "below 22 V for 25 ticks): warning" in warning[0], events
        # The operator resets and starts again: the controller stands, then holds again at once.
        rig.operator.reset()
        assert rig.run_until(lambda r: r.state == GaitState.STAND, 100), rig.state
        steps = len(rig.core.steps)
        rig.operator.start()
        rig.run(20)
        assert rig.state == HOLD and len(rig.core.steps) == steps
        assert [s.cause.kind for s in stops_from(rig, t0)] == [K.SUPPLY_CRITICAL, K.SUPPLY_CRITICAL]
        assert rig.oracle.violations == [] and stop.tick > t0


def test_F29_a_supply_critical_in_a_swing_holds_once_the_swing_has_landed():
    with at("swing") as rig:
        t0 = rig.tick + 1
        supply_ramp(rig, t0, volts_per_s=40.0)
        assert rig.run_until(lambda r: r.state not in (GaitState.SWING_LEFT, GaitState.SWING_RIGHT), 200)
        step = rig.core.steps[-1]
        assert rig.state == GaitState.DOUBLE_SUPPORT and step.landed, (rig.state, step)
        rig.run(5)
        stop = expect_stop(rig, t0, HOLD, K.SUPPLY_CRITICAL, detect=200, react=0)
        assert stop.tick == step.end_tick + 1


def test_F29_a_low_supply_above_critical_only_warns():
    """One node reports 21.5 V (below the warning, above the critical level): a warning, and the
    walk goes on."""
    with at("stance") as rig:
        t0 = rig.tick + 1
        rig.inject_node("sensor_value", "LEFT_HIP", start_tick=t0, message="HEARTBEAT_LH", signal="supply_voltage_V", value=21.5)
        events = [e for r in rig.run(400) for e in r.events]
        assert [e for e in events if e.startswith("SUPPLY")] == ["SUPPLY_LOW(21.50 V below 22 V for 25 ticks): warning"]
        expect_walking_on(rig, t0)


def test_F18_a_push_that_topples_the_hhea_is_a_fall():
    """A 600 N backward push on the trunk for 0.3 s in double support: the HHEA falls; the trunk's
    tilt beyond fall_tilt_rad for fall_ticks ticks is a FALL, FAULT, and the roll-out ends."""
    with at("stance") as rig:
        world = rig.host.plant.world
        step = world.step
        pushing = {"steps": int(0.3 / world.dt)}

        def pushed(n: int = 1):  # an external force acts for one physics step: apply it before each
            for _ in range(n):
                if pushing["steps"] > 0:
                    world.client.applyExternalForce(world.robot, -1, [-600.0, 0.0, 0.0], [0.0, 0.0, 0.2], pybullet.LINK_FRAME)
                    pushing["steps"] -= 1
                step()

        world.step = pushed
        t0 = rig.tick + 1
        rig.run(150)
        expect_stop(rig, t0, FAULT, K.FALL, detect=150)
        assert rig.host.plant.patient.fall is not None  # the simulation's ground truth agrees


def test_F26_a_wall_clock_jump_changes_nothing(monkeypatch):
    """The loop runs on the monotonic clock: the same walk with time.time jumping by an hour
    either way goes through the same states."""
    def states(jump: float) -> list[GaitState]:
        if jump:
            real = time.time
            calls = {"n": 0}

            def jumping() -> float:
                calls["n"] += 1
                return real() + (jump if calls["n"] % 2 else -jump)

            monkeypatch.setattr(time, "time", jumping)
        with FaultRig(CFG, seed=3) as rig:
            rig.operator.start()
            rig.run(200)
            out = [r.state for r in rig.results]
        monkeypatch.undo()
        return out

    assert states(3600.0) == states(0.0)


def test_F31_simultaneous_faults_make_one_fault_record_with_every_cause():
    """A drive fault and a lost node in the same tick: one FAULT record, both causes kept."""
    with at("swing") as rig:
        t0 = rig.tick + 1
        silence("RIGHT_KNEE")(rig, t0)  # lost at t0 + lost_ticks - 1 ...
        rig.inject_node("drive_fault", "LEFT_HIP", start_tick=t0 + LOST - 1)  # ... with this drive fault
        rig.run(10)
        stop = expect_stop(rig, t0, FAULT, None, detect=LOST - 1)
        causes = rig.core.fsm.fault_causes
        assert {c.subject for c in causes} >= {"LEFT_HIP", "RIGHT_KNEE"}, causes
        assert stop.cause == causes[0]
