r"""The interacting multiple model (IMM) filter.

A target that switches between behaviours (flying straight, turning) is
described by several models, one per *mode*, and a Markov chain over the
modes. The IMM filter of Blom and Bar-Shalom [1]_ keeps one Gaussian per
mode and, at each step, mixes them according to the mode transition
probabilities, runs each mode's Kalman step (through the linearisation
strategies and :mod:`gaussfuse.kalman`, as every filter here), re-weights
the modes by how well each predicted the measurement, and reports the
moment-matched Gaussian of the mixture.

References
----------
.. [1] H. A. P. Blom and Y. Bar-Shalom, "The interacting multiple model
   algorithm for systems with Markovian switching coefficients", IEEE
   Transactions on Automatic Control 33(8), 780–783, 1988.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import kalman
from ._frozen import reduce_frozen, shapes_repr
from ._validation import as_array
from .errors import ModelFunctionError
from .gaussian import Gaussian, moment_match
from .inference.drivers import warn_unconverged
from .inference.registry import check_options, linearisation, resolve_method
from .inference.validation import (check_controls, check_measurements, check_prior, check_semidefinite,
                                   check_steps)
from .models.linear import LinearModel
from .models.nonlinear import NonlinearModel

__all__ = ["imm_filter", "IMMResult"]

_TOL = 1e-8  # how far from 1 a probability vector may sum


@dataclass(frozen=True, eq=False)
class IMMResult:
    """The output of :func:`imm_filter` for T steps, n states and M models.

    Attributes
    ----------
    means : ndarray of shape (T, n)
        Combined (moment-matched) filtered means.
    covs : ndarray of shape (T, n, n)
        Combined filtered covariances, including the spread of the modes.
    mode_probs : ndarray of shape (T, M)
        Posterior mode probabilities ``P(mode_k = j | z_1..z_k)``; each row
        sums to 1.
    mode_means : ndarray of shape (T, M, n)
        Mode-matched filtered means.
    mode_covs : ndarray of shape (T, M, n, n)
        Mode-matched filtered covariances.
    loglik : float
        ``Σ_k log Σ_j c_j Λ_j``: the IMM approximation of
        ``log p(z_1..z_T)`` (see :func:`imm_filter`).
    """

    means: np.ndarray
    covs: np.ndarray
    mode_probs: np.ndarray
    mode_means: np.ndarray
    mode_covs: np.ndarray
    loglik: float

    __reduce__ = reduce_frozen  # pickles and copies keep the arrays read-only
    __repr__ = shapes_repr


def _probabilities(name: str, value, M: int, *, matrix: bool) -> np.ndarray:
    """A probability vector (M,) or a row-stochastic matrix (M, M), checked."""
    arr = as_array(name, value)
    shape = (M, M) if matrix else (M,)
    if arr.shape != shape:
        what = "Markov matrix (one row and column per model)" if matrix else "vector (one per model)"
        raise ValueError(
            f"`{name}` must be a probability {what} of shape {shape}; got shape {arr.shape}."
        )
    if (arr < 0).any():
        index = tuple(int(i) for i in np.argwhere(arr < 0)[0])
        raise ValueError(f"`{name}` must be non-negative; got {arr[index]:.6g} at index {index}.")
    sums = arr.sum(axis=-1)
    bad = np.abs(sums - 1.0) > _TOL
    if bad.any():
        if matrix:
            row = int(np.argmax(bad))
            raise ValueError(f"the rows of `{name}` must sum to 1; row {row} sums to {sums[row]:.12g}.")
        raise ValueError(f"`{name}` must sum to 1; it sums to {float(sums):.12g}.")
    return arr / sums[..., None] if matrix else arr / sums


def _check_models(models) -> list:
    if isinstance(models, (LinearModel, NonlinearModel)) or not isinstance(models, Sequence) \
            or isinstance(models, str) or len(models) == 0:
        raise TypeError(
            "`models` must be a non-empty sequence (list or tuple) of LinearModel or "
            f"NonlinearModel; got {type(models).__name__}."
        )
    for j, model in enumerate(models):
        if not isinstance(model, (LinearModel, NonlinearModel)):
            raise TypeError(
                f"`models[{j}]` must be a LinearModel or NonlinearModel; got {type(model).__name__}."
            )
    for attr, what in (("n", "state"), ("m", "measurement")):
        sizes = [getattr(model, attr) for model in models]
        if len(set(sizes)) > 1:
            raise ValueError(
                f"`models` must all have the same {what} dimension {attr}; got {attr} = {sizes}."
            )
    return list(models)


def _state_angles(models: list) -> np.ndarray | None:
    """The state-angle mask the models share (None when there are none)."""
    n = models[0].n
    masks = [np.asarray(getattr(model, "state_angles", np.zeros(n, dtype=bool))) for model in models]
    if any(not np.array_equal(masks[0], mask) for mask in masks[1:]):
        listed = [np.flatnonzero(mask).tolist() for mask in masks]
        raise ValueError(
            f"`models` must agree on which state components are angles (they are mixed); "
            f"got state_angles = {listed}."
        )
    return masks[0] if masks[0].any() else None


def imm_filter(models, prior: Gaussian, zs, transition, mode_probs=None, us=None,
               method: str | None = None, **options) -> IMMResult:
    r"""Filter with the interacting multiple model (IMM) algorithm.

    Parameters
    ----------
    models : sequence of LinearModel or NonlinearModel, length M
        One model per mode, all with the same state dimension n and
        measurement dimension m (and the same state angles, if any).
    prior : Gaussian
        Belief about the state one step before the first measurement, the
        same for every mode.
    zs : array_like of shape (T, m), or (T,) when m = 1
        Measurements; a NaN component is missing.
    transition : array_like of shape (M, M)
        Markov matrix of the modes: ``transition[i, j] = P(mode_k = j |
        mode_{k-1} = i)``; non-negative, rows summing to 1.
    mode_probs : array_like of shape (M,), optional
        Mode probabilities at the prior's time; uniform by default.
    us : array_like of shape (T, p), optional
        Controls, given to every model (so every LinearModel must have B).
    method : str, optional
        How the NonlinearModels are linearised: ``"ekf"``, ``"iekf"``,
        ``"ukf"`` (the default), ``"ckf"``, ``"ghkf"`` or ``"iplf"``.
        LinearModels are always exact (``"kf"``).
    **options
        Options of `method` (see :func:`gaussfuse.filter`).

    Returns
    -------
    IMMResult
        ``means`` (T, n), ``covs`` (T, n, n), ``mode_probs`` (T, M),
        ``mode_means`` (T, M, n), ``mode_covs`` (T, M, n, n), ``loglik``.

    Raises
    ------
    TypeError, ValueError
        For bad models, prior, measurements, probabilities or options,
        naming the argument.
    ModelFunctionError
        (a ValueError) When a nonlinear mode's f, h or Jacobian raises or
        returns a wrong shape or a non-finite value, naming the step.
    numpy.linalg.LinAlgError
        At a step whose measurement is impossible under every mode that
        can be in force (each has a singular innovation covariance S that
        z lies outside), or where a mode's filtered covariance is not
        positive semi-definite (a sigma-point rule with a negative weight).

    Notes
    -----
    With :math:`p_{ij}` the transition matrix and, after step k - 1, mode
    probabilities :math:`\mu_i` and mode beliefs :math:`N(m_i, P_i)`, step k
    is:

    1. *Mixing.* The predicted mode probabilities and mixing weights are

       .. math::

           c_j = \sum_i p_{ij} \mu_i, \qquad \mu_{i|j} = p_{ij} \mu_i / c_j,

       and each mode starts from the moment-matched mixture

       .. math::

           m^0_j = \sum_i \mu_{i|j} m_i, \qquad
           P^0_j = \sum_i \mu_{i|j} \left[P_i + (m_i - m^0_j)(m_i - m^0_j)^\top\right].

    2. *Mode-matched filtering.* Each mode predicts and updates
       :math:`N(m^0_j, P^0_j)` with its own model
       (:func:`gaussfuse.kalman.predict`, :func:`gaussfuse.kalman.update`),
       giving :math:`N(m_j, P_j)` and the measurement likelihood
       :math:`\Lambda_j = N(z_k; \hat z_j, S_j)` over the observed components.

    3. *Mode probabilities.*

       .. math::

           \mu_j = \frac{\Lambda_j c_j}{\sum_l \Lambda_l c_l}, \qquad
           \log p(z_k \mid z_{1:k-1}) \approx \log \sum_l \Lambda_l c_l,

       An all-missing :math:`z_k` leaves :math:`\mu_j = c_j`. A mode whose
       :math:`S_j` is singular (a noise-free sensor, a state known exactly)
       and whose prediction :math:`z_k` contradicts, off the range of
       :math:`S_j`, has :math:`\Lambda_j = 0`: it drops out at that step,
       keeping its prediction (a measurement on that range has no density
       to weigh, and is an error, as in every filter). The
       probabilities are carried from step to step as logarithms (and
       :math:`c_j` taken by log-sum-exp), so a mode thousands of nats
       behind still comes back when the data turn to it, even where no
       other mode can switch into it.

    4. *Combination* (the reported belief):

       .. math::

           m = \sum_j \mu_j m_j, \qquad
           P = \sum_j \mu_j \left[P_j + (m_j - m)(m_j - m)^\top\right].

    Where the state has angles (``state_angles``), the means in 1 and 4 are
    circular means (the direction of :math:`\sum \mu (\cos, \sin)`) and the
    spreads :math:`m_j - m` are wrapped to :math:`[-\pi, \pi)`, as
    :func:`gaussfuse.gaussian.moment_match` does.

    With one model the IMM filter is that model's filter.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> quiet = gf.constant_velocity(dt=1.0, q=0.01, r=1.0)
    >>> agile = gf.constant_velocity(dt=1.0, q=10.0, r=1.0)
    >>> res = gf.imm_filter([quiet, agile], gf.Gaussian([0.0, 1.0], np.eye(2)),
    ...                     [1.0, 2.1, 2.9, 4.2], transition=[[0.95, 0.05], [0.05, 0.95]])
    >>> res.means.shape, res.mode_probs.shape
    ((4, 2), (4, 2))
    >>> bool(np.allclose(res.mode_probs.sum(axis=1), 1.0))
    True
    """
    models = _check_models(models)
    M, n, m = len(models), models[0].n, models[0].m
    prior = check_prior(prior, n)
    zs = check_measurements(zs, m, one=True)[0]
    T = zs.shape[0]
    P = _probabilities("transition", transition, M, matrix=True)
    mu = np.full(M, 1.0 / M) if mode_probs is None else _probabilities("mode_probs", mode_probs, M, matrix=False)
    with np.errstate(divide="ignore"):  # log space, so that a mode far behind can come back (no underflow to 0)
        log_mu, log_P = np.log(mu), np.log(P)
    modes = _modes(models, us, T, method, options)
    angles = modes[0].state_angles
    out = IMMResult(np.empty((T, n)), np.empty((T, n, n)), np.empty((T, M)), np.empty((T, M, n)),
                    np.empty((T, M, n, n)), 0.0)
    prev_means, prev_covs = np.broadcast_to(prior.mean, (M, n)), np.broadcast_to(prior.cov, (M, n, n))
    logl = np.empty(M)
    loglik = 0.0
    for k in range(T):
        log_c, starts = _mix(log_mu, log_P, prev_means, prev_covs, angles)
        for j, mode in enumerate(modes):
            post = mode.step(k, *starts[j], zs[k])
            check_semidefinite(mode.lin, post.cov[None], "filtered", lambda _: f"{k} (model {j})")  # (review R30)
            out.mode_means[k, j], out.mode_covs[k, j], logl[j] = post.mean, post.cov, post.loglik
        if not np.any(logl + log_c > -np.inf):
            raise np.linalg.LinAlgError(f"at step {k}: the measurement is impossible under every model that can be "
                                        "in force (each has a singular innovation covariance S that z lies outside).")
        log_mu, step_loglik = _reweight(logl, log_c)
        loglik += step_loglik
        out.mode_probs[k] = np.exp(log_mu)
        out.means[k], out.covs[k] = moment_match(out.mode_probs[k], out.mode_means[k], out.mode_covs[k], angles)
        prev_means, prev_covs = out.mode_means[k], out.mode_covs[k]
    for mode in modes:  # (the iterated updates' steps at their limit were told by filter, not here: audit YY1)
        warn_unconverged(mode.spec, mode.options, mode.unconverged, T,
                         where=f"in `models[{mode.j}]`" if M > 1 else "", stacklevel=3)
    fields = (out.means, out.covs, out.mode_probs, out.mode_means, out.mode_covs)
    for a in fields:
        a.setflags(write=False)
    return IMMResult(*fields, loglik)


class _Mode:
    """One model of the IMM filter: its linearisation, and :func:`gaussfuse.kalman.step` through it."""

    def __init__(self, j: int, spec, options: dict, lin, iterations: int, tol, state_angles,
                 measurement_angles) -> None:
        self.j, self.spec, self.options, self.lin, self.iterations, self.tol = j, spec, options, lin, iterations, tol
        self.state_angles, self.measurement_angles = state_angles, measurement_angles
        self.unconverged = 0  # steps whose iterated update made `iterations` passes without meeting `tol`

    def step(self, k: int, mean: np.ndarray, cov: np.ndarray, z: np.ndarray) -> kalman.Update:
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised by the step, as in run_filter
                st = kalman.step(self.lin, k, mean, cov, z, self.iterations, self.tol, self.state_angles,
                                 self.measurement_angles)
            self.unconverged += not st.converged
            return st.update
        except np.linalg.LinAlgError as exc:
            impossible = self._impossible(k, mean, cov, z)
            if impossible is None:
                raise type(exc)(f"at step {k}, in `models[{self.j}]`: {exc}") from exc
            return impossible
        except (ModelFunctionError, FloatingPointError) as exc:
            raise type(exc)(f"at step {k}, in `models[{self.j}]`: {exc}") from exc

    def _impossible(self, k: int, mean: np.ndarray, cov: np.ndarray, z: np.ndarray) -> kalman.Update | None:
        """The mode's prediction with likelihood 0 when z lies outside the range of its singular S (a noise-free
        measurement that z contradicts), else None (z has a degenerate density there, not one of 0)."""
        pm, pc = kalman.forecast(self.lin, k, mean, cov, self.state_angles, check=False)
        H, d, R = self.lin.measurement(k, pm, pc)
        S_full = kalman.predict(pm, pc, H, R, d)[1]  # H P⁻ Hᵀ + R
        o = kalman.observed_components(z)
        innovation, v = kalman._innovation(pm, z, H, d, self.measurement_angles, o)
        S = S_full if o is None else S_full[np.ix_(o, o)]
        vals, vecs = np.linalg.eigh(0.5 * (S + S.T))
        null = vecs[:, vals <= 8 * vals.shape[0] * np.finfo(np.float64).eps * max(vals.max(initial=0.0), 0.0)]
        if not np.all(np.isfinite(v)) or np.linalg.norm(null.T @ v) <= 1e-8 * max(np.linalg.norm(v), 1e-300):
            return None
        return kalman.Update(pm, pc, innovation, S_full, -np.inf, None, np.inf)


def _modes(models: list, us, T: int, method: str | None, options: dict) -> list[_Mode]:
    """Each model's mode: LinearModels exact ("kf"), NonlinearModels by `method`."""
    angles = _state_angles(models)
    us = None if us is None else as_array("us", us)  # its values, once: a NaN is no model's error
    any_nonlinear = any(isinstance(model, NonlinearModel) for model in models)
    modes = []
    for j, model in enumerate(models):
        try:
            check_steps(model, T)  # (named: audit AA2)
            controls = check_controls(us, model, 1, T)
        except ValueError as exc:  # the values are checked: whether and how this model takes controls
            raise ValueError(f"in `models[{j}]`: {exc}") from exc
        if isinstance(model, LinearModel) and (any_nonlinear or method not in (None, "kf")):
            if method is not None:  # for the NonlinearModels (if any): checked, though a LinearModel is exact
                check_options(method, options, imm_filter)
            spec, opts = resolve_method(model, "kf", {})
        else:
            spec, opts = resolve_method(model, method, options, imm_filter)
        lin, iterations, tol = linearisation(spec, model, None if controls is None else controls[0], opts)
        z_angles = getattr(model, "measurement_angles", None)
        modes.append(_Mode(j, spec, opts, lin, iterations, tol, angles,
                           z_angles if z_angles is not None and z_angles.any() else None))
    return modes


def _mix(log_mu: np.ndarray, log_P: np.ndarray, means: np.ndarray, covs: np.ndarray, angles):
    """Step 1, mixing, in log space: ``log c`` and each mode's moment-matched start."""
    joint = log_mu[:, None] + log_P  # log p_ij μ_i
    log_c = np.logaddexp.reduce(joint, axis=0)
    starts = []
    for j in range(log_P.shape[0]):
        if log_c[j] > -np.inf:
            w = np.exp(joint[:, j] - log_c[j])
        else:  # an unreachable mode: keep its own belief (its probability stays 0)
            w = np.zeros(log_P.shape[0])
            w[j] = 1.0
        starts.append(moment_match(w, means, covs, angles))
    return log_c, starts


def _reweight(logl: np.ndarray, log_c: np.ndarray) -> tuple[np.ndarray, float]:
    """Step 3: the posterior log mode probabilities and ``log Σ_j Λ_j c_j``."""
    a = logl + log_c
    total = np.logaddexp.reduce(a)
    return a - total, float(total)
