"""Components of the controller's numerical core, built from the ``controller`` configuration section."""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

import numpy as np

from config.controller_schema import ControllerConfig
from controller.balance import GRAVITY, BalanceGains, LegLoads
from controller.compensation import StepBounds
from controller.dmp import Dmp
from controller.dmp_model import DmpWeights
from controller.envelope import JointBounds
from controller.gait import GaitPlanner
from controller.kinematics import Leg
from controller.pi2 import Pi2Learner, Pi2Params
from controller.policy import StepPolicy
from protocol.clock import TICK_S

if TYPE_CHECKING:
    from controller.learned import LearnedSaver


def leg(cfg: ControllerConfig) -> Leg:
    g, j = cfg.legs, cfg.hardware.joints
    return Leg(g.thigh_m, g.shank_m, j.hip.lower_rad, j.hip.upper_rad, j.knee.lower_rad, j.knee.upper_rad)


def joint_bounds(cfg: ControllerConfig) -> tuple[JointBounds, ...]:
    """The four joints' ranges, named as the controller names them (hip_l, knee_l, hip_r, knee_r)."""
    j = cfg.hardware.joints
    return tuple(JointBounds(f"{kind}_{side}", joint.lower_rad, joint.upper_rad) for side in ("l", "r")
                 for kind, joint in (("hip", j.hip), ("knee", j.knee)))


def gait_planner(cfg: ControllerConfig, swing_weights: DmpWeights) -> GaitPlanner:
    """The gait of one tick period with the fitted swing."""
    return GaitPlanner(leg(cfg), Dmp(swing_weights), cfg.gait, leg_loads(cfg), balance_gains(cfg),
                       ankle_height_m=cfg.legs.ankle_height_m, swing_s=swing_duration_s(cfg), dt_s=TICK_S,
                       substeps=cfg.swing.substeps)


def leg_loads(cfg: ControllerConfig) -> LegLoads:
    return LegLoads(cfg.body, leg(cfg), cfg.hardware.foot)


def balance_gains(cfg: ControllerConfig) -> BalanceGains:
    b = cfg.balance
    return BalanceGains(com_n_m=b.com_stiffness_n_m, com_ns_m=b.com_damping_ns_m, height_n_m=b.height_stiffness_n_m,
                        height_ns_m=b.height_damping_ns_m, tilt_nm_rad=b.tilt_stiffness_nm_rad, tilt_nms_rad=b.tilt_damping_nms_rad,
                        friction=b.friction, min_foot_n=b.min_foot_n, ankle_stiffness_nm_rad=cfg.hardware.joints.ankle.stiffness_nm_rad,
                        ankle_rest_rad=cfg.hardware.joints.ankle.rest_rad)


#: step lengths are commanded to a tenth of a millimetre
STEP_RESOLUTION_DIGITS = 4


def step_bounds(cfg: ControllerConfig) -> StepBounds:
    """The step lengths in metres: ``controller.step``'s fractions of this patient's leg length,
    to STEP_RESOLUTION_DIGITS decimals (the reference patient's fractions give its round metres)."""
    leg, s = cfg.legs.length_m, cfg.step
    return StepBounds(*(round(f * leg, STEP_RESOLUTION_DIGITS) for f in (s.init_fraction, s.min_fraction, s.max_fraction)))


#: swings last a whole millisecond
SWING_RESOLUTION_DIGITS = 3


def swing_duration_s(cfg: ControllerConfig) -> float:
    """The swing's duration tau in seconds: ``swing.duration_scaled`` in units of sqrt(leg length / g),
    so that patients of every size swing at the same Froude number (dynamic similarity, Hof 1996),
    to the millisecond."""
    return round(cfg.swing.duration_scaled * math.sqrt(cfg.legs.length_m / GRAVITY), SWING_RESOLUTION_DIGITS)


def pi2_params(cfg: ControllerConfig) -> Pi2Params:
    c = cfg.learning
    return Pi2Params(
        rollouts_per_update=c.rollouts_per_update,
        steps_per_rollout=c.steps_per_rollout,
        h=c.temperature_h,
        noise_std=(c.noise_alpha, c.noise_xhat),
        noise_decay=c.noise_decay,
        noise_floor=c.noise_floor,
        lower=(c.alpha_min, c.xhat_min),
        upper=(c.alpha_max, c.xhat_max),
        method=c.method,
        lambda1=c.fall_cost,
        lambda2=c.force_cost,
        average_last=c.average_last,
        reuse_best=c.reuse_best,
        max_consecutive_rejections=c.max_consecutive_rejections,
    )


def learner(cfg: ControllerConfig, rng: np.random.Generator) -> Pi2Learner:
    """A new learner at the configured start theta = (alpha, Xhat_CoM)."""
    return Pi2Learner(pi2_params(cfg), np.array([cfg.learning.initial_alpha, cfg.learning.initial_xhat]), rng)


def step_policy(
    cfg: ControllerConfig, *, fixed_m: float | None = None, learn: bool = False, patient: str | None = None,
    learned_dir: str | None = None, rng: np.random.Generator | None = None,
) -> tuple[StepPolicy, LearnedSaver | None]:
    """Where every swing's step length comes from, and the patient-file writer to close at the end
    (None when nothing is saved):

    * ``fixed_m``: every step that long (the baseline without compensation);
    * ``learn``: online PI² from the patient's stored learner (or a new one at the configured
      start), its file rewritten after every roll-out when a ``patient`` is named (so a restart
      loses no finished roll-out);
    * otherwise the compensation with the patient's learned theta, or the configured one without
      ``patient``; a named patient without a file is a :class:`LearnedError` naming the path (only
      learning creates a patient's learned file).
    """
    from controller.learned import LearnedError, LearnedSaver, load_learned, learned_path, restore_learner

    bounds = step_bounds(cfg)
    directory = learned_dir if learned_dir is not None else os.path.expanduser(cfg.learned_dir)
    if fixed_m is not None:
        if learn:
            raise LearnedError("a fixed step length cannot be learned: give --fixed-step or --learn, not both")
        if patient:
            raise LearnedError(f"a fixed step length uses no learned parameters: --patient {patient} has no effect with --fixed-step")
        return StepPolicy(bounds, fixed_m=fixed_m), None
    c = cfg.learning
    record = load_learned(directory, patient, lower=(c.alpha_min, c.xhat_min), upper=(c.alpha_max, c.xhat_max)) if patient else None
    if not learn:
        if patient and record is None:  # a typo or another folder must never walk a patient on the defaults
            raise LearnedError(f"{learned_path(directory, patient)}: no such learned file (--patient {patient}); check the "
                               "name and the folder (--learned-dir, controller.learned_dir), or create it with --learn")
        theta = record.theta if record is not None else (cfg.compensation.alpha, cfg.compensation.xhat_com)
        return StepPolicy(bounds, theta=theta), None
    rng = rng if rng is not None else np.random.default_rng()
    pi2 = restore_learner(record, rng, learned_path(directory, patient)) if record is not None else None
    pi2 = pi2 or learner(cfg, rng)
    saver = LearnedSaver(directory, patient) if patient else None

    def on_update(l: Pi2Learner, _record: object) -> None:
        if saver is not None:
            saver.submit(l.evaluation_theta(), l)

    return StepPolicy(bounds, learner=pi2, on_update=on_update), saver
