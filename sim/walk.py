"""A walk of the HHEA: the patient (:mod:`sim.patient`), the exoskeleton's legs and the physics,
advanced one bus tick (20 ms) at a time.

With ``scripted_exo`` the legs are :class:`sim.scripted_gait.ScriptedGait`'s (``aider-exo sim``);
without, someone else commands them through the node boards (the controller, via
:mod:`nodes.host`) and the patient senses the steps from the plantar forces, as a person in an
exoskeleton feels a foot leave and reach the floor. Every step is recorded from the previous foot
contact to its own: the paper's per-step cost (equation (10): the stick force integrated over the
step, divided by its duration), the X_CoM/X_SP at the swing's start, the patient's intention.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from config.sim_schema import GaitConfig, SimConfig
from protocol.clock import TICK_S
from sim.kinematics import Kinematics
from sim.model import build_body
from sim.patient import OTHER, SIDES, Patient, Phase, StepPlan
from sim.scripted_gait import ScriptedGait
from sim.sensors import Reading, Sensors
from protocol.geometry import fore_aft_ratio
from sim.truth import FallCriteria, pivot_polygon
from sim.world import StancePose, World

__all__ = ["OTHER", "SIDES", "Phase", "StepRecord", "WalkResult", "Walker", "gait_settings", "initial_pose", "walk"]

_ALLOWED_CONTACTS = frozenset({"foot_l", "foot_r", "forearm_l", "forearm_r"})
_OFF_FLOOR_M = 0.005  # an unloaded foot whose ankle is this much higher than standing is off the floor


def gait_settings(cfg: SimConfig, **changes: float) -> GaitConfig:
    """The configured gait (``sim.gait``) with ``changes`` (a sweep's step length, a test's knob)."""
    return dataclasses.replace(cfg.gait, **changes)


@dataclass
class StepRecord:
    """One step of the gait: from the previous foot contact (the start of the walk for the first
    step) through the patient's stick moves and lean and the exoskeleton's swing to this step's
    foot contact. Its means are the paper's per-step cost (equation (10))."""

    index: int
    leg: str
    start_s: float
    end_s: float = math.nan
    stick_force_sum_n: float = 0.0  # integral pieces: both sticks together per tick
    arm_torque_sum_nm: float = 0.0
    samples: int = 0
    min_margin_m: float = math.inf
    landed: bool = False
    x_ratio: float = math.nan  # X_CoM/X_SP at the swing's start (Walker.swing_ratio)
    intention_m: float = math.nan  # the patient's intended stick placement ahead of its reference (sim.intention)
    lean_x: float = math.nan  # the X_CoM/X_SP the patient meant to lean to
    placed_ahead_m: float = math.nan  # where its sticks went: their mean goal ahead of the intention's reference
    clamped: int = 0  # stick goals moved to where the arm reaches or ahead of where the stick stood

    def add(self, sticks_n: float, arm_torque_nm: float, margin_m: float) -> None:
        self.stick_force_sum_n += sticks_n
        self.arm_torque_sum_nm += arm_torque_nm
        self.samples += 1
        self.min_margin_m = min(self.min_margin_m, margin_m)

    @property
    def mean_sticks_force_n(self) -> float:
        """Both sticks together, mean over the step (the quantity of equation (10) over both sticks)."""
        return self.stick_force_sum_n / self.samples if self.samples else math.nan

    @property
    def mean_stick_force_n(self) -> float:
        """Per stick, mean over the step."""
        return self.mean_sticks_force_n / 2

    @property
    def mean_arm_torque_nm(self) -> float:
        return self.arm_torque_sum_nm / self.samples if self.samples else math.nan


@dataclass
class WalkResult:
    mode: str
    step_length_m: float
    seed: int
    steps: list[StepRecord] = field(default_factory=list)
    fell: bool = False
    fall_reason: str | None = None
    fall_phase: str | None = None
    fall_step: int | None = None
    fall_margin_m: float | None = None
    fall_direction: str | None = None  # "lateral", "forward" or "backward" (FallCriteria.direction)
    duration_s: float = 0.0

    @property
    def steps_completed(self) -> int:
        return sum(1 for s in self.steps if s.landed)

    @property
    def cycles_completed(self) -> int:
        return self.steps_completed // 2


class Walker:
    """One walk in ``world`` (closed by the caller): the patient, the legs, the records."""

    def __init__(
        self, world: World, cfg: SimConfig, settings: GaitConfig, rng: np.random.Generator, *, scripted_exo: bool = True
    ) -> None:
        self.world, self.cfg, self.s, self.rng = world, cfg, settings, rng
        self.kin = Kinematics(world)
        self.sensors = Sensors(world, cfg.sensors, rng)
        self.patient = Patient(world, self.kin, dataclasses.replace(cfg, gait=settings), rng)
        self.patient.dt = TICK_S
        self.patient.walking = scripted_exo  # under the controller, its gait state sets it
        self.gait = ScriptedGait(world, self.kin, cfg, settings, self.patient) if scripted_exo else None
        self.body = world.body
        self.physics_steps = round(cfg.physics.rate_hz * TICK_S)
        self.t = 0.0
        self.steps: list[StepRecord] = []
        self._next = StepRecord(index=-1, leg="", start_s=0.0)  # the step in the making, until its swing starts
        self.swing_leg: str | None = None
        self.next_swing = "r"
        self.unloaded_s = {"l": 0.0, "r": 0.0}  # how long each foot has been unloaded (sensed)
        self.airborne_s = {"l": 0.0, "r": 0.0}  # ... and wholly off the floor (felt)
        self.margin = math.inf
        self.fall: str | None = None
        self.fall_direction: str | None = None
        self._fall_criteria = FallCriteria(_ALLOWED_CONTACTS, cfg.fall.tilt_limit_rad, cfg.fall.min_hip_height_m)

    # -- shared views ----------------------------------------------------------------------------

    @property
    def walking(self) -> bool:
        return self.patient.walking

    @walking.setter
    def walking(self, value: bool) -> None:
        self.patient.walking = value

    @property
    def clamps(self) -> dict[str, int]:
        return self.patient.clamps

    def ankle_xy(self, side: str) -> np.ndarray:
        return self.patient.ankle_xy(side)

    def tip_point(self, side: str) -> np.ndarray:
        return self.patient.tip_point(side)

    def patient_state(self) -> dict:
        return self.patient.state()

    def intentions_m(self) -> list[float]:
        """The intended placement of every step whose swing has started, and last that of the step
        in the making (its stick moves may have been drawn already)."""
        plan = self.patient.plan.intention
        return [s.intention_m for s in self.steps] + [plan.ahead_m if plan is not None else math.nan]

    # -- the steps ---------------------------------------------------------------------------------

    def _swing_started(self, leg: str) -> None:
        plan: StepPlan = self.patient.plan
        record = dataclasses.replace(self._next, index=len(self.steps), leg=leg, placed_ahead_m=plan.placed_ahead_m,
                                     clamped=plan.clamped)
        if plan.intention is not None:
            record.intention_m, record.lean_x = plan.intention.ahead_m, plan.intention.lean_x
        record.x_ratio = self.swing_ratio(OTHER[leg])
        self.steps.append(record)
        self.swing_leg = leg
        self.patient.swing_started(leg)

    def _landed(self, leg: str, down: bool) -> None:
        record = self.steps[-1]
        record.end_s, record.landed = self.t, down
        self._next = StepRecord(index=-1, leg="", start_s=self.t)
        self.swing_leg, self.next_swing = None, OTHER[leg]
        self.patient.landed(leg)

    def swing_ratio(self, stance: str) -> float:
        """X_CoM/X_SP over the swing's support (SPEC; :meth:`sim.patient.Patient.swing_span`)."""
        rear, front = self.patient.swing_span(stance)
        return (float(self.kin.com[0]) - rear) / (front - rear) if front - rear > 0.0 else math.nan

    def _sense_steps(self, reading: Reading) -> None:
        """The patient's view of a step the exoskeleton makes: a foot that stays unloaded for
        ``foot_lift_s``, wholly off the floor (no part of its sole touching) with its ankle raised
        ``foot_raise_m``, has left it: a swing, the patient feels the leg lifted. A rear foot that
        is merely unloaded as the CoM passes over the front one, or on its toes in a deep lean, is
        no swing. The swing ends when the foot carries load again."""
        s, p = self.s, self.patient
        plantar = reading.heel_force_n + reading.toe_force_n
        for i, side in enumerate(SIDES):
            self.unloaded_s[side] = self.unloaded_s[side] + TICK_S if plantar[i] < s.foot_contact_n else 0.0
            self.airborne_s[side] = self.airborne_s[side] + TICK_S if not self.world.contacts(f"foot_{side}") else 0.0
        if self.swing_leg is None:
            raised = {side: self.kin.joint_origin[p.ankle_idx[side]][2] - self.body.ankle_height_m for side in SIDES}
            lifted = [side for side in SIDES if min(self.unloaded_s[side], self.airborne_s[side]) >= s.foot_lift_s and raised[side] > s.foot_raise_m]
            if len(lifted) == 1 and p.phase is Phase.LEAN:
                self.next_swing = lifted[0]
                self._swing_started(lifted[0])
            else:  # a foot lifted outside the patient's lean: balance on what is down, no step
                # (a foot on the floor is support whatever it carries now: its load follows the CoM)
                for side in SIDES:
                    p.stance[side] = not (self.unloaded_s[side] >= s.foot_lift_s and raised[side] > _OFF_FLOOR_M)
                if not any(p.stance.values()):
                    p.stance = {"l": True, "r": True}  # airborne: keep the model's legs
        elif self.unloaded_s[self.swing_leg] == 0.0 and p.phase_t >= s.foot_lift_s:
            self._landed(self.swing_leg, True)

    # -- the loop ----------------------------------------------------------------------------------

    def start(self) -> Reading:
        """Latch the initial posture as the goals; returns the first sensor reading."""
        self.kin.update()
        self.patient.start()
        return self.sensors.read()

    def tick(self, reading: Reading) -> Reading:
        """One 20 ms tick: the patient (and the scripted exoskeleton) act on ``reading``, the
        physics advances, and the sensors are sampled again; returns the new reading."""
        w, p = self.world, self.patient
        p.update(reading)
        if self.gait is None:
            self._sense_steps(reading)
        else:
            event = self.gait.update(reading, TICK_S)
            if event is not None:
                kind, leg = event
                if kind == "swing":
                    self._swing_started(leg)
                else:
                    self._landed(leg, kind == "land")
        p.balance()
        if self.gait is not None:
            self.gait.command(reading)
        w.step(self.physics_steps)
        self.t += TICK_S
        self.kin.update()
        self.margin = p.support_margin()
        step = self.steps[-1] if self.steps and not self.steps[-1].landed else self._next
        step.add(float(reading.stick_force_n.sum()), float(np.abs(w.arms.applied).sum()), self.margin)
        self.fall = self._fall_reason()
        return self.sensors.read()

    def _fall_reason(self) -> str | None:
        """Ground truth (:class:`sim.truth.FallCriteria`): a link other than a foot or a stick
        touches the floor, or the trunk rolls, pitches or sinks beyond the configured limits; the
        reason names the fall's direction (``lateral``, ``forward`` or ``backward``: from the trunk's
        attitude, or the CoM's motion while the trunk is upright), which :attr:`fall_direction` keeps."""
        w = self.world
        origin, rot = w.link_frame("trunk")
        roll, pitch, _ = w.link_states().trunk_rpy.tolist()
        reason = self._fall_criteria.check(w.touching_links(), roll, pitch, float(origin[2]))
        if reason is None:
            return None
        heading = rot[:2, 0] / np.linalg.norm(rot[:2, 0])
        vx, vy = self.kin.com_velocity[:2].tolist()
        velocity = (vx * heading[0] + vy * heading[1], -vx * heading[1] + vy * heading[0])
        self.fall_direction = FallCriteria.direction(roll, pitch, self.s.trunk_pitch_rad, velocity)
        return f"{self.fall_direction} fall: {reason}"

    def x_ratio_truth(self, foot_n: float, stick_n: float, min_support_m: float) -> float:
        """Ground truth of X_CoM/X_SP: the CoM's fore-aft place, along the trunk's heading, in the
        pivot polygon of the feet carrying more than ``foot_n`` and the sticks carrying more than
        ``stick_n``; nan for a polygon shorter than ``min_support_m`` fore-aft (the rules of the
        controller's estimator, which computes it from the sensors)."""
        w, p = self.world, self.patient
        feet = [s for s in SIDES if w.contact_normal_force(f"foot_{s}") > foot_n]
        tips = [s for s in SIDES if w.contact_normal_force(f"forearm_{s}") > stick_n]
        ankles = np.array([p.ankle_xy(s) for s in feet]).reshape(-1, 2)
        tip_xy = np.array([p.tip_point(s)[:2] for s in tips]).reshape(-1, 2)
        poly = pivot_polygon(ankles, tip_xy, ankle_halfwidth=self.cfg.hardware.foot.half_width_m)
        heading = w.link_frame("trunk")[1][:2, 0]
        heading = heading / np.linalg.norm(heading)  # the support and the CoM along it
        return fore_aft_ratio(float(self.kin.com[:2] @ heading), (poly @ heading).tolist(), min_support_m)

    def run(self, max_steps: int, max_time_s: float = 120.0, on_tick=None) -> WalkResult:
        """Walk until ``max_steps`` steps have landed, a fall, or ``max_time_s``.

        ``on_tick(world, t)`` is called after every control tick (recording, progress).
        """
        result = WalkResult(mode=self.cfg.mode, step_length_m=self.s.step_length_m, seed=-1)
        reading = self.start()
        while self.t < max_time_s:
            reading = self.tick(reading)
            if on_tick is not None:
                on_tick(self.world, self.t)
            if self.fall:
                result.fell, result.fall_reason = True, self.fall
                result.fall_phase = self.patient.phase.value
                result.fall_step = len(self.steps)
                result.fall_margin_m = round(self.margin, 4)
                result.fall_direction = self.fall_direction
                break
            if sum(1 for r in self.steps if r.landed) >= max_steps:
                break
        result.steps = self.steps
        result.duration_s = self.t
        return result


def initial_pose(cfg: SimConfig) -> StancePose:
    """Standing in a short split stance, the trunk pitched 0.1 rad, the sticks planted 0.25 m ahead of
    the front ankle, or nearer if the arms, bent as far as ``stick_reach_elbow_rad``, reach no farther."""
    body = build_body(cfg)
    pitch, hip_x, feet, half = 0.10, 0.05, (0.06, -0.06), cfg.patient.stick_half_width_m
    shoulder = np.array([hip_x + body.shoulder_above_hip_m * math.sin(pitch), body.shoulder_half_width_m,
                         body.hip_height_m + body.shoulder_above_hip_m * math.cos(pitch)])
    reach = body.arm_span_m(cfg.patient.stick_reach_elbow_rad)
    ahead = math.sqrt(max(reach**2 - (half - shoulder[1]) ** 2 - (shoulder[2] - cfg.hardware.sticks.tip_radius_m) ** 2, 0.0))
    tips_x = min(max(feet) + 0.25, float(shoulder[0] + ahead))
    return StancePose(foot_x_m=feet, tip_xy_m=((tips_x, half), (tips_x, -half)), trunk_pitch_rad=pitch, hip_x_m=hip_x, knee_rad=0.08)


def walk(
    cfg: SimConfig, settings: GaitConfig, seed: int, max_steps: int, *, gui: bool = False, on_tick=None,
    max_time_s: float = 120.0,
) -> WalkResult:
    """One episode in a fresh world (deterministic for a seed); it ends after ``max_steps`` steps,
    a fall, or ``max_time_s`` of simulated time (a stall: the patient waited for a safe stick move)."""
    rng = np.random.default_rng(seed)
    with World(cfg, gui=gui) as world:
        world.place(initial_pose(cfg))
        walker = Walker(world, cfg, settings, rng)
        result = walker.run(max_steps, max_time_s=max_time_s, on_tick=on_tick)
    result.seed = seed
    return result
