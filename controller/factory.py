"""Components of the controller's numerical core, built from the ``controller`` configuration section."""

from __future__ import annotations

import numpy as np

from config.controller_schema import ControllerConfig
from controller.compensation import StepBounds
from controller.kinematics import Leg
from controller.pi2 import Pi2Learner, Pi2Params


def leg(cfg: ControllerConfig) -> Leg:
    g = cfg.legs
    return Leg(g.thigh_m, g.shank_m, g.hip_min_rad, g.hip_max_rad, g.knee_min_rad, g.knee_max_rad)


def step_bounds(cfg: ControllerConfig) -> StepBounds:
    return StepBounds(init_m=cfg.step.init_m, min_m=cfg.step.min_m, max_m=cfg.step.max_m)


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
    )


def learner(cfg: ControllerConfig, rng: np.random.Generator) -> Pi2Learner:
    """A new learner at the configured start theta = (alpha, Xhat_CoM)."""
    return Pi2Learner(pi2_params(cfg), np.array([cfg.learning.initial_alpha, cfg.learning.initial_xhat]), rng)
