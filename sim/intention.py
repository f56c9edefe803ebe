"""The patient's intention: how far ahead it means to place the sticks, step by step.

The paper's simulation sets "the pilot's intention (goal places of sticks) ... as a noisy
parameter with Gaussian white noise, which makes each step of the pilot not fixed", and on the
real AIDER "the pilot put the sticks randomly in each step". Before the stick moves of each step
the patient picks one intended placement, ``ahead_m`` ahead of its centre of mass (or of its front
ankle, ``reference``) plus the regime's variation (``sim.patient.intention``):

* ``steady``: always ``ahead_m``;
* ``noisy`` (default): Gaussian white noise of standard deviation ``spread_m`` (the paper's);
* ``drifting``: an intended pace that wanders slowly, a first-order autoregressive process of
  stationary standard deviation ``spread_m`` and correlation length ``drift_steps`` steps;
* ``obstacle``: ``ahead_m``, except with probability ``obstacle_probability`` a deliberately
  short or long placement, ``obstacle_offset_m`` shorter or longer (either with equal chance).

Each stick then lands at the intention plus its own placement error (``stick_noise_m``), within
what the arms can reach (:mod:`sim.walk` clamps and counts). Pure and seeded: the same generator
gives the same intentions.
"""

from __future__ import annotations

import math

import numpy as np

from config.sim_schema import IntentionConfig


class Intention:
    """The intended placements of one patient, drawn one step at a time from ``rng``."""

    def __init__(self, cfg: IntentionConfig, rng: np.random.Generator) -> None:
        self.cfg, self.rng = cfg, rng
        self._wander: float | None = None  # drifting: the pace's departure from ahead_m

    def next_m(self) -> float:
        """The intended placement of the next step's sticks ahead of the CoM, m."""
        c = self.cfg
        if c.regime == "steady":
            return c.ahead_m
        if c.regime == "noisy":
            return c.ahead_m + float(self.rng.normal(0.0, c.spread_m))
        if c.regime == "drifting":
            if self._wander is None:  # the first step: drawn from the stationary distribution
                self._wander = float(self.rng.normal(0.0, c.spread_m))
            else:
                a = math.exp(-1.0 / c.drift_steps)
                self._wander = a * self._wander + math.sqrt(1.0 - a * a) * float(self.rng.normal(0.0, c.spread_m))
            return c.ahead_m + self._wander
        # obstacle
        if self.rng.random() < c.obstacle_probability:
            return c.ahead_m + (c.obstacle_offset_m if self.rng.random() < 0.5 else -c.obstacle_offset_m)
        return c.ahead_m
