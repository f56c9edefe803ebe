"""PI² learning of the step-length compensation parameters (paper section III).

The learned parameters are ``theta = [alpha, Xhat_CoM]`` of the compensation
``g = g_init + alpha * (Xhat_CoM - X_CoM / X_SP)`` (see :mod:`controller.compensation`). They are
held constant over a roll-out of ``N`` steps (gait cycles); ``K`` roll-outs with
``theta + eps_k``, ``eps_k ~ N(0, diag(sigma^2))``, make one update.

Costs (paper equations (10), (11)):

- immediate cost of step ``i``: ``r_i``, the mean stick force over the step;
- roll-out cost ``R = lambda1 * (N - m) / N + lambda2 * sum_i r_i`` where the HHEA fell after ``m``
  of ``N`` steps (``m = N`` without a fall). The fall term is the terminal cost ``phi_k``.

PI² (Theodorou, Buchli, Schaal 2010, as the reference code implements it):

1. cost-to-go ``S(i, k) = phi_k + sum_{j >= i} q_{j,k}`` with ``q = lambda2 * r`` (steps not
   completed cost 0: the fall is paid through ``phi_k``);
2. ``P(i, k) = exp(-h (S(i,k) - min_l S(i,l)) / (max_l S(i,l) - min_l S(i,l)))`` normalised over
   ``k`` (uniform when ``max == min``);
3. ``dtheta_i = sum_k P(i, k) eps_k``;
4. ``dtheta = sum_i (N - i) dtheta_i / sum_i (N - i)``; ``theta <- theta + dtheta``.

PI^BB (Stulp and Sigaud, dmpbbo ``costs_to_weights``) is available as an option: one total cost
per roll-out, ``theta_new = sum_k P_k theta_k``.

The numerical core is pure: no I/O, no clock, no global random state (a ``numpy.random.Generator``
is injected), inputs are never mutated. :mod:`controller.pi2.rules` holds the costs, the update
rules and the settings, :mod:`controller.pi2.learner` the online learner,
:mod:`controller.pi2.state` its state for a patient's learned file.
"""

from controller.pi2.learner import Pi2Learner, Rejection, UpdateRecord
from controller.pi2.rules import LearnerError, Pi2Params, cost_to_go, costs_to_weights, pi2_update, pibb_update, rollout_cost
from controller.pi2.state import learner_state, learner_from_state

__all__ = [
    "LearnerError",
    "Pi2Learner",
    "Pi2Params",
    "Rejection",
    "UpdateRecord",
    "cost_to_go",
    "costs_to_weights",
    "learner_state",
    "pi2_update",
    "pibb_update",
    "learner_from_state",
    "rollout_cost",
]
