"""The patient's intention for each step: where it means to place the sticks and how far it means
to lean onto them.

The paper's simulation sets "the pilot's intention (goal places of sticks) ... as a noisy
parameter with Gaussian white noise, which makes each step of the pilot not fixed", and on the
real AIDER "the pilot put the sticks randomly in each step". Before the stick moves of each step
the patient picks one intended placement, ``ahead_m`` ahead of its front ankle (or of its centre
of mass, ``reference``), and how far it will lean before the step: the X_CoM/X_SP ``lean_x`` of
the swing's support (stance heel to stick tips). Both vary by the regime
(``sim.patient.intention``), each by its own draw:

* ``steady``: always ``ahead_m`` and ``lean_x``;
* ``noisy`` (default): Gaussian white noise of standard deviation ``spread_m`` and
  ``lean_spread`` (the paper's);
* ``drifting``: a pace that wanders slowly, a first-order autoregressive process of stationary
  standard deviation ``spread_m`` (``lean_spread``) and correlation length ``drift_steps`` steps;
* ``obstacle``: the steady intention, except with probability ``obstacle_probability`` a
  deliberately short or long placement, ``obstacle_offset_m`` shorter or longer (either with
  equal chance); the lean stays ``lean_x``.

Each stick then lands at the intention plus its own placement error (``stick_noise_m``), within
what the arms can reach (:mod:`sim.patient` clamps and counts). Pure and seeded: the same
generator gives the same intentions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from config.sim_schema import IntentionConfig


@dataclass(frozen=True)
class StepIntention:
    """What the patient means to do in one step."""

    ahead_m: float  # its sticks this far ahead of the reference
    lean_x: float  # the X_CoM/X_SP (stance heel to tips) it leans to before the swing


class Intention:
    """The intentions of one patient, drawn one step at a time from ``rng``."""

    def __init__(self, cfg: IntentionConfig, rng: np.random.Generator) -> None:
        self.cfg, self.rng = cfg, rng
        self._wander: tuple[float, float] | None = None  # drifting: the departures from the means, in spreads

    def next(self) -> StepIntention:
        """The intention of the next step (placement, then lean, drawn in that order)."""
        c = self.cfg
        if c.regime == "steady":
            return StepIntention(c.ahead_m, c.lean_x)
        if c.regime == "noisy":
            z_place, z_lean = self.rng.normal(size=2).tolist()
        elif c.regime == "drifting":
            if self._wander is None:  # the first step: drawn from the stationary distribution
                self._wander = tuple(self.rng.normal(size=2).tolist())
            else:
                a = math.exp(-1.0 / c.drift_steps)
                fresh = self.rng.normal(size=2).tolist()
                self._wander = tuple(a * w + math.sqrt(1.0 - a * a) * f for w, f in zip(self._wander, fresh))
            z_place, z_lean = self._wander
        else:  # obstacle
            offset = 0.0
            if self.rng.random() < c.obstacle_probability:
                offset = c.obstacle_offset_m if self.rng.random() < 0.5 else -c.obstacle_offset_m
            return StepIntention(c.ahead_m + offset, c.lean_x)
        return StepIntention(c.ahead_m + c.spread_m * z_place, c.lean_x + c.lean_spread * z_lean)
