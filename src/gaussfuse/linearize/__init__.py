"""Linearisation strategies: how a model becomes affine around a belief.

A strategy has two methods, each returning an affine Gaussian approximation
for step k (the transition into the k-th state, and the k-th measurement):

* ``transition(k, mean, cov) -> (A, b, Q)``: ``x_k ≈ A x_{k-1} + b + w``, ``w ~ N(0, Q)``;
* ``measurement(k, mean, cov) -> (H, d, R)``: ``z_k ≈ H x_k + d + v``, ``v ~ N(0, R)``;

where ``Q`` and ``R`` include any linearisation error. The one affine Kalman
step (:mod:`gaussfuse.kalman`) does the rest.

======================  =====================================================
strategy                affine map
======================  =====================================================
:class:`Exact`          a LinearModel: ``A = F_k``, ``b = B_k u_k``, ``H = H_k``
:class:`Taylor`         first-order Taylor expansion at the mean (EKF, IEKF)
:class:`SigmaPoints`    statistical linear regression (UKF, CKF, GHKF, IPLF)
:class:`Nominal`        any of these, frozen at a given trajectory (iterated smoothers)
======================  =====================================================
"""

from __future__ import annotations

import numpy as np

from .sigma_points import RULES, SigmaPoints, SigmaRule, cubature, gauss_hermite, slr, unscented
from .taylor import Taylor, jacobian

__all__ = [
    "Exact", "Taylor", "SigmaPoints", "Nominal", "SigmaRule", "RULES",
    "unscented", "cubature", "gauss_hermite", "slr", "jacobian",
]


class Exact:
    """The exact affine form of a LinearModel with controls `us` (T, p)."""

    def __init__(self, model, us: np.ndarray | None = None) -> None:
        self.model, self.us = model, us

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        F, _, Q, _, B = self.model.at(k)
        return F, None if B is None else B @ self.us[k], Q

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        _, H, _, R, _ = self.model.at(k)
        return H, None, R


class Nominal:
    """A strategy frozen at a nominal trajectory, ignoring the belief it is given.

    Parameters
    ----------
    strategy : Taylor or SigmaPoints
        How to linearise.
    means : ndarray of shape (T + 1, n)
        Nominal means at times 0..T, where time 0 is the prior's (one step
        before the first measurement).
    covs : ndarray of shape (T + 1, n, n)
        Nominal covariances (used by sigma-point strategies).

    Notes
    -----
    Step k's transition is linearised at the nominal state at time k (the
    state it starts from) and its measurement at time k + 1.
    """

    def __init__(self, strategy, means: np.ndarray, covs: np.ndarray) -> None:
        self.strategy, self.means, self.covs = strategy, means, covs

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        return self.strategy.transition(k, self.means[k], self.covs[k])

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        return self.strategy.measurement(k, self.means[k + 1], self.covs[k + 1])
