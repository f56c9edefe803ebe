"""The model of the swing's Dynamic Movement Primitive: its parameters, basis, forcing term and fit.

A discrete DMP in the form of Pastor et al. (ICRA 2009), n-dimensional. Per coordinate (SPEC.md,
"The model"; the paper's equation (5) with its lost minus sign restored):

    tau dv/dt = K (g - x) - D v - K (g - x0) s + K f(s)
    tau dx/dt = v
    tau ds/dt = -alpha_s s                                  (phase s: 1 -> 0)
    f(s)      = sum_i w_i psi_i(s) s / sum_i psi_i(s),      psi_i(s) = exp(-h_i (s - c_i)^2)
    f_target  = (tau dv/dt + D v) / K - (g - x) + (g - x0) s      (v = tau dx/dt)

We use d = 2 (x forward, z up: the swing ankle in the sagittal plane), but nothing here depends on d.
Unlike the Ijspeert (2002) form, f is not scaled by (g - x0), so a coordinate whose start equals its
goal (the ankle height z) is learnt and reproduced without blowing up. The price: a new goal does
not scale the demonstrated shape in proportion; it adds the spring's response to the goal shift.

This module defines the model and learns its weights from one demonstration (``fit``, through
:mod:`controller.swing` when ``aider-exo dmp fit`` refits the cached weights); :mod:`controller.dmp`
integrates a fitted primitive tick by tick (the 20 ms loop steps a ``Dmp`` and never fits).

Pure numerical core: no I/O, no clock, no global state; inputs are never modified.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.arrays import float_array


class DmpError(ValueError):
    """Invalid parameters, demonstration or state for a DMP (one-line message)."""


def _finite_positive(name: str, value: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise DmpError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise DmpError(f"{name} must be finite and > 0, got {value}")
    return value


@dataclass(frozen=True)
class DmpParams:
    """Hyper-parameters of the DMP (dimensionless: time enters only through ``tau_s``).

    Parameters
    ----------
    n_basis : int
        Number of Gaussian basis functions of f (>= 2).
    stiffness : float
        K (> 0). The default 156.25 with critical damping gives D = 25 (movement_primitives' a_y = 25,
        b_y = 6.25).
    damping : float or None
        D (>= 0); None means critical damping 2 sqrt(K). Read ``effective_damping``.
    alpha_s : float
        Phase decay rate (> 0); the default ln(100) makes s = 0.01 at t = tau.
    regularisation : float
        Ridge term (>= 0) added to the normal equations of the fit.
    goal_alpha : float or None
        Rate alpha_g (> 0) of the goal filter ``tau dg/dt = alpha_g (g_request - g)``; None means
        sqrt(K) (= D / 2 at critical damping). Read ``effective_goal_alpha``.
    """

    n_basis: int = 25
    stiffness: float = 156.25
    damping: float | None = None
    alpha_s: float = math.log(100.0)
    regularisation: float = 1e-6
    goal_alpha: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.n_basis, bool) or not isinstance(self.n_basis, (int, np.integer)) or self.n_basis < 2:
            raise DmpError(f"n_basis must be an integer >= 2, got {self.n_basis!r}")
        _finite_positive("stiffness", self.stiffness)
        _finite_positive("alpha_s", self.alpha_s)
        if self.damping is not None and not (math.isfinite(self.damping) and self.damping >= 0.0):
            raise DmpError(f"damping must be finite and >= 0 (or None), got {self.damping}")
        if not (math.isfinite(self.regularisation) and self.regularisation >= 0.0):
            raise DmpError(f"regularisation must be finite and >= 0, got {self.regularisation}")
        if self.goal_alpha is not None:
            _finite_positive("goal_alpha", self.goal_alpha)

    @property
    def effective_damping(self) -> float:
        """D: ``damping``, or 2 sqrt(K) when it is None."""
        return 2.0 * math.sqrt(self.stiffness) if self.damping is None else float(self.damping)

    @property
    def effective_goal_alpha(self) -> float:
        """alpha_g: ``goal_alpha``, or sqrt(K) when it is None."""
        return math.sqrt(self.stiffness) if self.goal_alpha is None else float(self.goal_alpha)


def phase(times_s, tau_s: float, alpha_s: float) -> np.ndarray:
    """Analytic phase ``s(t) = exp(-alpha_s t / tau)``.

    Parameters
    ----------
    times_s : array_like, shape (m,) or scalar
        Time since the start of the movement, s.
    tau_s : float
        Duration of the movement, s.
    alpha_s : float
        Phase decay rate.

    Returns
    -------
    ndarray, shape (m,) or ()
    """
    tau_s = _finite_positive("tau_s", tau_s)
    alpha_s = _finite_positive("alpha_s", alpha_s)
    return np.exp(-alpha_s * np.asarray(times_s, dtype=np.float64) / tau_s)


def basis(params: DmpParams) -> tuple[np.ndarray, np.ndarray]:
    """Centres and widths of the Gaussian basis functions in phase.

    Centres are the phase values at ``n_basis`` equally spaced times from 0 to tau (so c_0 = 1 and
    c_{n-1} = exp(-alpha_s)); widths make neighbouring kernels overlap at 0.8:
    ``h_i = -ln(0.8) / (c_{i+1} - c_i)^2``, the last width equal to the previous one.

    Returns
    -------
    centres : ndarray, shape (n_basis,)
    widths : ndarray, shape (n_basis,)
    """
    centres = np.exp(-params.alpha_s * np.linspace(0.0, 1.0, params.n_basis))
    widths = np.empty(params.n_basis)
    widths[:-1] = -math.log(0.8) / np.diff(centres) ** 2
    widths[-1] = widths[-2]
    return centres, widths


def _features(s: np.ndarray, centres: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """Normalised, phase-gated basis ``psi_i(s) s / sum_j psi_j(s)``, shape (m, n) for s of shape (m,)."""
    psi = np.exp(-widths * (s[:, None] - centres) ** 2)
    return psi * (s / psi.sum(axis=1))[:, None]


def forcing(s, weights, centres, widths) -> np.ndarray:
    """Forcing term ``f(s) = sum_i w_i psi_i(s) s / sum_i psi_i(s)`` per coordinate.

    Parameters
    ----------
    s : float or array_like, shape (m,)
        Phase value(s) in [0, 1].
    weights : array_like, shape (d, n)
    centres, widths : array_like, shape (n,)
        From ``basis``.

    Returns
    -------
    ndarray, shape (d,) for a scalar s, (m, d) for s of shape (m,)
    """
    weights = float_array(weights, "weights", DmpError, ndim=2)
    n = weights.shape[1]
    centres = float_array(centres, "centres", DmpError, shape=(n,))
    widths = float_array(widths, "widths", DmpError, shape=(n,))
    s_array = float_array(s, "s", DmpError)
    if s_array.ndim > 1:
        raise DmpError(f"s must be a scalar or have shape (m,), got {s_array.shape}")
    if np.any((s_array < 0.0) | (s_array > 1.0)):
        raise DmpError("phase s must lie in [0, 1]")
    values = _features(np.atleast_1d(s_array), centres, widths) @ weights.T
    return values[0] if s_array.ndim == 0 else values


@dataclass(frozen=True, eq=False)
class DmpWeights:
    """A fitted DMP: forcing weights plus the demonstration's start, goal and duration.

    Attributes
    ----------
    weights : ndarray, shape (d, n_basis)
        Read-only.
    x0 : ndarray, shape (d,)
        Start of the demonstration. Read-only.
    g : ndarray, shape (d,)
        Goal (end) of the demonstration. Read-only.
    tau_s : float
        Duration of the demonstration, s.
    params : DmpParams
    """

    weights: np.ndarray
    x0: np.ndarray
    g: np.ndarray
    tau_s: float
    params: DmpParams

    def __post_init__(self) -> None:
        if not isinstance(self.params, DmpParams):
            raise DmpError(f"params must be a DmpParams, got {type(self.params).__name__}")
        weights = float_array(self.weights, "weights", DmpError, ndim=2)
        d, n = weights.shape
        if n != self.params.n_basis or d < 1:
            raise DmpError(f"weights must have shape (d >= 1, {self.params.n_basis}), got {weights.shape}")
        x0 = float_array(self.x0, "x0", DmpError, shape=(d,))
        g = float_array(self.g, "g", DmpError, shape=(d,))
        for name, array in (("weights", weights), ("x0", x0), ("g", g)):
            array.setflags(write=False)
            object.__setattr__(self, name, array)
        object.__setattr__(self, "tau_s", _finite_positive("tau_s", self.tau_s))

    @property
    def dimensions(self) -> int:
        """d, the number of coordinates."""
        return self.weights.shape[0]


def fit(times_s, trajectory, params: DmpParams = DmpParams()) -> DmpWeights:
    """Learn the forcing weights from one demonstration by ridge regression over all samples.

    Velocities and accelerations come from second-order finite differences (``np.gradient``, also
    at the edges) on the possibly non-uniform time grid. tau is the demonstration's duration, x0 its
    first and g its last sample. One batched solve of the regularised normal equations covers all
    coordinates.

    Parameters
    ----------
    times_s : array_like, shape (m,)
        Strictly increasing sample times, s (m >= 3).
    trajectory : array_like, shape (m, d)
        Positions at those times.
    params : DmpParams

    Returns
    -------
    DmpWeights

    Raises
    ------
    DmpError
        Too few samples, time not increasing, non-finite values or mismatched shapes.
    """
    if not isinstance(params, DmpParams):
        raise DmpError(f"params must be a DmpParams, got {type(params).__name__}")
    times = float_array(times_s, "times_s", DmpError, ndim=1)
    positions = float_array(trajectory, "trajectory", DmpError, ndim=2)
    if positions.shape[0] != times.shape[0]:
        raise DmpError(f"trajectory has {positions.shape[0]} samples but times_s has {times.shape[0]}")
    if times.shape[0] < 3:
        raise DmpError("a demonstration needs at least 3 samples")
    if positions.shape[1] < 1:
        raise DmpError("trajectory needs at least one coordinate")
    if np.any(np.diff(times) <= 0.0):
        raise DmpError("time must increase")

    t = times - times[0]
    tau = float(t[-1])
    stiffness, damping = params.stiffness, params.effective_damping
    x0, g = positions[0], positions[-1]
    xdot = np.gradient(positions, t, axis=0, edge_order=2)
    xddot = np.gradient(xdot, t, axis=0, edge_order=2)
    s = phase(t, tau, params.alpha_s)
    # v = tau xdot, tau dv/dt = tau^2 xddot
    target = (tau * tau * xddot + damping * tau * xdot) / stiffness - (g - positions) + np.outer(s, g - x0)

    centres, widths = basis(params)
    features = _features(s, centres, widths)  # (m, n)
    gram = features.T @ features + params.regularisation * np.eye(params.n_basis)
    weights = np.linalg.solve(gram, features.T @ target).T  # (d, n)
    if not np.all(np.isfinite(weights)):
        raise DmpError("the fit produced non-finite weights (demonstration too badly conditioned)")
    return DmpWeights(weights=weights, x0=x0, g=g, tau_s=tau, params=params)
