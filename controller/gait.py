"""The exoskeleton's legs through the gait cycle, from the state estimate alone (pure numpy).

The patient moves the sticks (where it places them is its intention) and balances with its arms;
the exoskeleton carries the body: every walking tick the legs get position targets (where the hips
should go over the planted feet) and a torque feed-forward (:mod:`controller.balance`: their share
of the body's weight and the moment that holds the trunk; with passive ankles only that share
moves the body fore-aft). The planner keeps a CoM goal, fore-aft over the planted foot that
carries the next swing. One gait cycle, per leg (docs/CONTROLLER.md):

1. **Double support, weight shift.** Until the sticks of this double support have moved (the next
   stance foot's in the four-point gait, both with ``stick_moves: both``), the CoM goal moves (at
   ``shift_speed``) into the window where the next stick may lift: on the support that stays (both
   feet, each ankle widened by half the sole across, and the other stick's tip) ``shift_margin``
   inside its edges, and ``balance_margin`` ahead of the ankles' midpoint (behind it the body rocks
   backward off its passive ankles, and a stick only pushes). Of two sticks still to move the
   patient lifts the one with the wider window first (:func:`controller.support.lift_window`). The
   goal holds while a stick is in the air. A stick has moved once it was off the floor (filtered
   force below ``stick_lifted_n`` for ``stick_lift_s``) and was planted again (above
   ``stick_placed_n``) since the last swing started (wherever it went: a stick put back where it
   stood is the patient's move too, and a patient who feels the foot down before the landing is
   detected may already lift one).
2. **Double support, lean.** With the sticks moved, the goal moves forward at ``lean_speed``, at
   most ``lean_lead`` ahead of the CoM (and not while a stick carries ``comfort_stick_n``): the
   legs lean the body onto the sticks until the patient stops it, pushing back on its sticks
   (their fore-aft pushes are left to act). The lean is over when the CoM gets no farther forward
   by ``lean_stall_m`` in ``lean_stall_s`` (``lean_start_s`` before it has first moved that far)
   with the CoM at least half of ``lean_over_stance`` past the stance ankle (a lean that stalls
   short of it waits: a stalled walk, not a swing that tips backward). The step is ready when the
   lean is over, both sticks carry ``swing_stick_n``, their midpoint stands ``tips_ahead`` ahead of the front
   ankle, and the stance foot carries ``foot_contact_n``. Where the CoM is then against the stance foot is
   the step length's business (the CoM compensation of the paper's equation (8)).
3. **Swing.** The swing ankle follows the DMP in the stance foot's frame, from where it is to the
   step length ahead of the stance ankle and ``landing_depth`` below it. The stance leg carries the
   CoM goal ``hip_advance_fraction`` of the step forward over the swing (minimum jerk): the
   exoskeleton's share of the step. The swing ends when the foot carries ``foot_contact_n`` after
   ``landing_fraction`` of the DMP's duration (a landing), or ``swing_timeout`` after its end.

Every leg target comes from the inverse kinematics of a commanded ankle position relative to the
hip in the heading frame; the hips' joint targets add the trunk's pitch goal (a stance leg) or its
measured pitch (the swing leg). The hips are commanded toward the CoM goal but at most
``max_lead`` from where they are (no wind-up when the body does not follow), a stance foot that
carries nothing is not pushed along the floor, and no joint target moves more than
``max_target_step`` per tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from config.controller_schema import GaitConfig
from controller import kinematics as kin
from controller.balance import GRAVITY, BalanceGains, Goals, LegLoads, feed_forward
from controller.dmp import Dmp
from controller.estimator import Estimate, Measurements
from controller.sticks import StickTracker
from controller.support import lift_window

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


def minimum_jerk(u: float) -> float:
    """0 to 1 over u in [0, 1] with zero velocity and acceleration at both ends."""
    u = _clip(u, 0.0, 1.0)
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


class GaitPlanner:
    """Joint targets and torque feed-forward of the four joints (left hip, left knee, right hip,
    right knee) per tick.

    The planner keeps a commanded ankle position per leg, (x, z) from its hip in the heading
    frame, the hips' stance height above the ankles, and the CoM goal fore-aft over the planted
    foot that carries the next swing (the reference foot: planted from the landing before that
    swing to the landing after it, so the goal and the CoM's velocity over it are the body's over
    the floor).
    """

    def __init__(self, leg: kin.Leg, dmp: Dmp, params: GaitConfig, loads: LegLoads, gains: BalanceGains, *, ankle_height_m: float,
                 swing_s: float, dt_s: float, substeps: int) -> None:
        self.leg, self.dmp, self.p = leg, dmp, params
        self.swing_s = swing_s  # the swing's duration tau (the patient's: controller.factory.swing_duration_s)
        self.loads, self.gains, self.ankle_height_m = loads, gains, ankle_height_m
        self.dt_s, self.substeps = dt_s, substeps
        self.sticks = StickTracker(params, dt_s)
        self.ankle_cmd = np.zeros((2, 2))
        self.stand_height_m = math.nan  # the hips above the ankles when walking started
        self.depth_m = math.nan  # the stance ankles below the hips now (lowered for a long stagger)
        self.hips_cmd_x = 0.0  # the hips' commanded place ahead of the mean stance ankle
        self.feet_spacing_m = math.nan  # right ankle less left ankle fore-aft, both planted
        self.pitch_goal_rad = 0.0
        self.targets = np.zeros(4)
        self.torques = np.zeros(4)  # the feed-forward (controller.balance)
        self.swing_leg: int | None = None
        self.swing_t = 0.0
        self.step_length_m = math.nan  # commanded
        self.aim_offset_m = 0.0  # how far beyond the commanded length the swings aim (foot placement)
        self.goal_x = math.nan  # the CoM goal over the reference foot's ankle, fore-aft
        self.swing_from_x = 0.0  # the CoM over the stance ankle when the swing started
        self._ref: int | None = None  # the reference foot
        self._com_x = math.nan  # the CoM over the reference ankle, last tick
        self._hip_z = math.nan  # the hips above the floor, last tick
        self.com_velocity_m_s = 0.0  # filtered, over the floor
        self.hip_velocity_m_s = 0.0
        self._lean_best_x = -math.inf  # the farthest the CoM got in this lean, and how long since
        self._lean_still_s = 0.0
        self._lean_moved = False  # the CoM got lean_stall_m beyond where this lean started
        self._landed_leg: int | None = None  # the leg of the last landing, and how long ago
        self._landed_s = 0.0

    # -- set-up ----------------------------------------------------------------------------------

    def stand_here(self, est: Estimate, m: Measurements) -> None:
        """Take the measured posture: the stance height, the trunk pitch and the ankles where they
        are (at the start of walking, after a stop or a fault)."""
        self.stand_height_m = self.depth_m = -float(np.mean(est.ankles[:, 2]))
        self.pitch_goal_rad = float(m.trunk_rpy_rad[1])
        self.ankle_cmd = np.array([[est.ankles[i][0], est.ankles[i][2]] for i in LEGS])
        self.hips_cmd_x = -float(np.mean(est.ankles[:, 0]))
        self.targets = np.array(m.joint_position_rad, dtype=float)
        self.torques = np.zeros(4)
        self.swing_leg = None
        self.goal_x, self._ref = math.nan, None
        self._new_cycle(est)

    def _new_cycle(self, est: Estimate, sticks: bool = True) -> None:
        """A new double support (``sticks``: the stick moves start afresh; after a swing they did
        when it started)."""
        if sticks:
            self.sticks.reset()
        self.feet_spacing_m = float(est.ankles[RIGHT][0] - est.ankles[LEFT][0])
        self._lean_best_x, self._lean_still_s, self._lean_moved = -math.inf, 0.0, False

    def track_sticks(self, est: Estimate, m: Measurements) -> None:
        """Every walking tick: the stick moves since the last landing."""
        self.sticks.update(m)

    # -- the CoM over the floor --------------------------------------------------------------------

    def _over(self, est: Estimate, ref: int) -> float:
        """The CoM over the reference ankle ``ref`` this tick, its velocity and the hips' height
        (filtered differences: the estimate's frame moves with the hips, the planted foot does
        not); on a new reference the goal is re-expressed over it."""
        com_x = float(est.com[0] - est.ankles[ref][0])
        hip_z = -float(est.floor_z)
        a = min(1.0, self.dt_s / self.p.velocity_filter_s)
        if self._ref is not None and ref != self._ref:
            self.goal_x += float(est.ankles[self._ref][0] - est.ankles[ref][0])
        elif self._ref is not None:
            self.com_velocity_m_s += a * ((com_x - self._com_x) / self.dt_s - self.com_velocity_m_s)
            self.hip_velocity_m_s += a * ((hip_z - self._hip_z) / self.dt_s - self.hip_velocity_m_s)
        if math.isnan(self.goal_x):
            self.goal_x = com_x
        self._ref, self._com_x, self._hip_z = ref, com_x, hip_z
        return com_x

    def _carry(self, est: Estimate, m: Measurements, legs: tuple[int, ...], com_x: float) -> None:
        """Targets and feed-forward of a tick: the hips toward the goal over the stance ``legs``."""
        self._stance(legs, est, m, self.goal_x - com_x)
        self._solve(m)
        goals = Goals(com_offset_m=self.goal_x - com_x, com_velocity_m_s=self.com_velocity_m_s,
                      hip_height_m=self.depth_m + self.ankle_height_m, hip_height_now_m=self._hip_z,
                      hip_velocity_m_s=self.hip_velocity_m_s, roll_rad=0.0, pitch_rad=self.pitch_goal_rad)
        stance = (LEFT in legs, RIGHT in legs)
        self.torques = feed_forward(self.loads, self.gains, est, m, stance, goals)
        landed, blend = self._landed_leg, self.p.landing_blend_s
        if landed is not None and len(legs) == 2 and self._landed_s < blend:
            # a foot just down takes its share over landing_blend_s, from the single support's
            # distribution to the double support's: loaded at once, a foot that carries little yet
            # slides back under its leg's push
            single = feed_forward(self.loads, self.gains, est, m, (landed != LEFT, landed != RIGHT), goals)
            share = self._landed_s / blend
            self.torques = share * self.torques + (1.0 - share) * single
        self._landed_s += self.dt_s

    # -- the legs --------------------------------------------------------------------------------

    def _stance(self, legs: tuple[int, ...], est: Estimate, m: Measurements, lead: float) -> None:
        """Carry the hips ``lead`` forward (at most ``max_lead``) over the planted ankles of
        ``legs``, at the stance height (lowered as far as the leg farthest from under the hips
        needs to reach its ankle).

        The ankles' midpoint is commanded where it is measured, shifted by the lead, and the two
        ankles at the feet's spacing on the floor: fore-aft as measured while both carry load,
        level in height (the floor is flat). The legs then agree on where the feet are (two
        position-controlled legs on two planted feet are a closed chain: commands that disagree
        push the feet apart or together and one of them off the floor; nearly straight legs are so
        stiff upward that a millimetre of height between the two commands puts the body's whole
        weight on one foot), and a foot that carries nothing is held where it stands instead of
        drifting with its own measurement.
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
        self.hips_cmd_x = -mid_x + _clip(lead, -p.max_lead_m, p.max_lead_m)  # the hips ahead of the feet
        mid_cmd_x = -self.hips_cmd_x
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
        measured_pitch = float(m.trunk_rpy_rad[1])
        ankle_cmd, targets = self.ankle_cmd.tolist(), self.targets.tolist()
        for i in LEGS:
            # a stance leg holds the trunk at its pitch goal; the swing ankle goes where it is
            # commanded whatever the trunk's pitch (0.04 rad of pitch is 3 cm at the ankle)
            pitch = measured_pitch if i == self.swing_leg else self.pitch_goal_rad
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
        stance = 1 - swing_leg
        com_x = self._over(est, stance)
        if not all(self.sticks.moved[i] for i in self._to_move(stance)):
            if not self.sticks.any_lifted_now:
                lo, hi = self.lift_window(est, stance)
                if math.isfinite(lo):
                    quarter = (hi - lo) / 4  # the middle half of the window (as the patient aims)
                    goal = _clip(com_x, lo + quarter, hi - quarter)
                    step = p.shift_speed_m_s * self.dt_s
                    self.goal_x += _clip(goal - self.goal_x, -step, step)
            self._carry(est, m, LEGS, com_x)
            return DoubleSupport(False, "shift", math.nan, self.sticks.loaded)
        # the legs lean the body as fast as the sticks' load leaves room below comfort_stick_n,
        # slowing over the last half of it, and lead no more once it is reached: with the body
        # on its sticks the arms, not the legs, must stop it
        room = 1.0 - max(m.stick_force_n.tolist()) / p.comfort_stick_n
        if room > 0.0:
            speed = p.lean_speed_m_s * min(1.0, 2.0 * room)
            self.goal_x = min(self.goal_x + speed * self.dt_s, com_x + p.lean_lead_m * min(1.0, 2.0 * room))
        else:
            self.goal_x = min(self.goal_x, com_x)
        self._carry(est, m, LEGS, com_x)
        if com_x > self._lean_best_x + p.lean_stall_m and room > 0.0:
            # (with a stick at comfort_stick_n the patient bears no more: a body that still creeps
            # forward is not leaning further, and the lean is over after lean_stall_s)
            # the lean's first tick sets where it starts; a new best after that: it has moved
            self._lean_moved = math.isfinite(self._lean_best_x)
            self._lean_best_x, self._lean_still_s = com_x, 0.0
        else:
            self._lean_still_s += self.dt_s
        stalled = self._lean_still_s >= (p.lean_stall_s if self._lean_moved else p.lean_start_s)
        # a lean that stalls short of the stance ankle is not over: a swing from there tips backward
        over = stalled and com_x >= p.lean_over_stance_m / 2
        front = float(np.max(est.ankles[:, 0]))
        # the support's front edge where the CoM crosses it: midway between the tips (staggered in
        # the four-point gait, where the older stick may stand just ahead of the front foot)
        ahead = float(np.mean(est.tips[:, 0])) > front + p.tips_ahead_m
        # the stance foot carries the body; a lean that has unloaded the rear (swing) foot is the
        # lean the swing wants
        feet = float(m.heel_force_n[stance] + m.toe_force_n[stance]) > p.foot_contact_n
        goal = self.goal_x + float(est.ankles[stance][0])
        return DoubleSupport(over and ahead and feet and self.sticks.loaded, "lean", goal, self.sticks.loaded)

    def _to_move(self, stance: int) -> tuple[int, ...]:
        """The sticks the patient moves before the swing over ``stance`` (``stick_moves``)."""
        return LEGS if self.p.stick_moves == "both" else (stance,)

    def lift_window(self, est: Estimate, stance: int) -> tuple[float, float]:
        """Over the reference ankle: the window of the next stick to lift (the wider one of two
        still to move), where the CoM rests on what stays."""
        p = self.p
        ref_x = float(est.ankles[self._ref][0])
        ankles = [(float(a[0]), float(a[1])) for a in est.ankles]
        best = (math.inf, -math.inf)
        for i in self._to_move(stance):
            if self.sticks.moved[i]:
                continue
            other = 1 - i
            stays = [(float(est.tips[other][0]), float(est.tips[other][1]))] if est.sticks_loaded[other] else []
            lo, hi = lift_window(ankles, stays, float(est.com[1]), self.loads.foot.half_width_m, p.shift_margin_m, p.balance_margin_m,
                                  share=p.comfort_stick_n / (self.loads.total_kg * GRAVITY))
            if hi - lo > best[1] - best[0]:
                best = (lo, hi)
        return best[0] - ref_x, best[1] - ref_x

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
        self.dmp.reset(x0=np.array([start[0], start[2]]), goal=np.array([aim, -self.p.landing_depth_m]), tau_s=self.swing_s)
        self.swing_leg, self.swing_t, self.step_length_m = leg, 0.0, length_m
        self.swing_from_x = self._com_x  # over the stance ankle: the reference of the lean that led here
        self.sticks.reset()  # the next cycle's stick moves count from now
        return aim

    def swing(self, est: Estimate, m: Measurements) -> SwingTick:
        leg, p = self.swing_leg, self.p
        stance = 1 - leg
        com_x = self._over(est, stance)
        tau = self.swing_s
        self.goal_x = self.swing_from_x + p.hip_advance_fraction * self.step_length_m * minimum_jerk(self.swing_t / tau)
        xz = self.dmp.step(self.dt_s, self.substeps) if not self.dmp.done else self.dmp.x
        self.swing_t += self.dt_s
        anchor = est.ankles[stance]  # the stance foot, where it is
        self.ankle_cmd[leg] = (float(anchor[0] + xz[0]), float(anchor[2] + xz[1]))
        self._carry(est, m, (stance,), com_x)
        loaded = float(m.heel_force_n[leg] + m.toe_force_n[leg]) > p.foot_contact_n
        landed = loaded and self.swing_t >= p.landing_fraction * tau
        done = landed or self.swing_t >= tau + p.swing_timeout_s
        if done:
            # The landed leg becomes a stance leg: its commanded ankle is re-expressed with the trunk
            # at its pitch goal so that its joint targets do not jump.
            self.ankle_cmd[leg] = kin.forward(self.leg, self.targets[2 * leg] - self.pitch_goal_rad, self.targets[2 * leg + 1])
            self.swing_leg = None
            self._landed_leg, self._landed_s = leg, 0.0
            self.goal_x = com_x  # the next cycle starts from where the swing left the body
            self.hips_cmd_x = -float(np.mean(est.ankles[:, 0]))
            self._new_cycle(est, sticks=False)
        return SwingTick(done, landed, xz)
