"""Validators of the filters' and smoothers' input: each checks a value and hands it back.

Messages name the argument in backticks, the expected shape and what was
given (:func:`gaussfuse._validation.shape_error`).
"""

from __future__ import annotations

import numpy as np

from .._linalg import indefinite, negative_weight
from .._validation import as_array, flag, shape_error
from ..gaussian import Gaussian
from ..models.compose import TimedModel
from ..models.linear import LinearModel
from ..models.motion import LinearMotion, NonlinearMotion
from ..models.nonlinear import NonlinearModel
from ..models.sensors import LinearSensor, NonlinearSensor
from .registry import FORMS, METHODS, resolve_method

__all__ = ["check_model", "check_prior", "check_measurements", "check_controls", "check_steps", "check_form", "check_steady",
           "prepare"]


def check_model(model) -> None:
    """`model` must be a LinearModel, a NonlinearModel or a TimedModel (what :func:`gaussfuse.model` makes)."""
    if not isinstance(model, (LinearModel, NonlinearModel, TimedModel)):
        part = ("motion" if isinstance(model, (LinearMotion, NonlinearMotion)) else
                "sensor" if isinstance(model, (LinearSensor, NonlinearSensor)) else None)
        hint = (f" (a {part} model: gaussfuse.model(motion, sensor) makes the model of both, or of a motion and a "
                "dict of named sensors)") if part else ""
        raise TypeError(f"`model` must be a gaussfuse.LinearModel, NonlinearModel or TimedModel; "
                        f"got {type(model).__name__}{hint}.")


def check_prior(prior, n: int, *, diffuse_ok: bool = False, name: str = "prior") -> Gaussian | str:
    """Check that `prior` (the argument `name`) is a Gaussian over the n-dimensional state (or "diffuse", where allowed)."""
    if diffuse_ok and isinstance(prior, str) and prior == "diffuse":
        return prior
    if not isinstance(prior, Gaussian):
        also = " or 'diffuse'" if diffuse_ok else ""
        shown = repr(prior) if isinstance(prior, str) else type(prior).__name__
        raise TypeError(
            f"`{name}` must be a gaussfuse.Gaussian(mean, cov){also}; got {shown}."
        )
    if prior.dim != n:
        raise ValueError(f"`{name}` must have dimension {n} (the model's state); got {prior.dim}.")
    return prior


def check_measurements(zs, m: int, one: bool = False) -> np.ndarray:
    """Return `zs` as an array (N, T, m); NaN (or a masked entry of a masked array) marks a missing component.

    With `one`, `zs` must be one series, (T, m) or (T,).
    """
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
    if arr.ndim != 3 or arr.shape[-1] != m or arr.shape[1] == 0 or arr.shape[0] == 0 or one and len(given) == 3:
        expected = f"(T, {m}){' or (T,)' if m == 1 else ''}" + (
            " (one series), with T >= 1" if one else f", or (N, T, {m}) for N series, with T >= 1 and N >= 1")
        raise shape_error("zs", expected, given)
    return arr


def check_controls(us, model, N: int, T: int, matching: str = "`zs`") -> np.ndarray | None:
    """Return `us` as an array (N, T, p), or None when there are no controls.

    A LinearModel needs controls exactly when it has ``B``; for a
    NonlinearModel they are optional and passed to ``f(x, u)``.
    """
    p = getattr(model, "p", None)  # a NonlinearModel's, when it knows its f's controls
    if p == 0 and us is not None:
        raise ValueError("`us` was given but the model has no control input"
                         + ("; give the model `B`." if isinstance(model, LinearModel) else "."))
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
        raise shape_error("us", f"(T, p) = ({T}, {shown}) or ({N}, {T}, {shown}), matching {matching}",
                          np.shape(us))
    return np.broadcast_to(arr, (N, *arr.shape[1:]))


def check_steps(model, T: int, counted: str = "`zs` has") -> None:
    """A time-varying model's steps against the T steps `counted` ("`zs` has", or the argument that asks)."""
    steps = getattr(model, "steps", None)
    if steps is not None and steps != T:
        raise ValueError(
            f"the model is time-varying over {steps} steps but {counted} {T} steps; they must agree."
        )


def check_form(spec, form) -> None:
    """`form` must be one of FORMS, and one that `spec`'s method runs in."""
    if not isinstance(form, str) or form not in FORMS:
        raise ValueError(f"`form` must be one of {list(FORMS)}; got {form!r}.")
    if form not in spec.forms:
        runs = sorted(name for name, m in METHODS.items() if form in m.forms)
        raise ValueError(f"`form={form!r}` is not available for method {spec.name!r}; it is for {runs} "
                         "(the iterated methods re-linearise within a step, which the square-root step does not).")


def check_steady(steady, spec, form: str, prior, model, timed: bool) -> None:
    """`steady` must be a bool, and True only for the Kalman filter in the covariance form, with a Gaussian prior,
    and not for a TimedModel (`timed`) at times of unequal steps (`model` as they discretised it)."""
    flag("steady", steady)
    if steady and (spec.name != "kf" or form != "cov" or isinstance(prior, str)):
        raise ValueError("`steady=True` is for method 'kf' in the covariance form with a Gaussian prior; got "
                         f"method {spec.name!r}, form {form!r}" + (", a 'diffuse' prior." if isinstance(prior, str)
                                                                   else "."))
    if steady and timed and np.ndim(model.F) == 3:  # (audit DD3: the message named a time axis)
        raise ValueError("`steady=True` needs one time step, and the steps between the times (`times`, or the "
                         "index of `zs`) are irregular: each step has its own F and Q, so the filter has no steady "
                         "state.")


def prepare(model, prior, zs, us, method, options, form: str = "cov", caller=None):
    spec, options = resolve_method(model, method, options, caller)
    check_form(spec, form)
    if form != "cov" and isinstance(prior, str) and prior == "diffuse":
        raise ValueError(f"a 'diffuse' prior is for the covariance form; with `form={form!r}` give a Gaussian "
                         "prior (a large covariance, say 1e12 I, is what the square-root form handles well).")
    prior = check_prior(prior, model.n, diffuse_ok=spec.name == "kf")
    checked = check_measurements(zs, model.m)
    batch = np.ndim(zs) == 3  # only after the check: a ragged `zs` must not reach NumPy
    zs = checked
    N, T = zs.shape[:2]
    check_steps(model, T)
    us = check_controls(us, model, N, T)
    return spec, options, prior, zs, us, batch


def check_semidefinite(lin, covs: np.ndarray, stage: str, step, last: bool = False) -> None:
    """Raise LinAlgError naming the first (or `last`) `stage` covariance of `covs` ((N,) T, n, n) that is not
    positive semi-definite, where `lin`'s sigma-point rule weighs a point negatively; `step(k)` names step k."""
    rule = getattr(lin, "rule", None)
    if rule is None or rule.wc.min() >= 0.0:
        return
    covs = covs if covs.ndim == 4 else covs[None]
    bad = indefinite(covs)
    if bad.any():
        s = int(np.flatnonzero(bad.any(axis=1))[0])
        k = int(np.flatnonzero(bad[s])[-1 if last else 0])
        vals = np.linalg.eigvalsh(covs[s, k])
        where = f"in series {s}, " if covs.shape[0] > 1 else ""
        raise np.linalg.LinAlgError(
            f"{where}at step {step(k)}: the {stage} covariance is not positive semi-definite "
            f"(smallest eigenvalue {vals[0]:.3g}, largest {vals[-1]:.3g}){negative_weight(rule.wc)}.")
