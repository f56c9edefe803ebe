"""The typed data between the hardware and the controller core (ros2_control's state and command
interfaces): a :class:`Snapshot` is what the hardware read in one tick, :class:`Commands` what
the core asks it to write. Neither names a CAN message, a signal or a counter: the hardware
(:mod:`controller.hardware`) maps them to frames with the DBC.
"""

from __future__ import annotations

from dataclasses import dataclass

from controller.estimator import Measurements
from controller.faults import Fault
from protocol.commands import JointCommand
from protocol.enums import GaitState, PolicyMode


@dataclass(frozen=True, slots=True)
class Snapshot:
    """One tick's view of the exoskeleton: its sensors and the health of its nodes and bus."""

    tick: int
    measurements: Measurements | None  # None until every sensor and joint has reported once
    fresh: bool  # every sensor value and joint status is of this tick
    operational: bool  # every node's NMT state is OPERATIONAL
    oldest_sample_ticks: int  # the age of the oldest sample of the measurements (huge before the first)
    lowest_supply_v: float  # the lowest supply voltage the nodes reported (inf before any)
    quiet_bus: bool  # no error frame within the integrity window (docs/FAULTS.md F11)
    faults: tuple[Fault, ...] = ()  # what the hardware found this tick: lost nodes, EMCY, integrity, ...
    events: tuple[str, ...] = ()  # what the hardware did this tick (the nodes' start)


@dataclass(frozen=True, slots=True)
class StepTelemetry:
    """The newest step, for monitors (no node acts on it)."""

    steps: int
    length_m: float  # the newest step's length
    placed_m: float  # the step before it, as the feet were placed
    cost_n: float  # the newest landed step's mean stick force (paper equation (10))
    policy: PolicyMode


@dataclass(frozen=True, slots=True)
class LearningTelemetry:
    """The compensation's theta and the learner's progress, for monitors."""

    alpha: float
    xhat_com: float
    updates: int = 0
    rollouts_in_batch: int = 0
    cycles: int = 0
    last_cost: float = 0.0


@dataclass(frozen=True, slots=True)
class Commands:
    """What the core asks of the hardware in one tick."""

    state: GaitState  # announced in the controller's heartbeat
    joints: tuple[JointCommand, ...]  # left hip, left knee, right hip, right knee
    reset: bool  # the operator's reset: the nodes clear their faults too
    step: StepTelemetry
    learning: LearningTelemetry
