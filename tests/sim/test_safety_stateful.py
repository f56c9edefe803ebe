"""A Hypothesis state machine over the whole pipeline (docs/FAULTS.md section 5): its rules advance ticks,
inject and clear faults at the bus and in the node boards, reset, start and stop the gait, in any
order; the invariants I1-I7 (tools/safety/oracle.py) are checked on every tick, and Hypothesis
shrinks a failing sequence to a short one."""

from __future__ import annotations

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from config import default_config_path, load_config
from protocol.codec import Codec
from protocol.enums import GaitState
from protocol.faultbus import BusFault
from tools.safety.rig import FaultRig

CFG = load_config(default_config_path())
CATALOG = Codec().catalog
NODES = CATALOG.joint_nodes
NODE_FRAMES = {n: frozenset(m.frame_id for m in CATALOG.sent_by(n)) for n in NODES}
CONTROLLER_FRAMES = frozenset(m.frame_id for m in CATALOG.sent_by("CONTROLLER"))
RX_KINDS = ("drop", "delay", "duplicate", "reorder", "corrupt", "truncate", "error_frame")
NODE_KINDS = ("freeze", "drive_fault", "reboot", "stuck_encoder")


class Pipeline(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.rig = FaultRig(CFG, seed=7, tick_timeout_s=0.005)
        self.rig.walk_to(GaitState.SWING_RIGHT)  # every sequence starts in the first swing

    def teardown(self) -> None:
        self.rig.close()

    @rule(ticks=st.integers(1, 60))
    def advance(self, ticks: int) -> None:
        self.rig.run(ticks)

    @rule(kind=st.sampled_from(RX_KINDS), node=st.sampled_from(NODES), ticks=st.integers(1, 8),
          probability=st.sampled_from([1.0, 0.5, 0.1]), delay=st.integers(1, 5))
    def bus_fault(self, kind: str, node: str, ticks: int, probability: float, delay: int) -> None:
        t0 = self.rig.tick + 1
        self.rig.inject_bus(BusFault(kind, frame_ids=NODE_FRAMES[node], start_tick=t0, end_tick=t0 + ticks,
                                     probability=probability, delay_ticks=delay))

    @rule(ticks=st.integers(1, 4))
    def send_failures(self, ticks: int) -> None:
        t0 = self.rig.tick + 1
        self.rig.inject_bus(BusFault("send_failure", "tx", frame_ids=CONTROLLER_FRAMES, start_tick=t0, end_tick=t0 + ticks))

    @rule(kind=st.sampled_from(NODE_KINDS), node=st.sampled_from(NODES), ticks=st.integers(1, 10))
    def node_fault(self, kind: str, node: str, ticks: int) -> None:
        t0 = self.rig.tick + 1
        self.rig.inject_node(kind, node, start_tick=t0, end_tick=t0 + ticks)

    @rule()
    def clear_bus_faults(self) -> None:
        self.rig.bus.clear()

    @rule()
    def reset(self) -> None:
        self.rig.operator.reset()

    @rule()
    def start(self) -> None:
        self.rig.operator.start()

    @precondition(lambda self: self.rig.state != GaitState.INIT)
    @rule()
    def stop(self) -> None:
        self.rig.operator.stop()

    @invariant()
    def invariants_hold(self) -> None:
        assert self.rig.oracle.violations == [], self.rig.oracle.violations[:5]


Pipeline.TestCase.settings = settings(
    max_examples=40, stateful_step_count=30, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
test_pipeline_under_any_fault_sequence_keeps_the_invariants = Pipeline.TestCase
