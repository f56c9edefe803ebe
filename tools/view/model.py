"""What the live view shows, from the frames on the bus alone (no I/O here).

:class:`ViewModel` takes every frame a passive listener sees, decodes and checks it with the
project's one receive path (:class:`protocol.e2e.Receiver`: CRC, alive counter, length, ranges,
each rejection counted by reason), and keeps what the page draws:

* the controller's gait state (its heartbeat), the steps and gait cycles counted from the swings
  it announced, and each landed step's length as the feet were placed (the estimator's ankles);
* the controller's telemetry frames: the step's index and commanded length, the step before it as
  the controller saw it placed, the last step's cost, where step lengths come from, theta, and the
  learner's update, roll-out and gait cycle with the costs of the last gait cycles;
* once per tick (at the next SYNC, when the tick's frames are in) the controller's own
  :class:`~controller.estimator.StateEstimator` on the tick's sensor frames: CoM, ankles, stick
  tips, the support polygon and X_CoM/X_SP, as the controller computes them;
* the swing foot's commanded path (the estimator's forward kinematics of the JOINT_COMMAND
  setpoints) beside its measured one;
* rolling per-tick series (stick forces, heel and toe loads, the four joints commanded and
  measured, X_CoM/X_SP) of the last ``history_s`` of bus time, each sample numbered so a client
  gets only what it has not seen;
* node health: NMT state and heartbeat age, supply, drive state and error code, EMCY records,
  rejections by reason, frames lost, and the bus load over the last 50 ticks (1 s at 20 ms).

Time is the controller's: its SYNC ticks of 20 ms since the first one seen (a lock-step run, which
the wall clock does not pace, and a trace replayed at any speed show the same times and ages).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from controller.estimator import Estimate, Measurements, StateEstimator
from protocol.busload import frame_bits
from protocol.catalog import Catalog
from protocol.clock import TICK_MS
from protocol.codec import Codec, Decoded
from protocol.e2e import Receiver
from protocol.enums import DriveState, EmcyCode, GaitState, JointMode, NmtState, NodeError, PolicyMode

#: the per-tick series, in the order of a sample (after its number and time)
SERIES = (
    "stick_force_l", "stick_force_r", "heel_l", "toe_l", "heel_r", "toe_r",
    "q_lh", "q_lk", "q_rh", "q_rk", "cmd_lh", "cmd_lk", "cmd_rh", "cmd_rk", "x_ratio",
)
SWINGS = {GaitState.SWING_LEFT: 0, GaitState.SWING_RIGHT: 1}
MAX_EMCY = 20  # EMCY records kept (newest last)
MAX_COSTS = 60  # gait-cycle costs kept (six roll-outs of the paper's ten cycles)
MAX_PATH = 400  # points of a swing's path kept (a swing is about 1-2 s: 50-100 ticks)
SENSORS = ("STICK_LEFT", "STICK_RIGHT", "PLANTAR_LEFT", "PLANTAR_RIGHT", "TRUNK_IMU_ORIENTATION")


def _name(enum: type, value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return str(value)


def _num(x: float, digits: int = 4) -> float | None:
    """A JSON number (None for nan or inf), rounded for the wire."""
    return round(float(x), digits) if math.isfinite(x) else None


@dataclass
class NodeHealth:
    nmt: str = "UNKNOWN"
    heartbeat_s: float | None = None  # bus time of its newest heartbeat
    supply_v: float | None = None
    drive_state: str = "UNKNOWN"
    error_code: str = "NONE"
    status_s: float | None = None  # bus time of its newest JOINT_STATUS


class ViewModel:
    """Everything the page shows; ``feed`` every frame, ``snapshot`` when the page wants it. Not
    thread-safe by itself: the caller holds one lock around both."""

    def __init__(self, controller_cfg: Any, catalog: Catalog, *, bitrate_bit_s: int = 500_000,
                 max_delta_counter: int = 2, history_s: float = 10.0) -> None:
        self.catalog = catalog
        self.receiver = Receiver(Codec(catalog), max_delta_counter=max_delta_counter)
        self.estimator = StateEstimator(controller_cfg.body, controller_cfg.legs, controller_cfg.hardware)
        self._command_estimator = StateEstimator(controller_cfg.body, controller_cfg.legs, controller_cfg.hardware)  # its own elbow state
        self.bitrate = bitrate_bit_s
        self.joint_nodes = catalog.joint_nodes
        self.nodes = {n: NodeHealth() for n in self.joint_nodes}
        self._joint_index = {catalog.message(family, n).frame_id: (family, i)
                             for i, n in enumerate(self.joint_nodes) for family in ("JOINT_STATUS", "JOINT_COMMAND")}
        self._heartbeat = {catalog.message("HEARTBEAT", n).frame_id: n for n in self.joint_nodes}
        self._emcy = {catalog.message("EMCY", n).frame_id: n for n in self.joint_nodes}
        self._ids = {name: catalog.by_name(name).frame_id
                     for name in (*SENSORS, "SYNC", "CONTROLLER_HEARTBEAT", "CONTROLLER_STEP", "CONTROLLER_LEARNING")}
        self._sensor_of = {self._ids[name]: name for name in SENSORS}
        self.frames = 0
        self.first_tick: int | None = None
        self.now_s = 0.0  # the newest SYNC's time: its ticks since the first one seen, in s
        self.newest_ts: float | None = None  # the newest frame's own timestamp (for latency)
        self.tick: int | None = None  # the newest SYNC's tick
        self.gait_state = "UNKNOWN"
        self.controller_heartbeat_s: float | None = None
        self.steps = 0  # swings started
        self.landings = 0  # swings that ended in double support
        self.landed: deque[dict[str, Any]] = deque(maxlen=20)  # the newest: {"step", "leg", "length_m", "t"}
        self.emcy: deque[dict[str, Any]] = deque(maxlen=MAX_EMCY)
        self.step: dict[str, Any] | None = None  # the newest CONTROLLER_STEP
        self.learning: dict[str, Any] | None = None  # the newest CONTROLLER_LEARNING
        self.costs: deque[dict[str, Any]] = deque(maxlen=MAX_COSTS)  # {"update", "rollout", "cycle", "cost_n"}
        self.sensors: dict[str, Any] = {}  # message name -> newest values
        self.q = [math.nan] * 4
        self.setpoints = [math.nan] * 4  # nan: not tracking (HOLD, QUICK_STOP, DISABLE)
        self.estimate: Estimate | None = None
        self.swing_leg: int | None = None
        self.paths: dict[str, list[tuple[float, float]]] = {"commanded": [], "measured": []}  # (x, z) of the swing ankle
        self._tick_bits = 0  # bits on the wire since the newest SYNC
        self._load: deque[int] = deque(maxlen=1000 // TICK_MS)  # bits of each of the last second's ticks
        self.samples: deque[list[Any]] = deque(maxlen=max(1, int(history_s * 1000 / TICK_MS)))
        self.sample_count = 0  # numbers the samples: the next one's number

    # -- input -----------------------------------------------------------------------------------

    def feed(self, msg: Any) -> None:
        """One frame as received (a :class:`can.Message` or a trace's frame)."""
        self.frames += 1
        self.newest_ts = float(msg.timestamp)
        t = self.now_s
        self._tick_bits += frame_bits(min(len(msg.data), 8), extended=msg.is_extended_id)
        result = self.receiver.receive(msg)
        if type(result) is not Decoded:
            return
        fid, v = result.message.frame_id, result.values
        joint = self._joint_index.get(fid)
        if joint is not None:
            family, i = joint
            if family == "JOINT_STATUS":
                node = self.nodes[self.joint_nodes[i]]
                node.drive_state, node.error_code = _name(DriveState, v.drive_state), _name(NodeError, v.error_code)
                node.status_s = t
                self.q[i] = v.position_rad
            else:
                self.setpoints[i] = v.position_setpoint_rad if v.mode == JointMode.TRACK else math.nan
        elif fid in self._sensor_of:
            self.sensors[self._sensor_of[fid]] = v
        elif fid == self._ids["SYNC"]:
            if self.tick is not None:
                self._end_tick()
            self._load.append(self._tick_bits)
            self._tick_bits = 0
            self.tick = v.tick
            if self.first_tick is None or v.tick < self.first_tick:  # the first, or a restarted controller
                self.first_tick = v.tick
            self.now_s = (v.tick - self.first_tick) * TICK_MS / 1000
        elif fid == self._ids["CONTROLLER_HEARTBEAT"]:
            self._gait(_name(GaitState, v.gait_state))
            self.controller_heartbeat_s = t
        elif fid == self._ids["CONTROLLER_STEP"]:
            self.step = {"index": v.step_index, "commanded_m": _num(v.step_length_m, 3) if v.step_index else None,
                         "placed_m": _num(v.placed_step_m, 3) if v.placed_step_m else None,
                         "cost_n": _num(v.step_cost_N, 1) if v.step_cost_N else None, "policy": _name(PolicyMode, v.policy)}
        elif fid == self._ids["CONTROLLER_LEARNING"]:
            self._learner(v)
        elif fid in self._heartbeat:
            node = self.nodes[self._heartbeat[fid]]
            node.nmt, node.supply_v, node.heartbeat_s = _name(NmtState, v.nmt_state), v.supply_voltage_V, t
        elif fid in self._emcy:
            self.emcy.append({"t": round(t, 3), "node": self._emcy[fid], "code": _name(EmcyCode, v.emcy_code),
                              "register": v.error_register, "detail": v.detail})

    def _gait(self, state: str) -> None:
        if state == self.gait_state:
            return
        before, self.gait_state = self.gait_state, state
        swing = SWINGS.get(GaitState[state]) if state in GaitState.__members__ else None
        if swing is not None:
            self.steps += 1
            self.swing_leg = swing
            self.paths = {"commanded": [], "measured": []}
        elif before in ("SWING_LEFT", "SWING_RIGHT") and state == "DOUBLE_SUPPORT":
            self.landings += 1
            a = self.estimate.ankles if self.estimate is not None else None
            self.landed.append({"step": self.steps, "leg": "left" if before == "SWING_LEFT" else "right",
                                "length_m": None if a is None else _num(abs(a[0][0] - a[1][0])), "t": round(self.now_s, 3)})
        if swing is None:
            self.swing_leg = None

    def _learner(self, v: Any) -> None:
        self.learning = {"alpha": _num(v.alpha, 2), "xhat_com": _num(v.xhat_com, 3), "update": v.update_index,
                         "rollout": v.rollout_index, "cycle": v.cycle_index}
        if v.cycle_index:  # a gait cycle told to the learner: keep its cost once
            key = {"update": v.update_index, "rollout": v.rollout_index, "cycle": v.cycle_index}
            if not self.costs or any(self.costs[-1][k] != key[k] for k in key):
                self.costs.append({**key, "cost_n": _num(v.cycle_cost_N, 1)})

    def _measurements(self) -> Measurements | None:
        s = self.sensors
        if len(s) < len(SENSORS) or any(math.isnan(x) for x in self.q):
            return None
        sl, sr, pl, pr, o = (s[n] for n in SENSORS)
        return Measurements(
            joint_position_rad=np.array(self.q), trunk_rpy_rad=np.array([o.roll_rad, o.pitch_rad, o.yaw_rad]),
            stick_rpy_rad=np.array([[sl.roll_rad, sl.pitch_rad, sl.yaw_rad], [sr.roll_rad, sr.pitch_rad, sr.yaw_rad]]),
            stick_force_n=np.array([sl.force_N, sr.force_N]),
            heel_force_n=np.array([pl.heel_force_N, pr.heel_force_N]), toe_force_n=np.array([pl.toe_force_N, pr.toe_force_N]),
        )

    def _end_tick(self) -> None:
        """The tick's frames are in (the next SYNC came): estimate, and keep the tick's sample."""
        m = self._measurements()
        if m is None:
            return
        est = self.estimate = self.estimator.update(m)
        leg = self.swing_leg
        if leg is not None and not math.isnan(self.setpoints[2 * leg]):
            commanded = self._command_estimator.update(replace(m, joint_position_rad=np.array(
                [self.setpoints[i] if not math.isnan(self.setpoints[i]) else self.q[i] for i in range(4)])))
            for key, ankles in (("commanded", commanded.ankles), ("measured", est.ankles)):
                path = self.paths[key]
                if len(path) < MAX_PATH:
                    path.append((_num(ankles[leg][0]), _num(ankles[leg][2] - est.floor_z)))
        s = self.sensors
        self.samples.append([
            self.sample_count, round(self.now_s, 3),
            _num(s["STICK_LEFT"].force_N, 1), _num(s["STICK_RIGHT"].force_N, 1),
            _num(s["PLANTAR_LEFT"].heel_force_N, 1), _num(s["PLANTAR_LEFT"].toe_force_N, 1),
            _num(s["PLANTAR_RIGHT"].heel_force_N, 1), _num(s["PLANTAR_RIGHT"].toe_force_N, 1),
            *(_num(x) for x in self.q), *(_num(x) for x in self.setpoints), _num(est.x_ratio, 3),
        ])
        self.sample_count += 1

    # -- output ----------------------------------------------------------------------------------

    def snapshot(self, since: int = -1) -> dict[str, Any]:
        """The page's state as JSON-ready data; the series' samples numbered after ``since``."""
        now = self.now_s
        est = self.estimate
        first = self.samples[0][0] if self.samples else 0
        new = list(self.samples)[max(0, since + 1 - first):] if since >= first - 1 else list(self.samples)
        stats = self.receiver.stats
        return {
            "t": round(now, 3),
            "newest_ts": self.newest_ts,
            "frames": self.frames,
            "tick": self.tick,
            "gait": {
                "state": self.gait_state,
                "steps": self.steps,
                "cycles": self.landings // 2,
                "landed": list(self.landed)[-6:],
                "heartbeat_age_s": None if self.controller_heartbeat_s is None else round(now - self.controller_heartbeat_s, 3),
                "controller_step": self.step,
            },
            "learning": None if self.learning is None else {**self.learning, "costs": list(self.costs)},
            "estimate": None if est is None else {
                "com": [_num(x) for x in est.com],
                "ankles": [[_num(x) for x in a] for a in est.ankles],
                "tips": [[_num(x) for x in p] for p in est.tips],
                "feet_loaded": list(est.feet_loaded),
                "sticks_loaded": list(est.sticks_loaded),
                "floor_z": _num(est.floor_z),
                "support": [[_num(x) for x in p] for p in est.support],
                "x_ratio": _num(est.x_ratio, 3),
                "swing_leg": self.swing_leg,
                "paths": self.paths,
            },
            "series": {"fields": ["n", "t", *SERIES], "samples": new},
            "nodes": {name: {
                "nmt": h.nmt, "heartbeat_age_s": None if h.heartbeat_s is None else round(now - h.heartbeat_s, 3),
                "supply_v": None if h.supply_v is None else round(h.supply_v, 2), "drive_state": h.drive_state,
                "error_code": h.error_code, "status_age_s": None if h.status_s is None else round(now - h.status_s, 3),
            } for name, h in self.nodes.items()},
            "emcy": list(self.emcy),
            "receiver": {"accepted": stats.accepted, "lost": stats.lost,
                         "rejected_by_reason": {r.value: n for r, n in sorted(stats.rejected.items(), key=lambda i: i[0].value)}},
            # per tick of the controller's 20 ms (a lock-step run is not paced by the wall clock)
            "bus_load": round(sum(self._load) / (len(self._load) * TICK_MS / 1000 * self.bitrate), 4) if self._load else None,
        }
