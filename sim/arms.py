"""The patient's arms and forearm crutches: where a stick's tip and a shoulder are, and the arms'
joint commands each tick.

A planted arm pushes its stick's share of the balance (``G - J^T f``, no position hold, within the
joints' strength); a moving arm follows its tip's path by inverse kinematics: lifted ``stick_lift_m``
with no speed at either end (``sin^2``), carried on a minimum-jerk path and set down at rest, then
pressed ``SET_DOWN_PRESS_M`` below the floor over the path's last 30 % until it carries
``stick_planted_n`` (a tip driven below the floor at once slams it through a near-straight arm).
"""

from __future__ import annotations

import math

import numpy as np

from config.sim_schema import SimConfig
from sim.balance import Contact
from sim.kinematics import Kinematics
from sim.linalg import minimum_jerk
from sim.model import ARM_JOINTS, SIDES, arm_ik
from sim.world import World

SET_DOWN_PRESS_M = 0.02  # how far below the floor a set-down's tip path ends (over the path's last 30 %)
SET_DOWN_SHARE = 0.3  # of the path's phase over which the press ramps in, past its end


class Arms:
    """Both arms of the patient in ``world`` (read through ``kin``), and the sticks in the air."""

    def __init__(self, world: World, kin: Kinematics, cfg: SimConfig) -> None:
        self.world, self.kin, self.cfg = world, kin, cfg
        self.body = world.body
        self.forearm_idx = {s: world.joint_index[f"elbow_{s}"] for s in SIDES}
        self.joints = {s: [world.joint_index[f"{j}_{s}"] for j in ARM_JOINTS] for s in SIDES}
        self.tip_path: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}  # stick -> (start, goal, phase 0..1.3)
        b = self.body
        # the fixed geometry of the tip and shoulder points, and of the arms' command bounds
        self._stick_reach = b.forearm_m + b.grip_m + b.stick_m  # from the elbow along the forearm's -z
        self._tip_radius = np.array([0.0, 0.0, cfg.hardware.sticks.tip_radius_m])
        self._shoulder_local = {s: np.array([0.0, sign * b.shoulder_half_width_m, b.shoulder_above_hip_m])
                                for s, sign in zip(SIDES, (1.0, -1.0))}
        arms = world.arms
        self._target_lo, self._target_hi = arms.lower + 1e-3, arms.upper - 1e-3

    def tip_point(self, side: str) -> np.ndarray:
        """The stick tip's lowest point (on the floor when planted); read-only, once per state."""
        return self.kin.memo(("tip_point", side), self._tip_point, side)

    def _tip_point(self, side: str) -> np.ndarray:
        origin, rot = self.world.link_frame(f"forearm_{side}")
        tip = origin - rot[:, 2] * self._stick_reach - self._tip_radius
        tip.flags.writeable = False
        return tip

    def shoulder(self, side: str) -> np.ndarray:
        """The shoulder joint's place; read-only, once per state."""
        return self.kin.memo(("shoulder", side), self._shoulder, side)

    def _shoulder(self, side: str) -> np.ndarray:
        origin, rot = self.world.link_frame("trunk")
        shoulder = origin + rot @ self._shoulder_local[side]
        shoulder.flags.writeable = False
        return shoulder

    def command(self, contacts: list[Contact], forces: np.ndarray) -> None:
        """Planted arms push their share of ``forces`` (the tip contacts among ``contacts``); moving
        arms follow their tip paths."""
        w, kin, g = self.world, self.kin, self.cfg.gait
        grav = kin.gravity_torques()
        tips = [(c.link, c.point, f) for c, f in zip(contacts, forces) if c.name.startswith("tip_")]
        tau = grav - kin.generalised_force([t[0] for t in tips], [t[1] for t in tips], [t[2] for t in tips]) if tips else grav
        _, rot = w.link_frame("trunk")
        upper, lower = self.body.arm_reach_m
        targets: list[float] = []
        torques: list[float] = []
        for side in SIDES:  # in the arms' joint order (ARM_JOINT_NAMES: left, then right)
            joints = self.joints[side]
            if side in self.tip_path:
                start, goal, u = self.tip_path[side]
                point = start + (goal - start) * minimum_jerk(u)
                lift = g.stick_lift_m * math.sin(math.pi * min(u, 1.0)) ** 2
                press = SET_DOWN_PRESS_M * min(max(u - 1.0, 0.0) / SET_DOWN_SHARE, 1.0)
                point = point + np.array([0.0, 0.0, lift - press + self.cfg.hardware.sticks.tip_radius_m])
                reach = point - self.shoulder(side)
                length = float(np.linalg.norm(reach))
                if length > upper + lower - 1e-4:  # out of reach: the straight arm toward it
                    reach *= (upper + lower - 1e-4) / length
                try:
                    targets += arm_ik(rot.T @ reach, upper, lower, side)
                except ValueError:  # too far to the side for this arm: it holds where it is
                    targets += [w.q[j] for j in joints]
                torques += [grav[j] for j in joints]
            else:
                targets += [w.q[j] for j in joints]
                torques += [tau[j] for j in joints]
        arms = w.arms
        arms.track(np.minimum(np.maximum(targets, self._target_lo), self._target_hi), np.minimum(np.maximum(torques, -arms.rated), arms.rated))
