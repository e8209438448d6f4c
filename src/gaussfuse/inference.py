"""Filtering and smoothing drivers: ``filter()``, ``smooth()`` and the method registry.

The front functions validate their input, pick a method from ``METHODS``
and run it over one series or, for a leading series axis, over each series.
The algebra of every step is in :mod:`gaussfuse.kalman`.
"""

from __future__ import annotations

import importlib
import importlib.util
import warnings
from dataclasses import dataclass, fields, replace
from typing import Callable, NamedTuple

import numpy as np

from . import kalman
from ._frozen import reduce_frozen
from ._validation import as_array, shape_error
from .errors import ConvergenceWarning
from .gaussian import Gaussian
from .linearize import Exact, Nominal, SigmaPoints, Taylor
from .linearize.sigma_points import cubature, gauss_hermite, unscented
from .models.linear import LinearModel
from .models.nonlinear import ModelFunctionError, NonlinearModel

__all__ = ["filter", "smooth", "run_filter", "run_smoother", "iterated_update", "FilterResult", "SmoothResult",
           "METHODS"]


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
    last_mean : ndarray of shape (n,)
        The final filtered mean (the belief to continue from).
    last_cov : ndarray of shape (n, n)
        The final filtered covariance.
    iterations : ndarray of int, shape (T,), or None
        For the iterated methods ("iekf", "iplf"): the number of
        linearise-and-update passes made at each step, at most the option
        `iterations` (see `tol` in :func:`filter`). None for the other
        methods.

    Notes
    -----
    With ``keep="means"`` the covariance fields are None; with
    ``keep="last"`` every per-step field (`iterations` too) is None, so that
    a long series filters in memory independent of its length.
    """

    means: np.ndarray | None
    covs: np.ndarray | None
    predicted_means: np.ndarray | None
    predicted_covs: np.ndarray | None
    innovations: np.ndarray | None
    innovation_covs: np.ndarray | None
    loglik: float | np.ndarray
    last_mean: np.ndarray
    last_cov: np.ndarray
    iterations: np.ndarray | None = None

    __reduce__ = reduce_frozen  # pickles and copies keep read-only arrays read-only

    @property
    def last(self) -> Gaussian:
        """The final filtered belief, to continue filtering from (one series only)."""
        if self.last_mean.ndim != 1:
            raise ValueError("`last` is for one series; use `last_mean` and `last_cov` for a batch.")
        return Gaussian(self.last_mean, self.last_cov)


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
    iterations : int or None
        For the iterated smoothers ("iekf", "iplf"): the number of passes
        made, at most the option `iterations` (see `tol` in :func:`smooth`).
        None for the other methods.
    """

    means: np.ndarray
    covs: np.ndarray
    gains: np.ndarray
    filtered: FilterResult
    iterations: int | np.ndarray | None = None

    __reduce__ = reduce_frozen

    @property
    def loglik(self) -> float | np.ndarray:
        """The log-likelihood of the measurements (from the forward pass)."""
        return self.filtered.loglik


# ---------------------------------------------------------------------------
# The drivers: one affine Kalman loop for every method
# ---------------------------------------------------------------------------


KEEP = ("all", "means", "last")


def run_filter(lin, prior: Gaussian, zs: np.ndarray, *, iterations: int = 1, tol: float | None = None,
               state_angles=None, measurement_angles=None, keep: str = "all") -> FilterResult:
    """Filter one series (T, m) with a linearisation strategy (see :mod:`gaussfuse.linearize`).

    Each step predicts through ``lin.transition`` and updates through
    ``lin.measurement``. With ``iterations > 1`` the update is repeated,
    each time re-linearising the measurement at the latest posterior and
    conditioning the *prediction* again (the iterated EKF's Gauss–Newton
    steps, or posterior linearisation), at most `iterations` times, and
    fewer when `tol` is given and met (see :func:`iterated_update`).
    `keep` is one of ``KEEP``.
    """
    return _filter_pass(lin, prior, zs, iterations, tol, state_angles, measurement_angles, keep)[0]


def iterate_changed(cov: np.ndarray):
    r"""The change of an iterate in the norm of `cov`: a function ``(new, old) -> float``.

    .. math::

        \lVert x_i - x_{i-1} \rVert_{P} = \sqrt{(x_i - x_{i-1})^\top P^{-1} (x_i - x_{i-1})},

    with ``P = L Lᵀ`` (Cholesky, or the semi-definite factor of
    :func:`gaussfuse.kalman.semidefinite_cholesky` on the range of a singular
    P, where the iterates move). It is scale-free: the change in standard
    deviations of P. A component that changed by no more than its round-off,
    ``4 ε max(|new|, |old|)``, counts as unchanged, so that a component whose
    variance is itself round-off does not keep the iteration going.
    """
    try:
        L = np.linalg.cholesky(cov)
        rows = slice(None)
    except np.linalg.LinAlgError:
        L = kalman.semidefinite_cholesky(cov)
        rows = np.diag(L) > 0.0
        L = L[np.ix_(rows, rows)]
    eps4 = 4.0 * np.finfo(np.float64).eps

    def changed(new: np.ndarray, old: np.ndarray, angles=None) -> float:
        delta = kalman.wrap_components(new - old, angles)
        delta = np.where(np.abs(delta) <= eps4 * np.maximum(np.abs(new), np.abs(old)), 0.0, delta)[rows]
        if not delta.any():
            return 0.0
        white = np.linalg.solve(L, delta)
        return float(np.sqrt(white @ white))

    return changed


def iterated_update(lin, k: int, mean: np.ndarray, cov: np.ndarray, z: np.ndarray, iterations: int = 1,
                    tol: float | None = None, state_angles=None, measurement_angles=None):
    """The update of step k, repeated: the loop body of every driver of the iterated methods.

    Pass i linearises the measurement (``lin.measurement``) at the previous
    posterior ``x_{i-1}`` (``x_0`` the prediction `mean`) and conditions the
    prediction ``N(mean, cov)`` on `z` again. With one iteration this is the
    plain update. With more, it stops after the first pass whose change
    ``‖x_i - x_{i-1}‖`` in the norm of `cov` (:func:`iterate_changed`) is at
    most `tol`, or after `iterations` passes.

    Returns
    -------
    post : kalman.Update
        The last pass's update (its mean not yet wrapped to the state angles).
    passes : int
        The passes made.
    converged : bool
        False when `iterations` > 1 passes were made without meeting `tol`
        (given); True otherwise.
    """
    post_mean, post_cov = mean, cov
    changed = iterate_changed(cov) if iterations > 1 and tol is not None else None
    for i in range(iterations):
        H, d, R = lin.measurement(k, post_mean, post_cov)
        post = kalman.update(mean, cov, z, H, R, d, angles=measurement_angles)
        previous, post_mean, post_cov = post_mean, kalman.wrap_components(post.mean, state_angles), post.cov
        if changed is not None and changed(post_mean, previous, state_angles) <= tol:
            return post, i + 1, True
    return post, iterations, changed is None


def _filter_pass(lin, prior: Gaussian, zs: np.ndarray, iterations: int, tol: float | None, state_angles,
                 measurement_angles, keep: str) -> tuple[FilterResult, int]:
    """:func:`run_filter`, and the number of steps that made `iterations` passes without meeting `tol`."""
    T, n, m = zs.shape[0], prior.dim, zs.shape[1]
    rows = 0 if keep == "last" else T
    crows = T if keep == "all" else 0
    means, covs = np.empty((rows, n)), np.empty((crows, n, n))
    pmeans, pcovs = np.empty((rows, n)), np.empty((crows, n, n))
    innov, icovs = np.empty((rows, m)), np.empty((crows, m, m))
    used = np.empty(rows if iterations > 1 else 0, dtype=np.int64)
    unconverged = 0
    loglik = 0.0
    mean, cov = prior.mean, prior.cov
    for k in range(T):
        with _at_step(k), np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised below
            A, b, Q = lin.transition(k, mean, cov)
            mean, cov = kalman.predict(mean, cov, A, Q, b)
            mean = kalman.wrap_components(mean, state_angles)
            check_finite(k, "predicted", mean, cov)
            if rows:
                pmeans[k] = mean
            if crows:
                pcovs[k] = cov
            post, passes, converged = iterated_update(lin, k, mean, cov, zs[k], iterations, tol, state_angles,
                                                      measurement_angles)
            unconverged += not converged
            if used.shape[0]:
                used[k] = passes
            check_finite(k, "filtered", post.mean, post.cov, post.loglik)
        mean, cov = kalman.wrap_components(post.mean, state_angles), post.cov
        if rows:
            means[k], innov[k] = mean, post.innovation
        if crows:
            covs[k], icovs[k] = cov, post.innovation_cov
        loglik += post.loglik
    per_step = (means, covs, pmeans, pcovs, innov, icovs)
    result = FilterResult(*(a if a.shape[0] else None for a in per_step), loglik, mean, cov,
                          used if used.shape[0] else None)
    return result, unconverged


def run_smoother(lin, filt: FilterResult, prior: Gaussian | None = None, *,
                 state_angles=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The RTS backward pass over a filtered series, with transitions from `lin`.

    The transition out of each filtered belief is re-linearised at that
    belief (for sigma-point smoothers: points re-drawn from ``(m_k, P_k)``),
    so ``A``, the prediction and the cross-covariance ``P_k Aᵀ`` agree. With
    `prior`, the pass continues back to the prior's time.

    Returns
    -------
    means : ndarray of shape (T, n), or (T + 1, n) with `prior`
    covs : ndarray of shape (T, n, n), or (T + 1, n, n) with `prior`
    gains : ndarray of shape (T - 1, n, n), or (T, n, n) with `prior`
    """
    means, covs = filt.means, filt.covs
    first = 1
    if prior is not None:
        means = np.concatenate([prior.mean[None], means])
        covs = np.concatenate([prior.cov[None], covs])
        first = 0
    sm_means, sm_covs = means.copy(), covs.copy()
    gains = np.empty((max(means.shape[0] - 1, 0), *covs.shape[1:]))
    for j in range(means.shape[0] - 2, -1, -1):
        with _at_step(j + first), np.errstate(over="ignore", invalid="ignore"):
            A, b, Q = lin.transition(j + first, means[j], covs[j])
            pred_mean, pred_cov = kalman.predict(means[j], covs[j], A, Q, b)
            sm_means[j], sm_covs[j], gains[j] = kalman.rts_step(
                means[j], covs[j], kalman.wrap_components(pred_mean, state_angles), pred_cov,
                sm_means[j + 1], sm_covs[j + 1], covs[j] @ A.T, angles=state_angles,
            )
            sm_means[j] = kalman.wrap_components(sm_means[j], state_angles)
        check_finite(j + first, "smoothed", sm_means[j], sm_covs[j])
    return sm_means, sm_covs, gains


def not_finite(stage: str, k: int, series: int | None = None) -> FloatingPointError:
    """The error for a belief that overflowed: the same words from every engine.

    `stage` is "predicted", "filtered" (whose log-likelihood term is checked
    too) or "smoothed"; `series` is named for a batch of series.
    """
    what = "mean, covariance or log-likelihood" if stage == "filtered" else "mean or covariance"
    where = f"at step {k}" if series is None else f"in series {series}, at step {k}"
    return FloatingPointError(
        f"{where}: the {stage} {what} is not finite (inf or NaN): the computation overflowed; "
        "check the scale of the model, the prior and the measurements."
    )


def check_smoothed(means: np.ndarray, covs: np.ndarray) -> None:
    """:func:`check_finite` for the smoothed beliefs (N, T, n) of a compiled engine, after its backward pass.

    Names the step the readable backward pass would have stopped at: in the
    first series that overflowed, the latest step.
    """
    bad = ~(np.isfinite(means).all(axis=-1) & np.isfinite(np.diagonal(covs, axis1=-2, axis2=-1)).all(axis=-1))
    if bad.any():
        s = int(np.flatnonzero(bad.any(axis=1))[0])
        raise not_finite("smoothed", int(np.flatnonzero(bad[s])[-1]), s if means.shape[0] > 1 else None)


def check_finite(k: int, stage: str, mean: np.ndarray, cov: np.ndarray, loglik: float = 0.0) -> None:
    """Raise :func:`not_finite` when the mean, the diagonal of the covariance or `loglik` is inf or NaN.

    The diagonal stands for the whole matrix (an infinite or NaN covariance
    has one there), so the check is O(n) a step.
    """
    if not (np.isfinite(mean).all() and np.isfinite(np.diagonal(cov)).all() and np.isfinite(loglik)):
        raise not_finite(stage, k)


class _at_step:
    """Prefix the time step to an error raised inside the block by the algebra or the model."""

    def __init__(self, k: int) -> None:
        self.k = k

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is not None and issubclass(exc_type, (np.linalg.LinAlgError, ModelFunctionError)):
            raise exc_type(f"at step {self.k}: {exc}") from exc
        return False


# ---------------------------------------------------------------------------
# Method registry
# ---------------------------------------------------------------------------


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"`{name}` must be a positive integer; got {value!r}.")
    return int(value)


def _real(name: str, value, *, positive: bool = False, nonnegative: bool = False, optional: bool = False):
    if optional and value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value) or (positive and value <= 0) or (nonnegative and value < 0):
        kind = "a positive" if positive else "a non-negative finite" if nonnegative else "a finite"
        raise ValueError(f"`{name}` must be {kind} number{' or None' if optional else ''}; got {value!r}.")
    return float(value)


OPTION_CHECKS: dict[str, Callable] = {
    "iterations": _positive_int,
    "order": _positive_int,
    "alpha": lambda name, v: _real(name, v, positive=True),
    "beta": _real,
    "kappa": lambda name, v: _real(name, v, optional=True),
    "tol": lambda name, v: _real(name, v, nonnegative=True),
}


class Method(NamedTuple):
    """A registered inference method.

    Attributes
    ----------
    model_types : tuple of type
        The model classes it accepts.
    options : dict
        Accepted keyword options and their defaults.
    strategy : callable
        ``(model, us, **options) -> strategy``: how the model is linearised
        (see :mod:`gaussfuse.linearize`); ``iterations`` and ``tol`` are not
        passed.
    iterated : bool
        Whether ``iterations`` repeats the update (filter) and the whole
        linearise-filter-smooth pass (smoother), at most that many times:
        the repetition stops when the change is at most ``tol``.
    description : str
        One line for listings.
    compiled : str or None
        Module under :mod:`gaussfuse._kernels` with the compiled engine:
        functions ``filter(method, model, prior, zs, us, options, keep)``
        and ``smooth(method, model, prior, zs, us, options)`` taking the
        validated (N, T, m) measurements and (N, T, p) controls (or None)
        and returning results with the leading N axis.
    """

    model_types: tuple[type, ...]
    options: dict
    strategy: Callable
    iterated: bool
    description: str
    compiled: str | None = None


DEFAULT_TOL = 1e-9
"""Default `tol` of the iterated methods: the iterate moved less than 1e-9 predicted standard deviations."""
DEFAULT_ITERATIONS = 50
"""Default `iterations` of the iterated methods: a limit; Gauss-Newton and posterior linearisation
converge linearly, and on Särkkä and Svensson's pendulum reach `tol` in 3-21 updates per step and
11 smoother passes."""

METHODS: dict[str, Method] = {
    "kf": Method((LinearModel,), {}, lambda model, us: Exact(model, us), False,
                 "Kalman filter / Rauch-Tung-Striebel smoother (exact for linear models)", "linear"),
    "ekf": Method((NonlinearModel,), {}, lambda model, us: Taylor(model, us), False,
                  "extended Kalman filter / extended RTS smoother"),
    "iekf": Method((NonlinearModel,), {"iterations": DEFAULT_ITERATIONS, "tol": DEFAULT_TOL},
                   lambda model, us: Taylor(model, us), True,
                   "iterated EKF / iterated extended (Gauss-Newton) smoother"),
    "ukf": Method((NonlinearModel,), {"alpha": 1.0, "beta": 0.0, "kappa": None},
                  lambda model, us, alpha, beta, kappa:
                  SigmaPoints(model, unscented(model.n, alpha, beta, kappa), us), False,
                  "unscented Kalman filter / unscented RTS smoother", "sigma_points"),
    "ckf": Method((NonlinearModel,), {}, lambda model, us: SigmaPoints(model, cubature(model.n), us),
                  False, "cubature Kalman filter / cubature RTS smoother", "sigma_points"),
    "ghkf": Method((NonlinearModel,), {"order": 3},
                   lambda model, us, order: SigmaPoints(model, gauss_hermite(model.n, order), us),
                   False, "Gauss-Hermite Kalman filter / RTS smoother", "sigma_points"),
    "iplf": Method((NonlinearModel,), {"iterations": DEFAULT_ITERATIONS, "order": 3, "tol": DEFAULT_TOL},
                   lambda model, us, order: SigmaPoints(model, gauss_hermite(model.n, order), us),
                   True, "iterated posterior-linearisation filter / smoother (Gauss-Hermite)"),
}

DEFAULT_METHOD: dict[type, str] = {LinearModel: "kf", NonlinearModel: "ukf"}


def _resolve_method(model, method: str | None, options: dict) -> tuple[Method, dict]:
    """Pick the method (default by model type) and check its options."""
    if method is None:
        for cls, name in DEFAULT_METHOD.items():
            if isinstance(model, cls):
                method = name
                break
        else:
            known = ", ".join(c.__name__ for c in DEFAULT_METHOD)
            raise TypeError(f"`model` must be a {known}; got {type(model).__name__}.")
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
    options = {name: OPTION_CHECKS[name](name, value) for name, value in options.items()}
    return spec, {**spec.options, **options}


def _angles(model):
    return getattr(model, "state_angles", None), getattr(model, "measurement_angles", None)


def _linearisation(spec: Method, model, us, options: dict):
    """The method's strategy for one series, and its ``iterations`` (1 if it has none)."""
    options = dict(options)
    iterations = options.pop("iterations", 1)
    options.pop("tol", None)
    return spec.strategy(model, us, **options), iterations


def _method_filter(spec: Method, model, prior, zs, us, options, keep: str = "all") -> tuple[FilterResult, int]:
    """The filter for one series, and how many of its steps stopped at the iteration limit."""
    lin, iterations = _linearisation(spec, model, us, options)
    xa, za = _angles(model)
    return _filter_pass(lin, prior, zs, iterations, options.get("tol"), xa, za, keep)


def _method_smooth(spec: Method, model, prior, zs, us, options) -> tuple[SmoothResult, int, bool]:
    """The smoother for one series; its filter's steps at the iteration limit; whether its passes did."""
    filt, unconverged = _method_filter(spec, model, prior, zs, us, options)
    lin, passes = _linearisation(spec, model, us, options)
    xa, za = _angles(model)
    if not spec.iterated:
        means, covs, gains = run_smoother(lin, filt, state_angles=xa)
        return SmoothResult(means, covs, gains, filt), unconverged, False
    # Iterated smoothers: each pass linearises about the previous pass's smoothed
    # trajectory (the first about the iterated filter's), from the prior's time on,
    # until the trajectory moves by at most `tol` (in the pass's predicted covariances).
    tol = options["tol"]
    means = np.concatenate([prior.mean[None], filt.means])
    covs = np.concatenate([prior.cov[None], filt.covs])
    converged = False
    for used in range(1, passes + 1):
        nominal = Nominal(lin, means, covs)
        last = run_filter(nominal, prior, zs, state_angles=xa, measurement_angles=za)
        new_means, covs, gains = run_smoother(nominal, last, prior, state_angles=xa)
        norms = (prior.cov, *last.predicted_covs)
        change = max(iterate_changed(P)(new, old, xa) for P, new, old in zip(norms, new_means, means))
        means = new_means
        if change <= tol:
            converged = True
            break
    return SmoothResult(means[1:], covs[1:], gains[1:], filt, used), unconverged, not converged


def _warn_unconverged(method: str, options: dict, steps: int, total: int, passes: int = 0, series: int = 1) -> None:
    """One ConvergenceWarning for a call: the steps (and smoother passes) that stopped at the limit."""
    if not steps and not passes:
        return
    limit, tol = options["iterations"], options["tol"]
    what = []
    if steps:
        what.append(f"{steps} of {total} steps of the filter made {limit} iterations")
    if passes:
        where = f" in {passes} of {series} series" if series > 1 else ""
        what.append(f"the smoother made {limit} passes{where}")
    warnings.warn(
        f"method {method!r}: {' and '.join(what)} (the limit, `iterations`={limit}) without the change "
        f"falling to `tol`={tol:g}; raise `iterations` or `tol`, or check the model.",
        ConvergenceWarning, stacklevel=3,
    )


# ---------------------------------------------------------------------------
# Input validation
# ---------------------------------------------------------------------------


def check_prior(prior, n: int, *, diffuse_ok: bool = False) -> Gaussian | str:
    """Check that `prior` is a Gaussian over the n-dimensional state (or "diffuse", where allowed)."""
    if diffuse_ok and isinstance(prior, str) and prior == "diffuse":
        return prior
    if not isinstance(prior, Gaussian):
        also = " or 'diffuse'" if diffuse_ok else ""
        shown = repr(prior) if isinstance(prior, str) else type(prior).__name__
        raise TypeError(
            f"`prior` must be a gaussfuse.Gaussian(mean, cov){also}; got {shown}."
        )
    if prior.dim != n:
        raise ValueError(f"`prior` must have dimension {n} (the model's state); got {prior.dim}.")
    return prior


def check_measurements(zs, m: int) -> np.ndarray:
    """Return `zs` as an array (N, T, m); NaN (or a masked entry of a masked array) marks a missing component."""
    try:
        kind = np.asarray(zs).dtype.kind
    except ValueError:  # ragged: as_array says so
        kind = None
    if kind in ("M", "m"):
        raise TypeError(f"`zs` must be an array of numbers; got {np.asarray(zs).dtype} values: "
                        "datetimes are not measurements.")
    arr = as_array("zs", zs, allow_nan=True, copy=False)
    given = arr.shape
    if arr.ndim == 1 and m == 1:
        arr = arr[:, None]
    if arr.ndim == 2 and arr.shape[1] == m:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[-1] != m or arr.shape[1] == 0 or arr.shape[0] == 0:
        expected = f"(T, {m}){' or (T,)' if m == 1 else ''}, or (N, T, {m}) for N series, with T >= 1 and N >= 1"
        raise shape_error("zs", expected, given)
    return arr


def check_controls(us, model, N: int, T: int) -> np.ndarray | None:
    """Return `us` as an array (N, T, p), or None when there are no controls.

    A LinearModel needs controls exactly when it has ``B``; for a
    NonlinearModel they are optional and passed to ``f(x, u)``.
    """
    p = model.p if isinstance(model, LinearModel) else None
    if p == 0 and us is not None:
        raise ValueError("`us` was given but the model has no control input; give the model `B`.")
    if us is None:
        if p:
            raise ValueError(f"`us` is required: the model has a control input with p = {p}.")
        return None
    arr = as_array("us", us)
    if arr.ndim == 1 and p in (1, None):
        arr = arr[:, None]
    if arr.ndim == 2:
        arr = arr[None]
    shown = "p" if p is None else p
    if arr.ndim != 3 or arr.shape[1] != T or (p is not None and arr.shape[2] != p) \
            or arr.shape[0] not in (1, N):
        raise shape_error("us", f"(T, p) = ({T}, {shown}) or ({N}, {T}, {shown}), matching `zs`",
                          np.shape(us))
    return np.broadcast_to(arr, (N, *arr.shape[1:]))


def _check_steps(model, T: int) -> None:
    steps = getattr(model, "steps", None)
    if steps is not None and steps != T:
        raise ValueError(
            f"the model is time-varying over {steps} steps but `zs` has {T} steps; they must agree."
        )


def _prepare(model, prior, zs, us, method, options):
    spec, options = _resolve_method(model, method, options)
    method = next(name for name, value in METHODS.items() if value is spec)
    prior = check_prior(prior, model.n, diffuse_ok=method == "kf")
    checked = check_measurements(zs, model.m)
    batch = np.ndim(zs) == 3  # only after the check: a ragged `zs` must not reach NumPy
    zs = checked
    N, T = zs.shape[:2]
    _check_steps(model, T)
    us = check_controls(us, model, N, T)
    return spec, method, options, prior, zs, us, batch


def _stack(results: list):
    """Stack per-series results along a new leading axis."""
    cls = type(results[0])
    values = {}
    for f in fields(cls):
        items = [getattr(r, f.name) for r in results]
        if f.name == "filtered":
            values[f.name] = _stack(items)
        else:
            values[f.name] = None if items[0] is None else np.stack(items)
    return cls(**values)


def _first(result):
    """The only series of a batched result, without the leading axis."""
    values = {}
    for f in fields(type(result)):
        item = getattr(result, f.name)
        if f.name == "filtered":
            values[f.name] = _first(item)
        elif f.name == "loglik":
            values[f.name] = float(item[0])
        elif f.name == "iterations" and np.ndim(item) == 1 and isinstance(result, SmoothResult):
            values[f.name] = int(item[0])
        else:
            values[f.name] = None if item is None else item[0]
    return type(result)(**values)


ENGINES = ("auto", "python", "numba")
AUTO_NUMBA_STEPS = 1000  # "auto" compiles from this many steps (all series together) on


def _compiled_engine(spec: Method, method: str, engine: str, steps: int):
    """The compiled module to run, or None for the readable Python path."""
    if engine not in ENGINES:
        raise ValueError(f"`engine` must be one of {list(ENGINES)}; got {engine!r}.")
    if engine == "python" or (engine == "auto" and steps < AUTO_NUMBA_STEPS):
        return None
    available = importlib.util.find_spec("numba") is not None
    if engine == "numba":
        if spec.compiled is None:
            fits = sorted(k for k, v in METHODS.items() if v.compiled)
            raise ValueError(
                f"`engine='numba'` is not available for method {method!r}; it is for {fits}."
            )
        if not available:
            raise ValueError("`engine='numba'` needs numba: pip install numba.")
    if spec.compiled is None or not available:
        return None
    return importlib.import_module(f"._kernels.{spec.compiled}", __package__)


# ---------------------------------------------------------------------------
# Front functions
# ---------------------------------------------------------------------------


def filter(model, prior: Gaussian, zs, us=None, method: str | None = None, *,
           engine: str = "auto", keep: str = "all", **options) -> FilterResult:
    r"""Filter a series of measurements: the belief about each state given the past.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The state-space model.
    prior : Gaussian or "diffuse"
        Belief about the state one step *before* the first measurement;
        every step is predict (with ``u_k``), then update (with ``z_k``).
        ``"diffuse"`` (linear models) makes the first state x₁ diffuse (a
        flat prior, handled exactly: :mod:`gaussfuse.diffuse`), as Durbin &
        Koopman, KFAS and statsmodels do, so the transition into x₁ plays no
        part; beliefs are NaN until the measurements identify the state,
        and `loglik` is the exact diffuse log-likelihood, equal to theirs
        for every F.
    zs : array_like of shape (T, m), (T,) when m = 1, or (N, T, m)
        Measurements; a NaN component (or a masked entry of a masked array)
        is missing. A leading axis holds N independent series, and every
        result then gains that axis.
    us : array_like of shape (T, p), (T,) when p = 1, or (N, T, p), optional
        Control inputs: required exactly when a LinearModel has ``B``;
        passed to a NonlinearModel's ``f(x, u_k)`` when given.
    method : str, optional
        One of ``METHODS``: ``"kf"`` (the default for a LinearModel) or,
        for a NonlinearModel, ``"ekf"``, ``"iekf"``, ``"ukf"`` (default),
        ``"ckf"``, ``"ghkf"`` or ``"iplf"``.
    **options
        Method options: ``iterations`` (iekf, iplf: the most update
        iterations per step, default 50) and ``tol`` (iekf, iplf: default
        1e-9; see Notes); ``alpha``, ``beta``, ``kappa`` (ukf; defaults 1, 0,
        3 - n); ``order`` (ghkf, iplf: Gauss–Hermite points per axis,
        default 3). An unknown one is rejected with the list of valid ones.
    engine : {"auto", "python", "numba"}, default "auto"
        ``"python"`` is the readable implementation, the specification;
        ``"numba"`` runs compiled kernels (methods "kf", with series in
        parallel, and "ukf", "ckf", "ghkf", whose whole loop is compiled when
        f and h are numba-jitted functions), equal to it to round-off; ``"auto"``
        compiles when numba is installed and the series have at least
        1000 steps in all.
    keep : {"all", "means", "last"}, default "all"
        What to return per step: everything; the means, predictions and
        innovations but no covariances; or nothing but the final belief
        (``last_mean``, ``last_cov``) and the log-likelihood, so memory does
        not grow with T.

    Returns
    -------
    FilterResult

    Raises
    ------
    ValueError, TypeError
        For input that cannot be right, naming the argument: shapes, non-finite
        model matrices, complex, boolean or datetime values, unknown options.
        A masked array's masked entries are not an error: they are missing.
    ModelFunctionError
        (a ValueError) When f, h or a Jacobian raises, or returns a wrong
        shape, a non-finite value, or complex or boolean values; the message
        names the function and the step.
    numpy.linalg.LinAlgError
        When an innovation covariance is not positive definite (at step k).
    FloatingPointError
        When a step's predicted or filtered mean, covariance or log-likelihood
        term is not finite: the computation overflowed (say a transition of
        1e200, or measurements near 1e308). The message names the step ("in
        series s, at step k" for a batch in the compiled linear engine).
        Both engines check the same values: the mean, the diagonal of the
        covariance and the log-likelihood term.

    Warns
    -----
    ConvergenceWarning
        Once per call, when steps of an iterated method made `iterations`
        passes without meeting `tol`; it says how many.

    Notes
    -----
    The iterated methods ("iekf", "iplf") repeat the update of each step:
    pass i linearises the measurement at the previous posterior mean
    :math:`x_{i-1}` (:math:`x_0` the prediction :math:`m^-`) and conditions
    the prediction again, giving :math:`x_i`. They stop after the first pass
    with

    .. math::

        \lVert x_i - x_{i-1} \rVert_{P^-} =
        \sqrt{(x_i - x_{i-1})^\top (P^-)^{-1} (x_i - x_{i-1})} \le \mathrm{tol},

    the change in predicted standard deviations (scale-free; on the range of
    :math:`P^-` when it is singular, and a component changing by no more than
    its round-off, :math:`4 \varepsilon |x|`, counts as unchanged), or after
    `iterations` passes. ``tol=0`` makes every step run to a fixed point or
    the limit. ``FilterResult.iterations`` holds the passes made at each
    step.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=[[1, 0], [0, 3]], R=10)
    >>> prior = gf.Gaussian([0, 1], 500 * np.eye(2))
    >>> res = gf.filter(model, prior, [1, 2, 3, 2, 1])
    >>> res.means.shape, res.covs.shape
    ((5, 2), (5, 2, 2))
    """
    if keep not in KEEP:
        raise ValueError(f"`keep` must be one of {list(KEEP)}; got {keep!r}.")
    spec, method, options, prior, zs, us, batch = _prepare(model, prior, zs, us, method, options)
    if prior == "diffuse":
        from .diffuse import diffuse_filter

        results = [_kept(diffuse_filter(model, z, None if us is None else us[i], engine), keep)
                   for i, z in enumerate(zs)]
        return _stack(results) if batch else results[0]
    compiled = _compiled_engine(spec, method, engine, zs.shape[0] * zs.shape[1])
    if compiled is not None:
        result = compiled.filter(method, model, prior, zs, us, options, keep)
        return result if batch else _first(result)
    runs = [_method_filter(spec, model, prior, z, None if us is None else us[i], options, keep)
            for i, z in enumerate(zs)]
    if spec.iterated:
        _warn_unconverged(method, options, sum(r[1] for r in runs), zs.shape[0] * zs.shape[1])
    results = [r[0] for r in runs]
    return _stack(results) if batch else results[0]


def smooth_from_prior(model: LinearModel, prior: Gaussian, zs, us=None, engine: str = "auto"):
    """RTS-smooth one series of a linear model back to the prior's time 0.

    Returns
    -------
    means : ndarray of shape (T + 1, n)
        Smoothed means at times 0..T, time 0 being the prior's.
    covs : ndarray of shape (T + 1, n, n)
    gains : ndarray of shape (T, n, n)
        Smoother gains from time t to t + 1.
    filtered : FilterResult
    """
    sm = smooth(model, prior, zs, us, engine=engine)
    F = model.at(0)[0]
    filt = sm.filtered
    m0, P0, G0 = kalman.rts_step(prior.mean, prior.cov, filt.predicted_means[0], filt.predicted_covs[0],
                                 sm.means[0], sm.covs[0], prior.cov @ F.T)
    return (np.concatenate([m0[None], sm.means]), np.concatenate([P0[None], sm.covs]),
            np.concatenate([G0[None], sm.gains]), filt)


def _kept(result: FilterResult, keep: str) -> FilterResult:
    """Drop what `keep` does not ask for from a full single-series result."""
    drop = {"all": (), "means": ("covs", "predicted_covs", "innovation_covs"),
            "last": ("means", "covs", "predicted_means", "predicted_covs", "innovations",
                     "innovation_covs")}[keep]
    return replace(result, **dict.fromkeys(drop))


def smooth(model, prior: Gaussian, zs, us=None, method: str | None = None, *,
           engine: str = "auto", **options) -> SmoothResult:
    """Smooth a series of measurements: the belief about each state given all of them.

    Takes the same arguments as :func:`filter` but `keep`. Every method ends in the
    Rauch–Tung–Striebel backward pass (:func:`gaussfuse.kalman.rts_step`):
    exact for ``"kf"``; with the transition re-linearised at each filtered
    belief for ``"ekf"``, ``"ukf"``, ``"ckf"`` and ``"ghkf"``. The iterated
    smoothers ``"iekf"`` and ``"iplf"`` make at most `iterations` passes,
    each a filter and RTS pass linearised about the previous pass's smoothed
    trajectory (the first about the iterated filter's), reaching back to the
    prior's time; they stop after the first pass in which no smoothed mean
    moved by more than `tol`, measured as in :func:`filter` (Notes) in the
    pass's predicted covariance of its step (the prior's at time 0). Their
    ``.filtered`` is the iterated filter, and ``.iterations`` the passes made.

    Returns
    -------
    SmoothResult
        ``.means`` (T, n), ``.covs`` (T, n, n), ``.gains`` (T-1, n, n) and
        ``.filtered``, the forward pass.

    Raises
    ------
    ValueError, TypeError, ModelFunctionError, numpy.linalg.LinAlgError, FloatingPointError
        As :func:`filter`; FloatingPointError also when a smoothed mean or
        covariance is not finite (at step k, the latest one of the backward
        pass).

    Warns
    -----
    ConvergenceWarning
        Once per call, when the iterated filter's steps or the smoother's
        passes stopped at `iterations` without meeting `tol`.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=[[1, 0], [0, 3]], R=10)
    >>> sm = gf.smooth(model, gf.Gaussian([0, 1], 500 * np.eye(2)), [1, 2, 3, 2, 1])
    >>> sm.means.shape, sm.filtered.means.shape
    ((5, 2), (5, 2))
    """
    spec, method, options, prior, zs, us, batch = _prepare(model, prior, zs, us, method, options)
    if prior == "diffuse":
        from .diffuse import diffuse_smooth

        results = [diffuse_smooth(model, z, None if us is None else us[i], engine) for i, z in enumerate(zs)]
        return _stack(results) if batch else results[0]
    compiled = _compiled_engine(spec, method, engine, zs.shape[0] * zs.shape[1])
    if compiled is not None:
        result = compiled.smooth(method, model, prior, zs, us, options)
        return result if batch else _first(result)
    runs = [_method_smooth(spec, model, prior, z, None if us is None else us[i], options)
            for i, z in enumerate(zs)]
    if spec.iterated:
        _warn_unconverged(method, options, sum(r[1] for r in runs), zs.shape[0] * zs.shape[1],
                          passes=sum(r[2] for r in runs), series=zs.shape[0])
    results = [r[0] for r in runs]
    return _stack(results) if batch else results[0]
