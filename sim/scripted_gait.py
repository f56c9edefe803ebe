"""The scripted exoskeleton: a stand-in for the main controller in ``aider-exo sim``.

It drives the four exoskeleton joints through the node boards' interface (track mode: position
target and torque feed-forward) with the controller's rules (docs/CONTROLLER.md), reading the
simulation where the controller reads its sensors. It keeps its own plan of where the centre of
mass should go:

* **Shift.** While the patient moves its sticks, toward the window where the next stick may lift
  (:meth:`sim.patient.Patient.next_lift_window`, the geometry both know), at ``shift_speed_m_s``.
* **Lean.** With both sticks moved, forward at ``lean_speed_m_s``, at most ``lean_lead_m`` ahead of
  the CoM, until the patient stops it: the CoM no farther by ``lean_stall_m`` in ``lean_stall_s``
  (``lean_start_s`` before it has first moved that far) with both sticks and both feet loaded.
  Then the rear leg swings.
* **Swing.** The swing ankle follows a lift-advance-descend path to ``step_length_m`` ahead of the
  stance ankle; the stance leg carries the hip ``hip_advance_fraction`` of the step forward (the
  exoskeleton's share of the step). The swing ends when the foot carries load after 75 % of the
  swing (a landing) or a second after its end.

Stance legs: every stance ankle commanded where it stands (its fore-aft place measured while the
foot is loaded, level at ankle height), the hips toward the plan but at most ``hip_lead_m`` from
where they are, the trunk at the patient's pitch, joint targets at most ``target_step_rad`` a
tick apart. Their torque feed-forward carries the body: a wrench at the CoM toward the plan and the
posture, less what the sticks measurably carry upward (each stick's load cell along its axis),
distributed over the stance soles, as joint torques ``G - J^T f``. With passive ankles the legs
and trunk rock about the ankles in a mode that position targets cannot hold; only the legs' share
of the load moves it. The sticks' fore-aft pushes are left to act: they are how the patient
stops a lean it does not want.
"""

from __future__ import annotations

import math

import numpy as np

from config.sim_schema import GaitConfig, SimConfig
from protocol.geometry import leg_inverse
from sim.balance import distribute
from sim.kinematics import Kinematics
from sim.linalg import clamp, cross3, minimum_jerk
from sim.model import EXO_JOINTS
from sim.patient import OTHER, SIDES, WRENCH_WEIGHTS, Patient, Phase
from sim.sensors import Reading
from sim.world import GRAVITY, World


class ScriptedGait:
    """The exoskeleton's legs through the gait cycle, beside ``patient``."""

    def __init__(self, world: World, kin: Kinematics, cfg: SimConfig, settings: GaitConfig, patient: Patient) -> None:
        self.world, self.kin, self.cfg, self.s, self.patient = world, kin, cfg, settings, patient
        self.body = world.body
        self.leg_joints = {s: (world.joint_index[f"hip_{s}"], world.joint_index[f"knee_{s}"]) for s in SIDES}
        self.swing_leg: str | None = None
        self.next_swing = "r"
        self.phase_t = 0.0
        self.swing_start = np.zeros(2)
        self.swing_goal_x = 0.0
        self.swing_com_x = 0.0  # the CoM's place when the swing started
        self.com_goal_x = math.nan  # the plan (the CoM's place at the first update)
        self.lean = LeanTracker(settings)
        self.foot_x: dict[str, float] = {}
        self.targets = {name: float(world.q[world.joint_index[name]]) for name in EXO_JOINTS}

    # -- the plan and when to step -----------------------------------------------------------------

    def update(self, reading: Reading, dt: float) -> tuple[str, str] | None:
        """Move the plan on; the swing's start or end this tick, as ``("swing", leg)`` or
        ``("land", leg)`` (``("timeout", leg)``: the swing ended in the air)."""
        s, p = self.s, self.patient
        com_x = float(self.kin.com[0])
        if math.isnan(self.com_goal_x):
            self.com_goal_x = com_x
        self.phase_t += dt
        if self.swing_leg is None:
            if p.phase is Phase.LEAN:
                self.com_goal_x = min(self.com_goal_x + s.lean_speed_m_s * dt, com_x + s.lean_lead_m)
                self.lean.update(com_x, dt)
                plantar = reading.heel_force_n + reading.toe_force_n
                loaded = bool(np.all(reading.stick_force_n > s.swing_trigger_stick_n)) and bool(np.all(plantar > s.foot_contact_n))
                if loaded and self.lean.stalled:
                    return self._start_swing(self.next_swing)
                return None
            self.lean.reset()
            if p.phase is Phase.SHIFT:
                lo, hi = p.next_lift_window()
                goal = (lo + hi) / 2 if lo > hi else clamp(com_x, lo, hi)
                if math.isfinite(goal):
                    self.com_goal_x += clamp(goal - self.com_goal_x, -s.shift_speed_m_s * dt, s.shift_speed_m_s * dt)
            return None
        self.com_goal_x = self.swing_com_x + self._advance()
        leg = self.swing_leg
        down = (reading.heel_force_n + reading.toe_force_n)[SIDES.index(leg)] > s.foot_contact_n
        if (self.phase_t > 0.75 * s.swing_time_s and down) or self.phase_t > s.swing_time_s + 1.0:
            self.swing_leg, self.next_swing = None, OTHER[leg]
            self.foot_x[leg] = float(p.ankle_xy(leg)[0])  # where it landed (its last place is a step behind)
            self.com_goal_x = com_x
            return "land" if down else "timeout", leg
        return None

    def _start_swing(self, leg: str) -> tuple[str, str]:
        self.swing_leg, self.phase_t = leg, 0.0
        self.swing_start = self.patient.ankle_xy(leg)
        self.swing_goal_x = float(self.patient.ankle_xy(OTHER[leg])[0]) + self.s.step_length_m
        self.swing_com_x = float(self.kin.com[0])
        return "swing", leg

    def swing_target(self) -> np.ndarray:
        """Ankle (x, z) of the swing leg: lift, advance, descend (minimum-jerk blends). The ankle
        rises over the first 30 % of the swing, advances from 15 % to 85 %, and comes down over the
        last 30 %, to a centimetre below the floor."""
        s = self.s
        u = min(self.phase_t / s.swing_time_s, 1.0)
        x = self.swing_start[0] + (self.swing_goal_x - self.swing_start[0]) * minimum_jerk((u - 0.15) / 0.7)
        lift = minimum_jerk(u / 0.3) - minimum_jerk((u - 0.7) / 0.3)
        return np.array([x, self.body.ankle_height_m + s.swing_clearance_m * lift + (0.0 if u < 1.0 else -0.01)])

    def _advance(self) -> float:
        """How far the stance leg has carried the body forward in this swing, by plan."""
        u = min(self.phase_t / self.s.swing_time_s, 1.0)
        return self.s.hip_advance_fraction * self.s.step_length_m * minimum_jerk(u)

    # -- the legs' commands ----------------------------------------------------------------------

    def command(self, reading: Reading) -> None:
        """Position targets and torque feed-forward of the four joints (see the module doc)."""
        w, s, b, p = self.world, self.s, self.body, self.patient
        origin, _ = w.link_frame("trunk")
        pitch = float(w.link_states().trunk_rpy[1])
        plantar = reading.heel_force_n + reading.toe_force_n
        for i, side in enumerate(SIDES):
            if p.stance[side] and (plantar[i] > s.foot_contact_n or side not in self.foot_x):
                self.foot_x[side] = float(p.ankle_xy(side)[0])
        hip_now = float(origin[0])
        hip_x = hip_now + clamp(self.com_goal_x - float(self.kin.com[0]), -s.hip_lead_m, s.hip_lead_m)
        tau = self._feed_forward(reading)
        positions, torques = np.empty(len(EXO_JOINTS)), np.empty(len(EXO_JOINTS))
        for side in SIDES:
            hip_i, knee_i = self.leg_joints[side]
            if side == self.swing_leg:
                ankle = self.swing_target() - np.array([origin[0], origin[2]])
                trunk_pitch = pitch
            else:
                ankle = np.array([self.foot_x[side] - hip_x, b.ankle_height_m - p.hip_goal[1]])
                trunk_pitch = p.pitch_goal
            reach = b.thigh_m + b.shank_m - 0.005  # a straight knee makes the inverse kinematics ill-conditioned
            length = float(np.hypot(*ankle))
            if length > reach:
                ankle = ankle * reach / length
            try:
                thigh, knee = leg_inverse(b.thigh_m, b.shank_m, float(ankle[0]), float(ankle[1]))
            except ValueError:
                thigh, knee = w.q[hip_i] - pitch, w.q[knee_i]
            for name, joint, target in ((f"hip_{side}", hip_i, thigh + trunk_pitch), (f"knee_{side}", knee_i, knee)):
                if side != self.swing_leg:
                    last = self.targets[name]
                    target = last + clamp(target - last, -s.target_step_rad, s.target_step_rad)
                n = w.exo.index(name)
                target = clamp(target, w.exo.lower[n] + 1e-3, w.exo.upper[n] - 1e-3)
                self.targets[name] = target
                positions[n], torques[n] = target, clamp(float(tau[joint]), -100.0, 100.0)
        w.exo.track(positions, torques)  # every joint: track mode, no velocity feed-forward, the rated limit

    def _feed_forward(self, reading: Reading) -> np.ndarray:
        """Joint torques that carry the body: the wrench toward the plan and the patient's posture,
        less what each stick's load cell measures upward along the stick (and its moment), over the
        stance soles; the swing leg carries its own weight."""
        w, kin, p = self.world, self.kin, self.patient
        com = kin.com
        wrench = p.wrench(np.array([self.com_goal_x, 0.0]))
        for i, side in enumerate(SIDES):
            _, rot = w.link_frame(f"forearm_{side}")
            up = (0.0, 0.0, float(reading.stick_force_n[i]) * rot[2, 2])
            wrench -= (*up, *cross3((p.tip_point(side) - com).tolist(), up))  # its force and its moment about the CoM
        feet = p.foot_contacts()
        forces, _ = distribute(wrench, com, feet, mu=0.5, min_normal_n=self.s.min_contact_n, weights=WRENCH_WEIGHTS,
                               known_moment=p.ankle_spring_moment())
        soles = [w.link_index[f"foot_{f}"] for f in SIDES if p.stance[f]]
        links = soles + [c.link for c in feet]
        points = [kin.link_com[i + 1] for i in soles] + [c.point for c in feet]
        loads = [(0.0, 0.0, w.masses[i + 1] * GRAVITY) for i in soles] + list(forces)
        grav = kin.gravity_torques()
        return grav - kin.generalised_force(links, points, loads) if links else grav


class LeanTracker:
    """Whether a lean is over: the CoM no farther forward by ``lean_stall_m`` for ``lean_stall_s``
    once it has moved that far (``lean_start_s`` before: the body takes a moment to follow)."""

    def __init__(self, settings: GaitConfig) -> None:
        self.s = settings
        self.reset()

    def reset(self) -> None:
        self.best_x, self.still_s, self.moved = -math.inf, 0.0, False

    def update(self, com_x: float, dt: float) -> None:
        if com_x > self.best_x + self.s.lean_stall_m:
            self.moved = math.isfinite(self.best_x)
            self.best_x, self.still_s = com_x, 0.0
        else:
            self.still_s += dt

    @property
    def stalled(self) -> bool:
        return self.still_s >= (self.s.lean_stall_s if self.moved else self.s.lean_start_s)
