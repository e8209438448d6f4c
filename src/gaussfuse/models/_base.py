"""What motion and sensor models share: the immutable base and the validators of their settings."""

from __future__ import annotations

import numpy as np

from .._validation import as_array, as_numbers, integer, is_integer, shape_error, shown_integer

__all__ = ["Frozen", "check_dim", "check_noise_kind", "check_names", "check_state", "check_step", "check_step_sizes"]

def check_dim(value) -> int:
    """`dim`, the number of spatial axes: an integer 1, 2 or 3 (TypeError for another type, as for every integer
    argument: 2.0 was a ValueError, audit VV4; ValueError for another integer)."""
    if not is_integer(value):
        raise TypeError(f"`dim` must be an integer 1, 2 or 3; got {value!r} ({type(value).__name__}).")
    if not 1 <= value <= 3:
        raise ValueError(f"`dim` must be 1, 2 or 3; got {shown_integer(value)}.")
    return int(value)


def check_step(k, steps: int | None) -> int:
    """`k` as a step of a model: an integer from 0, below `steps` where the model is time-varying over `steps`.

    A negative step read a time-varying model's matrices from its end, one past its last raised NumPy's
    IndexError, and None added an axis (audit GG5).
    """
    if is_integer(k) and 0 <= k and (
            steps is None or k < steps):
        return k
    k = integer("k", k, minimum=0)
    raise ValueError(f"`k` must be a step of the model, 0 to {steps - 1} (it is time-varying over {steps} "
                     f"steps); got {k}.")


def check_step_sizes(dts, expected: str = "(k,)", empty: bool = True) -> np.ndarray:
    """`dts` as float64 of shape (k,) (k >= 1 unless `empty`), each a positive time step; the errors name `dts`,
    the `expected` shape, and the first step that is not positive (TimedModel.at's, and the motions' transitions:
    their closed forms took dt = -1 into a Q with a negative eigenvalue, audit MM2)."""
    dts = as_array("dts", dts, copy=False)
    if dts.ndim != 1 or not (empty or dts.size):
        raise shape_error("dts", expected, dts.shape)
    bad = np.flatnonzero(~(dts > 0.0))
    if bad.size:
        raise ValueError(f"`dts` must be positive step sizes; got {float(dts[bad[0]])!r} at index {bad[0]}.")
    return dts


def check_noise_kind(value) -> str:
    if not isinstance(value, str) or value not in ("continuous", "piecewise"):
        raise ValueError(f"`noise` must be 'continuous' or 'piecewise'; got {value!r}.")
    return value


def check_names(value, n: int, default: tuple[str, ...]) -> tuple[str, ...]:
    """A tuple of n strings (component names), or `default` for None."""
    if value is None:
        return default
    # (a 0-d array has __iter__ and raised NumPy's own "iteration over a 0-d array", naming nothing: audit VV5)
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__") or np.ndim(value) == 0:
        raise TypeError(f"`names` must be a sequence of {n} strings; got {value!r}.")
    names = tuple(value)
    if not all(isinstance(s, str) for s in names):
        raise TypeError(f"`names` must be a sequence of {n} strings; got {value!r}.")
    names = tuple(str(s) for s in names)  # (NumPy's str_ of a str array printed as np.str_('a') in reprs)
    if len(names) != n:
        raise ValueError(f"`names` must have {n} entries, one per component; got {len(names)}.")
    if not all(names) or len(set(names)) != n:  # they label columns (review R13)
        raise ValueError(f"`names` must be distinct and non-empty; got {list(names)!r:.200}.")
    taken = sorted(set(names) & {f"{name}_sd" for name in names})
    if taken:  # to_pandas names a standard deviation so (review R14)
        raise ValueError(f"`names` must not hold a name with '_sd' after another, the column of its standard "
                         f"deviation; got {taken[0]!r}.")
    return names


def check_state(x, n: int, name: str = "x") -> np.ndarray:
    """`x` as an array of shape (n,) or (k, n), real or complex (for complex-step derivatives)."""
    arr = as_numbers(name, x)
    if arr.ndim not in (1, 2) or arr.shape[-1] != n:
        raise ValueError(f"`{name}` must have shape ({n},) or (k, {n}); got shape {arr.shape}.")
    return arr


class Frozen:
    """Immutable value: slots set once in ``__init__`` through `_set`; pickles by its arguments."""

    __slots__ = ()

    def _set(self, **values) -> None:
        for name, value in values.items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, name, value)

    def __setattr__(self, name, value):
        raise AttributeError(f"{type(self).__name__} is immutable; build a new one instead.")

    def __delattr__(self, name):
        raise AttributeError(f"{type(self).__name__} is immutable; build a new one instead.")

    def _fields(self) -> tuple[str, ...]:
        """The constructor's arguments, in order: the slots of the class and its bases."""
        return tuple(s for cls in reversed(type(self).__mro__) for s in cls.__dict__.get("__slots__", ()))

    def __reduce__(self):
        return type(self), tuple(getattr(self, s) for s in self._fields())

    def __repr__(self) -> str:
        args = ", ".join(f"{s}={getattr(self, s)!r}" for s in self._fields())
        return f"{type(self).__name__}({args})"
