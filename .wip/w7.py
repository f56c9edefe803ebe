"""A walk of the HHEA: the patient (sticks and arms), a scripted exoskeleton gait and the physics.

The patient is a controller inside the plant, running at a human rate (``patient.control_hz``):

1. before a stick leaves the ground it shifts the CoM into the support that remains (the feet, and
   in the alternating gait the other stick) and waits until it is there;
2. it places the stick(s) ahead of its own body: before each step's stick moves it picks how far
   ahead of its CoM (or of its front ankle) to put them (its intention, :mod:`sim.intention`), and
   each stick lands there plus its own placement error, within the reach of its arm (a goal beyond
   it is clamped, and counted in the step's record);
3. it leans: the CoM target moves toward the sticks at a comfortable speed, until it is a
   comfortable distance behind them, or the stick load reaches what the patient's arms will bear.

Balance throughout is a contact-force distribution over the loaded contacts
(:mod:`sim.balance`). The arms apply their share (Jacobian-transpose torques) within the patient's
strength; the exoskeleton's stance legs receive theirs as the torque feed-forward of their node
commands. The exoskeleton (:class:`GaitDriver`, a scripted stand-in for the real controller)
swings the rear leg along a lift-advance-descend ankle path to a fixed step length when its
sensors say both sticks are loaded and both feet are down; the swing ends at foot contact.

So the trunk's progress is the patient's and the step length is the exoskeleton's: a step that is
too long leaves the CoM behind the front ankle when the rear foot lifts, and the sticks, which can
only push, cannot hold it.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field

import numpy as np

from config.sim_schema import GaitConfig, SimConfig
from sim.actuation import Mode
from balance2 import Contact, WrenchGains, desired_wrench, distribute
from sim.intention import Intention
from sim.kinematics import Kinematics
from sim.linalg import clamp
from sim.model import arm_ik, leg_ik
from sim.sensors import Sensors, rpy_from_matrix
from sim.truth import FallCriteria, convex_hull_2d, fore_aft_ratio, pivot_polygon, stability_margin
from sim.world import GRAVITY, StancePose, World

SIDES = ("l", "r")
OTHER = {"l": "r", "r": "l"}


class Phase(enum.Enum):
    SETTLE = "settle"
    SHIFT = "shift"  # patient moves the CoM into the support left when a stick lifts
    STICKS = "sticks"  # patient moves stick(s)
    LEAN = "lean"  # patient leans toward the sticks; the exoskeleton may start its swing
    SWING = "swing"  # the exoskeleton swings a leg


def gait_settings(cfg: SimConfig, **changes: float) -> GaitConfig:
    """The configured gait (``sim.gait``) with ``changes`` (a sweep's step length, a test's knob)."""
    return dataclasses.replace(cfg.gait, **changes)


@dataclass
class StepRecord:
    """One step of the gait: from the previous foot contact (the start of the walk for the first
    step) through the patient's stick moves and lean and the exoskeleton's swing to this step's
    foot contact. Its means are the paper's per-step cost (equation (10): the stick force
    integrated over the step, divided by its duration)."""

    index: int
    leg: str
    start_s: float
    end_s: float = math.nan
    stick_force_sum_n: float = 0.0  # integral pieces: mean of (left + right) / 2 per tick
    arm_torque_sum_nm: float = 0.0
    samples: int = 0
    min_margin_m: float = math.inf
    landed: bool = False
    intention_m: float = math.nan  # the patient's intended stick placement ahead of its reference (sim.intention)
    placed_ahead_m: float = math.nan  # where its sticks went: their mean goal ahead of the intention's reference
    x_swing: float = math.nan
    clamped: int = 0  # stick goals moved to where the arm reaches or ahead of where the stick stood

    def add(self, stick_force_n: float, arm_torque_nm: float, margin_m: float) -> None:
        self.stick_force_sum_n += stick_force_n
        self.arm_torque_sum_nm += arm_torque_nm
        self.samples += 1
        self.min_margin_m = min(self.min_margin_m, margin_m)

    @property
    def mean_stick_force_n(self) -> float:
        return self.stick_force_sum_n / self.samples if self.samples else math.nan

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
    """Runs one walk; owns nothing but references (the world is closed by the caller)."""

    def __init__(
        self, world: World, cfg: SimConfig, settings: GaitConfig, rng: np.random.Generator, *, scripted_exo: bool = True
    ) -> None:
        """``scripted_exo=False``: the patient alone; the exoskeleton's joints are commanded by
        someone else (the emulated node boards) and the patient senses its steps from the plantar
        forces, as a person in an exoskeleton feels a foot leave and reach the floor."""
        self.world, self.cfg, self.s, self.rng = world, cfg, settings, rng
        self.scripted_exo = scripted_exo
        # The patient starts the gait cycle (stick moves, lean) only while this is set; without the
        # scripted exoskeleton, whoever hosts the patient sets it (the controller's gait state).
        self.walking = scripted_exo
        self.kin = Kinematics(world)
        self.sensors = Sensors(world, cfg.sensors, rng)
        # its own stream (spawned, not drawn from rng): the sensors' noise does not move the intentions
        self.intention = Intention(cfg.patient.intention, rng.spawn(1)[0])
        self.clamps = {"reach": 0, "advance": 0}  # stick goals clamped, by reason, over the walk
        self.body = world.body
        self.gains = WrenchGains()
        self.ticks_per_control = cfg.physics.rate_hz // cfg.patient.control_hz
        self.dt_control = 1.0 / cfg.patient.control_hz
        self.together = cfg.patient.stick_mode == "together" or cfg.mode == "sagittal"
        self.ankle_idx = {s: world.joint_index[f"ankle_{s}"] for s in SIDES}
        self.forearm_idx = {s: world.joint_index[f"elbow_{s}"] for s in SIDES}
        self.arm_joints = {s: [world.joint_index[f"{j}_{s}"] for j in ("shoulder_flexion", "shoulder_abduction", "elbow")] for s in SIDES}
        self.leg_joints = {s: [world.joint_index[f"hip_{s}"], world.joint_index[f"knee_{s}"]] for s in SIDES}
        # State of the gait.
        self.phase = Phase.SETTLE
        self.phase_t = 0.0
        self.t = 0.0
        self.com_target = np.zeros(2)
        self.planted = {"l": True, "r": True}  # stick tips on the ground and loaded
        self.unloading: dict[str, float] = {}
        self.tip_path: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
        self.stick_queue: list[str] = []
        self.swing_leg: str | None = None
        self.swing_start = np.zeros(2)
        self.swing_goal = np.zeros(2)
        self.next_swing = "r"
        self.stance_feet = {"l": True, "r": True}
        self.lean_goal_x = 0.0
        self.lean_rest_s = 0.0  # how long the lean has been at rest with a stick light (see patient_update)
        self.steps: list[StepRecord] = []
        self._next_step = StepRecord(index=-1, leg="", start_s=0.0)  # the step in the making, until its swing starts
        self.margin = math.inf
        self.residual = 0.0
        self.unloaded_s = {"l": 0.0, "r": 0.0}  # how long each foot has been off the floor (sensed)
        self.fall: str | None = None
        self.fall_direction: str | None = None
        self._fall_criteria = FallCriteria(_ALLOWED_CONTACTS, cfg.fall.tilt_limit_rad, cfg.fall.min_hip_height_m)

    # -- geometry helpers ----------------------------------------------------------------------

    def ankle_xy(self, side: str) -> np.ndarray:
        return self.kin.joint_origin[self.ankle_idx[side]][:2].copy()

    def tip_point(self, side: str) -> np.ndarray:
        origin, rot = self.world.link_frame(f"forearm_{side}")
        b = self.body
        tip = origin - rot[:, 2] * (b.forearm_m + b.grip_m + b.stick_m)
        return tip - np.array([0.0, 0.0, self.cfg.model.sticks.tip_radius_m])

    # -- the patient ---------------------------------------------------------------------------

    def _set_phase(self, phase: Phase) -> None:
        self.phase, self.phase_t = phase, 0.0

    def _start_stick_moves(self) -> None:
        self.stick_queue = list(SIDES) if self.together else sorted(SIDES, key=lambda s: self.tip_point(s)[0])
        self._next_step.intention_m = self.intention.next_m()
        self._set_phase(Phase.SHIFT)

    def _stick_goal(self, side: str, start: np.ndarray) -> np.ndarray:
        """Where a lifted stick goes: the intention plus its placement error ahead of the CoM (or the
        front ankle, ``intention.reference``), at
        least ``stick_min_advance_m`` ahead of where it stood and no farther than the straight arm
        and stick reach less ``stick_reach_margin_m`` (either clamp counted in ``clamps`` and the
        step's record, which also keeps the mean goal ahead of the reference)."""
        pc = self.cfg.patient
        sign = 1.0 if side == "l" else -1.0
        if pc.intention.reference == "com":
            origin_x = float(self.kin.com[0])
        else:
            origin_x = max(float(self.ankle_xy(f)[0]) for f in SIDES)
        x = origin_x + self._next_step.intention_m + float(self.rng.normal(0.0, pc.stick_noise_m))
        y, z = sign * pc.stick_half_width_m, self.cfg.model.sticks.tip_radius_m
        origin, rot = self.world.link_frame("trunk")
        shoulder = origin + rot @ np.array([0.0, sign * self.body.shoulder_half_width_m, self.body.shoulder_above_hip_m])
        up, low = self.body.arm_reach_m
        reach = math.sqrt(up * up + low * low + 2 * up * low * math.cos(MIN_ELBOW))
        across = reach * reach - (y - shoulder[1]) ** 2 - (z - shoulder[2]) ** 2
        far = shoulder[0] + math.sqrt(max(across, 0.0))
        near = float(start[0]) + pc.stick_min_advance_m
        reason = "reach" if x > far else "advance" if x < near else None
        record = self._next_step
        if reason is not None:
            x = far if reason == "reach" else near
            self.clamps[reason] += 1
            record.clamped += 1
        ahead = x - origin_x  # the step's sticks: their mean
        record.placed_ahead_m = ahead if math.isnan(record.placed_ahead_m) else (record.placed_ahead_m + ahead) / 2
        return np.array([x, y, 0.0])

    def _lean_goal_x(self) -> float:
        """Where the patient leans to once both sticks are placed: ``lean_behind_sticks`` behind them
        (the intention sets how far), and past the stance ankle by at least ``lean_past_stance`` (a
        swing that starts with the CoM over or behind the stance heel tips the body backward, as
        sticks can push but not pull) and at most ``lean_most_past_stance`` (its comfort)."""
        s = self.s
        tips_x = float(np.mean([self.tip_point(side)[0] for side in SIDES]))
        stance_x = float(self.ankle_xy(OTHER[self.next_swing])[0])
        if LEAN_X:
            heel = stance_x - self.cfg.model.foot.heel_back_m
            return heel + LEAN_X * (tips_x - heel)
        return clamp(tips_x - s.lean_behind_sticks_m, stance_x + s.lean_past_stance_m, stance_x + s.lean_most_past_stance_m)

    def _lifting(self) -> list[str]:
        """The stick(s) the patient lifts next."""
        return self.stick_queue[:2] if self.together else self.stick_queue[:1]

    def _remaining_tips(self) -> list[str]:
        """The planted sticks that stay down when the next stick(s) lift."""
        lifting = self._lifting()
        return [side for side in SIDES if side not in lifting and self.planted[side]]

    def _shift_target(self) -> np.ndarray:
        """Where the CoM must be before the next stick(s) lift: inside the support that remains."""
        ankles, tip_xy = self._support_points(self._remaining_tips())
        lo, hi = ankles[:, 0].min(), ankles[:, 0].max()
        x = float(self.kin.com[0])
        m = self.s.shift_margin_m
        if self.cfg.mode == "sagittal":
            return np.array([np.clip(x, lo + m, max(hi - m, lo + m)), 0.0])
        # 3-D: the legs have no frontal-plane joints, so the patient cannot carry the CoM sideways
        # (docs/SIM.md item 13); it moves fore-aft only, to the nearest point that the remaining
        # support holds with margin.
        poly = convex_hull_2d(pivot_polygon(ankles, tip_xy, ankle_halfwidth=self.cfg.model.foot.half_width_m))
        y = float(self.kin.com[1])
        far = max(hi, *tip_xy[:, 0]) if len(tip_xy) else hi
        xs = np.linspace(lo - self.cfg.model.foot.heel_back_m, (hi + far) / 2, 61)
        margins = np.array([stability_margin(poly, (xi, y)) for xi in xs])
        ok = margins >= m
        best = xs[ok][np.argmin(np.abs(xs[ok] - x))] if ok.any() else xs[np.argmax(margins)]
        return np.array([best, y])

    def _shift_margin(self) -> float:
        """How far the CoM is inside the support that stays when the next stick(s) lift."""
        return self._support_margin(tips=self._remaining_tips())

    def patient_state(self) -> dict:
        """Where the patient is in its gait, for a report (a walk that makes no progress says whom it
        waits for): its phase and how long it has been in it, the sticks it has still to move, and
        in the weight shift how far the CoM is inside the support that stays when they lift
        (the patient lifts at ``shift_margin_m / 2``)."""
        state = {"phase": self.phase.value, "phase_s": round(self.phase_t, 2), "sticks_to_move": list(self.stick_queue)}
        if self.phase is Phase.SHIFT:
            state["shift_margin_m"] = round(self._shift_margin(), 4)
        return state

    def intentions_m(self) -> list[float]:
        """The intended placement of every step whose swing the patient has sensed, and last that of
        the step in the making (its stick moves may have been drawn already)."""
        return [s.intention_m for s in self.steps] + [self._next_step.intention_m]

    def patient_update(self, reading) -> None:
        s, dt = self.s, self.dt_control
        self.phase_t += dt
        com = self.kin.com
        if self.phase is Phase.SETTLE:
            if self.phase_t >= s.settle_s and self.walking:
                self._start_stick_moves()
            return
        if self.phase is Phase.SHIFT:
            target = self._shift_target()
            self.com_target += np.clip(target - self.com_target, -s.shift_speed_m_s * dt, s.shift_speed_m_s * dt)
            # The patient lifts a stick only once the CoM is where the remaining support holds it;
            # a patient who cannot get there waits (the walk stalls rather than falls).
            settled = self._shift_margin() >= s.shift_margin_m / 2 and np.linalg.norm(self.kin.com_velocity[:2]) < s.shift_still_speed_m_s
            if settled and self.phase_t > s.shift_min_s:
                for side in self._lifting():
                    self.unloading[side] = 0.0
                self._set_phase(Phase.STICKS)
            return
        if self.phase is Phase.STICKS:
            for side in list(self.unloading):
                self.unloading[side] += dt
                if self.unloading[side] >= s.unload_time_s:
                    del self.unloading[side]
                    self.planted[side] = False
                    start = self.tip_point(side)
                    self.tip_path[side] = (start, self._stick_goal(side, start), 0.0)
            for side, (start, goal, tau) in list(self.tip_path.items()):
                tau += dt / s.stick_move_time_s
                if tau >= 1.0 and reading.stick_force_n[SIDES.index(side)] > s.stick_planted_n:
                    del self.tip_path[side]
                    self.planted[side] = True
                    self.stick_queue.remove(side)
                else:
                    self.tip_path[side] = (start, goal, min(tau, 1.3))
            if not self.unloading and not self.tip_path:
                if self.stick_queue:
                    self._set_phase(Phase.SHIFT)
                else:
                    self.lean_goal_x = self._lean_goal_x()
                    self.lean_rest_s = 0.0
                    self._set_phase(Phase.LEAN)
            return
        if self.phase in (Phase.LEAN, Phase.SWING):
            sticks = reading.stick_force_n
            step = s.lean_speed_m_s * dt
            comfortable = max(sticks) < s.stick_force_comfort_n
            if self.phase is Phase.LEAN and not self.scripted_exo:
                # A lean at rest on the feet alone (the passive ankles' springs carry the CoM over
                # the soles; the trailing leg straight, the hips go no farther), a stick carrying
                # less than a swing wants: the exoskeleton waits for the sticks, so the patient
                # presses on them (control(): the sticks' share made cheaper), docs/SIM.md item 23.
                resting = abs(self.kin.com_velocity[0]) < s.still_speed_m_s and min(sticks) < s.swing_trigger_stick_n
                self.lean_rest_s = self.lean_rest_s + dt if resting else 0.0
            if not self.scripted_exo and comfortable:
                # The legs may carry the body toward the goal faster than the patient would: it
                # goes along, up to its goal (past it, it holds the body back).
                self.com_target[0] = max(self.com_target[0], min(float(com[0]), self.lean_goal_x))
            if self.com_target[0] < self.lean_goal_x and comfortable:
                self.com_target[0] = min(self.com_target[0] + step, self.lean_goal_x)
            self.com_target[1] += clamp(0.0 - self.com_target[1], -step, step)

    # -- the exoskeleton's scripted gait -------------------------------------------------------

    def exo_update(self, reading) -> None:
        if not self.scripted_exo:
            self._sense_steps(reading)
            return
        s = self.s
        plantar = reading.heel_force_n + reading.toe_force_n
        if self.phase is Phase.LEAN and self.swing_leg is None:
            loaded = all(reading.stick_force_n > s.swing_trigger_stick_n) and all(plantar > s.foot_contact_n)
            lead = self.kin.com[0] - self.ankle_xy(OTHER[self.next_swing])[0]
            leaned = loaded and lead >= s.lean_past_stance_m - s.lean_tolerance_m and self.phase_t > 0.3
            if LEAN_X:
                leaned = loaded and self.kin.com[0] >= self.lean_goal_x - 0.01 and self.phase_t > 0.3
            # A lean that stops short (the trailing leg straight, item 12 of docs/SIM.md) with the
            # CoM past the stance ankle: the step starts anyway, as the patient's step button would.
            stalled = (
                self.phase_t > s.stalled_lean_s and lead >= s.stalled_lean_lead_m
                and abs(self.kin.com_velocity[0]) < s.still_speed_m_s and all(plantar > s.foot_contact_n)
            )
            if leaned or stalled:
                self._start_swing(self.next_swing)
            return
        if self.phase is Phase.SWING and self.swing_leg is not None:
            leg = self.swing_leg
            down = plantar[SIDES.index(leg)] > s.foot_contact_n
            if (self.phase_t > 0.75 * s.swing_time_s and down) or self.phase_t > s.swing_time_s + 1.0:
                self._land(bool(down))

    def _start_swing(self, leg: str) -> None:
        st = OTHER[leg]
        heel = self.ankle_xy(st)[0] - self.cfg.model.foot.heel_back_m
        tips = max(self.tip_point(side)[0] for side in SIDES)
        self._next_step.x_swing = float((self.kin.com[0] - heel) / (tips - heel))
        self.swing_leg = leg
        self.stance_feet[leg] = False
        self.stance_feet[OTHER[leg]] = True  # whatever its load said before: it carries the body now
        self.swing_start = self.ankle_xy(leg)
        self.swing_hip_x0 = self.hip_cmd_x
        self.swing_goal = np.array([self.ankle_xy(OTHER[leg])[0] + self.s.step_length_m, self.swing_start[1]])
        self.steps.append(dataclasses.replace(self._next_step, index=len(self.steps), leg=leg))
        self._set_phase(Phase.SWING)

    def _land(self, down: bool) -> None:
        leg = self.swing_leg
        record = self.steps[-1]
        record.end_s, record.landed = self.t, down
        self._next_step = StepRecord(index=-1, leg="", start_s=self.t)
        self.stance_feet[leg] = True
        self.swing_leg = None
        self.next_swing = OTHER[leg]
        # Load acceptance: the patient takes the CoM from where the landing left it (often
        # ahead of the front foot, on the sticks) rather than snapping back to the target
        # of the lean, which throws the body backward off the new support.
        self.com_target = self.kin.com[:2].copy()
        self._start_stick_moves()

    def _sense_steps(self, reading) -> None:
        """The patient's view of a step the exoskeleton makes: a foot that stays unloaded for
        ``foot_lift_s`` and is raised ``foot_raise_m`` off the floor has left it (a swing: the
        patient feels the leg lifted, not merely unloaded as a rear foot is when the CoM passes
        over the front one), and the swing ends when it carries load again."""
        s = self.s
        plantar = reading.heel_force_n + reading.toe_force_n
        for i, side in enumerate(SIDES):
            self.unloaded_s[side] = self.unloaded_s[side] + self.dt_control if plantar[i] < s.foot_contact_n else 0.0
        if self.swing_leg is None:
            lifted = [
                side for side in SIDES
                if self.unloaded_s[side] >= s.foot_lift_s
                and self.kin.joint_origin[self.ankle_idx[side]][2] - self.body.ankle_height_m > s.foot_raise_m
            ]
            if len(lifted) == 1 and self.phase is Phase.LEAN:
                self.next_swing = lifted[0]
                self._start_swing(lifted[0])
            else:  # a foot lifted outside the patient's lean: balance on what is down, no step
                # (a foot on the floor is support whatever it carries now: its load follows the CoM)
                for side in SIDES:
                    off = self.kin.joint_origin[self.ankle_idx[side]][2] - self.body.ankle_height_m > _OFF_FLOOR_M
                    self.stance_feet[side] = not (self.unloaded_s[side] >= s.foot_lift_s and off)
                if not any(self.stance_feet.values()):
                    self.stance_feet = {"l": True, "r": True}  # airborne: keep the model's legs
        elif self.unloaded_s[self.swing_leg] == 0.0 and self.phase_t >= s.foot_lift_s:
            self._land(True)

    def swing_target(self) -> np.ndarray:
        """Ankle (x, z) of the swing leg: lift, advance, descend (minimum-jerk blends)."""
        s = self.s
        u = min(self.phase_t / s.swing_time_s, 1.0)

        # The ankle rises over the first 30 % of the swing, advances from 15 % to 85 %, and comes
        # down over the last 30 % (the shape of the scripted swing; the controller's DMP has its own).
        x = self.swing_start[0] + (self.swing_goal[0] - self.swing_start[0]) * _minimum_jerk((u - 0.15) / 0.7)
        lift = _minimum_jerk(u / 0.3) - _minimum_jerk((u - 0.7) / 0.3)
        z = self.body.ankle_height_m + s.swing_clearance_m * lift + (0.0 if u < 1.0 else -0.01)
        return np.array([x, z])

    # -- joint commands ------------------------------------------------------------------------

    def control(self, reading) -> None:
        w, kin, s = self.world, self.kin, self.s
        com = kin.com
        trunk_origin, trunk_rot = w.link_frame("trunk")
        rpy = rpy_from_matrix(trunk_rot)
        links = w.link_states()
        base_v, omega = links.com_velocity[0], links.base_angular_velocity
        feet = [side for side in SIDES if self.stance_feet[side]]
        tips = [side for side in SIDES if self.planted[side]]
        # Where the stance legs carry the hip: the patient's lean sets x (rate-limited), height is
        # the stance height as far as every stance foot can reach.
        dt = self.dt_control
        want_x = trunk_origin[0] + (self.com_target[0] - com[0])
        back = s.shift_speed_m_s if self.phase is Phase.SHIFT else s.hip_speed_m_s
        self.hip_goal[0] += clamp(want_x - self.hip_goal[0], -back * dt, s.hip_speed_m_s * dt)
        reach = min(
            math.sqrt(max(s.leg_reach_m**2 - (self.hip_goal[0] - self.ankle_xy(f)[0]) ** 2, 0.05)) for f in feet
        )
        z_goal = min(self.hip_height_nominal, self.body.ankle_height_m + reach)
        self.hip_goal[1] += clamp(z_goal - self.hip_goal[1], -0.1 * dt, 0.1 * dt)
        hip_target = self.hip_goal[1]
        self.pitch_goal += clamp(s.trunk_pitch_rad - self.pitch_goal, -0.2 * dt, 0.2 * dt)
        # Stance feet rest on the floor: the body above the ankles is what the contacts must carry.
        foot_links = {f: w.link_index[f"foot_{f}"] for f in feet}
        carried = w.total_mass - sum(w.masses[i + 1] for i in foot_links.values())
        wrench = desired_wrench(
            carried, com, kin.com_velocity, self.com_target, trunk_origin[2], hip_target, base_v[2],
            rpy, trunk_rot.T @ omega, np.array([0.0, s.trunk_pitch_rad]), self.gains,
        )
        # In 3-D the legs (hip and knee pitch only) cannot push sideways: the sticks carry the
        # lateral force and the roll moment.
        lateral = self.cfg.mode == "sagittal"
        contacts = []
        hw = self.cfg.model.foot.half_width_m
        for f in feet:
            a = kin.joint_origin[self.ankle_idx[f]]
            across = kin.joint_axis[self.ankle_idx[f]]
            for sgn in (-1.0, 1.0):
                contacts.append(Contact(f"foot_{f}", self.ankle_idx[f], a + sgn * hw * across, 1e-4, FEET_LATERAL))
        pressing = self.phase is Phase.LEAN and self.lean_rest_s >= s.stalled_lean_s
        for t in tips:
            if t in self.unloading:
                cost = 4e-4 * (1.0 + 400.0 * (self.unloading[t] / s.unload_time_s) ** 2)
            else:
                cost = 4e-4 * s.press_stick_cost if pressing else 4e-4
            sign = 1.0 if t == "l" else -1.0
            shoulder = trunk_origin + trunk_rot @ np.array([0.0, sign * self.body.shoulder_half_width_m, self.body.shoulder_above_hip_m])
            tp = self.tip_point(t)
            axis = (shoulder - tp) / np.linalg.norm(shoulder - tp) if STRUT else None
            contacts.append(Contact(f"tip_{t}", self.forearm_idx[t], tp, cost, True, axis, STRUT_SPREAD))
        # A stance foot's spring acts on its shank with minus the ankle torque about the ankle axis.
        ankle = self.cfg.model.joints.ankle
        spring = np.zeros(3)
        for f in feet:
            j = self.ankle_idx[f]
            spring -= -ankle.stiffness_nm_rad * (w.q[j] - ankle.rest_rad) * kin.joint_axis[j]
        forces, self.residual = distribute(
            wrench, com, contacts, mu=0.5, min_normal_n=s.min_contact_n,
            weights=np.array([1.0, 1.0, 1.0, 2.0, 2.0, 0.5]), known_moment=spring,
        )
        if LEG_FF == "exo":
            # the exoskeleton's own balance: the same wrench, the sticks' measured forces known, the rest over the feet
            from sim.sensors import contact_force_on_robot
            known = np.zeros(6)
            for t in SIDES:
                for cp in w.contacts(f"forearm_{t}"):
                    f_ = contact_force_on_robot(cp); r_ = np.array(cp[6]) - com
                    known[:3] += f_; known[3:] += np.cross(r_, f_)
            feet_contacts = [c for c in contacts if c.name.startswith("foot")]
            wr = wrench.copy(); wr -= known
            ff_forces, _ = distribute(wr, com, feet_contacts, mu=0.5, min_normal_n=s.min_contact_n,
                                      weights=np.array([1.0, 1.0, 1.0, 2.0, 2.0, 0.5]), known_moment=spring)
            fl = [contact.link for contact in feet_contacts]
            feet_i = [w.link_index[f"foot_{f}"] for f in feet]
            fp = [contact.point for contact in feet_contacts]
            g0 = kin.gravity_torques()
            self._tau_exo = g0 - kin.generalised_force(feet_i + fl, [kin.link_com[i + 1] for i in feet_i] + fp,
                                                      [(0.0, 0.0, w.masses[i + 1] * GRAVITY) for i in feet_i] + list(ff_forces)) if fl else g0
        g = kin.gravity_torques()  # the arms' and the swing leg's feed-forward
        # minus the contact forces: the stance legs' and planted arms' share; and the floor holds a
        # stance foot up, not the leg
        feet_i = list(foot_links.values())
        links = feet_i + [contact.link for contact in contacts]
        points = [kin.link_com[i + 1] for i in feet_i] + [contact.point for contact in contacts]
        loads = [(0.0, 0.0, w.masses[i + 1] * GRAVITY) for i in feet_i] + list(forces)
        tau = g - kin.generalised_force(links, points, loads) if links else g.copy()
        if LEG_FF == "vertical":
            vloads = [np.array([0.0, 0.0, l[2]]) if (c_i >= len(feet_i) and contacts[c_i - len(feet_i)].name.startswith("foot")) else np.asarray(l, float) for c_i, l in enumerate(loads)]
            self._tau_vertical = g - kin.generalised_force(links, points, vloads) if links else g.copy()
        if self.scripted_exo:
            self._command_legs(reading, tau, g, trunk_origin, rpy[1])
        # Patient: planted arms push (torque feed-forward), moving arms follow their tip path.
        targets: list[float] = []
        torques: list[float] = []
        for side in SIDES:  # in the arms' joint order (ARM_JOINT_NAMES: left, then right)
            joints = self.arm_joints[side]
            if side in self.tip_path:
                start, goal, u = self.tip_path[side]
                point = start + (goal - start) * _minimum_jerk(u)
                lift = 4 * min(u, 1.0) * (1 - min(u, 1.0)) * s.stick_lift_m
                point = point + np.array([0.0, 0.0, lift - (0.02 if u >= 1.0 else 0.0) + self.cfg.model.sticks.tip_radius_m])
                sign = 1.0 if side == "l" else -1.0
                shoulder = trunk_origin + trunk_rot @ np.array([0.0, sign * self.body.shoulder_half_width_m, self.body.shoulder_above_hip_m])
                d = point - shoulder
                up, low = self.body.arm_reach_m
                n = float(np.linalg.norm(d))
                if n > up + low - 1e-4:
                    d = d * (up + low - 1e-4) / n
                try:
                    targets += arm_ik(trunk_rot.T @ d, up, low, side)
                except ValueError:
                    targets += [w.q[j] for j in joints]
                torques += [g[j] for j in joints]
            else:
                targets += [w.q[j] for j in joints]
                torques += [tau[j] for j in joints]
        arms = w.arms
        arms.track(np.minimum(np.maximum(targets, arms.lower + 1e-3), arms.upper - 1e-3),
                   np.minimum(np.maximum(torques, -arms.rated), arms.rated))

    def _lever_leg_torques(self, reading, g, cop=False):
        w, kin = self.world, self.kin
        feet = [s_ for s_ in SIDES if self.stance_feet[s_]]
        carried = w.total_mass * GRAVITY - float(np.sum(reading.stick_force_n)) - sum(w.masses[self.ankle_idx[f] + 1] for f in feet) * GRAVITY
        carried = max(carried, 0.0)
        xs = {f: kin.joint_origin[self.ankle_idx[f]][0] for f in feet}
        com = kin.com[0]
        if cop:
            h = kin.com[2] - self.body.ankle_height_m
            acc = COP_K * (self.com_target[0] - com) - COP_D * kin.com_velocity[0]
            com = com - acc * h / GRAVITY
        if len(feet) == 2:
            a, b = xs["l"], xs["r"]
            share_l = 0.5 if abs(a - b) < 1e-3 else min(max((com - b) / (a - b), 0.0), 1.0)
            shares = {"l": share_l, "r": 1.0 - share_l}
        else:
            shares = {feet[0]: 1.0}
        links, pts, fs = [], [], []
        for f in feet:
            li = self.ankle_idx[f]
            links.append(li); pts.append(kin.joint_origin[li].copy()); fs.append(np.array([0.0, 0.0, carried * shares[f]]))
        return g - kin.generalised_force(links, np.array(pts), np.array(fs))

    def _plantar_leg_torques(self, reading, g):
        w, kin = self.world, self.kin
        plantar = reading.heel_force_n + reading.toe_force_n
        if not hasattr(self, "_pf"):
            self._pf = np.array(plantar, float)
        self._pf += PLANTAR_ALPHA * (plantar - self._pf)
        links, pts, fs = [], [], []
        for i, side in enumerate(SIDES):
            if not self.stance_feet[side]:
                continue
            li = self.ankle_idx[side]
            links.append(li); pts.append(kin.joint_origin[li].copy()); fs.append(np.array([0.0, 0.0, float(self._pf[i]) - w.masses[li + 1] * GRAVITY]))
        if not links:
            return g
        return g - kin.generalised_force(links, np.array(pts), np.array(fs))

    def _measured_leg_torques(self, g):
        from sim.sensors import contact_force_on_robot
        w, kin = self.world, self.kin
        links, pts, fs = [], [], []
        for side in SIDES:
            li = w.link_index[f"foot_{side}"]
            for cp in w.contacts(f"foot_{side}"):
                links.append(li); pts.append(np.array(cp[6])); fs.append(contact_force_on_robot(cp))
        if not links:
            return g
        return g - kin.generalised_force(links, np.array(pts), np.array(fs))

    def _command_legs(self, reading, tau: np.ndarray, g: np.ndarray, trunk_origin: np.ndarray, pitch: float) -> None:
        """The scripted exoskeleton's node commands: every stance foot commanded where it stands (level,
        at the spacing measured while loaded), the hips commanded toward their goal (at most
        ``MAX_LEAD`` ahead of where they are), the swing leg along its path."""
        w, s, b = self.world, self.s, self.body
        plantar = reading.heel_force_n + reading.toe_force_n
        hip_now_x = float(trunk_origin[0])
        for i, side in enumerate(SIDES):
            if self.stance_feet[side] and (plantar[i] > s.foot_contact_n or side not in self.foot_x):
                self.foot_x[side] = float(self.ankle_xy(side)[0])
        if self.swing_leg is not None:
            u = min(self.phase_t / s.swing_time_s, 1.0)
            goal = self.swing_hip_x0 + HIP_ADVANCE * self.s.step_length_m * _minimum_jerk(u)
        else:
            goal = float(self.hip_goal[0])
        self.hip_cmd_x = clamp(goal, hip_now_x - MAX_LEAD, hip_now_x + MAX_LEAD)
        if self.swing_leg is not None:
            self.hip_cmd_x = hip_now_x + (goal - self.swing_hip_x0) * 0 + SWING_LEAD
        hip_z = float(self.hip_goal[1])
        for side in SIDES:
            hip_i, knee_i = self.leg_joints[side]
            n_hip, n_knee = w.exo.index(f"hip_{side}"), w.exo.index(f"knee_{side}")
            if side == self.swing_leg:
                target = self.swing_target()
                rel = target - np.array([trunk_origin[0], trunk_origin[2]])
                hip_pitch = pitch
                ff = (clamp(g[hip_i], -90, 90), clamp(g[knee_i], -90, 90))
            else:
                rel = np.array([self.foot_x[side] - self.hip_cmd_x, b.ankle_height_m - hip_z])
                hip_pitch = self.pitch_goal
                if LEG_FF == "exo":
                    ff = (self._tau_exo[hip_i], self._tau_exo[knee_i])
                elif LEG_FF == "cop":
                    tl = self._lever_leg_torques(reading, g, cop=True)
                    ff = (tl[hip_i], tl[knee_i])
                elif LEG_FF == "lever":
                    tl = self._lever_leg_torques(reading, g)
                    ff = (tl[hip_i], tl[knee_i])
                elif LEG_FF == "plantar":
                    tp = self._plantar_leg_torques(reading, g)
                    ff = (tp[hip_i], tp[knee_i])
                elif LEG_FF == "vertical":
                    ff = (self._tau_vertical[hip_i], self._tau_vertical[knee_i])
                elif LEG_FF == "meas":
                    tm = self._measured_leg_torques(g)
                    ff = (tm[hip_i], tm[knee_i])
                else:
                    ff = (LEG_FF * tau[hip_i], LEG_FF * tau[knee_i])
            self.dbg[side] = (np.round(rel, 3).tolist(), round(hip_pitch, 3))
            r = float(np.hypot(*rel))
            reach = b.thigh_m + b.shank_m - 0.01
            if r > reach:
                rel = rel * reach / r
            try:
                h_world, knee = leg_ik(rel, b.thigh_m, b.shank_m)
            except ValueError:
                h_world, knee = w.q[hip_i] - pitch, w.q[knee_i]
            for n, target, torque, last in ((n_hip, h_world + hip_pitch, ff[0], self.leg_target[n_hip]), (n_knee, knee, ff[1], self.leg_target[n_knee])):
                if side != self.swing_leg:
                    target = last + clamp(target - last, -MAX_STEP, MAX_STEP)
                q_cmd = clamp(target, w.exo.lower[n] + 1e-3, w.exo.upper[n] - 1e-3)
                self.leg_target[n] = q_cmd
                w.exo.command(n, Mode.TRACK, q_cmd, 0.0, clamp(torque, -100.0, 100.0))

    # -- the loop ------------------------------------------------------------------------------

    def _support_points(self, tips: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(k, 2) stance ankles and (j, 2) points of the stick tips ``tips``, on the floor plane."""
        ankles = np.array([self.ankle_xy(s) for s in SIDES if self.stance_feet[s]]).reshape(-1, 2)
        return ankles, np.array([self.tip_point(s)[:2] for s in tips]).reshape(-1, 2)

    def _support_margin(self, tips: list[str] | None = None) -> float:
        """Static stability margin of the CoM over the stance ankles and ``tips`` (by default every
        planted tip). In 3-D the pivot polygon; in the sagittal mode, where the plane spring holds
        the trunk laterally, its fore-aft extent (two ankles at different y would otherwise make a
        thin diagonal strip that says nothing about the sagittal balance)."""
        ankles, tip_xy = self._support_points([s for s in SIDES if self.planted[s]] if tips is None else tips)
        com = self.kin.com[:2]
        if self.cfg.mode == "sagittal":
            xs = np.concatenate([ankles[:, 0], tip_xy[:, 0]])
            return float(min(com[0] - xs.min(), xs.max() - com[0]))
        poly = pivot_polygon(ankles, tip_xy, ankle_halfwidth=self.cfg.model.foot.half_width_m)
        return float(stability_margin(poly, com))

    def x_ratio_truth(self, foot_n: float, stick_n: float, min_support_m: float) -> float:
        """Ground truth of X_CoM/X_SP: the CoM's fore-aft place, along the trunk's heading, in the
        pivot polygon of the feet carrying more than ``foot_n`` and the sticks carrying more than
        ``stick_n``; nan for a polygon shorter than ``min_support_m`` fore-aft (the rules of the
        controller's estimator, which computes it from the sensors)."""
        w = self.world
        feet = [s for s in SIDES if w.contact_normal_force(f"foot_{s}") > foot_n]
        tips = [s for s in SIDES if w.contact_normal_force(f"forearm_{s}") > stick_n]
        ankles = np.array([self.ankle_xy(s) for s in feet]).reshape(-1, 2)
        tip_xy = np.array([self.tip_point(s)[:2] for s in tips]).reshape(-1, 2)
        poly = pivot_polygon(ankles, tip_xy, ankle_halfwidth=self.cfg.model.foot.half_width_m)
        heading = w.link_frame("trunk")[1][:2, 0]
        heading = heading / np.linalg.norm(heading)
        extent = poly @ heading if len(poly) else np.zeros(1)
        if float(extent.max() - extent.min()) < min_support_m:
            return math.nan
        return fore_aft_ratio(poly, self.kin.com[:2], heading=heading)

    def start(self):
        """Latch the initial posture as the targets; returns the first sensor reading."""
        w = self.world
        self.kin.update()
        self.com_target = self.kin.com[:2].copy()
        origin, rot = w.link_frame("trunk")
        self.hip_goal = np.array([origin[0], origin[2]])
        self.hip_cmd_x = float(origin[0])
        self.foot_x = {}
        self.dbg = {}
        self.leg_target = [float(w.q[w.joint_index[n]]) for n in ("hip_l", "knee_l", "hip_r", "knee_r")]
        self.pitch_goal = float(rpy_from_matrix(rot)[1])
        self.hip_height_nominal = float(origin[2])
        return self.sensors.read()

    def tick(self, reading):
        """One 20 ms tick: the patient (and the scripted exoskeleton) act on ``reading``, the
        physics advances, and the sensors are sampled again; returns the new reading."""
        w = self.world
        self.patient_update(reading)
        self.exo_update(reading)
        self.control(reading)
        for _ in range(self.ticks_per_control):
            w.step()
        self.t += self.dt_control
        self.kin.update()
        margin = self._support_margin()
        step = self.steps[-1] if self.steps and not self.steps[-1].landed else self._next_step
        step.add(float(np.mean(reading.stick_force_n)), float(np.sum(np.abs(w.arms.applied))), margin)
        self.margin = margin
        self.fall = self._fall_reason()
        return self.sensors.read()

    def _fall_reason(self) -> str | None:
        """Ground truth (:class:`sim.truth.FallCriteria`): a link other than a foot or a stick
        touches the floor, or the trunk rolls, pitches or sinks beyond the configured limits; the
        reason names the fall's direction (``lateral``, ``forward`` or ``backward`` from the trunk's
        attitude), which :attr:`fall_direction` keeps."""
        w = self.world
        origin, rot = w.link_frame("trunk")
        roll, pitch, _ = rpy_from_matrix(rot).tolist()
        reason = self._fall_criteria.check(w.touching_links(), roll, pitch, float(origin[2]))
        if reason is None:
            return None
        self.fall_direction = FallCriteria.direction(roll, pitch, self.s.trunk_pitch_rad)
        return f"{self.fall_direction} fall: {reason}"

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
                result.fall_phase = self.phase.value
                result.fall_step = len(self.steps)
                result.fall_margin_m = round(self.margin, 4)
                result.fall_direction = self.fall_direction
                break
            if sum(1 for r in self.steps if r.landed) >= max_steps:
                break
        result.steps = self.steps
        result.duration_s = self.t
        return result


MIN_ELBOW = 0.3
LEAN_X = 0.55
HIP_ADVANCE = 0.0
MAX_LEAD = 0.02
MAX_STEP = 0.078
SWING_LEAD = 0.0
LEG_FF = "exo"
PLANTAR_ALPHA = 0.5
COP_K = 15.0
COP_D = 5.0
STRUT = True
STRUT_SPREAD = 0.15
INIT_TIPS_X = 0.30
FEET_LATERAL = True
_ALLOWED_CONTACTS = frozenset({"foot_l", "foot_r", "forearm_l", "forearm_r"})
_OFF_FLOOR_M = 0.005  # an unloaded foot whose ankle is this much higher than standing is off the floor


def _minimum_jerk(a: float) -> float:
    """Minimum-jerk blend ``10 a^3 - 15 a^4 + 6 a^5`` from 0 to 1, clamped outside [0, 1]."""
    a = min(max(a, 0.0), 1.0)
    return a * a * a * (10 - 15 * a + 6 * a * a)


def initial_pose(cfg: SimConfig) -> StancePose:
    ahead = INIT_TIPS_X
    w = cfg.patient.stick_half_width_m
    return StancePose(foot_x_m=(0.06, -0.06), tip_xy_m=((ahead, w), (ahead, -w)), trunk_pitch_rad=0.10, hip_x_m=0.05, knee_rad=0.08)


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


