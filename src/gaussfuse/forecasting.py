r"""Forecasts: the model's predictions of states and measurements past a belief.

From a belief :math:`N(m_0, P_0)` (a filter's last one, say) the forecast
runs the prediction of the Kalman filter with no update, step after step,

.. math::

    m_j = A_j m_{j-1} + b_j, \qquad P_j = A_j P_{j-1} A_j^\top + Q_j, \qquad
    \hat z_j = H_j m_j + d_j, \qquad S_j = H_j P_j H_j^\top + R_j,

with each step's model made affine around the predicted belief by the
method's linearisation (exact for a LinearModel; Taylor or sigma points for
a NonlinearModel, whose regression error is part of :math:`Q_j` and
:math:`R_j`): :func:`gaussfuse.kalman.forecast` for the states, and
:func:`gaussfuse.kalman.predict` through the measurement map for the
measurements. These are the means and covariances of the states and of new
measurements, the measurement noise included.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from . import kalman
from ._frozen import reduce_frozen, shapes_repr
from ._linalg import marginal_std, wrap_components
from ._validation import integer
from .errors import STEP_ERRORS, at_step
from .gaussian import Gaussian
from .models.compose import TimedModel
from .inference.frames import ahead, measurement_names
from .inference.registry import linearisation, resolve_method
from .inference.results import FilterResult, SmoothResult
from .inference.timing import as_seconds, resolve, same_time
from .inference.validation import check_controls, check_model, check_prior

__all__ = ["forecast", "Forecast"]


@dataclass(frozen=True, eq=False)
class Forecast:
    """The output of :func:`forecast`; its arrays are read-only.

    Attributes
    ----------
    means : ndarray of shape (k, n)
        Predicted state means, one row per step ahead.
    covs : ndarray of shape (k, n, n)
        Their covariances.
    measurement_means : ndarray of shape (k, m)
        Predicted measurements.
    measurement_covs : ndarray of shape (k, m, m)
        Their covariances, the measurement noise included.
    index : array_like of shape (k,) or None
        The forecast steps' labels for :meth:`to_pandas`: `times` after the
        belief's, or the steps after a pandas input's index (see there).
    state_names, measurement_names : tuple of str or None
        The components' names, from the result forecast from, else the model's.
    """

    means: np.ndarray
    covs: np.ndarray
    measurement_means: np.ndarray
    measurement_covs: np.ndarray
    index: object = None
    state_names: tuple[str, ...] | None = None
    measurement_names: tuple[str, ...] | None = None

    __reduce__ = reduce_frozen
    __repr__ = shapes_repr

    def interval(self, level: float = 0.95, of: str = "measurements") -> tuple[np.ndarray, np.ndarray]:
        """The central `level` interval of each component: ``mean ± z σ`` with z the normal quantile.

        Parameters
        ----------
        level : float, default 0.95
            In (0, 1).
        of : {"measurements", "states"}, default "measurements"
            The intervals of the predicted measurements or of the states.

        Returns
        -------
        lower : ndarray of shape (k, m) or (k, n)
            ``mean - z σ``, of the measurements (m) or the states (n).
        upper : ndarray of shape (k, m) or (k, n)
            ``mean + z σ``.
        """
        if isinstance(level, bool) or not isinstance(level, (int, float, np.floating)) or not 0.0 < level < 1.0:
            raise ValueError(f"`level` must be a number in (0, 1); got {level!r}.")
        if not isinstance(of, str) or of not in ("measurements", "states"):
            raise ValueError(f"`of` must be 'measurements' or 'states'; got {of!r}.")
        means, covs = ((self.measurement_means, self.measurement_covs) if of == "measurements"
                       else (self.means, self.covs))
        z = -NormalDist().inv_cdf((1.0 - level) / 2.0)  # not inv_cdf(0.5 + level / 2): that rounds to 1 near 1
        half = z * marginal_std(covs)
        return means - half, means + half

    def to_pandas(self, of: str = "measurements", covariances: bool = False, names=None):
        """The forecast's means and standard deviations as a pandas DataFrame, one row per step ahead.

        Parameters
        ----------
        of : {"measurements", "states"}, default "measurements"
            The predicted measurements or the predicted states.
        covariances : bool, default False
            Also the covariances, one column ``cov_a_b`` per pair of components.
        names : sequence of str, optional
            The components' names (default: those of the pandas input or the
            model the belief came from, else the states' of `model`, else
            z0, z1, ... or x0, x1, ...).

        Returns
        -------
        pandas.DataFrame
            Columns ``name`` and ``name_sd`` per component. Its index is
            `times` after the belief's when the forecast was given them; else
            the steps that follow the index of the Series or DataFrame the
            belief was filtered from, where that index has a regular step
            (a frequency, a RangeIndex); else the steps ahead, 1 to k.
        """
        import pandas as pd

        from .inference.frames import Table, to_frame

        if not isinstance(of, str) or of not in ("measurements", "states"):
            raise ValueError(f"`of` must be 'measurements' or 'states'; got {of!r}.")
        if of == "measurements":
            means, covs, default, letter = (self.measurement_means, self.measurement_covs, self.measurement_names,
                                            "z")
        else:
            means, covs, default, letter = self.means, self.covs, self.state_names, "x"
        index = (pd.RangeIndex(1, means.shape[0] + 1, name="steps ahead") if self.index is None
                 else pd.Index(self.index))
        if names is None:
            names = default or tuple(f"{letter}{i}" for i in range(means.shape[1]))
        return to_frame(means, covs, Table(index, None), names, covariances, of[:-1])


def forecast(model, belief, steps: int | None = None, us=None, *, times=None, method: str | None = None,
             **options) -> Forecast:
    """Predict the states and measurements `steps` steps past a belief.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        Step j of the forecast (j = 1..`steps`) uses the model's matrices of
        step j - 1: a time-varying model describes the horizon, with at
        least `steps` steps.
    belief : Gaussian, FilterResult or SmoothResult
        The belief to forecast from; for a result of one series, its last
        belief (the filtered one, which is also the last smoothed one).
    steps : int, optional
        How many steps ahead, at least 1 (or `times`).
    us : array_like of shape (steps, p), optional
        Controls of the forecast steps, when the model has ``B`` (or its
        ``f`` takes them).
    times : array_like of shape (steps + 1,), optional
        The belief's time, then the times to forecast at (see
        :func:`gaussfuse.filter`'s `times`): a TimedModel
        (:func:`gaussfuse.model` without dt) is discretised for each step.
        From a result whose pandas index gave its times, the first must be
        the index's last entry.
    method : str, optional
        How a NonlinearModel is made affine (see :data:`gaussfuse.METHODS`;
        default "ukf"); a LinearModel's is exact.
    **options
        The method's options (``alpha``, ``order``, ...).

    Returns
    -------
    Forecast

    Raises
    ------
    TypeError, ValueError
        For a model or belief of the wrong kind, a belief of the wrong
        dimension, a batch result, bad `steps`, `times` or `us`, or a
        time-varying model shorter than `steps`.

    Notes
    -----
    See the module notes for the recursion. The iterated methods have
    nothing to iterate without measurements: they forecast as their
    one-pass forms.

    Examples
    --------
    >>> import numpy as np
    >>> import gaussfuse as gf
    >>> model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=2.0)
    >>> fc = gf.forecast(model, gf.Gaussian([0.0], [[1.0]]), steps=3)
    >>> fc.covs[:, 0, 0], fc.measurement_covs[:, 0, 0]
    (array([2., 3., 4.]), array([4., 5., 6.]))
    """
    check_model(model)
    sensed = measurement_names(model)  # (a TimedModel's, before it is discretised: audit DD6)
    if times is not None:
        if steps is not None:
            raise ValueError("give `steps` or `times`, not both: the number of steps is len(times) - 1.")
        steps = len(as_seconds("times", times)) - 1
        if steps < 1:
            raise ValueError("`times` must hold the belief's time and at least one time to forecast at.")
        _check_origin(belief, times)
        model, us = resolve(model, times, steps, us, rows=False)  # (no rows to take one step each: review R10)
    elif steps is None:
        import difflib

        typo = [f" (`{k}` for `{close[0]}`?)" for k in options for close in [difflib.get_close_matches(
            k, ["steps", "times"], n=1)] if close]  # (it was not named: review R10)
        raise TypeError("forecast() needs `steps` (how many steps ahead) or `times`" + "".join(typo) + ".")
    elif isinstance(model, TimedModel):
        raise ValueError("`times` is required: the model was built by gf.model(motion, sensor) without dt.")
    steps = integer("steps", steps)
    given, belief = belief, _last_belief(belief, model.n)
    spec, options = resolve_method(model, method, options, forecast)
    model_steps = getattr(model, "steps", None)
    if model_steps is not None and model_steps < steps:
        raise ValueError(f"the model is time-varying over {model_steps} steps, fewer than `steps` = {steps}.")
    us = check_controls(us, model, 1, steps, matching="`steps`")
    lin = linearisation(spec, model, None if us is None else us[0], options)[0]
    xa = _angles(model, "state_angles")
    za = _angles(model, "measurement_angles")
    n, m = model.n, model.m
    means, covs = np.empty((steps, n)), np.empty((steps, n, n))
    zmeans, zcovs = np.empty((steps, m)), np.empty((steps, m, m))
    mean, cov = belief.mean, belief.cov
    k = 0
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised, naming the step
            for k in range(steps):
                mean, cov = kalman.forecast(lin, k, mean, cov, xa)
                H, d, R = lin.measurement(k, mean, cov)
                zmean, zcov = kalman.predict(mean, cov, H, R, d)
                kalman.check_finite("predicted measurement", zmean, zcov)
                means[k], covs[k], zmeans[k], zcovs[k] = mean, cov, wrap_components(zmean, za), zcov
    except STEP_ERRORS as exc:
        raise at_step(exc, k) from exc
    for a in (means, covs, zmeans, zcovs):
        a.setflags(write=False)
    return Forecast(means, covs, zmeans, zcovs, *_labels(given, times, steps, n, m, getattr(model, "names", None),
                                                         sensed))


def _check_origin(belief, times) -> None:
    """`times[0]` must be the belief's time where the belief knows it: the last entry of the index that gave a
    pandas result its times. Only the future times would make the first step the gap between the first two of
    them, and the forecast one step short, silently (audit DD6)."""
    result = belief.filtered if isinstance(belief, SmoothResult) else belief
    table = getattr(result, "table", None)
    if table is None or not table.index_times:
        return
    last, first = table.index[-1], np.asarray(times.to_numpy() if hasattr(times, "to_numpy") else times).ravel()[0]
    if not same_time(last, first):
        raise ValueError(f"`times[0]` must be the belief's time, the last entry of zs.index ({last}); got {first}. "
                         "Give that time, then the times to forecast at.")


def _labels(belief, times, steps: int, n: int, m: int, names, sensed) -> tuple:
    """The forecast's index, state names and measurement names (see :class:`Forecast`): from `times` or the
    pandas input of the result `belief`, if any; the state names else the model's `names`, the measurement names
    else the model's `sensed`."""
    if isinstance(belief, SmoothResult):
        belief = belief.filtered
    result = belief if isinstance(belief, FilterResult) else None
    table = None if result is None else result.table
    if times is not None:
        index = times[1:]  # (a pandas Index only in to_pandas: pandas is optional)
    else:
        index = None if table is None else ahead(table.index, steps)

    def fitting(names, size: int):  # (the forecast's model may have another m, or n, than the filter's)
        return names if names is not None and len(names) == size else None

    columns = None if table is None else table.columns
    states = None if result is None else result.state_names
    return index, fitting(states, n) or names, fitting(columns, m) or fitting(sensed, m)


def _angles(model, name: str) -> np.ndarray | None:
    angles = getattr(model, name, None)
    return None if angles is None or not np.any(angles) else np.asarray(angles, dtype=bool)


def _last_belief(belief, n: int) -> Gaussian:
    """The Gaussian to forecast from: `belief` itself, or a one-series result's last belief."""
    if isinstance(belief, SmoothResult):
        belief = belief.filtered
    if isinstance(belief, FilterResult):
        if belief.last_mean.ndim != 1:
            raise ValueError(f"`belief` must be the result of one series; got a batch of {belief.last_mean.shape[0]} "
                             "(forecast each series from its own result).")
        belief = belief.last
    if not isinstance(belief, Gaussian):
        raise TypeError(f"`belief` must be a gaussfuse.Gaussian, FilterResult or SmoothResult; "
                        f"got {type(belief).__name__}.")
    return check_prior(belief, n, name="belief")
