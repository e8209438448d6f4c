r"""Statistical linear regression (SLR) through sigma points.

A sigma-point rule (:mod:`gaussfuse.linearize.rules`) is a set of unit points :math:`\xi_i` with weights
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
points, and neither :math:`P^{-1}` nor :math:`A P A^\top` is formed.
:math:`\Omega` is computed as :math:`\sum_i w^c_i e_i e_i^\top` from the
residuals :math:`e_i = \delta\mathcal Y_i - \Xi^\top \xi_i` (the same in
exact arithmetic, as :math:`\sum_i w^c_i \xi_i \xi_i^\top = I`), those at
round-off set to 0, and not as the difference: for a huge prior and a
precise sensor the round-off of :math:`S - \Xi^\top \Xi` exceeded R (a
posterior variance of 3 for 1, and means hundreds of standard deviations
off). For a
singular :math:`P` the factor is its semi-definite Cholesky factor
(:func:`gaussfuse._linalg.semidefinite_cholesky`: a component that is, to round-off, an affine
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

from typing import Callable

import numpy as np

from .._linalg import (back_solve, back_substitute, circular_mean, sqrt_cov, symmetrize, unresolved, weighted_mean,
                       wrap_angle)
from .rules import SigmaRule, unscented

__all__ = ["SigmaPoints", "slr", "slr_sqrt"]


def slr(
    g: Callable[[np.ndarray], np.ndarray],
    rule: SigmaRule,
    mean: np.ndarray,
    cov: np.ndarray,
    angles: np.ndarray | None = None,
    name: str = "the covariance",
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
    name : str, default "the covariance"
        What `cov` is, for the error when it is not positive semi-definite.

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
    L, keep = sqrt_cov(cov, mean, name, rule.wc)
    y_mean, dY = _spread(g, rule, mean, L, angles)
    weighted = dY * rule.wc[:, None]
    points = rule.points if keep.all() else rule.points[:, keep]  # (over the nonzero columns only)
    Xi = points.T @ weighted                            # C = L Ξ
    A = np.zeros((dY.shape[1], mean.shape[0]))
    A[:, keep] = back_substitute(L[np.ix_(keep, keep)], Xi).T  # Aᵀ = L⁻ᵀ Ξ
    # Ω = Σ w_i e_i e_iᵀ from the residuals e_i = δY_i - Ξᵀ ξ_i, not as S - ΞᵀΞ: that difference of terms of the
    # prior's size left its round-off (more than R, for a huge prior and a precise sensor) in Ω
    E = _resolved(dY - points @ Xi, rule, mean, L, A, dY, y_mean)
    return A, y_mean - A @ mean, symmetrize((E * rule.wc[:, None]).T @ E)


def _resolved(E: np.ndarray, rule: SigmaRule, mean: np.ndarray, L: np.ndarray, A: np.ndarray, dY: np.ndarray,
              y_mean: np.ndarray) -> np.ndarray:
    r"""The residuals `E` (k, d) with those at the round-off of the points and outputs set to 0 (see :func:`slr_sqrt`).

    :math:`|e_{ij}| \le 4 k \epsilon\, (|A| (|m| + |L \xi_i|) + |\delta\mathcal Y_i| + |\bar y|
    + \sum_l |w^m_l| |\delta\mathcal Y_l|)_j`: not information about g's curvature, and for a linear g (all
    residuals at round-off) they would leave an Ω of round-off size, indefinite in the square-root form. The
    last term is the round-off of :math:`\bar y`, a sum of the outputs that may cancel (a prior spread of
    1e15 left the centre point a residual of 0.2 beside a sensor noise of 1, a third of the update lost).
    """
    size = (np.abs(mean) + np.abs(rule.points @ L.T)) @ np.abs(A).T + np.abs(dY) + np.abs(y_mean) \
        + np.abs(rule.wm) @ np.abs(dY)
    E[np.abs(E) <= 4 * len(rule.wc) * np.finfo(np.float64).eps * size] = 0.0
    return E


def _spread(g, rule: SigmaRule, mean: np.ndarray, L: np.ndarray, angles) -> tuple[np.ndarray, np.ndarray]:
    """``ȳ`` and the rows ``δY_i = g(m + L ξ_i) - ȳ`` (angles: circular mean, wrapped residuals)."""
    Y = g(mean + rule.points @ L.T)
    y_mean = weighted_mean(Y, rule.wm)
    dY = Y - y_mean
    if angles is not None and angles.any():
        ref = Y[0, angles]  # centred, as weighted_mean: a constant angle is its own mean, exactly
        y_mean[angles] = ref + circular_mean(Y[:, angles] - ref, rule.wm)
        dY[:, angles] = wrap_angle(Y[:, angles] - y_mean[angles])
    return y_mean, dY


def slr_sqrt(
    g: Callable[[np.ndarray], np.ndarray],
    rule: SigmaRule,
    mean: np.ndarray,
    factor: np.ndarray,
    angles: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    r""":func:`slr` on a Cholesky factor: the affine map, and the regression error as factor columns.

    Parameters
    ----------
    g, rule, mean, angles :
        As :func:`slr`.
    factor : ndarray of shape (n, n)
        Lower-triangular :math:`L`, :math:`P = L L^\top`; it draws the points.

    Returns
    -------
    A : ndarray of shape (d, n)
    b : ndarray of shape (d,)
    Omega_plus : ndarray of shape (d, k₊)
    Omega_minus : ndarray of shape (d, k₋), or None
        :math:`\Omega = \Omega_+ \Omega_+^\top - \Omega_- \Omega_-^\top`;
        None when no weight is negative.

    Notes
    -----
    The residual of point i about the regression line is, with
    :math:`A L = \Xi^\top`,

    .. math::

        e_i = \delta\mathcal Y_i - A (\mathcal X_i - m) = \delta\mathcal Y_i - \Xi^\top \xi_i,

    and since the unit points have :math:`\sum_i w^c_i \xi_i \xi_i^\top = I`,
    :math:`\sum_i w^c_i e_i e_i^\top = S - \Xi^\top \Xi = \Omega`. So
    :math:`\Omega`'s square root is the columns :math:`\sqrt{w^c_i}\, e_i`
    for the positive weights, less the outer products of
    :math:`\sqrt{-w^c_i}\, e_i` for the negative ones (the unscented
    rule's centre point when :math:`\lambda < 0`, as for its default
    :math:`\kappa = 3 - n` past three states). :math:`\Omega` is never formed
    as a difference of two large terms. Where :math:`L` is singular (a
    zero on its diagonal), :math:`A` is the minimum-norm solution of
    :math:`A L = \Xi^\top`, with each state component scaled to unit
    variance so that the cut-off does not depend on units.

    A residual within the round-off of the points and outputs,
    :math:`|e_{ij}| \le 4 k \epsilon\, (|A| (|m| + |L \xi_i|) + |\delta\mathcal Y_i| + |\bar y|
    + \sum_l |w^m_l| |\delta\mathcal Y_l|)_j` for k points, is set to 0: it is not information about g's curvature,
    and for a linear g (all residuals at round-off) it would otherwise leave
    an indefinite :math:`\Omega` of round-off size to downdate.
    """
    flat = unresolved(np.einsum("ij,ij->i", factor, factor).tolist(), mean)  # as sqrt_cov: known exactly
    if flat:
        factor = factor.copy()
        factor[flat] = 0.0
    y_mean, dY = _spread(g, rule, mean, factor, angles)
    wc, points = rule.wc, rule.points
    Xi = (points * wc[:, None]).T @ dY                 # C = L Ξ
    A = back_solve(factor, Xi).T                        # Aᵀ = L⁻ᵀ Ξ
    E = _resolved(dY - points @ Xi, rule, mean, factor, A, dY, y_mean)  # e_i = δY_i - Ξᵀ ξ_i, by rows
    plus, minus = wc > 0.0, wc < 0.0
    Omega_plus = (E[plus] * np.sqrt(wc[plus])[:, None]).T
    Omega_minus = (E[minus] * np.sqrt(-wc[minus])[:, None]).T if minus.any() else None
    return A, y_mean - A @ mean, Omega_plus, Omega_minus


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

    needs_spread = True
    """A regression sees a slope only where its belief has spread (:func:`gaussfuse._linalg.unseen_directions`)."""

    def __init__(self, model, rule: SigmaRule, us: np.ndarray | None = None) -> None:
        self.model, self.rule, self.us = model, rule, us

    def transition(self, k: int, mean: np.ndarray, cov: np.ndarray):
        """``(A, b, Q + Ω)`` from the regression of f under ``N(mean, cov)``."""
        m = self.model
        u = None if self.us is None else self.us[k]
        A, b, omega = slr(lambda X: m.transition(X, u), self.rule, mean, cov, m.state_angles,
                          name="the filtered covariance")
        return A, b, m.noise(k)[0] + omega

    def measurement(self, k: int, mean: np.ndarray, cov: np.ndarray):
        """``(H, d, R + Ω)`` from the regression of h under ``N(mean, cov)``."""
        m = self.model
        H, d, omega = slr(m.measurement, self.rule, mean, cov, m.measurement_angles, name="the predicted covariance")
        return H, d, m.noise(k)[1] + omega

    def transition_sqrt(self, k: int, mean: np.ndarray, factor: np.ndarray, factors):
        """``(A, b, [L_Q  Ω₊], Ω₋)`` from the regression of f on the factor (:func:`slr_sqrt`)."""
        m = self.model
        u = None if self.us is None else self.us[k]
        A, b, plus, minus = slr_sqrt(lambda X: m.transition(X, u), self.rule, mean, factor, m.state_angles)
        return A, b, np.concatenate([factors("Q", m.noise(k)[0]), plus], axis=1), minus

    def measurement_sqrt(self, k: int, mean: np.ndarray, factor: np.ndarray, factors):
        """``(H, d, [L_R  Ω₊], Ω₋)`` from the regression of h on the factor (:func:`slr_sqrt`)."""
        m = self.model
        H, d, plus, minus = slr_sqrt(m.measurement, self.rule, mean, factor, m.measurement_angles)
        return H, d, np.concatenate([factors("R", m.noise(k)[1]), plus], axis=1), minus
