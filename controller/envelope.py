"""The safety envelope: the last gate of every joint command before it is encoded (docs/FAULTS.md I1).

For each joint: the position setpoint inside [limit + margin], the setpoint's change per tick, the
velocity feed-forward, the torque feed-forward and the torque limit within their bounds, and every
value finite. A value outside is clamped and the clamp reported; a value beyond the envelope by
more than its excess allowance (``position_excess_rad``, or ``rate_excess_factor`` times a rate or
torque bound) or a non-finite value is a *violation*: the caller treats it as a fault, because
saturation would hide a wrong trajectory (F17). Hold commands carry no setpoint to check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from protocol.commands import JointCommand
from protocol.enums import JointMode


class EnvelopeError(ValueError):
    """Inconsistent envelope bounds (a configuration error, raised at start)."""


@dataclass(frozen=True)
class JointBounds:
    name: str
    lower_rad: float  # joint limits (the margin is applied by the envelope)
    upper_rad: float


class Checked(NamedTuple):
    command: JointCommand  # safe to encode
    clamped: tuple[str, ...] = ()  # what was clamped, e.g. "position 2.10 -> 1.98"
    violation: str | None = None  # beyond the allowance: a fault


class Envelope:
    def __init__(
        self, joints: tuple[JointBounds, ...], *, margin_rad: float, max_velocity_rad_s: float, max_step_rad: float,
        max_torque_nm: float, position_excess_rad: float, rate_excess_factor: float,
    ) -> None:
        for j in joints:
            if not j.lower_rad + margin_rad < j.upper_rad - margin_rad:
                raise EnvelopeError(f"{j.name}: the margin {margin_rad} leaves no range inside [{j.lower_rad}, {j.upper_rad}]")
        self.joints = {j.name: j for j in joints}
        self.margin = margin_rad
        self.max_velocity = max_velocity_rad_s
        self.max_step = max_step_rad
        self.max_torque = max_torque_nm
        self.position_excess = position_excess_rad
        self.excess = rate_excess_factor

    @classmethod
    def from_config(cls, joints: tuple[JointBounds, ...], cfg) -> Envelope:  # cfg: config.controller_schema.EnvelopeConfig
        return cls(
            joints, margin_rad=cfg.position_margin_rad, max_velocity_rad_s=cfg.max_velocity_rad_s,
            max_step_rad=cfg.max_step_rad, max_torque_nm=cfg.max_torque_nm,
            position_excess_rad=cfg.position_excess_rad, rate_excess_factor=cfg.rate_excess_factor,
        )

    def check(self, joint: str, cmd: JointCommand, previous_position_rad: float) -> Checked:
        """Clamp ``cmd`` of ``joint`` into the envelope; ``previous_position_rad`` is the setpoint
        of the last tick (or the measured position when the last command was not a track)."""
        b = self.joints[joint]
        values = (cmd.position_rad, cmd.velocity_rad_s, cmd.torque_nm, cmd.torque_limit_nm, previous_position_rad)
        if not all(map(math.isfinite, values)):
            hold = JointCommand(JointMode.HOLD, torque_limit_nm=self.max_torque)
            return Checked(hold, violation=f"{joint}: non-finite command {values[:4]}")
        if cmd.mode != JointMode.TRACK:
            limit = min(max(cmd.torque_limit_nm, 0.0), self.max_torque)
            return Checked(JointCommand(cmd.mode, torque_limit_nm=limit))
        step, v, t = self.max_step, self.max_velocity, self.max_torque
        step_lo, step_hi = previous_position_rad - step, previous_position_rad + step
        lo, hi = b.lower_rad + self.margin, b.upper_rad - self.margin
        q, qd, tau, limit = values[:4]
        if step_lo <= q <= step_hi and lo <= q <= hi and -v <= qd <= v and -t <= tau <= t and 0.0 <= limit <= t:
            # inside every bound: nothing to clamp (what the clamps below would return unchanged)
            return Checked(cmd if cmd.mode is JointMode.TRACK else JointCommand(JointMode.TRACK, q, qd, tau, limit))
        clamped: list[str] = []
        violation: str | None = None

        def clip(what: str, value: float, lo: float, hi: float, allowance: float) -> float:
            nonlocal violation
            if lo <= value <= hi:
                return value
            out = min(max(value, lo), hi)
            clamped.append(f"{what} {value:.4g} -> {out:.4g}")
            if abs(value - out) > allowance and violation is None:
                violation = f"{joint}: {what} {value:.4g} beyond [{lo:.4g}, {hi:.4g}]"
            return out

        q = clip("setpoint step", q, step_lo, step_hi, (self.excess - 1.0) * step)
        q = clip("position", q, lo, hi, self.position_excess)  # last: the joint range always wins
        qd = clip("velocity", qd, -v, v, (self.excess - 1.0) * v)
        tau = clip("torque", tau, -t, t, (self.excess - 1.0) * t)
        limit = clip("torque limit", limit, 0.0, t, (self.excess - 1.0) * t)
        return Checked(JointCommand(JointMode.TRACK, q, qd, tau, limit), tuple(clamped), violation)
