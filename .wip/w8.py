"""Prototype: the HHEA as a position-controlled quadruped following one kinematic plan.

The plan is the trunk's pose (hip x, hip z, pitch); the exoskeleton's legs and the patient's
planted arms track it by inverse kinematics from their planted feet / tips; loads emerge.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from config.sim_schema import GaitConfig, SimConfig
from sim.actuation import Mode
from sim.intention import Intention
from sim.kinematics import Kinematics
from sim.linalg import clamp
from sim.model import arm_ik, leg_ik
from sim.sensors import Sensors, rpy_from_matrix
from sim.truth import FallCriteria, convex_hull_2d, pivot_polygon, stability_margin, fore_aft_ratio
from sim.world import StancePose, World

SIDES = ("l", "r")
OTHER = {"l": "r", "r": "l"}

P = dict(
    press_m=0.004,          # arm targets this far below the floor (preload)
    lean_x=0.6,             # X_CoM/X_SP goal of the lean
    hip_advance=0.0,        # fraction of the step the stance leg advances the hip in the swing
    balance_margin_m=0.03,  # CoM ahead of the ankles' midpoint (double support) by this
    lift_margin_m=0.02,     # CoM inside the support left when a stick lifts
    shift_speed=0.10,
    lean_speed=0.12,
    min_elbow=0.25,
    stick_ahead=0.30,       # intention: tips this far ahead of the CoM at the lift
    reference="com",
    init_tips_x=0.30,
    swing_time=1.2,
    clearance=0.10,
    stick_time=0.8,
    stick_lift=0.06,
    pitch=0.10,
    arm_k=None,
)


def _mj(a: float) -> float:
    a = min(max(a, 0.0), 1.0)
    return a * a * a * (10 - 15 * a + 6 * a * a)


def _rot_y(p: float) -> np.ndarray:
    c, s = math.cos(p), math.sin(p)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass
class StepRecord:
    index: int
    leg: str
    start_s: float
    end_s: float = math.nan
    stick_force_sum_n: float = 0.0
    arm_torque_sum_nm: float = 0.0
    samples: int = 0
    landed: bool = False
    x_swing: float = math.nan
    swing_force_sum: float = 0.0
    swing_samples: int = 0

    @property
    def mean_stick_force_n(self):  # per stick, the existing convention
        return self.stick_force_sum_n / self.samples / 2 if self.samples else math.nan

    @property
    def mean_arm_torque_nm(self):
        return self.arm_torque_sum_nm / self.samples if self.samples else math.nan


@dataclass
class WalkResult:
    mode: str
    step_length_m: float
    seed: int
    steps: list = field(default_factory=list)
    fell: bool = False
    fall_reason: str | None = None
    fall_phase: str | None = None
    fall_step: int | None = None
    duration_s: float = 0.0
    extra: dict | None = None

    @property
    def steps_completed(self):
        return sum(1 for s in self.steps if s.landed)

    @property
    def cycles_completed(self):
        return self.steps_completed // 2


def gait_settings(cfg: SimConfig, **changes) -> GaitConfig:
    return dataclasses.replace(cfg.gait, **changes)


class Walker:
    def __init__(self, world: World, cfg: SimConfig, settings: GaitConfig, rng: np.random.Generator) -> None:
        self.world, self.cfg, self.s, self.rng = world, cfg, settings, rng
        self.kin = Kinematics(world)
        self.sensors = Sensors(world, cfg.sensors, rng)
        self.intention = Intention(cfg.patient.intention, rng.spawn(1)[0])
        self.body = world.body
        self.ankle_idx = {s: world.joint_index[f"ankle_{s}"] for s in SIDES}
        self.arm_joints = {s: [world.joint_index[f"{j}_{s}"] for j in ("shoulder_flexion", "shoulder_abduction", "elbow")] for s in SIDES}
        self.leg_joints = {s: [world.joint_index[f"hip_{s}"], world.joint_index[f"knee_{s}"]] for s in SIDES}
        self.t = 0.0
        self.phase = "settle"
        self.phase_t = 0.0
        self.steps: list[StepRecord] = []
        self.next_step = StepRecord(-1, "", 0.0)
        self.fall = None
        self.margin = 0.0
        self.stance = {"l": True, "r": True}
        self.swing_leg = None
        self.next_swing = "r"
        self.queue: list[str] = []
        self.tip_path: dict = {}
        self.planted = {"l": True, "r": True}
        self.criteria = FallCriteria(frozenset({"foot_l", "foot_r", "forearm_l", "forearm_r"}), cfg.fall.tilt_limit_rad, cfg.fall.min_hip_height_m)
        self.log = []

    # geometry
    def ankle(self, side):
        return self.kin.joint_origin[self.ankle_idx[side]]

    def tip_point(self, side):
        origin, rot = self.world.link_frame(f"forearm_{side}")
        b = self.body
        return origin - rot[:, 2] * (b.forearm_m + b.grip_m + b.stick_m) - np.array([0.0, 0.0, self.cfg.model.sticks.tip_radius_m])

    def shoulder_plan(self, side):
        sign = 1.0 if side == "l" else -1.0
        o = np.array([self.hip_x, self.hip_y, self.hip_z])
        return o + _rot_y(self.pitch) @ np.array([0.0, sign * self.body.shoulder_half_width_m, self.body.shoulder_above_hip_m])

    def support(self, tips):
        ank = np.array([self.foot[s] for s in SIDES if self.stance[s]])
        tp = np.array([self.anchor[s] for s in tips]).reshape(-1, 2)
        return pivot_polygon(ank, tp, ankle_halfwidth=self.cfg.model.foot.half_width_m)

    def x_ratio(self):
        st = OTHER[self.next_swing]
        heel = self.foot[st][0] - self.cfg.model.foot.heel_back_m
        tips = max(self.anchor[s][0] for s in SIDES)
        return (self.kin.com[0] - heel) / (tips - heel)

    def start(self):
        w = self.world
        self.kin.update()
        o, rot = w.link_frame("trunk")
        self.hip_x, self.hip_y, self.hip_z = float(o[0]), float(o[1]), float(o[2])
        self.pitch = float(rpy_from_matrix(rot)[1])
        self.hip_z_nominal = self.hip_z
        self.foot = {s: self.ankle(s)[:2].copy() for s in SIDES}
        self.anchor = {s: self.tip_point(s)[:2].copy() for s in SIDES}
        self.com_target = float(self.kin.com[0])
        self.targets = {}
        return self.sensors.read()

    # the plan
    def set_phase(self, ph):
        self.phase, self.phase_t = ph, 0.0

    def start_sticks(self):
        self.next_step.intention_m = self.intention.next_m()
        self.queue = sorted(SIDES, key=lambda s: self.anchor[s][0])
        self.set_phase("shift")

    def lift_window(self, side):
        """(lo, hi) of the CoM x for lifting ``side``: ahead of the ankles' midpoint, inside the rest."""
        ank_mid = np.mean([self.foot[s][0] for s in SIDES])
        lo = ank_mid + P["balance_margin_m"]
        poly = convex_hull_2d(self.support([OTHER[side]] if self.planted[OTHER[side]] else []))
        y = float(self.kin.com[1])
        xs = np.linspace(min(self.foot[s][0] for s in SIDES) - 0.1, max(self.anchor[s][0] for s in SIDES), 121)
        ok = [x for x in xs if stability_margin(poly, (x, y)) >= P["lift_margin_m"]]
        hi = max(ok) if ok else -math.inf
        lo2 = min(ok) if ok else math.inf
        return max(lo, lo2), hi

    def stick_goal(self, side, start):
        sign = 1.0 if side == "l" else -1.0
        ref = float(self.kin.com[0]) if P["reference"] == "com" else max(self.foot[s][0] for s in SIDES)
        x = ref + self.next_step.intention_m + float(self.rng.normal(0.0, self.cfg.patient.stick_noise_m))
        y, z = sign * self.cfg.patient.stick_half_width_m, self.cfg.model.sticks.tip_radius_m
        sh = self.shoulder_plan(side)
        up, low = self.body.arm_reach_m
        reach = math.sqrt(up * up + low * low + 2 * up * low * math.cos(P["min_elbow"]))
        across = reach * reach - (y - sh[1]) ** 2 - (z - sh[2]) ** 2
        far = sh[0] + math.sqrt(max(across, 0.0))
        near = float(start[0]) + self.cfg.patient.stick_min_advance_m
        x = min(max(x, near), far)
        return np.array([x, y, 0.0])

    def plan(self, reading):
        dt = 0.02
        self.phase_t += dt
        com = self.kin.com
        ph = self.phase
        if ph == "settle":
            if self.phase_t > 0.6:
                self.start_sticks()
        elif ph == "shift":
            side = self.queue[0]
            lo, hi = self.lift_window(side)
            if hi < lo and len(self.queue) > 1 and self.phase_t < 0.05:
                self.queue.reverse()
                side = self.queue[0]
                lo, hi = self.lift_window(side)
            target = (lo + hi) / 2 if hi < lo else clamp(float(com[0]), lo, hi)
            self.com_target += clamp(target - self.com_target, -P["shift_speed"] * dt, P["shift_speed"] * dt)
            inside = lo - 0.003 <= com[0] <= hi + 0.003 and abs(self.kin.com_velocity[0]) < 0.05
            if inside and self.phase_t > 0.2:
                self.planted[side] = False
                start = self.tip_point(side)
                self.tip_path[side] = (start, self.stick_goal(side, start), 0.0)
                self.set_phase("stick")
        elif ph == "stick":
            side = self.queue[0]
            start, goal, u = self.tip_path[side]
            u += dt / P["stick_time"]
            force = reading.stick_force_n[SIDES.index(side)]
            if u >= 1.0 and force > 20.0:
                del self.tip_path[side]
                self.planted[side] = True
                self.anchor[side] = self.tip_point(side)[:2].copy()
                self.queue.pop(0)
                if self.queue:
                    self.set_phase("shift")
                else:
                    self.set_phase("lean")
            else:
                self.tip_path[side] = (start, goal, min(u, 1.5))
        elif ph == "lean":
            st = OTHER[self.next_swing]
            heel = self.foot[st][0] - self.cfg.model.foot.heel_back_m
            tips = float(np.mean([self.anchor[s][0] for s in SIDES]))
            goal = heel + P["lean_x"] * (tips - heel)
            self.com_target += clamp(goal - self.com_target, -P["lean_speed"] * dt, P["lean_speed"] * dt)
            loaded = all(reading.stick_force_n > 20.0)
            if com[0] >= goal - 0.01 and loaded and self.phase_t > 0.3:
                self.start_swing()
            elif self.phase_t > 6.0 and loaded:
                self.start_swing()
        elif ph == "swing":
            u = min(self.phase_t / P["swing_time"], 1.0)
            self.com_target = self.swing_com0 + P["hip_advance"] * self.s.step_length_m * _mj(u)
            leg = self.swing_leg
            plantar = (reading.heel_force_n + reading.toe_force_n)[SIDES.index(leg)]
            if (u > 0.75 and plantar > 60.0) or self.phase_t > P["swing_time"] + 1.0:
                self.land(plantar > 60.0)
        # the plan's hip from the CoM target (the CoM's offset from the hip, as measured)
        off = float(com[0]) - float(self.world.link_frame("trunk")[0][0])
        want = self.com_target - off
        self.hip_x += clamp(want - self.hip_x, -0.2 * dt, 0.2 * dt)
        feet = [s for s in SIDES if self.stance[s]]
        reach = min(math.sqrt(max(0.85**2 - (self.hip_x - self.foot[f][0]) ** 2, 0.05)) for f in feet)
        zgoal = min(self.hip_z_nominal, self.body.ankle_height_m + reach)
        self.hip_z += clamp(zgoal - self.hip_z, -0.1 * dt, 0.1 * dt)
        self.pitch += clamp(P["pitch"] - self.pitch, -0.2 * dt, 0.2 * dt)

    def start_swing(self):
        leg = self.next_swing
        st = OTHER[leg]
        self.next_step.x_swing = self.x_ratio()
        self.swing_leg = leg
        self.stance[leg] = False
        self.swing_start = self.ankle(leg)[:2].copy()
        self.swing_goal_x = self.foot[st][0] + self.s.step_length_m
        self.swing_com0 = self.com_target
        self.steps.append(dataclasses.replace(self.next_step, index=len(self.steps), leg=leg))
        self.set_phase("swing")

    def land(self, down):
        leg = self.swing_leg
        rec = self.steps[-1]
        rec.end_s, rec.landed = self.t, down
        self.next_step = StepRecord(-1, "", self.t)
        self.stance[leg] = True
        self.foot[leg] = self.ankle(leg)[:2].copy()
        self.swing_leg = None
        self.next_swing = OTHER[leg]
        self.com_target = float(self.kin.com[0])
        self.start_sticks()

    def swing_target(self):
        u = min(self.phase_t / P["swing_time"], 1.0)
        x = self.swing_start[0] + (self.swing_goal_x - self.swing_start[0]) * _mj((u - 0.15) / 0.7)
        lift = _mj(u / 0.3) - _mj((u - 0.7) / 0.3)
        z = self.body.ankle_height_m + P["clearance"] * lift + (0.0 if u < 1.0 else -0.01)
        return x, z

    def control(self):
        w, b = self.world, self.body
        g = self.kin.gravity_torques()
        rot = _rot_y(self.pitch)
        o = np.array([self.hip_x, self.hip_y, self.hip_z])
        for side in SIDES:
            hi, ki = self.leg_joints[side]
            n_h, n_k = w.exo.index(f"hip_{side}"), w.exo.index(f"knee_{side}")
            if side == self.swing_leg:
                x, z = self.swing_target()
                trunk = w.link_frame("trunk")[0]
                rel = np.array([x - trunk[0], z - trunk[2]])
                pitch = float(rpy_from_matrix(w.link_frame("trunk")[1])[1])
                ff = (clamp(g[hi], -90, 90), clamp(g[ki], -90, 90))
            else:
                rel = np.array([self.foot[side][0] - self.hip_x, b.ankle_height_m - self.hip_z])
                pitch = self.pitch
                ff = (0.0, 0.0)
            r = float(np.hypot(*rel))
            if r > b.thigh_m + b.shank_m - 0.005:
                rel = rel * (b.thigh_m + b.shank_m - 0.005) / r
            try:
                h, k = leg_ik(rel, b.thigh_m, b.shank_m)
            except ValueError:
                continue
            for n, tgt, f in ((n_h, h + pitch, ff[0]), (n_k, k, ff[1])):
                last = self.targets.get(n, tgt)
                if side != self.swing_leg:
                    tgt = last + clamp(tgt - last, -0.078, 0.078)
                tgt = clamp(tgt, w.exo.lower[n] + 1e-3, w.exo.upper[n] - 1e-3)
                self.targets[n] = tgt
                w.exo.command(n, Mode.TRACK, tgt, 0.0, f)
        targets, torques = [], []
        up, low = b.arm_reach_m
        for side in SIDES:
            joints = self.arm_joints[side]
            sh = self.shoulder_plan(side)
            if side in self.tip_path:
                start, goal, u = self.tip_path[side]
                p = start + (goal - start) * _mj(u)
                lift = 4 * min(u, 1.0) * (1 - min(u, 1.0)) * P["stick_lift"]
                p = p + np.array([0.0, 0.0, lift - (0.02 if u >= 1.0 else 0.0) + self.cfg.model.sticks.tip_radius_m])
                # a moving arm follows the body as it is
                to, tr = w.link_frame("trunk")
                sign = 1.0 if side == "l" else -1.0
                sh = to + tr @ np.array([0.0, sign * b.shoulder_half_width_m, b.shoulder_above_hip_m])
                R = tr
            else:
                p = np.array([self.anchor[side][0], self.anchor[side][1], self.cfg.model.sticks.tip_radius_m - P["press_m"]])
                R = rot
            d = p - sh
            n = float(np.linalg.norm(d))
            if n > up + low - 1e-4:
                d = d * (up + low - 1e-4) / n
            try:
                targets += list(arm_ik(R.T @ d, up, low, side))
            except ValueError:
                targets += [w.q[j] for j in joints]
            torques += [g[j] for j in joints]
        arms = w.arms
        arms.track(np.minimum(np.maximum(targets, arms.lower + 1e-3), arms.upper - 1e-3),
                   np.minimum(np.maximum(torques, -arms.rated), arms.rated))

    def tick(self, reading):
        w = self.world
        self.plan(reading)
        self.control()
        for _ in range(5):
            w.step()
        self.t += 0.02
        self.kin.update()
        rec = self.steps[-1] if self.steps and not self.steps[-1].landed else self.next_step
        f = float(np.sum(reading.stick_force_n))
        rec.stick_force_sum_n += f
        rec.arm_torque_sum_nm += float(np.sum(np.abs(w.arms.applied)))
        rec.samples += 1
        if self.phase == "swing":
            rec.swing_force_sum += f
            rec.swing_samples += 1
        origin, rot = w.link_frame("trunk")
        roll, pitch, _ = rpy_from_matrix(rot).tolist()
        reason = self.criteria.check(w.touching_links(), roll, pitch, float(origin[2]))
        if reason:
            self.fall = f"{FallCriteria.direction(roll, pitch, 0.1)} fall: {reason}"
        return self.sensors.read()

    def run(self, max_steps, max_time_s=120.0, on_tick=None):
        result = WalkResult(self.cfg.mode, self.s.step_length_m, -1)
        reading = self.start()
        while self.t < max_time_s:
            reading = self.tick(reading)
            if on_tick:
                on_tick(self.world, self.t)
            if self.fall:
                result.fell, result.fall_reason, result.fall_phase, result.fall_step = True, self.fall, self.phase, len(self.steps)
                break
            if sum(1 for r in self.steps if r.landed) >= max_steps:
                break
        result.steps = self.steps
        result.duration_s = self.t
        sw = [r.swing_force_sum / r.swing_samples for r in self.steps if r.swing_samples]
        result.extra = {"swingF": round(float(np.mean(sw)), 0) if sw else None}
        return result


def initial_pose(cfg):
    w = cfg.patient.stick_half_width_m
    return StancePose(foot_x_m=(0.06, -0.06), tip_xy_m=((P["init_tips_x"], w), (P["init_tips_x"], -w)), trunk_pitch_rad=0.10, hip_x_m=0.05, knee_rad=0.08)


def walk(cfg, settings, seed, max_steps, *, on_tick=None, max_time_s=120.0):
    rng = np.random.default_rng(seed)
    with World(cfg) as world:
        world.place(initial_pose(cfg))
        walker = Walker(world, cfg, settings, rng)
        result = walker.run(max_steps, max_time_s=max_time_s, on_tick=on_tick)
    result.seed = seed
    return result
