"""The demonstration the DMP imitates: a healthy-looking swing of the ankle in the sagittal plane.

Provenance. We ship no recorded data. The demonstration is an analytic profile, shaped after the
swing-phase ankle trajectory of healthy gait as described in the gait literature (e.g. D. A.
Winter, *Biomechanics and Motor Control of Human Movement*, Wiley: the ankle moves forward with a
smooth bell-shaped velocity and rises to its highest point in early-to-mid swing, then comes down
to heel strike). It is *not* digitised from Winter's or anyone's data. Simplifications: the foot
starts and ends at rest on the ground (a discrete movement, as the exoskeleton swing is), and the
lift is a single smooth bump.

Profiles, with u = t / T in [0, 1]:

- forward, x(t) = L * (10 u^3 - 15 u^4 + 6 u^5)   (minimum jerk: zero velocity and acceleration at
  both ends, velocity peak at mid-swing);
- up, z(t) = ankle_height + H * u^3 (1 - u)^4 / (u_p^3 (1 - u_p)^4) with u_p = 3/7   (a polynomial
  bump: zero velocity and acceleration at both ends, peak H at 43 % of the swing, a slower descent
  than rise). z starts and ends at the same height, which the Pastor DMP form handles.

Pure functions; no I/O.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

from controller.dmp import DmpError

# Exponents of the lift bump u^a (1 - u)^b: its peak is at u = a / (a + b).
LIFT_RISE_EXPONENT = 3
LIFT_FALL_EXPONENT = 4
LIFT_PEAK_FRACTION = LIFT_RISE_EXPONENT / (LIFT_RISE_EXPONENT + LIFT_FALL_EXPONENT)


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
    """Foot-lift bump ``u^3 (1 - u)^4``, normalised to peak 1 at u = 3/7; 0 at u = 0 and 1.

    Parameters
    ----------
    u : array_like, shape (m,)

    Returns
    -------
    ndarray, shape (m,)
    """
    u = np.asarray(u, dtype=np.float64)
    a, b, p = LIFT_RISE_EXPONENT, LIFT_FALL_EXPONENT, LIFT_PEAK_FRACTION
    return u**a * (1.0 - u) ** b / (p**a * (1.0 - p) ** b)


def swing_demonstration(
    step_m: float = 0.30,
    lift_m: float = 0.10,
    duration_s: float = 1.2,
    samples: int = 241,
    *,
    ankle_height_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Swing-ankle trajectory: forward ``step_m`` with a ``lift_m`` bump, sampled uniformly.

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
    xz = np.column_stack([step_m * minimum_jerk(u), ankle_height_m + lift_m * lift_profile(u)])
    return duration_s * u, xz


def demonstration_hash(times_s, xz) -> str:
    """Stable identifier of a demonstration: SHA-256 (hex) of its shapes and little-endian float64 bytes.

    Use it to check that cached fitted weights belong to the demonstration at hand. Equal arrays give
    equal hashes on every platform; a change of the last bit of any sample changes the hash (which
    only forces a refit).

    Parameters
    ----------
    times_s : array_like, shape (m,)
    xz : array_like, shape (m, d)

    Returns
    -------
    str
        64 hexadecimal characters.
    """
    digest = hashlib.sha256(b"aider-exo swing demonstration v1")
    for array in (times_s, xz):
        canonical = np.ascontiguousarray(np.asarray(array, dtype="<f8"))
        digest.update(repr(canonical.shape).encode())
        digest.update(canonical.tobytes())
    return digest.hexdigest()
