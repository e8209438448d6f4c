"""Nonlinear state-space models with additive Gaussian noise."""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from .._validation import as_matrix, check_psd
from ..kalman import wrap_angle

__all__ = ["NonlinearModel", "ModelFunctionError", "wrap_angle", "call_checked", "size_reason"]


class ModelFunctionError(ValueError):
    """A model function (f, h or a Jacobian) raised, or returned a bad value."""


def _indices(name: str, value, size: int) -> np.ndarray:
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
                    f"`{name}` must hold component indices in [0, {size}) or be a boolean mask of "
                    f"length {size}; got {items}."
                )
            mask[i] = True
    mask.setflags(write=False)
    return mask


class NonlinearModel:
    r"""A nonlinear state-space model with additive Gaussian noise.

    .. math::

        x_k = f(x_{k-1}[, u_k]) + w_k, \quad w_k \sim N(0, Q_k), \\
        z_k = h(x_k) + v_k, \quad v_k \sim N(0, R_k).

    Parameters
    ----------
    f : callable
        Dynamics: ``f(x)`` with x of shape (n,) returning shape (n,), or
        ``f(x, u)`` when controls are given to the filter.
    h : callable
        Measurement: ``h(x)`` returning shape (m,) (or a scalar when m = 1).
    Q : array_like of shape (n, n) or (T, n, n)
        Process-noise covariance.
    R : array_like of shape (m, m) or (T, m, m)
        Measurement-noise covariance; a scalar when m = 1.
    f_jacobian, h_jacobian : callable, optional
        ``f_jacobian(x[, u])`` of shape (n, n) and ``h_jacobian(x)`` of shape
        (m, n). When absent, Jacobians are computed by complex-step
        differentiation (exact to round-off for functions built from
        analytic NumPy operations), falling back to adaptive finite
        differences (:func:`scipy.differentiate.jacobian`) for functions
        that reject complex input.
    vectorized : bool, default False
        If True, f and h take a stack of states of shape (k, n) and return
        (k, n) and (k, m), so sigma-point filters call each once per step.
    state_angles, measurement_angles : sequence of int or of bool, optional
        Components that are angles in radians: their residuals are wrapped
        to [-π, π), and means over sigma points are circular means. Either
        the components' indices, or a boolean mask with one entry per
        component.

    Notes
    -----
    Complex-step differentiation assumes f and h are analytic in the real
    variables: functions using ``abs``, ``np.maximum`` or comparisons give
    wrong complex-step derivatives silently; pass analytic Jacobians for them.

    The model is immutable. It copies (``copy.copy``, ``copy.deepcopy``)
    whatever its functions, and pickles when they do: module-level
    functions, :func:`functools.partial` of them, or instances of
    module-level classes with ``__call__``; not lambdas or closures.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> dt = 0.01
    >>> pendulum = gf.NonlinearModel(
    ...     f=lambda x: np.array([x[0] + dt * x[1], x[1] - 9.81 * np.sin(x[0]) * dt]),
    ...     h=lambda x: np.sin(x[:1]),
    ...     Q=0.01 * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]),
    ...     R=0.1,
    ... )
    >>> pendulum.n, pendulum.m
    (2, 1)
    """

    __slots__ = ("f", "h", "Q", "R", "f_jacobian", "h_jacobian", "vectorized",
                 "state_angles", "measurement_angles")

    def __init__(
        self,
        f: Callable,
        h: Callable,
        Q,
        R,
        f_jacobian: Callable | None = None,
        h_jacobian: Callable | None = None,
        vectorized: bool = False,
        *,
        state_angles=(),
        measurement_angles=(),
    ) -> None:
        for name, fn, required in (("f", f, True), ("h", h, True),
                                   ("f_jacobian", f_jacobian, False),
                                   ("h_jacobian", h_jacobian, False)):
            if (fn is not None or required) and not callable(fn):
                raise TypeError(f"`{name}` must be callable; got {type(fn).__name__}.")
        Q = as_matrix("Q", Q, None, None)
        if Q.shape[-1] != Q.shape[-2]:
            raise ValueError(f"`Q` must be square, of shape (n, n) or (T, n, n); got shape {Q.shape}.")
        R = as_matrix("R", R, None, None)
        if R.shape[-1] != R.shape[-2]:
            raise ValueError(f"`R` must be square, of shape (m, m) or (T, m, m); got shape {R.shape}.")
        Q, R = check_psd("Q", Q), check_psd("R", R)
        if Q.ndim == 3 and R.ndim == 3 and Q.shape[0] != R.shape[0]:
            raise ValueError(
                f"time-varying matrices must all have the same number of steps; "
                f"`Q` has {Q.shape[0]}, `R` has {R.shape[0]}."
            )
        if not isinstance(vectorized, (bool, np.bool_)):
            raise TypeError(f"`vectorized` must be True or False; got {vectorized!r}.")
        Q.setflags(write=False)
        R.setflags(write=False)
        values = dict(
            f=f, h=h, Q=Q, R=R, f_jacobian=f_jacobian, h_jacobian=h_jacobian,
            vectorized=bool(vectorized),
            state_angles=_indices("state_angles", state_angles, Q.shape[-1]),
            measurement_angles=_indices("measurement_angles", measurement_angles, R.shape[-1]),
        )
        for name, value in values.items():
            object.__setattr__(self, name, value)

    def __setattr__(self, name, value):
        raise AttributeError("NonlinearModel is immutable; build a new one instead.")

    def __reduce__(self):
        # Pickled and copied by its arguments, rebuilt (validated, read-only) by the constructor.
        # f, h and the Jacobians pickle as themselves: a lambda or a closure raises pickle's own
        # error; a module-level function, a partial of one or a picklable callable object works.
        angles = {name: tuple(np.flatnonzero(getattr(self, name)).tolist())
                  for name in ("state_angles", "measurement_angles")}
        return (functools.partial(type(self), **angles),
                (self.f, self.h, self.Q, self.R, self.f_jacobian, self.h_jacobian, self.vectorized))

    @property
    def n(self) -> int:
        """State dimension."""
        return self.Q.shape[-1]

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.R.shape[-1]

    @property
    def steps(self) -> int | None:
        """Number of steps T of a time-varying Q or R, ``None`` otherwise."""
        for a in (self.Q, self.R):
            if a.ndim == 3:
                return a.shape[0]
        return None

    def noise(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(Q, R)`` in force at step k."""
        return tuple(a[k] if a.ndim == 3 else a for a in (self.Q, self.R))

    def __repr__(self) -> str:
        return f"NonlinearModel(n={self.n}, m={self.m}, vectorized={self.vectorized})"

    # -- evaluation with checked shapes ------------------------------------

    def transition(self, X: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """``f`` at the states X of shape (n,) or (k, n); returns the same shape."""
        args = () if u is None else (u,)
        return _evaluate("f", self.f, X, args, self.n, self.vectorized)

    def measurement(self, X: np.ndarray) -> np.ndarray:
        """``h`` at the states X of shape (n,) or (k, n); returns (m,) or (k, m)."""
        return _evaluate("h", self.h, X, (), self.m, self.vectorized)


def _evaluate(name: str, fn: Callable, X: np.ndarray, args: tuple, size: int, vectorized: bool) -> np.ndarray:
    """Call a model function on one state or a stack, checking what comes back."""
    because = size_reason(name, size)
    if X.ndim == 1:
        if vectorized:
            return call_checked(name, fn, X[None], args, (1, size), because)[0]
        return call_checked(name, fn, X, args, (size,), because)
    if vectorized:
        return call_checked(name, fn, X, args, (X.shape[0], size), because)
    return np.stack([call_checked(name, fn, x, args, (size,), because) for x in X])


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
                 because: str | None = None) -> np.ndarray:
    """Call ``fn(x, *args)`` and check that it returns a finite array of `shape`.

    `because` says what fixed `shape` (see :func:`size_reason`), for the
    message of a wrong shape.

    Raises
    ------
    ModelFunctionError
        Naming the function, the input shape and what went wrong: an
        exception, a wrong shape, values that are complex, boolean or dates,
        or a non-finite value.
    """
    try:
        out = fn(x, *args)
    except Exception as exc:  # a user's function may raise anything
        raise ModelFunctionError(
            f"`{name}` raised {type(exc).__name__} on an input of shape {x.shape}: {exc}"
        ) from exc
    try:
        kind = np.asarray(out).dtype.kind
    except (TypeError, ValueError):  # ragged: the cast below says so
        kind = None
    if kind in ("c", "b", "M", "m"):
        # Before the cast, which would drop an imaginary part or turn True into 1.0.
        what = {"c": "complex", "b": "boolean", "M": "datetime64", "m": "timedelta64"}[kind]
        raise ModelFunctionError(
            f"`{name}` must return an array of real numbers; got {what} values for an input of shape {x.shape}."
        )
    try:
        out = np.asarray(out, dtype=np.float64)
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
