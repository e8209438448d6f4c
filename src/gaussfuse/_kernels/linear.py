r"""Compiled engine for the linear Kalman filter and RTS smoother (method ``"kf"``).

The per-step algebra is :mod:`gaussfuse.kalman` written out as loops over the
small dimensions, one compiled helper per readable function and under the
same name: :func:`predict`, :func:`update` (Joseph form, observed components
only), :func:`cholesky`, :func:`rts_step`, and :func:`smoother_gain` (the
gain of kalman.rts_step). A reader can put the two files side by side; the
tests hold them equal to 1e-10.

The arguments are laid out so that one compiled signature serves every case
(time-invariant or time-varying, with or without controls, any ``keep``,
filtering or smoothing):

* the model matrices are 3-D, read-only, C-contiguous float64 with a leading
  axis of length T (time-varying) or 1 (in force at every step);
* the control offsets ``b = B_k u_k`` are computed with NumPy before the
  kernel, shape (N or 1, T or 1, n); zeros (1, 1, n) without controls;
* every per-step output has the shape (N, T, ...) when kept and (N, 0, ...)
  when not, so ``keep="last"`` allocates nothing that grows with T; the
  smoother gains are (N, T - 1, n, n) when smoothing and (N, 0, n, n) when
  filtering;
* a failure (an innovation covariance that is not positive definite) stops
  that series and is reported in ``err`` (step, size) and ``err_S`` (the
  matrix), and the Python side raises ``numpy.linalg.LinAlgError``; a
  predicted or filtered belief that is not finite (an overflow) is reported
  in ``err`` (step, a negative code), and the Python side raises the readable
  path's ``FloatingPointError`` (:func:`gaussfuse.inference.check_finite`);
  the smoothed beliefs are checked after the backward pass.

The forward kernel filters and, when smoothing, computes each gain
``G_{k-1}`` at step k from the prediction's ``F_k P_{k-1}``; the backward
kernel is the RTS recursion. Series run in parallel (``prange`` over chunks
of series, one set of scratch arrays per chunk, nothing allocated per step).
Every kernel is compiled with :func:`._jit.jit`, cached on disk, so a new
process loads it instead of compiling it again.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import prange

from ..errors import not_finite
from ..inference.results import FilterResult, SmoothResult, check_smoothed
from ._jit import jit, parallel_launch
from ._nrt import borrow as _borrow, readonly as _readonly

__all__ = ["filter", "smooth"]

_JIT = {"nogil": True, "error_model": "numpy"}  # and cached on disk (see _jit.jit)
_INLINE = dict(_JIT, inline="always")  # the step helpers are inlined into the loops
_LOG_2PI = math.log(2.0 * math.pi)
_S_NAME = "the innovation covariance S = H P Hᵀ + R"
_CHUNKS_PER_THREAD = 16  # chunks of series per thread, handed out dynamically, for balance
# err[s, 1] when a belief overflowed (otherwise the size of the S that could not be factorised)
PREDICTED_NOT_FINITE, FILTERED_NOT_FINITE = -1, -2

# ---------------------------------------------------------------------------
# Small dense algebra: explicit loops over a handful of rows and columns.
#
# Every covariance here is exactly symmetric (the model symmetrises Q, R and
# the prior, and every covariance below is built symmetric), so a product
# with one is written as dot products of contiguous rows, P[c, j] = P[j, c];
# and a symmetric result is computed on its lower triangle and mirrored,
# row by row as soon as the rows it needs are known. That is the
# symmetrisation ``(X + Xᵀ) / 2`` of kalman.py, to round-off, at about half
# the cost, and it keeps the loops few, which is what costs at these sizes.
# ---------------------------------------------------------------------------


@jit(**_INLINE)
def cholesky(S, L, size):
    """Lower Cholesky factor of ``S[:size, :size]`` into `L` (kalman.cholesky).

    Returns False, like LAPACK's ``potrf``, as soon as a pivot is not
    positive (or NaN): the matrix is not positive definite.
    """
    for j in range(size):
        d = S[j, j]
        for c in range(j):
            d -= L[j, c] * L[j, c]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        L[j, j] = d
        inv = 1.0 / d
        for i in range(j + 1, size):
            s = S[i, j]
            for c in range(j):
                s -= L[i, c] * L[j, c]
            L[i, j] = s * inv
    return True


@jit(**_INLINE)
def cho_solve(L, X, size, ncols):
    """In place ``X[:size, :ncols] = (L Lᵀ)⁻¹ X`` (scipy.linalg.cho_solve), row by row."""
    for a in range(size):
        for b in range(a):
            f = L[a, b]
            for c in range(ncols):
                X[a, c] -= f * X[b, c]
        inv = 1.0 / L[a, a]
        for c in range(ncols):
            X[a, c] *= inv
    for a in range(size - 1, -1, -1):
        for b in range(a + 1, size):
            f = L[b, a]
            for c in range(ncols):
                X[a, c] -= f * X[b, c]
        inv = 1.0 / L[a, a]
        for c in range(ncols):
            X[a, c] *= inv


# ---------------------------------------------------------------------------
# The Kalman step: kalman.predict, kalman.update, kalman.rts_step
# ---------------------------------------------------------------------------


@jit(**_INLINE)
def predict(mean, cov, A, Q, b, pred_mean, pred_cov, AP):
    r"""kalman.predict: :math:`m^- = A m + b`, :math:`P^- = \mathrm{sym}(A P A^\top + Q)`.

    Writes `pred_mean`, `pred_cov`, and ``AP = A P`` (which the smoother's
    gain reuses).
    """
    n = mean.shape[0]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += A[i, j] * mean[j]
        pred_mean[i] = s + b[i]
        for j in range(n):  # row i of A P
            s = 0.0
            for c in range(n):
                s += A[i, c] * cov[j, c]
            AP[i, j] = s
        for j in range(i + 1):  # row i of (A P) Aᵀ + Q, mirrored
            s = 0.0
            for c in range(n):
                s += AP[i, c] * A[j, c]
            s += Q[i, j]
            pred_cov[i, j] = s
            pred_cov[j, i] = s


@jit(**_INLINE)
def update_scalar(mean, cov, z, H, R, post_mean, post_cov, innovation, S_full, S, HP, K, IKH, IKHP):
    r"""kalman.update for a single measurement component (m = 1), as :func:`update`.

    S is a number: its Cholesky factor is :math:`\sqrt S` (positive definite
    means S > 0), :math:`K = P^- H^\top / S`, and
    :math:`\ell = -\tfrac12 (v^2 / S + \log S + \log 2\pi)`.
    """
    n = mean.shape[0]
    s = 0.0
    for j in range(n):
        s += H[0, j] * mean[j]
    v = z[0] - s
    innovation[0] = v
    for j in range(n):  # H P⁻
        s = 0.0
        for c in range(n):
            s += H[0, c] * cov[j, c]
        HP[0, j] = s
    s = 0.0
    for j in range(n):
        s += H[0, j] * HP[0, j]
    s += R[0, 0]
    S_full[0, 0] = s
    if math.isnan(z[0]):
        for i in range(n):
            post_mean[i] = mean[i]
            for j in range(n):
                post_cov[i, j] = cov[i, j]
        return True, 0.0, np.int64(0)
    if not s > 0.0:
        S[0, 0] = s
        return False, 0.0, np.int64(1)
    inv = 1.0 / s
    r = R[0, 0]
    # The Joseph form row by row, as in update.
    for i in range(n):
        k = HP[0, i] * inv
        K[i, 0] = k
        post_mean[i] = mean[i] + k * v
        for j in range(n):
            IKH[i, j] = (1.0 if i == j else 0.0) - k * H[0, j]
        for j in range(n):
            t = 0.0
            for c in range(n):
                t += IKH[i, c] * cov[j, c]
            IKHP[i, j] = t
        kr = k * r
        for j in range(i + 1):
            t = 0.0
            for c in range(n):
                t += IKHP[i, c] * IKH[j, c]
            t += kr * K[j, 0]
            post_cov[i, j] = t
            post_cov[j, i] = t
    return True, -0.5 * (v * v * inv + math.log(s) + _LOG_2PI), np.int64(1)


@jit(**_INLINE)
def update(mean, cov, z, H, R, post_mean, post_cov, innovation, S_full,
           obs, HP, Ho, Ro, S, L, Kt, K, KR, IKH, IKHP, v, white):
    r"""kalman.update: condition on the observed components of `z` (Joseph form).

    With ``o`` the non-NaN components of `z`:

    * ``innovation = z - H m⁻`` (all m; NaN where missing),
      ``S_full = sym(H P⁻ Hᵀ + R)`` (all m);
    * ``S = S_full[o, o] = L Lᵀ``, ``Kᵀ = S⁻¹ H_o P⁻`` (Cholesky solve),
      ``m = m⁻ + K v``,
      ``P = sym((I - K H_o) P⁻ (I - K H_o)ᵀ + K R_oo Kᵀ)``;
    * ``loglik = -½ (|L⁻¹ v|² + 2 Σ log L_ii + |o| log 2π)``.

    Writes `post_mean`, `post_cov`, `innovation`, `S_full`; the rest is
    scratch. Returns ``(ok, loglik, |o|)``; ``ok`` is False when S is not
    positive definite (then ``S[:|o|, :|o|]`` holds it). Nothing observed:
    the prediction is returned unchanged with ``loglik = 0``.
    """
    n = mean.shape[0]
    m = z.shape[0]
    if m == 1:
        return update_scalar(mean, cov, z, H, R, post_mean, post_cov, innovation, S_full,
                             S, HP, K, IKH, IKHP)
    mo = np.int64(0)  # (not a literal 0, which numba would type as a constant)
    for a in range(m):
        s = 0.0
        for j in range(n):
            s += H[a, j] * mean[j]
        innovation[a] = z[a] - s
        if not math.isnan(z[a]):
            obs[mo] = a
            mo += 1
        for j in range(n):  # row a of H P⁻
            s = 0.0
            for c in range(n):
                s += H[a, c] * cov[j, c]
            HP[a, j] = s
        for b in range(a + 1):  # row a of (H P⁻) Hᵀ + R, mirrored
            s = 0.0
            for j in range(n):
                s += H[b, j] * HP[a, j]
            s += R[a, b]
            S_full[a, b] = s
            S_full[b, a] = s
    if mo == 0:
        for i in range(n):
            post_mean[i] = mean[i]
            for j in range(n):
                post_cov[i, j] = cov[i, j]
        return True, 0.0, mo

    # The observed components: v, H_o, R_oo, S = S_full[o, o], and Kᵀ ← H_o P⁻.
    for a in range(mo):
        oa = obs[a]
        v[a] = innovation[oa]
        for j in range(n):
            Ho[a, j] = H[oa, j]
            Kt[a, j] = HP[oa, j]
        for b in range(mo):
            Ro[a, b] = R[oa, obs[b]]
            S[a, b] = S_full[oa, obs[b]]
    if not cholesky(S, L, mo):
        return False, 0.0, mo
    cho_solve(L, Kt, mo, n)  # Kᵀ = S⁻¹ H_o P⁻
    # m = m⁻ + K v, and the Joseph form (I - K H_o) P⁻ (I - K H_o)ᵀ + (K R_oo) Kᵀ
    # row by row: row i needs rows 0..i of I - K H_o and of K.
    for i in range(n):
        s = 0.0
        for a in range(mo):
            K[i, a] = Kt[a, i]
            s += Kt[a, i] * v[a]
        post_mean[i] = mean[i] + s
        for j in range(n):
            s = 0.0
            for a in range(mo):
                s += K[i, a] * Ho[a, j]
            IKH[i, j] = (1.0 if i == j else 0.0) - s
        for j in range(n):
            s = 0.0
            for c in range(n):
                s += IKH[i, c] * cov[j, c]
            IKHP[i, j] = s
        for b in range(mo):
            s = 0.0
            for a in range(mo):
                s += K[i, a] * Ro[b, a]
            KR[i, b] = s
        for j in range(i + 1):
            s = 0.0
            for c in range(n):
                s += IKHP[i, c] * IKH[j, c]
            t = 0.0
            for b in range(mo):
                t += KR[i, b] * K[j, b]
            s += t
            post_cov[i, j] = s
            post_cov[j, i] = s
    # log N(v; 0, S) with white = L⁻¹ v.
    quad = 0.0
    logdet = 0.0
    for a in range(mo):
        s = v[a]
        for b in range(a):
            s -= L[a, b] * white[b]
        white[a] = s / L[a, a]
        quad += white[a] * white[a]
        logdet += math.log(L[a, a])
    return True, -0.5 * (quad + 2.0 * logdet + mo * _LOG_2PI), mo


@jit(**_INLINE)
def smoother_gain(CT, pred_cov, gain, L):
    r"""The RTS gain of kalman.rts_step: :math:`G = C (P^-)^{-1}`, :math:`C = P A^\top`.

    `CT` holds :math:`C^\top = A P` (the forward pass has it from
    :func:`predict`) and is overwritten; `pred_cov` is
    :math:`P^- = A P A^\top + Q`. :math:`G^\top = (P^-)^{-1} C^\top` is a
    Cholesky solve. Returns False when :math:`P^-` is not positive
    definite; the caller then takes the least-squares solution, as
    kalman.rts_step does. `L` is (n, n) scratch.
    """
    n = CT.shape[0]
    ok = cholesky(pred_cov, L, n)
    if ok:
        cho_solve(L, CT, n, n)
        for i in range(n):
            for j in range(n):
                gain[i, j] = CT[j, i]
    return ok


@jit(**_INLINE)
def rts_step(filt_mean, filt_cov, pred_mean, pred_cov, next_mean, next_cov, gain,
             mean, cov, diff, GD):
    r"""kalman.rts_step, given the gain :math:`G_k`.

    .. math::

        m^s_k = m_k + G_k (m^s_{k+1} - m^-_{k+1}), \qquad
        P^s_k = \mathrm{sym}(P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top).

    Writes `mean`, `cov`; `diff` (n,) and `GD` (n, n) are scratch.
    """
    n = filt_mean.shape[0]
    for j in range(n):
        diff[j] = next_mean[j] - pred_mean[j]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += gain[i, j] * diff[j]
        mean[i] = filt_mean[i] + s
        for j in range(n):  # row i of G (P^s - P⁻)
            s = 0.0
            for c in range(n):
                s += gain[i, c] * (next_cov[j, c] - pred_cov[j, c])
            GD[i, j] = s
        for j in range(i + 1):  # row i of P + (G D) Gᵀ, mirrored
            s = 0.0
            for c in range(n):
                s += GD[i, c] * gain[j, c]
            s = filt_cov[i, j] + s
            cov[i, j] = s
            cov[j, i] = s


@jit(**_INLINE)
def nonfinite(mean, cov, loglik):
    """True when the mean, the diagonal of the covariance or `loglik` is inf or NaN (inference.check_finite).

    Branch-free: ``x * 0`` is 0 for a finite x and NaN for inf or NaN, and the
    sum of those cannot overflow.
    """
    acc = loglik * 0.0
    for i in range(mean.shape[0]):
        acc += mean[i] * 0.0 + cov[i, i] * 0.0
    return acc != acc


# ---------------------------------------------------------------------------
# Loops over steps and series
# ---------------------------------------------------------------------------


@jit(**_JIT)
def _filter_loop(lo, hi, F, H, Q, R, b, zs, m0, P0,
                 means, covs, pmeans, pcovs, innov, icovs, gains, failed,
                 loglik, last_mean, last_cov, err, err_S,
                 mean0, cov0, pm0, pP0, v0, S0, AP, Ln,
                 obs, HP, Ho, Ro, S, L, Kt, K, KR, IKH, IKHP, v, white):
    """Filter series ``lo..hi-1`` of `zs`: the loop of inference.run_filter.

    Each step writes straight into the output arrays that are kept, and into
    the scratch arrays ``mean0, cov0, pm0, pP0, v0, S0`` otherwise. With
    `gains` of length T - 1 (smoothing), the smoother gain ``G_{k-1}`` is
    computed at step k from the prediction's ``A P``.
    """
    F, H, Q, R, b, zs, m0, P0 = (_borrow(F), _borrow(H), _borrow(Q), _borrow(R), _borrow(b),
                                 _borrow(zs), _borrow(m0), _borrow(P0))
    means, covs, pmeans, pcovs, innov, icovs = (_borrow(means), _borrow(covs), _borrow(pmeans),
                                                _borrow(pcovs), _borrow(innov), _borrow(icovs))
    gains, failed, loglik, last_mean, last_cov, err, err_S = (
        _borrow(gains), _borrow(failed), _borrow(loglik), _borrow(last_mean), _borrow(last_cov),
        _borrow(err), _borrow(err_S))
    mean0, cov0, pm0, pP0, v0, S0, AP, Ln = (_borrow(mean0), _borrow(cov0), _borrow(pm0),
                                             _borrow(pP0), _borrow(v0), _borrow(S0), _borrow(AP),
                                             _borrow(Ln))
    obs, HP, Ho, Ro, S, L, Kt, K, KR = (_borrow(obs), _borrow(HP), _borrow(Ho), _borrow(Ro),
                                        _borrow(S), _borrow(L), _borrow(Kt), _borrow(K), _borrow(KR))
    IKH, IKHP, v, white = _borrow(IKH), _borrow(IKHP), _borrow(v), _borrow(white)
    T = zs.shape[1]
    n = m0.shape[0]
    keep_means = means.shape[1] > 0
    keep_covs = covs.shape[1] > 0
    keep_gains = gains.shape[1] > 0
    for s in range(lo, hi):
        mean, cov = mean0, cov0
        for i in range(n):
            mean[i] = m0[i]
            for j in range(n):
                cov[i, j] = P0[i, j]
        total = 0.0
        err[s, 0] = -1
        err[s, 1] = 0
        bs = s if b.shape[0] > 1 else 0
        for k in range(T):
            pred_mean = pmeans[s, k] if keep_means else pm0
            pred_cov = pcovs[s, k] if keep_covs else pP0
            predict(mean, cov, F[k if F.shape[0] > 1 else 0], Q[k if Q.shape[0] > 1 else 0],
                    b[bs, k if b.shape[1] > 1 else 0], pred_mean, pred_cov, AP)
            if nonfinite(pred_mean, pred_cov, 0.0):  # an overflow: inference.check_finite
                err[s, 0] = k
                err[s, 1] = PREDICTED_NOT_FINITE
                break
            if keep_gains and k > 0:
                failed[s, k - 1] = not smoother_gain(AP, pred_cov, gains[s, k - 1], Ln)
            # The posterior overwrites the previous one in scratch: predict has used it.
            mean = means[s, k] if keep_means else mean0
            cov = covs[s, k] if keep_covs else cov0
            innovation = innov[s, k] if keep_means else v0
            S_full = icovs[s, k] if keep_covs else S0
            ok, ll, mo = update(pred_mean, pred_cov, zs[s, k], H[k if H.shape[0] > 1 else 0],
                                R[k if R.shape[0] > 1 else 0], mean, cov, innovation, S_full,
                                obs, HP, Ho, Ro, S, L, Kt, K, KR, IKH, IKHP, v, white)
            if not ok:
                err[s, 0] = k
                err[s, 1] = mo
                for a in range(mo):
                    for c in range(mo):
                        err_S[s, a, c] = S[a, c]
                break
            if nonfinite(mean, cov, ll):
                err[s, 0] = k
                err[s, 1] = FILTERED_NOT_FINITE
                break
            total += ll
        loglik[s] = total
        for i in range(n):
            last_mean[s, i] = mean[i]
            for j in range(n):
                last_cov[s, i, j] = cov[i, j]


@jit(**_JIT)
def _filter_series(lo, hi, F, H, Q, R, b, zs, m0, P0, means, covs, pmeans, pcovs, innov, icovs,
                   gains, failed, loglik, last_mean, last_cov, err, err_S):
    """Filter series ``lo..hi-1`` with one set of scratch arrays (nothing is allocated per step)."""
    m = zs.shape[2]
    n = m0.shape[0]
    _filter_loop(lo, hi, F, H, Q, R, b, zs, m0, P0, means, covs, pmeans, pcovs, innov, icovs,
                 gains, failed, loglik, last_mean, last_cov, err, err_S,
                 np.empty(n), np.empty((n, n)), np.empty(n), np.empty((n, n)),  # mean0, cov0, pm0, pP0
                 np.empty(m), np.empty((m, m)),  # v0, S0
                 np.empty((n, n)), np.empty((n, n)),  # AP, Ln
                 np.empty(m, dtype=np.int64), np.empty((m, n)), np.empty((m, n)),  # obs, HP, Ho
                 np.empty((m, m)), np.empty((m, m)), np.empty((m, m)),  # Ro, S, L
                 np.empty((m, n)), np.empty((n, m)), np.empty((n, m)),  # Kt, K, KR
                 np.empty((n, n)), np.empty((n, n)), np.empty(m), np.empty(m))  # IKH, IKHP, v, white


@jit(parallel=True, **_JIT)
def _filter_parallel(chunks, F, H, Q, R, b, zs, m0, P0, means, covs, pmeans, pcovs, innov, icovs,
                     gains, failed, loglik, last_mean, last_cov, err, err_S):
    """:func:`_filter_series` over `chunks` contiguous groups of series, in parallel."""
    N = zs.shape[0]
    for c in prange(chunks):
        _filter_series(c * N // chunks, (c + 1) * N // chunks, F, H, Q, R, b, zs, m0, P0,
                       means, covs, pmeans, pcovs, innov, icovs, gains, failed,
                       loglik, last_mean, last_cov, err, err_S)


@jit(**_JIT)
def _backward_loop(lo, hi, means, covs, pmeans, pcovs, gains, sm_means, sm_covs, diff, GD):
    """The RTS backward pass of inference.run_smoother over series ``lo..hi-1``."""
    means, covs, pmeans, pcovs = _borrow(means), _borrow(covs), _borrow(pmeans), _borrow(pcovs)
    gains, sm_means, sm_covs = _borrow(gains), _borrow(sm_means), _borrow(sm_covs)
    diff, GD = _borrow(diff), _borrow(GD)
    T = means.shape[1]
    n = means.shape[2]
    for s in range(lo, hi):
        for i in range(n):
            sm_means[s, T - 1, i] = means[s, T - 1, i]
            for j in range(n):
                sm_covs[s, T - 1, i, j] = covs[s, T - 1, i, j]
        for j in range(T - 2, -1, -1):
            rts_step(means[s, j], covs[s, j], pmeans[s, j + 1], pcovs[s, j + 1],
                     sm_means[s, j + 1], sm_covs[s, j + 1], gains[s, j],
                     sm_means[s, j], sm_covs[s, j], diff, GD)


@jit(**_JIT)
def _backward(lo, hi, means, covs, pmeans, pcovs, gains, sm_means, sm_covs):
    """:func:`_backward_loop` with its scratch."""
    n = means.shape[2]
    _backward_loop(lo, hi, means, covs, pmeans, pcovs, gains, sm_means, sm_covs,
                   np.empty(n), np.empty((n, n)))


@jit(parallel=True, **_JIT)
def _backward_parallel(chunks, means, covs, pmeans, pcovs, gains, sm_means, sm_covs):
    """:func:`_backward` over `chunks` groups of series, in parallel."""
    N = means.shape[0]
    for c in prange(chunks):
        _backward(c * N // chunks, (c + 1) * N // chunks, means, covs, pmeans, pcovs, gains,
                  sm_means, sm_covs)


KERNELS = (_filter_series, _filter_parallel, _backward, _backward_parallel)
"""The compiled entry points (numba dispatchers), e.g. for their ``stats``: the
forward and backward kernels for one chunk of series, and their parallel forms."""

# ---------------------------------------------------------------------------
# Python side: arrange the arguments, call the kernels, raise errors
# ---------------------------------------------------------------------------


def _matrices(model) -> tuple[np.ndarray, ...]:
    """F, H, Q, R of the model as (T or 1, rows, cols) arrays."""
    return tuple(_readonly(a if a.ndim == 3 else a[None])
                 for a in (model.F, model.H, model.Q, model.R))


def _offsets(model, us: np.ndarray | None) -> np.ndarray:
    """The control offsets ``b = B_k u_k``, (N or 1, T or 1, n): zeros without controls."""
    if us is None:
        return _readonly(np.zeros((1, 1, model.n)))
    if us.shape[0] > 1 and us.strides[0] == 0:  # one control series broadcast to all
        us = us[:1]
    B = model.B
    return _readonly(np.einsum("tnp,itp->itn" if B.ndim == 3 else "np,itp->itn", B, us))


def _run(serial, parallel, items: int, *args) -> None:
    """``serial(0, items, *args)``, or ``parallel(chunks, *args)`` over chunks of the items.

    Chunks are handed to the threads one at a time as they finish (numba's
    parallel chunk size 1), so a thread slowed down by other work on the
    machine takes fewer of them. One call at a time runs in parallel
    (:func:`._jit.parallel_launch`): a call made while another thread's
    runs takes the serial kernel, which gives the same numbers.
    """
    chunks = max(1, min(items, _CHUNKS_PER_THREAD * numba.get_num_threads()))
    if chunks > 1:
        with parallel_launch() as mine:
            if mine:
                previous = numba.set_parallel_chunksize(1)
                try:
                    parallel(chunks, *args)
                finally:
                    numba.set_parallel_chunksize(previous)
                return
    serial(0, items, *args)


def _raise_not_pd(err: np.ndarray, err_S: np.ndarray) -> None:
    """Raise the readable path's error for the first series that failed.

    A LinAlgError for an innovation covariance that is not positive definite;
    a FloatingPointError (:func:`gaussfuse.errors.not_finite`) for a
    belief that overflowed.
    """
    failed = np.flatnonzero(err[:, 0] >= 0)
    if failed.size == 0:
        return
    s = int(failed[0])
    k, mo = (int(x) for x in err[s])
    if mo < 0:
        stage = "predicted" if mo == PREDICTED_NOT_FINITE else "filtered"
        where = f"in series {s}, at step {k}" if err.shape[0] > 1 else f"at step {k}"
        raise FloatingPointError(f"{where}: {not_finite(stage)}")
    with np.printoptions(precision=4, threshold=36):
        shown = np.array2string(err_S[s, :mo, :mo], separator=", ").replace("\n", "")
    where = f"in series {s}, at step {k}" if err.shape[0] > 1 else f"at step {k}"
    raise np.linalg.LinAlgError(
        f"{where}: {_S_NAME} is not positive definite, so it cannot be factorised: {shown}"
    )


def _forward(model, prior, zs, us, keep: str, smoothing: bool):
    """Run the forward kernel; return the FilterResult and, when smoothing, the gains."""
    F, H, Q, R = _matrices(model)
    b = _offsets(model, us)
    zs = _readonly(zs)
    N, T, m = zs.shape
    n = model.n
    rows = 0 if keep == "last" else T
    crows = T if keep == "all" else 0
    grows = T - 1 if smoothing else 0
    means, pmeans = np.empty((N, rows, n)), np.empty((N, rows, n))
    innov = np.empty((N, rows, m))
    covs, pcovs = np.empty((N, crows, n, n)), np.empty((N, crows, n, n))
    icovs = np.empty((N, crows, m, m))
    gains, failed = np.empty((N, grows, n, n)), np.zeros((N, grows), dtype=np.bool_)
    loglik, last_mean, last_cov = np.empty(N), np.empty((N, n)), np.empty((N, n, n))
    err, err_S = np.empty((N, 2), dtype=np.int64), np.zeros((N, m, m))
    args = (F, H, Q, R, b, zs, _readonly(prior.mean), _readonly(prior.cov),
            means, covs, pmeans, pcovs, innov, icovs, gains, failed,
            loglik, last_mean, last_cov, err, err_S)
    _run(_filter_series, _filter_parallel, N, *args)
    _raise_not_pd(err, err_S)
    per_step = (means, covs, pmeans, pcovs, innov, icovs)
    filt = FilterResult(*(a if a.shape[1] else None for a in per_step), loglik, last_mean, last_cov)
    if failed.any():
        # P⁻ singular: the minimum-norm least-squares gain, as kalman.rts_step
        # (lstsq, with its default cut-off eps * n, here batched as a pseudo-inverse).
        s, j = np.nonzero(failed)
        CT = F[j + 1 if F.shape[0] > 1 else 0] @ covs[s, j]
        pinv = np.linalg.pinv(pcovs[s, j + 1], np.finfo(np.float64).eps * n)
        gains[s, j] = np.swapaxes(pinv @ CT, -1, -2)
    return filt, gains


def filter(lin, model, prior, zs, us, keep) -> FilterResult:
    """The Kalman filter over N series: `zs` (N, T, m), `us` (N, T, p) or None.

    Returns a FilterResult whose fields all carry the leading N axis; fields
    that `keep` leaves out are None and never allocated.
    """
    return _forward(model, prior, zs, us, keep, smoothing=False)[0]


def smooth(lin, model, prior, zs, us) -> SmoothResult:
    """The Kalman filter and RTS smoother over N series (see :func:`filter`)."""
    filt, gains = _forward(model, prior, zs, us, "all", smoothing=True)
    N, T, n = filt.means.shape
    sm_means, sm_covs = np.empty((N, T, n)), np.empty((N, T, n, n))
    args = (filt.means, filt.covs, filt.predicted_means, filt.predicted_covs, gains, sm_means, sm_covs)
    _run(_backward, _backward_parallel, N, *args)
    check_smoothed(sm_means, sm_covs)
    return SmoothResult(sm_means, sm_covs, gains, filt)
