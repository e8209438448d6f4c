r"""Learning a linear-Gaussian model from data: EM and maximum likelihood.

Both methods stand on the smoothed moments of the states, from the prior's
time 0 to T, and the lag-one covariances
:math:`C_t = \operatorname{Cov}(x_t, x_{t-1} \mid z_{1:T}) = P^s_t G_{t-1}^\top`.
With them every expectation of the complete-data log-likelihood

.. math::

    \ell_c = \log N(x_0; m_0, P_0)
      + \sum_t \log N(x_t; F_t x_{t-1} + B_t u_t, Q_t)
      + \sum_t \log N(z_t; H_t x_t, R_t)

is a quadratic form in the moments of
:math:`s_t = (x_t, x_{t-1}, u_t, 1)` and :math:`r_t = (z_t, x_t, 1)`: the
transition residual is :math:`w_t = [I, -F_t, -B_t, 0]\, s_t` and the
measurement residual :math:`v_t = [I, -H_t, 0]\, r_t`, so that
:math:`E[w_t w_t^\top] = W_t \operatorname{Cov}[s_t] W_t^\top + W_t E[s_t] (W_t E[s_t])^\top`.
A missing component of :math:`z_t` is part of the complete data; its moments
given the observed ones are exact:
:math:`z_\mu = (H_\mu - L H_o) x + L z_o + e`,
:math:`L = R_{\mu o} R_{oo}^{+}`, :math:`e \sim N(0, R_{\mu\mu} - L R_{o\mu})`.
With a diffuse prior the first state :math:`x_1` is diffuse (see
:mod:`gaussfuse.inference.diffuse`): there is no :math:`x_0` and no first transition,
so the sums over transitions start at :math:`t = 2`.

* **EM** (Shumway & Stoffer 1982) maximises :math:`E[\ell_c]`: :math:`[F, B]`
  by regression of :math:`x_t` on :math:`(x_{t-1}, u_t)`,
  :math:`H = \sum E[z x^\top] (\sum E[x x^\top])^{-1}`, then
  :math:`Q = \frac1{T_w} \sum E[w w^\top]` over the :math:`T_w` transitions,
  :math:`R = \frac1T \sum E[v v^\top]`,
  :math:`m_0 = E[x_0]`, :math:`P_0 = \operatorname{Cov}[x_0]`; the steps
  after a series' last observation (a short series padded to a long one's
  length) are left out of these sums, as is a series with none, and the
  steps with nothing observed are left out of the measurement's sums (H
  and R, over the :math:`T` steps with an observation), as pykalman does:
  their expected statistics are the current model's own, which would only
  slow EM (their likelihood is 1 either way; the complete data are then
  the states and the measurements of those steps). A diagonal
  or scalar covariance keeps the diagonal or its mean. Each step is an
  exact maximisation, so the likelihood never decreases. A learned
  covariance is projected onto the positive semi-definite matrices (its
  round-off negative eigenvalues set to zero), and a variance that starts at
  exactly zero stays exactly zero, with its row and column: EM cannot move
  it (the posterior of a noise-free component has no residual), and the
  maximum-likelihood parametrisation below holds it fixed for the same
  reason.
* **Maximum likelihood** optimises :math:`\log p(z \mid \theta)` with
  scipy.optimize (BFGS) over unconstrained parameters :math:`\theta`: the
  entries of F, H, B and m0; a learned covariance on its non-zero variances
  through log variances (diagonal), the log of the common variance
  (scalar), or its Cholesky factor with a log diagonal (full). Its gradient
  is exact, and is computed one of two ways. Where every covariance it
  needs is non-singular, by Fisher's identity
  :math:`\nabla \log p(z) = E[\nabla \ell_c \mid z]` from the smoother's
  moments: for example
  :math:`\partial/\partial Q = \tfrac12 Q^{-1}(\sum E[w w^\top] - T_w Q) Q^{-1}`
  and :math:`\partial/\partial F = Q^{-1} \sum E[w x_{t-1}^\top]`. Where one
  is singular (a noise-free state or sensor, a known constant, an ARMA
  model in state-space form), the complete-data density has no inverse to
  offer; where one is tiny beside what the data resolve of the states
  (a process noise of 1e-20), the smoothed :math:`E[w]` it is divided into
  is round-off (:func:`_fisher_resolves`). There the gradient is the
  derivative of the filter's own
  log-likelihood :math:`\sum_t -\tfrac12 (v_t^\top S_t^{-1} v_t + \log|S_t|)`,
  propagated along each parameter direction :math:`\dot\theta` with the
  filter (Harvey 1989, sec. 3.4.6):

  .. math::

      \dot m^-_t &= \dot F m_{t-1} + F \dot m_{t-1} + \dot B u_t, \qquad
      \dot P^-_t = \dot F P_{t-1} F^\top + F P_{t-1} \dot F^\top + F \dot P_{t-1} F^\top + \dot Q, \\
      \dot v_t &= -\dot H m^-_t - H \dot m^-_t, \qquad
      \dot S_t = \dot H P^-_t H^\top + H P^-_t \dot H^\top + H \dot P^-_t H^\top + \dot R, \\
      \dot K_t^\top &= S_t^{-1} (\dot H P^-_t + H \dot P^-_t - \dot S_t K_t^\top), \qquad
      \dot m_t = \dot m^-_t + \dot K_t v_t + K_t \dot v_t, \\
      \dot P_t &= (I - K_t H) \dot P^-_t (I - K_t H)^\top - X_t - X_t^\top + K_t \dot R K_t^\top,
      \quad X_t = K_t \dot H P^-_t (I - K_t H)^\top, \\
      \dot\ell_t &= -\tfrac12 \operatorname{tr}(S_t^{-1} \dot S_t) - v_t^\top S_t^{-1} \dot v_t
      + \tfrac12 v_t^\top S_t^{-1} \dot S_t S_t^{-1} v_t .

  :math:`\dot P_t` has no :math:`\dot K_t` term because the Joseph form is
  stationary in the gain at the optimal gain. With a diffuse prior the same
  recursion carries the sensitivity columns of :mod:`gaussfuse.inference.diffuse`,
  and the diffuse terms are differentiated through their information
  :math:`\mathcal S_T` and score :math:`s_T`. The search's first step moves
  no entry of :math:`\theta` by more than one of its units (a log variance by
  a factor e): from variances far below the data's, the gradient is huge and
  a step of its size would leave the region the search can come back from.

Standard errors, for both methods, come from the observed information: the
Hessian of the log-likelihood at the estimate, by central differences of
the exact gradient, and the delta method for the learned matrices' entries.
A variance estimated at the boundary of its range (about 0, where the
log-likelihood hardly moves with its logarithm) has none: there the
gradient's differences are round-off, which a second difference of the
log-likelihood over a wider step tells.

References
----------
.. [1] R. H. Shumway and D. S. Stoffer, "An approach to time series smoothing
   and forecasting using the EM algorithm", J. Time Series Analysis 3(4), 1982.
.. [2] A. C. Harvey, *Forecasting, Structural Time Series Models and the
   Kalman Filter*, Cambridge University Press, 1989.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np

from ._frozen import reduce_frozen, shapes_repr
from ._linalg import LOG_2PI, cho_solve, cholesky, is_positive_definite, psd_solve, shown, symmetrize, unit_diagonal
from ._validation import as_vector, integer, real
from .errors import ConvergenceWarning, ModelFunctionError, fixed_text
from .gaussian import Gaussian
from .inference.diffuse import NotIdentified, augmented_runs, diffuse_moments, not_identified
from .inference.results import first
from .inference.drivers import AUTO_NUMBA_STEPS, ENGINES, compiled_engine, filter_batch, smooth_batch, switch_step
from .inference.registry import METHODS as _METHODS
from .inference import chunked, frames, timing
from .inference.validation import check_controls, check_measurements, check_prior, check_steps
from .models.compose import TimedModel
from .models.linear import LinearModel

__all__ = ["fit", "FitResult", "LEARNABLE", "STRUCTURES"]

LEARNABLE = ("F", "H", "Q", "R", "B", "m0", "P0")
COVARIANCES = ("Q", "R", "P0")
STRUCTURES = ("full", "diagonal", "scalar")
METHODS = ("em", "mle")
FIT_PASSES = {"em": 100, "mle": 30}
"""Filter passes a fit is expected to cost on the readable path, by method, when it stops at its
tolerance: on a local level with 5,000 steps, EM (its smoothers) took as long as 113 filter passes
and MLE (its likelihoods and gradients) 36. A fit without a tolerance (``tol=0``) is expected to run
all its iterations, each about three passes. What ``engine="auto"`` weighs compiling against
(:func:`gaussfuse.inference.drivers.compiled_engine`)."""
_MATRICES = ("F", "H", "Q", "R", "B")


@dataclass(frozen=True, eq=False)
class FitResult:
    """The output of :func:`fit`.

    Attributes
    ----------
    model : LinearModel
        The fitted model.
    prior : Gaussian or "diffuse"
        The fitted (or given) prior.
    loglik : float
        Log-likelihood of the data under `model` and `prior`.
    history : ndarray of shape (k,)
        Log-likelihood at each iteration, the last being `loglik`.
    method : str
        "em" or "mle".
    converged : bool
        Whether the tolerance was met (False after `iterations`, with a
        :class:`~gaussfuse.ConvergenceWarning`, or after Ctrl-C).
    message : str
        How the fit ended.
    standard_errors : dict of str to ndarray, or None
        Standard errors of every learned matrix (same shape; zero where an
        entry is held fixed), from the observed information (the Hessian of
        the log-likelihood at the estimate), or of the user's parameters
        under ``"params"``. None when the information could not be computed,
        and after Ctrl-C (the estimate is not at a maximum).
    params : dict of str to float
        The learned values by name: ``"R"`` for a 1 x 1 matrix, ``"Q[0,1]"``
        for an entry (the lower triangle of a full covariance, the diagonal
        of a diagonal one, the common variance ``"Q"`` of a scalar one),
        ``"theta[i]"`` for the user's parameters of ``params=``. Variances
        held at zero are not parameters.
    bse : dict of str to float
        The standard error of each of `params` (NaN when the observed
        information is not positive definite at the estimate, or, on its
        correlation scale, its smallest eigenvalue is within 10 times
        the term the gradient of the learned log variances adds to it short
        of a stationary point (:math:`g_i / I_{ii}`); and for a
        parameter the log-likelihood does not depend on, such as the
        variance of a sensor never observed, or does not resolve from the
        boundary of its range, a variance estimated at about 0: the others
        are then those of the model with it held fixed).
    nobs : int
        The number of observed measurement components (NaN ones excluded),
        over all series.
    series : int
        The number of series fitted (with a diffuse prior, those with an
        observed value: each has its own diffuse initial state).
    """

    model: LinearModel
    prior: Gaussian | str
    loglik: float
    history: np.ndarray
    method: str
    converged: bool
    message: str
    standard_errors: dict | None = None
    params: dict = field(default_factory=dict)
    bse: dict = field(default_factory=dict)
    nobs: int = 0
    series: int = 1

    __reduce__ = reduce_frozen  # pickles and copies keep read-only arrays read-only
    __repr__ = shapes_repr

    @property
    def df_model(self) -> int:
        """The number of estimated quantities: `params`, and the diffuse states when the prior is diffuse.

        A diffuse state is estimated from the data too, and counts in the
        information criteria, as in Harvey (1989) and statsmodels: n for
        each series.
        """
        return len(self.params) + self._diffuse_states

    @property
    def _diffuse_states(self) -> int:
        return self.series * self.model.n if isinstance(self.prior, str) else 0

    @property
    def aic(self) -> float:
        """Akaike's information criterion, ``-2 loglik + 2 df_model``."""
        return -2.0 * self.loglik + 2.0 * self.df_model

    @property
    def bic(self) -> float:
        """The Bayesian information criterion, ``-2 loglik + df_model log(nobs)``."""
        return -2.0 * self.loglik + self.df_model * np.log(self.nobs)

    def to_pandas(self):
        """The learned parameters as a pandas Series named "estimate" (index: the names of `params`)."""
        import pandas as pd

        return pd.Series(self.params, name="estimate", dtype=float)

    def summary(self) -> str:
        """A table of the estimates with standard errors and 95% intervals, and the fit's figures.

        Examples
        --------
        >>> import gaussfuse as gf
        >>> from gaussfuse.datasets import nile
        >>> res = gf.fit(gf.LinearModel(F=1, H=1, Q=1000.0, R=10000.0), "diffuse", nile()[1], method="mle")
        >>> print(res.summary())  # doctest: +NORMALIZE_WHITESPACE
        gaussfuse fit: maximum likelihood, converged
        log-likelihood -633.4646   AIC 1272.9291   BIC 1280.7446   observations 100 (with 1 diffuse state)
        parameter         estimate      std err       [0.025        0.975]
        Q                   1469.2       1280.4      -1040.3       3978.7
        R                  15098.5       3145.5       8933.4      21263.7
        """
        how = {"em": "EM", "mle": "maximum likelihood"}[self.method]
        state = "converged" if self.converged else self.message if self.message.startswith("ran the ") else \
            f"NOT converged ({self.message})"
        k = self._diffuse_states
        after = f" (with {k} diffuse state{'s' * (k > 1)})" if k else ""
        lines = [f"gaussfuse fit: {how}, {state}",
                 f"log-likelihood {fixed_text(self.loglik, 4)}   AIC {fixed_text(self.aic, 4)}   "
                 f"BIC {fixed_text(self.bic, 4)}   "
                 f"observations {self.nobs}{after}",
                 f"{'parameter':<14} {'estimate':>11} {'std err':>12} {'[0.025':>12} {'0.975]':>13}"]
        for name, value in self.params.items():
            se = self.bse.get(name, np.nan)
            lines.append(f"{name:<14} {_fmt(value):>11} {_fmt(se):>12} {_fmt(value - 1.959963984540054 * se):>12} "
                         f"{_fmt(value + 1.959963984540054 * se):>12}")
        missing = [name for name in self.params if not np.isfinite(self.bse.get(name, np.nan))]
        them, their = ("it", "its") if len(missing) == 1 else ("them", "their")
        if missing:  # (a table of nan said nothing of why: audit Y3)
            lines.append("std err nan: " + (
                "the observed information is not positive definite here, or not beyond the gradient (the fit is "
                "not at a maximum, or the data do not identify every parameter)" if len(missing) == len(self.params)
                else
                f"the log-likelihood does not depend on {', '.join(missing)}, or does not resolve {them} from the "
                f"boundary of {their} range, a variance of 0 (the others' are those of the model with {them} held "
                "fixed)"))
        return "\n".join(lines)


def _fmt(x: float) -> str:
    """A figure for the summary table: 1 decimal in [1e3, 1e7), 4 significant digits otherwise."""
    if not np.isfinite(x):
        return "nan"
    if x == 0 or 1e-4 <= abs(x) < 1e3:
        return f"{x:.4g}"
    if 1e3 <= abs(x) < 1e7:
        return f"{x:.1f}"
    return f"{x:.4e}"  # (below 1e-4 too: 1.469e-05 printed as 0.0)


# ---------------------------------------------------------------------------
# The E-step: smoothed moments and expected sufficient statistics
# ---------------------------------------------------------------------------


def _per_step(a: np.ndarray | None, T: int) -> np.ndarray | None:
    """A matrix as a stack over T steps (broadcast when time-invariant)."""
    if a is None:
        return None
    return a if a.ndim == 3 else np.broadcast_to(a, (T, *a.shape))


class Statistics:
    """Expected first and second moments of a block of N series (see the module notes), their steps in one stack.

    The steps of the N series follow each other, series after series: a
    sum over the stack is a sum over steps and series, and a per-step
    quantity is the stack reshaped to (N, steps, ...) and summed over N.

    Attributes
    ----------
    mu, sig : ndarray of shape (N·T_w, d), (N·T_w, d, d)
        Mean and covariance of s_t = (x_t, x_{t-1}, u_t, 1), d = 2n + p + 1,
        over the T_w = T - `start` transitions of the model.
    nu, tau : ndarray of shape (N·T, e), (N·T, e, e)
        Mean and covariance of r_t = (z_t, x_t, 1), e = m + n + 1.
    start : int
        The first transition that is part of the model (1 for a diffuse x_1).
    x0_mean, x0_cov : ndarray of shape (N, n), (N, n, n)
        Smoothed moments of x_0.
    filtered_w, filtered_v, filtered_x0 : ndarray of shape (N·T_w, d), (N·T, e), (N, n)
        The filter's variances of the states in s_t, r_t and x_0 (zeros where not given).
    innovation_var, observed : ndarray of shape (N·T, m)
        The filter's innovation variances (NaN where not given), and which components of z are observed.
    kept_w, kept_v, seen : ndarray of bool, shape (N·T_w,), (N·T,), (N,)
        The transitions up to each series' last observation, the steps with
        an observation, and the series with one: EM's sums
        (:func:`_first_sums`, :func:`_second_sums`) leave out the others (a
        series padded to a longer one's length, a gap), whose expected statistics are the
        current model's own and would only slow EM, and series with none.
    """

    def __init__(self, model: LinearModel, means: np.ndarray, covs: np.ndarray, cross: np.ndarray, zs: np.ndarray,
                 us: np.ndarray | None, start: int = 0, filtered: tuple | None = None):
        N, T, m = zs.shape
        n = model.n
        p = 0 if us is None else us.shape[2]
        self.n, self.m, self.p, self.T, self.N = n, m, p, T, N
        a = self.start = start
        d = 2 * n + p + 1
        mu = np.zeros((N, T, d))
        mu[..., :n], mu[..., n:2 * n], mu[..., -1] = means[:, 1:], means[:, :-1], 1.0
        if p:
            mu[..., 2 * n:2 * n + p] = us
        sig = np.zeros((N, T, d, d))
        sig[..., :n, :n], sig[..., n:2 * n, n:2 * n] = covs[:, 1:], covs[:, :-1]
        sig[..., :n, n:2 * n] = cross
        sig[..., n:2 * n, :n] = np.swapaxes(cross, -1, -2)
        self.mu, self.sig = mu[:, a:].reshape(-1, d), sig[:, a:].reshape(-1, d, d)

        H, R = self.per_step(model.H), self.per_step(model.R)
        z, x, P = zs.reshape(-1, m), means[:, 1:].reshape(-1, n), covs[:, 1:].reshape(-1, n, n)
        e = m + n + 1
        nu = np.zeros((N * T, e))
        nu[:, :m], nu[:, m:m + n], nu[:, -1] = np.nan_to_num(z), x, 1.0
        tau = np.zeros((N * T, e, e))
        tau[:, m:m + n, m:m + n] = P
        gaps = np.isnan(z)
        rows = np.flatnonzero(gaps.any(axis=1))
        if model.H.ndim == 2 and model.R.ndim == 2:  # one conditioning per pattern of missing components
            patterns, which = np.unique(gaps[rows], axis=0, return_inverse=True)
            groups = [(rows[which.ravel() == g], ~patterns[g]) for g in range(len(patterns))]
        else:
            groups = [(rows[i:i + 1], ~gaps[t]) for i, t in enumerate(rows)]
        for t, o in groups:
            # z = A x + c + noise, A and the noise zero on the observed rows o;
            # the missing rows given the observed: H_μ x + L (z_o - H_o x) + noise.
            mis = ~o
            Ht, Rt = H[t[0]], R[t[0]]
            A, E = np.zeros((m, n)), np.zeros((m, m))
            L = psd_solve(Rt[np.ix_(o, o)], Rt[np.ix_(o, mis)]).T if o.any() else np.zeros((mis.sum(), 0))
            A[mis] = Ht[mis] - L @ Ht[o]
            E[np.ix_(mis, mis)] = Rt[np.ix_(mis, mis)] - L @ Rt[np.ix_(o, mis)]
            c = np.where(o, z[t], 0.0)
            c[:, mis] = z[t][:, o] @ L.T
            nu[t, :m] = x[t] @ A.T + c
            AP = A @ P[t]
            tau[t, :m, :m] = AP @ A.T + E
            tau[t, :m, m:m + n] = AP
            tau[t, m:m + n, :m] = np.swapaxes(AP, -1, -2)
        self.nu, self.tau = nu, tau
        self.x0_mean, self.x0_cov = means[:, 0], covs[:, 0]
        # the filter's variances, (N, T + 1, n) from the prior's time, and its innovations', (N, T, m): the sizes of
        # the numbers the smoother cancelled, and the scale of the filter's own score (see _fisher_resolves)
        self._filtered = filtered if filtered is not None else (np.zeros((N, T + 1, n)), np.full((N, T, m), np.nan))
        self.observed = ~gaps
        observed = ~np.isnan(zs).all(axis=2)  # (N, T)
        self.seen = observed.any(axis=1)
        upto = np.cumsum(observed[:, ::-1], axis=1)[:, ::-1] > 0  # at or before the series' last observation
        self.kept_w, self.kept_v = upto[:, a:].ravel(), observed.ravel()

    @property
    def filtered_w(self) -> np.ndarray:
        """The filter's variances of s_t's states, (N·T_w, d): x_t's, x_{t-1}'s, then zeros."""
        variances = self._filtered[0]
        zeros = np.zeros((self.N, self.T, self.p + 1))
        return np.concatenate([variances[:, 1:], variances[:, :-1], zeros], axis=-1)[:, self.start:].reshape(
            self.mu.shape)

    @property
    def filtered_v(self) -> np.ndarray:
        """The filter's variances of r_t's state, (N·T, e): zeros for z_t and 1."""
        variances = self._filtered[0]
        return np.concatenate([np.zeros((self.N, self.T, self.m)), variances[:, 1:], np.zeros((self.N, self.T, 1))],
                              axis=-1).reshape(self.nu.shape)

    @property
    def filtered_x0(self) -> np.ndarray:
        """The filter's variances at the prior's time, (N, n)."""
        return self._filtered[0][:, 0]

    @property
    def innovation_var(self) -> np.ndarray:
        """The filter's innovation variances, (N·T, m)."""
        return self._filtered[1].reshape(-1, self.m)

    def per_step(self, M: np.ndarray | None, start: int = 0) -> np.ndarray | None:
        """A model matrix (time-invariant, or one per step) at each step of the stack from step `start` on."""
        if M is None:
            return None
        steps = _per_step(M, self.T)[start:]
        return np.broadcast_to(steps, (self.N, *steps.shape)).reshape(-1, *steps.shape[1:])

    def per_series_sum(self, stack: np.ndarray) -> np.ndarray:
        """A per-step quantity of the stack (N·steps, ...) summed over the series: (steps, ...)."""
        return stack.reshape(self.N, -1, *stack.shape[1:]).sum(axis=0)

    @property
    def Phi(self) -> np.ndarray:
        """``E[s_t s_tᵀ]`` over the transitions, (T_w, d, d)."""
        return self.sig + self.mu[:, :, None] * self.mu[:, None, :]

    @property
    def Psi(self) -> np.ndarray:
        """``E[r_t r_tᵀ]``, (T, e, e)."""
        return self.tau + self.nu[:, :, None] * self.nu[:, None, :]

    # selectors into s_t = (x_t, x_{t-1}, u_t, 1) and r_t = (z_t, x_t, 1)
    def w_map(self, F: np.ndarray, B: np.ndarray | None) -> np.ndarray:
        """``[I, -F_t, -B_t, 0]`` over the transitions, shape (N·T_w, n, d)."""
        n, p, a = self.n, self.p, self.start
        W = np.zeros((self.mu.shape[0], n, 2 * n + p + 1))
        W[:, :, :n] = np.eye(n)
        W[:, :, n:2 * n] = -self.per_step(F, a)
        if p:
            W[:, :, 2 * n:2 * n + p] = -self.per_step(B, a)
        return W

    def v_map(self, H: np.ndarray) -> np.ndarray:
        """``[I, -H_t, 0]`` of shape (N·T, m, e)."""
        m, n = self.m, self.n
        V = np.zeros((self.nu.shape[0], m, m + n + 1))
        V[:, :, :m] = np.eye(m)
        V[:, :, m:m + n] = -self.per_step(H)
        return V

    def residual_second_moment(self, which: str, M: np.ndarray) -> np.ndarray:
        """``E[w_t w_tᵀ]`` (which="w", M = W_t) or ``E[v_t v_tᵀ]`` (which="v", M = V_t), per step.

        Covariance part plus mean part: the mean part is an exact outer
        product, which keeps round-off out of a small residual variance.
        """
        mean, cov = (self.mu, self.sig) if which == "w" else (self.nu, self.tau)
        r = (M @ mean[:, :, None])[..., 0]
        return _quad(M, cov) + r[:, :, None] * r[:, None, :]


def _quad(M: np.ndarray, S: np.ndarray, N: np.ndarray | None = None) -> np.ndarray:
    """``M_t S_t N_tᵀ`` for each t (N defaults to M)."""
    return M @ S @ np.swapaxes(M if N is None else N, -1, -2)


_BLOCK = 1 << 21
"""About how many numbers a block of series' statistics holds (N·T·d², 16 MB): memory stays bounded on a
long panel while the numpy calls per series vanish."""


def _e_step(model, prior, zs, us, engine: str = "auto") -> tuple[float, list[Statistics]]:
    """The log-likelihood of the series `zs` (N, T, m) and their statistics, in blocks of series.

    One call of the batch smoother for all series (compiled: in parallel),
    then the statistics of each block of series at once; with a diffuse
    prior, series by series (:func:`gaussfuse.inference.diffuse.diffuse_moments`).
    """
    if isinstance(prior, str):
        loglik, stats = 0.0, []
        for i, z in enumerate(zs):
            mom = diffuse_moments(model, z, None if us is None else us[i], engine)
            loglik += mom.loglik
            filtered = _filtered(mom.filtered, mom.covs[:1])
            stats.append(Statistics(model, mom.means[None], mom.covs[None], mom.cross[None], zs[i:i + 1],
                                    None if us is None else us[i:i + 1], mom.first,
                                    tuple(a[None] for a in filtered)))
        return loglik, stats
    sm = smooth_batch(_METHODS["kf"], model, prior, zs, us, {}, engine, to_prior=True)
    cross = sm.covs[:, 1:] @ np.swapaxes(sm.gains, -1, -2)
    N, T = zs.shape[:2]
    d = 2 * model.n + (0 if us is None else us.shape[2]) + 1
    size = max(1, _BLOCK // max(1, (T + 1) * d * d))
    variances, innovations = _filtered(sm.filtered, np.broadcast_to(prior.cov, (N, 1, model.n, model.n)))
    stats = [Statistics(model, sm.means[i:i + size], sm.covs[i:i + size], cross[i:i + size], zs[i:i + size],
                        None if us is None else us[i:i + size], filtered=(variances[i:i + size],
                                                                          innovations[i:i + size]))
             for i in range(0, N, size)]
    return float(np.sum(sm.filtered.loglik)), stats


def _filtered(result, first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The variances of a filter's `result` from the prior's time on (`first`: the covariance there, (..., 1, n, n))
    and its innovation variances: what :class:`Statistics` keeps of the filter."""
    variances = np.concatenate([np.diagonal(first, axis1=-2, axis2=-1), np.diagonal(result.covs, axis1=-2, axis2=-1)],
                               axis=-2)
    return variances, np.diagonal(result.innovation_covs, axis1=-2, axis2=-1)


# ---------------------------------------------------------------------------
# EM
# ---------------------------------------------------------------------------


def _structured(cov: np.ndarray, structure: str, fixed: np.ndarray) -> np.ndarray:
    """`cov` with the structure imposed, projected onto the PSD matrices, rows and columns `fixed` zero."""
    if structure == "diagonal":
        out = np.diag(np.clip(np.diag(cov), 0.0, None))
    elif structure == "scalar":
        out = max(float(np.mean(np.diag(cov))), 0.0) * np.eye(cov.shape[0])
    else:
        vals, vecs = np.linalg.eigh(symmetrize(cov))
        out = cov if vals[0] >= 0 else symmetrize((vecs * np.clip(vals, 0.0, None)) @ vecs.T)
        out = symmetrize(out)
    if fixed.any():
        out = out.copy()
        out[fixed], out[:, fixed] = 0.0, 0.0
    return out


def _fixed_zeros(cov: np.ndarray, structure: str) -> np.ndarray:
    """The components held at zero variance: those at zero now (all or none for a scalar covariance)."""
    zero = np.diag(cov) == 0.0
    if structure == "scalar":
        zero[:] = zero.all()
    return zero


def _m_step(model: LinearModel, prior, stats: list[Statistics], learn: tuple, structure: dict, fixed: dict):
    """The M-step: the matrices in `learn` that maximise the expected log-likelihood of `stats`.

    In two stages, each a sum over the series: F, B, H and m0 from the
    moments (:func:`_first_sums`), then Q, R and P0 from the residuals of the
    new F, B, H and m0 (:func:`_second_sums`). A pool of series held in
    chunks sums each stage chunk by chunk (:class:`_Chunks`).
    """
    first = _first_sums(model, stats, learn)
    new = _first_solve(model, prior, first, learn)
    return _second_solve(model, prior, first, new, _second_sums(stats, new, learn), learn, structure, fixed)


def _first_sums(model: LinearModel, stats: list[Statistics], learn: tuple) -> dict:
    """The M-step's first-stage sums over `stats`: counts, and the regressions of F, B and H and the mean of x₀."""
    n, p, m = model.n, model.p, model.m
    out = {"T_w": sum(int(s.kept_w.sum()) for s in stats), "T_v": sum(int(s.kept_v.sum()) for s in stats),
           "series": sum(int(s.seen.sum()) for s in stats)}
    if "F" in learn or "B" in learn:
        # Regress x_t on the learned regressors, the known parts moved to the target.
        rows = ([np.arange(n, 2 * n)] if "F" in learn else []) + \
               ([np.arange(2 * n, 2 * n + p)] if "B" in learn else [])
        sel = np.concatenate(rows)
        Fk = np.zeros_like(model.F) if "F" in learn else model.F
        Bk = (np.zeros_like(model.B) if "B" in learn else model.B) if p else None
        Phi = [s.Phi[s.kept_w] for s in stats]
        out["lhs"] = sum(np.sum((s.w_map(Fk, Bk)[s.kept_w] @ ph)[:, :, sel], axis=0) for s, ph in zip(stats, Phi))
        out["gram"] = sum(np.sum(ph[:, sel][:, :, sel], axis=0) for ph in Phi)
    if "H" in learn:
        Psi = [s.Psi[s.kept_v] for s in stats]
        out["zx"] = sum(np.sum(ps[:, :m, m:m + n], axis=0) for ps in Psi)
        out["xx"] = sum(np.sum(ps[:, m:m + n, m:m + n], axis=0) for ps in Psi)
    if "m0" in learn:
        out["x0"] = sum(s.x0_mean[s.seen].sum(axis=0) for s in stats)
    return out


def _first_solve(model: LinearModel, prior, sums: dict, learn: tuple) -> dict:
    """F, B, H and m0 of the M-step, from the first-stage sums (the others as they are)."""
    n = model.n
    F, B, H = model.F, model.B, model.H
    if "F" in learn or "B" in learn:
        coef = psd_solve(sums["gram"], sums["lhs"].T).T
        if "F" in learn:
            F, coef = coef[:, :n], coef[:, n:]
        if "B" in learn:
            B = coef
    if "H" in learn:
        H = psd_solve(sums["xx"], sums["zx"].T).T
    m0 = sums["x0"] / sums["series"] if "m0" in learn else (None if isinstance(prior, str) else prior.mean)
    return {"F": F, "B": B, "H": H, "m0": m0}


def _second_sums(stats: list[Statistics], new: dict, learn: tuple) -> dict:
    """The M-step's second-stage sums: the residuals' second moments under the new F, B, H and m0."""
    out = {}
    if "Q" in learn:
        out["Q"] = sum(np.sum(s.residual_second_moment("w", s.w_map(new["F"], new["B"]))[s.kept_w], axis=0)
                       for s in stats)
    if "R" in learn:
        out["R"] = sum(np.sum(s.residual_second_moment("v", s.v_map(new["H"]))[s.kept_v], axis=0) for s in stats)
    if "P0" in learn:
        out["P0"] = sum(np.sum((s.x0_cov + _outer(s.x0_mean - new["m0"]))[s.seen], axis=0) for s in stats)
    return out


def _second_solve(model: LinearModel, prior, first: dict, new: dict, second: dict, learn: tuple, structure: dict,
                  fixed: dict):
    """The M-step's model and prior, from both stages' sums."""
    Q, R = model.Q, model.R
    if "Q" in learn:
        Q = _structured(second["Q"] / first["T_w"], structure["Q"], fixed["Q"])
    if "R" in learn:
        R = _structured(second["R"] / first["T_v"], structure["R"], fixed["R"])
    new_prior = prior
    if "m0" in learn or "P0" in learn:
        P0 = _structured(second["P0"] / first["series"], structure["P0"], fixed["P0"]) if "P0" in learn \
            else prior.cov
        new_prior = Gaussian(new["m0"], P0)
    return model._replace(F=new["F"], H=new["H"], Q=Q, R=R, B=new["B"]), new_prior


def _second_needs_the_first(learn: tuple) -> bool:
    """Whether the second stage depends on a matrix the first stage learns (a pool in chunks then passes twice)."""
    return bool(({"F", "B"} & set(learn) and "Q" in learn) or ({"H", "R"} <= set(learn))
                or ({"m0", "P0"} <= set(learn)))


class _Series(NamedTuple):
    """The measurements (N, T, m) and controls of a fit, in memory: what EM and the score are computed over."""

    zs: np.ndarray
    us: np.ndarray | None

    def e_step(self, model, prior, learn, structure, fixed, engine):
        """The log-likelihood at (model, prior), and the M-step as a function of no arguments."""
        loglik, stats = _e_step(model, prior, self.zs, self.us, engine)
        return loglik, lambda: _m_step(model, prior, stats, learn, structure, fixed)

    def score(self, model, prior, directions, engine):
        """The log-likelihood and its derivative along each direction."""
        return _loglik_and_gradient(model, prior, self.zs, self.us, directions, engine)

    def scores(self, requests, engine):
        """:meth:`score` of each ``(model, prior, directions)`` in `requests`."""
        return [self.score(*request, engine) for request in requests]


class _Chunks:
    """The measurements of a fit as a dask array chunked over series: each sum computed chunk by chunk.

    Each chunk's E-step runs where Dask puts it, and returns only the small
    sums the M-step needs (:func:`_first_sums`, :func:`_second_sums`), or
    its log-likelihood and score; they are added by a tree reduction. The
    second stage of an M-step that learns both a matrix and the noise of
    its residual (F and Q, H and R, m0 and P0) needs the first stage's
    matrices, so it is a second pass over the chunks. The sums are those of
    the in-memory fit, added in another order: the fits agree to round-off where the maximum is interior (where
    a learned variance goes to 0 the search ends where round-off takes it: audit UU3, Q at 2.5e-12 in memory and
    1.7e-9 here, log-likelihoods 8e-9 apart, and maximum likelihood's converged flag True and False).
    """

    def __init__(self, zs, us) -> None:
        self.zs, self.us, self.sizes = chunked.paired_blocks(zs, us)
        self.firsts = np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(int).tolist()

    def total(self, fn, *args):
        """``fn(zs_c, us_c, *args)`` summed over the chunks c (numbers, arrays, and tuples or dicts of them)."""
        import dask

        shared = dask.delayed(args, traverse=False)  # one node for every chunk: not searched, hashed or sent again
        parts = [dask.delayed(_apply)(fn, first, z, u, shared)
                 for first, z, u in zip(self.firsts, self.zs, self.us)]
        while len(parts) > 1:
            parts = [dask.delayed(_add)(*parts[i:i + 2]) for i in range(0, len(parts), 2)]
        return dask.compute(parts[0])[0]

    def e_step(self, model, prior, learn, structure, fixed, engine):
        loglik, first, second = self.total(_chunk_e_step, model, prior, learn, engine)

        def m_step():
            new = _first_solve(model, prior, first, learn)
            sums = second if second is not None else self.total(_chunk_second_sums, model, prior, new, learn, engine)
            return _second_solve(model, prior, first, new, sums, learn, structure, fixed)

        return loglik, m_step

    def score(self, model, prior, directions, engine):
        return self.scores([(model, prior, directions)], engine)[0]

    def scores(self, requests, engine):
        """Each request's score, in one pass over the chunks (one task a chunk, rather than one a request)."""
        return list(self.total(_chunk_scores, tuple(requests), engine))


def _apply(fn, first: int, zs, us, args):
    """``fn(zs, us, *args)`` on the chunk of series from `first`, its errors naming them by their numbers in the whole
    array (audit NN1: "in series 2" for the 6th)."""
    try:
        return fn(zs, us, *args)
    except (ValueError, TypeError, FloatingPointError) as err:
        chunked.renumber(err, first, zs.shape[0])
        raise


def _chunk_e_step(zs, us, model, prior, learn, engine):
    """A chunk's log-likelihood and first-stage sums; its second-stage ones too when they need no new matrix."""
    loglik, stats = _e_step(model, prior, zs, us, engine)
    first = _first_sums(model, stats, learn)
    second = None if _second_needs_the_first(learn) else _second_sums(stats, _first_solve(model, prior, {}, ()), learn)
    return loglik, first, second


def _chunk_second_sums(zs, us, model, prior, new, learn, engine):
    return _second_sums(_e_step(model, prior, zs, us, engine)[1], new, learn)


def _chunk_scores(zs, us, requests, engine):
    return tuple(_loglik_and_gradient(model, prior, zs, us, directions, engine)
                 for model, prior, directions in requests)


def _add(a, b=None):
    """The sum of two partial results of :meth:`_Chunks.total` (one alone is itself)."""
    if b is None:
        return a
    if isinstance(a, tuple):
        return tuple(_add(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return {key: _add(a[key], b[key]) for key in a}
    return a + b


def _em(model, prior, data, learn, structure, iterations, tol, nobs, callback, engine, switch=None):
    """EM's iterations: the model and prior kept, the history, whether it converged, why it stopped, and the
    engine of its last iteration (`engine` before iteration `switch`, when given, compiled from it on).

    It converges when the log-likelihood changes by at most `tol` per observed value (of `nobs`): a change of
    log-likelihood does not depend on the data's units, as the log-likelihood itself does.
    """
    history: list[float] = []
    fixed = {name: (_fixed_zeros(_current(model, prior, name), structure[name]) if name in learn else None)
             for name in COVARIANCES}
    model, prior = _structured_start(model, prior, learn, structure, fixed)
    best = (model, prior)
    message, converged = f"stopped at the limit of {iterations} iterations", False
    try:
        for it in range(iterations + 1):
            if switch is not None and it >= switch:
                engine = "numba"
            try:
                loglik, m_step = data.e_step(model, prior, learn, structure, fixed, engine)
            except NotIdentified as exc:
                if it == 0:
                    raise
                # the diffuse likelihood grows without bound as a learned F or H loses rank: stopped as below,
                # with the model before it (the error lost the iterations' work: audit Y2)
                message = (f"stopped at iteration {it}: the learned model no longer identifies the diffuse initial "
                           f"state (the log-likelihood rose to {history[-1]:.6g} on the way): {exc} Or learn fewer "
                           "of F and H, whose smallest singular values EM can shrink toward zero; the model before "
                           "it is returned")
                break
            except (np.linalg.LinAlgError, FloatingPointError) as exc:
                if it == 0:
                    raise
                # the M-step left a model the filter cannot run: a singular S where the likelihood grows without
                # bound (one sensor a copy of another, learned with no noise between them), or an overflow
                message = (f"stopped at iteration {it}: the learned model cannot be filtered ({exc}); the "
                           "likelihood may have no maximum (a measurement that others determine exactly, say); "
                           "the model before it is returned")
                break
            history.append(loglik)
            if it > 0 and np.isfinite(loglik) and loglik < history[-2] - 1e-6 * (1.0 + abs(history[-2])):
                message = (f"stopped at iteration {it}: the log-likelihood fell from {history[-2]:.6g} to {loglik:.6g}, "
                           "which an EM step cannot do, so round-off has taken it over (a learned variance near 0, "
                           "say); the model before it is returned")
                history.pop()
                break
            best = (model, prior)
            if callback is not None:
                callback(it, loglik)
            if tol > 0 and it > 0 and abs(history[-1] - history[-2]) <= tol * nobs:
                message, converged = "converged: the log-likelihood changed by less than `tol`", True
                break
            if it == iterations:
                break
            model, prior = m_step()
    except KeyboardInterrupt:
        if not history:
            raise
        message = "interrupted: the best model so far"
    model, prior = best
    return model, prior, np.array(history), converged, message, engine


def _check_regression_q(Q: np.ndarray) -> None:
    """Refuse EM's F (or B) step under a fixed Q that is singular on its non-zero variances.

    The M-step's least-squares regression of x_t on x_{t-1} is the maximiser of
    the expected complete-data log-likelihood when Q is positive definite (and
    a row of a state with zero variance is held); with Q = g gᵀ, an ARMA
    model's, the residuals lie in the range of Q exactly and the regression
    can leave it: the likelihood fell (-482.24056 to -482.24061) and
    structural zeros of F moved. Maximum likelihood has no such step.
    """
    seen = np.diagonal(Q) > 0.0
    block = Q[np.ix_(seen, seen)]
    if block.size and not is_positive_definite(block):
        raise ValueError("learning F or B by EM needs Q positive definite on its non-zero variances (its M-step is "
                         "a least-squares regression, not a maximiser, when Q is singular there, and EM could lower "
                         "the likelihood); learn Q too, or use method='mle'.")


def _structured_start(model: LinearModel, prior, learn: tuple, structure: dict, fixed: dict):
    """The start with each learned covariance projected onto its `structure`, as every M-step leaves it.

    Otherwise the history would start from a model EM cannot return to: a
    non-scalar R under ``"scalar"`` scored above the scalar optimum, and the
    first iteration "lowered" the log-likelihood.
    """
    new = {name: _structured(_current(model, prior, name), structure[name], fixed[name])
           for name in COVARIANCES if name in learn and structure[name] != "full"}
    if not new:
        return model, prior
    if "Q" in new or "R" in new:
        model = model._replace(Q=new.get("Q", model.Q), R=new.get("R", model.R))
    if "P0" in new:
        prior = Gaussian(prior.mean, new["P0"])
    return model, prior


def _current(model: LinearModel, prior, name: str) -> np.ndarray:
    """The value of a learnable quantity."""
    if name == "m0":
        return prior.mean
    if name == "P0":
        return prior.cov
    return getattr(model, name)


# ---------------------------------------------------------------------------
# Parameters and their directions
# ---------------------------------------------------------------------------


def _resolved_sizes(model: LinearModel) -> np.ndarray:
    r"""Each state component's size as n noise-free steps from a known start resolve it: 1 / √ of the diagonal of
    their information about it, :math:`\sum_k (H_k \Phi_k)^\top R_k^{-1} (H_k \Phi_k)`,
    :math:`\Phi_k = F_k \cdots F_1`, in the data's units (measurements with R_ii = 0 left out). Each component
    counts the n steps from the first that informs it, through each step's matrices (a time-varying model's
    walked on until every component has had its n, or its steps end); the largest of the others' sizes for a
    component none resolves, and 1 if they resolve none. A velocity that H = [1, 0] does not see is resolved
    through F. A unit of 1 left m0 at its start for data of 1e8, said converged (audit EE1); a sensor's own noise
    over a gain of 1e-10 (1e10) kept the search from meeting `tol` (review R35); a first step measuring nothing,
    or a component first measured late, was sized by another's or by 1 (reviews R36, R38); a never-resolved
    component's walk over all T steps shrank the others' sizes with T (review R37)."""
    n, m = model.n, model.m
    Fs, Hs = model.F.reshape(-1, n, n), model.H.reshape(-1, m, n)
    Rs = np.diagonal(model.R.reshape(-1, m, m), axis1=-2, axis2=-1)
    steps = max(len(Fs), len(Hs), len(Rs))
    # the components any step can inform: those some measurement reads, and through F's entries those that move
    # them (a component none can inform walked all T steps, 1.8 s at T = 1e5: review R39)
    informed = ((Hs != 0) & (Rs > 0)[..., None]).any(axis=(0, 1))
    moves = (Fs != 0).any(axis=0)  # moves[i, j]: component j moves component i at some step
    for _ in range(n):
        informed = informed | moves[informed].any(axis=0)
    info, power, counted = np.zeros(n), np.eye(n), np.zeros(n, dtype=np.int64)  # steps of information counted
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for k in range(max(n, steps)):
            F, H, r = Fs[min(k, len(Fs) - 1)], Hs[min(k, len(Hs) - 1)], Rs[min(k, len(Rs) - 1)]
            seen = r > 0
            power = F @ power
            if not np.isfinite(power).any():  # (everything overflowed: nothing more to learn)
                break
            A = H[seen] @ power
            gathering = counted < n
            terms = (A * A / r[seen][:, None]).sum(axis=0)  # an explosive component's inf or NaN is no information:
            info += np.where(gathering & np.isfinite(terms), terms, 0.0)  # the others' still count (reviews R37, R38)
            counted += gathering & (info > 0)
            if (counted >= n)[informed].all() or (k + 1 >= n and steps <= n):  # (a time-invariant model: n steps)
                break
        size = 1.0 / np.sqrt(info)
    resolved = np.isfinite(size) & (size > 0)
    return np.where(resolved, size, size[resolved].max() if resolved.any() else 1.0)


class _Parametrisation:
    """Unconstrained parameters θ ↔ the learned matrices (see the module notes).

    A learned covariance is parametrised on its free components, those with
    a positive variance at the start; the others stay at zero.
    """

    def __init__(self, model: LinearModel, prior, learn: tuple, structure: dict, *, labels_only: bool = False,
                 controls: np.ndarray | None = None):
        """With `labels_only`, only :meth:`names` and :meth:`values` (no θ: a full covariance may be singular).
        `controls` (p,) is the size of each control in the data (for the units of B)."""
        self.model, self.prior, self.learn, self.structure = model, prior, learn, structure
        self.controls = controls
        self.free = {name: ~_fixed_zeros(_current(model, prior, name), structure[name])
                     for name in learn if name in COVARIANCES}
        if labels_only:
            return
        for name, free in self.free.items():
            if structure[name] == "full" and free.any():
                block = _current(model, prior, name)[np.ix_(free, free)]
                if not is_positive_definite(block):
                    raise ValueError(
                        f"`{name}` must be positive definite on its non-zero variances to be learned by "
                        f"maximum likelihood (through its Cholesky factor); got {name} = "
                        f"{shown(_current(model, prior, name))}. Start from a "
                        "positive definite value, hold a component at zero by giving it zero variance, "
                        "or use method='em'."
                    )
        self.sizes = [self._encode(name, _current(model, prior, name)).size for name in learn]

    def _encode(self, name: str, value: np.ndarray) -> np.ndarray:
        if name not in COVARIANCES:
            return value.ravel()
        free, kind = self.free[name], self.structure[name]
        if not free.any():
            return np.zeros(0)
        sub = value[np.ix_(free, free)]
        if kind == "scalar":
            return np.array([np.log(np.mean(np.diag(sub)))])
        if kind == "diagonal":
            return np.log(np.diag(sub))
        L = cholesky(sub)
        rows, cols = np.tril_indices(sub.shape[0])
        out = L[rows, cols].copy()
        out[rows == cols] = np.log(out[rows == cols])
        return out

    def _factor(self, name: str, theta: np.ndarray) -> np.ndarray:
        """The Cholesky factor of a full covariance's free block."""
        k = int(self.free[name].sum())
        L = np.zeros((k, k))
        rows, cols = np.tril_indices(k)
        L[rows, cols] = np.where(rows == cols, np.exp(theta), theta)
        return L

    def _place(self, name: str, sub: np.ndarray) -> np.ndarray:
        """A covariance with block `sub` on its free components and zeros elsewhere."""
        free = self.free[name]
        out = np.zeros((free.size, free.size))
        out[np.ix_(free, free)] = sub
        return out

    def _decode(self, name: str, theta: np.ndarray) -> np.ndarray:
        shape = _current(self.model, self.prior, name).shape
        if name not in COVARIANCES:
            return theta.reshape(shape)
        kind, k = self.structure[name], int(self.free[name].sum())
        if k == 0:
            return np.zeros(shape)
        if kind == "scalar":
            sub = np.exp(theta[0]) * np.eye(k)
        elif kind == "diagonal":
            sub = np.diag(np.exp(theta))
        else:
            L = self._factor(name, theta)
            sub = L @ L.T
        return self._place(name, sub)

    def encode(self) -> np.ndarray:
        return np.concatenate([self._encode(n, _current(self.model, self.prior, n)) for n in self.learn])

    def units(self, theta: np.ndarray) -> np.ndarray:
        """The size of a change of each entry of θ that moves the model as much in any units of the data: 1 for
        a log variance and an entry of F, a component's standard deviation for an entry of a Cholesky
        factor's row or of m0 (which scale with the data), for H[i, j] the larger of 1 and measurement i's
        noise standard deviation over component j's size (the largest of its prior mean, its prior's and its
        process noise's standard deviations), and for B[i, j] the process noise's standard deviation of
        component i over the size of control j (B u moves the state; the controls may be in other
        units than the data). Where those are missing, a component is sized by what the measurements resolve
        of it (:func:`_resolved_sizes`): m0 under a prior certain of it by the larger of that and the process
        noise's (a Q of 1e-20 beside an R of 1 is no size: the search stopped at its start), under a prior nearly
        certain of it by the larger of its standard deviation and that, B's row by the
        larger of that and its process noise's (else its prior's)."""
        out = []
        model, prior = self(theta)
        n = model.n
        sd = np.zeros(n) if isinstance(prior, str) else np.sqrt(np.clip(np.diag(prior.cov), 0.0, None))
        variances = np.diagonal(model.Q, axis1=-2, axis2=-1).reshape(-1, n).mean(axis=0)
        noise = np.sqrt(np.clip(variances, 0.0, None))
        measured = _resolved_sizes(model)
        for name, t in self.split(theta).items():
            if name == "m0":
                # (a tiny Q is no size for m0; nor a prior nearly certain of it, below what the data resolve: at
                # P0 = 1e-16 the search stayed at its start, converged, 17.6 below the maximum: audit UU1)
                out.append(np.where(sd > 0, np.maximum(sd, measured), np.maximum(noise, measured)))
            elif name == "H":
                # 1, or where it is larger a measurement's noise over its state's size: a unit of 1 for data of
                # 1e6 kept the search at its start, as if the likelihood did not depend on H (audit UU2). The
                # state's size is the largest of its prior mean and its prior's and process noise's standard
                # deviations: the noise's alone (1e-3 for a level of 1e5) made H's unit 1e6 times its size (review
                # R52), and the ratio alone, under a prior of 1e4 beside a level of 1, 1e-4 of it (review R53):
                # either stalled the search short of the maximum, where a unit of 1 reached it
                r = np.diagonal(model.R, axis1=-2, axis2=-1).reshape(-1, model.m).mean(axis=0)
                rows = np.sqrt(np.clip(r, 0.0, None))
                level = np.zeros(n) if isinstance(prior, str) else np.abs(prior.mean)
                cols = np.maximum(np.maximum(level, sd), noise)
                unit = np.where((rows[:, None] > 0) & (cols[None, :] > 0), rows[:, None] / np.where(cols > 0, cols, 1.0),
                                1.0)
                out.append(np.maximum(1.0, np.broadcast_to(unit, model.H.shape).ravel()))
            elif name == "B":
                p = t.size // n
                rows = np.maximum(np.where(noise > 0, noise, sd), measured)  # (a tiny Q is no size for B either)
                cols = np.ones(p) if self.controls is None else np.where(self.controls > 0, self.controls, 1.0)
                out.append((rows[:, None] / cols[None, :]).ravel())
            elif name in COVARIANCES and self.structure[name] == "full" and t.size:
                L = self._factor(name, t)
                rows, cols = np.tril_indices(L.shape[0])
                norms = np.sqrt(np.sum(L * L, axis=1))
                out.append(np.where(rows == cols, 1.0, norms[rows]))
            else:
                out.append(np.ones(t.size))
        return np.concatenate(out) if out else np.zeros(0)

    def curved(self, theta: np.ndarray) -> np.ndarray:
        """Which entries of θ are log variances: a diagonal or scalar covariance's, and a full one's Cholesky
        diagonal (see :func:`_beyond_gradient`; a full one's other entries have a standard deviation's units)."""
        out = []
        for name, t in self.split(theta).items():
            if name in COVARIANCES and self.structure[name] == "full" and t.size:
                rows, cols = np.tril_indices(self._factor(name, t).shape[0])
                out.append(rows == cols)
            else:
                out.append(np.full(t.size, name in COVARIANCES))
        return np.concatenate(out) if out else np.zeros(0, dtype=bool)

    def split(self, theta: np.ndarray) -> dict:
        out, start = {}, 0
        for name, size in zip(self.learn, self.sizes):
            out[name] = theta[start:start + size]
            start += size
        return out

    def __call__(self, theta: np.ndarray):
        parts = {name: self._decode(name, t) for name, t in self.split(theta).items()}
        prior = self.prior
        if "m0" in parts or "P0" in parts:
            prior = Gaussian(parts.get("m0", prior.mean), parts.get("P0", prior.cov))
        return self.model._replace(**{k: parts[k] for k in _MATRICES if k in parts}), prior

    def directions(self, theta: np.ndarray) -> list[dict]:
        """``∂(learned matrices)/∂θ_j`` for each j: a dict of the one matrix θ_j moves."""
        out = []
        for name, t in self.split(theta).items():
            shape = _current(self.model, self.prior, name).shape
            if name not in COVARIANCES:
                for j in range(t.size):
                    d = np.zeros(t.size)
                    d[j] = 1.0
                    out.append({name: d.reshape(shape)})
                continue
            kind, k = self.structure[name], int(self.free[name].sum())
            if kind == "scalar":
                out.extend([{name: self._place(name, np.exp(t[0]) * np.eye(k))}] if k else [])
            elif kind == "diagonal":
                for j in range(k):
                    sub = np.zeros((k, k))
                    sub[j, j] = np.exp(t[j])
                    out.append({name: self._place(name, sub)})
            else:
                L = self._factor(name, t)
                for r, c in zip(*np.tril_indices(k)):
                    dL = np.zeros((k, k))
                    dL[r, c] = L[r, c] if r == c else 1.0  # d exp(θ)/dθ = exp(θ) on the diagonal
                    X = dL @ L.T
                    out.append({name: self._place(name, X + X.T)})
        return out

    def names(self) -> list[str]:
        """Names of the learned values (see FitResult.params)."""
        out = []
        for name in self.learn:
            value = _current(self.model, self.prior, name)
            if name not in COVARIANCES:
                out.extend(_entry_names(name, value.shape))
                continue
            free, kind = np.flatnonzero(self.free[name]), self.structure[name]
            if kind == "scalar" or value.shape == (1, 1):
                out.extend([name] if free.size else [])
            elif kind == "diagonal":
                out.extend(f"{name}[{i},{i}]" for i in free)
            else:
                out.extend(f"{name}[{free[r]},{free[c]}]" for r, c in zip(*np.tril_indices(free.size)))
        return out

    def natural(self, theta: np.ndarray) -> np.ndarray:
        """The learned values named by :meth:`names`, at θ."""
        return self.values(*self(theta))

    def values(self, model: LinearModel, prior) -> np.ndarray:
        """The learned values named by :meth:`names`, of `model` and `prior`."""
        out = []
        for name in self.learn:
            value = _current(model, prior, name)
            if name not in COVARIANCES:
                out.append(value.ravel())
                continue
            free, kind = np.flatnonzero(self.free[name]), self.structure[name]
            if not free.size:
                continue
            if kind == "scalar":
                out.append(value[free[:1], free[:1]])
            elif kind == "diagonal":
                out.append(value[free, free])
            else:
                rows, cols = np.tril_indices(free.size)
                out.append(value[free[rows], free[cols]])
        return np.concatenate(out) if out else np.zeros(0)


def _control_sizes(us) -> np.ndarray | None:
    """The root mean square of each control (p,) over every series and step (computed, for a dask array), or
    None without controls."""
    if us is None:
        return None
    if chunked.is_dask(us):
        return np.sqrt(np.asarray((us * us).mean(axis=(0, 1)).compute(), dtype=np.float64))
    return np.sqrt(np.mean(us * us, axis=(0, 1)))


def _entry_names(name: str, shape: tuple) -> list[str]:
    if int(np.prod(shape)) == 1:
        return [name]
    return [f"{name}[{','.join(str(i) for i in idx)}]" for idx in np.ndindex(*shape)]


class _UserParams:
    """A user's function θ → model (or (model, prior)); its directions by central differences."""

    def __init__(self, fn: Callable, prior, size: int):
        self.fn, self.prior, self.size = fn, prior, size

    def __call__(self, theta: np.ndarray):
        try:
            out = self.fn(theta.copy())
        except (ValueError, TypeError, FloatingPointError):
            raise  # a model its constructors refuse: no likelihood there (NO_LIKELIHOOD), or a named error
        except Exception as exc:  # ZeroDivisionError, KeyError, ...: named, not bare
            raise ModelFunctionError(f"`params` raised {type(exc).__name__} at theta = {theta.tolist()}: {exc}") \
                from exc
        model, prior = (out if isinstance(out, tuple) else (out, self.prior))
        if not isinstance(model, LinearModel):
            raise TypeError(f"`params` must return a LinearModel (or (LinearModel, Gaussian)); "
                            f"got {type(model).__name__}.")
        return model, check_prior(prior, model.n, diffuse_ok=True)

    def directions(self, theta: np.ndarray) -> list[dict]:
        out = []
        for j in range(theta.size):
            h = 1e-6 * max(1.0, abs(theta[j]))
            up, down = theta.copy(), theta.copy()
            up[j] += h
            down[j] -= h
            (m1, p1), (m2, p2) = self(up), self(down)
            d = {}
            for k in _MATRICES:
                a, b = getattr(m1, k), getattr(m2, k)
                if a is not None and np.any(a != b):
                    d[k] = (a - b) / (2 * h)
            if not isinstance(p1, str):
                for k, a, b in (("m0", p1.mean, p2.mean), ("P0", p1.cov, p2.cov)):
                    if np.any(a != b):
                        d[k] = (a - b) / (2 * h)
            out.append(d)
        return out

    def names(self) -> list[str]:
        return [f"theta[{i}]" for i in range(self.size)]

    def units(self, theta: np.ndarray) -> np.ndarray:
        """1 for each entry: a user's θ is in the units the user chose."""
        return np.ones(theta.size)

    def curved(self, theta: np.ndarray) -> np.ndarray:
        """None of a user's θ: how its model depends on it is not known (see :func:`_beyond_gradient`)."""
        return np.zeros(theta.size, dtype=bool)

    def natural(self, theta: np.ndarray) -> np.ndarray:
        return theta


# ---------------------------------------------------------------------------
# The exact gradient
# ---------------------------------------------------------------------------


def _needed(directions: list[dict]) -> set:
    return {name for d in directions for name in d}


def _well_conditioned(a: np.ndarray) -> bool:
    """Whether the covariance `a` (or each of a stack) is safely invertible: condition number below 1e8.

    Fisher's identity inverts it, with round-off amplified by its condition
    number; a singular covariance that round-off has made barely positive
    definite (a rank-one Q of an ARMA model, say) must not pass.
    """
    vals = np.linalg.eigvalsh(a)
    return bool(np.all(vals[..., 0] > 1e-8 * vals[..., -1]))


def _fisher_applies(model: LinearModel, prior, needed: set, start: int) -> bool:
    """Whether every covariance Fisher's identity inverts for `needed` is well conditioned."""
    Q = model.Q[start:] if model.Q.ndim == 3 else model.Q
    return ((not needed & {"F", "B", "Q"} or _well_conditioned(Q))
            and (not needed & {"H", "R"} or _well_conditioned(model.R))
            and (not needed & {"m0", "P0"} or isinstance(prior, str) or _well_conditioned(prior.cov)))


def _covariance_gradient(C: np.ndarray, second: np.ndarray, count: int = 1) -> np.ndarray:
    """``½ C⁻¹ (E[e eᵀ] - count·C) C⁻¹``: dℓ/dC of ``count`` Gaussian terms with residual second moment `second`."""
    L = cholesky(C)
    inner = cho_solve(L, second - count * C)
    return 0.5 * cho_solve(L, np.swapaxes(inner, -1, -2))


def _matrix_gradients(model: LinearModel, prior, stats: list[Statistics], needed: set) -> dict:
    """dℓ/dM for each `needed` M, per step (T, ...) summed over series, by Fisher's identity."""
    n, m = model.n, model.m
    T = stats[0].T
    g: dict = {}

    def add(name, value, start=0):
        full = np.zeros((T, *value.shape[1:]))
        full[start:] = value
        g[name] = g.get(name, 0.0) + full

    # Q, R, F, H and B are the same for every series at a step, and each gradient is linear in the
    # statistics: so the statistics are summed over the series first, and each step solves once.
    for s in stats:
        if needed & {"F", "B", "Q"}:
            Q = _per_step(model.Q, T)[s.start:]
            W = s.w_map(model.F, model.B)
            if "Q" in needed:
                add("Q", _covariance_gradient(Q, s.per_series_sum(s.residual_second_moment("w", W)), s.N), s.start)
            Qi_wS = cho_solve(cholesky(Q), s.per_series_sum(W @ s.Phi))  # Q⁻¹ E[w sᵀ], (T_w, n, d)
            if "F" in needed:
                add("F", Qi_wS[:, :, n:2 * n], s.start)
            if "B" in needed and model.B is not None:
                add("B", Qi_wS[:, :, 2 * n:2 * n + s.p], s.start)
        if needed & {"H", "R"}:
            R = _per_step(model.R, T)
            V = s.v_map(model.H)
            if "R" in needed:
                add("R", _covariance_gradient(R, s.per_series_sum(s.residual_second_moment("v", V)), s.N))
            if "H" in needed:
                add("H", cho_solve(cholesky(R), s.per_series_sum((V @ s.Psi)[:, :, m:m + n])))
    if needed & {"m0", "P0"} and not isinstance(prior, str):
        dev = [s.x0_mean - prior.mean for s in stats]
        g["m0"] = cho_solve(cholesky(prior.cov), sum(d.sum(axis=0) for d in dev))
        second = sum(np.sum(s.x0_cov + _outer(d), axis=0) for s, d in zip(stats, dev))
        g["P0"] = _covariance_gradient(prior.cov, second, count=sum(s.N for s in stats))
    return g


def _outer(v: np.ndarray) -> np.ndarray:
    """``v vᵀ`` for each row of `v` (N, n): (N, n, n)."""
    return v[:, :, None] * v[:, None, :]


def _contract(G: np.ndarray, D: np.ndarray) -> float:
    """``Σ G ⊙ D``: a per-step gradient (T, ...) or a matrix one against a direction."""
    if G.ndim == D.ndim + 1:
        G = G.sum(axis=0)
    return float(np.sum(G * D))


def _tangent_score(model: LinearModel, prior, zs: np.ndarray, us: np.ndarray | None,
                   directions: list[dict], engine: str) -> tuple[float, np.ndarray]:
    """``log p(z)`` of one series and its derivative along each direction (see the module notes).

    The values (means, covariances, innovations) come from the filter; the
    tangents are propagated alongside them, stacked over the directions.
    """
    T, n, p = zs.shape[0], model.n, len(directions)
    if isinstance(prior, str):
        runs = augmented_runs(model, zs, us, engine)
        mdl, results, first_step = runs.model, [runs.base, *runs.sens], 1
        us = None if us is None else np.vstack([np.zeros_like(us[:1]), us[1:]])
        M_prev, P_prev = np.hstack([runs.centre[:, None], np.eye(n)]), np.zeros((n, n))
    else:
        filt = first(filter_batch(_METHODS["kf"], model, prior, zs[None], None if us is None else us[None], {},
                                  engine, "all"))
        mdl, results, first_step = model, [filt], 0
        M_prev, P_prev = prior.mean[:, None], prior.cov
    c = len(results)
    Mp = np.stack([r.predicted_means for r in results], axis=-1)      # (T, n, c)
    Mf = np.stack([r.means for r in results], axis=-1)
    U = np.stack([r.innovations for r in results], axis=-1)          # (T, m, c)
    base = results[0]

    def tangent(name, k, shape):
        out = np.zeros((p, *shape))
        for j, d in enumerate(directions):
            if name in d:
                out[j] = d[name][k] if d[name].ndim == len(shape) + 1 else d[name]
        return out

    dM = np.zeros((p, n, c))
    dP = np.zeros((p, n, n))
    if first_step == 0:
        dM[:, :, 0] = tangent("m0", 0, (n,))
        dP = tangent("P0", 0, (n, n))
    G, dG = np.zeros((c, c)), np.zeros((p, c, c))
    logdet, dlogdet, observed = 0.0, np.zeros(p), 0
    I = np.eye(n)
    for k in range(T):
        F, H, _, R, B = mdl.at(k)
        if k >= first_step:
            dF = tangent("F", k, (n, n))
            X = dF @ P_prev @ F.T
            dMp = dF @ M_prev + F @ dM
            dPp = X + np.swapaxes(X, -1, -2) + F @ dP @ F.T + tangent("Q", k, (n, n))
            if B is not None:
                dMp[:, :, 0] += tangent("B", k, B.shape) @ us[k]
        else:
            dMp, dPp = F @ dM, F @ dP @ F.T
        M_prev, P_prev = Mf[k], base.covs[k]
        o = ~np.isnan(zs[k])
        if not o.any():
            dM, dP = dMp, dPp
            continue
        Ho, Pk, Uk = H[o], base.predicted_covs[k], U[k][o]
        dH = tangent("H", k, H.shape)[:, o]
        dR = tangent("R", k, R.shape)[:, o][:, :, o]
        L = cholesky(base.innovation_covs[k][np.ix_(o, o)], f"at step {k}: the innovation covariance S")
        dHP = dH @ Pk
        dS = dHP @ Ho.T
        dS = dS + np.swapaxes(dS, -1, -2) + Ho @ dPp @ Ho.T + dR
        dU = -(dH @ Mp[k]) - Ho @ dMp
        SiU = cho_solve(L, Uk)
        G += Uk.T @ SiU
        t = np.swapaxes(dU, -1, -2) @ SiU
        dG += t + np.swapaxes(t, -1, -2) - SiU.T @ dS @ SiU
        logdet += 2.0 * np.sum(np.log(np.diag(L)))
        dlogdet += np.trace(cho_solve(L, dS), axis1=-2, axis2=-1)
        observed += int(o.sum())
        Kt = cho_solve(L, Ho @ Pk)                              # Kᵀ, (m_o, n)
        dKt = cho_solve(L, Ho @ dPp + dHP - dS @ Kt)
        dM = dMp + np.swapaxes(dKt, -1, -2) @ Uk + Kt.T @ dU
        IKH = I - Kt.T @ Ho
        X = Kt.T @ dHP @ IKH.T
        dP = IKH @ dPp @ IKH.T - X - np.swapaxes(X, -1, -2) + Kt.T @ dR @ Kt
    loglik = -0.5 * (G[0, 0] + logdet + observed * LOG_2PI)
    grad = -0.5 * (dG[:, 0, 0] + dlogdet)
    if c > 1:  # the diffuse terms: ½ sᵀ 𝒮⁻¹ s - ½ log|𝒮|, 𝒮 = G[1:, 1:], s = -G[1:, 0]
        info, score = G[1:, 1:], -G[1:, 0]
        if not is_positive_definite(info):
            raise not_identified()
        LI = cholesky(info)
        a = cho_solve(LI, score)
        d_info, d_score = dG[:, 1:, 1:], -dG[:, 1:, 0]
        loglik += 0.5 * score @ a - np.sum(np.log(np.diag(LI)))
        grad += d_score @ a - 0.5 * np.einsum("i,pij,j->p", a, d_info, a) \
            - 0.5 * np.trace(cho_solve(LI, d_info), axis1=-2, axis2=-1)
    return float(loglik), grad


_EPS = float(np.finfo(np.float64).eps)

_FISHER_ROUNDOFF = 1e-8
"""Fisher's identity gives the gradient where the round-off of the residual means it reads is at most this
fraction of them (:func:`_fisher_resolves`); the filter's own score gives it elsewhere."""


def _fisher_resolves(model: LinearModel, prior, stats: list[Statistics], needed: set) -> bool:
    r"""Whether Fisher's identity resolves the gradient of `needed`, beside the filter's own score.

    The gradients of F and B read :math:`E[w_t] = E[x_t] - F_t E[x_{t-1}] - B_t u_t`
    through :math:`Q^{-1}`, that of H :math:`E[v_t] = z_t - H_t E[x_t]` through
    :math:`R^{-1}`, that of m0 :math:`E[x_0] - m_0` through :math:`P_0^{-1}`; each is a
    difference of numbers of the states' size, whose round-off does not
    shrink with the noise: where a noise is tiny beside what the data resolve
    of the states (:math:`E[w_t] \approx Q r_t`), the round-off is all there is
    of the difference. A process noise of 1e-20 gave B a gradient of -1.3e5
    for 6.1 and a fit that stopped at its start, 128 below the maximum; with
    states near 1e4, Q = 1e-8 gave it 3e-4 off. So, per component over the
    steps (those up to each series' last observation, or with one, as EM's
    sums), the round-off estimate (:math:`\epsilon` times the sizes of the
    terms) against the difference, as root sums of squares, must be at most
    :data:`_FISHER_ROUNDOFF`, or at most ten times the filter's own: its
    score (:func:`_tangent_score`) reads the innovations :math:`z_t - H_t m^-_t`
    against their standard deviations, with round-off
    :math:`\epsilon (|z_t| + |H_t| |m_t|)` (a level near 1e7 under unit noises
    costs both about 1e-10 per observation, and the filter's score took 3.7
    times as long: review R40).

    The gradients of Q, R and P0 read :math:`E[r_t r_t^\top]` minus the noise, in
    a log variance's units per observation the mean over the steps of
    :math:`(E[r_t^2] - \sigma^2) / \sigma^2`; its terms are of the filter's
    variances, which the smoother's covariances cancel (a prior variance of
    1e16 gave Q's gradient 30% off: review R40). Their round-off, summed with
    random signs over the steps, must be at most a tenth of maximum
    likelihood's default tolerance. (A variance the data hardly inform can
    have a gradient that is imprecise beside itself and negligible beside the
    tolerance: Q = 1e-20's is 1e-15 per observation.) Elsewhere the filter's
    own score gives the gradient. Not caught: a nearly singular Q amplifies,
    through :math:`Q^{-1}`, round-off that is small per component (condition
    2e7 gave B's gradient 2e-3 off).
    """
    sums: dict = {}  # per kind of mean: Σ read², Σ size² per component
    spread: dict = {}  # per kind of second moment: Σ (size / variance)² per component, and the steps

    def add(kind, read, size):
        total = sums.setdefault(kind, [0.0, 0.0])
        total[0] = total[0] + np.sum(read * read, axis=0)
        total[1] = total[1] + np.sum(size * size, axis=0)

    def residual(kind, M, mean, cov, filtered, noise, kept, linear, second):
        """E[r] = M s and the sizes of its terms, per component, where a `linear` parameter reads it; with `second`,
        the round-off of diag E[r rᵀ] - diag noise over the noise's variances; r's sizes, (steps, k)."""
        if not kept.all():
            M, mean, cov, filtered = M[kept], mean[kept], cov[kept], filtered[kept]
            noise = None if noise is None else noise[kept]
        absM = np.abs(M)
        r = (M @ mean[:, :, None])[..., 0]
        r_size = (absM @ np.abs(mean)[:, :, None])[..., 0]
        if linear:
            add(kind, r, r_size)
        if second:  # the covariance's terms are of the filter's variances, which the smoother's cancelled (NaN
            # before a diffuse state is known: fmax takes the smoothed one there)
            var = np.abs(np.diagonal(noise, axis1=-2, axis2=-1))
            sd = (absM @ np.sqrt(np.fmax(np.abs(np.diagonal(cov, axis1=-2, axis2=-1)), filtered))[:, :, None])[..., 0]
            size = sd ** 2 + 2.0 * r_size * np.abs(r) + var
            total = spread.setdefault(kind, [0.0, 0])
            total[0] = total[0] + np.sum((size / var) ** 2, axis=0)
            total[1] += r.shape[0]
        return r_size

    innovation = [0.0, 0.0]
    for s in stats:
        if needed & {"F", "B", "Q"}:
            residual("w", s.w_map(model.F, model.B), s.mu, s.sig, s.filtered_w, s.per_step(model.Q, s.start),
                     s.kept_w, bool(needed & {"F", "B"}), "Q" in needed)
        v_size = residual("v", s.v_map(model.H), s.nu, s.tau, s.filtered_v, s.per_step(model.R), s.kept_v,
                          "H" in needed, "R" in needed)
        variances = s.innovation_var[s.kept_v]
        seen = s.observed[s.kept_v] & np.isfinite(variances)  # (a diffuse first step has none)
        innovation[0] += float(np.sum(np.where(seen, variances, 0.0)))
        innovation[1] += float(np.sum(np.where(seen, v_size ** 2, 0.0)))
        if needed & {"m0", "P0"} and not isinstance(prior, str):
            x0, n, k = s.x0_mean[s.seen], model.n, int(s.seen.sum())
            residual("x0", np.broadcast_to(np.hstack([np.eye(n), -np.eye(n)]), (k, n, 2 * n)),
                     np.hstack([x0, np.broadcast_to(prior.mean, x0.shape)]),
                     np.pad(s.x0_cov[s.seen], ((0, 0), (0, n), (0, n))),
                     np.pad(s.filtered_x0[s.seen], ((0, 0), (0, n))), np.broadcast_to(prior.cov, (k, n, n)),
                     np.ones(k, dtype=bool), "m0" in needed, "P0" in needed)
    with np.errstate(divide="ignore", invalid="ignore"):  # (a component with no residual and no size: 0)
        fisher = max((float(np.max(np.where(size > 0.0, _EPS * np.sqrt(size) / np.sqrt(read), 0.0), initial=0.0))
                      for read, size in sums.values()), default=0.0)
        # a log variance's gradient per observation is the mean of (E[r²] - var) / var: its round-off, summed with
        # random signs over the steps, against a tenth of maximum likelihood's default tolerance
        variance = max((float(np.max(_EPS * np.sqrt(total) / max(steps, 1), initial=0.0))
                        for total, steps in spread.values()), default=0.0)
    tangent = _EPS * np.sqrt(innovation[1]) / np.sqrt(innovation[0]) if innovation[0] > 0.0 else 0.0
    return bool(fisher <= max(_FISHER_ROUNDOFF, 10.0 * tangent) and not variance > 0.1 * _MLE_GTOL)


def _fisher_gradient(model: LinearModel, prior, stats: list[Statistics], directions: list[dict]) -> np.ndarray:
    """The derivative of ``log p(z)`` along each direction by Fisher's identity, from the smoother's statistics."""
    G = _matrix_gradients(model, prior, stats, _needed(directions))
    return np.array([sum(_contract(G[k], D) for k, D in d.items()) for d in directions])


def _fisher_score(model, prior, zs, us, directions: list[dict], engine: str) -> tuple[float, np.ndarray]:
    """``log p(z)`` over the series and its derivative along each direction, by Fisher's identity."""
    ll, stats = _e_step(model, prior, zs, us, engine)
    return ll, _fisher_gradient(model, prior, stats, directions)


def _loglik_and_gradient(model, prior, zs, us, directions: list[dict], engine: str) -> tuple[float, np.ndarray]:
    """``log p(z)`` over the series and its exact derivative along each direction.

    By Fisher's identity where it applies and its statistics resolve the
    gradient (one smoother pass, compiled: :func:`_fisher_applies`,
    :func:`_fisher_resolves`), by the filter's own score otherwise.
    """
    needed = _needed(directions)
    if _fisher_applies(model, prior, needed, 1 if isinstance(prior, str) else 0):
        ll, stats = _e_step(model, prior, zs, us, engine)
        if _fisher_resolves(model, prior, stats, needed):
            return ll, _fisher_gradient(model, prior, stats, directions)
    ll, grad = 0.0, np.zeros(len(directions))
    for i, z in enumerate(zs):
        li, gi = _tangent_score(model, prior, z, None if us is None else us[i], directions, engine)
        ll, grad = ll + li, grad + gi
    return ll, grad


# ---------------------------------------------------------------------------
# Maximum likelihood and the observed information
# ---------------------------------------------------------------------------


_EM_STALLED = 1e3
"""EM has stalled, not converged, where a Newton step would gain this many times its last change or more
(`tol` per observation): a thousand iterations' worth, had it kept that pace."""

_MLE_GTOL = 1e-8
"""Maximum likelihood's default `tol`: the gradient's largest component per observation at a maximum."""


def _evaluator(build, data, engine):
    """``theta -> (loglik, gradient)``, cached on θ.

    ``evaluate.prefetch(thetas)`` evaluates many θ together, each pass over
    the data independent of the others: one round trip to a cluster for the
    2k points of a Hessian rather than 2k.
    """
    cache: dict[bytes, tuple[float, np.ndarray]] = {}

    def evaluate(theta: np.ndarray) -> tuple[float, np.ndarray]:
        key = theta.tobytes()
        if key not in cache:
            mdl, pri = build(theta)
            cache[key] = data.score(mdl, pri, build.directions(theta), engine)
        return cache[key]

    def prefetch(thetas: list[np.ndarray]) -> None:
        todo = {theta.tobytes(): theta for theta in thetas if theta.tobytes() not in cache}
        if not todo:  # (on a cluster, a round trip for nothing)
            return
        try:
            results = data.scores([(*build(theta), build.directions(theta)) for theta in todo.values()], engine)
        except NO_LIKELIHOOD:  # left to evaluate(), one θ at a time, to raise where it does alone
            return
        cache.update(zip(todo, results))

    evaluate.prefetch = prefetch
    return evaluate


def _boundary(model, prior, learn, start=None) -> str:
    """A hint for a fit that stopped near a singular learned covariance, where its maximum may lie ("" if none).

    There a variance tends to 0, a search in the covariance's Cholesky
    factor (MLE) or EM's fixed-point steps slow down, and they can stop
    short of their tolerance with a model that is as good as the maximum.
    Where the learned noise vanished altogether (below 1e-100 of the
    `start` model's), the data are fitted exactly and the likelihood has no
    maximum at all. A user's `params` (`learn` None) get none: what they
    learn is not known.
    """
    if learn is None:  # (it raised TypeError on a `params` fit that did not converge: review R10)
        return ""
    vanished = [name for name in ("Q", "R") if name in learn and isinstance(getattr(start, name, None), np.ndarray)
                and np.max(np.abs(getattr(model, name))) <= 1e-100 * np.max(np.abs(getattr(start, name)))]
    if vanished:
        names, it = " and ".join(vanished), "them" if len(vanished) > 1 else "it"
        return (f" The learned {names} went to 0 (below 1e-100 of the start) as the log-likelihood grew: a model "
                f"without that noise fits the data exactly (constant or noise-free data, say), so the likelihood has "
                f"no maximum; keep {names} fixed (leave {it} out of `learn`), or learn {it} through `params` with a "
                "floor.")
    for name in ("Q", "R", "P0"):
        if name not in learn:
            continue
        cov = getattr(prior, "cov", None) if name == "P0" else getattr(model, name, None)
        if not isinstance(cov, np.ndarray) or cov.ndim != 2 or cov.shape[0] < 2:
            continue
        values = np.linalg.eigvalsh(cov)
        if values[-1] > 0.0 and values[0] <= 1e-6 * values[-1]:
            return (f" The learned {name} is nearly singular (eigenvalues {values[0]:.3g} to {values[-1]:.3g}): the "
                    f"maximum may lie where one of its variances is 0, which the search approaches slowly; the model "
                    f"found may be as good, or constrain {name} (`structure={{{name!r}: 'diagonal'}}`, or a "
                    f"physical noise model through `params`).")
    return ""


NO_LIKELIHOOD = (ValueError, FloatingPointError)
"""What evaluating θ raises where it has no likelihood: a singular S (LinAlgError), a pass that overflows, or
a model the constructors refuse (a variance that overflowed). Only θ the search tried meet it: the start is
evaluated first, outside these handlers."""


def _mle(build, theta0, data, n_obs, iterations, tol, callback, engine):
    """BFGS on the log-likelihood per observation, in θ's units (``build.units``): the search, its gradient test
    (`tol`) and the Newton steps that finish it are the same in any units of the data.

    The units are those of the start; where the search ends, the gradient test is taken again in the units there,
    and where it fails the search goes on from there in those units (at most :data:`_MLE_ROUNDS` rounds in all,
    within `iterations`). A variance that grows by many orders over the search changes the units of what it
    measures: m0's unit under R = 1e-12 is 1e-6, and a search that raised R to 1e6 stopped there with m0 at its
    start of 0, said converged, 1041 below the maximum (review R41).
    """
    n_obs = max(n_obs, 1)
    evaluate = _evaluator(build, data, engine)
    units = build.units(theta0)  # the search moves φ = θ / units
    history: list[float] = []
    best = [theta0, -np.inf]

    def objective(phi):
        theta = phi * units
        try:
            ll, grad = evaluate(theta)
        except NO_LIKELIHOOD:  # a trial step with no likelihood: the line search steps back
            return np.inf, np.zeros_like(theta)
        if ll > best[1]:
            best[0], best[1] = theta.copy(), ll
        return -ll / n_obs, -grad * units / n_obs

    def on_iteration(phi):
        history.append(evaluate(phi * units)[0])
        if callback is not None:
            callback(len(history) - 1, history[-1])

    history.append(evaluate(theta0)[0])
    if callback is not None:
        callback(0, history[0])
    if theta0.size == 0:  # every learned variance starts at 0 and is held there, as EM holds it
        return theta0, np.array(history), True, "converged: nothing to learn (every learned variance is held at 0)", \
            evaluate
    from scipy import optimize

    theta = theta0
    try:
        for _ in range(_MLE_ROUNDS):
            # the first step is -hess_inv0 @ gradient: at most 1 in any entry of φ. With the identity, a start far
            # below the data's variances stepped a log variance by ~1e3 and stalled there (audit Y2: Nile from
            # Q = R = 1 stopped at loglik -1384.95 with Q = 8e-16)
            steepest = float(np.max(np.abs(objective(theta / units)[1])))
            hess_inv0 = np.eye(theta.size) / max(1.0, steepest)
            res = optimize.minimize(objective, theta / units, jac=True, method="BFGS", callback=on_iteration,
                                    options={"maxiter": max(iterations - len(history) + 1, 1), "gtol": tol,
                                             "hess_inv0": hess_inv0})
            theta, converged, message, reached = res.x * units, bool(res.success), str(res.message), None
            if evaluate(theta)[0] < best[1]:
                theta = best[0]
            if res.status == 2:  # BFGS's line search stalled near the optimum: finish with Newton steps
                theta, reached = _newton(evaluate, theta, tol * n_obs, units)
                converged = reached is not None
                if reached == "gradient":
                    message = "converged: the gradient is below `tol` after Newton steps with the observed information"
                elif reached == "resolution":
                    message = ("converged: a Newton step with the observed information moves no parameter beyond "
                               "its floating-point resolution (the gradient's round-off is above `tol`)")
            if reached == "resolution" or len(history) > iterations:
                break
            ended = build.units(theta)  # the gradient test again, in the units where the search ended
            if converged:
                if _gradient_met(evaluate(theta)[1], ended, tol * n_obs):
                    break
                converged, message = False, "stopped where the gradient test is not met in the units there"
            elif np.all((ended <= 2.0 * units) & (units <= 2.0 * ended)):  # stalled in the same units: no new try
                break
            units = ended
    except KeyboardInterrupt:
        theta, converged, message = best[0], False, "interrupted: the best model so far"
    ll = evaluate(theta)[0]
    if not history or history[-1] != ll:
        history.append(ll)
    return theta, np.array(history), converged, message, evaluate


_MLE_ROUNDS = 4
"""How many times :func:`_mle` starts BFGS afresh in the units where the last round ended."""


def _sizes(theta: np.ndarray, units: np.ndarray) -> np.ndarray:
    """Each entry's size, at least its unit: the scale of the finite-difference steps in θ."""
    return np.maximum(units, np.abs(theta))


def _hessian(evaluate, theta: np.ndarray, sizes: np.ndarray, units: np.ndarray) -> np.ndarray:
    """The Hessian of the log-likelihood in φ = θ / `units`, by central differences of the exact gradient
    (symmetrised): ``D H D`` with ``D = diag(units)``, formed without forming H in θ, whose entry for B of
    controls of 1e150 and data of 1e-10 is u²/Q, 1e320 (audit EE1: the standard errors raised LinAlgError).

    Each step is 1e-5 of the entry's `sizes` (:func:`_sizes`).
    """
    k = theta.size
    steps = 1e-5 * sizes
    up = [theta + h * e for h, e in zip(steps, np.eye(k))]
    down = [theta - h * e for h, e in zip(steps, np.eye(k))]
    evaluate.prefetch([theta] + up + down)  # (θ's gradient too, which the standard errors' test reads)
    hess = np.zeros((k, k))
    for j in range(k):
        hess[:, j] = (evaluate(up[j])[1] * units - evaluate(down[j])[1] * units) * (units[j] / (2 * steps[j]))
    return symmetrize(hess)


def _gradient_met(grad: np.ndarray, units: np.ndarray, gtol: float) -> bool:
    """Maximum likelihood's gradient test: ``max|∇ℓ units| <= gtol``, the gradient in φ = θ / units."""
    return bool(np.max(np.abs(grad * units), initial=0.0) <= gtol)


def _newton(evaluate, theta: np.ndarray, gtol: float, units: np.ndarray,
            steps: int = 5) -> tuple[np.ndarray, str | None]:
    """Newton steps ``θ + I(θ)⁻¹ ∇ℓ`` while they raise the log-likelihood; why they stopped at a maximum, or None.

    Near the optimum the log-likelihood is flat to round-off, so a step that
    lowers it by no more than round-off still counts as a rise. At a maximum:
    "gradient" where ``max|∇ℓ units| <= gtol``; "resolution" where the Newton
    step moves no entry of θ by more than 4 ε |θ_j|: θ is the maximum to
    floating point, whatever the gradient's round-off (a sensor of R = 1e-20
    measuring a level of 1, or 1e-12 one of 1e3: m0 equal to the data's mean to
    the last digit, and the gradient test out of reach).
    """
    for _ in range(steps):
        ll, grad = evaluate(theta)
        if _gradient_met(grad, units, gtol):
            return theta, "gradient"
        try:
            information = -_hessian(evaluate, theta, _sizes(theta, units), units)  # on φ = θ / units: finite
            if not is_positive_definite(information):
                break
            move = units * cho_solve(cholesky(information), grad * units)
            if np.all(np.abs(move) <= 4.0 * _EPS * np.abs(theta)):
                return theta, "resolution"
            step = theta + move
            if not evaluate(step)[0] >= ll - 1e-11 * (1.0 + abs(ll)):  # (a rise, to round-off)
                break
        except NO_LIKELIHOOD:  # a neighbour with no likelihood: no step
            break
        theta = step
    return theta, "gradient" if _gradient_met(evaluate(theta)[1], units, gtol) else None


def _flat(evaluate, theta: np.ndarray, information: np.ndarray, units: np.ndarray) -> np.ndarray:
    """The parameters the log-likelihood does not depend on (a never-observed sensor's variance), as a bool mask.

    Their row of the information is round-off, which can pass for positive definite (a standard error of 6e5
    for a variance the likelihood does not see). A parameter whose information, in its `units`, is below 1e-6 of
    the largest is moved by a tenth of its size (at least a tenth of its unit) both ways; it is flat when the
    log-likelihood stays within 1e-12 of its size.
    """
    diag = np.abs(np.diagonal(information))  # (the information in φ = θ / units: see _standard_errors)
    flat = np.zeros(theta.size, dtype=bool)
    suspects = np.flatnonzero(diag <= 1e-6 * diag.max(initial=0.0))
    if not suspects.size:
        return flat
    moved = {j: [theta + sign * 0.1 * max(units[j], abs(theta[j])) * np.eye(theta.size)[j] for sign in (1.0, -1.0)]
             for j in suspects}
    evaluate.prefetch([t for pair in moved.values() for t in pair])  # one pass over the data for all of them
    ll = evaluate(theta)[0]
    for j, pair in moved.items():
        flat[j] = all(abs(evaluate(t)[0] - ll) <= 1e-12 * (1.0 + abs(ll)) for t in pair)
    return flat


def _second_difference_noise(ll: float) -> float:
    """The round-off of three log-likelihoods near `ll` in a second difference (or of two in a first)."""
    return 4e-13 * (1.0 + abs(ll))


def _unresolved(evaluate, theta: np.ndarray, information: np.ndarray, curved: np.ndarray,
                steps: np.ndarray) -> np.ndarray:
    """The log variances whose information the gradient's differences do not resolve, as a bool mask: a variance
    estimated at the boundary of its range, 0.

    There the log-likelihood hardly moves with θ (a variance of 3e-9 times e^±0.02 changes it by about 1e-8), and
    differences of the gradient over steps of 1e-5 are its round-off: the information came out 560 times the
    log-likelihood's own curvature, and the standard error of a variance estimated at 3e-9 was 3.5e-7 where
    statsmodels' is 3.1e-3 (audit AA3). So each log variance's information is checked against the second
    difference of the log-likelihood: first over the Hessian's own `steps`, whose log-likelihoods are known; where
    that does not confirm it, over steps of 0.01 (a variance times e^±0.02, in any units of
    the data), whose round-off is far below an interior estimate's curvature. Where they differ by more than half,
    or the information is below that round-off (a variance of 1.7e-14 beside one of 1: review R16), it is not
    resolved. An interior estimate costs nothing more (the wider steps at every fit made the Nile's 30% slower).
    """
    bad = np.zeros(theta.size, dtype=bool)
    ll = evaluate(theta)[0]
    noise = _second_difference_noise(ll)

    def confirmed(j: int, h: float) -> bool:
        """Whether the second difference over ±h confirms θ_j's information: within half of it, and it above ten
        times the least curvature that difference resolves."""
        e = h * np.eye(theta.size)[j]
        curvature = -(evaluate(theta + e)[0] - 2.0 * ll + evaluate(theta - e)[0]) / h ** 2
        floor = noise / h ** 2
        return abs(curvature - information[j, j]) <= 0.5 * abs(information[j, j]) + floor \
            and information[j, j] > 10.0 * floor

    # only confirmation over the small steps is final: their second difference carries the data's round-off, which
    # a level of 1e6 makes larger than assumed (an interior variance 2.6 standard errors from 0 was NaN'd: review R18)
    doubt = [j for j in np.flatnonzero(curved) if not confirmed(j, steps[j])]
    evaluate.prefetch([theta + sign * _WIDER * np.eye(theta.size)[j] for j in doubt for sign in (1.0, -1.0)])
    for j in doubt:
        bad[j] = not confirmed(j, _WIDER)
    return bad


_WIDER = 1e-2  # :func:`_unresolved`'s wider step in a log variance


def _beyond_gradient(information: np.ndarray, gradient: np.ndarray, curved: np.ndarray) -> bool:
    r"""Whether the information, on its correlation scale, has its smallest eigenvalue over 10 times what the
    gradient adds to it through the parametrisation's curvature.

    Away from a stationary point the Hessian in θ carries, besides the curvature of the log-likelihood, the
    gradient times the parametrisation's second derivatives: for a log variance (a variance, or a Cholesky
    factor's diagonal entry, :math:`e^{\theta_i}`) exactly the gradient on the diagonal, which on the
    correlation scale :math:`C = D^{-1/2} I D^{-1/2}` is :math:`g_i / I_{ii}`, and moves C's eigenvalues by at
    most the largest of these (Weyl). `curved` marks the log variances, where both sides are unit-free; F, H,
    B and m0 enter linearly, a Cholesky factor's other entries are in a standard deviation's units (review
    R11: counted, they refused a fit's errors in units of 1e6 only), and a user's `params` are not known. EM
    stops where its steps become small, short of the stationary point: where only Q + R was identified
    (F = 0), the information along Q - R was that term alone and passed for positive definite (standard
    errors of 31.8 on estimates of 0.39; audit Y2). (Review R10: an eigenvalue against a gradient in θ's units
    refused genuine optima.)
    """
    term = np.max(np.abs(gradient[curved]) / np.diagonal(information)[curved], initial=0.0)
    return term == 0.0 or bool(np.linalg.eigvalsh(unit_diagonal(information))[0] > 10.0 * term)


def _em_stalled(evaluate, build, theta: np.ndarray, cov_theta: np.ndarray | None, tol: float,
                nobs: int) -> str | None:
    """Why EM, which met `tol` at θ, is short of a maximum, or None: a Newton step (on the inverse information
    `cov_theta`) would gain over :data:`_EM_STALLED` times `tol` per observation; or, where the information is
    not positive definite (None), the gradient per unit of θ is above :data:`_MLE_GTOL` per observation."""
    gradient = evaluate(theta)[1]
    if cov_theta is not None:
        scaled = gradient * build.units(theta)  # (cov_theta is on φ = θ / units: see _standard_errors)
        gain = 0.5 * scaled @ cov_theta @ scaled  # what a Newton step would add to the log-likelihood
        if gain > _EM_STALLED * tol * nobs:
            return (f"the log-likelihood changed by less than `tol`, but a Newton step from here would raise it by "
                    f"{gain:.3g} more: EM has stalled short of the maximum, as it does on a parameter its M-step "
                    "cannot move (the mean of a state component known exactly, the row of H of a sensor without "
                    "noise); try method='mle'")
        return None
    steepest = np.abs(gradient * build.units(theta)).max() / nobs  # per unit: in any units
    if steepest > _MLE_GTOL:  # a plateau or a saddle: EM's steps stalled, not at a maximum
        return (f"the log-likelihood changed by less than `tol`, but its gradient is still {steepest:.2g} per "
                "observation and the observed information is not positive definite: the likelihood is flat or "
                "curved upwards along some direction here (a plateau, a saddle, or the approach to a ridge of "
                "equally good models), not at a maximum, and EM's steps stall there (as from a variance started "
                "near 0); try method='mle', or another start")
    return None


class _Curvature(NamedTuple):
    """The observed information at θ, on φ = θ / `units`, and which parameters it measures (`flat`: those the
    log-likelihood does not depend on, or whose information the differences do not resolve)."""
    information: np.ndarray
    flat: np.ndarray
    units: np.ndarray
    sizes: np.ndarray


def _curvature(evaluate, build, theta: np.ndarray, nobs: int) -> _Curvature | None:
    """The observed information at θ by central differences of the exact gradient (:func:`_hessian`), with its
    flat parameters (:func:`_flat`, :func:`_unresolved`); None where a neighbour has no likelihood (a variance
    near 0) or there is nothing learned."""
    if theta.size == 0:
        return None
    units = build.units(theta)
    sizes = _sizes(theta, units)
    try:
        curved = build.curved(theta)
        information = -_hessian(evaluate, theta, sizes, units)  # on φ = θ / units: finite in any units
        flat = _flat(evaluate, theta, information, units)
        # (as flat: held fixed) where the log-likelihood is stationary along it, to maximum likelihood's tolerance;
        # elsewhere it is a plateau, not a boundary (EM stalled from Q = 1e-6 on the Nile: review R16)
        still = np.abs(evaluate(theta)[1] * units) <= _MLE_GTOL * nobs
        flat |= _unresolved(evaluate, theta, information, curved & still, 1e-5 * sizes)
    except NO_LIKELIHOOD:
        return None
    return _Curvature(information, flat, units, sizes)


def _above_saddle(evaluate, theta: np.ndarray, curvature: _Curvature | None) -> np.ndarray | None:
    r"""A point of higher log-likelihood than θ along a direction in which the log-likelihood curves upwards at
    θ, or None: θ, where the search stopped, is then a saddle or a minimum, not a maximum.

    The gradient vanishes at a saddle as at a maximum, and both searches stop there: learning H from a start of
    H = 0, where the likelihood is even in H, stopped at its start with ``converged=True``, 122 below the
    maximum (audit UU2). The directions are the eigenvectors :math:`w` of the information on its diagonal's
    scale, :math:`C = D^{-1/2} I D^{-1/2}` with :math:`D = |\mathrm{diag}\, I|`, whose eigenvalue
    :math:`\lambda` is negative, most negative first; a step :math:`t D^{-1/2} w` in φ changes the
    log-likelihood by :math:`-\tfrac12 \lambda t^2`, so the first step tried, :math:`t = \sqrt{2 / |\lambda|}`,
    is expected to raise it by one, and smaller ones (a quarter each time) follow where the likelihood is
    not that nearly quadratic. A direction counts only where the log-likelihood measured on both sides
    confirms it: its second difference is positive beyond round-off, and one side is higher than θ. (An
    information that is not positive definite only by round-off, or at a boundary the differences do not
    resolve, has no such side.)
    """
    if curvature is None:
        return None
    kept = ~curvature.flat
    information = curvature.information[np.ix_(kept, kept)]
    if not kept.any() or is_positive_definite(information):
        return None
    scale = np.sqrt(np.abs(np.diagonal(information)))
    scale = np.where(scale > 0.0, scale, 1.0)
    values, vectors = np.linalg.eigh(information / scale[:, None] / scale[None, :])
    ll = evaluate(theta)[0]
    noise = _second_difference_noise(ll)
    for value, w in zip(values, vectors.T):
        if not value < 0.0:
            break
        direction = np.zeros(theta.size)
        direction[kept] = curvature.units[kept] * w / scale  # in θ
        t = np.sqrt(2.0 / -value)
        for _ in range(6):
            sides = [theta + t * direction, theta - t * direction]
            try:
                up, down = (evaluate(side)[0] for side in sides)
            except NO_LIKELIHOOD:
                up = down = -np.inf
            if np.isfinite(up) and np.isfinite(down) and up + down - 2.0 * ll > noise and max(up, down) > ll + noise:
                return sides[0] if up >= down else sides[1]
            t /= 4.0
    return None


def _above_plateau(evaluate, build, theta: np.ndarray, curvature: _Curvature | None) -> np.ndarray | None:
    r"""A point of higher log-likelihood than θ with one learned variance raised, or None: θ is then on the
    plateau that a variance far below the data's scale makes, not at a maximum.

    As a variance :math:`v` tends to 0 the log-likelihood tends to its value at 0, so in :math:`\log v` it
    flattens, and its slope and curvature, :math:`v\,\partial\ell/\partial v` and that again, vanish with
    :math:`v`. A search whose start is far below the data's scale can raise the other variances first and stop
    on that plateau with the gradient test met: the Nile in units of 1e6 from Q = 1e3, R = 1e4 stopped with Q at
    2.6e-8 of its estimate, said converged, 18.2 below the maximum (audit YY1). So each log variance along which
    the log-likelihood does not curve downwards (its information is not positive, or not resolved:
    :func:`_flat`, :func:`_unresolved`) is raised by 1, 2, 4, ... 32 (a variance up to e^32, 8e13, times
    larger; a Cholesky factor's diagonal is its standard deviation's log) for as long as the log-likelihood
    rises, and the highest point is returned where it is above θ's beyond round-off. At an interior maximum
    every information is positive, and nothing is evaluated.
    """
    if curvature is None:
        return None
    ll = evaluate(theta)[0]
    noise = _second_difference_noise(ll)
    upward = curvature.flat | ~(np.diagonal(curvature.information) > 0.0)
    for j in np.flatnonzero(upward & build.curved(theta)):
        best, top = None, ll + noise
        for step in 2.0 ** np.arange(6):
            raised = theta.copy()
            raised[j] += step
            try:
                value = evaluate(raised)[0]
            except NO_LIKELIHOOD:
                break
            if value > top:
                best, top = raised, value
            elif value < top - noise:
                break
        if best is not None:
            return best
    return None


_ESCAPES = 3
"""How many times maximum likelihood, stopped at a saddle (:func:`_above_saddle`) or on a plateau
(:func:`_above_plateau`), searches on from above it."""

_SADDLE = ("stopped at a saddle point of the log-likelihood, not a maximum: it is higher on both sides along a "
           "direction in which it curves upwards there (as at H = 0, where it is even in H)")

_PLATEAU = ("stopped on a plateau of the log-likelihood, not at a maximum: a learned variance is so far below the "
            "data's scale that the likelihood hardly moves with it, but it is higher where that variance is larger "
            "(as from a start far below the data's variances)")


def _mle_past_saddles(build, theta0, data, nobs, iterations, tol, callback, engine):
    """:func:`_mle`, and again from above the saddle or the plateau where it stopped (:func:`_above_saddle`,
    :func:`_above_plateau`), at most :data:`_ESCAPES` times within `iterations`: its results, and the curvature
    where it ended (None where it was interrupted). The history and the callback's count go on over the
    searches."""
    history, escapes = np.zeros(0), 0
    while True:
        # values so far: a search from above the saddle starts with the next (its first, the point above), and
        # the searches hold iterations + 1 values in all, as one does (review R52: 13 told twice, 22 of 21)
        done = history.size
        tell = callback if callback is None or not done else (lambda it, ll, done=done: callback(it + done, ll))
        theta, run, converged, message, evaluate = _mle(build, theta0, data, nobs, iterations - done, tol, tell,
                                                        engine)
        history = np.concatenate([history, run])
        if message.startswith("interrupted"):
            return theta, history, converged, message, evaluate, None
        curvature = _curvature(evaluate, build, theta, nobs)
        above, why = _above_saddle(evaluate, theta, curvature) if converged else None, _SADDLE
        if above is None and (converged or iterations - history.size >= 1):  # (a search its limit stopped is told
            # so: review R54, "stopped on a plateau" at the Nile's -57841 after 2 iterations)
            above, why = _above_plateau(evaluate, build, theta, curvature), _PLATEAU
        if above is None:
            return theta, history, converged, message, evaluate, curvature
        if escapes == _ESCAPES or iterations - history.size < 1:
            return theta, history, False, why + "; try another start", evaluate, curvature
        escapes, theta0 = escapes + 1, above


def _standard_errors(evaluate, build, theta: np.ndarray, learn, curvature: _Curvature | None,
                     ) -> tuple[dict | None, np.ndarray, np.ndarray | None]:
    """Standard errors from the observed information (:func:`_curvature`).

    Returns the per-matrix standard errors (None if the information is not
    positive definite, or not beyond the gradient: :func:`_beyond_gradient`),
    those of ``build.natural`` (NaN then), and the inverse information on φ = θ / units
    (None where it is not positive definite; zero rows and columns for the
    parameters the log-likelihood does not depend on).
    """
    k = theta.size
    natural = build.natural
    nan = np.full(natural(theta).size, np.nan)
    if curvature is None:
        return None, nan, None
    information, flat, units, sizes = curvature
    kept = ~flat
    if not kept.any() or not is_positive_definite(information[np.ix_(kept, kept)]):  # it is at a maximum
        return None, nan, None
    cov_theta = np.zeros((k, k))
    cov_theta[np.ix_(kept, kept)] = cho_solve(cholesky(information[np.ix_(kept, kept)]), np.eye(int(kept.sum())))
    if not _beyond_gradient(information[np.ix_(kept, kept)], (evaluate(theta)[1] * units)[kept],
                            build.curved(theta)[kept]):
        return None, nan, cov_theta  # (what a Newton step would gain is still told: see _em_stalled)

    def jacobian(fn) -> np.ndarray:
        J = np.zeros((fn(theta).size, k))
        for j in range(k):
            h = 1e-6 * sizes[j]
            up, down = theta.copy(), theta.copy()
            up[j] += h
            down[j] -= h
            J[:, j] = (fn(up) - fn(down)) / (2 * h)
        return J

    def delta(J):  # each row scaled to its largest entry first: J C Jᵀ of estimates of 1e200 overflows
        moved = (J[:, flat] != 0.0).any(axis=1)
        J = J * units[None, :]  # on φ = θ / units, as cov_theta
        s = np.max(np.abs(J), axis=1)
        s = np.where(s > 0, s, 1.0)
        unit = J / s[:, None]
        se = s * np.sqrt(np.clip(np.einsum("ij,jk,ik->i", unit, cov_theta, unit), 0, None))
        return np.where(moved, np.nan, se)  # what moves with a flat parameter: none

    bse = delta(jacobian(natural))
    if learn is None:
        return {"params": bse}, bse, cov_theta

    def entries(t):  # every entry of the learned matrices
        mdl, pri = build(t)
        return np.concatenate([_current(mdl, pri, name).ravel() for name in learn])

    se = delta(jacobian(entries))
    out, start = {}, 0
    mdl, pri = build(theta)
    for name in learn:
        shape = _current(mdl, pri, name).shape
        size = int(np.prod(shape))
        out[name] = se[start:start + size].reshape(shape)
        start += size
    return out, bse, cov_theta


# ---------------------------------------------------------------------------
# The front function
# ---------------------------------------------------------------------------


def check_learn(model: LinearModel, prior, learn, structure) -> tuple[tuple, dict]:
    """`learn` as a tuple and `structure` as a dict for every covariance, checked against the model and prior."""
    if isinstance(learn, str):
        learn = (learn,)
    if isinstance(learn, Mapping):  # its values would be dropped without a word (a start belongs in the model)
        raise TypeError(f"`learn` must be a sequence of names from {list(LEARNABLE)}, not a dict; got {learn!r}.")
    try:
        learn = tuple(learn)
    except TypeError:
        raise TypeError(f"`learn` must be a sequence of names from {list(LEARNABLE)}; "
                        f"got {type(learn).__name__}.") from None
    unknown = [k for k in learn if not isinstance(k, str) or k not in LEARNABLE]
    if unknown or not learn or len(set(learn)) != len(learn):
        raise ValueError(f"`learn` must name distinct entries of {list(LEARNABLE)}; got {list(learn)}.")
    for name in learn:
        if name in ("m0", "P0"):
            if isinstance(prior, str):
                raise ValueError(f"`learn` cannot include {name!r} with a diffuse prior.")
            continue
        a = getattr(model, name)
        if a is None:
            raise ValueError("`learn` includes 'B' but the model has no control input; give it an initial `B`.")
        if a.ndim == 3:
            raise ValueError(f"`learn` includes {name!r}, which is time-varying in the model; "
                             "only time-invariant matrices can be learned.")
    if ("F" in learn or "B" in learn) and model.Q.ndim == 3:
        raise ValueError("learning F or B needs a time-invariant `Q`.")
    if "H" in learn and model.R.ndim == 3:
        raise ValueError("learning H needs a time-invariant `R`.")
    if structure is None:
        structure = {}
    if not isinstance(structure, Mapping):
        raise TypeError(f"`structure` must be a dict such as {{'Q': 'diagonal'}}, mapping {list(COVARIANCES)} "
                        f"to one of {list(STRUCTURES)}; got {type(structure).__name__} {structure!r:.60}.")
    for name, kind in structure.items():
        if name not in COVARIANCES or kind not in STRUCTURES:
            raise ValueError(f"`structure` maps {list(COVARIANCES)} to one of {list(STRUCTURES)}; "
                             f"got {name!r}: {kind!r}.")
        if name not in learn and kind != "full":
            raise ValueError(f"`structure` constrains {name}, which is not learned (`learn` = {list(learn)}): a "
                             f"structure applies to a learned covariance; add {name!r} to `learn` or leave it out.")
    return learn, {k: structure.get(k, "full") for k in COVARIANCES}


def _check_fitted(model: LinearModel, prior, history: np.ndarray, values: np.ndarray) -> None:
    """Raise FloatingPointError when a fit ended in a non-finite model or log-likelihood (an overflow)."""
    parts = {"the log-likelihood": history[-1:], "the learned parameters": values,
             **{name: getattr(model, name) for name in ("F", "H", "Q", "R")}}
    if not isinstance(prior, str):
        parts.update({"m0": prior.mean, "P0": prior.cov})
    bad = [name for name, value in parts.items() if value is not None and not np.all(np.isfinite(value))]
    if bad:
        raise FloatingPointError(
            f"the fit overflowed: {', '.join(bad)} {'is' if len(bad) == 1 else 'are'} not finite. The measurements "
            "or the model's matrices are too large or too small for float64; rescale them (for example to units "
            "in which the measurements are of order 1).")


def fit(
    model: LinearModel,
    prior: Gaussian | str,
    zs,
    us=None,
    *,
    learn=("Q", "R"),
    method: str = "em",
    structure: dict | None = None,
    iterations: int | None = None,
    tol: float | None = None,
    params: Callable | None = None,
    x0=None,
    callback: Callable[[int, float], None] | None = None,
    engine: str = "auto",
    times=None,
) -> FitResult:
    """Learn a linear-Gaussian model's matrices from measurements.

    Parameters
    ----------
    model : LinearModel
        The starting point; matrices not learned stay as they are (they may
        be time-varying, and singular).
    prior : Gaussian or "diffuse"
        The prior, one step before the first measurement (see :func:`filter`);
        ``"diffuse"`` makes the first state x₁ diffuse, as Durbin & Koopman,
        KFAS and statsmodels do; the log-likelihood is Durbin & Koopman's
        and statsmodels' (KFAS's leaves out the ½ log 2π of the
        observations that identify x₁).
    zs : array_like of shape (T, m), (T,) or (N, T, m)
        Measurements; NaN = missing. N series share one set of parameters
        and are pooled.
    us : array_like of shape (T, p) or (N, T, p), optional
        Controls, when the model has ``B``; with a dask `zs`, a dask array
        chunked over series as `zs` is, or an array in memory (chunked so).
    learn : sequence of str, default ("Q", "R")
        Which of ``"F", "H", "Q", "R", "B", "m0", "P0"`` to learn (m0 and
        P0 are the prior's mean and covariance).
    method : {"em", "mle"}, default "em"
        Expectation–maximisation, or maximum likelihood by BFGS with the
        exact gradient.
    structure : dict, optional
        ``{"Q" | "R" | "P0": "full" | "diagonal" | "scalar"}``: how a
        learned covariance is constrained (default full). Learned
        covariances stay symmetric positive semi-definite; with "full" or
        "diagonal", a variance that starts at exactly 0 stays at 0 (a
        noise-free component), with its row and column ("scalar" has one
        variance for every component, so it keeps 0 only when all start
        there). EM keeps the rows of F and B of a noise-free state (a zero
        variance of Q) at their start, to round-off (0.9999999999999993 for
        1): its M-step has no noise there to weigh them by, and its
        regression returns them because the smoothed moments obey that row
        exactly. Learn those rows with ``method="mle"``.
        A start outside its structure is first projected
        onto it (the mean of its variances for "scalar", its diagonal for
        "diagonal"), and the history starts from that model.
    iterations : int, optional
        Maximum iterations (EM: 500; MLE: 1000).
    tol : float, optional
        EM stops when the log-likelihood changes by at most `tol` per
        observed value (default 1e-10), whatever the data's units;
        ``tol=0`` runs exactly
        `iterations` EM iterations, without the convergence test and
        without a warning. MLE stops when the gradient's largest component,
        per observation and per unit of its parameter (a log variance, an
        entry of F or H, a Cholesky entry over its row's size, m0 over the
        prior's standard deviation, B[i, j] over Q's standard deviation i
        per size of control j), is below `tol` (default 1e-8): the same fit
        in any units of the data and of the controls.
    params : callable, optional
        For structured models (MLE only): ``params(theta) -> LinearModel`` or
        ``(LinearModel, Gaussian)``; `learn` and `structure` are then ignored.
    x0 : array_like of shape (k,), optional
        Starting `theta` for `params` (required with it, refused without it).
    callback : callable, optional
        ``callback(iteration, loglik)`` after each iteration (progress).
    engine : {"auto", "python", "numba"}, default "auto"
        Engine of the filter and smoother runs; "auto" decides for the whole
        fit, compiling when compiling (or loading from numba's disk cache)
        is expected to cost less than the fit's passes on the readable path
        (:data:`FIT_PASSES`, each over the steps of all series, times 1 + n
        runs under a diffuse prior). An EM fit kept readable starts the
        compiled kernels at the iteration where its readable iterations
        would have paid for them (counted, not timed:
        :func:`gaussfuse.inference.drivers.switch_step`), so that one that
        takes many more iterations than expected is not held to the slower path.
    times : array_like, optional
        The measurements' times, as in :func:`gaussfuse.filter`: a
        TimedModel (:func:`gaussfuse.model` without dt) is discretised for
        each step; its F, Q and B then vary with dt and are not learned.

    Returns
    -------
    FitResult
        ``.model``, ``.prior``, ``.loglik``, ``.history``, ``.params`` and
        their standard errors ``.bse``, ``.aic``, ``.bic`` and
        ``.summary()``; Ctrl-C during the fit returns the best model so far
        with ``converged=False``.

    Warns
    -----
    ConvergenceWarning
        When the fit stops at its iteration limit (EM, unless ``tol=0``) or
        the optimiser reports a failure (MLE) before meeting `tol`; when EM
        meets `tol` where a Newton step would still gain over 1000 times
        `tol` per observation (stalled, not at a maximum); when the fit
        meets `tol` at a saddle point, where the log-likelihood curves
        upwards along some direction and is higher on both sides (EM says
        so; maximum likelihood searches on from the higher side, up to three
        times, and says so only when it still ends at one), and when
        maximum likelihood stops on the plateau that a learned variance far
        below the data's scale makes (it searches on from where that
        variance is larger, as from a saddle); or when EM's
        learned model can no longer be filtered or no longer identifies a
        diffuse state (the likelihood growing without bound). The result is
        the best model found, with ``converged=False``.

    Raises
    ------
    ValueError, TypeError
        For invalid arguments, data with no observed value, or a diffuse
        state the starting model does not identify.
    FloatingPointError
        When the fit overflows (measurements or matrices near float64's
        limits): the message names what is not finite.

    Examples
    --------
    The Nile local level model (Durbin & Koopman, 2012, section 2.10):

    >>> import gaussfuse as gf
    >>> from gaussfuse.datasets import nile
    >>> _, flow = nile()
    >>> start = gf.LinearModel(F=1, H=1, Q=1000.0, R=10000.0)
    >>> res = gf.fit(start, "diffuse", flow, method="mle")
    >>> round(float(res.model.R[0, 0])), round(float(res.model.Q[0, 0]), 1)
    (15099, 1469.2)
    """
    timed = isinstance(model, TimedModel)
    start = model
    zs, times, table = frames.unpack(zs, times, model)
    us = frames.controls(us, table)
    where = "times" if table is None else table.times_name
    pooled = chunked.is_dask(zs)
    if pooled:
        chunked.check_lazy(zs, us, model)
    T = zs.shape[1] if pooled else zs
    if timed and times is not None and params is None:
        grid = timing.steps(where, times, T if pooled else check_measurements(zs, model.m).shape[1], model)
        if grid.regular:  # one model for the grid's step, whose F, Q (and B) can be learned
            model, us = model.at(np.full(1, grid.step), us)
            times = None
    model, us = timing.resolve(model, times, T, us, name=where)
    if timed and model.steps is not None and params is None:
        varying = sorted({"F", "Q", "B"} & set([learn] if isinstance(learn, str) else learn))
        if varying:
            raise ValueError(f"`learn` includes {varying}, which a model discretised for each step's dt has at every "
                             "step (they depend on dt); learn H, R, m0 or P0, or use times on a regular grid with a "
                             "model of that dt.")
    if not isinstance(model, LinearModel):
        raise TypeError(f"`model` must be a gaussfuse.LinearModel; got {type(model).__name__}.")
    if method not in METHODS:
        raise ValueError(f"`method` must be one of {list(METHODS)}; got {method!r}.")
    prior = check_prior(prior, model.n, diffuse_ok=True)
    if pooled:  # chunks of series, each summed where it is (_Chunks)
        us = chunked.chunked_like(us, zs)
        if (us is None) != (model.B is None) or (us is not None and us.shape[:2] != zs.shape[:2]):
            raise ValueError(f"`us` must be given, of shape (N, T, p) with the N and T of `zs`, exactly when the model "
                             f"has B; got {None if us is None else us.shape}.")
        nobs = int(chunked.observed(zs))
        if prior == "diffuse" and 0 < nobs:  # as in memory: a series with nothing observed adds nothing
            seen = chunked.observed_series(zs)
            if not seen.all():
                zs, us = zs[seen], None if us is None else us[seen]
                zs, us = zs.rechunk({0: tuple(c for c in zs.chunks[0] if c)}), \
                    None if us is None else us.rechunk({0: tuple(c for c in zs.chunks[0] if c)})
        data = _Chunks(zs, us)
    else:
        zs = check_measurements(zs, model.m)
        nobs = int(np.sum(~np.isnan(zs)))
        us = check_controls(us, model, zs.shape[0], zs.shape[1])
        if prior == "diffuse" and 0 < nobs:  # a series with nothing observed adds nothing, and identifies no x_0
            seen = ~np.isnan(zs).all(axis=(1, 2))
            if not seen.all():
                zs, us = zs[seen], None if us is None else us[seen]
        data = _Series(zs, us)
    if nobs == 0:
        raise ValueError("`zs` has no observed value (every entry is NaN): there is nothing to learn from.")
    if prior == "diffuse" and nobs <= zs.shape[0] * model.n:
        raise ValueError(f"with a 'diffuse' prior, the first {model.n} observed value(s) of a series only determine "
                         f"its initial state; `zs` has {nobs} in {zs.shape[0]} series, which leaves none to learn the "
                         "model from. Give more data, or a Gaussian prior.")
    check_steps(model, zs.shape[1])
    if iterations is None:
        iterations = 500 if method == "em" else 1000
    iterations = integer("iterations", iterations)
    if engine not in ENGINES:
        raise ValueError(f"`engine` must be one of {list(ENGINES)}; got {engine!r}.")
    tol = real("tol", (1e-10 if method == "em" else _MLE_GTOL) if tol is None else tol, nonnegative=True)
    switch = None  # the EM iteration from which "auto" runs compiled after all
    if engine == "auto":  # decided for the whole fit, on the whole work it is expected to do
        runs = 1 + model.n if isinstance(prior, str) else 1  # a diffuse prior: a base run and n sensitivity runs
        steps = zs.shape[0] * zs.shape[1] * runs
        passes = 3 * iterations if tol == 0 else min(FIT_PASSES[method], 3 * iterations)
        compiled = compiled_engine(_METHODS["kf"], "auto", steps * passes, 1.0, smoothing=True)
        engine = "python" if compiled is None else "numba"
        # EM may take many more iterations than expected; a fit expected to be short stays readable (its bits)
        if engine == "python" and method == "em" and steps * passes >= AUTO_NUMBA_STEPS:
            switch = switch_step("linear", True, 3 * steps)
    if callback is not None and not callable(callback):
        raise TypeError(f"`callback` must be callable as callback(iteration, loglik); got {type(callback).__name__}.")
    if params is not None:
        if not callable(params):
            raise TypeError(f"`params` must be callable as params(theta); got {type(params).__name__}.")
        if method != "mle":
            raise ValueError("`params` (a structured model) needs method='mle'.")
        if x0 is None:
            raise ValueError("`x0`, the starting parameters, is required with `params`.")
        theta0 = as_vector("x0", x0)
        build, learn = _UserParams(params, prior, theta0.size), None
        build(theta0)  # a bad `params` fails here, with its own message
    else:
        if x0 is not None:
            raise ValueError("`x0` is the starting point of `params` and is used only with it; "
                             "the starting point of a fit without `params` is `model` (and `prior`).")
        learn, structure = check_learn(model, prior, learn, structure)
        controls = _control_sizes(us) if "B" in learn else None  # the units of B's entries
        if method == "mle":
            build = _Parametrisation(model, prior, learn, structure, controls=controls)
            theta0 = build.encode()
        elif ("F" in learn or "B" in learn) and "Q" not in learn:
            _check_regression_q(model.Q)
    # Overflows (measurements or matrices near float64's limits) are not warnings: the result is checked below.
    with np.errstate(over="ignore", invalid="ignore"):
        curvature = None
        if method == "em":
            model, prior, history, converged, message, engine = _em(model, prior, data, learn, structure,
                                                                    iterations, tol, nobs, callback, engine, switch)
            try:
                build = _Parametrisation(model, prior, learn, structure, controls=controls)
            except ValueError:  # a learned full covariance became singular: no information matrix
                build = None
            if build is not None:
                theta = build.encode()
                evaluate = _evaluator(build, data, engine)
        else:
            theta, history, converged, message, evaluate, curvature = _mle_past_saddles(
                build, theta0, data, nobs, iterations, tol, callback, engine)
            model, prior = build(theta)
        if build is not None:
            # Ctrl-C asked to stop: the Hessian's 2k gradient passes (a minute on a long series) would not
            # be at a maximum anyway
            if curvature is None and not message.startswith("interrupted"):
                curvature = _curvature(evaluate, build, theta, nobs)
            errors, bse, cov_theta = _standard_errors(evaluate, build, theta, learn, curvature)
            names, values = build.names(), build.natural(theta)
            stalled = _em_stalled(evaluate, build, theta, cov_theta, tol, nobs) \
                if method == "em" and converged and theta.size else None
            if stalled is None and method == "em" and converged and _above_saddle(evaluate, theta, curvature) \
                    is not None:  # (not restarted: EM from above the Nile's plateau crawled 496 more iterations to the limit)
                stalled = _SADDLE + "; try method='mle', which searches on from above it, or another start"
            if stalled is not None:
                converged, message = False, stalled
        else:  # a learned full covariance ended singular: its values, without standard errors
            labels = _Parametrisation(model, prior, learn, structure, labels_only=True)
            errors, names, values = None, labels.names(), labels.values(model, prior)
            bse = np.full(values.size, np.nan)
    _check_fitted(model, prior, history, values)
    # (EM with tol=0 runs the iterations asked for: reaching the limit is no news, but a stop before it is)
    limit = method == "em" and tol == 0 and message.startswith("stopped at the limit")
    if limit:  # (its summary said "NOT converged" of a fit that tested nothing: audit BB2)
        message = f"ran the {iterations} iterations asked for (tol=0 tests no convergence)"
    if not converged and not message.startswith("interrupted") and not limit:
        how = "EM" if method == "em" else "maximum likelihood"
        warnings.warn(ConvergenceWarning(
            f"{how} did not converge: {message.rstrip('.')}. The result is the best model found (loglik "
            f"{history[-1]:.6g}); raise `iterations`, loosen `tol`, or check the model.{_boundary(model, prior, learn, start)}"),
            stacklevel=2)
    return FitResult(model, prior, float(history[-1]), history, method, bool(converged), message, errors,
                     params=dict(zip(names, map(float, values))), bse=dict(zip(names, map(float, bse))),
                     nobs=nobs, series=int(zs.shape[0]))
