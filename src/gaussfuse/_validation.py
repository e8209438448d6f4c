"""Validators for user input.

Each validator checks one value and hands it back as a float64 array, or
raises ``ValueError``/``TypeError`` whose message names the argument in
backticks, the expected shape and what was given (the style of SciPy's
``_ivp/common.py``).
"""

from __future__ import annotations

import datetime
import math
from functools import lru_cache, wraps
from inspect import signature
from operator import attrgetter
from typing import Callable

import numpy as np

from ._linalg import PSD_RTOL, marginal_std
from .errors import ModelFunctionError

_F64 = np.dtype(np.float64)
_DTYPE = attrgetter("dtype")

__all__ = ["as_array", "as_numbers", "flag", "as_vector", "as_matrix", "check_psd", "shape_error", "real", "integer", "call_checked",
           "call_each", "raise_call", "size_reason", "finite_step", "generator", "component_mask",
           "negative_variance"]


def shape_error(name: str, expected: str, got: tuple[int, ...]) -> ValueError:
    """The one message template for a wrong shape."""
    return ValueError(f"`{name}` must have shape {expected}; got shape {tuple(got)}.")


def as_array(name: str, value, *, allow_nan: bool = False, copy: bool = True) -> np.ndarray:
    """Return `value` as a float64 array, rejecting non-numeric and non-finite input.

    With ``copy=False`` a float64 array is used as it is (a long series, or a
    memory-mapped one, is not duplicated); the check allocates nothing the
    size of `value` unless it finds a bad entry.

    A masked array's masked entries are missing values: NaN where `allow_nan`
    (in a new array; the caller's is not modified), an error otherwise.
    Dates and times (``datetime64``, ``timedelta64``) are not numbers here:
    their cast would silently give counts of days or nanoseconds.
    """
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(f"`{name}` must be an array of numbers; got {type(value).__name__}.")
    try:
        kind = np.asarray(value).dtype.kind
    except ValueError:  # ragged nesting; the cast below says so
        kind = None
    if kind == "c":
        # Checked before the cast, which would warn and drop the imaginary part.
        raise TypeError(f"`{name}` must be real; got complex values.")
    if kind == "O" and not np.ma.isMaskedArray(value):  # an object array: what each entry is, named
        entries = np.asarray(value, dtype=object)
        for index, entry in np.ndenumerate(entries):
            if isinstance(entry, (bool, np.bool_)):
                raise TypeError(f"`{name}` must be an array of numbers; got booleans.")
            if entry is None and not allow_nan:
                raise ValueError(f"`{name}` must be an array of numbers; got None at index {index}.")
            # the cast below would read the text "10" as 10, a date as a count of days, and drop an imaginary part
            if isinstance(entry, (str, bytes)):
                raise TypeError(f"`{name}` must be an array of numbers; got the text {entry!r:.40} at index {index}.")
            if isinstance(entry, (complex, np.complexfloating)):
                raise TypeError(f"`{name}` must be real; got the complex value {entry} at index {index}.")
            if isinstance(entry, (datetime.date, datetime.timedelta, np.datetime64, np.timedelta64)):
                raise TypeError(f"`{name}` must be an array of numbers; got the date or time {entry} at index {index} "
                                "(dates and times are not numbers here, and are not converted to counts of days or "
                                "seconds).")
    if kind == "b" or (isinstance(value, (list, tuple)) and _holds_bool(value)):
        raise TypeError(f"`{name}` must be an array of numbers; got booleans.")
    if kind in ("U", "S"):  # the cast below would read "1" as 1.0
        raise TypeError(f"`{name}` must be an array of numbers; got strings.")
    if kind in ("M", "m"):
        what = "datetime64" if kind == "M" else "timedelta64"
        raise TypeError(f"`{name}` must be an array of numbers; got {what} values (dates and times "
                        "are not numbers here, and are not converted to counts of days or seconds).")
    if np.ma.isMaskedArray(value):
        masked = np.ma.getmaskarray(value)
        if masked.any():
            if not allow_nan:
                index = tuple(int(i) for i in np.argwhere(masked)[0])
                raise ValueError(f"`{name}` must not have masked entries (only measurements may be "
                                 f"missing); got a masked entry at index {index}.")
            value = np.ma.getdata(value).astype(np.float64)  # a copy: the caller's array stays as it was
            value[masked] = np.nan
            copy = False
        else:
            value = np.ma.getdata(value)
    try:
        arr = np.array(value, dtype=np.float64, copy=copy or None)
    except OverflowError:  # a Python integer beyond float64 (from a TOML file, say)
        raise ValueError(f"`{name}` must be finite; got an integer too large for float64 (above 1.8e308).") from None
    except (TypeError, ValueError) as exc:
        if kind is None and isinstance(value, (list, tuple)):  # ragged: sequences of different lengths
            lengths = [len(v) if hasattr(v, "__len__") else 1 for v in value]
            hint = "; pad the shorter series at the end with NaN (missing steps)" if name == "zs" else ""
            shown = ", ".join(map(str, lengths[:6])) + (", ..." if len(lengths) > 6 else "")
            raise TypeError(f"`{name}` must be a rectangular array of real numbers; got rows of different lengths "
                            f"({shown}){hint}.") from exc
        raise TypeError(f"`{name}` must be an array of real numbers; got {value!r:.80}.") from exc
    # The extremes are ±inf if any entry is, and NaN if any is (fmin/fmax skip NaN):
    # a check without a temporary the size of arr; the entry is looked for only then.
    lo, hi = (np.fmin, np.fmax) if allow_nan else (np.minimum, np.maximum)
    if arr.size and not (np.isfinite(lo.reduce(arr, axis=None)) and np.isfinite(hi.reduce(arr, axis=None))):
        bad = np.isinf(arr) if allow_nan else ~np.isfinite(arr)
        if bad.any():
            what = "an infinite" if allow_nan else "a non-finite (NaN or inf)"
            index = tuple(int(i) for i in np.argwhere(bad)[0])
            raise ValueError(f"`{name}` must be finite; got {what} value at index {index}.")
    return arr


def as_numbers(name: str, value) -> np.ndarray:
    """`value` as an array of real or complex numbers (complex for complex-step derivatives), integers as float64.

    Booleans, also inside lists (``[True, 2.0]`` would cast to ``[1.0, 2.0]``), strings and other kinds are
    refused, naming `name`. The shape is the caller's to check.
    """
    arr = np.asarray(value)
    if arr.dtype.kind == "b" or (isinstance(value, (list, tuple)) and _holds_bool(value)):
        raise TypeError(f"`{name}` must be an array of numbers; got booleans.")
    if arr.dtype.kind not in "iufc":
        raise TypeError(f"`{name}` must be an array of numbers; got {arr.dtype} values.")
    return arr.astype(np.float64) if arr.dtype.kind in "iu" else arr


def flag(name: str, value) -> bool:
    """`value` as a bool if it is one (Python's or NumPy's), else a TypeError naming `name`: "no" is not False."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"`{name}` must be True or False; got {value!r:.80}.")
    return bool(value)


def _holds_bool(items) -> bool:
    """Whether nested lists or tuples hold a bool anywhere (NumPy would cast it to 0 or 1 among numbers)."""
    return any(isinstance(x, (bool, np.bool_)) or (isinstance(x, (list, tuple)) and _holds_bool(x)) for x in items)


def as_vector(name: str, value, size: int | None = None) -> np.ndarray:
    """Return `value` as a vector of shape (size,); a scalar is a vector of length 1."""
    arr = as_array(name, value)
    given = arr.shape
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim != 1 or arr.shape[0] == 0 or (size is not None and arr.shape[0] != size):
        expected = f"({size},)" if size is not None else "(n,) with n >= 1"
        raise shape_error(name, expected, given)
    return arr


def as_matrix(
    name: str,
    value,
    rows: int | None,
    cols: int | None,
    *,
    steps: int | None = None,
    row_vector_ok: bool = False,
    column_vector_ok: bool = False,
    row_name: str = "m",
    col_name: str = "n",
    time_varying: bool = True,
    because: str | None = None,
) -> np.ndarray:
    """Return `value` as a matrix (rows, cols) or a time-varying stack (T, rows, cols).

    A scalar is accepted for a 1 x 1 matrix. With `row_vector_ok`, a 1-D array
    of length `cols` is one row; with `column_vector_ok`, a 1-D array of
    length `rows` is one column. `steps`, when given, is the length a
    leading time axis must have. `row_name` and `col_name` stand for a
    dimension left free (None) in the message; with ``time_varying=False``
    only a single matrix is accepted. Every dimension must be at least 1.
    `because` names what fixed the expected shape (another argument), for
    the message: "... (2, 2), because `H` has 2 rows; got ...".
    """
    arr = as_array(name, value)
    given = arr.shape
    if arr.ndim == 0:
        arr = arr.reshape(1, 1)
    elif arr.ndim == 1:
        if row_vector_ok and (cols is None or arr.shape[0] == cols):
            arr = arr.reshape(1, -1)
        elif column_vector_ok and (rows is None or arr.shape[0] == rows):
            arr = arr.reshape(-1, 1)
    r = row_name if rows is None else rows
    c = col_name if cols is None else cols
    t = "T" if steps is None else steps
    expected = f"({r}, {c}) or, time-varying, ({t}, {r}, {c})" if time_varying else f"({r}, {c})"
    if because:
        expected += f", because {because}"
    if arr.ndim not in ((2, 3) if time_varying else (2,)) or 0 in arr.shape:
        raise shape_error(name, expected, given)
    if (rows is not None and arr.shape[-2] != rows) or (cols is not None and arr.shape[-1] != cols):
        if given == () and rows == cols:  # (filterpy's users write R = 5; audit Y3)
            raise ValueError(f"{shape_error(name, expected, given)} A number is a 1 × 1 matrix only; for "
                             f"{arr[0, 0]:g} times the identity give {arr[0, 0]:g} * np.eye({rows}).")
        raise shape_error(name, expected, given)
    if arr.ndim == 3 and steps is not None and arr.shape[0] != steps:
        raise shape_error(name, expected, given)
    return arr


def negative_variance(covs: np.ndarray) -> tuple[int, int] | None:
    """The first (k, i) of a stack of covariances (k, n, n) whose variance i is below 0 by more than the round-off
    of its largest entry, 8 n ε of it (a 0 computed with round-off is not one); None where there is none."""
    n = covs.shape[-1]
    variances = np.diagonal(covs, axis1=-2, axis2=-1)
    top = np.nanmax(np.abs(covs), axis=(-2, -1), initial=0.0)[:, None]
    bad = np.argwhere(variances < -8 * n * np.finfo(np.float64).eps * top)
    return (int(bad[0][0]), int(bad[0][1])) if bad.size else None


def check_psd(name: str, cov: np.ndarray, *, rtol: float = PSD_RTOL) -> np.ndarray:
    r"""Check that `cov` (..., n, n) is symmetric positive semi-definite; return it symmetrised.

    Each entry is judged on its own components' scale: symmetry and the
    smallest eigenvalue of :math:`K_{ij} = c_{ij} / (s_i s_j)`, with
    :math:`s_i = \sqrt{|c_{ii}|}` (the correlation matrix of a covariance),
    must hold to `rtol`. So round-off in a user's matrix is accepted, but a
    negative variance or an asymmetry is not, however small next to the
    other components' variances (``diag(1e10, -0.5)`` is refused). A
    diagonal entry within round-off of the largest entry (:math:`8 n
    \epsilon` of it: a zero variance computed as -1e-20, say) is judged on
    the largest entry's scale instead, and its covariances must still obey
    :math:`|c_{ij}| \le \sqrt{c_{ii} c_{jj}}` to the round-off that scale
    leaves. An entry's round-off is at least half the spacing of the
    subnormal floats, u = 2**-1074, which a variance of that size may have
    lost entirely (a motion's Q at q = 1e-300 over 1e-8 s has c_00 =
    3.3e-325, rounded to 0, beside c_01 = 5e-317: audit BB1). Such errors
    move an eigenvalue by at most n u / 2, so the eigenvalue test is of
    :math:`C + (n u / 2) I` (n u / 2 rounded to a float), and the entry
    bound takes each variance as up to u larger.
    """
    n = cov.shape[-1]
    u = 2.0**-1074
    floor = n * u / 2 * np.eye(n)  # the eigenvalues' absolute round-off, as a variance (see above)
    top = np.max(np.abs(cov), axis=(-2, -1))[..., None]
    top = np.where(top > 0, top, 1.0)
    diag = np.abs(np.diagonal(cov, axis1=-2, axis2=-1))
    s = np.sqrt(np.where(diag > 8 * n * np.finfo(np.float64).eps * top, diag, top))
    K = cov / s[..., :, None] / s[..., None, :]  # divided twice: s_i s_j may overflow
    K_t = np.swapaxes(K, -1, -2)
    asym = np.abs(K - K_t) > rtol * np.maximum(1.0, np.abs(K))
    if asym.any():  # (the entries were not named: audit BB2)
        at = np.argwhere(asym)[0]
        i, j = int(at[-2]), int(at[-1])
        raise ValueError(f"`{name}` must be symmetric; its entries [{i}, {j}] and [{j}, {i}] differ, "
                         f"{float(cov[(*at[:-2], i, j)])!r} and {float(cov[(*at[:-2], j, i)])!r}{_where(at, cov.ndim)}.")
    # The user's symmetric entries are kept bit for bit (subnormals too); the others are
    # averaged halves first, so that entries near the largest float do not overflow.
    cov_t = np.swapaxes(cov, -1, -2)
    sym = np.where(cov == cov_t, cov, 0.5 * cov + 0.5 * cov_t)
    raised = (cov + floor) / s[..., :, None] / s[..., None, :]
    low = np.linalg.eigvalsh(0.5 * raised + 0.5 * np.swapaxes(raised, -1, -2))[..., 0] < -rtol
    if np.any(low):
        where = _where(np.argwhere(np.atleast_1d(low))[0], cov.ndim) if cov.ndim > 2 else ""
        eig = float(np.min(np.linalg.eigvalsh(sym)))
        raise ValueError(
            f"`{name}` must be positive semi-definite; its smallest eigenvalue is {eig:.3g}{where}."
        )
    # |c_ij| <= √(c_ii c_jj), to round-off: the eigenvalue test cannot see it where a variance is judged on the
    # largest scale. A variance that is 0 by cancellation of terms of the largest scale leaves c_ij off by about
    # ε √(c_max) √(c_jj).
    d = marginal_std(sym)
    slack = 8 * n * np.finfo(np.float64).eps * np.sqrt(top[..., None]) * np.maximum(d[..., :, None], d[..., None, :])
    e = np.sqrt(np.maximum(np.diagonal(sym, axis1=-2, axis2=-1), 0.0) + u)  # d, with its round-off
    wide = (np.abs(sym) > e[..., :, None] * e[..., None, :] * (1.0 + rtol) + slack) & ~np.eye(n, dtype=bool)
    if wide.any():
        at = np.argwhere(wide)[0]
        i, j = int(at[-2]), int(at[-1])
        raise ValueError(f"`{name}` must be positive semi-definite; its entry [{i}, {j}] is larger than the variances "
                         f"[{i}, {i}] and [{j}, {j}] allow (|c_ij| <= √(c_ii c_jj)){_where(at, cov.ndim)}.")
    return sym


def _where(index, ndim: int) -> str:
    """' at time step k' for a time-varying stack, '' for a single matrix."""
    return f" at time step {int(index[0])}" if ndim == 3 else ""


def real(name: str, value, *, positive: bool = False, nonnegative: bool = False, optional: bool = False):
    """`value` as a float: finite, and > 0 or >= 0 when asked; None passes when `optional`.

    One message for every invalid value: "`name` must be a positive number;
    got -1.0." (a number is shown as a float, anything else by its repr).

    Raises
    ------
    TypeError
        When `value` is not a real number (a bool, a string, an array, ...).
    ValueError
        When it is not finite, or out of range.
    """
    if optional and value is None:
        return None
    number = not isinstance(value, (bool, np.bool_, np.timedelta64)) and isinstance(
        value, (int, float, np.integer, np.floating))  # (a timedelta64 is an np.integer: its count, in any unit)
    kind = "a positive" if positive else "a non-negative" if nonnegative else "a finite"
    if isinstance(value, (np.timedelta64, datetime.timedelta)):
        raise TypeError(f"`{name}` must be {kind} number{' or None' if optional else ''}; got {value!r}, a "
                        "duration: give it in seconds (for example `d / np.timedelta64(1, 's')`).")
    try:
        as_float = float(value) if number else None
        shown = as_float if number else repr(value)
    except OverflowError:  # an int beyond float64 (10**400)
        as_float = math.inf if value > 0 else -math.inf
        shown = f"{shown_integer(value)}, beyond float64"
    expected = f"`{name}` must be {kind} number{' or None' if optional else ''}; got {shown}."
    if not number:
        raise TypeError(expected)
    if not math.isfinite(as_float) or (positive and as_float <= 0) or (nonnegative and as_float < 0):
        raise ValueError(expected)
    return as_float


def is_integer(value) -> bool:
    """Whether `value` is an integer: a Python or NumPy int, not a bool, nor a ``np.timedelta64`` (NumPy's is an
    integer type, whose count of its own units was taken for a size: audit VV2)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_, np.timedelta64))


def shown_integer(value) -> str:
    """`value`'s repr, or for an integer of over 20 digits their count (a `dim` of 401 digits was told in full)."""
    if is_integer(value) and abs(value) >= 10 ** 20:
        size = abs(int(value))  # (its digits by its bits: str() refuses an int of over 4300 digits: review R54)
        digits = int(size.bit_length() * math.log10(2))
        return f"an integer of {digits + (size >= 10 ** digits)} digits"
    return repr(value)


def integer(name: str, value, minimum: int = 1) -> int:
    """`value` as an int >= `minimum`.

    Raises
    ------
    TypeError
        When `value` is not an integer (a bool, a float, ...).
    ValueError
        When it is below `minimum`.
    """
    kind = {0: "a non-negative integer", 1: "a positive integer"}.get(minimum, f"an integer >= {minimum}")
    expected = f"`{name}` must be {kind}; got {shown_integer(value)}."
    if not is_integer(value):
        raise TypeError(expected)
    if value < minimum:
        raise ValueError(expected)
    return int(value)


# ---------------------------------------------------------------------------
# What a user's model function returns
# ---------------------------------------------------------------------------


@lru_cache(maxsize=64)  # asked for on every call of f and h
def size_reason(name: str, size: int, n: int | None = None) -> str | None:
    """What fixes the size of f's or h's output (or their Jacobians'), for the shape messages.

    f returns n values because `Q` is n × n, h returns m because `R` is m × m;
    a Jacobian's n columns also come from `Q` (give `n`).
    """
    base = name.removesuffix("_jacobian")
    if base not in ("f", "h"):
        return None
    noise = "Q" if base == "f" else "R"
    reason = f"`{noise}` is {size} × {size}"
    if name.endswith("_jacobian") and n is not None and base == "h":
        reason += f" and `Q` is {n} × {n}"
    return reason


def call_checked(name: str, fn: Callable, x: np.ndarray, args: tuple, shape: tuple[int, ...],
                 because: str | None = None, user: Callable | None = None) -> np.ndarray:
    """Call ``fn(x, *args)`` and check that it returns a finite array of `shape`.

    `because` says what fixed `shape` (see :func:`size_reason`), for the
    message of a wrong shape; `user` is the user's function when `fn` wraps
    it (default `fn`), for the message of a call it cannot take.

    Raises
    ------
    ModelFunctionError
        Naming the function, the input shape and what went wrong: an
        exception, a wrong shape, values that are complex (unless `x` is:
        a complex step), boolean or dates, or a non-finite value.
    """
    try:
        out = fn(x, *args)
    except Exception as exc:  # a user's function may raise anything
        hint = " (without `us`, f is called as f(x); f(x, u) needs `us`, a control per step)" \
            if name == "f" and not args and isinstance(exc, TypeError) and not _takes_one(user or fn) else ""
        raise ModelFunctionError(
            f"`{name}` raised {type(exc).__name__} on an input of shape {x.shape}: {exc}{hint}"
        ) from exc
    try:
        kind = np.asarray(out).dtype.kind
    except (TypeError, ValueError):  # ragged: the cast below says so
        kind = None
    step = np.iscomplexobj(x)  # a complex step: its result is complex (a Stacked sensor's h: audit TT2)
    if kind in ("b", "M", "m") or (kind == "c" and not step):
        # Before the cast, which would drop an imaginary part or turn True into 1.0.
        what = {"c": "complex", "b": "boolean", "M": "datetime64", "m": "timedelta64"}[kind]
        raise ModelFunctionError(
            f"`{name}` must return an array of real numbers; got {what} values for an input of shape {x.shape}."
        )
    try:
        out = np.asarray(out, dtype=np.complex128 if step else np.float64)
    except (TypeError, ValueError):
        raise ModelFunctionError(
            f"`{name}` must return an array of real numbers; got {type(out).__name__} {out!r:.60}."
        ) from None
    if out.shape != shape:
        if out.size == int(np.prod(shape)) and out.ndim <= 1 and len(shape) == 1:
            out = out.reshape(shape)
        else:
            reason = f", because {because}" if because else ""
            raise ModelFunctionError(
                f"`{name}` must return shape {shape} for an input of shape {x.shape}{reason}; "
                f"got shape {out.shape}."
            )
    if not np.all(np.isfinite(out)):
        raise ModelFunctionError(
            f"`{name}` returned a non-finite value (NaN or inf) for an input of shape {x.shape}."
        )
    return out


def call_each(name: str, fn: Callable, X: np.ndarray, args: tuple, size: int, finite: bool = True) -> np.ndarray:
    """``fn(x, *args)`` at each row x of `X` (k, n), stacked to (k, `size`) and checked as :func:`call_checked` does.

    The outputs are checked together, once; only when that finds something
    wrong are they checked one by one, in order, so that the error is
    :func:`call_checked`'s for the first bad point. With ``finite=False``
    non-finite values pass (a caller that finds them later).

    Raises
    ------
    ModelFunctionError
        As :func:`call_checked`, for the first point whose call raised or
        whose output is wrong.
    """
    outs = []
    append = outs.append
    try:
        if args:
            for x in X:
                append(fn(x, *args))
        else:
            for x in X:
                append(fn(x))
    except Exception as exc:  # the points before it are checked first, as one by one they would have been
        _check_each(name, outs, X, size)
        raise_call(name, exc, X[len(outs)], args, fn)
    # Only float64 arrays of the right shape are stacked as they are: stacking would turn a boolean output
    # among them into numbers, and put a wrong shape's error in NumPy's words.
    try:
        stackable = set(map(_DTYPE, outs)) == {_F64}
    except AttributeError:  # not an array
        stackable = False
    if stackable:
        try:
            out = np.array(outs)
        except ValueError:  # shapes that differ
            out = None
        if out is not None and out.shape == (X.shape[0], size) and (not finite or np.isfinite(out).all()):
            return out
    return _check_each(name, outs, X, size)


def raise_call(name: str, exc: Exception, x: np.ndarray, args: tuple = (), fn: Callable | None = None) -> None:
    """Raise :func:`call_checked`'s error for the function `fn`, named `name`, that raised `exc` on the input `x`
    (and `args`)."""
    def again(*_):
        raise exc

    call_checked(name, again, x, args, (), user=fn)


def _takes_one(fn: Callable) -> bool:
    """Whether `fn` can be called with one argument (True where its signature is not known): f(x, u) cannot,
    which is what the user meant whose f asks for a control and who gave no `us` (audit Y3). A TypeError raised
    inside an f that takes one argument is not that (review R10)."""
    import inspect

    try:
        inspect.signature(fn).bind(None)
    except TypeError:
        return False
    except ValueError:  # no signature (a builtin, a compiled function)
        return True
    return True


def _check_each(name: str, outs: list, X: np.ndarray, size: int) -> np.ndarray:
    """`outs` (returned by f or h at the rows of X) through :func:`call_checked`, in order, stacked."""
    because = size_reason(name, size)
    checked = [call_checked(name, lambda *_: out, x, (), (size,), because) for out, x in zip(outs, X)]
    return np.stack(checked) if checked else np.empty((0, size))


class StepOverflowError(ValueError):
    """A step that overflows (:func:`finite_step`); the outermost step function names itself."""


def finite_step(result: str) -> Callable:
    """Decorate a function or method of a step ``dt`` so that a `result` overflowing float64 is a ValueError.

    A step long enough for a power of ``dt`` to pass 1e308 gives inf or NaN
    (or Python's OverflowError, from a power of a Python float); the message
    names the step and the model (the class of a method, else the function)
    instead.
    """
    def decorate(fn: Callable) -> Callable:
        @wraps(fn)
        def checked(*args, **kwargs):
            try:
                with np.errstate(over="ignore", invalid="ignore"):
                    out = fn(*args, **kwargs)
                finite = all(a is None or np.isfinite(a).all() for a in (out if isinstance(out, tuple) else (out,)))
            except (OverflowError, StepOverflowError):  # a power of a Python float; a step function it called
                finite = False
            if not finite:
                method = "." in fn.__qualname__
                given = signature(fn).bind(*args, **kwargs).arguments
                # the step: `dt`, or a user's own motion's first argument after self, whatever its name
                dt = given["dt"] if "dt" in given else list(given.values())[1 if method else 0]
                owner = type(args[0]).__name__ if method else f"{fn.__name__}()"
                shown = f"{float(dt):g}" if isinstance(dt, (int, float, np.integer, np.floating)) else repr(dt)
                raise StepOverflowError(f"a step of dt = {shown} s is too long for {owner}: its {result} "
                                        "overflows float64 (inf or NaN; or its noise intensity is that large).")
            return out
        return checked
    return decorate


def generator(rng) -> np.random.Generator:
    """`rng` as a NumPy Generator: None (fresh entropy), a seed, or a Generator (used as is).

    Raises
    ------
    TypeError, ValueError
        For anything else, naming `rng` (NumPy's own messages do not; and
        ``default_rng(True)`` is the seed 1): a ValueError for a negative
        integer, a TypeError for what is not a seed at all.
    """
    try:
        if isinstance(rng, (bool, np.bool_)):
            raise TypeError
        return np.random.default_rng(rng)
    except (TypeError, ValueError) as exc:
        kind = ValueError if isinstance(rng, (int, np.integer)) and not isinstance(rng, (bool, np.bool_)) else TypeError
        raise kind(f"`rng` must be None, a non-negative integer seed or a numpy.random.Generator; "
                   f"got {rng!r}.") from exc


def component_mask(name: str, value, size: int) -> np.ndarray:
    """A read-only boolean mask of length `size` from a boolean mask or a sequence of component indices.

    A sequence of booleans is a mask and must have length `size`; a sequence of
    integers lists components (negative ones count from the end). A mix of the
    two is ambiguous (True is also the index 1) and is refused.
    """
    items = list(np.asarray(value if value is not None else (), dtype=object).reshape(-1))
    flags = [isinstance(i, (bool, np.bool_)) for i in items]
    if items and all(flags):
        if len(items) != size:
            raise ValueError(
                f"`{name}` as a boolean mask must have length {size}, one entry per component; "
                f"got length {len(items)}."
            )
        mask = np.array(items, dtype=bool)
    elif any(flags):
        raise ValueError(
            f"`{name}` must be a boolean mask of length {size} or a sequence of component indices, "
            f"not a mix of booleans and numbers; got {items}."
        )
    else:
        mask = np.zeros(size, dtype=bool)
        for i in items:
            if not isinstance(i, (int, np.integer)) or not -size <= i < size:
                raise ValueError(
                    f"`{name}` must hold component indices in [-{size}, {size}) (negative ones count from the end) "
                    f"or be a boolean mask of "
                    f"length {size}; got {items}."
                )
            mask[i] = True
    mask.setflags(write=False)
    return mask
