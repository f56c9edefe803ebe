"""Option C probe: the patient leans until its sticks carry a felt load (its intention), sticks placed from its shoulders.
Imported by sub.py when OPTC=1. Env: OPTC_AHEAD (m ahead of the shoulder), OPTC_REF (intention lean_x giving comfort load)."""
import os, math, dataclasses
import numpy as np
import sim.patient as P
from sim.patient import Phase
from sim.linalg import clamp
AHEAD = float(os.environ.get("OPTC_AHEAD", "0.30"))
REF = float(os.environ.get("OPTC_REF", "0.55"))
MAXN = float(os.environ.get("OPTC_MAX", "320"))
_update = P.Patient.update
def _lean_goal(self):
    rear, front = self.swing_span(self.front_foot())
    return rear + self.g.lean_x_max * (front - rear)
def update(self, reading):
    if self.phase in (Phase.LEAN, Phase.SWING) and self.plan.intention is not None:
        want = min(MAXN, self.g.stick_force_comfort_n * self.plan.intention.lean_x / REF)
        g0 = self.g
        self.g = dataclasses.replace(g0, stick_force_comfort_n=want)
        try:
            return _update(self, reading)
        finally:
            self.g = g0
    return _update(self, reading)
_stick_goal = P.Patient._stick_goal
def stick_goal(self, side, start):
    # shift the reference: the intention's ahead_m is taken from the shoulder, not the front ankle
    sh = float(self.shoulder(side)[0]); fa = float(self.ankle_xy(self.front_foot())[0])
    it = self.plan.intention
    self.plan.intention = dataclasses.replace(it, ahead_m=it.ahead_m - self.p.intention.ahead_m + AHEAD + (sh - fa))
    try:
        return _stick_goal(self, side, start)
    finally:
        self.plan.intention = it
P.Patient._lean_goal = _lean_goal
P.Patient.update = update
P.Patient._stick_goal = stick_goal
