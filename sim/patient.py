"""The simulated patient: a paraplegic in the exoskeleton, walking with two forearm crutches.

The patient owns its arms and its balance; the exoskeleton (the controller through the node
boards, or :mod:`sim.scripted_gait` in ``aider-exo sim``) owns the legs. Every 20 ms tick the
patient decides where its centre of mass should go (:meth:`Patient.update`) and balances on its
supports (:meth:`Patient.balance`); docs/SIM.md says why each rule is there:

1. **Sticks, one at a time.** Before each step it draws its intention (:mod:`sim.intention`).
   Before a stick lifts it brings the CoM into the window that the remaining support holds: ahead
   of the feet's balance point (the ankles' midpoint: behind it the body rocks backward off its
   passive ankles, and a stick only pushes), inside the two soles and the other stick with
   ``shift_margin_m``. There it unloads the stick, carries it to the intended place (within its
   arm's reach) and sets it down.
2. **Lean.** With both sticks placed it leans toward them until the CoM is at the X_CoM/X_SP it
   intends over the swing's support (the stance heel to the tips), as fast as the stick load stays
   comfortable.
3. **Swing.** While the exoskeleton swings a leg it goes along with the legs; a landing starts the
   next step's stick moves from where the CoM is.

Balance: a desired wrench at the CoM (a spring-damper toward the CoM target and the trunk
posture) distributed over the stance soles (two contacts across each sole) and the planted
sticks, each a strut pushing along the line from its tip to the shoulder
(:func:`sim.balance.distribute`); the arms (:mod:`sim.arms`) apply the planted sticks' share as
joint torques within the patient's strength and carry the moving sticks along their tip paths.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from config.sim_schema import SimConfig
from sim.arms import SET_DOWN_SHARE, Arms
from sim.balance import Contact, WrenchGains, desired_wrench, distribute
from sim.intention import Intention, StepIntention
from sim.kinematics import Kinematics
from sim.linalg import clamp, norm3
from sim.model import SIDES
from sim.sensors import Reading
from sim.support import lift_window, swing_support
from sim.truth import extent_on_line, pivot_margin
from sim.world import GRAVITY, World

OTHER = {"l": "r", "r": "l"}
#: weights of the wrench rows in the distribution (force x y z, moment x y z)
WRENCH_WEIGHTS = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 0.5])
FOOT_COST, STICK_COST = 1e-4, 4e-4  # relative effort of loading a foot (the legs) and a stick (the arms)


class Phase(enum.Enum):
    SETTLE = "settle"
    SHIFT = "shift"  # the CoM into the support that stays when the next stick lifts
    STICKS = "sticks"  # a stick unloaded, carried and set down
    LEAN = "lean"  # toward the sticks, to the intended X_CoM/X_SP
    SWING = "swing"  # the exoskeleton swings a leg


@dataclass
class StepPlan:
    """What the patient meant and did in the step in the making (copied into the step's record)."""

    intention: StepIntention | None = None
    placed_ahead_m: float = math.nan  # where its sticks went: their mean goal ahead of the intention's reference
    clamped: int = 0  # stick goals moved to where the arm reaches or ahead of where the stick stood


@dataclass
class BalanceResult:
    contacts: list[Contact] = field(default_factory=list)
    forces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    residual: float = 0.0
    wrench: np.ndarray = field(default_factory=lambda: np.zeros(6))


class Patient:
    """The patient's decisions and arms, in ``world`` (read through ``kin``)."""

    def __init__(self, world: World, kin: Kinematics, cfg: SimConfig, rng: np.random.Generator) -> None:
        self.world, self.kin, self.cfg, self.rng = world, kin, cfg, rng
        self.p, self.g = cfg.patient, cfg.gait
        self.body = world.body
        self.dt = 0.0  # set by the walker from the bus tick
        # its own stream (spawned, not drawn from rng): the sensors' noise does not move the intentions
        self.intention = Intention(cfg.patient.intention, rng.spawn(1)[0])
        self.gains = WrenchGains()
        self.ankle_idx = {s: world.joint_index[f"ankle_{s}"] for s in SIDES}
        self._foot_mass = {s: world.masses[world.link_index[f"foot_{s}"] + 1] for s in SIDES}
        self._trunk_target_rp = np.array([0.0, self.g.trunk_pitch_rad])  # upright, leaning forward as configured
        self.arms = Arms(world, kin, cfg)
        self.phase, self.phase_t = Phase.SETTLE, 0.0
        self.walking = True  # the gait cycle starts only while set (under the controller: its gait state)
        self.com_target = np.zeros(2)
        self.stance = {"l": True, "r": True}  # feet the patient balances on
        self.planted = {"l": True, "r": True}  # stick tips on the ground and leant on
        self.unloading: dict[str, float] = {}  # stick -> seconds it has been unloading
        self.stick_queue: list[str] = []
        self.lean_goal_x = math.nan
        self.plan = StepPlan()
        self.clamps = {"reach": 0, "advance": 0}  # stick goals clamped, by reason, over the walk
        self.last = BalanceResult()
        self.last_landed: str | None = None

    # -- geometry -----------------------------------------------------------------------------

    def ankle_xy(self, side: str) -> np.ndarray:
        return self.kin.joint_origin[self.ankle_idx[side]][:2].copy()

    def tip_point(self, side: str) -> np.ndarray:
        return self.arms.tip_point(side)

    def shoulder(self, side: str) -> np.ndarray:
        return self.arms.shoulder(side)

    def front_foot(self) -> str:
        """The stance foot of the next swing: the one that landed last (the exoskeleton alternates
        its legs, whether or not that step got ahead of the other foot); before the first swing,
        the foot ahead."""
        return self.last_landed or max(SIDES, key=lambda s: self.ankle_xy(s)[0])

    def support_margin(self, tips: list[str] | None = None) -> float:
        """Static margin of the CoM over the stance ankles (across the soles' width) and ``tips``
        (by default every planted tip): the pivot polygon in 3-D, its fore-aft extent in the
        sagittal mode, where the plane spring holds the trunk laterally."""
        tips = [s for s in SIDES if self.planted[s]] if tips is None else tips
        ankles = [tuple(self.kin.joint_origin[self.ankle_idx[s], :2].tolist()) for s in SIDES if self.stance[s]]
        tip_xy = [tuple(self.tip_point(s)[:2].tolist()) for s in tips]
        com = self.kin.com[:2].tolist()
        if self.cfg.mode == "sagittal":
            xs = [p[0] for p in ankles + tip_xy]
            return float(min(com[0] - min(xs), max(xs) - com[0])) if xs else -math.inf
        return pivot_margin(ankles, tip_xy, self.cfg.hardware.foot.half_width_m, com)

    # -- the gait cycle -------------------------------------------------------------------------

    def _set_phase(self, phase: Phase) -> None:
        self.phase, self.phase_t = phase, 0.0

    def start(self) -> None:
        """Take the standing posture as the goals."""
        self.com_target = self.kin.com[:2].copy()
        origin, _ = self.world.link_frame("trunk")
        self.hip_goal = np.array([origin[0], origin[2]])
        self.pitch_goal = float(self.world.link_states().trunk_rpy[1])
        self.hip_height_nominal = float(origin[2])

    def _start_stick_moves(self) -> None:
        mode = self.p.stick_mode
        if mode == "four_point":
            self.stick_queue = [self.front_foot()]  # the front foot's side: its window is always wide
        else:
            self.stick_queue = list(SIDES) if mode == "together" else sorted(SIDES, key=lambda s: self.tip_point(s)[0])
        self.plan.intention = self.intention.next()
        self._set_phase(Phase.SHIFT)

    def _lifting(self) -> list[str]:
        together = self.p.stick_mode == "together"
        return self.stick_queue[:2] if together else self.stick_queue[:1]

    def lift_window(self, lifting: list[str]) -> tuple[float, float]:
        """:func:`sim.support.lift_window` when ``lifting`` lift: on the stance soles and the other
        planted stick, that stick's share of the weight within ``stick_force_comfort_n``."""
        g = self.g
        ankles = np.array([self.ankle_xy(s) for s in SIDES if self.stance[s]]).reshape(-1, 2)
        stays = np.array([self.tip_point(s)[:2] for s in SIDES if s not in lifting and self.planted[s]]).reshape(-1, 2)
        return lift_window(ankles, stays, float(self.kin.com[1]), self.cfg.hardware.foot, shift_margin_m=g.shift_margin_m,
                           balance_margin_m=g.balance_margin_m, max_stick_share=g.stick_force_comfort_n / (self.world.total_mass * GRAVITY))

    def _stick_goal(self, side: str, start: np.ndarray) -> np.ndarray:
        """Where a lifted stick goes: the intention plus its placement error ahead of the front
        ankle (or the CoM, ``intention.reference``), at least ``stick_min_advance_m`` ahead of where
        it stood and no farther than the arm reaches with the elbow ``stick_reach_elbow_rad`` bent
        (either clamp counted in ``clamps`` and the step's plan, which also keeps the mean goal
        ahead of the reference)."""
        p = self.p
        sign = 1.0 if side == "l" else -1.0
        origin_x = float(self.kin.com[0]) if p.intention.reference == "com" else float(self.ankle_xy(self.front_foot())[0])
        x = origin_x + self.plan.intention.ahead_m + float(self.rng.normal(0.0, p.stick_noise_m))
        y, z = sign * p.stick_half_width_m, self.cfg.hardware.sticks.tip_radius_m
        shoulder = self.shoulder(side)
        reach = self.body.arm_span_m(p.stick_reach_elbow_rad)
        far = shoulder[0] + math.sqrt(max(reach**2 - (y - shoulder[1]) ** 2 - (z - shoulder[2]) ** 2, 0.0))
        near = float(start[0]) + p.stick_min_advance_m
        reason = "reach" if x > far else "advance" if x < near else None
        if reason is not None:
            x = far if reason == "reach" else near
            self.clamps[reason] += 1
            self.plan.clamped += 1
        ahead = x - origin_x
        placed = self.plan.placed_ahead_m
        self.plan.placed_ahead_m = ahead if math.isnan(placed) else (placed + ahead) / 2
        return np.array([x, y, 0.0])

    def swing_support(self, stance: str) -> np.ndarray:
        """The points of the support polygon of a swing over leg ``stance`` (its sole, both tips)."""
        return swing_support(self.ankle_xy(stance), self.cfg.hardware.foot, np.array([self.tip_point(s)[:2] for s in SIDES]))

    def swing_span(self, stance: str) -> tuple[float, float]:
        """(rear, front) of X_SP over :meth:`swing_support`: its rear-most point (the heel) and its
        front edge where the CoM's walking line crosses it (the tips' line; SPEC, as the
        controller's estimator measures it)."""
        support = self.swing_support(stance)
        return float(support[:, 0].min()), extent_on_line(support, self.kin.com[:2])[1]

    def _lean_goal(self) -> float:
        """The CoM's x at the intended X_CoM/X_SP of the swing's support (SPEC: along the walking
        direction at the CoM's lateral place, from the front foot's heel to the tips' line), within
        ``lean_x_min``..``lean_x_max`` and no farther than the arms hold in the swing."""
        g = self.g
        rear, front = self.swing_span(self.front_foot())
        ankle = float(self.ankle_xy(self.front_foot())[0])
        # the sticks' share of the weight over the stance ankle and the tips (lever rule) at most
        # stick_force_comfort_n on each
        share = min(1.0, 2.0 * g.stick_force_comfort_n / (self.world.total_mass * GRAVITY))
        return min(rear + clamp(self.plan.intention.lean_x, g.lean_x_min, g.lean_x_max) * (front - rear), ankle + share * (front - ankle))

    def next_lift_window(self) -> tuple[float, float]:
        """:meth:`lift_window` of the stick (or sticks) to lift next."""
        return self.lift_window(self._lifting())

    def update(self, reading: Reading) -> None:
        """One tick of decisions. In the lean and the swing the legs (the exoskeleton's) may carry
        the body toward the patient's goal faster than it would lean itself: it goes along as far
        as its goal and no farther, while the sticks' load stays comfortable."""
        g, dt = self.g, self.dt
        self.phase_t += dt
        com = self.kin.com
        if self.phase is Phase.SETTLE:
            if self.phase_t >= g.settle_s and self.walking:
                self._start_stick_moves()
        elif self.phase is Phase.SHIFT:
            lo, hi = self.lift_window(self._lifting())
            if len(self._lifting()) == 1 and len(self.stick_queue) == 2:
                # the other stick first when its window is the wider (the support left by a stick
                # on the rear foot's side is often a sliver until the other stick stands farther ahead)
                other_lo, other_hi = self.lift_window(self.stick_queue[1:])
                if other_hi - other_lo > hi - lo:
                    self.stick_queue.reverse()
                    lo, hi = other_lo, other_hi
            # into the middle half of the window, not to its edge: a stick lifted at the edge
            # leaves the other arm at its limit, and the body creeps on over it while the stick is up
            quarter = (hi - lo) / 4
            if lo <= hi:
                target = clamp(float(com[0]), lo + quarter, hi - quarter)
            else:
                # no window: back onto the feet (their balance point), where the legs carry the body
                # and the stance feet stop sliding; the window is looked for again from there
                target = float(np.mean([self.ankle_xy(s)[0] for s in SIDES if self.stance[s]])) + g.shift_margin_m
            step = g.shift_speed_m_s * dt
            self.com_target[0] += clamp(target - self.com_target[0], -step, step)
            slack = g.shift_margin_m / 2  # aimed with the whole margin, lifted with half of it
            inside = lo - slack <= com[0] <= hi + slack
            still = float(np.linalg.norm(self.kin.com_velocity[:2])) < g.shift_still_speed_m_s
            if inside and still and self.phase_t > g.shift_min_s:
                for side in self._lifting():
                    self.unloading[side] = 0.0
                self._set_phase(Phase.STICKS)
        elif self.phase is Phase.STICKS:
            self._move_sticks(reading, dt)
        elif self.phase in (Phase.LEAN, Phase.SWING):
            comfortable = max(reading.stick_force_n) < g.stick_force_comfort_n
            if comfortable:
                self.com_target[0] = max(self.com_target[0], min(float(com[0]), self.lean_goal_x))
            if self.phase is Phase.LEAN and comfortable and self.com_target[0] < self.lean_goal_x:
                # toward the goal, but never far ahead of the body (a target that runs away asks the
                # legs and arms for forces they cannot give)
                lead = float(com[0]) + g.lean_lead_m
                self.com_target[0] = min(self.com_target[0] + g.lean_speed_m_s * dt, self.lean_goal_x, max(lead, self.com_target[0]))
        self.com_target[1] += clamp(-self.com_target[1], -g.lean_speed_m_s * dt, g.lean_speed_m_s * dt)
        self._update_posture()

    def _update_posture(self) -> None:
        """The hip's goal follows the CoM target (backward no faster than the shift, forward no faster
        than ``hip_speed_m_s``); its height is the standing height as far as every stance foot
        reaches (``leg_reach_m``), rate-limited; the trunk pitch eases to ``trunk_pitch_rad``."""
        g, dt = self.g, self.dt
        hip = float(self.world.link_frame("trunk")[0][0])
        want_x = hip + (self.com_target[0] - float(self.kin.com[0]))
        back = g.shift_speed_m_s if self.phase is Phase.SHIFT else g.hip_speed_m_s
        self.hip_goal[0] += clamp(want_x - self.hip_goal[0], -back * dt, g.hip_speed_m_s * dt)
        reach = min(math.sqrt(max(g.leg_reach_m**2 - (self.hip_goal[0] - self.ankle_xy(f)[0]) ** 2, 0.05))
                    for f in SIDES if self.stance[f])
        height = min(self.hip_height_nominal, self.body.ankle_height_m + reach)
        self.hip_goal[1] += clamp(height - self.hip_goal[1], -0.1 * dt, 0.1 * dt)
        self.pitch_goal += clamp(g.trunk_pitch_rad - self.pitch_goal, -0.2 * dt, 0.2 * dt)

    def _move_sticks(self, reading: Reading, dt: float) -> None:
        g = self.g
        for side in list(self.unloading):
            self.unloading[side] += dt
            if self.unloading[side] >= g.unload_time_s:
                del self.unloading[side]
                self.planted[side] = False
                start = self.tip_point(side)
                self.arms.tip_path[side] = (start, self._stick_goal(side, start), 0.0)
        for side, (start, goal, u) in list(self.arms.tip_path.items()):
            u += dt / g.stick_move_time_s
            if u >= 1.0 and reading.stick_force_n[SIDES.index(side)] > g.stick_planted_n:
                del self.arms.tip_path[side]
                self.planted[side] = True
                self.stick_queue.remove(side)
            else:
                self.arms.tip_path[side] = (start, goal, min(u, 1.0 + SET_DOWN_SHARE))
        if not self.unloading and not self.arms.tip_path:
            if self.stick_queue:
                self._set_phase(Phase.SHIFT)
            else:
                self.lean_goal_x = self._lean_goal()
                self._set_phase(Phase.LEAN)

    def swing_started(self, leg: str) -> None:
        self.stance[leg] = False
        self.stance[OTHER[leg]] = True  # whatever its load said before: it carries the body now
        self._set_phase(Phase.SWING)

    def landed(self, leg: str) -> None:
        """A foot is down again. The patient takes the CoM target from where the landing left it
        (often ahead of the front foot, on the sticks) and starts the next step's stick moves."""
        self.stance[leg] = True
        self.last_landed = leg
        self.com_target = self.kin.com[:2].copy()
        self.plan = StepPlan()
        self._start_stick_moves()

    # -- balance --------------------------------------------------------------------------------

    def foot_contacts(self) -> tuple[Contact, ...]:
        """Two contacts per stance foot, at the ankle across the sole: the passive ankle carries no
        moment about its axis (its spring is a known moment), the sole carries a roll moment. Once
        per state and stance (the patient's balance and the legs' feed-forward both ask)."""
        return self.kin.memo(("foot_contacts", self.stance["l"], self.stance["r"]), self._foot_contacts)

    def _foot_contacts(self) -> tuple[Contact, ...]:
        half = self.cfg.hardware.foot.half_width_m
        out = []
        for f in SIDES:
            if self.stance[f]:
                j = self.ankle_idx[f]
                for sign in (-1.0, 1.0):
                    out.append(Contact(f"foot_{f}", j, self.kin.joint_origin[j] + sign * half * self.kin.joint_axis[j], FOOT_COST))
        return tuple(out)

    def ankle_spring_moment(self) -> np.ndarray:
        """The moment the stance ankles' springs put on the body above them; read-only, once per
        state and stance."""
        return self.kin.memo(("ankle_spring_moment", self.stance["l"], self.stance["r"]), self._ankle_spring_moment)

    def _ankle_spring_moment(self) -> np.ndarray:
        ankle = self.cfg.hardware.joints.ankle
        moment = np.zeros(3)
        for f in SIDES:
            if self.stance[f]:
                j = self.ankle_idx[f]
                moment += ankle.stiffness_nm_rad * (self.world.q[j] - ankle.rest_rad) * self.kin.joint_axis[j]
        moment.flags.writeable = False
        return moment

    def wrench(self, com_target: np.ndarray | None = None) -> np.ndarray:
        """The wrench at the CoM that pulls the body toward ``com_target`` (by default the patient's
        own) and the posture."""
        w, kin = self.world, self.kin
        links = w.link_states()
        origin, rot = w.link_frame("trunk")
        feet_mass = sum(self._foot_mass[f] for f in SIDES if self.stance[f])
        return desired_wrench(
            w.total_mass - feet_mass, kin.com, kin.com_velocity, self.com_target if com_target is None else com_target, origin[2], self.hip_goal[1], links.com_velocity[0][2],
            links.trunk_rpy, rot.T @ links.base_angular_velocity, self._trunk_target_rp, self.gains,
        )

    def balance(self) -> BalanceResult:
        """Distribute the wrench over the stance soles and the planted sticks and command the arms."""
        kin, g = self.kin, self.g
        contacts = list(self.foot_contacts())
        for t in SIDES:
            if self.planted[t] or t in self.unloading:
                tip, shoulder = self.tip_point(t), self.shoulder(t)
                along = shoulder - tip
                axis = along / norm3(along)
                cost = STICK_COST * (1.0 + 400.0 * (self.unloading[t] / g.unload_time_s) ** 2) if t in self.unloading else STICK_COST
                # in a swing both sticks stay pressed down as when it started: the one the balance
                # would spare lifts off its tip and the body loses a support it relies on; in the
                # lean both stay planted (stick_planted_n: with 0 the spared one unloads as the swing
                # starts, before the patient feels it)
                min_n = g.swing_trigger_stick_n if self.phase is Phase.SWING else (g.stick_planted_n if self.phase is Phase.LEAN else None)
                contacts.append(Contact(f"tip_{t}", self.arms.forearm_idx[t], tip, cost, axis=axis, spread=g.strut_spread, min_n=min_n))
        wrench = self.wrench()
        forces, residual = distribute(wrench, kin.com, contacts, mu=0.5, min_normal_n=g.min_contact_n,
                                      weights=WRENCH_WEIGHTS, known_moment=self.ankle_spring_moment())
        self.last = BalanceResult(contacts, forces, residual, wrench)
        self.arms.command(contacts, forces)
        return self.last

    # -- reports --------------------------------------------------------------------------------

    def state(self) -> dict:
        """Where the patient is in its gait, for a report (a walk that makes no progress says whom it
        waits for): its phase and how long it has been in it, the sticks it has still to move, and
        in the shift the window of the CoM's x where the next stick may lift."""
        state = {"phase": self.phase.value, "phase_s": round(self.phase_t, 2), "sticks_to_move": list(self.stick_queue)}
        if self.phase is Phase.SHIFT:
            lo, hi = self.lift_window(self._lifting())
            state["lift_window_m"] = [round(lo, 4), round(hi, 4)]
            state["com_x_m"] = round(float(self.kin.com[0]), 4)
        return state
