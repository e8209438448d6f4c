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

from . import exact, rules, sigma_points, taylor
from .exact import *  # noqa: F403
from .rules import *  # noqa: F403
from .sigma_points import *  # noqa: F403
from .taylor import *  # noqa: F403

__all__ = [*exact.__all__, *taylor.__all__, *sigma_points.__all__, *rules.__all__]
