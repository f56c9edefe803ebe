"""The demonstration the DMP imitates: the swing of an exoskeleton's ankle in the sagittal plane.

Provenance. We ship no recorded data. The demonstration is an analytic profile: the
lift-advance-descend ankle path that position-controlled exoskeleton swings use (and the scripted
gait of ``sim.walk``), with minimum-jerk blends so that it starts and ends at rest. A healthy
ankle's height peaks in early swing and comes down while the foot still advances; the
exoskeleton's ankle is a passive spring, so its foot hangs toe-down while the knee is flexed, and
a foot that advances low catches its toe (measured with a bump-shaped lift peaking at 43 % of
the swing: touch-down at 60 % of the swing, the step 26 % short). So the foot first rises, then
advances at full height, then comes down onto the floor at its goal.

Profiles, with u = t / T in [0, 1] and S(a) = 10 a^3 - 15 a^4 + 6 a^5 (minimum jerk, clamped to
0 below a = 0 and to 1 above a = 1):

- up, z(t) = ankle_height + H * (S(u / r) - S((u - (1 - r)) / r)) with r = ``LIFT_RAMP``: up to H
  over the first 30 % of the swing, level, down over the last 30 %;
- forward, x(t) = L * S((u - a0) / (a1 - a0)) with (a0, a1) = ``ADVANCE``: from 10 % to 85 % of
  the swing, so the foot advances only once it is clear of the floor and is over its goal before
  the last 15 % of the descent.

Both start and end with zero velocity and acceleration; z starts and ends at the same height,
which the Pastor DMP form handles.

Pure functions; no I/O.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

from controller.dmp_model import DmpError

LIFT_RAMP = 0.3  # fraction of the swing over which the foot rises (and, at the end, comes down)
ADVANCE = (0.10, 0.85)  # fraction of the swing over which the foot moves forward
HASH_RESOLUTION = 1e-10  # m and s: what demonstration_hash tells apart


class DemonstrationError(DmpError):
    """Invalid demonstration parameters (one-line message)."""


def minimum_jerk(u) -> np.ndarray:
    """Minimum-jerk position profile ``10 u^3 - 15 u^4 + 6 u^5``, 0 -> 1 on u in [0, 1].

    Parameters
    ----------
    u : array_like, shape (m,)

    Returns
    -------
    ndarray, shape (m,)
    """
    u = np.asarray(u, dtype=np.float64)
    return u**3 * (10.0 + u * (-15.0 + 6.0 * u))


def lift_profile(u) -> np.ndarray:
    """Foot lift from 0 to 1 and back: up over the first ``LIFT_RAMP`` of the swing, level, down
    over the last ``LIFT_RAMP`` (minimum-jerk blends).

    Parameters
    ----------
    u : array_like, shape (m,)
        Fraction of the swing, in [0, 1].

    Returns
    -------
    ndarray, shape (m,)
    """
    u = np.asarray(u, dtype=np.float64)
    return minimum_jerk(np.clip(u / LIFT_RAMP, 0.0, 1.0)) - minimum_jerk(np.clip((u - (1.0 - LIFT_RAMP)) / LIFT_RAMP, 0.0, 1.0))


def advance_profile(u) -> np.ndarray:
    """Forward progress from 0 to 1 between the fractions ``ADVANCE`` of the swing (minimum jerk).

    Parameters
    ----------
    u : array_like, shape (m,)
        Fraction of the swing, in [0, 1].

    Returns
    -------
    ndarray, shape (m,)
    """
    u = np.asarray(u, dtype=np.float64)
    a0, a1 = ADVANCE
    return minimum_jerk(np.clip((u - a0) / (a1 - a0), 0.0, 1.0))


def swing_demonstration(
    step_m: float = 0.30,
    lift_m: float = 0.10,
    duration_s: float = 1.2,
    samples: int = 241,
    *,
    ankle_height_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Swing-ankle trajectory: forward ``step_m`` at a ``lift_m`` lift, sampled uniformly.

    Parameters
    ----------
    step_m : float
        Forward displacement of the ankle over the swing, m (> 0).
    lift_m : float
        Peak foot lift above ``ankle_height_m``, m (>= 0).
    duration_s : float
        Swing duration T, s (> 0).
    samples : int
        Number of samples, including both ends (>= 3); the default gives 5 ms spacing.
    ankle_height_m : float
        Ankle height at the start and the end of the swing, m.

    Returns
    -------
    times_s : ndarray, shape (samples,)
        From 0 to ``duration_s``.
    xz : ndarray, shape (samples, 2)
        Columns x (forward, from 0 to ``step_m``) and z (up).
    """
    values = {"step_m": step_m, "lift_m": lift_m, "duration_s": duration_s, "ankle_height_m": ankle_height_m}
    for name, value in values.items():
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise DemonstrationError(f"{name} must be a finite number, got {value!r}")
    if step_m <= 0.0 or duration_s <= 0.0 or lift_m < 0.0:
        raise DemonstrationError(f"need step_m > 0, lift_m >= 0, duration_s > 0, got {step_m}, {lift_m}, {duration_s}")
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 3:
        raise DemonstrationError(f"samples must be an integer >= 3, got {samples!r}")
    u = np.linspace(0.0, 1.0, int(samples))
    xz = np.column_stack([step_m * advance_profile(u), ankle_height_m + lift_m * lift_profile(u)])
    return duration_s * u, xz


def demonstration_hash(times_s, xz) -> str:
    """Stable identifier of a demonstration: SHA-256 (hex) of its shapes and its samples rounded to
    ``HASH_RESOLUTION`` (little-endian float64).

    Use it to check that cached fitted weights belong to the demonstration at hand. The rounding
    makes it the same on every platform: numpy versions and CPUs differ in the last bits of the
    same arithmetic (numpy 2.4 changed the hash of the unrounded samples), while any change of the
    demonstration that matters to a fit moves a sample by far more than the resolution.

    Parameters
    ----------
    times_s : array_like, shape (m,)
    xz : array_like, shape (m, d)

    Returns
    -------
    str
        64 hexadecimal characters.
    """
    digest = hashlib.sha256(b"aider-exo swing demonstration v2")
    for array in (times_s, xz):
        canonical = np.ascontiguousarray(np.round(np.asarray(array, dtype="<f8") / HASH_RESOLUTION)).astype("<f8")
        digest.update(repr(canonical.shape).encode())
        digest.update(canonical.tobytes())
    return digest.hexdigest()
