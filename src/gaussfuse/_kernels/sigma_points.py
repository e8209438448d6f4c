r"""Compiled sigma-point filters and smoothers: methods "ukf", "ckf" and "ghkf".

The readable path (:class:`gaussfuse.linearize.SigmaPoints` feeding
:mod:`gaussfuse.kalman`) regresses f and h on the sigma points and runs the
affine Kalman step. For additive noise that collapses, in exact arithmetic,
to the classic sigma-point formulas computed here. With the points
:math:`\mathcal X_i = m + L \xi_i` of a belief :math:`N(m, P)`, :math:`P = L L^\top`
(the semi-definite Cholesky factor when P is singular), and :math:`\mathcal Y_i = f(\mathcal X_i)`:

.. math::

    m^- = \mathcal Y_0 + \textstyle\sum_i w^m_i (\mathcal Y_i - \mathcal Y_0), \qquad
    P^- = \textstyle\sum_i w^c_i\, \delta\mathcal Y_i \delta\mathcal Y_i^\top + Q, \qquad
    C^f = \textstyle\sum_i w^c_i\, (\mathcal X_i - m) \delta\mathcal Y_i^\top,

and with the points :math:`\mathcal X^-_i` of :math:`N(m^-, P^-)` and
:math:`\mathcal Z_i = h(\mathcal X^-_i)`, over the observed components o,

.. math::

    \bar z &= \mathcal Z_0 + \textstyle\sum_i w^m_i (\mathcal Z_i - \mathcal Z_0), \quad
    S = \textstyle\sum_i w^c_i\, \delta\mathcal Z_i \delta\mathcal Z_i^\top + R, \quad
    C = \textstyle\sum_i w^c_i\, (\mathcal X^-_i - m^-) \delta\mathcal Z_i^\top, \\
    S_o &= L_S L_S^\top, \quad W = L_S^{-1} C_o^\top, \quad \omega = L_S^{-1} v_o, \\
    m &= m^- + W^\top \omega, \quad P = P^- - W^\top W, \quad
    \ell = -\tfrac12 \left(\omega^\top \omega + 2 \textstyle\sum \log\operatorname{diag} L_S + |o| \log 2\pi\right),

i.e. :math:`K = C_o S_o^{-1}`, :math:`P = P^- - K S_o K^\top`. (The means are
centred on the first point, as the readable path's, so that a component
known exactly keeps a variance of exactly 0.) The readable path's regression
matrices :math:`A = C^\top P^{-1}` (computed as :math:`\Xi^\top L^{-1}` in the
unit points) cancel out of every one of these (its Joseph form, with
:math:`H = C^\top (P^-)^{-1}` and :math:`R + \Omega`, expands to
:math:`P^- - K S_o K^\top`), so the two agree to round-off;
:math:`P^- - W^\top W` is used because it is symmetric by
construction and costs one triangular solve. The RTS pass reuses the
filter's :math:`m^-, P^-, C^f` (the readable smoother re-draws the points at
each filtered belief, which gives the same numbers):
:math:`G_k = C^f_{k+1} (P^-_{k+1})^{-1}` (Cholesky solve; the minimum-norm
least-squares solution when :math:`P^-_{k+1}` is singular).

Angles follow the readable path: outputs marked as angles have circular
means and wrapped residuals, innovations and smoother differences are
wrapped, and state angles are wrapped after every predict, update and
smoothing step.

Execution modes, chosen per call:

* **compiled** -- f and h are numba-compiled functions
  (:func:`numba.extending.is_jitted`). The whole forward pass, all series
  included, is one compiled function that receives f and h as first-class
  function values, so it is compiled once per *signature*
  (f(x) or f(x, u); array or scalar results; one state or a stack of
  states for ``vectorized=True``) and cached on disk, whatever the
  functions. f and h must accept C-contiguous float64 arrays and return
  float64 arrays (or a float when the output has one component). A jitted
  function that does not fit (another return type, a locked signature)
  runs in the Python mode below, with the same results.
* **python** -- plain Python f and h: the loop over steps is Python, calling
  f and h once per sigma point (or once per step on the (k, n) stack when
  the model is vectorized); everything between the calls -- moments,
  prediction, update, drawing the next points, storing the results -- is two
  compiled calls per step.

A covariance that is not positive definite (a state known exactly, no
process noise on it) has no Cholesky factor: its points are then drawn in
Python through :func:`~gaussfuse._linalg.sqrt_cov`, the
readable path's semi-definite Cholesky factor (in the compiled mode, that series and the
following ones continue in the Python mode), and a singular :math:`P^-` in
the smoother gets the readable path's least-squares gain.
:func:`execution_mode` tells which mode a model gets.

Model-function errors (an exception, a wrong shape, a non-finite value) and
failed factorisations raise the same :class:`ModelFunctionError` /
:class:`numpy.linalg.LinAlgError` messages as the readable path, prefixed by
"at step k: ", and a predicted, filtered or smoothed belief that is not finite
(an overflow) the same :class:`FloatingPointError`
(:func:`gaussfuse.inference.check_finite`).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from numba import types
from numba.core.errors import NumbaError, NumbaExperimentalFeatureWarning
from numba.extending import is_jitted, overload

from .._linalg import sqrt_cov
from .._validation import call_checked, size_reason
from ..errors import ModelFunctionError, not_finite
from ..inference.results import FilterResult, SmoothResult, check_smoothed
from ._jit import jit
from ._nrt import borrow, readonly

__all__ = ["filter", "smooth", "execution_mode"]

_LOG_2PI = math.log(2.0 * math.pi)
_TWO_PI = 2.0 * math.pi
_F64 = np.dtype(np.float64)

# Status codes returned by the compiled code; details go to `iwork` and `errval`.
OK, F_SHAPE, F_NONFINITE, H_SHAPE, H_NONFINITE, NEED_ROOT, S_NOT_PD, PREDICTED_NOT_FINITE, FILTERED_NOT_FINITE = range(9)
# iwork: [code, series, step, stage, point, got0, got1, got_ndim, observed indices (m)...]
_CODE, _SERIES, _STEP, _STAGE, _POINT, _GOT = 0, 1, 2, 3, 4, 5
_NINFO = 8
# stage: what the compiled loop is doing (to name the function behind an exception)
_BEFORE, _IN_F, _IN_H, _ALGEBRA = -1, 0, 1, 2



# ---------------------------------------------------------------------------
# Compiled algebra (shared by both modes)
# ---------------------------------------------------------------------------


@jit(error_model="numpy", inline="always")
def _wrap(a):
    """``(a + π) % 2π - π`` as NumPy computes it, skipping the fmod when ``a + π`` is in [0, 2π)."""
    x = a + math.pi
    if not (x >= 0.0 and x < _TWO_PI):
        x = x % _TWO_PI
    return x - math.pi


@jit(error_model="numpy")
def _copy(dst, src):
    """``dst[...] = src`` for equal shapes (1-D or 2-D), as a plain loop.

    Array assignment would also compile NumPy's broadcasting and its error
    messages, seconds of compilation for nothing here.
    """
    if src.ndim == 1:
        for a in range(src.shape[0]):
            dst[a] = src[a]
    else:
        for a in range(src.shape[0]):
            for b in range(src.shape[1]):
                dst[a, b] = src[a, b]


@jit(error_model="numpy", inline="always")
def _cholesky_in_place(L, p):
    """Overwrite the lower triangle of ``L[:p, :p]`` by its Cholesky factor; False if not PD."""
    for j in range(p):
        s = L[j, j]
        for q in range(j):
            s -= L[j, q] * L[j, q]
        if not s > 0.0:  # LAPACK's test: fails on zero, negative and NaN pivots
            return False
        d = math.sqrt(s)
        L[j, j] = d
        inv = 1.0 / d
        for i in range(j + 1, p):
            t = L[i, j]
            for q in range(j):
                t -= L[i, q] * L[j, q]
            L[i, j] = t * inv
    return True


@jit(error_model="numpy", inline="always")
def _points(mean, L, pts, X, full):
    """``X = mean + pts @ L.T``; L lower triangular unless `full`.

    Column by column, skipping the zeros of `pts`: the unscented and
    cubature points have one nonzero coordinate each.
    """
    n = mean.shape[0]
    for i in range(pts.shape[0]):
        for a in range(n):
            X[i, a] = mean[a]
        for b in range(n):
            c = pts[i, b]
            if c != 0.0:
                for a in range(0 if full else b, n):
                    X[i, a] += c * L[a, b]


@jit(error_model="numpy", inline="always")
def _draw(mean, cov, pts, X, L):
    """Sigma points of ``N(mean, cov)`` into X, through the Cholesky factor (in L).

    NEED_ROOT when cov is not positive definite: the caller then draws them
    with :func:`gaussfuse._linalg.sqrt_cov`, as the readable path.
    """
    n = mean.shape[0]
    for a in range(n):
        for b in range(a + 1):
            L[a, b] = cov[a, b]
    if not _cholesky_in_place(L, n):
        return NEED_ROOT
    _points(mean, L, pts, X, False)
    return OK


@jit(error_model="numpy", inline="always")
def _moments(Y, d, wm, wc, angles, ybar, dY, S):
    """Weighted mean (circular for angles), wrapped residuals and ``S = Σ wc dY dYᵀ`` of ``Y[:, :d]``."""
    k = Y.shape[0]
    for a in range(d):
        if angles[a]:  # the circular mean, centred on the first point as the readable path
            s = 0.0
            c = 0.0
            for i in range(k):
                s += wm[i] * math.sin(Y[i, a] - Y[0, a])
                c += wm[i] * math.cos(Y[i, a] - Y[0, a])
            mu = Y[0, a] + math.atan2(s, c)
            for i in range(k):
                dY[i, a] = _wrap(Y[i, a] - mu)
        else:  # centred on the first point, as linearize.sigma_points.weighted_mean
            acc = 0.0
            for i in range(1, k):
                acc += wm[i] * (Y[i, a] - Y[0, a])
            mu = Y[0, a] + acc
            for i in range(k):
                dY[i, a] = Y[i, a] - mu
        ybar[a] = mu
    for a in range(d):
        for b in range(a, d):
            acc = 0.0
            for i in range(k):
                acc += wc[i] * dY[i, a] * dY[i, b]
            S[a, b] = acc
            S[b, a] = acc


@jit(error_model="numpy", inline="always")
def _cross(X, center, dY, d, wc, C):
    """``C = Σ wc (X - center) dYᵀ``, shape (n, d)."""
    n = X.shape[1]
    for a in range(n):
        for b in range(d):
            acc = 0.0
            for i in range(X.shape[0]):
                acc += wc[i] * (X[i, a] - center[a]) * dY[i, b]
            C[a, b] = acc


@jit(error_model="numpy", inline="always")
def _predict(X, Y, mean, wm, wc, xang, Q, pmean, pcov, cross, with_cross, scr):
    """Prediction ``(m⁻, P⁻)`` from the f-outputs Y at the points X of the belief with mean `mean`."""
    n = Y.shape[1]
    k = Y.shape[0]
    d = scr.shape[1]
    ybar = scr[2 * d + 2 * n + k]
    dY = scr[2 * d + 2 * n:2 * d + 2 * n + k]
    S = scr[d:2 * d]
    _moments(Y, n, wm, wc, xang, ybar, dY, S)
    for a in range(n):
        pmean[a] = _wrap(ybar[a]) if xang[a] else ybar[a]
        for b in range(n):
            pcov[a, b] = S[a, b] + Q[a, b]
    if with_cross:
        _cross(X, mean, dY, n, wc, cross)


@jit(error_model="numpy", inline="always")
def _update(Xh, Z, pmean, pcov, wm, wc, zang, xang, R, z, mean, cov, innov, Sfull, iwork, errval, scr):
    """Condition ``N(m⁻, P⁻)`` on z through the h-outputs Z at its points Xh; returns (status, loglik)."""
    n = Xh.shape[1]
    k = Xh.shape[0]
    m = Z.shape[1]
    d = scr.shape[1]
    L = scr[0:d]
    C = scr[2 * d:2 * d + n]
    Wt = scr[2 * d + n:2 * d + 2 * n]
    dZ = scr[2 * d + 2 * n:2 * d + 2 * n + k]
    zbar = scr[2 * d + 2 * n + k]
    wv = scr[2 * d + 2 * n + k + 1]
    _moments(Z, m, wm, wc, zang, zbar, dZ, Sfull)
    for a in range(m):
        for b in range(m):
            Sfull[a, b] += R[a, b]
    _cross(Xh, pmean, dZ, m, wc, C)
    obs = iwork[_NINFO:]
    p = 0
    for j in range(m):
        v = z[j] - zbar[j]
        innov[j] = _wrap(v) if zang[j] else v
        if not math.isnan(z[j]):
            obs[p] = j
            p += 1
    if p == 0:
        for a in range(n):
            mean[a] = pmean[a]
            for b in range(n):
                cov[a, b] = pcov[a, b]
        return OK, 0.0
    for r in range(p):
        for q in range(r + 1):
            L[r, q] = Sfull[obs[r], obs[q]]
    if not _cholesky_in_place(L, p):
        for r in range(p):
            for q in range(p):
                errval[r * p + q] = Sfull[obs[r], obs[q]]
        iwork[_GOT] = p
        return S_NOT_PD, 0.0
    # W = L⁻¹ C_oᵀ (stored transposed, n × p) and ω = L⁻¹ v_o, by forward substitution.
    ll = 0.0
    for r in range(p):
        inv = 1.0 / L[r, r]
        t = innov[obs[r]]
        for q in range(r):
            t -= L[r, q] * wv[q]
        wv[r] = t * inv
        ll += wv[r] * wv[r] + 2.0 * math.log(L[r, r])
        for a in range(n):
            t = C[a, obs[r]]
            for q in range(r):
                t -= L[r, q] * Wt[a, q]
            Wt[a, r] = t * inv
    for a in range(n):
        acc = 0.0
        for r in range(p):
            acc += Wt[a, r] * wv[r]
        v = pmean[a] + acc
        mean[a] = _wrap(v) if xang[a] else v
        for b in range(a, n):
            acc = 0.0
            for r in range(p):
                acc += Wt[a, r] * Wt[b, r]
            cov[a, b] = pcov[a, b] - acc
            cov[b, a] = cov[a, b]
    lk = -0.5 * (ll + p * _LOG_2PI)
    if _not_finite(mean, cov, lk):
        return FILTERED_NOT_FINITE, lk
    return OK, lk


@jit(error_model="numpy", inline="always")
def _not_finite(mean, cov, loglik):
    """True when the mean, the diagonal of the covariance or `loglik` is inf or NaN (inference.check_finite)."""
    if not math.isfinite(loglik):
        return True
    for a in range(mean.shape[0]):
        if not (math.isfinite(mean[a]) and math.isfinite(cov[a, a])):
            return True
    return False


@jit(error_model="numpy")
def _finite_rows(Y):
    """Index of the first row of Y with a non-finite value, or -1."""
    for i in range(Y.shape[0]):
        for j in range(Y.shape[1]):
            if not math.isfinite(Y[i, j]):
                return i
    return -1


def _scratch(k, n, m):
    """Work space of the compiled steps, d = max(n, m) wide: rows L (d) | S (d) | C (n) | Wᵀ (n) | dY (k) | ȳ | ω."""
    d = max(n, m)
    return np.empty((2 * d + 2 * n + k + 2, d))


@jit(error_model="numpy")
def _rts(means, covs, pmeans, pcovs, cross, xang, sm_means, sm_covs, gains, pos, given):
    """The RTS backward pass over N filtered series (see the module notes).

    Starts at series ``pos[0]``, step ``pos[1]`` (with ``sm_*[:, T-1]`` set
    by the caller), using the gain `given` there if ``pos[2]``. Returns 1,
    with `pos` at the step, when a predicted covariance is singular: the
    caller computes that gain by least squares (as the readable path) and
    resumes; 0 when done.
    """
    means, covs, pmeans, pcovs, cross = borrow(means), borrow(covs), borrow(pmeans), borrow(pcovs), borrow(cross)
    sm_means, sm_covs, gains = borrow(sm_means), borrow(sm_covs), borrow(gains)
    N, T, n = means.shape
    L = np.empty((n, n))
    Gt = np.empty((n, n))
    D = np.empty((n, n))
    dm = np.empty(n)
    for s in range(pos[0], N):
        for j in range(pos[1] if s == pos[0] else T - 2, -1, -1):
            Pp = pcovs[s, j + 1]
            Cf = cross[s, j + 1]
            for a in range(n):
                for b in range(a + 1):
                    L[a, b] = Pp[a, b]
            if pos[2]:
                pos[2] = 0
                for a in range(n):
                    for b in range(n):
                        Gt[b, a] = given[a, b]
            elif _cholesky_in_place(L, n):
                # Gᵀ = P⁻⁻¹ Cfᵀ: forward then backward substitution, column by column.
                for c in range(n):
                    for a in range(n):
                        t = Cf[c, a]
                        for q in range(a):
                            t -= L[a, q] * Gt[q, c]
                        Gt[a, c] = t / L[a, a]
                    for a in range(n - 1, -1, -1):
                        t = Gt[a, c]
                        for q in range(a + 1, n):
                            t -= L[q, a] * Gt[q, c]
                        Gt[a, c] = t / L[a, a]
            else:
                pos[0] = s
                pos[1] = j
                return 1
            G = gains[s, j]
            for a in range(n):
                for b in range(n):
                    G[a, b] = Gt[b, a]
            for a in range(n):
                v = sm_means[s, j + 1, a] - pmeans[s, j + 1, a]
                dm[a] = _wrap(v) if xang[a] else v
            for a in range(n):
                acc = 0.0
                for b in range(n):
                    acc += G[a, b] * dm[b]
                v = means[s, j, a] + acc
                sm_means[s, j, a] = _wrap(v) if xang[a] else v
            # P = P_f + G (P_s - P⁻) Gᵀ, symmetrised
            for a in range(n):
                for b in range(n):
                    acc = 0.0
                    for c in range(n):
                        acc += G[a, c] * (sm_covs[s, j + 1, c, b] - Pp[c, b])
                    D[a, b] = acc
            for a in range(n):
                for b in range(a, n):
                    acc = 0.0
                    for c in range(n):
                        acc += D[a, c] * G[b, c]
                    acc2 = 0.0
                    for c in range(n):
                        acc2 += D[b, c] * G[a, c]
                    v = covs[s, j, a, b] + 0.5 * (acc + acc2)
                    sm_covs[s, j, a, b] = v
                    sm_covs[s, j, b, a] = v
    return 0


# ---------------------------------------------------------------------------
# Compiled mode: the whole loop, with f and h as first-class functions
# ---------------------------------------------------------------------------


def _call(fn, x, us, s, k):  # pragma: no cover - replaced by the overload in compiled code
    raise NotImplementedError


@overload(_call)  # compiled into, and cached with, the loop that calls it
def _call_overload(fn, x, us, s, k):
    """``fn(x)``, or ``fn(x, u)`` with the control of series s at step k."""
    if not isinstance(fn, types.FunctionType):
        return None
    if fn.nargs == 2:
        return lambda fn, x, us, s, k: fn(x, us[s, k])
    return lambda fn, x, us, s, k: fn(x)


def _apply(fn, X, us, s, k, Y, iwork):  # pragma: no cover - replaced by the overload in compiled code
    raise NotImplementedError


@overload(_apply)  # compiled into, and cached with, the loop that calls it
def _apply_overload(fn, X, us, s, k, Y, iwork):
    """Evaluate a first-class model function at the points X into Y; a status code.

    Specialised on the function's signature: per point or on the stack,
    returning an array or a scalar. Shapes are checked, then values, point
    by point, as ``call_checked`` does: 0 when all is well, 1 for a wrong
    shape, 2 for a non-finite value.
    """
    if not isinstance(fn, types.FunctionType):
        return None
    sig = fn.signature
    if sig.args[0].ndim == 2:
        def impl(fn, X, us, s, k, Y, iwork):
            out = _call(fn, X, us, s, k)
            iwork[_POINT] = 0
            if out.shape[0] != Y.shape[0] or out.shape[1] != Y.shape[1]:
                iwork[_GOT] = out.shape[0]
                iwork[_GOT + 1] = out.shape[1]
                iwork[_GOT + 2] = 2
                return 1
            for i in range(Y.shape[0]):
                for j in range(Y.shape[1]):
                    v = out[i, j]
                    if not math.isfinite(v):
                        return 2
                    Y[i, j] = v
            return 0
    elif isinstance(sig.return_type, (types.Float, types.Integer)):
        def impl(fn, X, us, s, k, Y, iwork):
            for i in range(X.shape[0]):
                iwork[_POINT] = i
                v = _call(fn, X[i], us, s, k)
                if not math.isfinite(v):
                    return 2
                Y[i, 0] = v
            return 0
    else:
        def impl(fn, X, us, s, k, Y, iwork):
            d = Y.shape[1]
            for i in range(X.shape[0]):
                iwork[_POINT] = i
                out = _call(fn, X[i], us, s, k)
                if out.shape[0] != d:
                    iwork[_GOT] = out.shape[0]
                    iwork[_GOT + 2] = 1
                    return 1
                for j in range(d):
                    v = out[j]
                    if not math.isfinite(v):
                        return 2
                    Y[i, j] = v
            return 0
    return impl


def _filter_loop(f, h, us, zs, Q3, R3, pts, w, xang, zang, m0, P0, means, covs, pmeans, pcovs,
                 innov, icovs, cross, loglik, last_mean, last_cov, iwork, errval,
                 X, Y, Xh, Z, pmean, pcov, Cf, Sfull, v, scr):
    """The forward pass over all series, f and h called in the loop; a status code.

    On a status other than OK, ``iwork`` holds the series, step and point
    (and `errval` the matrix that failed to factorise). The last ten
    arguments are scratch. Every array is borrowed (see :mod:`._nrt`): the
    caller holds them for the whole call.
    """
    zs, Q3, R3, pts, w, xang, zang, m0, P0 = (borrow(zs), borrow(Q3), borrow(R3), borrow(pts), borrow(w),
                                              borrow(xang), borrow(zang), borrow(m0), borrow(P0))
    means, covs, pmeans, pcovs, innov, icovs, cross = (borrow(means), borrow(covs), borrow(pmeans),
                                                       borrow(pcovs), borrow(innov), borrow(icovs),
                                                       borrow(cross))
    loglik, last_mean, last_cov, iwork, errval = (borrow(loglik), borrow(last_mean), borrow(last_cov),
                                                  borrow(iwork), borrow(errval))
    X, Y, Xh, Z, pmean, pcov, Cf, Sfull, v, scr = (borrow(X), borrow(Y), borrow(Xh), borrow(Z),
                                                   borrow(pmean), borrow(pcov), borrow(Cf),
                                                   borrow(Sfull), borrow(v), borrow(scr))
    N, T, m = zs.shape
    k, n = pts.shape
    wm = w[0]
    wc = w[1]
    L = scr[0:n]
    rows = means.shape[1]
    crows = covs.shape[1]
    srows = cross.shape[1]
    for s in range(N):
        mean = last_mean[s]
        cov = last_cov[s]
        _copy(mean, m0)
        _copy(cov, P0)
        ll = 0.0
        iwork[_SERIES] = s
        for t in range(T):
            iwork[_STEP] = t
            iwork[_STAGE] = _ALGEBRA
            status = _draw(mean, cov, pts, X, L)
            if status != OK:
                iwork[_CODE] = status
                return status
            iwork[_STAGE] = _IN_F
            status = _apply(f, X, us, s, t, Y, iwork)
            iwork[_STAGE] = _ALGEBRA
            if status != 0:
                iwork[_CODE] = F_SHAPE if status == 1 else F_NONFINITE
                return iwork[_CODE]
            _predict(X, Y, mean, wm, wc, xang, Q3[t if Q3.shape[0] > 1 else 0], pmean, pcov, Cf,
                     srows > 0, scr)
            if _not_finite(pmean, pcov, 0.0):
                iwork[_CODE] = PREDICTED_NOT_FINITE
                return PREDICTED_NOT_FINITE
            for a in range(n):
                if rows:
                    pmeans[s, t, a] = pmean[a]
                for b in range(n):
                    if crows:
                        pcovs[s, t, a, b] = pcov[a, b]
                    if srows:
                        cross[s, t, a, b] = Cf[a, b]
            status = _draw(pmean, pcov, pts, Xh, L)
            if status != OK:
                iwork[_CODE] = status
                return status
            iwork[_STAGE] = _IN_H
            status = _apply(h, Xh, us, s, t, Z, iwork)
            iwork[_STAGE] = _ALGEBRA
            if status != 0:
                iwork[_CODE] = H_SHAPE if status == 1 else H_NONFINITE
                return iwork[_CODE]
            status, lk = _update(Xh, Z, pmean, pcov, wm, wc, zang, xang, R3[t if R3.shape[0] > 1 else 0],
                                 zs[s, t], mean, cov, v, Sfull, iwork, errval, scr)
            if status != OK:
                iwork[_CODE] = status
                return status
            ll += lk
            if rows:
                for a in range(n):
                    means[s, t, a] = mean[a]
                for a in range(m):
                    innov[s, t, a] = v[a]
            if crows:
                for a in range(n):
                    for b in range(n):
                        covs[s, t, a, b] = cov[a, b]
                for a in range(m):
                    for b in range(m):
                        icovs[s, t, a, b] = Sfull[a, b]
        loglik[s] = ll
    return OK


_C1 = types.float64[::1]
_C2 = types.float64[:, ::1]
_C3 = types.float64[:, :, ::1]
_C4 = types.float64[:, :, :, ::1]
_R3 = types.Array(types.float64, 3, "C", readonly=True)  # zs: read in place, never copied
_LOOPS: dict = {}
# Reassociation and fused multiply-adds let LLVM vectorise the sums over sigma
# points; NaN and inf keep their IEEE meaning, so the finiteness checks stand.
_LOOP_JIT = {"error_model": "numpy", "fastmath": {"reassoc", "contract", "arcp"}}


def _loop_for(f_sig, h_sig, with_u: bool):
    """The compiled loop for these function signatures (compiled on first use, cached on disk)."""
    key = (f_sig, h_sig, with_u)
    if key not in _LOOPS:
        sig = types.int64(
            types.FunctionType(f_sig), types.FunctionType(h_sig), _C3 if with_u else types.none,
            _R3, _C3, _C3, _C2, _C2, types.boolean[::1], types.boolean[::1], _C1, _C2,
            _C3, _C4, _C3, _C4, _C3, _C4, _C4, _C1, _C2, _C3, types.int64[::1], _C1,
            _C2, _C2, _C2, _C2, _C1, _C2, _C2, _C2, _C1, _C2,  # scratch
        )
        with warnings.catch_warnings():  # first-class function types are "experimental" in numba
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            _LOOPS[key] = jit(sig, **_LOOP_JIT)(_filter_loop)
    return _LOOPS[key]


def _loop_scratch(k, n, m):
    """The scratch arrays of :func:`_filter_loop`: X, Y, Xh, Z, m⁻, P⁻, Cᶠ, S, v and the work rows."""
    return (np.empty((k, n)), np.empty((k, n)), np.empty((k, n)), np.empty((k, m)),
            np.empty(n), np.empty((n, n)), np.empty((n, n)), np.empty((m, m)), np.empty(m),
            _scratch(k, n, m))


def _jitted_signatures(model, prior, us):
    """f's and h's first-class signatures, or None when they do not fit the compiled mode.

    f and h are called once, at the prior mean, to learn what they return;
    anything unexpected leaves the call to the Python mode, which reports
    it as the readable path does.
    """
    f, h = model.f, model.h
    if not (is_jitted(f) and is_jitted(h)):
        return None
    stacked = model.vectorized
    x = prior.mean.copy()[None] if stacked else prior.mean.copy()
    args = () if us is None else (np.ascontiguousarray(us[0, 0], dtype=np.float64),)
    x_type = _C2 if stacked else _C1
    sigs = []
    for fn, fargs, size in ((f, args, model.n), (h, (), model.m)):
        try:
            out = fn(x, *fargs)
        except Exception:
            return None
        if isinstance(out, np.ndarray) and out.dtype == _F64 and out.ndim == x.ndim:
            ret = types.float64[:, :] if stacked else types.float64[:]
        elif not stacked and size == 1 and isinstance(out, (float, np.floating)):
            ret = types.float64
        else:
            return None
        sigs.append(ret(x_type, *([_C1] * len(fargs))))
    return sigs


# ---------------------------------------------------------------------------
# Python mode: the loop in Python, the algebra compiled
# ---------------------------------------------------------------------------
#
# `bel` rows: 0 mean | 1..n cov | n+1 predicted mean | n+2..2n+1 predicted cov
#             | 2n+2..3n+1 a square root | 3n+2..4n+1 the cross-covariance C^f


@jit(error_model="numpy")
def _py_start(m0, P0, pts, bel, X):
    n = m0.shape[0]
    _copy(bel[0], m0)
    _copy(bel[1:n + 1], P0)
    return _draw(bel[0], bel[1:n + 1], pts, X, bel[2 * n + 2:3 * n + 2])


@jit(error_model="numpy")
def _py_after_f(t, Y, X, Q3, pts, w, angles, bel, Xh, pmeans, pcovs, cross, scr, iwork):
    """Check f's outputs, predict, store, and draw the points for h."""
    n = X.shape[1]
    i = _finite_rows(Y)
    if i >= 0:
        iwork[_POINT] = i
        return F_NONFINITE
    pmean = bel[n + 1]
    pcov = bel[n + 2:2 * n + 2]
    Cf = bel[3 * n + 2:4 * n + 2]
    _predict(X, Y, bel[0], w[0], w[1], angles[:n], Q3[t if Q3.shape[0] > 1 else 0], pmean, pcov, Cf,
             cross.shape[0] > 0, scr)
    if _not_finite(pmean, pcov, 0.0):
        return PREDICTED_NOT_FINITE
    if pmeans.shape[0]:
        _copy(pmeans[t], pmean)
    if pcovs.shape[0]:
        _copy(pcovs[t], pcov)
    if cross.shape[0]:
        _copy(cross[t], Cf)
    return _draw(pmean, pcov, pts, Xh, bel[2 * n + 2:3 * n + 2])


@jit(error_model="numpy")
def _py_after_h(t, Z, Xh, R3, zs, pts, w, angles, bel, X, means, covs, innov, icovs, scr, iwork, errval):
    """Check h's outputs, update, store, and draw the points for the next step's f."""
    n = X.shape[1]
    m = Z.shape[1]
    i = _finite_rows(Z)
    if i >= 0:
        iwork[_POINT] = i
        return H_NONFINITE
    mean = bel[0]
    cov = bel[1:n + 1]
    Sfull = icovs[t] if icovs.shape[0] else np.empty((m, m))
    v = innov[t] if innov.shape[0] else np.empty(m)
    status, lk = _update(Xh, Z, bel[n + 1], bel[n + 2:2 * n + 2], w[0], w[1], angles[n:], angles[:n],
                         R3[t if R3.shape[0] > 1 else 0], zs[t], mean, cov, v, Sfull, iwork, errval, scr)
    if status != OK:
        return status
    errval[errval.shape[0] - 1] += lk  # the running log-likelihood
    if means.shape[0]:
        _copy(means[t], mean)
    if covs.shape[0]:
        _copy(covs[t], cov)
    if t + 1 < zs.shape[0]:
        iwork[_STEP] = t + 1
        return _draw(mean, cov, pts, X, bel[2 * n + 2:3 * n + 2])
    return OK


def _evaluate(name, fn, X, Y, u, vectorized):
    """f or h at the points X (k, n): the (k, d) outputs, checked for type and shape.

    Non-finite values are found by the compiled step that follows; the
    type, shape and exception checks stay here, with the messages (and the
    order, point by point) of :func:`~gaussfuse.models.nonlinear.call_checked`.
    """
    args = () if u is None else (u,)
    if vectorized:
        try:
            out = fn(X, *args)
        except Exception as exc:
            _raise_call(name, exc, X)
        if type(out) is not np.ndarray or out.shape != Y.shape or out.dtype is not _F64:
            out = call_checked(name, lambda *_: out, X, (), Y.shape, size_reason(name, Y.shape[1]))
        if out.strides != Y.strides:  # a view (say X[:, :1]): copy, rather than compile for its layout
            Y[...] = out
            return Y
        return out
    outs = []
    append = outs.append
    try:
        if u is None:
            for x in X:
                append(fn(x))
        else:
            for x in X:
                append(fn(x, u))
    except Exception as exc:
        _check_each(name, outs, X, Y)  # the readable path would have stopped at an earlier point
        _raise_call(name, exc, X[len(outs)])
    try:
        out = np.array(outs)
    except (TypeError, ValueError):  # ragged, say
        out = None
    if out is None or out.shape != Y.shape or out.dtype is not _F64:
        _check_each(name, outs, X, Y)
        return Y
    return out


def _check_each(name, outs, X, Y):
    """Each output through call_checked, in order, into Y: raises at the first bad one."""
    shape = (Y.shape[1],)
    for i, out in enumerate(outs):
        Y[i] = call_checked(name, lambda *_: out, X[i], (), shape, size_reason(name, shape[0]))


def _raise_call(name, exc, x):
    """Raise call_checked's message for a function that raised `exc` on `x`."""
    def again(*_):
        raise exc

    call_checked(name, again, x, (), ())


def _root_points(t, mean, cov, pts, X):
    """Sigma points through the readable path's square root (for a singular covariance)."""
    try:
        L = sqrt_cov(cov)[0]
    except np.linalg.LinAlgError as exc:
        raise np.linalg.LinAlgError(f"at step {t}: {exc}") from exc
    _points(mean, np.ascontiguousarray(L), pts, X, True)


# ---------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------


def _raise_status(status, t, iwork, errval, X, d, model):
    """Raise the readable path's error for a status code of the compiled code, at step t."""
    try:
        if status in (F_SHAPE, F_NONFINITE, H_SHAPE, H_NONFINITE):
            name = "f" if status in (F_SHAPE, F_NONFINITE) else "h"
            x = X if model.vectorized else X[iwork[_POINT]]
            shape = (X.shape[0], d) if model.vectorized else (d,)
            if status in (F_SHAPE, H_SHAPE):
                got = tuple(int(g) for g in iwork[_GOT:_GOT + iwork[_GOT + 2]])
                raise ModelFunctionError(
                    f"`{name}` must return shape {shape} for an input of shape {x.shape}, "
                    f"because {size_reason(name, d)}; got shape {got}."
                )
            raise ModelFunctionError(
                f"`{name}` returned a non-finite value (NaN or inf) for an input of shape {x.shape}."
            )
        if status in (PREDICTED_NOT_FINITE, FILTERED_NOT_FINITE):  # inference.check_finite's error
            raise FloatingPointError(f"at step {t}: {not_finite('predicted' if status == PREDICTED_NOT_FINITE else 'filtered')}")
        if status == S_NOT_PD:  # kalman.cholesky's message, for the observed block of S
            p = int(iwork[_GOT])
            with np.printoptions(precision=4, threshold=36):
                shown = np.array2string(errval[:p * p].reshape(p, p), separator=", ").replace("\n", "")
            raise np.linalg.LinAlgError(
                "the innovation covariance S = H P Hᵀ + R is not positive definite, "
                f"so it cannot be factorised: {shown}"
            )
        raise RuntimeError(f"unexpected status {status} from the compiled sigma-point filter")
    except (ModelFunctionError, np.linalg.LinAlgError) as exc:
        raise type(exc)(f"at step {t}: {exc}") from exc


# ---------------------------------------------------------------------------
# Drivers
# ---------------------------------------------------------------------------


def execution_mode(model, prior, us=None) -> str:
    """``"compiled"`` when the model's f and h fit the compiled loop, otherwise ``"python"``.

    `us`, when given, is the (N, T, p) array of controls.
    """
    return "python" if _jitted_signatures(model, prior, us) is None else "compiled"


def _rule(lin):
    rule = lin.rule
    return (np.ascontiguousarray(rule.points, dtype=np.float64),
            np.ascontiguousarray(np.stack([rule.wm, rule.wc]), dtype=np.float64))


def _stacked(a):
    a = np.asarray(a, dtype=np.float64)
    return np.array(a[None] if a.ndim == 2 else a, dtype=np.float64, order="C")


def _forward(lin, model, prior, zs, us, keep, with_cross):
    """The forward pass: the FilterResult fields (with the N axis) and the cross-covariances."""
    N, T, m = zs.shape
    n = model.n
    pts, w = _rule(lin)
    k = pts.shape[0]
    rows = 0 if keep == "last" else T
    crows = T if keep == "all" else 0
    means, pmeans, innov = np.empty((N, rows, n)), np.empty((N, rows, n)), np.empty((N, rows, m))
    covs, pcovs, icovs = np.empty((N, crows, n, n)), np.empty((N, crows, n, n)), np.empty((N, crows, m, m))
    cross = np.empty((N, T if with_cross else 0, n, n))
    loglik, last_mean, last_cov = np.zeros(N), np.empty((N, n)), np.empty((N, n, n))
    outs = (means, covs, pmeans, pcovs, innov, icovs, cross)
    zs = readonly(zs)  # read in place, one compiled type whether or not the caller's is writable
    us = None if us is None else np.require(us, np.float64, ["C", "W"])
    Q3, R3 = _stacked(model.Q), _stacked(model.R)
    xang = np.array(model.state_angles, dtype=np.bool_)  # writable copies: numba types read-only arrays apart
    zang = np.array(model.measurement_angles, dtype=np.bool_)
    m0, P0 = np.array(prior.mean, dtype=np.float64), np.array(prior.cov, dtype=np.float64)
    iwork = np.zeros(_NINFO + m, dtype=np.int64)
    errval = np.zeros(m * m + 1)
    first = 0  # the first series left to the Python mode
    sigs = _jitted_signatures(model, prior, us)
    if sigs is not None:
        loop = _loop_for(sigs[0], sigs[1], us is not None)
        iwork[_STAGE] = _BEFORE
        try:
            status = loop(model.f, model.h, us, zs, Q3, R3, pts, w, xang, zang, m0, P0, *outs,
                          loglik, last_mean, last_cov, iwork, errval, *_loop_scratch(k, n, m))
        except Exception as exc:
            stage = iwork[_STAGE]
            if not (stage == _BEFORE and isinstance(exc, (TypeError, NumbaError))):
                if stage not in (_IN_F, _IN_H):
                    raise
                name = "f" if stage == _IN_F else "h"
                try:
                    _raise_call(name, exc, np.empty((k, n)) if model.vectorized else np.empty(n))
                except ModelFunctionError as err:
                    raise ModelFunctionError(f"at step {iwork[_STEP]}: {err}") from err
            # otherwise f or h do not convert to the signature: the Python mode runs them
        else:
            if status == NEED_ROOT:  # a singular covariance: this series on in the Python mode
                first = int(iwork[_SERIES])
            elif status != OK:
                d = n if status in (F_SHAPE, F_NONFINITE) else m
                _raise_status(status, int(iwork[_STEP]), iwork, errval, np.empty((k, n)), d, model)
            else:
                first = N
    if first < N:
        _python_mode(first, model, zs, us, Q3, R3, pts, w, xang, zang, m0, P0, outs, loglik, last_mean,
                     last_cov, iwork)
    return means, covs, pmeans, pcovs, innov, icovs, cross, loglik, last_mean, last_cov


def _python_mode(first, model, zs, us, Q3, R3, pts, w, xang, zang, m0, P0, outs, loglik, last_mean,
                 last_cov, iwork):
    """Series ``first..N-1`` with the loop in Python (see the module notes)."""
    N, T, m = zs.shape
    k, n = pts.shape
    f, h, vectorized = model.f, model.h, model.vectorized
    means, covs, pmeans, pcovs, innov, icovs, cross = outs
    angles = np.concatenate([xang, zang])
    X, Y, Xh, Z = np.empty((k, n)), np.empty((k, n)), np.empty((k, n)), np.empty((k, m))
    bel = np.empty((4 * n + 2, n))
    scr = _scratch(k, n, m)
    errval = np.zeros(m * m + 1)
    for s in range(first, N):
        zs_s = zs[s]
        means_s, covs_s, pmeans_s, pcovs_s = means[s], covs[s], pmeans[s], pcovs[s]
        innov_s, icovs_s, cross_s = innov[s], icovs[s], cross[s]
        errval[-1] = 0.0
        if _py_start(m0, P0, pts, bel, X) != OK:
            _root_points(0, bel[0], bel[1:n + 1], pts, X)
        for t in range(T):
            u = None if us is None else us[s, t]
            try:
                Yt = _evaluate("f", f, X, Y, u, vectorized)
            except ModelFunctionError as exc:
                raise ModelFunctionError(f"at step {t}: {exc}") from exc
            status = _py_after_f(t, Yt, X, Q3, pts, w, angles, bel, Xh, pmeans_s, pcovs_s, cross_s, scr, iwork)
            if status == NEED_ROOT:
                _root_points(t, bel[n + 1], bel[n + 2:2 * n + 2], pts, Xh)
            elif status != OK:
                _raise_status(status, t, iwork, errval, X, n, model)
            try:
                Zt = _evaluate("h", h, Xh, Z, None, vectorized)
            except ModelFunctionError as exc:
                raise ModelFunctionError(f"at step {t}: {exc}") from exc
            iwork[_STEP] = t
            status = _py_after_h(t, Zt, Xh, R3, zs_s, pts, w, angles, bel, X, means_s, covs_s, innov_s,
                                 icovs_s, scr, iwork, errval)
            if status == NEED_ROOT:
                _root_points(t + 1, bel[0], bel[1:n + 1], pts, X)
            elif status != OK:
                _raise_status(status, t, iwork, errval, Xh, m, model)
        loglik[s] = errval[-1]
        last_mean[s] = bel[0]
        last_cov[s] = bel[1:n + 1]


def _result(fields):
    means, covs, pmeans, pcovs, innov, icovs, _, loglik, last_mean, last_cov = fields
    kept = [a if a.shape[1] else None for a in (means, covs, pmeans, pcovs, innov, icovs)]
    return FilterResult(*kept, loglik, last_mean, last_cov)


def filter(lin, model, prior, zs, us, keep) -> FilterResult:
    """The sigma-point filter over N series (see the module notes); results carry the N axis."""
    return _result(_forward(lin, model, prior, zs, us, keep, with_cross=False))


def smooth(lin, model, prior, zs, us) -> SmoothResult:
    """The sigma-point RTS smoother over N series; results carry the N axis."""
    fields = _forward(lin, model, prior, zs, us, "all", with_cross=True)
    means, covs, pmeans, pcovs, _, _, cross = fields[:7]
    N, T, n = means.shape
    sm_means, sm_covs = np.empty_like(means), np.empty_like(covs)
    sm_means[:, -1], sm_covs[:, -1] = means[:, -1], covs[:, -1]
    gains = np.empty((N, T - 1, n, n))
    xang = np.array(model.state_angles, dtype=np.bool_)
    pos, given = np.array([0, T - 2, 0], dtype=np.int64), np.empty((n, n))
    while _rts(means, covs, pmeans, pcovs, cross, xang, sm_means, sm_covs, gains, pos, given):
        s, j = pos[0], pos[1]  # a singular prediction: the minimum-norm gain, as kalman.rts_step
        given[:] = np.linalg.lstsq(pcovs[s, j + 1], cross[s, j + 1].T, rcond=None)[0].T
        pos[2] = 1
    check_smoothed(sm_means, sm_covs)
    return SmoothResult(sm_means, sm_covs, gains, _result(fields))
