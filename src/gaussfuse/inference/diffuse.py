r"""Exact diffuse initialisation: a flat prior on the first state.

``prior="diffuse"`` says nothing is known about :math:`x_1`, the state at the
first measurement: :math:`x_1 \sim N(0, \kappa I)` with :math:`\kappa \to \infty`,
the convention of Durbin & Koopman (2012, ch. 5), KFAS and statsmodels'
exact diffuse filter. The transition into :math:`x_1` (``F_1``, ``B_1 u_1``,
``Q_1``) plays no part. The limit is computed exactly, not with a large
:math:`\kappa`, by the augmentation argument of de Jong (1991), which gives the
same filter, smoother and likelihood as the exact diffuse Kalman filter of
Koopman (1997):

Write :math:`x_1 = \delta + w`, :math:`w \sim N(0, P_*)` for any fixed
:math:`P_* \succeq 0`: a flat :math:`\delta` makes :math:`x_1` flat whatever
:math:`P_*`, with the same normalisation, so the diffuse results do not depend
on it (it is taken as :math:`Q_2`, the first process noise that is
part of the model, widened where that is singular). Given
:math:`\delta`, the model is an ordinary linear-Gaussian one, and every mean
the Kalman filter and RTS smoother produce is affine in :math:`\delta` while no
covariance depends on it:

.. math::

    m_t(\delta) = m_t^{(0)} + M_t \delta, \qquad
    v_t(\delta) = v_t^{(0)} + V_t \delta, \qquad
    m^s_t(\delta) = m_t^{s(0)} + N_t \delta .

The columns of :math:`M_t, V_t, N_t` are the same filter and smoother run from
:math:`\delta = e_i` on zero data. The likelihood of the measurements up to t is
then a Gaussian in :math:`\delta` with information and score

.. math::

    \mathcal S_t = \sum_{k \le t} V_k^\top S_k^{-1} V_k, \qquad
    s_t = -\sum_{k \le t} V_k^\top S_k^{-1} v_k^{(0)},

so under the flat prior :math:`\delta \mid z_{1:t} \sim N(\mathcal S_t^{-1}
s_t, \mathcal S_t^{-1})` once :math:`\mathcal S_t` is non-singular (the state is
*identified*). Averaging over it,

.. math::

    E[x_t \mid z_{1:t}] = m_t^{(0)} + M_t \hat\delta_t, \qquad
    \operatorname{Cov}[x_t \mid z_{1:t}] = P_t + M_t \mathcal S_t^{-1} M_t^\top,

and the same for the predictions (with :math:`\mathcal S_{t-1}`) and the
smoothed states (with :math:`\mathcal S_T`).

The diffuse log-likelihood is

.. math::

    \log L_d = \sum_t -\tfrac12\left(v_t^{(0)\top} S_t^{-1} v_t^{(0)} + \log|S_t|
    + m_t \log 2\pi\right) + \tfrac12 s_T^\top \mathcal S_T^{-1} s_T
    - \tfrac12 \log|\mathcal S_T|,

with :math:`m_t` the number of observed components at step t: every
observation, including those that identify the initial state, carries the
:math:`\log 2\pi` constant, as in Durbin & Koopman (2012, eq. 7.4), and the
flat prior contributes no constant. It equals statsmodels' exact diffuse
log-likelihood for every transition matrix whose measurements identify
:math:`x_1`, singular ones included (KFAS reports :math:`d \cdot \tfrac12 \log 2\pi`
more, leaving out the constant of the d observations that identify
:math:`x_1`); where a component of
:math:`x_1` is never seen (a singular F forgets it before any measurement),
it is refused as not identified, where statsmodels gives a value.
Filtered and predicted beliefs before the state is identified are NaN; the
prediction for step 1 always is.

References
----------
.. [1] P. de Jong, "The diffuse Kalman filter", Annals of Statistics 19(2), 1991.
.. [2] S. J. Koopman, "Exact initial Kalman filtering and smoothing for
   nonstationary time series models", JASA 92(440), 1997.
.. [3] J. Durbin and S. J. Koopman, *Time Series Analysis by State Space
   Methods*, 2nd ed., Oxford University Press, 2012.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._linalg import (cho_solve, cholesky, is_positive_definite, observed_gram, psd_solve, symmetrize, unit_diagonal,
                       whiten)
from ..diagnostics import nis
from ..errors import at_step, not_finite
from ..gaussian import Gaussian
from ..models.linear import LinearModel
from .drivers import filter_batch, smooth_batch
from .registry import METHODS
from .results import FilterResult, SmoothResult, first

__all__ = ["diffuse_filter", "diffuse_smooth", "diffuse_moments", "augmented_runs", "AugmentedRuns",
           "NotIdentified", "not_identified"]


class AugmentedRuns(NamedTuple):
    """The filter runs of the augmentation (see the module notes)."""

    model: LinearModel            # the model with x_1 = x_0 + w (see _first_state_diffuse)
    base: FilterResult            # from x_0 = centre, on the data
    sens: list[FilterResult]      # from x_0 = e_i, on zero data, no controls
    smoothed: list | None         # (means, covs, gains) from time 0 of base and sens, when asked
    centre: np.ndarray            # (n,): where the base run starts; δ is measured from it


def _first_state_diffuse(model: LinearModel, zs: np.ndarray, us: np.ndarray | None):
    """The model and controls whose step 1 is ``x_1 = x_0 + w``, ``w ~ N(0, P_*)``.

    With ``x_0 = δ`` flat, ``x_1`` is flat (see the module notes), so the
    augmentation over ``x_0`` below is the exact diffuse treatment of ``x_1``.
    Any ``P_*`` gives the same results in exact arithmetic; in floating
    point the runs lose about ε times ``P_*`` to cancellation, so it is
    taken on the scale of the model's own noise: the process noise of the
    first transition that is part of the model (``Q_2``; ``Q_1``, the noise
    into ``x_1``, plays no part and may be anything: 1e16 there cost a
    smoothed variance 37%), where that is positive definite. Else it is
    widened by a multiple of the identity: the largest variance of that
    noise or the median of the measurements' variances over every step,
    whichever is larger (not ``R_1``'s: widened on a noisy first
    measurement, R_1 = 1e16 cost the smoothed covariances 5.9; nor a tiny
    Q's alone, 1e-300, whose information about the diffuse state
    overflowed): with a
    singular ``P_*`` the base run's innovation covariance can be singular
    where a noise-free sensor meets a noise-free state (at the first step,
    or at the first step that sensor is observed), though the diffuse state
    is not known there.
    """
    T, n = zs.shape[0], model.n
    Q_star = np.array(model.at(min(1, T - 1))[2])
    P_star = Q_star
    if not is_positive_definite(P_star):
        sensed = np.diagonal(model.R, axis1=-2, axis2=-1)
        sensed = sensed[sensed > 0.0]
        scale = max(np.max(np.diag(Q_star)), float(np.median(sensed)) if sensed.size else 0.0)
        P_star = P_star + (scale if scale > 0 else 1.0) * np.eye(n)
    F = np.array(np.broadcast_to(model.F, (T, n, n)))
    Q = np.array(np.broadcast_to(model.Q, (T, n, n)))
    F[0], Q[0] = np.eye(n), P_star
    if us is not None:
        us = us.copy()
        us[0] = 0.0
    return LinearModel(F, model.H, Q, model.R, model.B), us


def augmented_runs(model, zs: np.ndarray, us: np.ndarray | None, engine: str,
                   smooth: bool = False) -> AugmentedRuns:
    """The base run and the n sensitivity runs of one series, filtered (and smoothed when asked).

    The base run starts from ``x_0 = 0``, or, where the data lie far from 0
    in units of their noise, again from the estimate of ``x_0`` that run
    gives: every result is affine in ``x_0`` (module notes), so any start
    gives the same results in exact arithmetic, but from 0 the diffuse
    log-likelihood is a difference of two terms of the size of
    ``(level / noise)²`` (a level of 1e10 with unit noise gave +20480 for
    -189.16), and from the estimate it is not. The estimate carries the
    round-off of the level, so where that is still far in units of the
    noise (a constant 3.0 under variances of 1e-73: 3 ε is 1e21 standard
    deviations) the run starts again from its own estimate, at most three
    times.
    """
    n = model.n
    model, us = _first_state_diffuse(model, zs, us)
    kf = METHODS["kf"]

    def run(x0, data, controls):
        known = Gaussian(x0, np.zeros((n, n)))
        controls = None if controls is None else controls[None]
        if smooth:
            sm = first(smooth_batch(kf, model, known, data[None], controls, {}, engine, to_prior=True))
            return sm.filtered, (sm.means, sm.covs, sm.gains)
        return first(filter_batch(kf, model, known, data[None], controls, {}, engine, "all")), None

    zero_data = np.where(np.isnan(zs), np.nan, 0.0)
    zero_controls = None if us is None else np.zeros_like(us)
    sens = [run(np.eye(n)[i], zero_data, zero_controls) for i in range(n)]
    centre = np.zeros(n)
    base = run(centre, zs, us)
    runs = AugmentedRuns(model, base[0], [f for f, _ in sens], [base[1]] + [s for _, s in sens] if smooth else None,
                         centre)
    for _ in range(3):  # (once left the constant 3.0 at variances 1e-73 with a loglik of 7.7e25 for ~4700)
        estimate = _far_estimate(model, runs)
        if estimate is None:
            break
        base = run(estimate, zs, us)
        runs = runs._replace(base=base[0], smoothed=[base[1]] + runs.smoothed[1:] if smooth else None,
                             centre=estimate)
    return runs


def _far_estimate(model, runs: AugmentedRuns, far: float = 1e4) -> np.ndarray | None:
    """The estimate of ``x_0`` from all the data, when the base run's start is more than √far standard
    deviations from it (the log-likelihood then loses about ``far`` units of round-off); else None."""
    inf = _information(model, runs)
    if not _identified(inf.info[-1:])[0]:
        return None  # refused later, with its message
    L = cholesky(inf.info[-1], "the information about the diffuse state")
    white = whiten(L, inf.score[-1])
    return runs.centre + cho_solve(L, inf.score[-1]) if white @ white > far else None


class _Information(NamedTuple):
    info: np.ndarray      # (T, n, n): S_t after step t
    score: np.ndarray     # (T, n): s_t after step t
    loglik0: float        # the sum of the known-x_0 contributions


def _information(model, runs: AugmentedRuns) -> _Information:
    base = runs.base
    V = _innovation_sensitivity(model, runs)                                  # (T, m, n)
    X = np.concatenate([V, np.nan_to_num(base.innovations)[..., None]], axis=-1)  # [V | v0]
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised below, naming the step
        gram, _ = observed_gram(base.innovation_covs, X, ~np.isnan(base.innovations),
                                "the innovation covariance S")
        inf = _Information(np.cumsum(gram[:, :-1, :-1], axis=0), -np.cumsum(gram[:, :-1, -1], axis=0), base.loglik)
    bad = np.flatnonzero(~(np.isfinite(inf.info).all(axis=(1, 2)) & np.isfinite(inf.score).all(axis=1)))
    if bad.size:  # an information of 1/variance: variances near 1e-308 (audit SS2-4: a log-likelihood of -inf)
        raise at_step(FloatingPointError(not_finite("filtered")), int(bad[0]))
    return inf


def _predicted_sensitivity(runs: AugmentedRuns) -> np.ndarray:
    """``Mp[t]``: how the prediction at step t moves with x_0, (T, n, n)."""
    return np.stack([r.predicted_means for r in runs.sens], axis=-1)


def _innovation_sensitivity(model, runs: AugmentedRuns) -> np.ndarray:
    """``V[t] = -H_t Mp[t]`` over all m components, (T, m, n)."""
    Mp = _predicted_sensitivity(runs)
    H = model.H if model.H.ndim == 3 else model.H[None]
    return -(H @ Mp)


def _identified(info: np.ndarray) -> np.ndarray:
    r"""Which of the information matrices (T, n, n) about x_0, accumulated step by step, are non-singular.

    Judged on the correlation form :math:`D^{-1/2} \mathcal S D^{-1/2}` (D the
    diagonal of :math:`\mathcal S`): its smallest eigenvalue above 1e-12 of
    its largest. The eigenvalues of :math:`\mathcal S` itself span the units
    of the state's components (a slope in units 1e6 smaller, a sensor 1e13
    times more precise than another) and the growth of the information with
    the length of the series (a quadratic trend's grows as T, T³ and T⁵), and
    refused identified states at 1e-12. Once identified, a state stays so:
    the information only grows.
    """
    seen = (np.diagonal(info, axis1=-2, axis2=-1) > 0.0).all(axis=-1)
    eig = np.linalg.eigvalsh(unit_diagonal(info))
    return np.logical_or.accumulate(seen & (eig[:, 0] > 1e-12 * eig[:, -1]))


def _spread(L: np.ndarray, score: np.ndarray, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``M δ̂`` and ``M S⁻¹ Mᵀ`` for δ ~ N(S⁻¹ s, S⁻¹), S = L Lᵀ; stacked over a leading axis."""
    delta = cho_solve(L, score[..., None])
    W = whiten(L, np.swapaxes(M, -1, -2))  # L⁻¹ Mᵀ
    return (M @ delta)[..., 0], np.swapaxes(W, -1, -2) @ W


class NotIdentified(ValueError):
    """The measurements do not determine every component of a diffuse x_0 (a ValueError, as other bad input)."""


def not_identified() -> NotIdentified:
    return NotIdentified(
        "the diffuse initial state is not identified by the measurements: "
        "no combination of them determines every component of the first state x_1; "
        "give a proper Gaussian prior instead."
    )


def diffuse_filter(model, zs: np.ndarray, us: np.ndarray | None = None, engine: str = "auto") -> FilterResult:
    """Exact diffuse Kalman filter of one series (see the module notes).

    Parameters
    ----------
    model : LinearModel
    zs : ndarray of shape (T, m)
    us : ndarray of shape (T, p), optional
    engine : str
        Engine of the underlying filter runs (see :func:`gaussfuse.filter`).

    Returns
    -------
    FilterResult
        With NaN beliefs at the steps before x_0 is identified and the
        diffuse log-likelihood.
    """
    runs = augmented_runs(model, zs, us, engine)
    return _filter(model, runs, _information(model, runs))


def _filter(model, runs: AugmentedRuns, inf: _Information) -> FilterResult:
    base = runs.base
    M = np.stack([r.means for r in runs.sens], axis=-1)            # (T, n, n)
    Mp = _predicted_sensitivity(runs)
    V = _innovation_sensitivity(model, runs)                        # (T, m, n)
    out = {name: np.full_like(getattr(base, name), np.nan) for name in
           ("means", "covs", "predicted_means", "predicted_covs", "innovations", "innovation_covs")}
    ok = _identified(inf.info)
    if not ok[-1]:
        raise not_identified()
    d = int(np.argmax(ok))  # the information only grows: identified from step d on
    L = cholesky(inf.info[d:], "the information about the diffuse state")
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised below, naming the step
        shift, spread = _spread(L, inf.score[d:], M[d:])
        out["means"][d:] = base.means[d:] + shift
        out["covs"][d:] = symmetrize(base.covs[d:] + spread)
        # predictions and innovations at step t use what is known after step t - 1
        L, sc = L[:-1], inf.score[d:-1]
        for name, base_name, sens in (("predicted_means", "predicted_covs", Mp),
                                      ("innovations", "innovation_covs", V)):
            shift, spread = _spread(L, sc, sens[d + 1:])
            out[name][d + 1:] = getattr(base, name)[d + 1:] + shift
            out[base_name][d + 1:] = symmetrize(getattr(base, base_name)[d + 1:] + spread)
    _check_overflow(out, d)
    out["nis"] = np.full(len(out["means"]), np.nan)  # once identified
    out["nis"][d + 1:] = nis(out["innovations"][d + 1:], out["innovation_covs"][d + 1:])
    loglik = _diffuse_loglik(inf, (cholesky(inf.info[-1]), inf.score[-1]))
    return FilterResult(**out, loglik=loglik, last_mean=out["means"][-1], last_cov=out["covs"][-1])


def _check_overflow(out: dict, d: int) -> None:
    """FloatingPointError at the first step whose assembled belief is not finite, as kalman.check_finite says it:
    data near float64's limits overflow here, past the runs that were checked (audit EE1: a ValueError named an
    internal `innovation_covs`)."""
    for stage, means, covs, start in (("filtered", out["means"], out["covs"], d),
                                      ("predicted", out["predicted_means"], out["predicted_covs"], d + 1),
                                      ("predicted measurement", None, out["innovation_covs"], d + 1)):
        total = np.trace(covs[start:], axis1=1, axis2=2) + (0.0 if means is None else means[start:].sum(axis=1))
        bad = np.flatnonzero(~np.isfinite(total))
        if bad.size:
            raise at_step(FloatingPointError(not_finite(stage)), start + int(bad[0]))


def _diffuse_loglik(inf: _Information, final: tuple[np.ndarray, np.ndarray]) -> float:
    L, s = final
    white = whiten(L, s)
    return float(inf.loglik0 + 0.5 * white @ white - np.sum(np.log(np.diag(L))))


class Moments(NamedTuple):
    """Smoothed moments over times 0..T, time 0 being the prior's.

    Attributes
    ----------
    means : ndarray of shape (T + 1, n)
    covs : ndarray of shape (T + 1, n, n)
    cross : ndarray of shape (T, n, n)
        ``cross[t] = Cov(x_{t+1}, x_t | z_1..z_T)``.
    loglik : float
    filtered : FilterResult
    gains : ndarray of shape (T, n, n)
        Smoother gains from time t to t + 1, t = 0..T-1.
    first : int
        The first transition that is part of the model: 0 (from the prior's
        time into x_1), or 1 for a diffuse x_1, whose time 0 is only the
        device of the module notes.
    """

    means: np.ndarray
    covs: np.ndarray
    cross: np.ndarray
    loglik: float
    filtered: FilterResult
    gains: np.ndarray
    first: int = 0


def diffuse_moments(model, zs: np.ndarray, us: np.ndarray | None = None, engine: str = "auto") -> Moments:
    """Exact diffuse smoothed moments of one series, from the prior's time on."""
    runs = augmented_runs(model, zs, us, engine, smooth=True)
    inf = _information(model, runs)
    filt = _filter(model, runs, inf)
    L = cholesky(inf.info[-1], "the information about the diffuse state")
    base_m, base_P, gains = runs.smoothed[0]
    N = np.stack([means for means, _, _ in runs.smoothed[1:]], axis=-1)   # (T + 1, n, n)
    delta = cho_solve(L, inf.score[-1])
    W = whiten(L, np.swapaxes(N, -1, -2))                           # L⁻¹ N_tᵀ, (T + 1, n, n)
    means = base_m + N @ delta
    covs = symmetrize(base_P + np.swapaxes(W, -1, -2) @ W)
    cross = base_P[1:] @ np.swapaxes(gains, -1, -2) + np.swapaxes(W[1:], -1, -2) @ W[:-1]
    gains = np.concatenate([gains[:1], _gains(runs, inf, gains[1:])])
    return Moments(means, covs, cross, filt.loglik, filt, gains, first=1)


def _gains(runs: AugmentedRuns, inf: _Information, base_gains: np.ndarray) -> np.ndarray:
    r"""The smoother gains of the diffuse model from step k to k + 1, k = 0..T-2 (see the module notes).

    Given δ the gain is the base run's :math:`G^{(0)}_k` (its filtered covariance :math:`P_k` and prediction
    :math:`P^-_{k+1}` do not depend on δ); the diffuse one is the limit, as the prior on δ widens, of the
    regression of :math:`x_k` on :math:`x_{k+1}` given :math:`z_{1:k}`, where δ carries the information
    :math:`\mathcal S_k`:

    .. math::

        G_k = G^{(0)}_k + (M_k - G^{(0)}_k M^-_{k+1}) \left(\mathcal S_k + M^{-\top}_{k+1} (P^-_{k+1})^{-1}
        M^-_{k+1}\right)^{-1} M^{-\top}_{k+1} (P^-_{k+1})^{-1},

    with :math:`M_k, M^-_{k+1}` the filtered and predicted sensitivities. It is finite before the state is
    identified (x_{k+1} tells what z_{1:k} do not), and the solves are least-squares where a matrix is singular,
    as the driver's gains (see :func:`gaussfuse.kalman.rts_step`). The base run's gains alone are not the model's
    (audit SS2-1: the lag-one covariance ``G_k P^s_{k+1}`` was 0.125 off at k = 0 and 0.005 at k = 6).
    """
    M = np.stack([r.means for r in runs.sens], axis=-1)[:-1]              # (T - 1, n, n)
    Mp = _predicted_sensitivity(runs)[1:]
    K = psd_solve(runs.base.predicted_covs[1:], Mp)              # (P⁻)⁻¹ M⁻
    A = inf.info[:-1] + np.swapaxes(Mp, -1, -2) @ K
    D = M - base_gains @ Mp
    return base_gains + D @ psd_solve(A, np.swapaxes(K, -1, -2))


def diffuse_smooth(model, zs: np.ndarray, us: np.ndarray | None = None, engine: str = "auto") -> SmoothResult:
    """Exact diffuse RTS smoother of one series (see the module notes)."""
    mom = diffuse_moments(model, zs, us, engine)
    return SmoothResult(mom.means[1:], mom.covs[1:], mom.gains[1:], mom.filtered)
