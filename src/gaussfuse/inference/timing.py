"""Time stamps: seconds from any clock, the step sizes between them, and the model for those steps.

A series' `times` (float seconds, ``datetime64``, Python datetimes, or a
pandas DatetimeIndex, TimedeltaIndex or Series of them) are converted to
float seconds; a time zone is converted to UTC first. With T measurements,
`times` holds either their T times (the prior is then one step of
``times[1] - times[0]`` before the first) or T + 1 times, the prior's first.

A model built by :func:`gaussfuse.model` without ``dt`` (a
:class:`~gaussfuse.models.TimedModel`) is discretised exactly for each
step's own dt; a model with fixed matrices accepts only regular times, and
only at its own ``dt`` when it records one.
"""

from __future__ import annotations

import numpy as np

from ..models.compose import TimedModel
from .validation import check_measurements

__all__ = ["as_seconds", "step_sizes", "resolve"]


def as_seconds(name: str, times) -> np.ndarray:
    """`times` as float seconds (relative to the first for datetimes), a 1-D array.

    Raises
    ------
    TypeError
        For values that are not times or numbers.
    ValueError
        For a shape other than 1-D, or non-finite values.
    """
    tz = getattr(times, "tz", None) or getattr(getattr(times, "dt", None), "tz", None)
    if tz is not None:  # pandas, aware of a time zone: the same instants in UTC, without the zone
        times = (times.tz_convert("UTC") if hasattr(times, "tz_convert") else times.dt.tz_convert("UTC"))
        times = times.tz_localize(None) if hasattr(times, "tz_localize") else times.dt.tz_localize(None)
    if hasattr(times, "to_numpy"):
        times = times.to_numpy()
    arr = np.asarray(times)
    if arr.dtype == object:
        try:
            arr = arr.astype("datetime64[ns]")
        except (TypeError, ValueError):
            raise TypeError(f"`{name}` must be numbers (seconds) or times (datetime64, datetime, a pandas "
                            f"DatetimeIndex); got {type(arr.flat[0]).__name__ if arr.size else 'nothing'}.") from None
    if arr.ndim != 1:
        raise ValueError(f"`{name}` must be one-dimensional, one time per step; got shape {arr.shape}.")
    if arr.dtype.kind == "M":
        if np.isnat(arr).any():
            raise ValueError(f"`{name}` must not hold NaT (missing times).")
        ns = (arr - arr[0]).astype("timedelta64[ns]").astype(np.int64) if arr.size else np.zeros(0, np.int64)
        return ns / 1e9
    if arr.dtype.kind == "m":
        if np.isnat(arr).any():
            raise ValueError(f"`{name}` must not hold NaT (missing times).")
        return arr.astype("timedelta64[ns]").astype(np.int64) / 1e9
    if arr.dtype.kind not in "iuf" or arr.dtype.kind == "b":
        raise TypeError(f"`{name}` must be numbers (seconds) or times (datetime64, datetime, a pandas "
                        f"DatetimeIndex); got {arr.dtype} values.")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"`{name}` must be finite.")
    return arr


def step_sizes(name: str, times, T: int) -> np.ndarray:
    """The T step sizes (seconds) of a series of T measurements at `times` (T or T + 1 entries; see the module notes).

    Raises
    ------
    ValueError
        When `times` has neither T nor T + 1 entries, or is not strictly
        increasing (naming the first step that is not).
    """
    t = as_seconds(name, times)
    if t.shape[0] == T + 1:
        with np.errstate(over="ignore"):
            dts = np.diff(t)
    elif t.shape[0] == T and T >= 2:
        with np.errstate(over="ignore"):
            dts = np.diff(t)
        dts = np.concatenate([dts[:1], dts])
    else:
        more = " (with one measurement, give two: the prior's time, then the measurement's)" if T == 1 else ""
        raise ValueError(f"`{name}` must have {T} entries, one per measurement, or {T + 1} with the prior's time "
                         f"first{more}; got {t.shape[0]}.")
    bad = np.flatnonzero(~(dts > 0))
    if bad.size:
        k = int(bad[0])
        raise ValueError(f"`{name}` must be strictly increasing; step {k} has dt = {dts[k]:g} s.")
    if np.isinf(dts).any():
        k = int(np.flatnonzero(np.isinf(dts))[0])
        raise ValueError(f"`{name}` step {k} is longer than the largest float64 (dt = inf s): times so far apart "
                         "cannot be stepped.")
    return dts


def resolve(model, times, zs, us=None, name: str = "times"):
    """The model to filter `zs` with at `times`, and its controls.

    A :class:`TimedModel` becomes the model of its steps (exactly
    discretised for each dt); a model with fixed matrices is returned as it
    is, once `times` are found regular (and at its ``dt``, if it has one).

    Raises
    ------
    ValueError
        A TimedModel without `times`; irregular `times` for a model with fixed
        matrices; regular `times` at another dt than the model's.
    """
    timed = isinstance(model, TimedModel)
    if times is None:
        if timed:
            raise ValueError("`times` is required: the model was built by gf.model(motion, sensor) without dt, "
                             "so it is discretised for each step's own time step.")
        return model, us
    T = zs if isinstance(zs, int) else check_measurements(zs, model.m).shape[1]
    dts = step_sizes(name, times, T)
    if timed:
        return model.at(dts, us)
    low, high = float(dts.min()), float(dts.max())
    if high - low > 1e-9 * high:
        raise ValueError(
            f"`{name}` are irregular (steps from {low:g} s to {high:g} s) but the model's matrices are fixed; build "
            "it with gf.model(motion, sensor) without dt, which discretises each step for its own dt.")
    dt = getattr(model, "dt", None)
    if dt is not None and abs(low - dt) > 1e-9 * dt:
        raise ValueError(f"`{name}` step by {low:g} s but the model is for dt = {dt:g} s; build it for the times' "
                         "step, or with gf.model(motion, sensor) without dt.")
    return model, us
