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
from ._frozen import reduce_frozen
from ._validation import as_array, shape_error
from .gaussian import Gaussian
from .inference import (_check_steps, _linearisation, _resolve_method, check_controls,
                        check_measurements, check_prior, iterated_update)
from .linearize.sigma_points import circular_mean
from .models.linear import LinearModel
from .models.nonlinear import ModelFunctionError, NonlinearModel

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


class _at:
    """Prefix the step and the model to an error raised by the algebra or a model function."""

    def __init__(self, k: int, j: int) -> None:
        self.k, self.j = k, j

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None and issubclass(exc_type, (np.linalg.LinAlgError, ModelFunctionError)):
            raise exc_type(f"at step {self.k}, in `models[{self.j}]`: {exc}") from exc
        return False


def moment_match(weights: np.ndarray, means: np.ndarray, covs: np.ndarray,
                 angles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""The Gaussian with the mean and covariance of a Gaussian mixture.

    Parameters
    ----------
    weights : array of shape (M,)
        Mixture weights, summing to 1.
    means : array of shape (M, n)
        Component means.
    covs : array of shape (M, n, n)
        Component covariances.
    angles : array of bool, shape (n,), optional
        Components that are angles: their mean is circular and their spread
        is measured with wrapped differences.

    Returns
    -------
    mean : array of shape (n,)
    cov : array of shape (n, n)

    Notes
    -----
    .. math::

        \bar m = \sum_i w_i m_i, \qquad
        \bar P = \sum_i w_i \left[ P_i + (m_i - \bar m)(m_i - \bar m)^\top \right].
    """
    mean = weights @ means
    if angles is not None and angles.any():
        mean[angles] = circular_mean(means[:, angles], weights)
    diff = kalman.wrap_components(means - mean, angles)
    cov = np.einsum("i,ijk->jk", weights, covs) + (diff * weights[:, None]).T @ diff
    return mean, kalman.symmetrize(cov)


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

       computed in log space. An all-missing :math:`z_k` leaves
       :math:`\mu_j = c_j`.

    4. *Combination* (the reported belief):

       .. math::

           m = \sum_j \mu_j m_j, \qquad
           P = \sum_j \mu_j \left[P_j + (m_j - m)(m_j - m)^\top\right].

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
    arr = check_measurements(zs, m)
    if np.ndim(zs) == 3:
        raise shape_error("zs", f"(T, {m}){' or (T,)' if m == 1 else ''} (one series)", np.shape(zs))
    zs = arr[0]
    T = zs.shape[0]
    P = _probabilities("transition", transition, M, matrix=True)
    mu = np.full(M, 1.0 / M) if mode_probs is None else _probabilities(
        "mode_probs", mode_probs, M, matrix=False)
    angles = _state_angles(models)
    any_nonlinear = any(isinstance(model, NonlinearModel) for model in models)
    strategies, iterations, tols, z_angles = [], [], [], []
    for j, model in enumerate(models):
        _check_steps(model, T)
        controls = check_controls(us, model, 1, T)
        controls = None if controls is None else controls[0]
        if isinstance(model, LinearModel) and any_nonlinear:
            spec, opts = _resolve_method(model, "kf", {})
        else:
            spec, opts = _resolve_method(model, method, options)
        lin, its = _linearisation(spec, model, controls, opts)
        strategies.append(lin)
        iterations.append(its)
        tols.append(opts.get("tol"))
        z_angles.append(getattr(model, "measurement_angles", None))

    means, covs = np.empty((T, n)), np.empty((T, n, n))
    probs = np.empty((T, M))
    mode_means, mode_covs = np.empty((T, M, n)), np.empty((T, M, n, n))
    prev_means = np.broadcast_to(prior.mean, (M, n))
    prev_covs = np.broadcast_to(prior.cov, (M, n, n))
    logl = np.empty(M)
    loglik = 0.0
    for k in range(T):
        # 1. Mixing.
        c = mu @ P
        weights = P * mu[:, None]
        for j in range(M):
            if c[j] > 0.0:
                w = weights[:, j] / c[j]
            else:  # an unreachable mode: keep its own belief (its probability stays 0)
                w = np.zeros(M)
                w[j] = 1.0
            mean, cov = moment_match(w, prev_means, prev_covs, angles)
            # 2. Mode-matched filtering.
            with _at(k, j):
                A, b, Q = strategies[j].transition(k, mean, cov)
                mean, cov = kalman.predict(mean, cov, A, Q, b)
                mean = kalman.wrap_components(mean, angles)
                post = iterated_update(strategies[j], k, mean, cov, zs[k], iterations[j], tols[j], angles,
                                       z_angles[j])[0]
                post_mean, post_cov = kalman.wrap_components(post.mean, angles), post.cov
            mode_means[k, j], mode_covs[k, j], logl[j] = post_mean, post_cov, post.loglik
        # 3. Mode probabilities, in log space.
        with np.errstate(divide="ignore"):
            a = logl + np.log(c)
        top = a.max()
        w = np.exp(a - top)
        total = w.sum()
        mu = w / total
        loglik += float(top + np.log(total))
        probs[k] = mu
        # 4. Combination.
        means[k], covs[k] = moment_match(mu, mode_means[k], mode_covs[k], angles)
        prev_means, prev_covs = mode_means[k], mode_covs[k]
    for a in (means, covs, probs, mode_means, mode_covs):
        a.setflags(write=False)
    return IMMResult(means, covs, probs, mode_means, mode_covs, loglik)
