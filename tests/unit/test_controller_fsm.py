"""The gait-phase state machine: the walk cycle, stops, HOLD and FAULT, and its invariants."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st

from controller.faults import Fault, FaultKind
from controller.fsm import FsmInputs, GaitFsm
from protocol.enums import SWINGS, WALKING
from protocol.enums import GaitState as G

HEALTHY = FsmInputs(nodes_operational=True, nodes_healthy=True, data_fresh=True)
READY = replace(HEALTHY, sticks_loaded=True, sticks_ahead=True)
OVERRUN = Fault(FaultKind.OVERRUN, detail="3 in 50 ticks")


def run(fsm: GaitFsm, *inputs: FsmInputs, start: int = 0) -> list[G]:
    return [fsm.step(start + k, i) for k, i in enumerate(inputs)]


def test_the_walk_cycle_alternates_swings_through_double_support():
    fsm = GaitFsm()
    assert run(fsm, FsmInputs(), HEALTHY) == [G.INIT, G.STAND]
    assert run(fsm, replace(HEALTHY, start=True), HEALTHY) == [G.DOUBLE_SUPPORT, G.DOUBLE_SUPPORT]
    seen = run(
        fsm, READY, READY, replace(READY, swing_done=True), HEALTHY, READY, replace(HEALTHY, swing_done=True), READY,
    )
    assert seen == [G.SWING_RIGHT, G.SWING_RIGHT, G.DOUBLE_SUPPORT, G.DOUBLE_SUPPORT, G.SWING_LEFT, G.DOUBLE_SUPPORT, G.SWING_RIGHT]


def test_no_step_without_both_sticks_loaded_and_ahead_and_fresh_data():
    fsm = GaitFsm(state=G.DOUBLE_SUPPORT)
    for inputs in (HEALTHY, replace(READY, sticks_loaded=False), replace(READY, sticks_ahead=False), replace(READY, data_fresh=False)):
        assert fsm.step(0, inputs) == G.DOUBLE_SUPPORT


def test_a_stop_in_swing_waits_for_the_foot_to_land():
    fsm = GaitFsm(state=G.DOUBLE_SUPPORT)
    assert run(fsm, READY, replace(READY, stop=True), READY, replace(READY, swing_done=True)) == [
        G.SWING_RIGHT, G.SWING_RIGHT, G.SWING_RIGHT, G.STOP,
    ]
    assert run(fsm, READY, replace(READY, start=True), READY) == [G.STOP, G.DOUBLE_SUPPORT, G.SWING_LEFT]


def test_fault_latches_from_any_state_and_needs_a_reset_with_its_preconditions():
    fsm = GaitFsm(state=G.SWING_LEFT, reset_healthy_ticks=25)
    lost, crc = Fault(FaultKind.NODE_LOST, "RIGHT_HIP"), Fault(FaultKind.FRAME_INTEGRITY, detail="2 in 5 ticks: CRC")
    assert fsm.step(10, replace(READY, fault=lost)) == G.FAULT
    fsm.step(11, replace(READY, fault=crc))
    assert fsm.fault_causes == (lost, crc)
    assert [t.cause for t in fsm.transitions] == [lost]  # one record
    assert str(lost) == "NODE_LOST(RIGHT_HIP)" and str(crc) == "FRAME_INTEGRITY(2 in 5 ticks: CRC)"
    # Healthy again, but a reset needs 25 healthy ticks and both sticks loaded.
    states = run(fsm, *[READY] * 10, replace(READY, reset=True), start=12)
    assert set(states) == {G.FAULT}
    states = run(fsm, *[READY] * 14, replace(HEALTHY, reset=True), replace(READY, reset=True), start=23)
    assert states[-2:] == [G.FAULT, G.STAND]
    assert not any(s in SWINGS or s == G.DOUBLE_SUPPORT for s in states)  # never resumes walking by itself


def test_protective_stop_holds_until_reset_and_a_fault_overrides_it():
    fsm = GaitFsm(state=G.DOUBLE_SUPPORT)
    assert fsm.step(0, replace(READY, protective_stop=OVERRUN)) == G.HOLD
    assert fsm.step(1, READY) == G.HOLD
    assert fsm.step(2, replace(READY, reset=True)) == G.STAND
    fsm = GaitFsm(state=G.STAND)
    assert fsm.step(0, replace(READY, protective_stop=OVERRUN, fault=Fault(FaultKind.NODE_LOST, "LEFT_HIP"))) == G.FAULT


def test_unhealthy_nodes_stop_the_gait():
    fsm = GaitFsm(state=G.SWING_RIGHT)
    assert fsm.step(0, replace(READY, nodes_healthy=False)) == G.HOLD


inputs = st.builds(
    FsmInputs,
    nodes_operational=st.booleans(),
    nodes_healthy=st.booleans(),
    data_fresh=st.booleans(),
    sticks_loaded=st.booleans(),
    sticks_ahead=st.booleans(),
    swing_done=st.booleans(),
    fault=st.sampled_from([None] * 8 + [Fault(FaultKind.NODE_LOST, "RIGHT_KNEE"), Fault(FaultKind.FALL, detail="trunk tilt 0.6 rad")]),
    protective_stop=st.sampled_from([None] * 8 + [OVERRUN]),
    start=st.booleans(),
    stop=st.booleans(),
    reset=st.booleans(),
)


@given(st.lists(inputs, min_size=1, max_size=80), st.sampled_from(list(G)))
@settings(max_examples=300)
def test_invariants_hold_for_any_input_sequence(sequence, initial):
    fsm = GaitFsm(state=initial, reset_healthy_ticks=3)
    healthy_run = 0
    for tick, i in enumerate(sequence):
        before, n_records = fsm.state, len(fsm.transitions)
        healthy_run = healthy_run + 1 if i.nodes_healthy else 0
        after = fsm.step(tick, i)
        if i.fault is not None:
            assert after == G.FAULT  # detected faults latch in the same tick
        if after in SWINGS and before not in SWINGS:  # I2: a step starts only when everything is right
            assert before == G.DOUBLE_SUPPORT and i.sticks_loaded and i.sticks_ahead and i.nodes_healthy and i.data_fresh
            assert not i.stop and i.protective_stop is None
        if before == G.FAULT and after != G.FAULT:  # I4: no automatic resume
            assert after == G.STAND and i.reset and healthy_run >= 3 and i.sticks_loaded
        if after != before:  # I6: one record per change, naming it
            assert len(fsm.transitions) == n_records + 1
            assert (fsm.transitions[-1].source, fsm.transitions[-1].target) == (before, after)
            if after in (G.HOLD, G.FAULT):  # its cause a fault of the kind that reacts so
                fault = fsm.transitions[-1].fault
                assert fault is not None and fault.kind.reaction.value == after.name
        else:
            assert len(fsm.transitions) == n_records
        assert fsm.moving == (after in WALKING)
