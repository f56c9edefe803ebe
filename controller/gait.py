"""The exoskeleton's legs through the gait cycle, from the state estimate alone (pure numpy).

The patient moves the sticks (where it places them is its intention) and balances with its arms;
the exoskeleton carries the body where only its legs can and makes the steps. With passive
ankles the legs can move the body fore-aft only while both feet are loaded (a closed chain over
two ankle pins); on one loaded foot the body turns freely about that ankle and the patient's
sticks hold it. One gait cycle, per leg (docs/CONTROLLER.md):

1. **Double support, weight shift.** Until both sticks have moved, the legs carry the CoM to the
   nearest point ``shift_margin`` inside the ankles' span (approaching it with time constant
   ``shift_time``, at most ``shift_speed``), where the patient can lift the sticks; they hold still
   while a stick is in the air. A stick has moved once it was off the floor (filtered force below
   ``stick_lifted_n`` for ``stick_lift_s``) and was planted again (above ``stick_placed_n``) at
   least ``stick_moved_m`` farther forward than it stood at the last landing.
2. **Double support, lean.** With both sticks moved, the legs carry the CoM forward (at
   ``lean_speed``, pausing while a stick carries ``comfort_stick_n``) until the swing foot is free
   (below ``foot_free_n`` for ``foot_free_s``): a trailing foot at its ankle's stop
   props the body on its toe, farther ahead the shorter the step, so a short step needs a lean
   farther onto the sticks. The patient lets the lean go at most ``lean_past_goal`` past its own
   goal, ``lean_behind_tips`` behind the mean stick tip (where it placed the sticks is its
   intention) and at least ``lean_over_stance`` past the stance ankle (sticks cannot pull: a swing
   with the CoM over or behind the stance ankle tips the body backward). The step is ready when
   both sticks carry ``swing_stick_n``, stand ``tips_ahead`` ahead of the front ankle, and the
   lean is over: the swing foot free, the CoM at the patient's limit, or no farther forward by
   ``lean_stall_m`` for ``lean_stall_s`` (``lean_start_s`` until the lean has first moved that far:
   the body, still coming back from the stick moves, takes up to half a second to follow) with
   the CoM at least half of ``lean_over_stance`` past the stance ankle (a lean that stalls short of
   that waits: a stalled walk, not a swing that tips backward). Beyond that, no check of where the
   CoM is against the stance foot: that is the step length's job (the CoM compensation of the paper's
   equation (8)); a step too long for the patient's lean falls.
3. **Swing.** The swing ankle follows the DMP in the stance foot's frame, from where it is to
   the step length ahead of the stance ankle and ``landing_depth`` below it. The stance leg holds
   the hips' height and the trunk's pitch and lets the body turn about its ankle as the patient's
   sticks allow. The swing ends when the foot carries ``foot_contact_n`` after
   ``landing_fraction`` of the DMP's duration (a landing), or ``swing_timeout`` after its end.

Every leg target comes from the inverse kinematics of a commanded ankle position relative to the
hip in the heading frame; the hips' joint targets add the trunk's pitch goal (a stance leg) or
its measured pitch (the swing leg). A stance leg's commanded ankle leads its measured one by at
most ``max_lead`` fore-aft (no wind-up when the body does not follow), a stance foot that carries
nothing is not pushed along the floor, and no joint target moves more than ``max_target_step``
per tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from config.controller_schema import GaitConfig
from controller import kinematics as kin
from controller.dmp import Dmp
from controller.estimator import Estimate, Measurements

LEFT, RIGHT = 0, 1
LEGS = (LEFT, RIGHT)


def _clip(value: float, lo: float, hi: float) -> float:
    """``np.clip`` of one float (the same result, NaN included, without the array call)."""
    return min(max(value, lo), hi)


@dataclass(frozen=True)
class DoubleSupport:
    """What a double-support tick found: whether the swing may start, and the part of double
    support the legs are in (``shift`` or ``lean``)."""

    ready: bool
    part: str
    lean_goal_x: float  # m, heading frame (nan in the shift)
    sticks_loaded: bool  # both (filtered) stick forces above swing_stick_n: planted and leant on


@dataclass(frozen=True)
class SwingTick:
    done: bool
    landed: bool  # the foot carries load (False: the swing timed out in the air)
    ankle_xz_m: np.ndarray  # the commanded swing ankle in the stance foot's frame


@dataclass
class StickTracker:
    """Which sticks the patient has moved since the last landing (see the module doc)."""

    params: GaitConfig
    dt_s: float
    force_n: np.ndarray = field(default_factory=lambda: np.zeros(2))  # filtered
    raw_n: np.ndarray = field(default_factory=lambda: np.zeros(2))  # this tick's
    unloaded_s: np.ndarray = field(default_factory=lambda: np.zeros(2))
    lifted: list[bool] = field(default_factory=lambda: [False, False])
    moved: list[bool] = field(default_factory=lambda: [False, False])
    ref_x: np.ndarray = field(default_factory=lambda: np.full(2, math.nan))  # tip - reference ankle, at the landing
    ref_leg: int = LEFT

    def reset(self, est: Estimate, ref_leg: int) -> None:
        """A new cycle: the sticks must move again; ``ref_leg``'s foot stays planted until the next
        swing starts, so tip positions are measured from its ankle."""
        self.ref_leg = ref_leg
        self.ref_x = est.tips[:, 0] - est.ankles[ref_leg][0]
        self.unloaded_s[:] = 0.0
        self.lifted = [False, False]
        self.moved = [False, False]

    def update(self, est: Estimate, m: Measurements) -> None:
        p = self.params
        a = min(1.0, self.dt_s / p.stick_filter_s) if p.stick_filter_s > 0 else 1.0
        self.raw_n = np.asarray(m.stick_force_n, dtype=float)
        raw, force, unloaded = self.raw_n.tolist(), self.force_n.tolist(), self.unloaded_s.tolist()
        ref_ankle_x = est.ankles[self.ref_leg][0]
        tips_x, ref_x = est.tips[:, 0].tolist(), self.ref_x.tolist()
        for i in LEGS:
            force[i] += a * (raw[i] - force[i])
            advance = tips_x[i] - ref_ankle_x - ref_x[i]
            unloaded[i] = unloaded[i] + self.dt_s if force[i] < p.stick_lifted_n else 0.0
            if unloaded[i] >= p.stick_lift_s:
                self.lifted[i] = True
            if self.lifted[i] and force[i] > p.stick_placed_n and advance >= p.stick_moved_m:
                self.moved[i] = True
        self.force_n[:], self.unloaded_s[:] = force, unloaded

    @property
    def loaded(self) -> bool:
        """Both sticks planted and leant on: their force above ``swing_stick_n``, filtered and now."""
        n = self.params.swing_stick_n
        (f_l, f_r), (r_l, r_r) = self.force_n.tolist(), self.raw_n.tolist()
        return f_l > n and f_r > n and r_l > n and r_r > n

    @property
    def any_lifted_now(self) -> bool:
        left, right = self.unloaded_s.tolist()
        return left > 0.0 or right > 0.0


class GaitPlanner:
    """Joint targets of the four joints (left hip, left knee, right hip, right knee) per tick.

    The planner keeps a commanded ankle position per leg, (x, z) from its hip in the heading
    frame, and the hips' stance height above the ankles.
    """

    def __init__(self, leg: kin.Leg, dmp: Dmp, params: GaitConfig, *, dt_s: float, substeps: int) -> None:
        self.leg, self.dmp, self.p = leg, dmp, params
        self.dt_s, self.substeps = dt_s, substeps
        self.sticks = StickTracker(params, dt_s)
        self.ankle_cmd = np.zeros((2, 2))
        self.stand_height_m = math.nan  # the hips above the ankles when walking started
        self.depth_m = math.nan  # the stance ankles below the hips now (lowered for a long stagger)
        self.hips_cmd_x = 0.0  # the hips' commanded place ahead of the mean stance ankle
        self.feet_spacing_m = math.nan  # right ankle less left ankle fore-aft, both planted
        self.pitch_goal_rad = 0.0
        self.targets = np.zeros(4)
        self.swing_leg: int | None = None
        self.swing_t = 0.0
        self.step_length_m = math.nan  # commanded
        self.aim_offset_m = 0.0  # how far beyond the commanded length the swings aim (foot placement)
        self._lean_best_x = -math.inf  # the farthest the CoM got in this lean, and how long since
        self._lean_still_s = 0.0
        self._lean_moved = False  # the CoM got lean_stall_m beyond where this lean started
        self._foot_free_s = 0.0  # how long the next swing's foot has been unloaded

    # -- set-up ----------------------------------------------------------------------------------

    def stand_here(self, est: Estimate, m: Measurements) -> None:
        """Take the measured posture: the stance height, the trunk pitch and the ankles where they
        are (at the start of walking, after a stop or a fault)."""
        self.stand_height_m = self.depth_m = -float(np.mean(est.ankles[:, 2]))
        self.pitch_goal_rad = float(m.trunk_rpy_rad[1])
        self.ankle_cmd = np.array([[est.ankles[i][0], est.ankles[i][2]] for i in LEGS])
        self.hips_cmd_x = -float(np.mean(est.ankles[:, 0]))
        self.targets = np.array(m.joint_position_rad, dtype=float)
        self.swing_leg = None
        self._new_cycle(est, ref_leg=int(np.argmin(est.ankles[:, 0])))

    def _new_cycle(self, est: Estimate, ref_leg: int) -> None:
        self.sticks.reset(est, ref_leg)
        self.feet_spacing_m = float(est.ankles[RIGHT][0] - est.ankles[LEFT][0])
        self._lean_best_x, self._lean_still_s, self._lean_moved = -math.inf, 0.0, False
        self._foot_free_s = 0.0

    def track_sticks(self, est: Estimate, m: Measurements) -> None:
        """Every walking tick: the stick moves since the last landing."""
        self.sticks.update(est, m)

    # -- the legs --------------------------------------------------------------------------------

    def _stance(self, legs: tuple[int, ...], est: Estimate, m: Measurements, dx: float) -> None:
        """Carry the hips ``dx`` forward over the planted ankles of ``legs``, at the stance height
        (lowered as far as the leg farthest from under the hips needs to reach its ankle).

        The ankles' midpoint is commanded where it is measured, shifted by the hips' commanded
        place relative to the feet less their measured place (at most ``max_lead`` fore-aft: a body
        that does not follow cannot wind the command up), and the two ankles at the feet's spacing
        on the floor: fore-aft as measured while both carry load, level in height (the floor is
        flat). The legs then agree on where the feet are (two position-controlled legs on two
        planted feet are a closed chain: commands that disagree push the feet apart or together
        and one of them off the floor; nearly straight legs are so stiff upward that a millimetre
        of height between the two commands puts the body's whole weight on one foot), and a foot
        that carries nothing is held where it stands instead of drifting with its own measurement.
        """
        p = self.p
        reach = self.leg.reach_m - p.reach_margin_m
        ankles = est.ankles.tolist()
        if len(legs) == 2:
            mid_x = (ankles[0][0] + ankles[1][0]) / 2  # the feet's mean, fore-aft
            load = (m.heel_force_n + m.toe_force_n).tolist()
            if load[0] > p.foot_contact_n and load[1] > p.foot_contact_n:
                self.feet_spacing_m = float(ankles[1][0] - ankles[0][0])
            offsets = (-0.5 * self.feet_spacing_m, 0.5 * self.feet_spacing_m)  # fore-aft; level in height
        else:
            mid_x = ankles[legs[0]][0]
            offsets = (0.0,)
        hips_x = -mid_x  # the hips ahead of the feet
        self.hips_cmd_x = _clip(self.hips_cmd_x + dx, hips_x - p.max_lead_m, hips_x + p.max_lead_m)
        mid_cmd_x = mid_x - (self.hips_cmd_x - hips_x)
        x_far = max(abs(mid_cmd_x + offset) for offset in offsets)
        depth = min(self.stand_height_m, math.sqrt(max(reach * reach - x_far * x_far, 0.0)))
        step = p.height_speed_m_s * self.dt_s
        self.depth_m += _clip(depth - self.depth_m, -step, step)
        for i, offset in zip(legs, offsets):
            self.ankle_cmd[i] = (mid_cmd_x + offset, -self.depth_m)

    def _solve(self, m: Measurements) -> None:
        """Joint targets for the commanded ankles. A target beyond the leg's reach less
        ``reach_margin`` is pulled in toward the hip (a straight knee makes the inverse kinematics
        ill-conditioned); an ankle the joint ranges cannot reach keeps the leg's targets."""
        reach = self.leg.reach_m - self.p.reach_margin_m
        step = self.p.max_target_step_rad
        pitch = self.pitch_goal_rad
        ankle_cmd, targets = self.ankle_cmd.tolist(), self.targets.tolist()
        for i in LEGS:
            x, z = ankle_cmd[i]
            r = math.hypot(x, z)
            if r > reach:
                x, z = x * reach / r, z * reach / r
            try:
                hip_world, knee = kin.inverse(self.leg, x, z)
            except kin.KinematicsError:
                continue
            h, k = 2 * i, 2 * i + 1
            targets[h] += _clip(hip_world + pitch - targets[h], -step, step)
            targets[k] += _clip(knee - targets[k], -step, step)
        self.targets[:] = targets

    # -- double support ----------------------------------------------------------------------------

    def double_support(self, est: Estimate, m: Measurements, swing_leg: int) -> DoubleSupport:
        """One double-support tick before the swing of ``swing_leg``."""
        p = self.p
        com_x = float(est.com[0])
        (ankle_l, _, _), (ankle_r, _, _) = est.ankles.tolist()
        (tip_l, _, _), (tip_r, _, _) = est.tips.tolist()
        front = max(ankle_l, ankle_r)
        if not all(self.sticks.moved):
            self._stance(LEGS, est, m, self._shift(est))
            self._solve(m)
            return DoubleSupport(False, "shift", math.nan, self.sticks.loaded)
        stance_x = (ankle_l, ankle_r)[1 - swing_leg]
        goal = max((tip_l + tip_r) / 2 - p.lean_behind_tips_m, stance_x + p.lean_over_stance_m)
        comfortable = max(m.stick_force_n.tolist()) < p.comfort_stick_n
        # The lean goes on until the swing foot is free: a trailing foot at its ankle's stop props
        # the body on its toe, farther ahead the shorter the step, so a short step needs a lean
        # farther onto the sticks. The patient lets it go at most ``lean_past_goal`` past its goal.
        unloaded = float(m.heel_force_n[swing_leg] + m.toe_force_n[swing_leg]) < p.foot_free_n
        self._foot_free_s = self._foot_free_s + self.dt_s if unloaded else 0.0
        free = self._foot_free_s >= p.foot_free_s
        reach = com_x if free else goal + p.lean_past_goal_m
        dx = min(p.lean_speed_m_s * self.dt_s, max(reach - com_x, 0.0)) if comfortable else 0.0
        self._stance(LEGS, est, m, dx)
        self._solve(m)
        progress = com_x - float(est.ankles[self.sticks.ref_leg][0])  # over a planted foot: the estimate's frame moves with the hips
        if progress > self._lean_best_x + p.lean_stall_m:
            # the lean's first tick sets where it starts; a new best after that: it has moved
            self._lean_moved = math.isfinite(self._lean_best_x)
            self._lean_best_x, self._lean_still_s = progress, 0.0
        else:
            self._lean_still_s += self.dt_s
        stalled = self._lean_still_s >= (p.lean_stall_s if self._lean_moved else p.lean_start_s)
        # a lean that stalls short of the stance ankle is not over: a swing from there tips backward
        over = free or com_x >= goal + p.lean_past_goal_m - p.lean_stall_m or (stalled and com_x >= stance_x + p.lean_over_stance_m / 2)
        ahead = tip_l > front + p.tips_ahead_m and tip_r > front + p.tips_ahead_m
        return DoubleSupport(over and ahead and self.sticks.loaded, "lean", goal, self.sticks.loaded)

    def _shift(self, est: Estimate) -> float:
        """How far to carry the hips forward this tick in the weight shift (0 with a stick in the air)."""
        p = self.p
        if self.sticks.any_lifted_now:
            return 0.0
        (x_l, _, _), (x_r, _, _) = est.ankles.tolist()
        com_x = float(est.com[0])
        lo, hi = min(x_l, x_r) + p.shift_margin_m, max(x_l, x_r) - p.shift_margin_m
        goal = (lo + hi) / 2 if lo > hi else min(max(com_x, lo), hi)
        step = p.shift_speed_m_s * self.dt_s
        return _clip((goal - com_x) * self.dt_s / p.shift_time_s, -step, step)

    # -- swing -------------------------------------------------------------------------------------

    def placed(self, commanded_m: float, placed_m: float) -> None:
        """A step ``commanded_m`` long was placed ``placed_m`` (measured once the double support after
        it was over): the next swings aim beyond the commanded length by ``placement_gain`` of the
        shortfall more (an integral loop on the placement, within ``max_aim_offset``). A length that
        is not a number changes nothing."""
        p = self.p
        if not (math.isfinite(commanded_m) and math.isfinite(placed_m)):
            return
        offset = self.aim_offset_m + p.placement_gain * (commanded_m - placed_m)
        self.aim_offset_m = _clip(offset, -p.max_aim_offset_m, p.max_aim_offset_m)

    def start_swing(self, leg: int, est: Estimate, length_m: float) -> float:
        """Start the swing of ``leg`` for a step ``length_m`` long; returns where it aims (the length
        plus the placement's offset)."""
        stance = 1 - leg
        start = est.ankles[leg] - est.ankles[stance]
        aim = length_m + self.aim_offset_m
        self.dmp.reset(x0=np.array([start[0], start[2]]), goal=np.array([aim, -self.p.landing_depth_m]))
        self.swing_leg, self.swing_t, self.step_length_m = leg, 0.0, length_m
        return aim

    def swing(self, est: Estimate, m: Measurements) -> SwingTick:
        leg, p = self.swing_leg, self.p
        stance = 1 - leg
        self.hips_cmd_x = -float(est.ankles[stance][0])  # the body turns about the stance ankle freely
        self._stance((stance,), est, m, 0.0)
        xz = self.dmp.step(self.dt_s, self.substeps) if not self.dmp.done else self.dmp.x
        self.swing_t += self.dt_s
        anchor = est.ankles[stance]  # the stance foot, where it is
        self.ankle_cmd[leg] = (float(anchor[0] + xz[0]), float(anchor[2] + xz[1]))
        self._solve(m)
        tau = self.dmp.tau_s
        loaded = float(m.heel_force_n[leg] + m.toe_force_n[leg]) > p.foot_contact_n
        landed = loaded and self.swing_t >= p.landing_fraction * tau
        done = landed or self.swing_t >= tau + p.swing_timeout_s
        if done:
            # The landed leg becomes a stance leg: its commanded ankle is re-expressed with the trunk
            # at its pitch goal so that its joint targets do not jump.
            self.ankle_cmd[leg] = kin.forward(self.leg, self.targets[2 * leg] - self.pitch_goal_rad, self.targets[2 * leg + 1])
            self.swing_leg = None
            self.hips_cmd_x = -float(np.mean(est.ankles[:, 0]))
            self._new_cycle(est, ref_leg=stance)
        return SwingTick(done, landed, xz)
