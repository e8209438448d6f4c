"""pandas in and out: measurements from a Series or DataFrame, results as DataFrames.

pandas is optional: nothing here imports it unless a pandas object is given
or a DataFrame is asked for. A Series or DataFrame as `zs` gives its values
(``pd.NA`` and NaN are missing), its index (a DatetimeIndex or
TimedeltaIndex supplies `times` when none are given, except calendar periods
for a model with fixed matrices: one step a row) and its column names (a
TimedModel's measurement names, in any order, are taken by name:
:func:`measurement_names`, :func:`unpack`); a
pandas `us` must have its index (:func:`controls`);
:meth:`~gaussfuse.FilterResult.to_pandas` gives the means, standard
deviations and, on request, covariances, indexed like the input.
"""

from __future__ import annotations

import datetime
from typing import NamedTuple

import numpy as np

from .._linalg import marginal_std
from ..models import LinearSensor, TimedModel

__all__ = ["Table", "ahead", "unpack", "controls", "to_frame", "measurement_names", "name_choices", "ColumnNames",
           "column_names", "in_model_order", "by_name"]


class Table:
    """What a pandas `zs` carried besides its values: its index and column names, and whether its index gave the
    times (so that their errors name it)."""

    __slots__ = ("index", "columns", "index_times")

    def __init__(self, index, columns, index_times: bool = False) -> None:
        self.index, self.columns, self.index_times = index, columns, index_times

    def __reduce__(self):
        return type(self), (self.index, self.columns, self.index_times)

    @property
    def times_name(self) -> str:
        """What the times are called in errors: the index's name where it gave them (audit DD6)."""
        return "zs.index" if self.index_times else "times"


def measurement_names(model) -> tuple[str, ...] | None:
    """A model's measurement names, where it has them: a TimedModel's sensor's, each that reads one of the
    motion's states alone under the name the model gives that state (``gf.model(..., names=[...])``: states
    relabelled ["y", "x", ...] kept the sensor's "x", "y", so a DataFrame in the model's names was read swapped:
    review R36); None (columns taken in order) where that would name two measurements alike (reviews R37, R38)."""
    if not isinstance(model, TimedModel):
        return None
    own, sensed = tuple(model.motion.names), tuple(model.sensor.names)
    if model.names == own:
        return sensed
    H = model.sensor.linear(model.n)[0] if isinstance(model.sensor, LinearSensor) else None
    out = []
    for i, name in enumerate(sensed):
        j = own.index(name) if name in own else None
        # a measurement takes the model's name of a state only where it reads that state alone (H's row i is a
        # multiple of e_j): a sensor's "x" of a motion whose "x" is another component is not that state
        reads = j is not None and (H is None or (np.count_nonzero(H[i]) == 1 and H[i, j] != 0))
        out.append(model.names[j] if reads else name)
    # a name twice (a sensor's own "speed" beside its "x" relabelled "speed") would match no column, and the
    # sensor's own names may be the model's for other states (R38): none, so that columns are taken in order
    return tuple(out) if len(set(out)) == len(out) else None


def name_choices(model) -> list[tuple[str, ...]]:
    """The names by which columns are matched to a model's measurements, alternatives in turn: its measurement
    names (:func:`measurement_names`), then its sensor's own where they differ and name none of the model's
    states. A renamed model (states "px", "py", ...) took a DataFrame of its sensor's "y", "x" by position,
    swapped, where the command line read the file by name (review R52); a sensor's own names that are the
    model's names of other states are no alternative (review R38: they swapped a frame in the model's names).
    None for a model without them (a LinearModel or NonlinearModel)."""
    names = measurement_names(model)
    if names is None and not isinstance(model, TimedModel):
        return []
    own = tuple(model.sensor.names)
    apart = len(set(own)) == len(own) and not set(own) & set(model.names)
    return [choice for choice in dict.fromkeys([names, own if apart else None]) if choice]


class ColumnNames(NamedTuple):
    """How a named model's measurement columns are matched (:func:`column_names`): `choices`, alternative lists of
    its measurement names (:func:`name_choices`), and `unmeasured`, its names of the states it does not measure."""
    choices: list
    unmeasured: tuple


def column_names(model) -> ColumnNames:
    """A model's :class:`ColumnNames`: :func:`name_choices`, and the names of the states its linear sensor does not
    read (H's column of zeros) and no choice names; none for another sensor (a range and bearing read x and y) or
    a model without names."""
    choices = name_choices(model)
    if not isinstance(model, TimedModel) or not isinstance(model.sensor, LinearSensor):
        return ColumnNames(choices, ())
    taken = {name.casefold() for names in choices for name in names}
    unread = ~np.any(model.sensor.linear(model.n)[0] != 0.0, axis=0)
    return ColumnNames(choices, tuple(name for name, no in zip(model.names, unread) if no and name.casefold() not in taken))


def in_model_order(columns, choices, what: str, fix: str, unmeasured=()) -> list[int] | None:
    """Where `columns` are the measurement names of one of the `choices` (:func:`name_choices`) in another order or
    case, the position of each name among them; None where they are taken in order. The first choice that all
    the columns name is taken; where none does, one that some name and others do not is refused (review R47:
    `t,Y,x` was refused on the exact names before the pass in any case), and so are columns taken in order of
    which some are named, in any case, as `unmeasured` states (columns vy, vx of a model that measures x, y were
    read as its x, y: audit YY1)."""
    refused = None
    for names in choices:
        if len(columns) != len(names) or len(set(names)) < len(names):
            continue  # (a count other than the model's is named by the caller)
        if list(columns) == list(names):
            return None
        try:
            order = by_name(columns, names, what, fix)
        except ValueError as exc:
            refused = refused or exc
            continue
        if order is not None:
            return order
    if refused is not None:
        raise refused
    others = {name.casefold() for name in unmeasured}
    named = [column for column in columns if column.casefold() in others]
    if named and choices and len(columns) == len(choices[0]):  # (another count is named by the caller)
        raise ValueError(f"{what} the model's states, {named}, which it does not measure (it measures "
                         f"{list(choices[0])}): name the columns as its measurements, or {fix}.")
    return None


def by_name(columns, names, what: str, fix: str) -> list[int] | None:
    """Where `columns` are the measurement `names` in another order, the position of each name among them; None
    where they are taken in order (no names, the same order, or none of them).

    The names are matched as written, then in any case (columns "Y", "X" for the measurements x, y were taken by
    position, swapped, silently, as the command line's were: audit SS1), unless case is all that tells two names
    apart.

    Raises
    ------
    ValueError
        Where they name some of the names and not others (taken by position, x and y could swap silently: audits
        DD6, EE2): "`what` the model's measurements [...], without [...], and [...] besides: ..., or `fix`."
        (The names as written decide what is missing, unless only the pass in any case matched some.)
    """
    columns = list(columns)
    if names is None or columns == list(names):
        return None
    names, refusal = list(names), None
    for fold in (str, str.casefold):
        given, wanted = [fold(c) for c in columns], [fold(n) for n in names]
        if len(set(given)) < len(set(columns)) or len(set(wanted)) < len(set(names)) or not set(given) & set(wanted):
            continue  # (none of them; or names that differ only in case, which only the first pass tells apart)
        if sorted(given) == sorted(wanted):
            return [given.index(name) for name in wanted]
        refusal = refusal or ([n for n, w in zip(names, wanted) if w not in given],
                              [c for c, g in zip(columns, given) if g not in wanted],
                              sorted({c for c, g in zip(columns, given) if given.count(g) > 1}))
    if refusal is None:
        return None
    missing, other, twice = refusal
    raise ValueError(f"{what} the model's measurements {names}" + (f", without {missing}" if missing else "")
                     + (f", and {other} besides" if other else "")
                     + (f", {twice} more than once" if twice else "")  # (it named nothing wrong: review R52)
                     + f": name them as the model does, in any order, or {fix}.")


def _is_pandas(value) -> bool:
    return type(value).__module__.split(".")[0] == "pandas" and hasattr(value, "to_numpy")


def _check_columns(zs, name: str = "zs") -> None:
    """Refuse what :func:`gaussfuse._validation.as_array` refuses in an array: complex, boolean, date and text values.

    pandas' cast to float dropped an imaginary part (with only its own
    warning), read True as 1.0 and parsed the text "1".
    """
    from pandas.api.types import (is_bool_dtype, is_complex_dtype, is_datetime64_any_dtype, is_numeric_dtype,
                                  is_timedelta64_dtype)

    columns = zs.items() if hasattr(zs, "columns") else [(zs.name, zs)]
    for label, column in columns:
        where = "in the Series" if label is None else f"in column {label!r}"  # (not "column None": audit DD6)
        if is_complex_dtype(column.dtype):
            raise TypeError(f"`{name}` must be real; got complex values {where}.")
        if is_bool_dtype(column.dtype):
            raise TypeError(f"`{name}` must hold numbers; got booleans {where}.")
        if is_datetime64_any_dtype(column.dtype) or is_timedelta64_dtype(column.dtype):  # (as nanosecond counts)
            what = "timedelta" if is_timedelta64_dtype(column.dtype) else "datetime"
            raise TypeError(f"`{name}` must hold numbers; got {what} values {where} (times go in `times` "
                            "or the index).")
        if not is_numeric_dtype(column.dtype):  # (dates in an object column were read as day counts: audit DD6)
            odd = [v for v in column.dropna() if isinstance(v, (str, bytes, bool, np.bool_, complex, np.datetime64,
                                                                np.timedelta64, datetime.date, datetime.timedelta))]
            if odd:
                raise TypeError(f"`{name}` must hold numbers; got {type(odd[0]).__name__} values {where} "
                                f"(such as {odd[0]!r}).")


def _calendar(index) -> bool:
    """Whether `index` steps by a calendar period whose length in seconds varies (months, years, business days):
    pandas' frequency of it (set, or inferred from three or more entries) is not a fixed span of time, and its
    steps in seconds are not all equal (weeks are)."""
    import pandas as pd

    if not isinstance(index, pd.DatetimeIndex) or np.unique(np.diff(index.asi8)).size <= 1:
        return False
    freq = _frequency(index)
    return freq is not None and not isinstance(freq, pd.tseries.offsets.Tick)


def _frequency(index):
    """A DatetimeIndex's or TimedeltaIndex's frequency: pandas' own, or inferred from three or more entries;
    None where it has none."""
    import pandas as pd

    freq = index.freq
    if freq is None and len(index) >= 3:
        try:  # pandas 3 warns that infer_freq will return an offset, not a string, unless asked for the offset
            with pd.option_context("future.infer_freq_returns_offset", True):
                inferred = pd.infer_freq(index)
        except KeyError:  # an earlier pandas, without that option: a string
            inferred = pd.infer_freq(index)
        freq = None if inferred is None else pd.tseries.frequencies.to_offset(inferred)
    return freq


def _by_rows(model) -> bool:
    """Whether `model` takes a calendar index one step a row (:func:`unpack`): its matrices are fixed, without a
    ``dt`` in seconds to check the times against."""
    return not isinstance(model, TimedModel) and getattr(model, "dt", None) is None


def unpack(zs, times, model):
    """`zs` as a float array (NaN for missing), the `times` to use, and its :class:`Table` (None for an array).

    The index of a pandas `zs` supplies `times` when none are given, except one of calendar periods (monthly,
    yearly, business days) for a model with fixed matrices and no ``dt`` (:func:`_by_rows`): its rows are then
    one step each, as they are in a statistical model of monthly data; in seconds they are irregular, which such
    a model refuses. A model with fixed matrices takes one row without times (it has no step to check).

    A DataFrame whose columns are the model's measurement names (:func:`measurement_names`: a TimedModel's, in
    its state names) in another order, or in another case, is taken in the model's order; one that names some of
    them and not others is refused (its columns were taken by position: x and y swapped, silently, audit DD6;
    and "Y", "X" for x, y until audit SS1's follow-up). Columns named otherwise,
    and every DataFrame for a LinearModel or NonlinearModel, which name no measurements, are taken by position.
    """
    if not _is_pandas(zs) or not hasattr(zs, "index"):
        return zs, times, None
    if getattr(zs.index, "nlevels", 1) > 1:  # a long table of several series would be filtered as one
        raise ValueError(f"`zs` has a MultiIndex ({', '.join(map(str, zs.index.names))}): a table of several series "
                         "would be filtered as one. Give one series (`zs.xs(key)`), or an array (N, T, m) of series "
                         "padded at the end with NaN.")
    _check_columns(zs)
    try:  # a DataFrame column by column: its own cast fails on pd.NA in an object column, a Series' does not
        if not hasattr(zs, "columns") or zs.shape[1] == 0:
            values = zs.to_numpy(dtype=np.float64, na_value=np.nan)
        else:
            values = np.column_stack([column.to_numpy(dtype=np.float64, na_value=np.nan) for _, column in zs.items()])
    except (TypeError, ValueError) as exc:
        raise TypeError(f"`zs` must hold numbers; its values do not convert to float ({exc}).") from None
    columns = (tuple(str(c) for c in zs.columns) if hasattr(zs, "columns")
               else None if zs.name is None else (str(zs.name),))  # (an unnamed Series' column is not "None")
    choices, unmeasured = column_names(model)
    order = None if not hasattr(zs, "columns") else in_model_order(
        columns, choices, f"`zs` has the columns {list(columns)}, some of",
        "give `zs.to_numpy()` to take the columns in their order", unmeasured)
    if order is not None:
        values, columns = values[:, order], choices[0]
    index, index_times = _datetimes(zs.index), False
    rows = _by_rows(model)
    if times is None and index is not None and (not rows or not _calendar(index)) and (
            len(index) > 1 or isinstance(model, TimedModel)):
        times, index_times = index, True
    return values, times, Table(zs.index, columns, index_times)


def _datetimes(index):
    """A pandas index of datetimes or durations as a DatetimeIndex or TimedeltaIndex (a pyarrow-backed index of
    timestamps was not taken for times: audit DD6), or None."""
    import pandas as pd
    from pandas.api.types import is_datetime64_any_dtype, is_timedelta64_dtype

    if isinstance(index, (pd.DatetimeIndex, pd.TimedeltaIndex)):
        return index
    if is_datetime64_any_dtype(index.dtype):
        return pd.DatetimeIndex(index)
    if is_timedelta64_dtype(index.dtype) or getattr(index.dtype, "kind", None) == "m":  # (pyarrow's: review R31)
        return pd.TimedeltaIndex(index.astype("timedelta64[ns]"))
    return None


def controls(us, table: Table | None):
    """A pandas `us` as a float array, its rows those of the pandas `zs` of `table` (its index must be `zs`'s: the
    controls were taken by position, whatever their labels, audit DD6); anything else as it is."""
    if not _is_pandas(us) or not hasattr(us, "index"):
        return us
    if table is not None and not us.index.equals(table.index):
        differ = next((k for k, (a, b) in enumerate(zip(us.index, table.index)) if a != b), None)
        where = (f"{len(us.index)} rows for {len(table.index)}" if differ is None
                 else f"row {differ} is {us.index[differ]!r} for {table.index[differ]!r}")
        raise ValueError(f"`us` is a pandas object whose index is not that of `zs` ({where}): give the controls of "
                         "the same rows (`us.reindex(zs.index)`), or an array to take them in order.")
    _check_columns(us, "us")
    return us.to_numpy(dtype=np.float64, na_value=np.nan)


def ahead(index, k: int):
    """The k labels that follow a pandas `index` at its own step, or None where it has none: a RangeIndex goes
    on; a DatetimeIndex, TimedeltaIndex or PeriodIndex with a frequency (set, or inferred from three or more
    entries) steps by it."""
    import pandas as pd

    if isinstance(index, pd.RangeIndex):
        return pd.RangeIndex(index.stop, index.stop + k * index.step, index.step, name=index.name)
    if isinstance(index, pd.PeriodIndex):
        return pd.period_range(index[-1] + 1, periods=k, freq=index.freq, name=index.name)
    freq = _frequency(index) if isinstance(index, (pd.DatetimeIndex, pd.TimedeltaIndex)) else None
    if freq is None:
        return None
    span = pd.date_range if isinstance(index, pd.DatetimeIndex) else pd.timedelta_range
    return span(index[-1] + freq, periods=k, freq=freq, name=index.name)


def to_frame(means: np.ndarray, covs: np.ndarray | None, table: Table | None, names, covariances: bool,
             what: str = "state"):
    """A DataFrame of means and standard deviations (and covariances) per step, indexed like the input; `what`
    the components are, for the messages."""
    import pandas as pd

    if means is None or means.ndim != 2:
        raise ValueError("to_pandas() is for one series whose means were kept (keep='all' or 'means').")
    n = means.shape[1]
    if names is not None and (isinstance(names, (str, bytes)) or not all(isinstance(x, str) for x in names)):
        raise TypeError(f"`names` must be a sequence of {n} str, one per {what} component; got {names!r:.60}.")
    if not isinstance(covariances, (bool, np.bool_)):
        raise TypeError(f"`covariances` must be True or False; got {covariances!r:.60}.")
    names = tuple(names) if names is not None else tuple(f"x{i}" for i in range(n))
    if len(names) != n:
        raise ValueError(f"`names` must have {n} entries, one per {what} component; got {len(names)}.")
    data = {name: means[:, i] for i, name in enumerate(names)}
    columns = list(names)
    if covs is not None:
        sds = marginal_std(covs)
        data.update({f"{name}_sd": sds[:, i] for i, name in enumerate(names)})
        columns += [f"{name}_sd" for name in names]
        if covariances:
            for i in range(n):
                for j in range(i + 1, n):
                    data[f"cov_{names[i]}_{names[j]}"] = covs[:, i, j]
                    columns.append(f"cov_{names[i]}_{names[j]}")
    elif covariances:
        raise ValueError("covariances=True needs the covariances (keep='all').")
    if len(set(columns)) != len(columns):  # a name twice, or one that is another's "_sd" column
        twice = sorted({c for c in columns if columns.count(c) > 1})
        raise ValueError(f"`names` {list(names)} give the column(s) {twice} twice (each component has a column "
                         "and a `_sd` column); give names that are distinct and not another's with `_sd`.")
    index = table.index if table is not None and len(table.index) == means.shape[0] else None
    return pd.DataFrame(data, index=index)
