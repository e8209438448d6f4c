r"""Compiled engine for the linear Kalman filter and RTS smoother (method ``"kf"``).

The loop of :func:`gaussfuse.inference.drivers.run_filter` with the
:class:`~gaussfuse.linearize.Exact` strategy, over a batch of series: at
each step :func:`._step.predict` with :math:`A = F_k`, :math:`b = B_k u_k`,
then :func:`._step.update` with :math:`H_k`, :math:`R_k`. The algebra is
:mod:`._step`'s; this module only lays out the arguments, loops, and
stores what is kept. When smoothing, the gain :math:`G_{k-1}` is computed at
step k, from :math:`F_k P_{k-1}` and the prediction (see :mod:`._rts`,
which runs the backward pass).

The arguments are laid out so that one compiled signature serves every case
(time-invariant or time-varying, with or without controls, any ``keep``,
filtering or smoothing):

* :class:`Model`: the matrices as read-only, C-contiguous float64 arrays
  with a leading axis of length T (time-varying) or 1 (in force at every
  step), and the control offsets ``b = B_k u_k``, computed with NumPy before
  the kernel, of shape (N or 1, T or 1, n) (zeros (1, 1, n) without
  controls);
* :class:`._step.Outputs`: every per-step output has the shape (N, T, ...) when
  kept and (N, 0, ...) when not, so ``keep="last"`` allocates nothing that
  grows with T; the gains are (N, T - 1, n, n) when smoothing and
  (N, 0, n, n) when filtering;
* :class:`._step.Failures`: why a series stopped (an innovation covariance
  that is not positive definite, an overflow), raised in Python as the
  readable path's error.

The series of a batch share the model and the prior, and a linear filter's
covariances depend only on which components are observed: :func:`forward`
and :func:`forward_sqrt` compute them once per chunk of series, in its first
series, and the others reuse them (a :class:`Table`) while they observe the
same components, computing their means only.

Kernels: :func:`forward` (and :func:`forward_sqrt`), compiled on first use
and cached on disk; a batch of series runs them over chunks of series on a
pool of threads (:func:`._jit.launch`). A state of :data:`._dense.BLAS_FROM`
components or more has its products computed by BLAS (see :mod:`._dense`),
which parallelises them itself: its series run one after the other.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from .._linalg import symmetrize
from ..inference.results import FilterResult, SmoothResult, check_smoothed
from ..kalman import SETTLED, STEADY_TOL, cov_factor
from . import _rts
from ._dense import BLAS_FROM, congruence, matmul
from ._jit import jit, launch
from ._nrt import borrow, readonly
from ._step import (FILTERED_NOT_FINITE, OK, PREDICTED_NOT_FINITE, READABLE, Outputs, at, copy1, copy2, failures,
                    filter_result, fixed, hold_fixed, nis, not_finite, not_finite_factor, not_finite_mean,
                    outputs, predict, predict_mean, predict_sqrt, raise_failure, record, record_not_pd, settled,
                    smoother_gain, sqrt_workspace, square, steady_update, update, update_sqrt, workspace)

__all__ = ["filter", "smooth", "smooth_sqrt", "KERNELS"]

_JIT = {"nogil": True, "error_model": "numpy"}


class Model(NamedTuple):
    """A LinearModel as the kernels read it (see the module notes); every array read-only."""

    F: np.ndarray       # (T or 1, n, n)
    H: np.ndarray       # (T or 1, m, n)
    Q: np.ndarray       # (T or 1, n, n)
    R: np.ndarray       # (T or 1, m, m)
    b: np.ndarray       # (N or 1, T or 1, n): B_k u_k
    d: np.ndarray       # (m,): zeros, the measurement offset of kalman.update
    angles: np.ndarray  # (m,) bool: False, no angle components
    target: np.ndarray  # (n, n) the stationary covariance to hold (kalman.SteadyState.target), or (0, 0)
    tol: float          # the fixed point's test: kalman.SteadyState.tol


@jit(inline="always", **_JIT)
def update_failed(fail, s, k, w, ok, mo, overflowed):
    """Record why step k of series s failed, if it did: S not positive definite (not `ok`), or an overflow."""
    if not ok:
        record_not_pd(fail, s, k, w, mo)
        return True
    if overflowed:
        record(fail, s, FILTERED_NOT_FINITE, k)
        return True
    return False


@jit(inline="always", **_JIT)
def keep_gain(steps, k, Kt, L, z, held):
    """Record in row k of `steps` the ``Kᵀ`` and ``L`` step k used, what it observed, and whether it started at the fixed point."""
    copy2(steps.Kt[k], Kt)
    copy2(steps.L[k], L)
    for a in range(z.shape[0]):
        steps.observed[k, a] = z[a] == z[a]
    steps.held[k] = held


@jit(inline="always", **_JIT)
def load_row(fx, steps, k):
    """Series lo's gain, factor of S and observed components at step k (row k of `steps`) into `fx`, to be held."""
    copy2(fx.Kt, steps.Kt[k])
    copy2(fx.L, steps.L[k])
    for a in range(steps.observed.shape[1]):
        fx.obs[a] = steps.observed[k, a]


class Table(NamedTuple):
    """Series lo's steps, for the other series of a batch (see :func:`forward`); T rows, or none."""

    Kt: np.ndarray        # (T, m, n) the gain Kᵀ over the observed components (leading rows)
    L: np.ndarray         # (T, m, m) the Cholesky factor of S_oo
    observed: np.ndarray  # (T, m) bool: the observed components
    held: np.ndarray      # (T,) bool: the step started from the fixed point (at_fixed)


@register_jitable
def table(T, n, m, shared):
    """A :class:`Table` of T rows when `shared` (covariances kept, more than one series in the chunk), else of none."""
    rows = T if shared else 0
    return Table(np.empty((rows, m, n)), np.empty((rows, m, m)), np.zeros((rows, m), dtype=np.bool_),
                 np.zeros(rows, dtype=np.bool_))


@jit(inline="always", **_JIT)
def fixed_gain(fx, w, F):
    r"""The smoother gain between two held steps, from the fixed point's covariances, in ``fx.gain``.

    :math:`G = P F^\top (P^-)^{-1}` with P and :math:`P^-` the fixed point's
    (:func:`._step.smoother_gain` on :math:`C^\top = F P`); where
    :math:`P^-` is not positive definite, ``fx.gain`` keeps :math:`C^\top`
    for the least-squares gain and ``fx.gain_failed[0]`` is set, as a
    computed step's gain is.
    """
    n = F.shape[0]
    matmul(F, fx.cov, w.A1, n, n, n)
    fx.gain_failed[0] = not smoother_gain(w, fx.pred_cov, w.A1, fx.gain)
    if fx.gain_failed[0]:
        copy2(fx.gain, w.A1)


@jit(**_JIT)
def held_steps(k0, total, lo, s, sharing, model, zs, out, fail, w, fx, steps_lo, mean, pm0, v0):
    """Steps ``k0..`` of series s while each reuses held covariances and gain: :func:`forward`'s held branch.

    The held step's covariances, gain and factor of S are series lo's at
    that step (`sharing`: its rows, and its gain and factor from `steps_lo`,
    loaded into `fx`), or the fixed point's in `fx`. Each step predicts the
    mean and updates it with the held gain (:func:`._step.steady_update`),
    operation for operation as the branch does, so bitwise the same; in a
    loop of its own, out of the registers of :func:`forward`'s other
    branches. Returns ``(k, total)``: the first step that observes other
    components than the held ones (left to the caller; T: none) and the
    log-likelihood with these steps added. The mean after step k - 1 is
    ``out.means[s, k - 1]`` when means are kept, else in `mean`; the
    covariances are kept only when `out` keeps them (the caller takes the
    held ones). A failure is recorded in `fail`, and returns its step.
    """
    T = zs.shape[1]
    m = zs.shape[2]
    keep_means = out.means.shape[1] > 0
    keep_covs = out.covs.shape[1] > 0
    smoothing = out.gains.shape[1] > 0
    recording = s == lo and steps_lo.held.shape[0] > 0  # series lo, whose steps the others reuse
    b = model.b[s if model.b.shape[0] > 1 else 0]
    prev = out.means[s, k0 - 1] if keep_means and k0 > 0 else mean
    for k in range(k0, T):
        z = zs[s, k]
        for a in range(m):
            if (z[a] == z[a]) != (steps_lo.observed[k, a] if sharing else fx.obs[a]):
                return k, total
        pm = out.predicted_means[s, k] if keep_means else pm0
        predict_mean(prev, at(model.F, k), at(b, k), pm)
        if keep_covs:
            if sharing:
                copy2(out.predicted_covs[s, k], out.predicted_covs[lo, k])
            else:
                copy2(out.predicted_covs[s, k], fx.pred_cov)
        if not_finite_mean(pm, 0.0):
            record(fail, s, PREDICTED_NOT_FINITE, k)
            return k, total
        if smoothing and k > 0:  # G_{k-1}: series lo's, or the fixed point's (between two held steps)
            if sharing:
                copy2(out.gains[s, k - 1], out.gains[lo, k - 1])
                out.failed[s, k - 1] = out.failed[lo, k - 1]
            else:
                copy2(out.gains[s, k - 1], fx.gain)
                out.failed[s, k - 1] = fx.gain_failed[0]
        if sharing:
            load_row(fx, steps_lo, k)
        post = out.means[s, k] if keep_means else mean
        v = out.innovations[s, k] if keep_means else v0
        _, ll = steady_update(fx, w, pm, z, at(model.H, k), model.d, model.angles, post, v)
        if keep_covs:
            if sharing:
                copy2(out.covs[s, k], out.covs[lo, k])
                copy2(out.innovation_covs[s, k], out.innovation_covs[lo, k])
            else:
                copy2(out.covs[s, k], fx.cov)
                copy2(out.innovation_covs[s, k], fx.S)
        if not_finite_mean(post, ll):
            record(fail, s, FILTERED_NOT_FINITE, k)
            return k, total
        if recording:
            keep_gain(steps_lo, k, fx.Kt, fx.L, z, True)
        total += ll
        if keep_means:
            out.nis[s, k] = nis(w, z)
        prev = post
    return T, total


@jit(**_JIT)
def forward(lo, hi, model, zs, m0, P0, out, fail, w):
    """Filter series ``lo..hi-1``: inference.drivers.run_filter's loop, with the workspace `w`.

    `w` is a :func:`._step.workspace`, which the caller keeps alive. A
    time-invariant model's steps reuse the covariance fixed point once it
    is reached (:class:`._step.Fixed`, as kalman.SteadyState).

    The series share one model and one prior, and a linear model's
    covariances do not depend on the measurements, only on which components
    are observed: series ``lo``'s predicted and filtered covariances, S, gain
    and factor of S at step k are every other series' while the same
    components have been observed at every step so far. When the
    covariances are kept, series ``lo`` records its gains and factors (a
    table of T rows) and the other series' steps reuse them, computing the
    means only (:func:`._step.steady_update`, bitwise the numbers of
    :func:`._step.update`); a series leaves the table at its first step that
    observes other components, and runs its own steps from there.
    """
    model, zs, m0, P0, out, fail, w = borrow((model, zs, m0, P0, out, fail, w))
    T = zs.shape[1]
    m = zs.shape[2]
    n = m0.shape[0]
    keep_means = out.means.shape[1] > 0
    keep_covs = out.covs.shape[1] > 0
    smoothing = out.gains.shape[1] > 0
    invariant = (model.F.shape[0] == 1 and model.H.shape[0] == 1 and model.Q.shape[0] == 1
                 and model.R.shape[0] == 1)
    # The fixed point, and where a step's belief goes when it is not kept: two covariances, so that
    # the last one is still there to compare with the next (the fixed point's test); series lo's steps,
    # for the others. Borrowed, as the arguments are; `scratch` owns them until the end.
    scratch = (fixed(n, m), np.empty(n), np.empty(n), np.empty((n, n)), np.empty((2, n, n)), np.empty(m),
               np.empty((m, m)), table(T, n, m, keep_covs and hi - lo > 1))
    fx, mean0, pm0, pc0, covs0, v0, S0, steps_lo = borrow(scratch)
    rows = steps_lo.held.shape[0]
    for s in range(lo, hi):
        mean, cov = mean0, covs0[1]
        copy1(mean, m0)
        copy2(cov, P0)
        total = 0.0
        fail.code[s] = OK
        at_fixed = False  # cov is the fixed point's posterior covariance
        sharing = rows > 0 and s > lo and fail.code[lo] == OK  # cov is series lo's at this step
        b = model.b[s if model.b.shape[0] > 1 else 0]
        k = np.int64(0)  # not the literal 0, for which numba would compile held_steps a second time (2 s)
        while k < T:
            if sharing or at_fixed:  # the held steps, in their own loop, up to one that observes otherwise
                k1, total = held_steps(k, total, lo, s, sharing, model, zs, out, fail, w, fx, steps_lo, mean0,
                                       pm0, v0)
                if fail.code[s] != OK:
                    break
                if k1 > k:
                    mean = out.means[s, k1 - 1] if keep_means else mean0
                    if keep_covs:
                        cov = out.covs[s, k1 - 1]
                    else:
                        cov = covs0[(k1 - 1) % 2]
                        copy2(cov, fx.cov)
                k = k1
                if k == T:
                    break
            pm = out.predicted_means[s, k] if keep_means else pm0
            pc = out.predicted_covs[s, k] if keep_covs else pc0
            F = at(model.F, k)
            held = at_fixed or sharing  # the step's covariances, gain and factor are held: series lo's, or fx's
            if sharing:  # series lo's gain and factor at step k, in fx (its covariances are copied from lo's rows)
                load_row(fx, steps_lo, k)
            if held:
                predict_mean(mean, F, at(b, k), pm)
                if sharing:
                    copy2(pc, out.predicted_covs[lo, k])
                else:
                    copy2(pc, fx.pred_cov)
                if not_finite_mean(pm, 0.0):
                    record(fail, s, PREDICTED_NOT_FINITE, k)
                    break
            else:
                predict(w, mean, cov, F, at(model.Q, k), at(b, k), pm, pc)
                if not_finite(pm, pc, 0.0):
                    record(fail, s, PREDICTED_NOT_FINITE, k)
                    break
            if smoothing and k > 0:  # G_{k-1} = C (P⁻_k)⁻¹, Cᵀ = F_k P_{k-1} from predict
                if sharing:
                    copy2(out.gains[s, k - 1], out.gains[lo, k - 1])
                    out.failed[s, k - 1] = out.failed[lo, k - 1]
                elif at_fixed:  # no predict ran: the fixed point's
                    copy2(out.gains[s, k - 1], fx.gain)
                    out.failed[s, k - 1] = fx.gain_failed[0]
                elif not smoother_gain(w, pc, w.A1, out.gains[s, k - 1]):
                    out.failed[s, k - 1] = True  # Cᵀ left for the least-squares gain
                    copy2(out.gains[s, k - 1], w.A1)
            previous = cov
            mean = out.means[s, k] if keep_means else mean0
            cov = out.covs[s, k] if keep_covs else covs0[k % 2]
            v = out.innovations[s, k] if keep_means else v0
            S = out.innovation_covs[s, k] if keep_covs else S0
            H = at(model.H, k)
            reused = False
            if held:
                reused, ll = steady_update(fx, w, pm, zs[s, k], H, model.d, model.angles, mean, v)
            if reused:
                if sharing:
                    copy2(cov, out.covs[lo, k])
                    copy2(S, out.innovation_covs[lo, k])
                else:
                    copy2(cov, fx.cov)
                    copy2(S, fx.S)
                if not_finite_mean(mean, ll):
                    record(fail, s, FILTERED_NOT_FINITE, k)
                    break
                if s == lo and rows > 0:
                    keep_gain(steps_lo, k, fx.Kt, fx.L, zs[s, k], True)
            else:
                # As series lo would: a step that leaves the fixed point is not tested for one.
                was_fixed = at_fixed or (sharing and steps_lo.held[k])
                sharing = False
                ok, ll, mo = update(w, pm, pc, zs[s, k], H, at(model.R, k), model.d, model.angles, mean, cov, v, S)
                if update_failed(fail, s, k, w, ok, mo, ok and not_finite(mean, cov, ll)):
                    break
                if s == lo and rows > 0:
                    keep_gain(steps_lo, k, w.Kt, w.L, zs[s, k], was_fixed)
                if invariant and not was_fixed and settled(cov, model.target if model.target.shape[0] else previous,
                                                          model.tol):
                    hold_fixed(fx, w, cov, pc, S, zs[s, k], mo)
                    if smoothing:  # the gain between two held steps: G = P Fᵀ (P⁻)⁻¹ of the fixed point
                        fixed_gain(fx, w, F)
                    reused = True  # the posterior is the fixed point's: the next step reuses it
            at_fixed = reused and not sharing
            total += ll
            if keep_means:
                out.nis[s, k] = nis(w, zs[s, k])
            k += 1
        out.loglik[s] = total
        copy1(out.last_mean[s], mean)
        copy2(out.last_cov[s], cov)
        out.leader[s] = lo if sharing else s  # shared series lo's covariances to the end: the smoother may too
    scratch[1][0] = 0.0  # alive until here


@jit(**_JIT)
def forward_sqrt(lo, hi, model, Qf, Rf, zs, m0, L0, out, fail, w, sw):
    """The square-root filter over series ``lo..hi-1``: inference.drivers.run_filter's loop with ``form="sqrt"``.

    `Qf` and `Rf` (T or 1, ·, ·) are the factors of Q and R, `L0` the
    prior's; `w` and `sw` the scratch (:func:`._step.workspace`,
    :func:`._step.sqrt_workspace`). Covariances are written as
    ``sym(L Lᵀ)`` where kept, with the factors. A time-invariant model's
    steps reuse the fixed point once the covariance ``L Lᵀ`` settles
    (kalman.SteadyState, as :func:`forward`): then only the means are
    computed, with the held ``K̄`` and ``L_S``. An update whose ``L_S`` has a
    zero pivot stops the series with READABLE: the driver runs the call on
    the readable path, which names S or downdates where it can. The
    series share series ``lo``'s factors, ``K̄`` and ``L_S`` while they
    observe what it observed, as in :func:`forward`.
    """
    model, Qf, Rf, zs, m0, L0, out, fail, w, sw = borrow((model, Qf, Rf, zs, m0, L0, out, fail, w, sw))
    T = zs.shape[1]
    m = zs.shape[2]
    n = m0.shape[0]
    keep_means = out.means.shape[1] > 0
    keep_covs = out.covs.shape[1] > 0
    invariant = (model.F.shape[0] == 1 and model.H.shape[0] == 1 and Qf.shape[0] == 1 and Rf.shape[0] == 1)
    # the fixed point (a Fixed holding factors, K̄ᵀ and L_S), the step's belief and scratch, series lo's steps
    scratch = (fixed(n, m), np.empty(n), np.empty((n, n)), np.empty(n), np.empty((n, n)), np.empty(m),
               np.empty((n, n)), np.empty((n, n)), table(T, n, m, keep_covs and hi - lo > 1))
    fx, mean, L, pm, pL, v0, cov0, prevL, steps_lo = borrow(scratch)
    rows = steps_lo.held.shape[0]
    for s in range(lo, hi):
        copy1(mean, m0)
        copy2(L, L0)
        total = 0.0
        fail.code[s] = OK
        at_fixed = False
        sharing = rows > 0 and s > lo and fail.code[lo] == OK  # L is series lo's at this step
        b = model.b[s if model.b.shape[0] > 1 else 0]
        for k in range(T):
            v = out.innovations[s, k] if keep_means else v0
            H = at(model.H, k)
            z = zs[s, k]
            reused = False
            held = at_fixed or sharing  # the step's factors, K̄ᵀ and L_S are held: series lo's, or fx's
            if sharing:  # series lo's K̄ᵀ and L_S at step k, in fx (its factors are copied from lo's rows)
                load_row(fx, steps_lo, k)
            if held:  # the held prediction, and its gain when the same components are observed
                predict_mean(mean, at(model.F, k), at(b, k), pm)
                if sharing:
                    copy2(pL, out.predicted_factors[lo, k])
                else:
                    copy2(pL, fx.pred_cov)
                reused, ll = steady_update(fx, w, pm, z, H, model.d, model.angles, mean, v, True)
                if reused:
                    if sharing:
                        copy2(L, out.factors[lo, k])
                    else:
                        copy2(L, fx.cov)
                    if not_finite_mean(mean, ll):
                        record(fail, s, FILTERED_NOT_FINITE, k)
                        break
                    if s == lo and rows > 0:
                        keep_gain(steps_lo, k, fx.Kt, fx.L, z, True)
            if not reused:
                sharing = False
                copy2(prevL, L)  # the factor this step's prediction started from: the fixed point's test
                if not held:
                    predict_sqrt(sw, mean, L, at(model.F, k), at(Qf, k), at(b, k), pm, pL)
                    if not_finite_factor(pm, pL, 0.0):
                        record(fail, s, PREDICTED_NOT_FINITE, k)
                        break
                ok, ll, mo = update_sqrt(w, sw, pm, pL, z, H, at(Rf, k), at(Rf, k)[:, :0], model.d, model.angles, mean, L, v)
                if not ok:  # L_S has a zero pivot: the readable path names S (or downdates, where it can)
                    record(fail, s, READABLE, k)
                    break
                if not_finite_factor(mean, L, ll):
                    record(fail, s, FILTERED_NOT_FINITE, k)
                    break
                if s == lo and rows > 0:
                    keep_gain(steps_lo, k, w.Kt, w.L, z, at_fixed)
                if invariant and mo > 0:  # the fixed point's test, on the covariances L Lᵀ
                    square(L, cov0)
                    square(prevL, fx.cov)
                    if settled(cov0, fx.cov, model.tol):
                        hold_fixed(fx, w, L, pL, fx.S, z, mo)
                        reused = True
            at_fixed = reused and not sharing
            total += ll
            if keep_means:
                copy1(out.means[s, k], mean)
                copy1(out.predicted_means[s, k], pm)
                out.nis[s, k] = nis(w, z)
            if sharing:  # series lo's, which these are
                copy2(out.factors[s, k], L)
                copy2(out.predicted_factors[s, k], pL)
                copy2(out.covs[s, k], out.covs[lo, k])
                copy2(out.predicted_covs[s, k], out.predicted_covs[lo, k])
                copy2(out.innovation_covs[s, k], out.innovation_covs[lo, k])
            elif keep_covs:
                copy2(out.factors[s, k], L)
                copy2(out.predicted_factors[s, k], pL)
                square(L, out.covs[s, k])
                square(pL, out.predicted_covs[s, k])
                # S = sym(H P⁻ Hᵀ + R), as the covariance form writes it
                congruence(H, out.predicted_covs[s, k], at(model.R, k), out.innovation_covs[s, k], w.HP, m, n)
        out.loglik[s] = total
        copy1(out.last_mean[s], mean)
        square(L, cov0)
        copy2(out.last_cov[s], cov0)
    scratch[1][0] = 0.0  # alive until here


KERNELS = (forward, forward_sqrt)
"""The forward kernels (numba dispatchers); the backward ones are :mod:`._rts`'s."""

# ---------------------------------------------------------------------------
# Python side: arrange the arguments, call the kernels, raise errors
# ---------------------------------------------------------------------------


def _layout(model, us: np.ndarray | None, target: np.ndarray | None = None) -> Model:
    """The model as :class:`Model`: matrices (T or 1, rows, cols), offsets ``b = B_k u_k``; the covariance to hold."""
    F, H, Q, R = (readonly(a if a.ndim == 3 else a[None]) for a in (model.F, model.H, model.Q, model.R))
    if us is None:
        b = np.zeros((1, 1, model.n))
    else:
        if us.shape[0] > 1 and us.strides[0] == 0:  # one control series broadcast to all
            us = us[:1]
        B = model.B
        b = np.einsum("tnp,itp->itn" if B.ndim == 3 else "np,itp->itn", B, us)
    m = model.m
    held = np.zeros((0, 0)) if target is None else np.ascontiguousarray(target, dtype=np.float64)
    return Model(F, H, Q, R, readonly(b), readonly(np.zeros(m)), np.zeros(m, dtype=np.bool_), readonly(held),
                 SETTLED if target is None else STEADY_TOL)


def _run_forward(model, prior, zs, us, keep: str, smoothing: bool, target: np.ndarray | None = None) -> Outputs:
    """Run the forward kernel over the series `zs` (N, T, m); raise what a failed series would."""
    zs = readonly(zs)
    N, T, m = zs.shape
    n = model.n
    out = outputs(N, T, n, m, keep, smoothing)
    fail = failures(N, m)
    args = (_layout(model, us, target), zs, readonly(prior.mean), readonly(prior.cov), out, fail)
    if n >= BLAS_FROM:  # BLAS parallelises the products itself: the series one after another
        forward(0, N, *args, workspace(n, m))
    else:
        launch(lambda lo, hi, *a: forward(lo, hi, *a, workspace(n, m)), N, *args)
    raise_failure(fail)
    if smoothing:
        _rts.least_squares_gains(out.gains, out.failed, out.predicted_covs)
    return out


def filter(lin, model, prior, zs, us, keep, target: np.ndarray | None = None, form: str = "cov") -> FilterResult:
    """The Kalman filter over N series: `zs` (N, T, m), `us` (N, T, p) or None.

    Returns a FilterResult whose fields all carry the leading N axis; fields
    that `keep` leaves out are None and never allocated. With `target` (the
    stationary filtered covariance), the steady-state filter (see
    kalman.SteadyState); with ``form="sqrt"``, the square-root filter.
    """
    if form == "sqrt":
        return filter_result(_run_sqrt(model, prior, zs, us, keep)[0])
    return filter_result(_run_forward(model, prior, zs, us, keep, smoothing=False, target=target))


def _factors(stack: np.ndarray, name: str) -> np.ndarray:
    """kalman.cov_factor of each matrix of a (T or 1, k, k) stack, read-only."""
    return readonly(np.stack([cov_factor(a, name) for a in stack]))


def _run_sqrt(model, prior, zs, us, keep: str) -> tuple[Outputs, Model, np.ndarray]:
    """Run the square-root kernel over the series `zs` (N, T, m); raise what a failed series would.

    Returns the outputs, the model's layout and the factors of its Q (for the smoother).
    """
    zs = readonly(zs)
    N, T, m = zs.shape
    n = model.n
    layout = _layout(model, us)
    out = outputs(N, T, n, m, keep, False, sqrt=True)
    fail = failures(N, m)
    Qf = _factors(layout.Q, "Q")
    forward_sqrt(0, N, layout, Qf, _factors(layout.R, "R"), zs, readonly(prior.mean),
                 readonly(cov_factor(prior.cov, "the prior covariance")), out, fail, workspace(n, m),
                 sqrt_workspace(n, m))
    raise_failure(fail)
    return out, layout, Qf


def smooth(lin, model, prior, zs, us, ending=None) -> SmoothResult:
    """The Kalman filter and RTS smoother over N series (see :func:`filter`).

    With `ending` (a Gaussian), the backward passes start from it at the
    last step instead of the last filtered belief.
    """
    out = _run_forward(model, prior, zs, us, "all", smoothing=True)
    angles = np.zeros(model.n, dtype=np.bool_)
    means, covs = out.means, out.covs
    if ending is not None:
        means, covs = means.copy(), covs.copy()
        means[:, -1], covs[:, -1] = ending.mean, ending.cov
    sm_means, sm_covs = _rts.smooth(means, covs, out.predicted_means, out.predicted_covs, out.gains, angles,
                                    out.leader)
    check_smoothed(sm_means, sm_covs)
    return SmoothResult(sm_means, sm_covs, out.gains, filter_result(out))


def smooth_sqrt(lin, model, prior, zs, us) -> tuple[SmoothResult, np.ndarray]:
    """The square-root filter and RTS smoother over N series, and which series the readable path must smooth.

    Returns the result and a bool array (N,): True for a series whose
    backward pass met a singular prediction or an overflow (the driver
    smooths it on the readable path, which takes the least-squares gain or
    raises the error, naming the step).
    """
    out, layout, Qf = _run_sqrt(model, prior, zs, us, "all")
    N, T, n = out.means.shape
    sm_means, sm_factors = np.empty_like(out.means), np.empty_like(out.factors)
    gains, failed = np.empty((N, max(T - 1, 0), n, n)), np.zeros(N, dtype=np.bool_)
    if T:
        _rts.backward_sqrt(0, N, out.means, out.factors, layout.F, Qf, layout.b, np.empty((N, 0, 2 * n, 2 * n)),
                           np.empty((N, 0, n)), np.zeros(n, dtype=np.bool_), sm_means, sm_factors, gains, failed)
    sm_means[failed], sm_factors[failed] = 0.0, 0.0  # left unwritten where they stopped: the driver fills them in
    return SmoothResult(sm_means, symmetrize(sm_factors @ sm_factors.swapaxes(-1, -2)), gains, filter_result(out), cov_factors=sm_factors), failed
