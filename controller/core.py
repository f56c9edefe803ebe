"""The main controller's tick logic at the level of decoded frames, without I/O.

:class:`ControllerCore` takes the frames the nodes sent in a tick (already decoded and E2E-checked
by :class:`protocol.e2e.Receiver`) and returns the frames the controller sends: SYNC at the start
of the tick, then the four joint commands (applied by the nodes at the next SYNC), the
controller's heartbeat with the gait state, and NMT commands. In between it runs the node
supervision (boot-up, NMT state, drive faults, EMCY, lost nodes), the state estimator on the
sensor frames of the tick, and the gait FSM.

What it does today (issue 6, first part): bring the nodes up (NMT start once all four have
booted), supervise them, estimate the state every tick, and hold the legs (HOLD commands) in every
state; FAULT latches on a lost node (no status for ``lost_ticks`` ticks), a drive fault or a fault
EMCY, and a node that reboots; an operator reset leaves it as the FSM allows. The walking states
(the DMP swing and the stance legs) are not wired yet: the FSM is never asked to start walking.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from config.controller_schema import ControllerConfig
from controller.envelope import Envelope, JointBounds, JointCommand
from controller.estimator import Estimate, Measurements, StateEstimator
from controller.fsm import FsmInputs, GaitFsm
from protocol.catalog import Catalog, default_catalog
from protocol.codec import Decoded
from protocol.enums import DriveState, GaitState, JointMode, NmtCommand, NmtState

SENSOR_MESSAGES = (
    "STICK_LEFT", "STICK_RIGHT", "PLANTAR_LEFT", "PLANTAR_RIGHT", "TRUNK_IMU_ORIENTATION", "TRUNK_IMU_RATE",
)


@dataclass
class NodeState:
    nmt: NmtState | None = None  # from its heartbeat (None: never heard)
    status: Any = None  # the newest JOINT_STATUS values
    status_tick: int = -1  # the tick it arrived in
    operational_since: int = -1  # the tick its heartbeat first said OPERATIONAL (-1: never)

    @property
    def was_operational(self) -> bool:
        return self.operational_since >= 0


@dataclass
class TickResult:
    tick: int
    state: GaitState
    frames: list[tuple[str, tuple]]  # (message name, values in signal order) to send after the tick's work
    # (the controller's heartbeat with ``state`` is the loop's, on the DBC's schedule)
    estimate: Estimate | None
    events: list[str] = field(default_factory=list)


class ControllerCore:
    def __init__(
        self, cfg: ControllerConfig, *, catalog: Catalog | None = None, lost_ticks: int = 3, hold_torque_nm: float = 80.0
    ) -> None:
        self.cfg = cfg
        catalog = catalog or default_catalog()
        self.node_names = catalog.joint_nodes  # left hip, left knee, right hip, right knee
        self._command_of = {n: catalog.message("JOINT_COMMAND", n).name for n in self.node_names}
        self.fsm = GaitFsm()
        self.estimator = StateEstimator(cfg.body, cfg.legs)
        legs = cfg.legs
        joints = tuple(
            JointBounds(f"{kind}_{side}", lo, hi)
            for side in ("l", "r")
            for kind, lo, hi in (("hip", legs.hip_min_rad, legs.hip_max_rad), ("knee", legs.knee_min_rad, legs.knee_max_rad))
        )
        self.envelope = Envelope.from_config(joints, cfg.envelope)
        self.joint_names = [j.name for j in joints]
        self.lost_ticks = lost_ticks
        self.hold_torque_nm = hold_torque_nm
        self.nodes = {n: NodeState() for n in self.node_names}
        self.latest: dict[str, tuple[int, Any]] = {}  # sensor message -> (tick, values)
        self.started = False
        self.pending_faults: list[str] = []
        self.reset_requested = False
        self.measurements: Measurements | None = None  # of the last tick

    # -- input -----------------------------------------------------------------------------------

    def receive(self, frame: Decoded, tick: int) -> None:
        """One accepted frame from a node, received during ``tick``."""
        spec, v = frame.message, frame.values
        family, sender = spec.family, spec.sender
        if family == "JOINT_STATUS":
            node = self.nodes[sender]
            node.status, node.status_tick = v, tick
        elif family == "HEARTBEAT":
            node = self.nodes[sender]
            state = NmtState(v.nmt_state)
            if state == NmtState.BOOT_UP:
                if node.was_operational:
                    self.pending_faults.append(f"NODE_REBOOTED({sender})")
            elif node.was_operational and state != NmtState.OPERATIONAL:
                self.pending_faults.append(f"NODE_NOT_OPERATIONAL({sender})")
            node.nmt = state
            if state == NmtState.OPERATIONAL and not node.was_operational:
                node.operational_since = tick
        elif family == "EMCY":
            if v.error_register != 0:
                self.pending_faults.append(f"EMCY {v.emcy_code:#06x} from {sender}")
        else:
            self.latest[spec.name] = (tick, v)

    def request_reset(self) -> None:
        """The operator's reset of HOLD or FAULT (sent to the nodes as FAULT_RESET too)."""
        self.reset_requested = True

    # -- the tick --------------------------------------------------------------------------------

    def _measurements(self, tick: int) -> tuple[Measurements | None, bool]:
        """The tick's sensor values, and whether every one of them is from this tick."""
        if any(n not in self.latest for n in SENSOR_MESSAGES) or any(s.status is None for s in self.nodes.values()):
            return None, False
        fresh = all(self.latest[n][0] == tick for n in SENSOR_MESSAGES) and all(s.status_tick == tick for s in self.nodes.values())
        v = {n: self.latest[n][1] for n in SENSOR_MESSAGES}
        q = np.array([s.status.position_rad for s in self.nodes.values()])
        stick = [v["STICK_LEFT"], v["STICK_RIGHT"]]
        plantar = [v["PLANTAR_LEFT"], v["PLANTAR_RIGHT"]]
        o = v["TRUNK_IMU_ORIENTATION"]
        return Measurements(
            joint_position_rad=q,
            trunk_rpy_rad=np.array([o.roll_rad, o.pitch_rad, o.yaw_rad]),
            stick_rpy_rad=np.array([[s.roll_rad, s.pitch_rad, s.yaw_rad] for s in stick]),
            stick_force_n=np.array([s.force_N for s in stick]),
            heel_force_n=np.array([p.heel_force_N for p in plantar]),
            toe_force_n=np.array([p.toe_force_N for p in plantar]),
        ), fresh

    def tick(self, tick: int) -> TickResult:
        """The work of ``tick`` after its node frames are in; returns what to send."""
        frames: list[tuple[str, tuple]] = []
        events: list[str] = []
        if not self.started and all(n.nmt is not None for n in self.nodes.values()):  # all booted or heard
            frames.append(("NMT_COMMAND", (int(NmtCommand.START), 0)))
            self.started = True
            events.append("NMT start")
        operational = all(n.nmt == NmtState.OPERATIONAL for n in self.nodes.values())
        ages = [tick - n.status_tick if n.status is not None else 10**9 for n in self.nodes.values()]
        for name, node in self.nodes.items():
            if node.was_operational and tick - max(node.status_tick, node.operational_since) >= self.lost_ticks:
                self.pending_faults.append(f"NODE_LOST({name})")
            if node.status is not None and node.status.drive_state == DriveState.FAULT and node.status_tick == tick:
                self.pending_faults.append(f"DRIVE_FAULT({name}: error {node.status.error_code})")
        healthy = operational and max(ages) <= 2 and not self.pending_faults
        measurements, fresh = self._measurements(tick)
        self.measurements = measurements
        estimate = self.estimator.update(measurements) if measurements is not None else None
        inputs = FsmInputs(
            nodes_operational=operational,
            nodes_healthy=healthy,
            data_fresh=fresh,
            sticks_loaded=bool(estimate and all(estimate.sticks_loaded)),
            sticks_ahead=False,
            fault=self.pending_faults[0] if self.pending_faults else None,
            reset=self.reset_requested,
        )
        before = len(self.fsm.transitions)
        state = self.fsm.step(tick, inputs)
        events += [f"{t.source.name} -> {t.target.name}: {t.cause}" for t in self.fsm.transitions[before:]]
        if self.reset_requested:
            frames.append(("NMT_COMMAND", (int(NmtCommand.FAULT_RESET), 0)))
            self.reset_requested = False
        self.pending_faults.clear()
        # Commands: hold every joint (the walking states are not wired yet), through the envelope.
        for name, joint in zip(self.node_names, self.joint_names):
            checked = self.envelope.check(joint, JointCommand(JointMode.HOLD, torque_limit_nm=self.hold_torque_nm), 0.0)
            c = checked.command
            frames.append((self._command_of[name], (int(c.mode), 0.0, 0.0, 0.0, float(round(c.torque_limit_nm)))))
        return TickResult(tick, state, frames, estimate, events)
