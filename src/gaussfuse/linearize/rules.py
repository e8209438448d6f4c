r"""Sigma-point rules: unit points and weights for a standard normal belief.

A rule is a set of unit points :math:`\xi_i` with weights :math:`w^m_i, w^c_i`;
for a belief :math:`N(m, P)` with :math:`P = L L^\top` the points are
:math:`\mathcal X_i = m + L \xi_i` (see :mod:`gaussfuse.linearize.sigma_points`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.polynomial.hermite_e import hermegauss

from .._validation import integer

__all__ = ["SigmaRule", "unscented", "cubature", "gauss_hermite", "MAX_GAUSS_HERMITE_ORDER", "MAX_SIGMA_POINTS"]


class SigmaRule(NamedTuple):
    """Unit sigma points and their weights.

    Attributes
    ----------
    points : ndarray of shape (k, n)
        Unit points :math:`\\xi_i`, for a standard normal belief.
    wm : ndarray of shape (k,)
        Weights of the mean.
    wc : ndarray of shape (k,)
        Weights of the covariances.
    """

    points: np.ndarray
    wm: np.ndarray
    wc: np.ndarray


def unscented(n: int, alpha: float = 1.0, beta: float = 0.0, kappa: float | None = None) -> SigmaRule:
    r"""The scaled unscented rule: 2n + 1 points.

    Parameters
    ----------
    n : int
        Dimension.
    alpha, beta : float
        Spread and prior-knowledge parameters; ``alpha=1, beta=0`` is the
        original unscented transform.
    kappa : float, optional
        Secondary scaling; defaults to ``3 - n``.

    Notes
    -----
    With :math:`\lambda = \alpha^2 (n + \kappa) - n`, the points are
    :math:`0` and :math:`\pm\sqrt{n + \lambda}\, e_i`, with weights
    :math:`w^m_0 = \lambda / (n + \lambda)`,
    :math:`w^c_0 = w^m_0 + 1 - \alpha^2 + \beta` and
    :math:`w_i = 1 / (2 (n + \lambda))` otherwise.
    """
    kappa = 3.0 - n if kappa is None else float(kappa)
    lam = float(alpha) * float(alpha) * (n + kappa) - n  # (float ** raises OverflowError; * gives inf)
    if not np.isfinite(lam):
        raise ValueError(f"`alpha` = {alpha} is too large: the unscented rule's spread alpha**2 * (n + kappa) "
                         f"overflows float64 (kappa = {kappa}, n = {n}).")
    if not n + lam > 0:
        raise ValueError(
            f"the unscented rule needs alpha**2 * (n + kappa) > 0; got alpha={alpha}, kappa={kappa}, n={n}."
        )
    scale = np.sqrt(n + lam)
    points = np.vstack([np.zeros(n), scale * np.eye(n), -scale * np.eye(n)])
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1.0 - float(alpha) * float(alpha) + beta
    return SigmaRule(points, wm, wc)


def cubature(n: int) -> SigmaRule:
    r"""The spherical–radial cubature rule: the 2n points :math:`\pm\sqrt n\, e_i`, equal weights."""
    points = np.sqrt(n) * np.vstack([np.eye(n), -np.eye(n)])
    w = np.full(2 * n, 0.5 / n)
    return SigmaRule(points, w, w)


MAX_GAUSS_HERMITE_ORDER = 200
"""The largest `order` of the 1-D Gauss–Hermite rule: NumPy's rule is tested to degree
100 and its weights overflow to NaN past 371."""
MAX_SIGMA_POINTS = 10**6
"""The most points a Gauss–Hermite rule may have (order**n): each is a call of f or h
at every step."""


def gauss_hermite(n: int, order: int = 3) -> SigmaRule:
    """The tensor-product Gauss–Hermite rule: order**n points.

    The 1-D rule is the probabilists' Hermite rule
    (:func:`numpy.polynomial.hermite_e.hermegauss`), exact for polynomials
    of degree up to 2·order − 1 under a standard normal; its weights are
    normalised to sum to 1.

    Raises
    ------
    ValueError
        When `order` is not an integer of at least 2, exceeds
        ``MAX_GAUSS_HERMITE_ORDER`` (200), or gives more than
        ``MAX_SIGMA_POINTS`` (10**6) points in n dimensions; the message
        says how many points that would be.
    """
    order = integer("order", order)
    if order < 2:
        raise ValueError(
            f"`order` must be at least 2: a rule of {order} point(s) per dimension sits at the mean only, so its "
            f"regression has no slope and the filter would ignore every measurement; got {order}."
        )
    if order > MAX_GAUSS_HERMITE_ORDER:
        raise ValueError(
            f"`order` must be at most {MAX_GAUSS_HERMITE_ORDER} (the 1-D Gauss–Hermite rule is not "
            f"accurate beyond); got {order}."
        )
    points = int(order) ** int(n)
    if points > MAX_SIGMA_POINTS:
        shown = f"{points:,}" if points < 10**15 else f"{float(points):.3g}"
        raise ValueError(
            f"`order` = {order} in n = {n} dimensions would give order**n = {shown} sigma points, more "
            f"than the limit of {MAX_SIGMA_POINTS:,}; use a smaller `order`, or the unscented or cubature "
            f"rule (2n + 1 or 2n points)."
        )
    x, w = hermegauss(order)
    w = w / w.sum()
    grids = np.meshgrid(*([x] * n), indexing="ij")
    points = np.stack([g.reshape(-1) for g in grids], axis=-1)
    weights = np.prod(np.stack(np.meshgrid(*([w] * n), indexing="ij")).reshape(n, -1), axis=0)
    return SigmaRule(points, weights, weights)
