"""The scripted exoskeleton: a stand-in for the main controller in ``aider-exo sim``.

It drives the four exoskeleton joints through the node boards' interface (track mode: position
target and torque feed-forward) with the same rules as the controller's gait (docs/CONTROLLER.md),
reading the simulation where the controller reads its sensors:

* **Stance legs.** Every stance ankle is commanded where it stands (its fore-aft place measured
  while the foot is loaded, level at ankle height), the hips toward the patient's goal but at most
  ``hip_lead_m`` from where they are, the trunk at the patient's pitch; joint targets move at most
  ``target_step_rad`` a tick. The legs then agree on where the feet are and never drag a foot.
* **Their torque feed-forward** carries the body: the patient's desired wrench at the CoM less what
  the sticks measurably push (each stick's load cell along its axis), distributed over the stance
  soles, as joint torques ``G - J^T f``. With passive ankles the legs and trunk rock about the
  ankles in a mode that position targets cannot hold; only the legs' share of the load moves it.
* **Swing.** When the patient's lean has reached its goal with both sticks loaded and both feet
  down, the rear leg swings along a lift-advance-descend ankle path to ``step_length_m`` ahead of
  the stance ankle while the stance leg carries the hip ``hip_advance_fraction`` of the step
  forward; the swing ends when the foot carries load after 75 % of the swing (a landing) or a
  second after its end.
"""

from __future__ import annotations

import numpy as np

from config.sim_schema import GaitConfig, SimConfig
from sim.actuation import Mode
from sim.balance import distribute
from sim.kinematics import Kinematics
from sim.linalg import clamp, minimum_jerk
from sim.model import EXO_JOINTS, leg_ik
from sim.patient import OTHER, SIDES, WRENCH_WEIGHTS, Patient
from sim.sensors import Reading, rpy_from_matrix
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
        self.swing_hip_x = 0.0  # the hip's place when the swing started
        self.foot_x: dict[str, float] = {}
        self.targets = {name: float(world.q[world.joint_index[name]]) for name in EXO_JOINTS}

    # -- when to step ----------------------------------------------------------------------------

    def update(self, reading: Reading, dt: float) -> tuple[str, str] | None:
        """The swing's start or end this tick, as ``("swing", leg)`` or ``("land", leg)``."""
        s = self.s
        self.phase_t += dt
        plantar = reading.heel_force_n + reading.toe_force_n
        if self.swing_leg is None:
            loaded = bool(np.all(reading.stick_force_n > s.swing_trigger_stick_n)) and bool(np.all(plantar > s.foot_contact_n))
            if loaded and self.patient.lean_reached() and self.patient.phase_t > 0.3:
                return self._start_swing(self.next_swing)
            return None
        leg = self.swing_leg
        down = plantar[SIDES.index(leg)] > s.foot_contact_n
        if (self.phase_t > 0.75 * s.swing_time_s and down) or self.phase_t > s.swing_time_s + 1.0:
            self.swing_leg, self.next_swing = None, OTHER[leg]
            return "land" if down else "timeout", leg
        return None

    def _start_swing(self, leg: str) -> tuple[str, str]:
        self.swing_leg, self.phase_t = leg, 0.0
        self.swing_start = self.patient.ankle_xy(leg)
        self.swing_goal_x = float(self.patient.ankle_xy(OTHER[leg])[0]) + self.s.step_length_m
        self.swing_hip_x = float(self.world.link_frame("trunk")[0][0])
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
        """How far the stance leg has carried the hip forward in this swing, by plan."""
        u = min(self.phase_t / self.s.swing_time_s, 1.0)
        return self.s.hip_advance_fraction * self.s.step_length_m * minimum_jerk(u)

    # -- the legs' commands ----------------------------------------------------------------------

    def command(self, reading: Reading) -> None:
        """Position targets and torque feed-forward of the four joints (see the module doc)."""
        w, s, b, p = self.world, self.s, self.body, self.patient
        origin, rot = w.link_frame("trunk")
        pitch = float(rpy_from_matrix(rot)[1])
        plantar = reading.heel_force_n + reading.toe_force_n
        for i, side in enumerate(SIDES):
            if p.stance[side] and (plantar[i] > s.foot_contact_n or side not in self.foot_x):
                self.foot_x[side] = float(p.ankle_xy(side)[0])
        hip_now = float(origin[0])
        if self.swing_leg is None:
            goal = float(p.hip_goal[0])
        else:
            goal = self.swing_hip_x + self._advance() if s.hip_advance_fraction > 0.0 else hip_now
        hip_x = clamp(goal, hip_now - s.hip_lead_m, hip_now + s.hip_lead_m)
        tau = self._feed_forward(reading)
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
                thigh, knee = leg_ik(ankle, b.thigh_m, b.shank_m)
            except ValueError:
                thigh, knee = w.q[hip_i] - pitch, w.q[knee_i]
            for name, joint, target in ((f"hip_{side}", hip_i, thigh + trunk_pitch), (f"knee_{side}", knee_i, knee)):
                if side != self.swing_leg:
                    last = self.targets[name]
                    target = last + clamp(target - last, -s.target_step_rad, s.target_step_rad)
                n = w.exo.index(name)
                target = clamp(target, w.exo.lower[n] + 1e-3, w.exo.upper[n] - 1e-3)
                self.targets[name] = target
                w.exo.command(n, Mode.TRACK, target, 0.0, clamp(float(tau[joint]), -100.0, 100.0))

    def _feed_forward(self, reading: Reading) -> np.ndarray:
        """Joint torques that carry the body: the patient's wrench (its CoM target carried forward by
        the swing's advance) less the sticks' measured pushes, over the stance soles; the swing leg
        carries its own weight."""
        w, kin, p = self.world, self.kin, self.patient
        com = kin.com
        wrench = p.wrench()
        if self.swing_leg is not None and self.s.hip_advance_fraction > 0.0:
            wrench[0] += p.gains.fore_aft_n_m * self._advance()
        for i, side in enumerate(SIDES):  # each stick's load cell pushes along the stick (forearm axis)
            origin, rot = w.link_frame(f"forearm_{side}")
            force = float(reading.stick_force_n[i]) * rot[:, 2]
            wrench[:3] -= force
            wrench[3:] -= np.cross(p.tip_point(side) - com, force)
        feet = p.foot_contacts()
        forces, _ = distribute(wrench, com, feet, mu=0.5, min_normal_n=self.s.min_contact_n, weights=WRENCH_WEIGHTS,
                               known_moment=p.ankle_spring_moment())
        soles = [w.link_index[f"foot_{f}"] for f in SIDES if p.stance[f]]
        links = soles + [c.link for c in feet]
        points = [kin.link_com[i + 1] for i in soles] + [c.point for c in feet]
        loads = [(0.0, 0.0, w.masses[i + 1] * GRAVITY) for i in soles] + list(forces)
        grav = kin.gravity_torques()
        return grav - kin.generalised_force(links, points, loads) if links else grav
