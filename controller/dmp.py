"""The runtime integrator of the swing's Dynamic Movement Primitive (Pastor et al., ICRA 2009).

``Dmp`` rolls out a fitted primitive tick by tick; the model (its equations, ``DmpParams``, the
basis, the forcing term) and the fit that gives ``DmpWeights`` are in :mod:`controller.dmp_model`.

Online goal changes. ``Dmp.set_goal`` does not jump ``g``: the goal seen by the equations follows the
requested one through a first-order filter ``tau dg/dt = alpha_g (g_request - g)`` (as in Ijspeert
et al. 2013, with ``alpha_g = sqrt(K) = D / 2`` by default), so a goal change mid-swing bends the
trajectory without an acceleration jump. ``reset`` sets both to the new goal (no filtering). The
price is latency: on the 0.15 m, 1.2 s swing, a +-0.05 m change at mid-swing leaves x about 3.6 mm
short of the new goal at t = tau and within 0.25 mm at t = 1.5 tau.

Integration. ``Dmp.step`` advances exactly ``dt_s`` with classical RK4 substeps over (x, v, s, g).
Because s and the filtered g obey their own linear ODEs, their RK4 stage values are fixed multiples
of their values at the start of the tick, and (x, v) is a linear time-invariant system driven by
``u = K (g - (g - x0) s + f(s))``. RK4 on such a system is an affine map of the state and the stage
inputs; ``_tick_map`` builds its matrices once per (dt_s, substeps, tau_s) and a tick is then one
vectorised evaluation of f at all 4 * substeps stage phases and a few small matrix products. The
result is the RK4 result (the tests check it against a plain substep-by-substep RK4 to 1e-12), about
2x faster than an RK4 loop over Python floats and far faster than RK4 on 2-element numpy arrays.

Pure numerical core: no I/O, no clock, no global state; inputs are never modified.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.arrays import float_array
from controller.dmp_model import (
    DmpError,
    DmpParams,
    DmpWeights,
    _features,
    _finite_positive,
    basis,
)

# Phases at or below exp(-alpha_s) mean t >= tau; the margin absorbs RK4 and time-sum rounding.
_DONE_TOLERANCE_S = 1e-9
# Classical RK4 is stable on a real eigenvalue lambda for |lambda h| < 2.78; keep a margin.
_RK4_MAX_RATE_STEP = 2.5


def _rk4_stage_multipliers(rate_step: float) -> tuple[np.ndarray, float]:
    """RK4 on ``dy/dt = -rate y`` over one substep h, with ``rate_step = rate * h``.

    Returns the four stage values and the end value as multiples of the start value y:
    ``(array([1, m2, m3, m4]), r)``.
    """
    a = -rate_step
    m2 = 1.0 + 0.5 * a
    m3 = 1.0 + 0.5 * a * m2
    m4 = 1.0 + a * m3
    r = 1.0 + a / 6.0 * (1.0 + 2.0 * m2 + 2.0 * m3 + m4)
    return np.array([1.0, m2, m3, m4]), r


@dataclass(frozen=True, eq=False)
class _TickMap:
    """One tick of RK4 substeps as an affine map (see ``_tick_map``)."""

    key: tuple[float, int, float]  # (dt_s, substeps, tau_s)
    state_matrix: np.ndarray  # (2, 2) M: [x; v] <- M [x; v] + ...
    anchor_matrix: np.ndarray  # (2, 3) C0 and
    anchor_phase_matrix: np.ndarray  # (2, 3) C1: (C0 + s C1) is the response to [g_request; g - g_request; x0]
    input_matrix: np.ndarray  # (2, 4 N) G: the response to u at the 4 N RK4 stages
    phase_stages: np.ndarray  # (4 N,) stage phases / phase at tick start
    phase_factor: float  # phase at tick end / at tick start
    goal_factor: float  # (g - g_request) at tick end / at tick start


def _tick_map(params: DmpParams, tau_s: float, dt_s: float, substeps: int) -> _TickMap:
    """Matrices that make one tick of ``substeps`` classical RK4 substeps a few matrix products.

    Per coordinate, y = [x, v] obeys dy/dt = A y + b u(t) with A = [[0, 1], [-K, -D]] / tau,
    b = [0, 1] / tau and u = K (g - (g - x0) s + f(s)). One RK4 substep h with stage inputs
    u1..u4 gives y+ = P y + Q [u1, u2, u3, u4] where, with B = h A,
    P = I + B + B^2/2 + B^3/6 + B^4/24 and
    Q = h/6 [(I + B + B^2/2 + B^3/4) b, (2I + B + B^2/2) b, (2I + B) b, b].
    N substeps chain to y_N = M y_0 + G u_all with M = P^N and G = [P^(N-1) Q, ..., P Q, Q].

    The stage phases are s * q_s and the stage goals g_r + e * q_g (RK4 on the phase and on the
    goal filter, e = g - g_r), so the goal and start part of u_all is
    K [(1 - s q_s), q_g (1 - s q_s), s q_s] [g_r; e; x0], and G times it is (C0 + s C1) [g_r; e; x0].
    """
    h = dt_s / substeps
    stiffness, damping = params.stiffness, params.effective_damping
    a = np.array([[0.0, 1.0], [-stiffness, -damping]]) / tau_s
    b = np.array([0.0, 1.0 / tau_s])
    big = h * a
    eye = np.eye(2)
    big2 = big @ big
    big3 = big2 @ big
    p = eye + big + big2 / 2.0 + big3 / 6.0 + big3 @ big / 24.0
    q = (h / 6.0) * np.column_stack([
        (eye + big + big2 / 2.0 + big3 / 4.0) @ b,
        (2.0 * eye + big + big2 / 2.0) @ b,
        (2.0 * eye + big) @ b,
        b,
    ])
    blocks = []
    power = eye
    for _ in range(substeps):  # built back to front: Q, P Q, P^2 Q, ...
        blocks.append(power @ q)
        power = p @ power
    input_matrix = np.hstack(blocks[::-1])

    def stages(rate: float) -> tuple[np.ndarray, float]:
        multipliers, r = _rk4_stage_multipliers(rate * h / tau_s)
        return (r ** np.arange(substeps)[:, None] * multipliers).ravel(), r**substeps

    phase_stages, phase_factor = stages(params.alpha_s)
    goal_stages, goal_factor = stages(params.effective_goal_alpha)
    g_qs = input_matrix @ phase_stages
    return _TickMap(
        key=(dt_s, substeps, tau_s),
        state_matrix=power,
        anchor_matrix=stiffness * np.column_stack([input_matrix.sum(axis=1), input_matrix @ goal_stages, np.zeros(2)]),
        anchor_phase_matrix=stiffness * np.column_stack([-g_qs, -(input_matrix @ (goal_stages * phase_stages)), g_qs]),
        input_matrix=input_matrix,
        phase_stages=phase_stages,
        phase_factor=phase_factor,
        goal_factor=goal_factor,
    )


class Dmp:
    """State of one DMP roll-out: position x, scaled velocity v = tau dx/dt, phase s, goal, x0, tau.

    Parameters
    ----------
    weights : DmpWeights
        The fitted primitive. The DMP starts reset to the demonstration's x0, goal and tau.

    Notes
    -----
    ``step`` is the per-tick call of the 20 ms loop. The tick matrices are cached for the last
    (dt_s, substeps) and rebuilt by ``reset`` when tau changes, so ticks build no matrices.
    """

    def __init__(self, weights: DmpWeights) -> None:
        if not isinstance(weights, DmpWeights):
            raise DmpError(f"weights must be a DmpWeights, got {type(weights).__name__}")
        self._weights = weights
        self._centres, self._widths = basis(weights.params)
        self._scaled_weights_t = weights.params.stiffness * weights.weights.T  # (n, d): K w^T
        self._d = weights.dimensions
        self._map: _TickMap | None = None
        # Rows: requested goal g_r, goal offset e = g - g_r (g: the filtered goal), start x0.
        self._anchors = np.zeros((3, self._d))
        self.reset()

    # --- state ---------------------------------------------------------------------------------

    @property
    def weights(self) -> DmpWeights:
        """The fitted primitive."""
        return self._weights

    @property
    def x(self) -> np.ndarray:
        """Position, shape (d,) (a copy)."""
        return self._y[0].copy()

    @property
    def v(self) -> np.ndarray:
        """Scaled velocity v = tau dx/dt, shape (d,) (a copy)."""
        return self._y[1].copy()

    @property
    def velocity(self) -> np.ndarray:
        """dx/dt in units per second, shape (d,)."""
        return self._y[1] / self._tau_s

    @property
    def s(self) -> float:
        """Phase, 1 at reset, decaying towards 0."""
        return self._s

    @property
    def goal(self) -> np.ndarray:
        """The requested goal, shape (d,) (a copy)."""
        return self._anchors[0].copy()

    @property
    def filtered_goal(self) -> np.ndarray:
        """The goal g currently in the equations (follows ``goal`` smoothly), shape (d,)."""
        return self._anchors[0] + self._anchors[1]

    @property
    def x0(self) -> np.ndarray:
        """Start position of the current movement, shape (d,) (a copy)."""
        return self._anchors[2].copy()

    @property
    def tau_s(self) -> float:
        """Duration of the current movement, s."""
        return self._tau_s

    @property
    def elapsed_s(self) -> float:
        """Time integrated since the last reset, s."""
        return self._elapsed_s

    @property
    def done(self) -> bool:
        """True once t >= tau, i.e. the phase has decayed to exp(-alpha_s) (0.01 by default)."""
        return self._elapsed_s >= self._tau_s - _DONE_TOLERANCE_S

    # --- commands ------------------------------------------------------------------------------

    def reset(self, x0=None, goal=None, tau_s: float | None = None) -> None:
        """Start a new movement at rest: x = x0, v = 0, s = 1, goal set at once (not filtered).

        Parameters
        ----------
        x0, goal : array_like, shape (d,), optional
            Start and goal; default the demonstration's.
        tau_s : float, optional
            Duration of the movement, s (> 0); default the demonstration's.
        """
        w = self._weights
        x0 = float_array(w.x0 if x0 is None else x0, "x0", DmpError, shape=(self._d,))
        goal = float_array(w.g if goal is None else goal, "goal", DmpError, shape=(self._d,))
        tau = w.tau_s if tau_s is None else _finite_positive("tau_s", tau_s)
        self._anchors[0] = goal
        self._anchors[1] = 0.0
        self._anchors[2] = x0
        self._tau_s = tau
        self._y = np.zeros((2, self._d))
        self._y[0] = x0
        self._s = 1.0
        self._elapsed_s = 0.0
        if self._map is not None and self._map.key[2] != tau:
            dt_s, substeps, _ = self._map.key
            self._map = _tick_map(w.params, tau, dt_s, substeps)

    def set_goal(self, goal) -> None:
        """Request a new goal, shape (d,); it enters the equations from the next step, smoothly.

        The goal g in the equations keeps its value and from then on relaxes towards the request
        (``tau dg/dt = alpha_g (goal - g)``).
        """
        goal = float_array(goal, "goal", DmpError, shape=(self._d,))
        filtered = self._anchors[0] + self._anchors[1]
        self._anchors[0] = goal
        self._anchors[1] = filtered - goal

    def step(self, dt_s: float, substeps: int = 10) -> np.ndarray:
        """Advance exactly ``dt_s`` with ``substeps`` classical RK4 substeps; return x, shape (d,).

        Raises
        ------
        DmpError
            dt_s not finite and positive, substeps not a positive integer, or a substep so long
            that RK4 would be unstable.
        """
        tick = self._map
        if tick is None or tick.key[0] != dt_s or tick.key[1] != substeps:
            tick = self._prepare(dt_s, substeps)
        s = self._s
        features = _features(s * tick.phase_stages, self._centres, self._widths)  # (4N, n)
        self._y = (tick.state_matrix @ self._y
                   + (tick.anchor_matrix + s * tick.anchor_phase_matrix) @ self._anchors
                   + (tick.input_matrix @ features) @ self._scaled_weights_t)
        self._s = s * tick.phase_factor
        self._anchors[1] *= tick.goal_factor
        self._elapsed_s += dt_s
        return self._y[0].copy()

    def rollout(self, dt_s: float, duration_s: float, substeps: int = 10) -> tuple[np.ndarray, np.ndarray]:
        """Step from the current state for the fewest whole ticks that cover ``duration_s``.

        Advances this DMP (its state afterwards is the end of the roll-out).

        Returns
        -------
        times_s : ndarray, shape (k + 1,)
            ``elapsed_s`` at each sample, starting with the current state.
        positions : ndarray, shape (k + 1, d)
        """
        duration_s = _finite_positive("duration_s", duration_s)
        dt_s = _finite_positive("dt_s", dt_s)
        ticks = max(1, math.ceil(duration_s / dt_s - 1e-9))
        times = self._elapsed_s + dt_s * np.arange(ticks + 1)
        positions = np.empty((ticks + 1, self._d))
        positions[0] = self._y[0]
        for k in range(1, ticks + 1):
            positions[k] = self.step(dt_s, substeps)
        return times, positions

    def _prepare(self, dt_s: float, substeps: int) -> _TickMap:
        dt_s = _finite_positive("dt_s", dt_s)
        if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise DmpError(f"substeps must be a positive integer, got {substeps!r}")
        params = self._weights.params
        stiffness, damping = params.stiffness, params.effective_damping
        # Largest |eigenvalue| of the (x, v), phase and goal-filter dynamics, per unit of t / tau.
        disc = damping * damping / 4.0 - stiffness
        spring_rate = damping / 2.0 + math.sqrt(disc) if disc > 0.0 else math.sqrt(stiffness)
        rate = max(spring_rate, params.alpha_s, params.effective_goal_alpha)
        h = dt_s / substeps
        if rate * h / self._tau_s > _RK4_MAX_RATE_STEP:
            raise DmpError(f"substep {h:.4g} s too long for a stable RK4 at tau {self._tau_s:.4g} s: use more substeps")
        self._map = _tick_map(params, self._tau_s, dt_s, int(substeps))
        return self._map


def reference_rollout(weights: DmpWeights, x0, goal, tau_s, dt_s, substeps, ticks, goal_change=None):
    """Plain RK4, substep by substep, over (x, v, s, g): the oracle ``Dmp.step`` is tested against,
    and the baseline of ``aider-exo bench algorithms``. Returns positions (ticks + 1, d).

    goal_change: (tick, new_goal) requested before that tick, filtered like ``Dmp.set_goal``.
    """
    p = weights.params
    k, d_, a_s, a_g = p.stiffness, p.effective_damping, p.alpha_s, p.effective_goal_alpha
    centres, widths = basis(p)
    request = np.array(goal, dtype=float)

    def f(s):
        psi = np.exp(-widths * (s - centres) ** 2)
        return weights.weights @ psi * s / psi.sum()

    def deriv(state):
        x, v, s, g = state
        return np.array([
            v / tau_s,
            (k * (g - x) - d_ * v - k * (g - x0) * s[0] + k * f(s[0])) / tau_s,
            -a_s * s / tau_s,
            a_g * (request - g) / tau_s,
        ], dtype=object)

    dim = len(x0)
    state = np.array([np.array(x0, float), np.zeros(dim), np.ones(dim), np.array(goal, float)], dtype=object)
    h = dt_s / substeps
    out = [state[0].copy()]
    for tick in range(ticks):
        if goal_change is not None and tick == goal_change[0]:
            request = np.array(goal_change[1], dtype=float)
        for _ in range(substeps):
            k1 = deriv(state)
            k2 = deriv(state + h / 2 * k1)
            k3 = deriv(state + h / 2 * k2)
            k4 = deriv(state + h * k3)
            state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(state[0].copy())
    return np.array(out)
