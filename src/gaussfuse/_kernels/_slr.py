r"""The compiled mirror of :func:`gaussfuse.linearize.sigma_points.slr`: sigma points and their regression.

For a belief :math:`N(m, P)` with :math:`P = L L^\top` (the Cholesky factor,
or the semi-definite factor of :func:`gaussfuse._linalg.sqrt_cov` with zero
columns, given by the caller), :func:`points` draws
:math:`\mathcal X_i = m + L \xi_i`; given the outputs
:math:`\mathcal Y_i = g(\mathcal X_i)`, :func:`regress` computes the affine
map :math:`g(x) \approx A x + b + e`, :math:`e \sim N(0, \Omega)` exactly as
the readable ``slr`` does, in the points' own coordinates (see
:mod:`gaussfuse.linearize.sigma_points` for why):

.. math::

    \bar y &= \mathcal Y_0 + \textstyle\sum_i w^m_i (\mathcal Y_i - \mathcal Y_0)
        \quad\text{(centred; circular for angles)}, \qquad
    \delta\mathcal Y_i = \mathcal Y_i - \bar y \quad\text{(wrapped for angles)}, \\
    \Xi = \textstyle\sum_i w^c_i\, \xi_{i,r}\, \delta\mathcal Y_i^\top, \qquad
    A_{:, r} = \Xi^\top L_{rr}^{-1}, \quad A_{:, \bar r} = 0, \\
    b &= \bar y - A m, \qquad \Omega = \mathrm{sym}\textstyle\sum_i w^c_i e_i e_i^\top, \quad
    e_i = \delta\mathcal Y_i - \Xi^\top \xi_{i,r}

(residuals at round-off set to 0), with r the nonzero columns of L. The filters then add :math:`\Omega` to Q
or R and run the affine step of :mod:`._step`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from .._linalg import UNRESOLVED
from ._dense import cholesky
from ._jit import jit
from ._step import wrap

__all__ = ["Rule", "Regression", "regression", "draw", "points", "regress", "regress_sqrt"]

_JIT = {"nogil": True, "error_model": "numpy"}
_EPS = float(np.finfo(np.float64).eps)


class Rule(NamedTuple):
    """A sigma-point rule (:class:`gaussfuse.linearize.rules.SigmaRule`) as the kernels read it."""

    points: np.ndarray  # (k, n) unit points ξ_i
    wm: np.ndarray      # (k,) weights of the mean
    wc: np.ndarray      # (k,) weights of the covariances


class Regression(NamedTuple):
    """Scratch and results of the regression of a function of n states with d outputs."""

    L: np.ndarray      # (n, n) the lower-triangular root that drew the points
    keep: np.ndarray   # (n,) bool: its nonzero columns r
    Lr: np.ndarray     # (n, n) L_rr, in the leading block
    ybar: np.ndarray   # (d,) the mean of the outputs
    dY: np.ndarray     # (k, d) the residuals δY_i
    E: np.ndarray      # (k, d) the regression's residuals e_i
    Xi: np.ndarray     # (n, d) Ξ, in its first |r| rows
    A: np.ndarray      # (d, n)
    b: np.ndarray      # (d,)
    noise: np.ndarray  # (d, d) Ω, then the noise covariance plus Ω
    reach: np.ndarray  # (k, n) |m| + |L ξ_i|, the size of each point's coordinates (written with the points)


@register_jitable
def regression(k, n, d):
    """A :class:`Regression` for k points, n states and d outputs."""
    return Regression(np.zeros((n, n)), np.ones(n, dtype=np.bool_), np.empty((n, n)), np.empty(d),
                      np.empty((k, d)), np.empty((k, d)), np.empty((n, d)), np.empty((d, n)), np.empty(d),
                      np.empty((d, d)), np.empty((k, n)))


@register_jitable(**_JIT)
def _points(mean, xi, L, X, reach):
    """``X_i = m + L ξ_i`` and ``reach_i = |m| + |L ξ_i|`` (the size of the point's coordinates, for regress)."""
    n = mean.shape[0]
    for i in range(xi.shape[0]):
        for a in range(n):  # each coordinate summed once, over b in order, zero terms skipped
            t = 0.0
            for b in range(a + 1):
                c = xi[i, b]
                if c != 0.0:
                    t += c * L[a, b]
            reach[i, a] = abs(mean[a]) + abs(t)
            X[i, a] = t + mean[a]


@jit(inline="always", **_JIT)
def points(mean, rule, g, X):
    """``X = mean + ξ Lᵀ`` with the lower-triangular ``g.L`` (``mean + rule.points @ L.T`` in slr).

    The terms of ξ that are zero are skipped (the unscented and cubature
    points have one nonzero coordinate each): they add exactly zero.
    """
    _points(mean, rule.points, g.L, X, g.reach)


@jit(inline="always", **_JIT)
def draw(mean, cov, rule, g, X):
    """The sigma points of ``N(mean, cov)`` into X through the Cholesky factor of cov (:func:`sqrt_cov`'s first try).

    Returns False, drawing nothing, when cov is not positive definite: the
    caller then gives :func:`gaussfuse._linalg.sqrt_cov`'s semi-definite
    factor in ``g.L`` and ``g.keep`` and calls :func:`points`.
    """
    return _draw(mean, cov, rule.points, g.L, g.keep, X, g.reach)


@register_jitable(**_JIT)
def _draw(mean, cov, xi, L, keep, X, reach):
    n = mean.shape[0]
    for a in range(n):  # a spread below the mean's resolution: _linalg.sqrt_cov's, given the mean, in Python
        if not cov[a, a] > 0.0 or math.sqrt(cov[a, a]) <= UNRESOLVED * abs(mean[a]):
            return False
    if not cholesky(cov, L, n):
        return False
    for a in range(n):  # a pivot of round-off: _linalg.sqrt_cov's semi-definite factor instead, in Python
        if L[a, a] * L[a, a] <= n * _EPS * cov[a, a]:
            return False
    for a in range(n):
        keep[a] = True
        for b in range(a + 1, n):
            L[a, b] = 0.0
    _points(mean, xi, L, X, reach)
    return True


@jit(inline="always", **_JIT)
def regress(Y, d, rule, mean, angles, g):
    r"""linearize.sigma_points.slr on the outputs ``Y[:, :d]`` at the points of ``N(mean, L Lᵀ)``.

    Writes ``g.A[:d]``, ``g.b[:d]`` and :math:`\Omega` in ``g.noise[:d, :d]``
    (see the module notes), with the root ``g.L`` and its columns ``g.keep``
    that drew the points.
    """
    _regress(Y, d, rule.points, rule.wm, rule.wc, mean, angles, g.L, g.keep, g.Lr, g.ybar, g.dY, g.E, g.Xi, g.A,
             g.b, g.noise, g.reach)


@register_jitable(**_JIT)
def _spread(Y, d, wm, angles, ybar, dY):
    """ȳ centred on the first point (_linalg.weighted_mean), or the circular mean of an angle; δY_i = Y_i - ȳ."""
    k = Y.shape[0]
    for a in range(d):
        ref = Y[0, a]
        if angles[a]:
            s = 0.0
            c = 0.0
            for i in range(k):
                s += wm[i] * math.sin(Y[i, a] - ref)
                c += wm[i] * math.cos(Y[i, a] - ref)
            ybar[a] = ref + math.atan2(s, c)
            for i in range(k):
                dY[i, a] = wrap(Y[i, a] - ybar[a])
        else:
            t = 0.0
            for i in range(k):
                t += wm[i] * (Y[i, a] - ref)
            ybar[a] = ref + t
            for i in range(k):
                dY[i, a] = Y[i, a] - ybar[a]


@register_jitable(**_JIT)
def _regress(Y, d, xi, wm, wc, mean, angles, L, keep, Lr, ybar, dY, E, Xi, A, offset, noise, reach):
    # Terms with a zero ξ (most: a rule's points lie on the axes) add exactly zero; Ξ and e skip them.
    k = Y.shape[0]
    n = mean.shape[0]
    _spread(Y, d, wm, angles, ybar, dY)
    r = 0
    for j in range(n):  # Ξ = (ξ_r wc)ᵀ δY, and L_rr
        if keep[j]:
            for a in range(d):
                t = 0.0
                for i in range(k):
                    c = xi[i, j] * wc[i]
                    if c != 0.0:
                        t += c * dY[i, a]
                Xi[r, a] = t
            rr = 0
            for jj in range(n):
                if keep[jj]:
                    Lr[r, rr] = L[j, jj]
                    rr += 1
            r += 1
    for i in range(k):  # e_i = δY_i - Ξᵀ ξ_{i,r}, before Ξ becomes Aᵀ
        for a in range(d):
            t = 0.0
            rr = 0
            for j in range(n):
                if keep[j]:
                    if xi[i, j] != 0.0:
                        t += xi[i, j] * Xi[rr, a]
                    rr += 1
            E[i, a] = dY[i, a] - t
    # Aᵀ_r = L_rr⁻ᵀ Ξ (back substitution), in place in Ξ
    for j in range(r - 1, -1, -1):
        for a in range(d):
            t = Xi[j, a]
            for jj in range(j + 1, r):
                t -= Lr[jj, j] * Xi[jj, a]
            Xi[j, a] = t / Lr[j, j]
    r = 0
    for j in range(n):
        if keep[j]:
            for a in range(d):
                A[a, j] = Xi[r, a]
            r += 1
        else:
            for a in range(d):
                A[a, j] = 0.0
    for a in range(d):  # b = ȳ - A m
        t = 0.0
        for j in range(n):
            t += A[a, j] * mean[j]
        offset[a] = ybar[a] - t
    cut = 4.0 * k * _EPS
    for a in range(d):  # the round-off of ȳ: Σ_l |w_l| |δY_l|
        t = 0.0
        for i in range(k):
            t += abs(wm[i]) * abs(dY[i, a])
        offset_err = t
        for i in range(k):  # residuals at the round-off of (|m| + |L ξ_i|) |A|ᵀ + |δY_i| + |ȳ| + Σ_l |w_l| |δY_l| are
            size = abs(dY[i, a]) + abs(ybar[a]) + offset_err  # zero (slr's _resolved)
            for j in range(n):
                size += reach[i, j] * abs(A[a, j])
            if abs(E[i, a]) <= cut * size:
                E[i, a] = 0.0
    for a in range(d):  # Ω = sym(Σ_i w_i e_i e_iᵀ), each pair once
        for b in range(a + 1):
            t = 0.0
            for i in range(k):
                t += E[i, a] * wc[i] * E[i, b]
            noise[a, b] = t
            noise[b, a] = t


@jit(inline="always", **_JIT)
def regress_sqrt(Y, d, rule, mean, angles, g, E, At):
    r"""linearize.sigma_points.slr_sqrt on the outputs ``Y[:, :d]`` at the points of ``N(mean, L Lᵀ)``.

    ``g.L`` is the lower-triangular factor that drew the points, with a
    positive diagonal. Writes ``g.A[:d]``, ``g.b[:d]`` and the residuals
    :math:`e_i = \delta\mathcal Y_i - \Xi^\top \xi_i` in ``E[:, :d]``, those
    within the round-off of the points and outputs set to 0 (see slr_sqrt);
    `At` (n, ≥ d) is scratch for :math:`A^\top`.
    """
    _regress_sqrt(Y, d, rule.points, rule.wm, rule.wc, mean, angles, g.L, g.ybar, g.dY, g.Xi, At, g.A, g.b, E,
                  g.reach)


@register_jitable(**_JIT)
def _regress_sqrt(Y, d, xi, wm, wc, mean, angles, L, ybar, dY, Xi, At, A, offset, E, reach):
    k = Y.shape[0]
    n = mean.shape[0]
    _spread(Y, d, wm, angles, ybar, dY)
    for j in range(n):  # Ξ = (ξ wc)ᵀ δY
        for a in range(d):
            t = 0.0
            for i in range(k):
                t += xi[i, j] * wc[i] * dY[i, a]
            Xi[j, a] = t
    for i in range(k):  # e_i = δY_i - Ξᵀ ξ_i
        for a in range(d):
            t = 0.0
            for j in range(n):
                t += xi[i, j] * Xi[j, a]
            E[i, a] = dY[i, a] - t
    for j in range(n - 1, -1, -1):  # Aᵀ = L⁻ᵀ Ξ: back substitution
        for a in range(d):
            t = Xi[j, a]
            for jj in range(j + 1, n):
                t -= L[jj, j] * At[jj, a]
            At[j, a] = t / L[j, j]
    for a in range(d):  # b = ȳ - A m
        t = 0.0
        for j in range(n):
            A[a, j] = At[j, a]
            t += At[j, a] * mean[j]
        offset[a] = ybar[a] - t
    cut = 4.0 * k * _EPS
    for a in range(d):  # the round-off of ȳ: Σ_l |w_l| |δY_l|
        t = 0.0
        for i in range(k):
            t += abs(wm[i]) * abs(dY[i, a])
        offset_err = t
        for i in range(k):  # residuals at the round-off of (|m| + |ξ_i Lᵀ|) |A|ᵀ + |δY_i| + |ȳ| + Σ_l |w_l| |δY_l|
            size = abs(dY[i, a]) + abs(ybar[a]) + offset_err  # are zero
            for j in range(n):
                size += reach[i, j] * abs(A[a, j])
            if abs(E[i, a]) <= cut * size:
                E[i, a] = 0.0
