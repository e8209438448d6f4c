r"""The compiled mirror of :mod:`gaussfuse.kalman`: predict, update, the RTS step, once.

Every compiled filter and smoother is a loop (:mod:`.linear`,
:mod:`.sigma_points`) around these functions, which compute what
:func:`gaussfuse.kalman.predict`, :func:`~gaussfuse.kalman.update`,
:func:`~gaussfuse.kalman.rts_step` and :func:`~gaussfuse.kalman.check_finite`
compute, in the same order of operations, so that the two paths agree to
round-off (the tests hold them to 1e-10):

* :func:`predict` -- :math:`m^- = A m + b`, :math:`P^- = \mathrm{sym}(A P A^\top + Q)`;
* :func:`update` -- the Joseph form over the observed components, with the
  Gaussian log-density of the innovation;
* :func:`smoother_gain` and :func:`rts_step` -- the RTS gain
  :math:`G = C (P^-)^{-1}` (a Cholesky solve) and the backward step;
* :func:`not_finite` -- the overflow check.

They write into arrays the caller owns: outputs passed in, and scratch in a
:class:`Work` (made by :func:`workspace`), so that a loop allocates nothing
per step. The products are :mod:`._dense`'s: loops for a small state, BLAS
for a large one.
Failures are returned, never raised (compiled code cannot raise the
readable path's exceptions): :func:`update` returns ``ok = False`` for an
innovation covariance that is not positive definite, :func:`smoother_gain`
for a singular prediction (the caller then takes the least-squares gain in
Python, as ``kalman.rts_step`` does), and :func:`not_finite` flags an
overflow. The loops record them in a :class:`Failures` and
:func:`raise_failure` raises what the readable path would.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from .._linalg import shown
from ..errors import ReadablePath, not_finite as not_finite_message
from ..inference.results import FilterResult
from ..kalman import _S_NAME, _innovation_error
from ._jit import jit
from ._dense import (abs_congruence_diagonal, cho_solve, cholesky, clip_variances, congruence, matmul,
                     negative_variance, roundoff_pivot)

__all__ = ["Work", "workspace", "SqrtWork", "sqrt_workspace", "tria", "predict_sqrt", "update_sqrt", "square",
           "SqrtBack", "sqrt_back_workspace", "joint_factor", "rts_back", "downdate", "times_factor",
           "not_finite_factor", "at", "predict", "predict_mean", "update", "innovate", "gain_mean", "log_density",
           "nis", "copy1", "copy2", "Fixed", "fixed", "hold_fixed", "steady_update", "settled", "smoother_gain", "rts_step", "rts_mean", "wrap",
           "not_finite",
           "not_finite_mean", "Failures", "failures", "raise_failure", "OK", "NOT_POSITIVE_DEFINITE",
           "PREDICTED_NOT_FINITE", "FILTERED_NOT_FINITE", "LOG_2PI", "Outputs", "outputs", "filter_result"]

LOG_2PI = math.log(2.0 * math.pi)
_TWO_PI = 2.0 * math.pi
_JIT = {"nogil": True, "error_model": "numpy"}
_EPS = float(np.finfo(np.float64).eps)
_ZERO_COLUMN = -1e9  # tria's mark for a column of zeros, below every binary exponent


class Work(NamedTuple):
    """Scratch of one series' steps, for n states and m measurement components.

    The names are those of kalman.update and kalman.rts_step; ``_o`` marks
    the observed components (the first ``|o|`` rows are used).
    """

    pred_z: np.ndarray  # (m,)    H m + d
    HP: np.ndarray      # (m, n)  H P⁻
    obs: np.ndarray     # (m,)    int64: the observed components
    H_o: np.ndarray     # (m, n)
    R_o: np.ndarray     # (m, m)
    v: np.ndarray       # (m,)    the observed innovation
    S: np.ndarray       # (m, m)  S_oo
    L: np.ndarray       # (m, m)  its Cholesky factor
    Kt: np.ndarray      # (m, n)  Kᵀ = S⁻¹ H_o P⁻
    K: np.ndarray       # (n, m)
    KR: np.ndarray      # (n, m)  K R_oo
    white: np.ndarray   # (m,)    L⁻¹ v
    A1: np.ndarray      # (n, n)  I - K H_o; in predict A P; in rts_step the cross-covariance
    A2: np.ndarray      # (n, n)  products
    A3: np.ndarray      # (n, n)
    Ln: np.ndarray      # (n, n)  the Cholesky factor of P⁻ (smoother gain)
    diff: np.ndarray    # (n,)


@register_jitable
def workspace(n, m):
    """A :class:`Work` for n states and m measurement components (in Python or compiled code)."""
    return Work(np.empty(m), np.empty((m, n)), np.empty(m, dtype=np.int64), np.empty((m, n)), np.empty((m, m)),
                np.empty(m), np.empty((m, m)), np.zeros((m, m)), np.empty((m, n)), np.empty((n, m)),
                np.empty((n, m)), np.empty(m), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)),
                np.zeros((n, n)), np.empty(n))


# ---------------------------------------------------------------------------
# _linalg.wrap_angle
# ---------------------------------------------------------------------------


@jit(inline="always", **_JIT)
def at(a, k):
    """``a[k]``, or ``a[0]`` for a model matrix in force at every step (leading axis of length 1)."""
    return a[k if a.shape[0] > 1 else 0]


@jit(inline="always", **_JIT)
def wrap(a):
    """_linalg.wrap_angle: ``(a + π) % 2π - π``, with NumPy's (Python's) floating modulo."""
    w = (a + math.pi) % _TWO_PI - math.pi
    return w - _TWO_PI if w >= math.pi else w


# ---------------------------------------------------------------------------
# kalman.predict, kalman.update, kalman.rts_step, kalman.check_finite
# ---------------------------------------------------------------------------


@jit(inline="always", **_JIT)
def predict(w, mean, cov, A, Q, b, pred_mean, pred_cov):
    r"""kalman.predict: :math:`m^- = A m + b`, :math:`P^- = \mathrm{sym}(A P A^\top + Q)`.

    Parameters
    ----------
    w : Work
    mean, cov : arrays of shape (n,), (n, n)
    A, Q : arrays of shape (n, n)
    b : array of shape (n,)
        The offset (zeros for none: adding 0 changes nothing).
    pred_mean, pred_cov : arrays of shape (n,), (n, n)
        Written.

    Notes
    -----
    .. math::

        m^- = A m + b, \qquad P^- = \tfrac12 (X + X^\top), \quad X = (A P) A^\top + Q.

    Leaves :math:`A P` in ``w.A1``: :math:`C^\top` of the smoother gain
    (:func:`smoother_gain`).
    """
    n = mean.shape[0]
    predict_mean(mean, A, b, pred_mean)
    congruence(A, cov, Q, pred_cov, w.A1, n, n)      # A P in w.A1 (the smoother gain's Cᵀ)
    if negative_variance(pred_cov, n):  # round-off of a zero variance, on the terms' scale |A| |P| |A|ᵀ + |Q|
        abs_congruence_diagonal(A, cov, w.diff, n, n, False)
        for j in range(n):
            w.diff[j] += abs(Q[j, j])
        clip_variances(pred_cov, w.diff, n)


@jit(inline="always", **_JIT)
def update(w, mean, cov, z, H, R, d, angles, post_mean, post_cov, innovation, S_full):
    r"""kalman.update: condition ``N(mean, cov)`` on the observed components of z (Joseph form).

    Parameters
    ----------
    w : Work
    mean, cov : arrays of shape (n,), (n, n)
        The prediction :math:`(m^-, P^-)`.
    z : array of shape (m,)
        NaN components are missing.
    H, R : arrays of shape (m, n), (m, m)
    d : array of shape (m,)
        The measurement offset (zeros for none).
    angles : bool array of shape (m,)
        Components whose innovation is wrapped to [-π, π).
    post_mean, post_cov, innovation, S_full : arrays of shape (n,), (n, n), (m,), (m, m)
        Written: the posterior, ``z - (H m + d)`` (NaN where missing) and
        ``S = sym(H P Hᵀ + R)`` over all m components.

    Returns
    -------
    ok : bool
        False when ``S_oo`` is not positive definite, to round-off (``w.S`` then holds it).
    loglik : float
        :math:`\log N(v_o; 0, S_{oo})`, 0.0 when nothing is observed.
    observed : int
        :math:`|o|`.

    Notes
    -----
    .. math::

        v &= z_o - (H_o m^- + d_o), \qquad S = H_o P^- H_o^\top + R_{oo} = L L^\top, \\
        K^\top &= S^{-1} H_o P^-, \qquad m = m^- + K v, \\
        P &= \mathrm{sym}\left((I - K H_o) P^- (I - K H_o)^\top + K R_{oo} K^\top\right), \\
        \ell &= -\tfrac12 \left(\lVert L^{-1} v \rVert^2 + 2 \textstyle\sum_i \log L_{ii}
                + |o| \log 2\pi\right).

    With nothing observed the prediction is returned unchanged.
    """
    n = mean.shape[0]
    m = z.shape[0]
    mo = innovate(w, mean, z, H, d, angles, innovation)
    congruence(H, cov, R, S_full, w.HP, m, n)        # H P⁻ in w.HP, S = sym(H P⁻ Hᵀ + R)
    if mo == 0:
        copy1(post_mean, mean)
        copy2(post_cov, cov)
        return True, 0.0, mo
    # The observed block: H_o, R_oo, v, S_oo, and Kᵀ ← H_o P⁻.
    for a in range(mo):
        oa = w.obs[a]
        w.v[a] = innovation[oa]
        for j in range(n):
            w.H_o[a, j] = H[oa, j]
            w.Kt[a, j] = w.HP[oa, j]
        for b in range(mo):
            w.R_o[a, b] = R[oa, w.obs[b]]
            w.S[a, b] = S_full[oa, w.obs[b]]
    if not cholesky(w.S, w.L, mo) or roundoff_pivot(w.L, w.S, mo):  # as kalman.gain's cholesky(resolved=True)
        return False, 0.0, mo
    cho_solve(w.L, w.Kt, mo, n)              # Kᵀ = S⁻¹ H_o P⁻
    gain_mean(w.Kt, w.v, mean, post_mean, mo)  # m⁻ + K v
    for i in range(n):
        for a in range(mo):
            w.K[i, a] = w.Kt[a, i]
    matmul(w.K, w.H_o, w.A1, n, mo, n)               # I - K H_o
    for i in range(n):
        for j in range(n):
            w.A1[i, j] = (1.0 if i == j else 0.0) - w.A1[i, j]
    congruence(w.K, w.R_o, None, w.A3, w.KR, n, mo)  # K R_oo Kᵀ
    congruence(w.A1, cov, w.A3, post_cov, w.A2, n, n)  # (I - K H_o) P⁻ (I - K H_o)ᵀ + K R_oo Kᵀ
    if negative_variance(post_cov, n):  # on the scale |I - K H| |P⁻| |I - K H|ᵀ + |K| |R| |K|ᵀ
        abs_congruence_diagonal(w.A1, cov, w.diff, n, n, False)
        abs_congruence_diagonal(w.K, w.R_o, w.diff, n, mo, True)
        clip_variances(post_cov, w.diff, n)
    return True, log_density(w.L, w.v, w.white, mo), mo


# ---------------------------------------------------------------------------
# The square-root form: kalman.predict_sqrt, kalman.update_sqrt
# ---------------------------------------------------------------------------


class SqrtWork(NamedTuple):
    """Scratch of one series' square-root steps (names as in kalman.update_sqrt).

    For n states, m measurement components and k extra noise columns (a
    sigma-point regression's residuals, :func:`sqrt_workspace`).
    """

    M: np.ndarray    # (n + m, 2n + m + k) the pre-array, triangularised in place
    T: np.ndarray    # (n + m, n + m) its lower-triangular result
    u: np.ndarray    # (2n + m + k,)  a Householder vector
    HL: np.ndarray   # (m, n)     H L⁻
    LRo: np.ndarray  # (m, m)     the factor of R_oo
    V: np.ndarray    # (n + m, k) the columns to downdate by
    v: np.ndarray    # (n + m,)   one of them, turned by the rotations
    order: np.ndarray  # (m,) int  the measurements' pivot order (pivot_order)
    B: np.ndarray    # (m, n + m)  the measurements' rows of the pre-array, to start again from in that order


@register_jitable
def sqrt_workspace(n, m, k=0):
    """A :class:`SqrtWork` for n states, m measurement components and k extra noise columns."""
    c = 2 * n + m + k
    return SqrtWork(np.zeros((n + m, c)), np.zeros((n + m, n + m)), np.empty(c), np.empty((m, n)),
                    np.zeros((m, m)), np.zeros((n + m, k)), np.empty(n + m), np.empty(m, dtype=np.int64),
                    np.empty((m, n + m)))


@register_jitable(**_JIT)
def _scaled_norm(W, r, lo, hi):
    """The norm of ``W[r, lo:hi]``, scaled by its largest entry so that it neither overflows nor underflows."""
    top = 0.0
    for j in range(lo, hi):
        top = max(top, abs(W[r, j]))
    if top == 0.0:
        return 0.0
    ss = 0.0
    for j in range(lo, hi):
        t = W[r, j] / top
        ss += t * t
    return top * math.sqrt(ss)


@register_jitable(**_JIT)
def in_pivot_order(L, k):
    """_linalg.in_pivot_order of ``L[:k, :k]``."""
    for i in range(k - 1):
        for r in range(i + 1, k):
            tail = _scaled_norm(L, r, i, k)
            if tail > 0.0 and (L[i, i] <= 0.0 or math.frexp(tail)[1] > math.frexp(L[i, i])[1]):
                return False
    return True


@register_jitable(**_JIT)
def pivot_order(M, rows, cols, W, order):
    """_linalg.pivot_order of ``M[:rows, :cols]`` into ``order[:rows]`` (W, at least rows × cols, is scratch);
    returns whether the order moves a row."""
    for r in range(rows):
        order[r] = r
        for j in range(cols):
            W[r, j] = M[r, j]
    for i in range(rows):  # order[i:] are left, in their order
        best, pick, size = -(2**31), i, 0.0
        for a in range(i, rows):
            x = _scaled_norm(W, order[a], 0, cols)
            b = math.frexp(x)[1] if x > 0.0 else -(2**31)
            if b > best:
                best, pick, size = b, a, x
        chosen = order[pick]
        for a in range(pick, i, -1):  # the chosen one to place i, the others keeping their order
            order[a] = order[a - 1]
        order[i] = chosen
        if size == 0.0:
            break
        for a in range(i + 1, rows):
            r = order[a]
            dot = 0.0
            for j in range(cols):
                dot += W[r, j] * (W[chosen, j] / size)
            for j in range(cols):
                W[r, j] -= dot * (W[chosen, j] / size)
    for r in range(rows):
        if order[r] != r:
            return True
    return False


@register_jitable(**_JIT)
def downdate(L, V, q, p, v):
    r"""_linalg.downdate in place: ``L[:q, :q]`` becomes the factor of :math:`L L^\top - V V^\top`, ``V = V[:q, :p]``.

    The same hyperbolic rotations in the "mixed" form, column by column of
    V (copied into `v`, so V is left as it is), with the same floor: a
    component :math:`v_k` within :math:`8 q \epsilon` of its standard
    deviation is left alone. Returns False where a pivot :math:`\rho^2 \le 0`
    (the readable path then factors the difference itself, or raises naming
    the matrix when it is not positive semi-definite).
    """
    floor = 8 * q * _EPS
    for c in range(p):
        for i in range(q):
            v[i] = V[i, c]
        for k in range(q):
            norm = 0.0
            for j in range(k + 1):
                norm += L[k, j] * L[k, j]
            if abs(v[k]) <= floor * math.sqrt(norm):
                continue
            a = L[k, k]
            rho2 = (a - v[k]) * (a + v[k])
            if not rho2 > 0.0:
                return False
            rho = math.sqrt(rho2)
            cos = rho / a
            sin = v[k] / a
            L[k, k] = rho
            for i in range(k + 1, q):
                L[i, k] = (L[i, k] - sin * v[i]) / cos
                v[i] = cos * v[i] - sin * L[i, k]
    return True


@register_jitable(**_JIT)
def tria(M, rows, cols, u, L):
    r"""_linalg.tria: ``L`` (``rows`` × ``rows``, lower, diagonal >= 0) with :math:`L L^\top = M M^\top`.

    Householder reflections from the right make ``M[:rows, :cols]``
    lower triangular in place (the LQ factorisation, which is the QR of
    :math:`M^\top` that LAPACK's ``geqrf`` computes); its first ``rows``
    columns are L, with each column's sign made that of a non-negative
    diagonal. The nonzero columns are first put in decreasing order of the
    binary exponent of their largest entry, stably, zero columns last, as
    the readable tria does. ``u`` (length ``cols``) holds those
    exponents, then a reflection's vector.
    """
    for j in range(cols):
        big = 0.0
        for r in range(rows):
            big = max(big, abs(M[r, j]))
        u[j] = math.frexp(big)[1] if big > 0.0 else _ZERO_COLUMN
    for j in range(1, cols):  # insertion sort by swaps, stable: decreasing exponents, zero columns last
        k = j
        while k > 0 and u[k - 1] < u[k]:
            u[k - 1], u[k] = u[k], u[k - 1]
            for r in range(rows):
                M[r, k - 1], M[r, k] = M[r, k], M[r, k - 1]
            k -= 1
    for i in range(rows):
        if i < cols:
            scale = 0.0
            for j in range(i, cols):
                scale = max(scale, abs(M[i, j]))
            if scale > 0.0:
                ss = 0.0
                for j in range(i, cols):
                    t = M[i, j] / scale
                    ss += t * t
                norm = scale * math.sqrt(ss)
                alpha = -norm if M[i, i] >= 0.0 else norm
                for j in range(i, cols):
                    u[j] = M[i, j]
                u[i] -= alpha
                vtv = norm * (norm + abs(M[i, i])) * 2.0
                for r in range(i, rows):
                    dot = 0.0
                    for j in range(i, cols):
                        dot += u[j] * M[r, j]
                    f = 2.0 * dot / vtv
                    for j in range(i, cols):
                        M[r, j] -= f * u[j]
        for r in range(rows):
            L[r, i] = M[r, i] if r >= i and i < cols else 0.0
        if L[i, i] < 0.0:
            for r in range(i, rows):
                L[r, i] = -L[r, i]


@register_jitable(**_JIT)
def times_factor(A, L, out, col):
    """``out[:, col:col + n] = A L`` for a lower-triangular L (n, n): the zeros above its diagonal are skipped."""
    n = L.shape[0]
    for i in range(A.shape[0]):
        for j in range(n):
            s = 0.0
            for k in range(j, n):
                s += A[i, k] * L[k, j]
            out[i, col + j] = s


@jit(inline="always", **_JIT)
def predict_sqrt(sw, mean, factor, A, Q_factor, b, pred_mean, pred_factor):
    r"""kalman.predict_sqrt: :math:`m^- = A m + b`, :math:`L^- = \mathrm{tria}[A L, L_Q]`, `Q_factor` (n, q)."""
    n = mean.shape[0]
    q = Q_factor.shape[1]
    predict_mean(mean, A, b, pred_mean)
    times_factor(A, factor, sw.M, 0)
    for i in range(n):
        for j in range(q):
            sw.M[i, n + j] = Q_factor[i, j]
    tria(sw.M, n, n + q, sw.u, pred_factor)


@jit(inline="always", **_JIT)
def update_sqrt(w, sw, mean, factor, z, H, R_factor, D, d, angles, post_mean, post_factor, innovation):
    r"""kalman.update_sqrt: the pre-array ``[[L_R,o, H_o L⁻], [0, L⁻]]`` triangularised.

    `R_factor` is (m, r); `D` (m, p) the columns :math:`D_R` to take away
    (p = 0 for none): the post-array is downdated by :math:`[D_{R,o};\, 0]`
    before its blocks are read. Returns ``(ok, loglik, mo)``; ``ok`` is
    False when :math:`L_S` has a pivot at round-off of its row (the innovation covariance of
    the observed components may be singular: kalman.sqrt_gain decides) or the downdate fails. Leaves :math:`L_S` in ``w.L``, :math:`\bar K^\top` in ``w.Kt``
    (what :func:`hold_fixed` keeps) and the whitened innovation in ``w.white``.
    """
    n = mean.shape[0]
    m = z.shape[0]
    mo = innovate(w, mean, z, H, d, angles, innovation)
    times_factor(H, factor, sw.HL, 0)
    if mo == 0:
        copy1(post_mean, mean)
        copy2(post_factor, factor)
        return True, 0.0, mo
    # the factor of R_oo: tria of the observed rows of L_R
    r = R_factor.shape[1]
    for a in range(mo):
        for b in range(r):
            sw.M[a, b] = R_factor[w.obs[a], b]
    tria(sw.M, mo, r, sw.u, sw.LRo)
    q = mo + n
    for r in range(q):
        for c in range(q):
            sw.M[r, c] = 0.0
    for a in range(mo):
        for b in range(mo):
            sw.M[a, b] = sw.LRo[a, b]
        for j in range(n):
            sw.M[a, mo + j] = sw.HL[w.obs[a], j]
    for i in range(n):
        for j in range(n):
            sw.M[mo + i, mo + j] = factor[i, j]
    for a in range(mo):  # a copy of the measurements' rows, to start again from in another order
        for c in range(q):
            sw.B[a, c] = sw.M[a, c]
    tria(sw.M, q, q, sw.u, sw.T)
    moved = not in_pivot_order(sw.T, mo)
    if moved:  # the measurements in the order of column pivoting (see kalman.sqrt_gain), and again
        pivot_order(sw.B, mo, q, sw.T, sw.order)
        for a in range(mo):
            for c in range(q):
                sw.M[a, c] = sw.B[sw.order[a], c]
        for i in range(n):
            for c in range(q):
                sw.M[mo + i, c] = factor[i, c - mo] if c >= mo else 0.0
        tria(sw.M, q, q, sw.u, sw.T)
    else:
        for a in range(mo):
            sw.order[a] = a
    p = D.shape[1]
    if p > 0:
        for i in range(q):
            for c in range(p):
                sw.V[i, c] = D[w.obs[sw.order[i]], c] if i < mo else 0.0
        if not downdate(sw.T, sw.V, q, p, sw.v):
            return False, 0.0, mo
    for a in range(mo):
        row = 0.0
        for b in range(a + 1):
            row += sw.T[a, b] * sw.T[a, b]
        if not sw.T[a, a] > 8 * mo * _EPS * math.sqrt(row):  # _linalg.zero_pivots: the readable path decides
            return False, 0.0, mo
    for i in range(n):
        for j in range(n):
            post_factor[i, j] = sw.T[mo + i, mo + j]
    if moved:  # back to the measurements' order: [L_S; K̄] turned by one orthogonal Θ (as kalman.sqrt_gain)
        for a in range(mo):
            for b in range(mo):
                sw.M[sw.order[a], b] = sw.T[a, b]
        for i in range(n):
            for b in range(mo):
                sw.M[mo + i, b] = sw.T[mo + i, b]
        tria(sw.M, q, mo, sw.u, sw.T)
    for a in range(mo):
        w.v[a] = innovation[w.obs[a]]
        for b in range(mo):
            w.L[a, b] = sw.T[a, b]        # L_S
        for i in range(n):
            w.Kt[a, i] = sw.T[mo + i, a]  # K̄ᵀ
    loglik = log_density(w.L, w.v, w.white, mo)  # w.white = L_S⁻¹ v
    gain_mean(w.Kt, w.white, mean, post_mean, mo)  # m = m⁻ + K̄ L_S⁻¹ v
    return True, loglik, mo


class SqrtBack(NamedTuple):
    """Scratch of :func:`joint_factor` and :func:`rts_back` for n states and k extra noise columns (names as in kalman.rts_step_sqrt)."""

    M: np.ndarray    # (2n, 2n + k) the joint pre-array [[L_Q, A L_k], [0, L_k]], triangularised in place
    T: np.ndarray    # (2n, 2n)    its lower-triangular result [[L⁻, 0], [Y, X]]
    u: np.ndarray    # (2n + k,)   a Householder vector
    rhs: np.ndarray  # (n, 2n + 1) [m^s - m⁻, L^s, I], then (L⁻)⁻¹ of it
    N: np.ndarray    # (n, 2n)     [X, G L^s], triangularised in place
    pm: np.ndarray   # (n,)        m⁻
    V: np.ndarray    # (2n, k)     the columns [D_Q; 0] to downdate by
    v: np.ndarray    # (2n,)       one of them, turned by the rotations


@register_jitable
def sqrt_back_workspace(n, k=0):
    """A :class:`SqrtBack` for n states and k extra noise columns."""
    return SqrtBack(np.zeros((2 * n, 2 * n + k)), np.zeros((2 * n, 2 * n)), np.empty(2 * n + k),
                    np.empty((n, 2 * n + 1)), np.zeros((n, 2 * n)), np.empty(n), np.zeros((2 * n, k)),
                    np.empty(2 * n))


@jit(inline="always", **_JIT)
def joint_factor(bw, filt_factor, A, Q_factor, D):
    r"""kalman.joint_factor's triangularisation, into ``bw.T``: :math:`[[L^-, 0], [Y, X]]`.

    :math:`\mathrm{tria}[[L_Q, A L_k], [0, L_k]]` with `Q_factor` (n, q),
    downdated by :math:`[D_Q;\, 0]` with `D` (n, p; p = 0 for none).
    Returns False when the downdate fails (the readable path then raises).
    """
    n = filt_factor.shape[0]
    q = Q_factor.shape[1]
    M = bw.M
    times_factor(A, filt_factor, M, q)
    for i in range(n):
        for j in range(q):
            M[i, j] = Q_factor[i, j]
            M[n + i, j] = 0.0
        for j in range(n):
            M[n + i, q + j] = filt_factor[i, j]
    tria(M, 2 * n, q + n, bw.u, bw.T)
    p = D.shape[1]
    if p == 0:
        return True
    for i in range(2 * n):
        for c in range(p):
            bw.V[i, c] = D[i, c] if i < n else 0.0
    return downdate(bw.T, bw.V, 2 * n, p, bw.v)


@jit(inline="always", **_JIT)
def rts_back(bw, filt_mean, next_mean, next_factor, angles, mean, factor, gain):
    r"""The backward step from the joint factor in ``bw.T`` and the prediction's mean in ``bw.pm``.

    :math:`G_k = Y (L^-)^{-1}`, :math:`m^s_k = m_k + G_k (m^s_{k+1} - m^-_{k+1})`
    and :math:`L^s_k = \mathrm{tria}[X, G_k L^s_{k+1}]`, by one forward
    substitution with :math:`L^-`. Returns False when :math:`L^-` has a zero pivot, to round-off
    (:func:`gaussfuse._linalg.zero_pivots`).
    """
    n = filt_mean.shape[0]
    for i in range(n):
        row = 0.0
        for k in range(i + 1):
            row += bw.T[i, k] * bw.T[i, k]
        if not bw.T[i, i] > 8.0 * n * _EPS * np.sqrt(row):
            return False
    rhs = bw.rhs
    for i in range(n):
        diff = next_mean[i] - bw.pm[i]
        rhs[i, 0] = wrap(diff) if angles[i] else diff
        for j in range(n):
            rhs[i, 1 + j] = next_factor[i, j]
            rhs[i, 1 + n + j] = 1.0 if i == j else 0.0
    for c in range(2 * n + 1):  # (L⁻)⁻¹ [m^s - m⁻, L^s, I]: forward substitution
        for i in range(n):
            s = rhs[i, c]
            for k in range(i):
                s -= bw.T[i, k] * rhs[k, c]
            rhs[i, c] = s / bw.T[i, i]
    N = bw.N
    for i in range(n):  # Y (L⁻)⁻¹ [...]: the step of the mean, G L^s and G
        for c in range(2 * n + 1):
            s = 0.0
            for k in range(n):
                s += bw.T[n + i, k] * rhs[k, c]
            if c == 0:
                mean[i] = filt_mean[i] + s
            elif c <= n:
                N[i, n + c - 1] = s
            else:
                gain[i, c - n - 1] = s
        for j in range(n):
            N[i, j] = bw.T[n + i, n + j]
    tria(N, n, 2 * n, bw.u, factor)  # L^s_k = tria[X, G L^s_{k+1}]
    return True


@jit(inline="always", **_JIT)
def square(factor, cov):
    """``cov = sym(L Lᵀ)`` (exactly symmetric: each pair of entries is computed once)."""
    n = factor.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = 0.0
            for k in range(j + 1):
                s += factor[i, k] * factor[j, k]
            cov[i, j] = s
            cov[j, i] = s


@jit(inline="always", **_JIT)
def not_finite_factor(mean, factor, loglik):
    """kalman.check_finite(..., factor=True): the mean, `loglik` and the trace of ``L Lᵀ`` (its squared entries)."""
    acc = loglik * 0.0
    n = mean.shape[0]
    tr = 0.0
    for i in range(n):
        acc += mean[i] * 0.0
        for j in range(n):
            tr += factor[i, j] * factor[i, j]
    acc += tr * 0.0
    return acc != acc


@jit(inline="always", **_JIT)
def innovate(w, mean, z, H, d, angles, innovation):
    """The innovation ``z - (H m + d)`` (wrapped for angles, in `innovation`), and the observed components.

    Writes ``H m + d`` in ``w.pred_z`` and the indices of the components of
    z that are not NaN in ``w.obs``; returns how many, ``|o|``.
    """
    n = mean.shape[0]
    mo = 0
    for a in range(z.shape[0]):
        s = 0.0
        for j in range(n):
            s += H[a, j] * mean[j]
        s += d[a]
        w.pred_z[a] = s
        diff = z[a] - s
        innovation[a] = wrap(diff) if angles[a] else diff
        if z[a] == z[a]:  # not NaN
            w.obs[mo] = a
            mo += 1
    return mo


@jit(inline="always", **_JIT)
def gain_mean(Kt, v, mean, post_mean, mo):
    """``post_mean = mean + K v`` with ``Kᵀ`` in ``Kt[:mo]`` and the observed innovation ``v[:mo]``."""
    for i in range(mean.shape[0]):
        s = 0.0
        for a in range(mo):
            s += Kt[a, i] * v[a]
        post_mean[i] = mean[i] + s


@jit(inline="always", **_JIT)
def log_density(L, v, white, mo):
    r"""kalman's ``log_density(whiten(L, v), L)``: :math:`\log N(v; 0, L L^\top)` over the first `mo` components.

    The whitened innovation :math:`L^{-1} v` (forward substitution) goes to `white`.
    """
    quad = 0.0
    logdet = 0.0
    for a in range(mo):
        s = v[a]
        for b in range(a):
            s -= L[a, b] * white[b]
        s /= L[a, a]
        white[a] = s
        quad += s * s
        logdet += math.log(L[a, a])
    return -0.5 * (quad + 2.0 * logdet + mo * LOG_2PI)


@register_jitable(**_JIT)
def nis(w, z):
    """The normalised innovation squared of the update just made with `z`: ``|L⁻¹ v|²`` from ``w.white``; NaN if none."""
    mo = 0
    for a in range(z.shape[0]):
        if z[a] == z[a]:
            mo += 1
    if mo == 0:
        return np.nan
    total = 0.0
    for a in range(mo):
        total += w.white[a] * w.white[a]
    return total


@register_jitable(**_JIT)
def copy1(dst, src):
    """``dst[:] = src`` for vectors of one length."""
    for a in range(src.shape[0]):
        dst[a] = src[a]


@register_jitable(**_JIT)
def copy2(dst, src):
    """``dst[:, :] = src`` for matrices of one shape."""
    for a in range(src.shape[0]):
        for b in range(src.shape[1]):
            dst[a, b] = src[a, b]


class Fixed(NamedTuple):
    """kalman.SteadyState compiled: a fixed point of the covariance recursion, and what it reuses.

    For a time-invariant model, once an update returns the covariance the
    step's prediction started from, to round-off (:func:`settled`), every
    following step with the same observed components would compute the
    same prediction, gain and posterior covariance again, to round-off:
    :func:`steady_update` then computes the means only, with the gain and
    covariances held here (see kalman.SteadyState for the accuracy).
    """

    cov: np.ndarray       # (n, n)  the fixed-point posterior covariance
    pred_cov: np.ndarray  # (n, n)  its prediction
    Kt: np.ndarray        # (m, n)  Kᵀ over the observed components (leading rows)
    L: np.ndarray         # (m, m)  the Cholesky factor of S_oo
    S: np.ndarray         # (m, m)  S over all m components
    obs: np.ndarray       # (m,)    bool: the observed components
    gain: np.ndarray      # (n, n)  when smoothing: the smoother gain G = P Fᵀ (P⁻)⁻¹ between two held steps,
    #                                 or Cᵀ = F P for the least-squares gain when gain_failed[0]
    gain_failed: np.ndarray  # (1,) bool: P⁻ not positive definite (see smoother_gain)


@register_jitable
def fixed(n, m):
    """An empty :class:`Fixed` for n states and m measurement components."""
    return Fixed(np.empty((n, n)), np.empty((n, n)), np.empty((m, n)), np.empty((m, m)), np.empty((m, m)),
                 np.zeros(m, dtype=np.bool_), np.empty((n, n)), np.zeros(1, dtype=np.bool_))


@jit(inline="always", **_JIT)
def hold_fixed(fx, w, post_cov, pred_cov, S_full, z, mo):
    """Record the fixed point that :func:`update` has just reached (its scratch `w` and outputs)."""
    copy2(fx.cov, post_cov)
    copy2(fx.pred_cov, pred_cov)
    copy2(fx.S, S_full)
    copy2(fx.Kt[:mo], w.Kt[:mo])
    copy2(fx.L[:mo, :mo], w.L[:mo, :mo])
    for a in range(z.shape[0]):
        fx.obs[a] = z[a] == z[a]


@jit(inline="always", **_JIT)
def steady_update(fx, w, mean, z, H, d, angles, post_mean, innovation, factors=False):
    r""":func:`update` of the fixed point's prediction ``fx.pred_cov``, reusing its gain: the means only.

    With `factors` (the square-root form, whose :class:`Fixed` holds the
    factors, :math:`\bar K^\top` and :math:`L_S`), the mean is
    :math:`m^- + \bar K L_S^{-1} v`, as :func:`update_sqrt` computes it.

    Returns ``(reused, loglik)``; `reused` is False, and nothing is
    written, when the observed components of z are not the fixed point's
    (the caller then runs :func:`update`). The posterior covariance and S
    are ``fx.cov`` and ``fx.S``. The operations are :func:`update`'s, in its
    order, so the results are bitwise the same.
    """
    for a in range(z.shape[0]):
        if (z[a] == z[a]) != fx.obs[a]:
            return False, 0.0
    mo = innovate(w, mean, z, H, d, angles, innovation)
    for a in range(mo):
        w.v[a] = innovation[w.obs[a]]
    if mo == 0:  # as update: the prediction, copied
        copy1(post_mean, mean)
        return True, 0.0
    loglik = log_density(fx.L, w.v, w.white, mo)
    gain_mean(fx.Kt, w.white if factors else w.v, mean, post_mean, mo)
    return True, loglik


@jit(inline="always", **_JIT)
def predict_mean(mean, A, b, pred_mean):
    """The mean half of :func:`predict`: :math:`m^- = A m + b`."""
    n = mean.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += A[i, j] * mean[j]
        pred_mean[i] = s + b[i]


@jit(inline="always", **_JIT)
def settled(new, old, tol):
    """kalman.settled: whether every entry of `new` is within `tol` of `old`, relative to its variances."""
    n = new.shape[0]
    for i in range(n):
        si = math.sqrt(abs(new[i, i]))
        for j in range(n):
            if not abs(new[i, j] - old[i, j]) <= tol * (si * math.sqrt(abs(new[j, j]))):
                return False
    return True


@jit(inline="always", **_JIT)
def smoother_gain(w, pred_cov, CT, gain):
    r"""The gain of kalman.rts_step: :math:`G = C (P^-)^{-1}`, as :math:`G^\top = (P^-)^{-1} C^\top`.

    Parameters
    ----------
    w : Work
    pred_cov : array of shape (n, n)
        :math:`P^-_{k+1}`.
    CT : array of shape (n, n)
        :math:`C^\top_{k+1} = A P_k` (from :func:`predict`, in ``w.A1``).
    gain : array of shape (n, n)
        Written.

    Returns
    -------
    bool
        False when :math:`P^-_{k+1}` is not positive definite, to round-off:
        the caller takes the minimum-norm least-squares gain, as
        kalman.rts_step does.
    """
    n = pred_cov.shape[0]
    if not cholesky(pred_cov, w.Ln, n) or roundoff_pivot(w.Ln, pred_cov, n):  # as _linalg.psd_solve
        return False
    copy2(w.A2, CT)
    cho_solve(w.Ln, w.A2, n, n)
    for i in range(n):
        for j in range(n):
            gain[i, j] = w.A2[j, i]
    return True


@jit(inline="always", **_JIT)
def rts_step(w, filt_mean, filt_cov, pred_mean, pred_cov, next_mean, next_cov, gain, angles, mean, cov):
    r"""kalman.rts_step, given the gain :math:`G_k` (:func:`smoother_gain`).

    Parameters
    ----------
    w : Work
    filt_mean, filt_cov : arrays of shape (n,), (n, n)
        :math:`(m_k, P_k)`.
    pred_mean, pred_cov : arrays of shape (n,), (n, n)
        :math:`(m^-_{k+1}, P^-_{k+1})`.
    next_mean, next_cov : arrays of shape (n,), (n, n)
        :math:`(m^s_{k+1}, P^s_{k+1})`.
    gain : array of shape (n, n)
    angles : bool array of shape (n,)
        State components whose difference :math:`m^s_{k+1} - m^-_{k+1}` is wrapped.
    mean, cov : arrays of shape (n,), (n, n)
        Written: :math:`(m^s_k, P^s_k)`.

    Notes
    -----
    .. math::

        m^s_k = m_k + G_k (m^s_{k+1} - m^-_{k+1}), \qquad
        P^s_k = \mathrm{sym}\left(P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top\right).
    """
    n = filt_mean.shape[0]
    rts_mean(w, filt_mean, pred_mean, next_mean, gain, angles, mean)
    for i in range(n):
        for j in range(n):
            w.A1[i, j] = next_cov[i, j] - pred_cov[i, j]
    congruence(gain, w.A1, filt_cov, cov, w.A2, n, n)  # sym(P + G (P^s - P⁻) Gᵀ)
    if negative_variance(cov, n):  # on the scale |P| + |G| (|P^s| + |P⁻|) |G|ᵀ
        for i in range(n):
            for j in range(n):
                w.A1[i, j] = abs(next_cov[i, j]) + abs(pred_cov[i, j])
        abs_congruence_diagonal(gain, w.A1, w.diff, n, n, False)
        for j in range(n):
            w.diff[j] += abs(filt_cov[j, j])
        clip_variances(cov, w.diff, n)


@jit(inline="always", **_JIT)
def rts_mean(w, filt_mean, pred_mean, next_mean, gain, angles, mean):
    """The mean half of :func:`rts_step`: :math:`m^s_k = m_k + G_k (m^s_{k+1} - m^-_{k+1})`."""
    n = filt_mean.shape[0]
    for j in range(n):
        diff = next_mean[j] - pred_mean[j]
        w.diff[j] = wrap(diff) if angles[j] else diff
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += gain[i, j] * w.diff[j]
        mean[i] = filt_mean[i] + s


@jit(inline="always", **_JIT)
def not_finite(mean, cov, loglik):
    """kalman.check_finite's test: True when the mean, the covariance or `loglik` holds inf or NaN.

    ``x · 0`` is 0 for a finite x and NaN otherwise, and a sum of zeros
    cannot overflow.
    """
    acc = loglik * 0.0
    n = mean.shape[0]
    for i in range(n):
        acc += mean[i] * 0.0
        for j in range(n):
            acc += cov[i, j] * 0.0
    return acc != acc


@jit(inline="always", **_JIT)
def not_finite_mean(mean, loglik):
    """:func:`not_finite` for the mean and `loglik` alone (a covariance known to be finite)."""
    acc = loglik * 0.0
    for i in range(mean.shape[0]):
        acc += mean[i] * 0.0
    return acc != acc


# ---------------------------------------------------------------------------
# Failures: recorded per series by the compiled loops, raised in Python
# ---------------------------------------------------------------------------

# READABLE: a square-root step that needs the readable path (a zero pivot, a downdate or an update that fails),
# which takes the least-squares step or raises the error, naming the matrix.
OK, NOT_POSITIVE_DEFINITE, PREDICTED_NOT_FINITE, FILTERED_NOT_FINITE, READABLE = 0, 1, 2, 3, 4


class Failures(NamedTuple):
    """Why each series stopped, if it did (written by the compiled loops).

    Attributes
    ----------
    code : int64 array of shape (N,)
        OK, NOT_POSITIVE_DEFINITE, PREDICTED_NOT_FINITE, FILTERED_NOT_FINITE,
        READABLE (or a kernel's own codes, above these).
    step : int64 array of shape (N,)
        The step it stopped at.
    size : int64 array of shape (N,)
        For NOT_POSITIVE_DEFINITE, the observed components ``|o|``.
    S : array of shape (N, m, m)
        For NOT_POSITIVE_DEFINITE, ``S_oo`` in its leading block.
    """

    code: np.ndarray
    step: np.ndarray
    size: np.ndarray
    S: np.ndarray


def failures(N: int, m: int) -> Failures:
    """An empty :class:`Failures` for N series with m measurement components."""
    return Failures(np.zeros(N, dtype=np.int64), np.zeros(N, dtype=np.int64), np.zeros(N, dtype=np.int64),
                    np.zeros((N, m, m)))


@jit(inline="always", **_JIT)
def record(fail, s, code, step):
    """Record in `fail` that series s stopped at `step` for `code`."""
    fail.code[s] = code
    fail.step[s] = step


@jit(inline="always", **_JIT)
def record_not_pd(fail, s, step, w, size):
    """Record an innovation covariance ``w.S[:size, :size]`` that is not positive definite.

    One holding inf or NaN is an overflow upstream: FILTERED_NOT_FINITE, as
    kalman.gain raises it.
    """
    record(fail, s, NOT_POSITIVE_DEFINITE, step)
    fail.size[s] = size
    for a in range(size):
        for b in range(size):
            fail.S[s, a, b] = w.S[a, b]
            if not math.isfinite(w.S[a, b]):
                record(fail, s, FILTERED_NOT_FINITE, step)


def where(s: int, step: int, series: int) -> str:
    """"at step k", or "in series s, at step k" for a batch of `series` series."""
    return f"in series {s}, at step {step}" if series > 1 else f"at step {step}"


def raise_failure(fail: Failures) -> None:
    """Raise the readable path's error for the first series that failed, if any.

    numpy.linalg.LinAlgError for an innovation covariance that is not
    positive definite (kalman.cholesky's message); FloatingPointError
    (kalman.check_finite's) for a belief that overflowed. Kernel-specific
    codes are the caller's to raise first.
    """
    stopped = np.flatnonzero(fail.code != OK)
    if stopped.size == 0:
        return
    s = int(stopped[0])
    code, step, N = int(fail.code[s]), int(fail.step[s]), fail.code.shape[0]
    if code == READABLE:
        raise ReadablePath(f"{where(s, step, N)}: the square-root step needs the readable path")
    if code == NOT_POSITIVE_DEFINITE:
        S = fail.S[s, :int(fail.size[s]), :int(fail.size[s])]
        raise _innovation_error(
            f"{where(s, step, N)}: {_S_NAME} is not positive definite, so it cannot be factorised: {shown(S)}", S)
    if code in (PREDICTED_NOT_FINITE, FILTERED_NOT_FINITE):
        stage = "predicted" if code == PREDICTED_NOT_FINITE else "filtered"
        raise FloatingPointError(f"{where(s, step, N)}: {not_finite_message(stage)}")
    raise RuntimeError(f"unexpected failure code {code} from a compiled kernel")  # pragma: no cover


# ---------------------------------------------------------------------------
# What a forward kernel writes
# ---------------------------------------------------------------------------


class Outputs(NamedTuple):
    """What the forward kernel writes, per series (see the module notes)."""

    means: np.ndarray            # (N, T or 0, n)
    covs: np.ndarray             # (N, T or 0, n, n)
    predicted_means: np.ndarray  # (N, T or 0, n)
    predicted_covs: np.ndarray   # (N, T or 0, n, n)
    innovations: np.ndarray      # (N, T or 0, m)
    innovation_covs: np.ndarray  # (N, T or 0, m, m)
    loglik: np.ndarray           # (N,)
    last_mean: np.ndarray        # (N, n)
    last_cov: np.ndarray         # (N, n, n)
    gains: np.ndarray            # (N, T - 1 or 0, n, n): G_k, or C_{k+1}ᵀ where failed
    failed: np.ndarray           # (N, T - 1 or 0) bool: P⁻_{k+1} not positive definite
    nis: np.ndarray              # (N, T or 0): vᵀ S⁻¹ v over the observed components, NaN with none
    factors: np.ndarray          # (N, T or 0, n, n): the square-root form's L_k
    predicted_factors: np.ndarray  # (N, T or 0, n, n): its L⁻_k
    leader: np.ndarray           # (N,) int64: a series with the same covariances at every step (s itself if none)


def outputs(N: int, T: int, n: int, m: int, keep: str, smoothing: bool, sqrt: bool = False) -> Outputs:
    """The :class:`Outputs` of N series of T steps: per-step arrays of length T where `keep` keeps them, else 0.

    With `sqrt`, the square-root form's factors too.
    """
    rows = 0 if keep == "last" else T
    crows = T if keep == "all" else 0
    frows = crows if sqrt else 0
    grows = T - 1 if smoothing else 0
    return Outputs(np.empty((N, rows, n)), np.empty((N, crows, n, n)), np.empty((N, rows, n)),
                   np.empty((N, crows, n, n)), np.empty((N, rows, m)), np.empty((N, crows, m, m)),
                   np.empty(N), np.empty((N, n)), np.empty((N, n, n)), np.empty((N, grows, n, n)),
                   np.zeros((N, grows), dtype=np.bool_), np.empty((N, rows)), np.empty((N, frows, n, n)),
                   np.empty((N, frows, n, n)), np.arange(N))


def filter_result(out: Outputs) -> FilterResult:
    """The FilterResult of a forward kernel's outputs (with the N axis); None for what was not kept."""
    per_step = (out.means, out.covs, out.predicted_means, out.predicted_covs, out.innovations, out.innovation_covs)
    return FilterResult(*(a if a.shape[1] else None for a in per_step), out.loglik, out.last_mean, out.last_cov,
                        nis=out.nis if out.nis.shape[1] else None,
                        cov_factors=out.factors if out.factors.shape[1] else None,
                        predicted_cov_factors=out.predicted_factors if out.predicted_factors.shape[1] else None)
