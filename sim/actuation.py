"""Joint-level actuation: the node boards' firmware loop for the exoskeleton joints, and the same
impedance structure for the patient's arm muscles.

A node board's interface is what the CAN protocol carries: mode (track / hold / quick-stop /
disable), position target, velocity and torque feed-forward, torque limit; it reports encoder,
velocity and applied torque. The firmware's loop is a joint impedance at the physics rate:

    tau = clip(K (q* - q) + D (qd* - qd) + tau_ff, -limit, limit)

``hold`` and ``quick_stop`` hold the position latched when the mode was entered, with the hold
gains and the hold torque limit (CiA 402 "quick stop and stay"); ``disable`` applies no torque.
Commands are validated here, at the boundary: a non-finite value, a limit outside the joint's
rating or a target outside the joint's range is rejected (counted; the previous command stays).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np


class Mode(enum.IntEnum):
    """Same values as the protocol's JOINT_COMMAND.mode."""

    HOLD = 0
    TRACK = 1
    QUICK_STOP = 2
    DISABLE = 3


@dataclass(frozen=True)
class Gains:
    stiffness: np.ndarray  # (n,) N.m/rad
    damping: np.ndarray  # (n,) N.m.s/rad
    hold_stiffness: np.ndarray
    hold_damping: np.ndarray
    hold_torque_limit: np.ndarray


#: rows of a joint-loop law: every joint's loop is ``clip(k (x0 - q) + d (v0 - qd) + f, lo, hi)``
LAW_ROWS = 7


def law_torques(rows: tuple[np.ndarray, ...], q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Every column's ``clip(k (x0 - q) + d (v0 - qd) + f, lo, hi)`` for the rows (k, x0, d, v0,
    f, lo, hi) of a (7, n) law (``tuple(law)``, made once: views that follow the law's changes).
    Element by element, so each joint's torque is the same whichever other joints share the law."""
    k, x0, d, v0, f, lo, hi = rows
    tau = k * (x0 - q) + d * (v0 - qd) + f
    return np.minimum(np.maximum(tau, lo), hi)  # np.clip(tau, lo, hi) without its dispatch


def spring_law(stiffness: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """The (7, n) law of passive springs ``k (rest - q)``: no damping, no feed-forward, no limit."""
    n = len(stiffness)
    return np.array([stiffness, rest, np.zeros(n), np.zeros(n), np.zeros(n), np.full(n, -np.inf), np.full(n, np.inf)], dtype=float)


class JointImpedance:
    """Impedance loops of ``n`` joints, vectorised: each command sets its joint's column of a
    (7, n) law, which :func:`law_torques` turns into torques once per physics step
    (:meth:`torques` for these joints alone).

    ``law``, if given, is a (7, n) view into a larger law array whose torques the owner computes
    at once with :func:`law_torques` (the world's every torque-driven joint in one step); it must
    then call :meth:`latch` with these joints' positions first and set :attr:`applied`."""

    def __init__(self, names: tuple[str, ...], lower: np.ndarray, upper: np.ndarray, rated_torque: np.ndarray, gains: Gains,
                 law: np.ndarray | None = None) -> None:
        self.names = names
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.rated = np.asarray(rated_torque, float)
        self.gains = gains
        n = len(names)
        self.mode = np.full(n, int(Mode.HOLD))
        self.target = np.zeros(n)
        self.velocity_ff = np.zeros(n)
        self.torque_ff = np.zeros(n)
        self.limit = self.gains.hold_torque_limit.copy()
        self.hold_position = np.zeros(n)
        self.rejected = 0
        self.applied = np.zeros(n)
        self._needs_latch = np.ones(n, dtype=bool)
        self._latch_pending = True
        # Each joint's loop as tau = clip(k (x0 - q) + d (v0 - qd) + f, lo, hi), set per command and
        # latch (:meth:`_set_law`), so that the per-step :meth:`torques` is a few array operations.
        self._law = np.zeros((LAW_ROWS, n)) if law is None else law  # rows k, x0, d, v0, f, lo, hi; a joint's column set at once
        if self._law.shape != (LAW_ROWS, n):
            raise ValueError(f"a law of {n} joints is ({LAW_ROWS}, {n}), not {self._law.shape}")
        self._rows = tuple(self._law)
        for i in range(n):
            self._set_law(i)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def command(self, i: int, mode: int, position: float, velocity: float = 0.0, torque: float = 0.0, limit: float | None = None) -> bool:
        """Set joint ``i``'s command; returns False (and counts a rejection) for an invalid one."""
        limit = self.rated[i] if limit is None else limit
        if mode not in (0, 1, 2, 3) or not all(map(math.isfinite, (position, velocity, torque, limit))):
            self.rejected += 1
            return False
        if not (self.lower[i] <= position <= self.upper[i]) or not (0.0 <= limit <= self.rated[i]):
            self.rejected += 1
            return False
        # int(): a numpy integer compared with an IntEnum member costs microseconds (numpy probes the enum class)
        if mode in (Mode.HOLD, Mode.QUICK_STOP) and int(self.mode[i]) not in (Mode.HOLD, Mode.QUICK_STOP):
            self._needs_latch[i] = True
            self._latch_pending = True
        self.mode[i] = mode
        self.target[i], self.velocity_ff[i], self.torque_ff[i], self.limit[i] = position, velocity, torque, limit
        self._set_law(i)
        return True

    def track(self, positions: np.ndarray, torques: np.ndarray) -> int:
        """Every joint in track mode at once, to ``positions`` with the feed-forward ``torques``, no
        velocity feed-forward and the rated limit: :meth:`command` of each, vectorised (an invalid
        joint's command is rejected and counted, the others taken; the rated limit needs no check).
        Returns the rejections."""
        positions, torques = np.asarray(positions, dtype=float), np.asarray(torques, dtype=float)
        ok = np.isfinite(positions) & np.isfinite(torques) & (self.lower <= positions) & (positions <= self.upper)
        rejected = len(ok) - np.count_nonzero(ok)
        cols: slice | np.ndarray = slice(None)
        if rejected:
            positions, torques, cols = positions[ok], torques[ok], ok
            self.rejected += rejected
        self.mode[cols] = int(Mode.TRACK)
        self.target[cols], self.velocity_ff[cols], self.torque_ff[cols], self.limit[cols] = positions, 0.0, torques, self.rated[cols]
        self._track_law(cols)
        return rejected

    def _track_law(self, cols: int | slice | np.ndarray) -> None:
        """The track loop ``K (q* - q) + D (qd* - qd) + tau_ff`` within the command's limit, for
        the joints ``cols`` (one index, or several at once) from their commands."""
        g, limit = self.gains, self.limit[cols]
        self._law[:, cols] = (g.stiffness[cols], self.target[cols], g.damping[cols], self.velocity_ff[cols], self.torque_ff[cols], -limit, limit)

    def _set_law(self, i: int) -> None:
        """Joint ``i``'s loop coefficients for its mode. Track: :meth:`_track_law`; hold and quick stop: ``K_h (q_latched - q) + D_h (0 - qd)``
        (the same value as ``... - D_h qd``) within the hold limit; disable: zero gains, zero limit."""
        g, mode = self.gains, int(self.mode[i])
        if mode == Mode.TRACK:
            self._track_law(i)
        elif mode == Mode.HOLD or mode == Mode.QUICK_STOP:
            limit = min(g.hold_torque_limit[i], self.rated[i])
            self._law[:, i] = (g.hold_stiffness[i], self.hold_position[i], g.hold_damping[i], 0.0, 0.0, -limit, limit)
        else:
            self._law[:, i] = 0.0

    @property
    def latch_pending(self) -> bool:
        """Whether a joint entered hold or quick stop since the last :meth:`latch` (rarely)."""
        return self._latch_pending

    def latch(self, q: np.ndarray) -> None:
        """Hold and quick stop latch the position measured when entered: from ``q``, these joints'
        positions before the step whose torques follow (nothing to do on most steps)."""
        if self._latch_pending:
            for i in np.flatnonzero(self._needs_latch):
                self.hold_position[i] = q[i]
                self._needs_latch[i] = False
                self._set_law(i)
            self._latch_pending = False

    def torques(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Torque of every joint for the measured positions and velocities."""
        self.latch(q)
        self.applied = law_torques(self._rows, q, qd)
        return self.applied
