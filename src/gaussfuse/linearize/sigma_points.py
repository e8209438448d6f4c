r"""Sigma-point rules and statistical linear regression (SLR).

A sigma-point rule is a set of unit points :math:`\xi_i` with weights
:math:`w^m_i, w^c_i`; for a belief :math:`N(m, P)` with :math:`P = L L^\top`
the points are :math:`\mathcal X_i = m + L \xi_i`.

Statistical linear regression fits the affine map that best explains
:math:`y = g(x)` under the belief. With :math:`\delta\mathcal Y_i = g(\mathcal X_i) - \bar y`,

.. math::

    \bar y &= \textstyle\sum_i w^m_i\, g(\mathcal X_i), \qquad
    S = \textstyle\sum_i w^c_i\, \delta\mathcal Y_i \delta\mathcal Y_i^\top, \qquad
    C = \textstyle\sum_i w^c_i\, (\mathcal X_i - m)\, \delta\mathcal Y_i^\top, \\
    A &= C^\top P^{-1}, \qquad b = \bar y - A m, \qquad \Omega = S - A P A^\top,

so that :math:`g(x) \approx A x + b + e`, :math:`e \sim N(0, \Omega)`. Fed to
the affine Kalman step this gives exactly the sigma-point filter's formulas:
the predicted mean is :math:`\bar y`, the innovation covariance
:math:`S + R`, the gain :math:`C (S + R)^{-1}`, and the smoother gain
:math:`C_f (P^-)^{-1}`.

These are computed in the points' own coordinates. Since
:math:`\mathcal X_i - m = L \xi_i`,

.. math::

    \Xi = \textstyle\sum_i w^c_i\, \xi_i\, \delta\mathcal Y_i^\top, \qquad
    C = L\, \Xi, \qquad
    A = \Xi^\top L^{-1}, \qquad
    A P A^\top = \Xi^\top \Xi, \qquad
    \Omega = S - \Xi^\top \Xi,

so :math:`A` is one triangular solve with the Cholesky factor that drew the
points, and neither :math:`P^{-1}` nor :math:`A P A^\top` is formed. For a
singular :math:`P` the factor is its semi-definite Cholesky factor
(:func:`gaussfuse.kalman.semidefinite_cholesky`: a component that is, to round-off, an affine
function of the earlier ones gets a zero column). With :math:`r` the nonzero
columns, the points move in the range of :math:`P` only, :math:`\Xi` keeps
the rows :math:`r`, and :math:`A_{:, r} = \Xi_r^\top (L_{rr})^{-1}`, zero
elsewhere: still :math:`A L = \Xi^\top`, so the regression is exact on the
support of the belief, where the points are.

This matters when :math:`P` is nearly singular, say a component whose
variance is round-off (:math:`10^{-32}`) next to one of order 1: its points
sit within a unit in the last place of the mean, so :math:`\mathcal X_i - m`
is quantised to 0 or one ulp, and :math:`C^\top P^{-1}` divided that
quantisation by :math:`10^{-32}`, putting :math:`10^{15}` into :math:`A`
and leaving :math:`\Omega` to cancel two huge terms. In the unit points the
regression stays of the size of :math:`g`'s slope.

The mean :math:`\bar y` is computed centred on the first point,
:math:`\mathcal Y_0 + \sum_i w^m_i (\mathcal Y_i - \mathcal Y_0)` (and the
circular mean of an angle likewise, on :math:`\mathcal Y_i - \mathcal Y_0`),
so that an output that is the same at every point (a state component known
exactly) has exactly that mean and exactly zero spread, although the
weights' sum carries round-off: such a component keeps a variance of exactly
0, not one of :math:`10^{-32}`.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np
from numpy.polynomial.hermite_e import hermegauss

from ..kalman import semidefinite_cholesky, symmetrize, wrap_angle

__all__ = ["SigmaPoints", "SigmaRule", "unscented", "cubature", "gauss_hermite", "slr", "RULES"]


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
    lam = alpha**2 * (n + kappa) - n
    if not n + lam > 0:
        raise ValueError(
            f"the unscented rule needs alpha**2 * (n + kappa) > 0; got alpha={alpha}, kappa={kappa}, n={n}."
        )
    scale = np.sqrt(n + lam)
    points = np.vstack([np.zeros(n), scale * np.eye(n), -scale * np.eye(n)])
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wm[0] = lam / (n + lam)
    wc = wm.copy()
    wc[0] += 1.0 - alpha**2 + beta
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
        When `order` is not a positive integer, exceeds
        ``MAX_GAUSS_HERMITE_ORDER`` (200), or gives more than
        ``MAX_SIGMA_POINTS`` (10**6) points in n dimensions; the message
        says how many points that would be.
    """
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"`order` must be a positive integer; got {order!r}.")
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


RULES: dict[str, Callable[..., SigmaRule]] = {
    "unscented": unscented,
    "cubature": cubature,
    "gauss_hermite": gauss_hermite,
}


def _root(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A lower-triangular square root ``L Lᵀ = cov`` and the mask of its nonzero columns.

    Cholesky when `cov` is positive definite; otherwise the semi-definite
    Cholesky factorisation of :func:`gaussfuse.kalman.semidefinite_cholesky`.
    """
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        L = semidefinite_cholesky(cov)
        return L, np.diag(L) > 0.0
    return L, np.ones(cov.shape[0], dtype=bool)


def sqrt_cov(cov: np.ndarray) -> np.ndarray:
    """A lower-triangular square root L with L Lᵀ = cov (see :func:`gaussfuse.kalman.semidefinite_cholesky`)."""
    return _root(cov)[0]


def weighted_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``Σ_i w_i values_i`` along axis 0, centred on the first row.

    Computed as ``values_0 + Σ_i w_i (values_i - values_0)``: the plain sum
    when the weights sum to 1, but exact for a component that is the same
    at every point. The weights' sum carries round-off, and a constant
    output must keep a mean equal to it and a spread of exactly 0, so that a
    state component known exactly stays known exactly.
    """
    return values[0] + weights @ (values - values[0])


def circular_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean of angles along axis 0: ``atan2(Σ w sin, Σ w cos)``."""
    return np.arctan2(weights @ np.sin(values), weights @ np.cos(values))


def slr(
    g: Callable[[np.ndarray], np.ndarray],
    rule: SigmaRule,
    mean: np.ndarray,
    cov: np.ndarray,
    angles: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Statistical linear regression of `g` under ``N(mean, cov)`` (see the module notes).

    Parameters
    ----------
    g : callable
        Maps a stack of states (k, n) to outputs (k, d).
    rule : SigmaRule
        Unit points and weights for dimension n.
    mean : ndarray of shape (n,)
    cov : ndarray of shape (n, n)
    angles : ndarray of bool, shape (d,), optional
        Output components that are angles: their mean is circular and their
        residuals wrapped to [-π, π).

    Returns
    -------
    A : ndarray of shape (d, n)
    b : ndarray of shape (d,)
    Omega : ndarray of shape (d, d)

    Notes
    -----
    See the module notes for the formulas and why they are computed in the
    points' own coordinates (:math:`\Xi`, never :math:`P^{-1}` or
    :math:`\mathcal X_i - m`).

    Examples
    --------
    Julier and Uhlmann's polar-to-Cartesian example: with r ~ N(1, 0.02²) and
    θ ~ N(90°, (15°)²), linearising y = r sin θ at the mean gives E[y] = 1,
    while the unscented transform gives the true 0.966:

    >>> import numpy as np
    >>> mean, cov = np.array([1.0, np.pi / 2]), np.diag([0.02**2, np.deg2rad(15.0) ** 2])
    >>> A, b, _ = slr(lambda X: X[:, :1] * np.sin(X[:, 1:]), unscented(2), mean, cov)
    >>> print(np.round(A @ mean + b, 5))
    [0.96631]
    """
    L, keep = _root(cov)
    X = mean + rule.points @ L.T
    Y = g(X)
    y_mean = weighted_mean(Y, rule.wm)
    dY = Y - y_mean
    if angles is not None and angles.any():
        ref = Y[0, angles]  # centred, as weighted_mean: a constant angle is its own mean, exactly
        y_mean[angles] = ref + circular_mean(Y[:, angles] - ref, rule.wm)
        dY[:, angles] = wrap_angle(Y[:, angles] - y_mean[angles])
    S = (dY * rule.wc[:, None]).T @ dY
    Xi = (rule.points[:, keep] * rule.wc[:, None]).T @ dY  # C = L Ξ, over the nonzero columns
    A = np.zeros((dY.shape[1], mean.shape[0]))
    A[:, keep] = np.linalg.solve(L[np.ix_(keep, keep)].T, Xi).T  # Aᵀ = L⁻ᵀ Ξ: back substitution
    return A, y_mean - A @ mean, symmetrize(S - Xi.T @ Xi)


class SigmaPoints:
    """Statistical linear regression of a NonlinearModel through a sigma-point rule.

    Parameters
    ----------
    model : NonlinearModel
    rule : SigmaRule
        Unit points for the model's state dimension.
    us : ndarray of shape (T, p), optional
        Controls, passed to f as ``f(x, u_k)``.

    Notes
    -----
    f and h are evaluated once per step on the whole stack of points when
    the model is vectorized, otherwise once per point.
    """

    def __init__(self, model, rule: SigmaRule, us: np.ndarray | None = None) -> None:
        self.model, self.rule, self.us = model, rule, us

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        """``(A, b, Q + Ω)`` from the regression of f under ``N(mean, cov)``."""
        m = self.model
        u = None if self.us is None else self.us[k]
        A, b, omega = slr(lambda X: m.transition(X, u), self.rule, mean, cov, m.state_angles)
        return A, b, m.noise(k)[0] + omega

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        """``(H, d, R + Ω)`` from the regression of h under ``N(mean, cov)``."""
        m = self.model
        H, d, omega = slr(m.measurement, self.rule, mean, cov, m.measurement_angles)
        return H, d, m.noise(k)[1] + omega
