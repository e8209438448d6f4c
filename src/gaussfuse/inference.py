"""Filtering and smoothing drivers: ``filter()``, ``smooth()`` and the method registry.

The front functions validate their input, pick a method from ``METHODS``
and run it over one series or, for a leading series axis, over each series.
The algebra of every step is in :mod:`gaussfuse.kalman`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Callable, NamedTuple

import numpy as np

from . import kalman
from ._validation import as_array, shape_error
from .gaussian import Gaussian
from .models.linear import LinearModel

__all__ = ["filter", "smooth", "FilterResult", "SmoothResult", "METHODS"]


@dataclass(frozen=True, eq=False)
class FilterResult:
    """The output of :func:`filter`.

    With a leading series axis on the measurements (N series), every array
    gains that axis and `loglik` has shape (N,).

    Attributes
    ----------
    means : ndarray of shape (T, n)
        Filtered means ``E[x_k | z_1..z_k]``.
    covs : ndarray of shape (T, n, n)
        Filtered covariances.
    predicted_means : ndarray of shape (T, n)
        One-step predictions ``E[x_k | z_1..z_{k-1}]``.
    predicted_covs : ndarray of shape (T, n, n)
        Covariances of the predictions.
    innovations : ndarray of shape (T, m)
        ``z_k - E[z_k | z_1..z_{k-1}]``; NaN where ``z_k`` is missing.
    innovation_covs : ndarray of shape (T, m, m)
        Covariances of the predicted measurements.
    loglik : float
        ``log p(z_1..z_T)`` over the observed components, including the
        ``-m/2 log 2π`` constants.
    """

    means: np.ndarray
    covs: np.ndarray
    predicted_means: np.ndarray
    predicted_covs: np.ndarray
    innovations: np.ndarray
    innovation_covs: np.ndarray
    loglik: float | np.ndarray


@dataclass(frozen=True, eq=False)
class SmoothResult:
    """The output of :func:`smooth`.

    Attributes
    ----------
    means : ndarray of shape (T, n)
        Smoothed means ``E[x_k | z_1..z_T]``.
    covs : ndarray of shape (T, n, n)
        Smoothed covariances.
    gains : ndarray of shape (T - 1, n, n)
        Smoother gains ``G_k``, k = 0..T-2.
    filtered : FilterResult
        The forward pass.
    """

    means: np.ndarray
    covs: np.ndarray
    gains: np.ndarray
    filtered: FilterResult

    @property
    def loglik(self) -> float | np.ndarray:
        """The log-likelihood of the measurements (from the forward pass)."""
        return self.filtered.loglik


# ---------------------------------------------------------------------------
# The linear Kalman filter and RTS smoother
# ---------------------------------------------------------------------------


def _kf_filter(model: LinearModel, prior: Gaussian, zs: np.ndarray, us: np.ndarray | None) -> FilterResult:
    T, n, m = zs.shape[0], model.n, model.m
    means, covs = np.empty((T, n)), np.empty((T, n, n))
    pmeans, pcovs = np.empty((T, n)), np.empty((T, n, n))
    innov, icovs = np.empty((T, m)), np.empty((T, m, m))
    loglik = 0.0
    mean, cov = prior.mean, prior.cov
    for k in range(T):
        F, H, Q, R, B = model.at(k)
        with _at_step(k):
            mean, cov = kalman.predict(mean, cov, F, Q, None if B is None else B @ us[k])
            pmeans[k], pcovs[k] = mean, cov
            mean, cov, innov[k], icovs[k], ll = kalman.update(mean, cov, zs[k], H, R)
        means[k], covs[k] = mean, cov
        loglik += ll
    return FilterResult(means, covs, pmeans, pcovs, innov, icovs, loglik)


def _kf_smooth(model: LinearModel, prior: Gaussian, zs: np.ndarray, us: np.ndarray | None) -> SmoothResult:
    filt = _kf_filter(model, prior, zs, us)
    F = model.F[1:] if model.F.ndim == 3 else model.F
    cross = filt.covs[:-1] @ np.swapaxes(F, -1, -2)
    return rts(filt, cross)


def rts(filt: FilterResult, cross_covs: np.ndarray) -> SmoothResult:
    """Run the RTS backward pass over a filtered series.

    Parameters
    ----------
    filt : FilterResult
        A single-series forward pass.
    cross_covs : array of shape (T - 1, n, n)
        ``cross_covs[k] = Cov(x_k, x_{k+1} | z_1..z_k)``.
    """
    T, n = filt.means.shape
    means, covs = filt.means.copy(), filt.covs.copy()
    gains = np.empty((max(T - 1, 0), n, n))
    for k in range(T - 2, -1, -1):
        with _at_step(k):
            means[k], covs[k], gains[k] = kalman.rts_step(
                filt.means[k], filt.covs[k],
                filt.predicted_means[k + 1], filt.predicted_covs[k + 1],
                means[k + 1], covs[k + 1], cross_covs[k],
            )
    return SmoothResult(means, covs, gains, filt)


class _at_step:
    """Prefix the time step to a ``LinAlgError`` raised inside the block."""

    def __init__(self, k: int) -> None:
        self.k = k

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None and issubclass(exc_type, np.linalg.LinAlgError):
            raise np.linalg.LinAlgError(f"at step {self.k}: {exc}") from exc
        return False


# ---------------------------------------------------------------------------
# Method registry
# ---------------------------------------------------------------------------


class Method(NamedTuple):
    """A registered inference method.

    Attributes
    ----------
    model_types : tuple of type
        The model classes it accepts.
    options : dict
        Accepted keyword options and their defaults.
    filter, smooth : callable
        ``(model, prior, zs, us, **options)`` on one series, returning a
        :class:`FilterResult` / :class:`SmoothResult`.
    """

    model_types: tuple[type, ...]
    options: dict
    filter: Callable[..., FilterResult]
    smooth: Callable[..., SmoothResult]


METHODS: dict[str, Method] = {
    "kf": Method((LinearModel,), {}, _kf_filter, _kf_smooth),
}

DEFAULT_METHOD: dict[type, str] = {LinearModel: "kf"}


def _resolve_method(model, method: str | None, options: dict) -> tuple[Method, dict]:
    if method is None:
        for cls, name in DEFAULT_METHOD.items():
            if isinstance(model, cls):
                method = name
                break
        else:
            known = ", ".join(c.__name__ for c in DEFAULT_METHOD)
            raise TypeError(f"`model` must be one of {known}; got {type(model).__name__}.")
    if method not in METHODS:
        raise ValueError(f"`method` must be one of {sorted(METHODS)}; got {method!r}.")
    spec = METHODS[method]
    if not isinstance(model, spec.model_types):
        fits = sorted(k for k, v in METHODS.items() if isinstance(model, v.model_types))
        raise TypeError(
            f"method {method!r} does not apply to a {type(model).__name__}; "
            f"valid methods for it are {fits}."
        )
    unknown = sorted(set(options) - set(spec.options))
    if unknown:
        valid = sorted(spec.options) or "none"
        raise TypeError(
            f"unknown option(s) {unknown} for method {method!r}; valid options are {valid}."
        )
    return spec, {**spec.options, **options}


# ---------------------------------------------------------------------------
# Input validation
# ---------------------------------------------------------------------------


def check_prior(prior, n: int) -> Gaussian:
    """Check that `prior` is a Gaussian over the n-dimensional state."""
    if not isinstance(prior, Gaussian):
        raise TypeError(
            f"`prior` must be a gaussfuse.Gaussian(mean, cov); got {type(prior).__name__}."
        )
    if prior.dim != n:
        raise ValueError(f"`prior` must have dimension {n} (the model's state); got {prior.dim}.")
    return prior


def check_measurements(zs, m: int) -> np.ndarray:
    """Return `zs` as an array (N, T, m); NaN marks a missing component."""
    arr = as_array("zs", zs, allow_nan=True)
    if arr.ndim == 1 and m == 1:
        arr = arr[:, None]
    if arr.ndim == 2 and arr.shape[1] == m:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[-1] != m or arr.shape[1] == 0:
        expected = f"(T, {m}){' or (T,)' if m == 1 else ''}, or (N, T, {m}) for N series, with T >= 1"
        raise shape_error("zs", expected, np.shape(arr))
    return arr


def check_controls(us, model, N: int, T: int) -> np.ndarray | None:
    """Return `us` as an array (N, T, p), or None for a model without control input."""
    p = getattr(model, "p", 0)
    if p == 0:
        if us is not None:
            raise ValueError("`us` was given but the model has no control input; give the model `B`.")
        return None
    if us is None:
        raise ValueError(f"`us` is required: the model has a control input with p = {p}.")
    arr = as_array("us", us)
    if arr.ndim == 1 and p == 1:
        arr = arr[:, None]
    if arr.ndim == 2:
        arr = np.broadcast_to(arr, (N, *arr.shape))
    if arr.ndim != 3 or arr.shape[1:] != (T, p) or arr.shape[0] not in (1, N):
        raise shape_error("us", f"(T, p) = ({T}, {p}) or ({N}, {T}, {p}), matching `zs`", np.shape(us))
    return np.broadcast_to(arr, (N, T, p))


def _check_steps(model, T: int) -> None:
    steps = getattr(model, "steps", None)
    if steps is not None and steps != T:
        raise ValueError(
            f"the model is time-varying over {steps} steps but `zs` has {T} steps; they must agree."
        )


def _prepare(model, prior, zs, us, method, options):
    spec, options = _resolve_method(model, method, options)
    prior = check_prior(prior, model.n)
    batch = np.ndim(zs) == 3
    zs = check_measurements(zs, model.m)
    N, T = zs.shape[:2]
    _check_steps(model, T)
    us = check_controls(us, model, N, T)
    return spec, options, prior, zs, us, batch


def _stack(results: list):
    """Stack per-series results along a new leading axis."""
    cls = type(results[0])
    values = {}
    for f in fields(cls):
        items = [getattr(r, f.name) for r in results]
        values[f.name] = _stack(items) if f.name == "filtered" else np.stack(items)
    return cls(**values)


# ---------------------------------------------------------------------------
# Front functions
# ---------------------------------------------------------------------------


def filter(model, prior: Gaussian, zs, us=None, method: str | None = None, **options) -> FilterResult:
    """Filter a series of measurements: the belief about each state given the past.

    Parameters
    ----------
    model : LinearModel
        The state-space model.
    prior : Gaussian
        Belief about the state one step *before* the first measurement;
        every step is predict (with ``u_k``), then update (with ``z_k``).
    zs : array_like of shape (T, m), (T,) when m = 1, or (N, T, m)
        Measurements; a NaN component is missing. A leading axis holds N
        independent series, and every result then gains that axis.
    us : array_like of shape (T, p), (T,) when p = 1, or (N, T, p), optional
        Control inputs, required exactly when the model has ``B``.
    method : str, optional
        One of ``METHODS``; defaults to ``"kf"`` for a LinearModel.
    **options
        Method options; an unknown one is rejected with the list of valid ones.

    Returns
    -------
    FilterResult

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=[[1, 0], [0, 3]], R=10)
    >>> prior = gf.Gaussian([0, 1], 500 * np.eye(2))
    >>> res = gf.filter(model, prior, [1, 2, 3, 2, 1])
    >>> res.means.shape, res.covs.shape
    ((5, 2), (5, 2, 2))
    """
    spec, options, prior, zs, us, batch = _prepare(model, prior, zs, us, method, options)
    results = [
        spec.filter(model, prior, z, None if us is None else us[i], **options)
        for i, z in enumerate(zs)
    ]
    return _stack(results) if batch else results[0]


def smooth(model, prior: Gaussian, zs, us=None, method: str | None = None, **options) -> SmoothResult:
    """Smooth a series of measurements: the belief about each state given all of them.

    Takes the same arguments as :func:`filter`; the linear method is the
    Rauch–Tung–Striebel smoother (see :func:`gaussfuse.kalman.rts_step`).

    Returns
    -------
    SmoothResult
        ``.means`` (T, n), ``.covs`` (T, n, n), ``.gains`` (T-1, n, n) and
        ``.filtered``, the forward pass.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=[[1, 0], [0, 3]], R=10)
    >>> sm = gf.smooth(model, gf.Gaussian([0, 1], 500 * np.eye(2)), [1, 2, 3, 2, 1])
    >>> sm.means.shape, sm.filtered.means.shape
    ((5, 2), (5, 2))
    """
    spec, options, prior, zs, us, batch = _prepare(model, prior, zs, us, method, options)
    results = [
        spec.smooth(model, prior, z, None if us is None else us[i], **options)
        for i, z in enumerate(zs)
    ]
    return _stack(results) if batch else results[0]
