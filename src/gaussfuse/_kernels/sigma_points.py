r"""Compiled sigma-point filters and smoothers: methods "ukf", "ckf" and "ghkf".

The loop of :func:`gaussfuse.inference.drivers.run_filter` with the
:class:`~gaussfuse.linearize.SigmaPoints` strategy: at step k, the
regression of f at the belief (:func:`._slr.regress`), its :math:`\Omega`
added to :math:`Q_k`, :func:`._step.predict`; the regression of h at the
prediction, its :math:`\Omega` added to :math:`R_k`, :func:`._step.update`
(the Joseph form); state angles wrapped after each, and the overflow check
of kalman.step. The algebra is :mod:`._slr`'s and :mod:`._step`'s; this
module only sequences it and calls f and h. When smoothing, the gain
:math:`G_{k-1}` is computed at step k from the regression of f at the
filtered belief :math:`(m_{k-1}, P_{k-1})`, the one run_smoother
re-linearises at, and :mod:`._rts` runs the backward pass.

A step is four stages, run by a small state machine (:func:`advance`) whose
position is a :class:`Cursor`:

1. ``DRAW_F``: the sigma points of the belief (a new series starts from the
   prior; a finished one stores its last belief and log-likelihood);
2. ``FORECAST``: given f at those points, the prediction;
3. ``DRAW_H``: the sigma points of the prediction;
4. ``CORRECT``: given h at those points, the update; then the next step.

The machine stops where it needs something it cannot compute: f's or h's
values (``NEED_F``, ``NEED_H``), or the square root of a covariance that is
not positive definite (``NEED_ROOT``: the caller puts
:func:`gaussfuse._linalg.sqrt_cov`'s semi-definite factor in the
regression's ``L`` and ``keep``, as the readable path does, and resumes).
Two execution modes, chosen per call (:func:`execution_mode`), drive it:

* **compiled** -- f and h are numba-compiled functions
  (:func:`numba.extending.is_jitted`): :func:`run`, compiled once per
  *signature* of f and h (f(x) or f(x, u); array or scalar results; one
  state or a stack of states for ``vectorized=True``) and cached on disk,
  receives them as first-class function values and evaluates them itself,
  calling :func:`advance` (the Python mode's kernel) between them the same
  way, through its address: the whole forward pass is compiled, and a new
  signature of f and h compiles only the small loop (0.45 s here), not
  the step again (25 s). f and h must accept C-contiguous float64 arrays and
  return float64 arrays (or a float when the output has one component). A
  jitted function that does not fit (another return type, a locked
  signature) runs in the Python mode, with the same results.
* **python** -- plain Python f and h: the loop is Python, calling f and h
  once per sigma point (or once per step on the (k, n) stack when the model
  is vectorized) and :func:`advance` twice a step for everything between
  (its arguments held, borrowed, in one structure, :func:`hold`, that numba
  unboxes once for the whole run, not at every call).

The square-root form (``form="sqrt"``: :func:`gaussfuse.kalman.step_sqrt`
through SigmaPoints' ``transition_sqrt`` and ``measurement_sqrt``) runs the
same machine on a :class:`SqrtBelief`, whose type selects, when compiled,
each stage's square-root version: the points are drawn from the factor,
:func:`._slr.regress_sqrt` carries the regression's error as factor columns,
:func:`._step.predict_sqrt` and :func:`._step.update_sqrt` triangularise
them and :func:`._step.downdate` takes away those of negative weights. A
factor with a zero pivot (whose regression is the readable path's
least-squares solve) or a downdate that fails stops the run with
:class:`gaussfuse.errors.ReadablePath`, and the driver runs the call on the
readable path. When smoothing, the forward pass stores each transition's
joint factor (:func:`._step.joint_factor`) for :func:`._rts.backward_sqrt`.

Model-function errors (an exception, a wrong shape, a non-finite value) and
failed factorisations raise the same :class:`ModelFunctionError` /
:class:`numpy.linalg.LinAlgError` messages as the readable path, prefixed
by "at step k: " ("in series s, at step k: " for a batch), and a predicted,
filtered or smoothed belief that is not finite (an overflow) the same
:class:`FloatingPointError`.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np
from numba import types
from numba.experimental import structref
from numba.core.errors import NumbaError, NumbaExperimentalFeatureWarning
from numba.extending import is_jitted, overload, register_jitable

from .._linalg import UNRESOLVED, sqrt_cov, symmetrize, weighed
from ..kalman import cov_factor
from .._validation import call_checked, call_each, raise_call, size_reason
from ..errors import ModelFunctionError
from ..inference.results import SmoothResult, check_smoothed
from . import _rts
from ._jit import cached_signatures, entry_point, jit
from ._nrt import borrow, readonly
from ._slr import Rule, draw, points, regress, regress_sqrt, regression
from ._step import (FILTERED_NOT_FINITE, PREDICTED_NOT_FINITE, READABLE, SqrtBack, SqrtWork, at, copy1, copy2, downdate,
                    failures, filter_result, joint_factor, nis, not_finite, not_finite_factor, outputs, predict,
                    predict_mean, predict_sqrt, raise_failure, record, record_not_pd, smoother_gain, sqrt_back_workspace,
                    sqrt_workspace, square, update, update_sqrt, where, workspace, wrap)

__all__ = ["filter", "smooth", "smooth_sqrt", "execution_mode", "loop_state", "advance", "advance_sqrt", "hold"]

_JIT = {"nogil": True, "error_model": "numpy"}
_F64 = np.dtype(np.float64)

# Stages of a step, and what advance() and run() return.
START, DRAW_F, FORECAST, DRAW_H, CORRECT = range(5)
DONE, NEED_F, NEED_H, NEED_ROOT, FAILED = range(5)
# Failure codes beyond _step's: f or h returned a non-finite value, or (compiled mode) a wrong shape; and a
# square-root step that needs the readable path (a singular factor, or a downdate or update that fails).
F_NOT_FINITE, H_NOT_FINITE, F_SHAPE, H_SHAPE = 10, 11, 12, 13
DRAWN = -1  # a draw's status when the points are drawn


class Problem(NamedTuple):
    """The model, prior and measurements as the kernels read them (read-only)."""

    zs: np.ndarray                  # (N, T, m)
    Q: np.ndarray                   # (T or 1, n, n)
    R: np.ndarray                   # (T or 1, m, m)
    rule: Rule
    state_angles: np.ndarray        # (n,) bool
    measurement_angles: np.ndarray  # (m,) bool
    m0: np.ndarray                  # (n,)
    P0: np.ndarray                  # (n, n)
    Qf: np.ndarray                  # (T or 1, n, n) the factors of Q (square-root form; else length 0)
    Rf: np.ndarray                  # (T or 1, m, m) the factors of R (idem)
    L0: np.ndarray                  # (n, n) the factor of P0 (idem)


class Belief(NamedTuple):
    """The current series' belief and scratch, kept between calls of :func:`advance`."""

    mean: np.ndarray        # (n,) the filtered belief
    cov: np.ndarray         # (n, n)
    pmean: np.ndarray       # (n,) the prediction
    pcov: np.ndarray        # (n, n)
    innovation: np.ndarray  # (m,)
    S: np.ndarray           # (m, m)
    X: np.ndarray           # (k, n) the points of the belief, where f is evaluated
    Xh: np.ndarray          # (k, n) the points of the prediction, where h is evaluated
    Q: np.ndarray           # (n, n) Q_k + Ω
    R: np.ndarray           # (m, m) R_k + Ω
    loglik: np.ndarray      # (1,) the series' log-likelihood so far


class SqrtBelief(NamedTuple):
    r""":class:`Belief` for the square-root form: ``cov`` and ``pcov`` hold the factors L and L⁻; and its scratch.

    k points, n states, m measurement components; the columns of a
    regression's noise are :math:`[L_Q, \sqrt{w_i} e_i]` (positive
    weights) and :math:`\sqrt{-w_i} e_i` (negative ones), see
    :func:`._slr.regress_sqrt`.
    """

    mean: np.ndarray        # (n,)
    cov: np.ndarray         # (n, n) L
    pmean: np.ndarray       # (n,)
    pcov: np.ndarray        # (n, n) L⁻
    innovation: np.ndarray  # (m,)
    S: np.ndarray           # (m, m)
    X: np.ndarray           # (k, n)
    Xh: np.ndarray          # (k, n)
    loglik: np.ndarray      # (1,)
    E: np.ndarray           # (k, max(n, m)) the residuals e_i
    At: np.ndarray          # (n, max(n, m)) Aᵀ
    Qc: np.ndarray          # (n, n + k) [L_Q, √w e]
    Qm: np.ndarray          # (n, k) √-w e
    Rc: np.ndarray          # (m, m + k) [L_R, √w e]
    Rm: np.ndarray          # (m, k) √-w e
    sw: SqrtWork
    bw: SqrtBack
    joint: np.ndarray       # (N, T - 1 or 0, 2n, 2n) the smoother's joint factor of each transition
    jpm: np.ndarray         # (N, T - 1 or 0, n) and the mean of its prediction, A m + b


class Cursor(NamedTuple):
    """Where :func:`advance` stands, and what it reports (one-element arrays: written by compiled code)."""

    series: np.ndarray  # int64 (1,)
    step: np.ndarray    # int64 (1,)
    stage: np.ndarray   # int64 (1,): START, DRAW_F, FORECAST, DRAW_H or CORRECT
    given: np.ndarray   # int64 (1,): 1 when the caller gave the root of the next draw
    point: np.ndarray   # int64 (1,): the sigma point of a model-function failure
    got: np.ndarray     # int64 (3,): the shape f or h returned (compiled mode): two sizes and ndim


def _belief(k: int, n: int, m: int) -> Belief:
    return Belief(np.empty(n), np.empty((n, n)), np.empty(n), np.empty((n, n)), np.empty(m), np.empty((m, m)),
                  np.empty((k, n)), np.empty((k, n)), np.empty((n, n)), np.empty((m, m)), np.zeros(1))


def _sqrt_belief(k: int, n: int, m: int, N: int, T: int, smoothing: bool) -> SqrtBelief:
    d = max(n, m)
    links = max(T - 1, 0) if smoothing else 0
    return SqrtBelief(np.empty(n), np.empty((n, n)), np.empty(n), np.empty((n, n)), np.empty(m), np.empty((m, m)),
                      np.empty((k, n)), np.empty((k, n)), np.zeros(1), np.empty((k, d)),
                      np.empty((n, d)), np.empty((n, n + k)), np.empty((n, k)), np.empty((m, m + k)),
                      np.empty((m, k)), sqrt_workspace(n, m, k), sqrt_back_workspace(n, k),
                      np.empty((N, links, 2 * n, 2 * n)), np.empty((N, links, n)))


def _cursor(first: int) -> Cursor:
    return Cursor(np.array([first]), np.zeros(1, dtype=np.int64), np.array([START]), np.zeros(1, dtype=np.int64),
                  np.zeros(1, dtype=np.int64), np.zeros(3, dtype=np.int64))


# ---------------------------------------------------------------------------
# The stages
# ---------------------------------------------------------------------------


@register_jitable(**_JIT)
def _first_not_finite(Y):
    """The first row of Y holding inf or NaN, or -1."""
    for i in range(Y.shape[0]):
        for j in range(Y.shape[1]):
            if not math.isfinite(Y[i, j]):
                return i
    return -1


@register_jitable(**_JIT)
def _noise(base, omega, out):
    """``out = base + Ω``: the noise covariance of step k plus the regression's error (SigmaPoints)."""
    for a in range(out.shape[0]):
        for b in range(out.shape[1]):
            out[a, b] = base[a, b] + omega[a, b]


@register_jitable(**_JIT)
def _wrap_angles(x, angles):
    """The components of x that are angles, wrapped to [-π, π)."""
    for a in range(x.shape[0]):
        if angles[a]:
            x[a] = wrap(x[a])


@jit(inline="always", **_JIT)
def _accept(s, t, prob, bel, out, w, ll):
    """A finite update of either form: its log-likelihood added, its mean, innovation and NIS kept."""
    bel.loglik[0] += ll
    if out.means.shape[1]:
        copy1(out.means[s, t], bel.mean)
        copy1(out.innovations[s, t], bel.innovation)
        out.nis[s, t] = nis(w, prob.zs[s, t])


@jit(inline="always", **_JIT)
def _forecast(s, t, Y, prob, bel, out, w, gf, fail):
    """kalman.forecast through SigmaPoints.transition, with f's values Y at ``bel.X``; False on an overflow."""
    n = bel.mean.shape[0]
    regress(Y, n, prob.rule, bel.mean, prob.state_angles, gf)
    _noise(at(prob.Q, t), gf.noise, bel.Q)
    predict(w, bel.mean, bel.cov, gf.A, bel.Q, gf.b, bel.pmean, bel.pcov)
    _wrap_angles(bel.pmean, prob.state_angles)
    if not_finite(bel.pmean, bel.pcov, 0.0):
        record(fail, s, PREDICTED_NOT_FINITE, t)
        return False
    if out.predicted_means.shape[1]:
        copy1(out.predicted_means[s, t], bel.pmean)
    if out.predicted_covs.shape[1]:
        copy2(out.predicted_covs[s, t], bel.pcov)
    if out.gains.shape[1] and t > 0:  # G_{t-1} = C (P⁻_t)⁻¹, Cᵀ = A P_{t-1} from predict
        if not smoother_gain(w, bel.pcov, w.A1, out.gains[s, t - 1]):
            out.failed[s, t - 1] = True  # Cᵀ left for the least-squares gain
            copy2(out.gains[s, t - 1], w.A1)
    return True


@jit(inline="always", **_JIT)
def _correct(s, t, Z, prob, bel, out, w, gh, fail):
    """kalman.correct through SigmaPoints.measurement, with h's values Z at ``bel.Xh``; False if it fails."""
    m = prob.zs.shape[2]
    regress(Z, m, prob.rule, bel.pmean, prob.measurement_angles, gh)
    _noise(at(prob.R, t), gh.noise, bel.R)
    ok, ll, mo = update(w, bel.pmean, bel.pcov, prob.zs[s, t], gh.A, bel.R, gh.b, prob.measurement_angles,
                        bel.mean, bel.cov, bel.innovation, bel.S)
    if not ok:
        record_not_pd(fail, s, t, w, mo)
        return False
    _wrap_angles(bel.mean, prob.state_angles)
    if not_finite(bel.mean, bel.cov, ll):
        record(fail, s, FILTERED_NOT_FINITE, t)
        return False
    _accept(s, t, prob, bel, out, w, ll)
    if out.covs.shape[1]:
        copy2(out.covs[s, t], bel.cov)
        copy2(out.innovation_covs[s, t], bel.S)
    return True


@jit(inline="always", **_JIT)
def _draw(cursor, bel, prob, g, predicted, s, t, fail):
    """The points of the belief (`predicted`: of the prediction): through the root the caller gave, or the
    Cholesky factor; DRAWN, or NEED_ROOT if it has none."""
    mean, cov, X = (bel.pmean, bel.pcov, bel.Xh) if predicted else (bel.mean, bel.cov, bel.X)
    if cursor.given[0]:
        cursor.given[0] = 0
        points(mean, prob.rule, g, X)
        return DRAWN
    return DRAWN if draw(mean, cov, prob.rule, g, X) else NEED_ROOT


# ---------------------------------------------------------------------------
# The square-root form's stages (kalman.forecast_sqrt / correct_sqrt through SigmaPoints)
# ---------------------------------------------------------------------------


@register_jitable(**_JIT)
def _columns(E, d, wc, base, plus, minus):
    """``plus = [base, √w_i e_i]`` over the positive weights and ``minus = [√-w_i e_i]`` over the negative
    ones (linearize.sigma_points.slr_sqrt's Ω₊ and Ω₋ after the noise's factor); returns their widths."""
    r = base.shape[1]
    for a in range(d):
        for c in range(r):
            plus[a, c] = base[a, c]
    q = r
    p = 0
    for i in range(wc.shape[0]):
        if wc[i] > 0.0:
            root = math.sqrt(wc[i])
            for a in range(d):
                plus[a, q] = E[i, a] * root
            q += 1
        elif wc[i] < 0.0:
            root = math.sqrt(-wc[i])
            for a in range(d):
                minus[a, p] = E[i, a] * root
            p += 1
    return q, p


@jit(inline="always", **_JIT)
def _draw_sqrt(cursor, bel, prob, g, predicted, s, t, fail):
    """The points ``m + L ξ_i`` of the factor itself; READABLE (a FAILED status) where it has a zero pivot."""
    mean, L, X = (bel.pmean, bel.pcov, bel.Xh) if predicted else (bel.mean, bel.cov, bel.X)
    n = mean.shape[0]
    for a in range(n):
        row = 0.0
        for b in range(a + 1):
            row += L[a, b] * L[a, b]
        # a singular factor, or a spread below the mean's resolution: the readable path's least-squares regression
        if not L[a, a] > 0.0 or math.sqrt(row) <= UNRESOLVED * abs(mean[a]):
            record(fail, s, READABLE, t)
            return FAILED
        g.keep[a] = True
        for b in range(n):
            g.L[a, b] = L[a, b] if b <= a else 0.0
    points(mean, prob.rule, g, X)
    return DRAWN


@jit(inline="always", **_JIT)
def _forecast_sqrt(s, t, Y, prob, bel, out, w, gf, fail):
    """kalman.forecast_sqrt through SigmaPoints.transition_sqrt, with f's values Y; False if it fails.

    When smoothing, the joint factor of :math:`(x_t, x_{t-1})` from the same
    regression (kalman.joint_factor, what run_smoother re-linearises at)
    is stored for the backward pass.
    """
    n = bel.mean.shape[0]
    regress_sqrt(Y, n, prob.rule, bel.mean, prob.state_angles, gf, bel.E, bel.At)
    q, p = _columns(bel.E, n, prob.rule.wc, at(prob.Qf, t), bel.Qc, bel.Qm)
    predict_sqrt(bel.sw, bel.mean, bel.cov, gf.A, bel.Qc[:, :q], gf.b, bel.pmean, bel.pcov)
    if p > 0 and not downdate(bel.pcov, bel.Qm, n, p, bel.sw.v):
        record(fail, s, READABLE, t)
        return False
    if bel.joint.shape[1] and t > 0:
        if not joint_factor(bel.bw, bel.cov, gf.A, bel.Qc[:, :q], bel.Qm[:, :p]):
            record(fail, s, READABLE, t)
            return False
        copy2(bel.joint[s, t - 1], bel.bw.T)
        predict_mean(bel.mean, gf.A, gf.b, bel.jpm[s, t - 1])
    _wrap_angles(bel.pmean, prob.state_angles)
    if not_finite_factor(bel.pmean, bel.pcov, 0.0):
        record(fail, s, PREDICTED_NOT_FINITE, t)
        return False
    if out.predicted_means.shape[1]:
        copy1(out.predicted_means[s, t], bel.pmean)
    if out.predicted_covs.shape[1]:
        square(bel.pcov, out.predicted_covs[s, t])
        copy2(out.predicted_factors[s, t], bel.pcov)
    return True


@jit(inline="always", **_JIT)
def _correct_sqrt(s, t, Z, prob, bel, out, w, gh, fail):
    """kalman.correct_sqrt through SigmaPoints.measurement_sqrt, with h's values Z; False if it fails."""
    n = bel.mean.shape[0]
    m = prob.zs.shape[2]
    regress_sqrt(Z, m, prob.rule, bel.pmean, prob.measurement_angles, gh, bel.E, bel.At)
    q, p = _columns(bel.E, m, prob.rule.wc, at(prob.Rf, t), bel.Rc, bel.Rm)
    ok, ll, mo = update_sqrt(w, bel.sw, bel.pmean, bel.pcov, prob.zs[s, t], gh.A, bel.Rc[:, :q], bel.Rm[:, :p],
                             gh.b, prob.measurement_angles, bel.mean, bel.cov, bel.innovation)
    if not ok:  # the readable path downdates, or raises, naming the matrix
        record(fail, s, READABLE, t)
        return False
    _wrap_angles(bel.mean, prob.state_angles)
    if not_finite_factor(bel.mean, bel.cov, ll):
        record(fail, s, FILTERED_NOT_FINITE, t)
        return False
    _accept(s, t, prob, bel, out, w, ll)
    if out.covs.shape[1]:
        square(bel.cov, out.covs[s, t])
        copy2(out.factors[s, t], bel.cov)
        S = out.innovation_covs[s, t]  # sym(H L⁻ (H L⁻)ᵀ + [L_R, Ω₊][L_R, Ω₊]ᵀ - Ω₋ Ω₋ᵀ), as sqrt_gain
        HL = bel.sw.HL
        for a in range(m):
            for b in range(a + 1):
                x = 0.0
                for j in range(n):
                    x += HL[a, j] * HL[b, j]
                r = 0.0
                for c in range(q):
                    r += bel.Rc[a, c] * bel.Rc[b, c]
                for c in range(p):
                    r -= bel.Rm[a, c] * bel.Rm[b, c]
                S[a, b] = x + r
                S[b, a] = x + r
    return True


# ---------------------------------------------------------------------------
# The form of a run is the type of its belief: each stage resolves, when compiled, to its form's version
# ---------------------------------------------------------------------------


def _is_sqrt(bel) -> bool:
    return isinstance(bel, types.BaseNamedTuple) and bel.instance_class is SqrtBelief


def _begin(prob, bel):  # pragma: no cover - replaced by the overload in compiled code
    raise NotImplementedError


@overload(_begin)
def _begin_overload(prob, bel):
    """A series starts at the prior: its covariance, or its factor."""
    if _is_sqrt(bel):
        def impl(prob, bel):
            copy1(bel.mean, prob.m0)
            copy2(bel.cov, prob.L0)
            bel.loglik[0] = 0.0
    else:
        def impl(prob, bel):
            copy1(bel.mean, prob.m0)
            copy2(bel.cov, prob.P0)
            bel.loglik[0] = 0.0
    return impl


def _end(s, bel, out):  # pragma: no cover - replaced by the overload in compiled code
    raise NotImplementedError


@overload(_end)
def _end_overload(s, bel, out):
    """A series is done: its log-likelihood and last belief (the covariance squared from its factor)."""
    if _is_sqrt(bel):
        def impl(s, bel, out):
            out.loglik[s] = bel.loglik[0]
            copy1(out.last_mean[s], bel.mean)
            square(bel.cov, out.last_cov[s])
    else:
        def impl(s, bel, out):
            out.loglik[s] = bel.loglik[0]
            copy1(out.last_mean[s], bel.mean)
            copy2(out.last_cov[s], bel.cov)
    return impl


def _draw_any(cursor, bel, prob, g, predicted, s, t, fail):  # pragma: no cover - replaced by the overload
    raise NotImplementedError


@overload(_draw_any)
def _draw_any_overload(cursor, bel, prob, g, predicted, s, t, fail):
    if _is_sqrt(bel):
        return lambda cursor, bel, prob, g, predicted, s, t, fail: _draw_sqrt(cursor, bel, prob, g, predicted, s, t,
                                                                              fail)
    return lambda cursor, bel, prob, g, predicted, s, t, fail: _draw(cursor, bel, prob, g, predicted, s, t, fail)


def _forecast_any(s, t, Y, prob, bel, out, w, gf, fail):  # pragma: no cover - replaced by the overload
    raise NotImplementedError


@overload(_forecast_any)
def _forecast_any_overload(s, t, Y, prob, bel, out, w, gf, fail):
    if _is_sqrt(bel):
        return lambda s, t, Y, prob, bel, out, w, gf, fail: _forecast_sqrt(s, t, Y, prob, bel, out, w, gf, fail)
    return lambda s, t, Y, prob, bel, out, w, gf, fail: _forecast(s, t, Y, prob, bel, out, w, gf, fail)


def _correct_any(s, t, Z, prob, bel, out, w, gh, fail):  # pragma: no cover - replaced by the overload
    raise NotImplementedError


@overload(_correct_any)
def _correct_any_overload(s, t, Z, prob, bel, out, w, gh, fail):
    if _is_sqrt(bel):
        return lambda s, t, Z, prob, bel, out, w, gh, fail: _correct_sqrt(s, t, Z, prob, bel, out, w, gh, fail)
    return lambda s, t, Z, prob, bel, out, w, gh, fail: _correct(s, t, Z, prob, bel, out, w, gh, fail)


@jit(inline="always", **_JIT)
def _advance(cursor, Y, prob, bel, out, w, gf, gh, fail):
    """Run the stages from the cursor until one needs f, h or a root, or every series is done (see the module notes)."""
    N, T = prob.zs.shape[0], prob.zs.shape[1]
    s, t, stage = cursor.series[0], cursor.step[0], cursor.stage[0]
    status = DONE
    while True:
        if stage == START:  # series s begins at the prior
            _begin(prob, bel)
            t = 0
            stage = DRAW_F
        if stage == DRAW_F:
            if t == T:  # series s is done
                _end(s, bel, out)
                s += 1
                if s == N:
                    status = DONE
                    break
                stage = START
                continue
            got = _draw_any(cursor, bel, prob, gf, False, s, t, fail)
            if got != DRAWN:
                status = got
                break
            stage = FORECAST
            status = NEED_F
            break
        if stage == FORECAST:
            i = _first_not_finite(Y)
            if i >= 0:
                cursor.point[0] = i
                record(fail, s, F_NOT_FINITE, t)
                status = FAILED
                break
            if not _forecast_any(s, t, Y, prob, bel, out, w, gf, fail):
                status = FAILED
                break
            stage = DRAW_H
        if stage == DRAW_H:
            got = _draw_any(cursor, bel, prob, gh, True, s, t, fail)
            if got != DRAWN:
                status = got
                break
            stage = CORRECT
            status = NEED_H
            break
        if stage == CORRECT:
            i = _first_not_finite(Y)
            if i >= 0:
                cursor.point[0] = i
                record(fail, s, H_NOT_FINITE, t)
                status = FAILED
                break
            if not _correct_any(s, t, Y, prob, bel, out, w, gh, fail):
                status = FAILED
                break
            t += 1
            stage = DRAW_F
    cursor.series[0] = s
    cursor.step[0] = t
    cursor.stage[0] = stage
    return status


@structref.register
class _HeldType(types.StructRef):
    """The numba type of :class:`_Held`."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class _Held(structref.StructRefProxy):
    """:func:`advance`'s arguments but f's or h's values, unboxed once for a whole run of the Python mode.

    Handing numba the tuples of arrays at every call unboxes each of their
    (about seventy) arrays every time, several microseconds a call; a
    structure holding them is one pointer.
    """


structref.define_proxy(_Held, _HeldType, ["args"])


@jit(**_JIT)
def hold(cursor, prob, bel, out, w, gf, gh, fail):
    """A :class:`_Held` of :func:`advance`'s arguments, borrowed, made by compiled (and cached) code.

    ``_Held(...)`` called from Python would compile numba's constructor in
    every process, uncached: seconds on a first call. The arguments are held
    borrowed (:func:`._nrt.borrow`), so that taking them out costs no
    reference counting (two atomic operations for each of about seventy
    arrays, at every call): the caller keeps them alive while the
    :class:`_Held` is in use.
    """
    return _Held(borrow((cursor, prob, bel, out, w, gf, gh, fail)))


@jit(inline="always", **_JIT)
def _advance_held(held, Y):
    cursor, prob, bel, out, w, gf, gh, fail = held.args  # borrowed already (see hold)
    return _advance(cursor, borrow(Y), prob, bel, out, w, gf, gh, fail)


@jit(**_JIT)
def advance(held, Y):
    """The step's kernel: :func:`_advance` with f's or h's values `Y` (k, n or m) from the caller.

    Called from Python in the Python mode, and from :func:`run`, through its
    address, in the compiled mode. `held` (made by :func:`hold`) keeps the
    cursor, problem, belief, outputs, workspace, regressions and failures.
    The caller holds every array for the call (see :mod:`._nrt`).
    """
    return _advance_held(held, Y)


@jit(**_JIT)
def advance_sqrt(held, Y):
    """:func:`advance` for the square-root form (a :class:`SqrtBelief` in `held`).

    A function of its own, so that numba's cache and its compiled
    signatures name it apart: :func:`gaussfuse._kernels.kernel_states`
    reads those of :func:`advance` to tell whether the covariance form's
    kernel is compiled, and must not take this one for it.
    """
    return _advance_held(held, Y)


# ---------------------------------------------------------------------------
# Compiled mode: f and h evaluated in the loop, as first-class functions
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


def _apply(fn, X, us, s, k, Y, cursor):  # pragma: no cover - replaced by the overload in compiled code
    raise NotImplementedError


@overload(_apply)  # compiled into, and cached with, the loop that calls it
def _apply_overload(fn, X, us, s, k, Y, cursor):
    """Evaluate a first-class model function at the points X into Y; False for a wrong shape.

    Specialised on the function's signature: per point or on the stack,
    returning an array or a scalar. A wrong shape is reported in
    ``cursor.point`` and ``cursor.got``; non-finite values are left for
    :func:`_advance` to find, point by point, as ``call_checked`` does.
    """
    if not isinstance(fn, types.FunctionType):
        return None
    sig = fn.signature
    if sig.args[0].ndim == 2:
        def impl(fn, X, us, s, k, Y, cursor):
            out = _call(fn, X, us, s, k)
            cursor.point[0] = 0
            if out.shape[0] != Y.shape[0] or out.shape[1] != Y.shape[1]:
                cursor.got[0] = out.shape[0]
                cursor.got[1] = out.shape[1]
                cursor.got[2] = 2
                return False
            for i in range(Y.shape[0]):
                for j in range(Y.shape[1]):
                    Y[i, j] = out[i, j]
            return True
    elif isinstance(sig.return_type, (types.Float, types.Integer)):
        def impl(fn, X, us, s, k, Y, cursor):
            for i in range(X.shape[0]):
                Y[i, 0] = _call(fn, X[i], us, s, k)
            return True
    else:
        def impl(fn, X, us, s, k, Y, cursor):
            d = Y.shape[1]
            for i in range(X.shape[0]):
                cursor.point[0] = i
                out = _call(fn, X[i], us, s, k)
                if out.shape[0] != d:
                    cursor.got[0] = out.shape[0]
                    cursor.got[2] = 1
                    return False
                for j in range(d):
                    Y[i, j] = out[j]
            return True
    return impl


def run(f, h, step, us, held, Yf, Yh):
    """The compiled mode's kernel: :func:`advance` (`step`), evaluating f and h itself (see the module notes).

    f, h and `step` are first-class functions: called through their
    addresses, so that this loop, compiled once per signature of f and h,
    holds none of the step's code (compiling it takes under a second, not the step's
    half a minute). `held` is :func:`hold`'s. Returns DONE, NEED_ROOT or
    FAILED. While f or h runs, ``cursor.stage`` is FORECAST or CORRECT and
    ``cursor.step`` the step: what the caller needs to name an exception
    raised in them.
    """
    cursor, prob, bel, out, w, gf, gh, fail = held.args
    Y = Yf
    while True:
        status = step(held, Y)
        s, t = cursor.series[0], cursor.step[0]
        if status == NEED_F:
            Y = Yf
            if not _apply(f, bel.X, us, s, t, Y, cursor):
                record(fail, s, F_SHAPE, t)
                return FAILED
        elif status == NEED_H:
            Y = Yh
            if not _apply(h, bel.Xh, us, s, t, Y, cursor):
                record(fail, s, H_SHAPE, t)
                return FAILED
        else:
            return status


_C1 = types.float64[::1]
_C2 = types.float64[:, ::1]
_LOOPS: dict = {}


def _loop_key(f_sig, h_sig, controls: bool, sqrt: bool) -> tuple:
    """What a compiled :func:`run` is specialised on: f's and h's signatures, controls or none, the form."""
    return f_sig, h_sig, controls, sqrt


def _run_for(f_sig, h_sig, args, sqrt: bool) -> object:
    """:func:`run` compiled for these function signatures and the types of `args` (compiled once, cached on disk).

    `args` are :func:`run`'s after f, h and the step: ``(us, held, Yf, Yh)``; `sqrt`, the form.
    """
    us, held, Yf, _ = args
    key = _loop_key(f_sig, h_sig, us is not None, sqrt)
    if key not in _LOOPS:
        from numba import typeof

        held_t, Y_t = typeof(held), typeof(Yf)
        sig = types.int64(types.FunctionType(f_sig), types.FunctionType(h_sig),
                          types.FunctionType(types.int64(held_t, Y_t)), typeof(us), held_t, Y_t, Y_t)
        with warnings.catch_warnings():  # first-class function types are "experimental" in numba
            warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
            _LOOPS[key] = jit(sig, **_JIT)(run)
    return _LOOPS[key]


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


def loop_state(model, prior, us=None, form: str = "cov") -> str | None:
    """Whether :func:`run` is compiled for the model's numba-jitted f and h: "loaded", "cached" or "cold".

    None when f and h do not fit the compiled mode (the call runs the
    Python mode's :func:`advance`). "loaded": compiled, or loaded, in this
    process; "cached": numba's disk cache holds it for these signatures of
    f and h (and controls and form), from the current sources; "cold"
    otherwise. `us`, when given, is the (N, T, p) array of controls.
    """
    sigs = _jitted_signatures(model, prior, us)
    if sigs is None:
        return None
    key = _loop_key(sigs[0], sigs[1], us is not None, form == "sqrt")
    if key in _LOOPS:
        return "loaded"
    for sig in cached_signatures(run):  # run(f, h, step, us, held, Yf, Yh)
        args = sig.args
        if (len(args) == 7 and args[0] == types.FunctionType(sigs[0]) and args[1] == types.FunctionType(sigs[1])
                and (args[3] != types.none) == key[2] and _held_form(args[4]) == key[3]):
            return "cached"
    return "cold"


def _held_form(held_type) -> bool | None:
    """Whether a :class:`_Held` type holds a :class:`SqrtBelief` (None: not a _Held's type)."""
    fields = getattr(held_type, "field_dict", {}).get("args")
    belief = fields[2] if isinstance(fields, types.BaseTuple) and len(fields) > 2 else None
    return {SqrtBelief: True, Belief: False}.get(getattr(belief, "instance_class", None))


def execution_mode(model, prior, us=None) -> str:
    """``"compiled"`` when the model's f and h fit the compiled loop, otherwise ``"python"``.

    `us`, when given, is the (N, T, p) array of controls.
    """
    return "python" if _jitted_signatures(model, prior, us) is None else "compiled"


# ---------------------------------------------------------------------------
# Python side: f and h in the Python mode, roots, errors
# ---------------------------------------------------------------------------


def _evaluate(name, fn, X, Y, u, vectorized):
    """f or h at the points X (k, n): the (k, d) outputs, checked for type and shape.

    Non-finite values are found by the compiled stage that follows; the
    type, shape and exception checks stay here, with the messages (and the
    order, point by point) of :func:`gaussfuse._validation.call_checked`.
    """
    args = () if u is None else (u,)
    if vectorized:
        try:
            out = fn(X, *args)
        except Exception as exc:
            raise_call(name, exc, X, args, fn)
        if type(out) is not np.ndarray or out.shape != Y.shape or out.dtype is not _F64:
            out = call_checked(name, lambda *_: out, X, (), Y.shape, size_reason(name, Y.shape[1]))
        if out.strides != Y.strides or not out.flags.writeable:  # a view (say X[:, :1]): copy it
            Y[...] = out
            return Y
        return out
    return call_each(name, fn, X, args, Y.shape[1], finite=False)


def _give_root(cursor: Cursor, bel: Belief, gf, gh, N: int, weights: np.ndarray) -> None:
    """The semi-definite square root of the covariance the stopped draw needs (kalman's sqrt_cov), into gf or gh."""
    stage = int(cursor.stage[0])
    mean, cov, g = (bel.mean, bel.cov, gf) if stage == DRAW_F else (bel.pmean, bel.pcov, gh)
    try:
        L, keep = sqrt_cov(cov, mean, "the filtered covariance" if stage == DRAW_F else "the predicted covariance",
                           weights)
    except np.linalg.LinAlgError as exc:
        raise np.linalg.LinAlgError(f"{where(int(cursor.series[0]), int(cursor.step[0]), N)}: {exc}") from exc
    g.L[...] = L
    g.keep[...] = keep
    cursor.given[0] = 1


def _raise_failed(cursor: Cursor, fail, model, k: int, N: int, weights: np.ndarray) -> None:
    """Raise the readable path's error for a stopped series (a rule's negative covariance `weights` named as the
    likely cause of a covariance that is not positive definite, as the readable path names it)."""
    s = int(cursor.series[0])
    code, step = int(fail.code[s]), int(fail.step[s])
    if code in (F_NOT_FINITE, H_NOT_FINITE, F_SHAPE, H_SHAPE):
        name = "f" if code in (F_NOT_FINITE, F_SHAPE) else "h"
        d = model.n if name == "f" else model.m
        x_shape = (k, model.n) if model.vectorized else (model.n,)
        if code in (F_SHAPE, H_SHAPE):
            want = (k, d) if model.vectorized else (d,)
            got = tuple(int(g) for g in cursor.got[:int(cursor.got[2])])
            message = (f"`{name}` must return shape {want} for an input of shape {x_shape}, "
                       f"because {size_reason(name, d)}; got shape {got}.")
        else:
            message = f"`{name}` returned a non-finite value (NaN or inf) for an input of shape {x_shape}."
        raise ModelFunctionError(f"{where(s, step, N)}: {message}")
    try:
        raise_failure(fail)
    except np.linalg.LinAlgError as exc:
        raise weighed(exc, weights) from None


def _problem(lin, model, prior, zs, sqrt: bool) -> Problem:
    rule = lin.rule
    Q, R = (readonly(a if a.ndim == 3 else a[None]) for a in (model.Q, model.R))
    angles = (np.array(model.state_angles, dtype=np.bool_), np.array(model.measurement_angles, dtype=np.bool_))
    if sqrt:  # kalman.cov_factor of each Q_k, R_k and P0, as SigmaPoints.transition_sqrt's `factors`
        factors = (readonly(np.stack([cov_factor(a, name) for a in stack])) for stack, name in ((Q, "Q"), (R, "R")))
        Qf, Rf = factors
        L0 = readonly(cov_factor(prior.cov, "the prior covariance"))
    else:
        Qf, Rf, L0 = Q[:0], R[:0], readonly(prior.cov)
    return Problem(readonly(zs), Q, R, Rule(readonly(rule.points), readonly(rule.wm), readonly(rule.wc)), *angles,
                   readonly(prior.mean), readonly(prior.cov), Qf, Rf, L0)


def _forward(lin, model, prior, zs, us, keep: str, smoothing: bool, sqrt: bool = False):
    """The forward pass over the series `zs` (N, T, m): the kernel's outputs (see :mod:`._step`), and the belief.

    With `sqrt`, the square-root form: the belief is a :class:`SqrtBelief`,
    which (when smoothing) holds the joint factors for the backward pass.
    Raises :class:`gaussfuse.errors.ReadablePath` where a square-root step
    needs the readable path.
    """
    N, T, m = zs.shape
    n = model.n
    prob = _problem(lin, model, prior, zs, sqrt)
    k = prob.rule.points.shape[0]
    out, fail, w = outputs(N, T, n, m, keep, smoothing and not sqrt, sqrt), failures(N, m), workspace(n, m)
    bel = _sqrt_belief(k, n, m, N, T, smoothing) if sqrt else _belief(k, n, m)
    gf, gh = regression(k, n, n), regression(k, n, m)
    cursor = _cursor(0)
    us = None if us is None else np.require(us, np.float64, ["C", "W"])
    Yf, Yh = np.empty((k, n)), np.empty((k, m))
    sigs = _jitted_signatures(model, prior, us)
    if sigs is not None:
        held = hold(cursor, prob, bel, out, w, gf, gh, fail)
        args = (us, held, Yf, Yh)
        try:
            kernel = _run_for(sigs[0], sigs[1], args, sqrt)
        except (TypeError, NumbaError):  # f or h do not convert to the signature: the Python mode runs them
            sigs = None
    if sigs is None:
        _python_mode(model, us, cursor, Yf, Yh, prob, bel, out, w, gf, gh, fail, k, N)
        return out, bel
    step = advance_sqrt if sqrt else advance
    # Compiled (or loaded) as the Python mode calls it, before the loop asks for its address: numba's disk
    # cache keys a compile for an address (with its return type) apart, and would compile the step twice.
    entry_point(step, held, Yf)
    while True:
        try:
            status = kernel(model.f, model.h, step, *args)
        except Exception as exc:
            stage = int(cursor.stage[0])
            if stage not in (FORECAST, CORRECT):
                raise
            name = "f" if stage == FORECAST else "h"
            try:
                raise_call(name, exc, np.empty((k, n)) if model.vectorized else np.empty(n),
                           () if us is None else (us,), model.f if name == "f" else model.h)
            except ModelFunctionError as err:
                where_ = where(int(cursor.series[0]), int(cursor.step[0]), N)
                raise ModelFunctionError(f"{where_}: {err}") from err
        if status == NEED_ROOT:
            _give_root(cursor, bel, gf, gh, N, prob.rule.wc)
        elif status == FAILED:
            _raise_failed(cursor, fail, model, k, N, prob.rule.wc)
        else:
            return out, bel


def _python_mode(model, us, cursor, Yf, Yh, prob, bel, out, w, gf, gh, fail, k: int, N: int) -> None:
    """The Python mode (see the module notes): f and h called here, :func:`advance` between the calls."""
    f, h, vectorized = model.f, model.h, model.vectorized
    held = hold(cursor, prob, bel, out, w, gf, gh, fail)
    kernel = advance_sqrt if isinstance(bel, SqrtBelief) else advance
    step = entry_point(kernel, held, Yf)  # the compiled function, without numba's dispatch per call
    Y = Yf
    while True:
        status = step(held, Y)
        if status == NEED_F or status == NEED_H:
            s, t = int(cursor.series[0]), int(cursor.step[0])
            try:
                if status == NEED_F:
                    Y = _evaluate("f", f, bel.X, Yf, None if us is None else us[s, t], vectorized)
                else:
                    Y = _evaluate("h", h, bel.Xh, Yh, None, vectorized)
            except ModelFunctionError as exc:
                raise ModelFunctionError(f"{where(s, t, N)}: {exc}") from exc
        elif status == NEED_ROOT:
            _give_root(cursor, bel, gf, gh, N, prob.rule.wc)
        elif status == FAILED:
            _raise_failed(cursor, fail, model, k, N, prob.rule.wc)
        else:
            return


def filter(lin, model, prior, zs, us, keep, form: str = "cov"):
    """The sigma-point filter over N series (see the module notes); results carry the N axis.

    With ``form="sqrt"``, the square-root filter (kalman.step_sqrt through
    SigmaPoints); it raises :class:`gaussfuse.errors.ReadablePath` where a
    step needs the readable path.
    """
    return filter_result(_forward(lin, model, prior, zs, us, keep, smoothing=False, sqrt=form == "sqrt")[0])


def smooth(lin, model, prior, zs, us) -> SmoothResult:
    """The sigma-point RTS smoother over N series; results carry the N axis."""
    out = _forward(lin, model, prior, zs, us, "all", smoothing=True)[0]
    _rts.least_squares_gains(out.gains, out.failed, out.predicted_covs)
    angles = np.array(model.state_angles, dtype=np.bool_)
    sm_means, sm_covs = _rts.smooth(out.means, out.covs, out.predicted_means, out.predicted_covs, out.gains, angles)
    check_smoothed(sm_means, sm_covs)
    return SmoothResult(sm_means, sm_covs, out.gains, filter_result(out))


def smooth_sqrt(lin, model, prior, zs, us) -> tuple[SmoothResult, np.ndarray]:
    """The square-root sigma-point filter and RTS smoother over N series, and which series the readable path must smooth.

    The forward pass stores the joint factor of each transition from its
    regression; :func:`._rts.backward_sqrt` reads them. Returns the result
    and a bool array (N,), True for a series whose backward pass met a
    singular prediction or an overflow (as :func:`.linear.smooth_sqrt`).
    """
    out, bel = _forward(lin, model, prior, zs, us, "all", smoothing=True, sqrt=True)
    N, T, n = out.means.shape
    sm_means, sm_factors = np.empty_like(out.means), np.empty_like(out.factors)
    gains, failed = np.empty((N, max(T - 1, 0), n, n)), np.zeros(N, dtype=np.bool_)
    if T:
        none = readonly(np.empty((1, n, n)))  # read-only, as the linear engine's: one compiled signature for both
        _rts.backward_sqrt(0, N, out.means, out.factors, none, none, readonly(np.empty((1, 1, n))), bel.joint, bel.jpm,
                           np.array(model.state_angles, dtype=np.bool_), sm_means, sm_factors, gains, failed)
    sm_means[failed], sm_factors[failed] = 0.0, 0.0  # left unwritten where they stopped: the driver fills them in
    return SmoothResult(sm_means, symmetrize(sm_factors @ sm_factors.swapaxes(-1, -2)), gains, filter_result(out),
                        cov_factors=sm_factors), failed
