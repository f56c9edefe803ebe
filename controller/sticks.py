"""The patient's stick moves, from the sticks' measured forces (pure numpy).

The gait (:mod:`controller.gait`) waits for them in each double support. A stick has moved once it
was off the floor (filtered force below ``stick_lifted_n`` for ``stick_lift_s``) and was planted
again (above ``stick_placed_n``) since the last swing started, wherever it went. ``StickTracker``
keeps that per stick, and whether both sticks are planted and leant on (``swing_stick_n``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from config.controller_schema import GaitConfig
from controller.balance import LEGS
from controller.estimator import Measurements


@dataclass
class StickTracker:
    """Which sticks the patient has moved since the last swing started (see the module doc)."""

    params: GaitConfig
    dt_s: float
    force_n: np.ndarray = field(default_factory=lambda: np.zeros(2))  # filtered
    raw_n: np.ndarray = field(default_factory=lambda: np.zeros(2))  # this tick's
    unloaded_s: np.ndarray = field(default_factory=lambda: np.zeros(2))
    lifted: list[bool] = field(default_factory=lambda: [False, False])
    moved: list[bool] = field(default_factory=lambda: [False, False])

    def reset(self) -> None:
        """A new cycle: the sticks must move again."""
        self.unloaded_s[:] = 0.0
        self.lifted = [False, False]
        self.moved = [False, False]

    def update(self, m: Measurements) -> None:
        p = self.params
        a = min(1.0, self.dt_s / p.stick_filter_s) if p.stick_filter_s > 0 else 1.0
        self.raw_n = np.asarray(m.stick_force_n, dtype=float)
        raw, force, unloaded = self.raw_n.tolist(), self.force_n.tolist(), self.unloaded_s.tolist()
        for i in LEGS:
            force[i] += a * (raw[i] - force[i])
            # with hysteresis: a lifted stick's reading (sensor noise about 0 N) may cross
            # stick_lifted_n now and then; only a load of stick_placed_n ends the count
            if force[i] < p.stick_lifted_n:
                unloaded[i] += self.dt_s
            elif force[i] > p.stick_placed_n or unloaded[i] < self.dt_s:
                unloaded[i] = 0.0
            if unloaded[i] >= p.stick_lift_s:
                self.lifted[i] = True
            if self.lifted[i] and force[i] > p.stick_placed_n:
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
