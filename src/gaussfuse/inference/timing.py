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

import datetime
from typing import NamedTuple

import numpy as np

from ..models.compose import TimedModel
from .validation import check_measurements

__all__ = ["as_seconds", "as_instants", "same_time", "step_sizes", "steps", "Steps", "round_off", "resolve", "stamp",
           "within", "ticks", "elapsed", "finest", "per_second", "since"]


_FINE = ("s", "ms", "us", "ns", "ps", "fs", "as")
"""The datetime64 units of at most a second, each 1000 times finer than the one before."""


def finest(units) -> str:
    """The finest of datetime64 `units` (each one of :data:`_FINE`)."""
    return max(units, key=_FINE.index)


def per_second(unit: str) -> int:
    """How many of `unit` (one of :data:`_FINE`) make a second."""
    return 1000 ** _FINE.index(unit)


def stamp(name: str, value) -> np.datetime64 | None:
    """A datetime (``datetime``, ``numpy.datetime64``, ``pandas.Timestamp``) as a naive UTC datetime64, else None.

    The value keeps its own resolution: a Timestamp's nanoseconds, a
    datetime's microseconds, a datetime64's unit (calendar units, years to
    minutes, as seconds), so no year is wrapped through another unit.

    Raises
    ------
    ValueError
        For NaT, naming `name`.
    """
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if hasattr(value, "tz_localize"):  # a pandas Timestamp (or NaT)
        if value != value:
            raise ValueError(f"`{name}` must be a time; got {value!r}.")
        if value.tzinfo is not None:
            value = value.tz_convert("UTC").tz_localize(None)
        return value.to_datetime64()
    if isinstance(value, datetime.datetime):
        if value.tzinfo is not None:  # aware: the same instant in UTC
            value = value.astimezone(datetime.timezone.utc).replace(tzinfo=None)
        return np.datetime64(value, "us")
    if isinstance(value, np.datetime64):
        if np.isnat(value):
            raise ValueError(f"`{name}` must be a time; got {value!r}.")
        unit = np.datetime_data(value.dtype)[0]
        return within(name, value, unit if unit in _FINE else "s")
    return None


def within(name: str, values, unit: str):
    """Datetime64 (or timedelta64) `values` in `unit` (one of :data:`_FINE`), exactly.

    Raises
    ------
    ValueError
        When a value is not a whole number of `unit` or lies outside the
        years that unit's int64 holds (NumPy's cast wraps them silently).
    """
    values = np.asarray(values)
    kind = "datetime64" if values.dtype.kind == "M" else "timedelta64"

    def cast(a, dtype):
        try:
            return a.astype(dtype)
        except OverflowError:  # NumPy's conversion factor itself overflows (seconds and attoseconds): through ms
            return a.astype(f"{kind}[ms]").astype(dtype)  # (reviews R36, R37)

    try:
        out = cast(values, f"{kind}[{unit}]")
        bad = np.flatnonzero(np.isnat(out).ravel() | (cast(out, values.dtype) != values).ravel())
    except OverflowError:
        out, bad = values, np.arange(values.size)
    if bad.size:
        shown = values.ravel()[bad[0]]
        raise ValueError(f"`{name}` holds {shown}, which {kind}[{unit}] (the finest resolution among the times) "
                         "cannot hold exactly: give the times in one resolution, within the years it holds.")
    return out[()] if out.ndim == 0 else out


def ticks(name: str, stamps: np.ndarray) -> tuple[np.ndarray, int]:
    """Datetime64 or timedelta64 `stamps` as int64 counts of their unit (at most a second), and the counts per second."""
    unit = np.datetime_data(stamps.dtype)[0]
    if unit not in _FINE:
        unit = "s"
        stamps = within(name, stamps, unit)
    return stamps.astype(f"{stamps.dtype.kind}8[{unit}]").astype(np.int64), per_second(unit)


def elapsed(counts: np.ndarray, per_second: int) -> np.ndarray:
    """The seconds between consecutive int64 `counts` (of ``1 / per_second`` s), each rounded once from the exact difference."""
    steps = np.diff(counts)
    wrapped = (steps < 0) != (counts[1:] < counts[:-1])  # an int64 difference past 2**63
    if wrapped.any() or np.abs(steps).max(initial=0) > 2**53:  # not exact in float64: in Python ints
        whole = counts.tolist()
        return np.array([(b - a) / per_second for a, b in zip(whole[:-1], whole[1:])], dtype=np.float64)
    return steps.astype(np.float64) / per_second


def _naive_utc(times):
    """A pandas Series or DatetimeIndex aware of a time zone as the same instants in UTC, without the zone."""
    values = getattr(times, "dt", None)  # a pandas Series of datetimes: its values (tz_convert would convert its index)
    if values is not None and getattr(values, "tz", None) is not None:
        return values.tz_convert("UTC").dt.tz_localize(None)
    if values is None and getattr(times, "tz", None) is not None:  # a DatetimeIndex aware of a time zone
        return times.tz_convert("UTC").tz_localize(None)
    return times


def as_instants(name: str, times) -> np.ndarray | None:
    """`times` as a datetime64 or timedelta64 array when they are dates or durations (a zone as UTC), else None.

    Raises
    ------
    ValueError
        For NaT, naming `name`.
    """
    if isinstance(times, (str, bytes)):
        return None
    arr = _array(times)
    if arr.dtype == object:
        read = _stamps(name, arr.ravel())
        spans = [_span(f"{name}[{i}]", v) for i, v in enumerate(arr.ravel().tolist())]
        if read and all(v is not None for v in read):
            arr = _in_one_unit(name, read).reshape(arr.shape)
        elif spans and all(v is not None for v in spans):
            arr = _in_one_unit(name, spans).reshape(arr.shape)
        else:
            return None
    if arr.dtype.kind not in "Mm":
        return None
    return _without_nat(name, arr)


def same_time(a, b) -> bool:
    """Whether `a` and `b` are one time: both numbers of seconds, both datetimes or both durations (in any unit; a
    zone as UTC), equal; False for two kinds, or anything that is not a time."""
    read = []
    for value in (a, b):
        arr = np.array([value.to_numpy() if hasattr(value, "to_numpy") else value])  # pandas' as NumPy's (zone: UTC)
        try:
            instants = as_instants("times", arr)
            values, per_second = _clock("times", arr)
        except (TypeError, ValueError):
            return False
        read.append((None if instants is None else instants.dtype.kind, values[0], per_second))
    (kind_a, x, per_a), (kind_b, y, per_b) = read
    if kind_a != kind_b:
        return False
    return bool(x == y) if per_a is None else int(x) * per_b == int(y) * per_a  # (exact across units)


def _array(times) -> np.ndarray:
    """`times` as a NumPy array (pandas' values; a time zone as UTC)."""
    times = _naive_utc(times)
    return np.asarray(times.to_numpy() if hasattr(times, "to_numpy") else times)


def _stamps(name: str, arr: np.ndarray) -> list:
    """Each entry of a 1-D object array as a naive UTC datetime64 (:func:`stamp`), or None where it is not a time."""
    return [stamp(f"{name}[{i}]", v) for i, v in enumerate(arr.tolist())]


def _span(name: str, value) -> np.timedelta64 | None:
    """A duration (``datetime.timedelta``, ``numpy.timedelta64``, ``pandas.Timedelta``) as a timedelta64, else None."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if hasattr(value, "to_timedelta64"):  # a pandas Timedelta (its NaT is pandas' NaT, a time: see stamp)
        value = value.to_timedelta64()
    elif isinstance(value, datetime.timedelta):
        value = np.timedelta64(value)
    if not isinstance(value, np.timedelta64):
        return None
    if np.isnat(value):
        raise ValueError(f"`{name}` must be a time; got {value!r}.")
    unit = np.datetime_data(value.dtype)[0]
    return within(name, value, unit if unit in _FINE else "s")


def _in_one_unit(name: str, read: list) -> np.ndarray:
    """Datetime64 (or timedelta64) values in the finest of their units, exactly (:func:`within`)."""
    unit = finest(np.datetime_data(v.dtype)[0] for v in read)
    return np.array([within(f"{name}[{i}]", v, unit) for i, v in enumerate(read)])


def _without_nat(name: str, arr: np.ndarray) -> np.ndarray:
    if np.isnat(arr).any():
        raise ValueError(f"`{name}` must not hold NaT (missing times).")
    return arr


_KINDS = ("numbers (seconds), times (datetime64, datetime, a pandas DatetimeIndex) or durations (timedelta64, "
          "timedelta, a pandas TimedeltaIndex)")


def _clock(name: str, times) -> tuple[np.ndarray, int | None]:
    """`times` as a 1-D array: float seconds (and None), or int64 counts of a datetime64/timedelta64 unit and the counts per second.

    Raises
    ------
    TypeError
        For values that are not times or numbers.
    ValueError
        For a shape other than 1-D, or non-finite values.
    """
    if isinstance(times, (str, bytes)):  # not a 0-d array of characters
        raise TypeError(f"`{name}` must be {_KINDS}, one per step; got {type(times).__name__} {times!r}.")
    arr = _array(times)
    if arr.ndim != 1:
        raise ValueError(f"`{name}` must be one-dimensional, one time per step; got shape {arr.shape}.")
    if arr.dtype == object:
        items = arr.tolist()
        read = _stamps(name, arr)
        spans = [_span(f"{name}[{i}]", v) for i, v in enumerate(items)]
        kinds = ["time" if r is not None else "duration" if d is not None else "number"
                 if not isinstance(v, (bool, np.bool_)) and isinstance(v, (int, float, np.integer, np.floating))
                 else None for v, r, d in zip(items, read, spans)]
        if not arr.size or None in kinds or len(set(kinds)) > 1:
            bad = next((i for i, k in enumerate(kinds) if k is None), None)
            if bad is None and arr.size:  # kinds mixed: the first that differs from the first
                bad = next(i for i, k in enumerate(kinds) if k != kinds[0])
            got = "nothing" if bad is None else f"{type(arr[bad]).__name__} at `{name}[{bad}]`"
            raise TypeError(f"`{name}` must be {_KINDS}, all of one kind; got {got}.")
        if kinds[0] == "number":  # numbers held as objects (a pandas object column): seconds
            arr = np.array(items, dtype=np.float64)
        elif kinds[0] == "duration":
            arr = _in_one_unit(name, spans)
        else:
            arr = _in_one_unit(name, read)
    if arr.dtype.kind in "Mm":
        return ticks(name, _without_nat(name, arr))
    if arr.dtype.kind not in "iuf" or arr.dtype.kind == "b":
        raise TypeError(f"`{name}` must be {_KINDS}; got {arr.dtype} values.")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"`{name}` must be finite.")
    return arr, None


def as_seconds(name: str, times) -> np.ndarray:
    """`times` as float seconds (relative to the first for datetimes), a 1-D array; raises as :func:`_clock`."""
    values, per_second = _clock(name, times)
    if per_second is None:
        return values
    whole = values.tolist()
    return since(whole, whole[0], per_second)


def since(counts: list[int], origin: int, per_second: int) -> np.ndarray:
    """Integer `counts` of 1/`per_second` s as float seconds after `origin`: each an exact difference (Python
    integers, of any span) rounded once."""
    return np.array([(c - origin) / per_second for c in counts], dtype=np.float64)


def step_sizes(name: str, times, T: int) -> np.ndarray:
    """The T step sizes (seconds) of a series of T measurements at `times` (T or T + 1 entries; see the module notes).

    Datetimes' steps are each rounded once from their exact difference, so a
    millisecond step a day after the first time is as exact as the first.

    Raises
    ------
    ValueError
        When `times` has neither T nor T + 1 entries, or is not strictly
        increasing (naming the first step that is not).
    """
    return steps(name, times, T).dts


class Steps(NamedTuple):
    """A series' step sizes, and how far each may be off through the round-off of the times it came from."""

    dts: np.ndarray  # (T,) seconds
    slack: float     # seconds: 8 eps max|t| for float seconds (a 0.1 s grid as seconds since 1970 steps by
    #                  0.09999990 to 0.10000014 s), 0 for datetimes (exact differences)
    total: float | None = None  # the steps' sum and number, and the number of series they belong to, where `dts`
    count: int = 0              # holds only the smallest and the largest (a file read in pieces, a table's series:
    series: int = 1             # gaussfuse.panels.step_range)
    resolution: float = 0.0     # seconds: a datetime's unit, to which each time was rounded (0 for float seconds)

    def _rounded(self, step: float) -> float:
        """The datetimes' rounding, where it is at most 1e-4 of `step`: a 30 Hz grid stamped in nanoseconds steps
        by 33333333 and 33333334 ns (33333332 to 33333335 ns from float seconds, each stamp within a unit or so
        either way), and was refused as irregular (audit DD6); steps of 1 s and 2 s stamped in seconds are not
        one step."""
        return self.resolution if self.resolution <= 1e-4 * step else 0.0

    @property
    def regular(self) -> bool:
        """Whether the steps are one step: to 1e-9 of it or to the times' round-off (one infinite step too); or,
        for datetimes, to 4 units of their unit, the times staying within 4 units plus 1e-9 of their span of one
        grid (steps of 10000 and 10004 ns, 500 of each, drift 1000 ns from it: review R31; a 30 Hz clock summed
        in float seconds drifts 317 ns over 1e6 rows, 1e-11 of its span: review R32)."""
        low, high = self.dts.min(), self.dts.max()
        with np.errstate(invalid="ignore"):  # inf - inf
            if high == low or high - low <= 1e-9 * high + self.slack:
                return True
        unit = self._rounded(low)
        if not (unit > 0.0 and high - low <= 4 * unit):  # (a datetime's steps are all kept: no `total`)
            return False
        drift = np.abs(np.cumsum(self.dts - self.dts.mean())).max()
        return bool(drift <= 4 * unit + 1e-9 * float(np.sum(self.dts)))

    @property
    def step(self) -> float:
        """The mean step: a regular grid's step."""
        return float(self.dts.mean()) if self.total is None else self.total / self.count

    def near(self, dt: float) -> bool:
        """Whether a regular grid steps by `dt`, to 1e-9 of it or to the round-off of its mean step (the times'
        round-off over the number of steps: a grid of 1.0001 ms is not one of 1 ms). Each series' mean step is
        off by its times' round-off over its number of steps, and series on one grid are off alike: their mean
        over all steps by as many times that as there are series (review R12: 200 series of 2 rows, allowed the
        round-off over 200 steps, were told a 0.1 s grid steps by 0.0999999 s)."""
        count = self.dts.shape[0] if self.total is None else self.count / self.series
        return abs(self.step - dt) <= 1e-9 * dt + self.slack / count + self._rounded(dt)  # (a step in whole units)


def round_off(largest: float) -> float:
    """How far a difference of float times up to `largest` in size may be off: two times' round-off, with margin."""
    return 8.0 * float(np.finfo(np.float64).eps) * largest


def steps(name: str, times, T: int, model=None) -> Steps:
    """:func:`step_sizes` as :class:`Steps`; raises as it does, and where `times` are dates and `model` is a
    TimedModel whose motion counts steps (:func:`no_dates_for_steps`)."""
    values, per_second = _clock(name, times)
    slack, resolution = 0.0, 0.0 if per_second is None else 1.0 / per_second
    if per_second is None:
        with np.errstate(over="ignore"):
            diffs = np.diff(values)
        slack = round_off(float(np.abs(values).max(initial=0.0)))
    else:
        diffs = elapsed(values, per_second)
    if values.shape[0] == T + 1:
        dts = diffs
    elif values.shape[0] == T and T >= 2:
        dts = np.concatenate([diffs[:1], diffs])
    else:
        if T == 1:  # one time alone gives no step: its dt is not known
            if name == "zs.index":  # (it cannot have two: review R31)
                raise ValueError("`zs` has one row, whose time alone gives no time step: pass `times` with the "
                                 "prior's time first, and then the row's.")
            raise ValueError(f"`{name}` must have 2 entries with one measurement, the prior's time and then the "
                             f"measurement's (one time alone gives no time step); got {values.shape[0]}.")
        raise ValueError(f"`{name}` must have {T} entries, one per measurement, or {T + 1} with the prior's time "
                         f"first; got {values.shape[0]}.")
    bad = np.flatnonzero(~(dts > 0))
    if bad.size:
        k = int(bad[0])
        raise ValueError(f"`{name}` must be strictly increasing; step {k} has dt = {dts[k]:g} s.")
    if np.isinf(dts).any():
        k = int(np.flatnonzero(np.isinf(dts))[0])
        raise ValueError(f"`{name}` step {k} is longer than the largest float64 (dt = inf s): times so far apart "
                         "cannot be stepped.")
    if resolution > 0.0:
        no_dates_for_steps(getattr(model, "motion", None), name, ", or build the model with dt=1 and pass "
                           "`zs.to_numpy()`" if name == "zs.index" else "")
    return Steps(dts, slack, resolution=resolution)


def no_dates_for_steps(motion, name: str, instead: str = "") -> None:
    """Refuse dated `name` for a motion whose dt counts steps (LocalLevel, LocalLinearTrend), not seconds.

    A day would be 86400 of its steps, its variances 86400 times those of a step, silently (audit MM1).
    """
    if getattr(motion, "_counts_steps", False):
        raise ValueError(
            f"`{name}` gives dates or durations, but {type(motion).__name__} counts steps (dt = 1 for consecutive "
            "observations), not seconds: a day would be 86400 of its steps. Give times as step numbers (np.arange(T) for "
            f"consecutive observations, or the days since the first where days are missed){instead}.")


def resolve(model, times, zs, us=None, name: str = "times", rows: bool = True, one_step: bool = False):
    """The model to filter `zs` with at `times`, and its controls.

    A :class:`TimedModel` becomes the model of its steps (exactly
    discretised for each dt); with `one_step`, a linear one at regular
    times (:attr:`Steps.regular`: to the rounding of datetimes too) that of
    their one step, which has a steady state (a 30 Hz index in nanoseconds,
    steps of 33333333 and 33333334 ns, was refused by ``steady=True``:
    review R33). A model with fixed matrices is returned as it
    is, once `times` are found regular (and at its ``dt``, if it has one).
    `rows` is whether the steps are rows of data, which the messages then
    offer to take one step each (a forecast's are not).

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
    grid = steps(name, times, T, model)
    if timed:  # (a nonlinear one is left to the steady filter's refusal of its method: review R34)
        return model.at(np.full(1, grid.step) if one_step and model.linear and grid.regular else grid.dts, us)
    low, high = float(grid.dts.min()), float(grid.dts.max())
    each = (", or, if each row is one step{} whatever its time, give `zs.to_numpy()` (its index gives the times)"
            if name == "zs.index" else
            ", or, if each row is one step{} whatever its time, leave `times` out (for a pandas `zs`, pass its values)")
    if not grid.regular:
        raise ValueError(
            f"`{name}` are irregular (steps from {low:g} s to {high:g} s) but the model's matrices are fixed; build "
            "it with gf.model(motion, sensor) without dt, which discretises each step for its own dt in seconds"
            + (each.format("") + ", with a row of NaN for a step missed." if rows else "."))
    dt = getattr(model, "dt", None)
    if dt is not None and not grid.near(dt):  # (the rows' part: audit Y3)
        raise ValueError(f"`{name}` step by {grid.step:g} s but the model is for dt = {dt:g} s; build it for the times' "
                         "step, or with gf.model(motion, sensor) without dt" + (each.format(" of dt") + "." if rows
                                                                                  else "."))
    return model, us
