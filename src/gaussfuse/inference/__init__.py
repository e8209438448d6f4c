"""Filtering and smoothing: the front functions ``filter()`` and ``smooth()``.

They validate their input (:mod:`~gaussfuse.inference.validation`), pick a
method from the registry (:mod:`~gaussfuse.inference.registry`) and run it
over one series or, for a leading series axis, over each series
(:mod:`~gaussfuse.inference.drivers`; a diffuse prior through
:mod:`~gaussfuse.inference.diffuse`). The algebra of every step is in
:mod:`gaussfuse.kalman`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import kalman
from .._validation import flag
from ..gaussian import Gaussian
from ..models.compose import TimedModel
from . import chunked, diffuse, drivers, frames, timing
from .registry import METHODS
from .results import KEEP, FilterResult, SmoothResult, first, kept, stack
from .validation import check_model, check_steady, prepare

__all__ = ["filter", "smooth", "FilterResult", "SmoothResult", "METHODS"]


def filter(model, prior: Gaussian | str, zs, us=None, method: str | None = None, *,
           engine: str = "auto", keep: str = "all", form: str = "cov", steady: bool = False,
           gains: bool = False, check: str = "warn", gate: float | None = None, gate_by: str = "measurement",
           times=None, **options) -> FilterResult:
    r"""Filter a series of measurements: the belief about each state given the past.

    Parameters
    ----------
    model : LinearModel, NonlinearModel or TimedModel
        The state-space model; a :class:`~gaussfuse.models.TimedModel`
        (:func:`gaussfuse.model` without dt) is discretised for each step's
        own time step, from `times`.
    prior : Gaussian or "diffuse"
        Belief about the state one step *before* the first measurement;
        every step is predict (with ``u_k``), then update (with ``z_k``).
        ``"diffuse"`` (linear models) makes the first state x₁ diffuse (a
        flat prior, handled exactly: :mod:`gaussfuse.inference.diffuse`), as Durbin &
        Koopman, KFAS and statsmodels do, so the transition into x₁ plays no
        part; beliefs are NaN until the measurements identify the state,
        and `loglik` is the exact diffuse log-likelihood, equal to Durbin &
        Koopman's and statsmodels' for every F whose measurements identify
        x₁ (else NotIdentified); KFAS's leaves out the ½ log 2π of the
        observations that identify x₁.
    zs : array_like of shape (T, m), (T,) when m = 1, or (N, T, m)
        Measurements; a NaN component (or a masked entry of a masked array)
        is missing. A leading axis holds N independent series, and every
        result then gains that axis. A dask array (N, T, m), chunked over
        series, is filtered chunk by chunk as a Dask graph: the result's
        arrays are dask arrays with its chunks, computed when asked
        (:mod:`gaussfuse.inference.chunked`; `us` then a dask array
        chunked over series as `zs` is, or an array in memory, chunked so).
        A pandas Series or DataFrame gives its index as `times` (see
        :mod:`gaussfuse.inference.frames`); its columns are taken by name
        where they are a TimedModel's sensor's names in another order or
        case (some of them and not all is an error), else in order (a LinearModel
        names no measurements), and a pandas `us` must have its index.
    us : array_like of shape (T, p), (T,) when p = 1, or (N, T, p), optional
        Control inputs: required exactly when a LinearModel has ``B``;
        passed to a NonlinearModel's ``f(x, u_k)`` when given.
    method : str, optional
        One of ``METHODS``: ``"kf"`` (the default for a LinearModel) or,
        for a NonlinearModel, ``"ekf"``, ``"iekf"``, ``"ukf"`` (default),
        ``"ckf"``, ``"ghkf"`` or ``"iplf"``.
    engine : {"auto", "python", "numba"}, default "auto"
        ``"python"`` is the readable implementation, the specification;
        ``"numba"`` runs compiled kernels (methods "kf", with series in
        parallel, and "ukf", "ckf", "ghkf", whose whole loop is compiled when
        f and h are numba-jitted functions), equal to it to round-off; ``"auto"``
        takes the compiled path when numba is installed, the series have at
        least 1000 steps in all, and compiling the kernels (or loading them
        from numba's disk cache) is expected to cost less than the readable
        path would take (see :func:`gaussfuse.inference.drivers.compiled_engine`).
    keep : {"all", "means", "last"}, default "all"
        What to return per step: everything; the means, predictions and
        innovations but no covariances; or nothing but the final belief
        (``last_mean``, ``last_cov``) and the log-likelihood, so memory does
        not grow with T.
    form : {"cov", "sqrt"}, default "cov"
        ``"cov"`` propagates covariances (the Joseph-form update);
        ``"sqrt"`` propagates their Cholesky factors by orthogonal (QR)
        transformations (:func:`gaussfuse.kalman.update_sqrt`), for
        problems where the covariance form loses its accuracy: a huge
        prior with a precise sensor, states on very different scales. The
        result then also holds ``cov_factors``. For the one-pass methods
        "kf", "ekf", "ukf", "ckf" and "ghkf": the sigma-point methods
        regress on the factor (:func:`gaussfuse.linearize.slr_sqrt`) and
        downdate it, by hyperbolic rotations, where a weight is negative
        (the unscented rule's centre past three states).
        ``engine="numba"`` runs the "kf", "ukf", "ckf" and "ghkf" filters
        and smoothers compiled (a sigma-point call that meets a singular
        factor, or a downdate that fails, runs on the readable path, which
        takes the least-squares regression or raises the error); ``"auto"``
        takes the readable path; a ``"diffuse"`` prior is for the
        covariance form.
    steady : bool, default False
        The steady-state filter, for a time-invariant LinearModel (method
        "kf", covariance form): once a step's filtered covariance is within
        ``kalman.STEADY_TOL`` (1e-10, relative to the variances) of the
        stationary one (:func:`gaussfuse.steady_state`), that step's gain
        and covariances are reused and only the means are computed. The
        covariances and gains equal the full filter's to about 1e-10 after
        that point, the means to about 1e-9 of the innovations' size (on 20
        random 4-state models, up to 9e-10 standard deviations with
        innovations of about one, 9e-8 with innovations of 100), the
        log-likelihood accordingly; sooner than the
        default, which holds the covariance only once it stops changing to
        round-off (see :class:`gaussfuse.kalman.SteadyState`). Steps with
        missing components are computed in full, from the stationary
        prediction: where few components are observed that difference can
        grow (1.8e-9 of the variances measured, with 1 of 3 observed) and
        decays again over the next steps.
    gains : bool, default False
        Also return the Kalman gain of each step, ``FilterResult.gains``
        (T, n, m), on the readable path (not with ``keep="last"``).
    check : {"warn", "raise", "off"}, default "warn"
        The divergence test: when the normalised innovations
        (``FilterResult.nis``) of a window of 50 steps are too large for the
        filter's own covariances (a χ² test that a consistent filter fails
        with probability at most 1e-3 per call:
        :func:`gaussfuse.diagnostics.divergence`; with a `gate`, also where
        it rejected at least half of a window, which a gated filter of its
        own model can do by itself: :class:`gaussfuse.kalman.Gate`), issue a
        :class:`gaussfuse.DivergenceWarning` naming the steps, raise it, or
        do nothing. Not made with ``keep="last"`` (no per-step values); with
        a ``"diffuse"`` prior, made from the step after the state is
        identified.
    gate : float, optional
        Outlier gating at this chi-square probability (0.99, say): a
        measurement whose normalised innovation squared is beyond the
        quantile of :math:`\chi^2_{|o|}` is treated as missing, and
        ``FilterResult.rejected`` (T, m) says which were
        (:class:`gaussfuse.kalman.Gate`). On the readable path.
    gate_by : {"measurement", "component"}, default "measurement"
        Gate the whole measurement, or each component on its own
        (:math:`v_i^2 / S_{ii}` against :math:`\chi^2_1`).
    times : array_like of shape (T,) or (T + 1,), optional
        The measurements' times: float seconds, dates (``datetime64``,
        datetimes, a pandas DatetimeIndex; time zones taken to UTC) or
        durations (``timedelta64``, timedeltas, a pandas TimedeltaIndex);
        with T + 1, the prior's time first, otherwise the prior is one step
        of ``times[1] - times[0]`` before the first
        (:mod:`gaussfuse.inference.timing`). Required by a TimedModel; a
        model with fixed matrices takes only regular times (at its ``dt``,
        if it records one), and says how to fix irregular ones.
    **options
        Method options: ``iterations`` (iekf, iplf: the most update
        iterations per step, default 50) and ``tol`` (iekf, iplf: default
        1e-9; see Notes); ``alpha``, ``beta``, ``kappa`` (ukf; defaults 1, 0,
        3 - n); ``order`` (ghkf, iplf: Gauss–Hermite points per axis,
        default 3). An unknown one is rejected with the list of valid ones.

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
        That happens when a component measured without noise (R = 0 there)
        meets a state that earlier measurements already determine exactly
        (no process noise): S is then zero only to round-off, so round-off
        decides the step that raises, and where it leaves S slightly
        positive, the filter goes on with log-likelihood terms that
        round-off sets, on either engine. Give R a variance above round-off.
    FloatingPointError
        When a step's predicted or filtered mean, covariance or log-likelihood
        term is not finite: the computation overflowed (say a transition of
        1e200, or measurements near 1e308). The message names the step ("in
        series s, at step k" for a batch in the compiled linear engine).
        Both engines check the same values: the mean, the diagonal of the
        covariance and the log-likelihood term.
    gaussfuse.inference.diffuse.NotIdentified
        (a ValueError) With ``prior="diffuse"``, when the measurements do not
        determine every component of x₁ (one that F removes before any
        measurement sees it, say).

    Warns
    -----
    ConvergenceWarning
        Once per call, when steps of an iterated method made `iterations`
        passes without meeting `tol`; it says how many.
    DivergenceWarning
        When the divergence test fails (see `check`).

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
    its round-off, :math:`4 \varepsilon \max(|x|, |m^-|)`, counts as
    unchanged), or after
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
    if chunked.is_dask(zs):
        drivers.checked(check)
        return chunked.map_series(filter, zs, us, dict(
            model=model, prior=prior, method=method, engine=engine, keep=keep, form=form, steady=steady,
            gains=gains, check=check, gate=gate, gate_by=gate_by, times=times, **options))
    timed = isinstance(model, TimedModel)
    model, zs, us, table, names = _inputs(model, zs, us, times, steady)
    spec, options, prior, zs, us, batch = prepare(model, prior, zs, us, method, options, form, filter)
    check_steady(steady, spec, form, prior, model, timed)
    gains = flag("gains", gains)
    if gains and prior == "diffuse":
        raise ValueError("`gains=True` is not available with a 'diffuse' prior.")
    if gains and keep == "last":
        raise ValueError("`gains=True` keeps each step's gain, which keep='last' does not keep: pass keep='all' or "
                         "'means'.")
    gate = _gate(gate, gate_by, prior)
    drivers.checked(check)
    if prior == "diffuse":
        result = stack(drivers.each_series(
            lambda i: kept(diffuse.diffuse_filter(model, zs[i], None if us is None else us[i], engine), keep),
            zs.shape[0]))
    else:
        result = drivers.filter_batch(spec, model, prior, zs, us, options, engine, keep, form, steady, gains, gate)
    drivers.check_divergence(result, check, gate=gate)
    return _labelled(result, None, names) if batch else _labelled(first(result), table, names)  # (a batch's too: DD6)


def smooth(model, prior: Gaussian | str, zs, us=None, method: str | None = None, *,
           engine: str = "auto", form: str = "cov", check: str = "warn", gate: float | None = None,
           gate_by: str = "measurement", times=None, **options) -> SmoothResult:
    """Smooth a series of measurements: the belief about each state given all of them.

    Every method ends in the
    Rauch–Tung–Striebel backward pass (:func:`gaussfuse.kalman.rts_step`):
    exact for ``"kf"``; with the transition re-linearised at each filtered
    belief for ``"ekf"``, ``"ukf"``, ``"ckf"`` and ``"ghkf"``. The iterated
    smoothers ``"iekf"`` and ``"iplf"`` make at most `iterations` passes,
    each a filter and RTS pass linearised about the previous pass's smoothed
    trajectory (the first about the iterated filter's), reaching back to the
    prior's time; they stop after the first pass in which no smoothed mean
    moved by more than `tol`, measured as in :func:`filter` (Notes) in the
    pass's predicted covariance of its step (the prior's at time 0), or once
    a pass moves them by at most 1e-10 standard deviations and no less than
    the pass before (round-off: so ``tol=0`` runs to the fixed point). With
    ``iterations=1`` they are the plain smoothers of their filters (the
    extended and Gauss–Hermite RTS smoothers). Their ``.filtered`` is the
    iterated filter, and ``.iterations`` the passes made.
    `check` tests the forward pass's innovations as in :func:`filter`.
    With ``form="sqrt"`` the backward pass runs on Cholesky factors
    (:func:`gaussfuse.kalman.rts_step_sqrt`), and the result holds them in
    ``cov_factors``.

    Parameters
    ----------
    model : LinearModel, NonlinearModel or TimedModel
        As for :func:`filter`.
    prior : Gaussian or "diffuse"
        As for :func:`filter`.
    zs : array_like of shape (T, m), (T,) when m = 1, or (N, T, m)
        As for :func:`filter` (pandas and dask arrays too).
    us : array_like of shape (T, p) or (N, T, p), optional
        As for :func:`filter`.
    method : str, optional
        As for :func:`filter`; the smoother of that method.
    engine : {"auto", "python", "numba"}, default "auto"
        As for :func:`filter`.
    form : {"cov", "sqrt"}, default "cov"
        As for :func:`filter`; "sqrt" smooths on Cholesky factors.
    check : {"warn", "raise", "off"}, default "warn"
        The divergence test of the forward pass, as for :func:`filter`.
    gate : float, optional
        As for :func:`filter`: what the forward pass rejects, the backward
        pass leaves out too.
    gate_by : {"measurement", "component"}, default "measurement"
        As for :func:`filter`.
    times : array_like, optional
        As for :func:`filter`.
    **options
        Method options, as for :func:`filter`.

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
    if chunked.is_dask(zs):
        drivers.checked(check)
        return chunked.map_series(smooth, zs, us, dict(
            model=model, prior=prior, method=method, engine=engine, form=form, check=check, gate=gate,
            gate_by=gate_by, times=times, **options))
    model, zs, us, table, names = _inputs(model, zs, us, times)
    spec, options, prior, zs, us, batch = prepare(model, prior, zs, us, method, options, form, smooth)
    gate = _gate(gate, gate_by, prior)
    drivers.checked(check)
    if prior == "diffuse":
        result = stack(drivers.each_series(
            lambda i: diffuse.diffuse_smooth(model, zs[i], None if us is None else us[i], engine), zs.shape[0]))
    else:
        result = drivers.smooth_batch(spec, model, prior, zs, us, options, engine, form=form, gate=gate)
    drivers.check_divergence(result.filtered, check, gate=gate)
    if batch:
        return replace(result, filtered=_labelled(result.filtered, None, names))
    result = first(result)
    return replace(result, filtered=_labelled(result.filtered, table, names))


def _inputs(model, zs, us, times, steady: bool = False):
    """A pandas `zs` unpacked and a TimedModel discretised at `times`: ``(model, zs, us, table, state names)``;
    with `steady`, at regular times for their one step (:func:`~.timing.resolve`)."""
    check_model(model)  # (before `model` is read: its message names a TimedModel, and a motion's remedy: audit GG6)
    zs, times, table = frames.unpack(zs, times, model)
    us = frames.controls(us, table)
    names = getattr(model, "names", None)
    model, us = timing.resolve(model, times, zs, us, name="times" if table is None else table.times_name,
                               one_step=isinstance(steady, (bool, np.bool_)) and bool(steady))
    return model, zs, us, table, names


def _labelled(result: FilterResult, table, names) -> FilterResult:
    """`result` carrying a pandas input's index and columns and the state names, for to_pandas()."""
    return result if table is None and names is None else replace(result, table=table, state_names=names)


def _gate(gate, gate_by: str, prior) -> kalman.Gate | None:
    """The Gate of `gate` and `gate_by` (checked), or None."""
    if gate is not None and prior == "diffuse":
        raise ValueError("`gate` is not available with a 'diffuse' prior.")
    return kalman.Gate.of(gate, gate_by)
