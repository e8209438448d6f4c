"""Nonlinear state-space models with additive Gaussian noise."""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from .._validation import (as_matrix, call_checked, call_each, check_psd, component_mask, flag, integer, real,
                           size_reason)
from ._base import Frozen, check_names, check_step

__all__ = ["NonlinearModel"]


class NonlinearModel(Frozen):
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
    dt : float, optional
        The time step f and Q are for, when known (see
        :class:`LinearModel`'s `dt`).
    p : int, optional
        The number of control components f takes, when known: the filters
        then require ``us`` of that width (``f(x, u)`` with u of shape
        (p,)). None (the default): controls are optional and passed to f
        as given.
    names : sequence of n str, optional
        The state components' names (see :class:`LinearModel`'s `names`).

    Notes
    -----
    Complex-step differentiation assumes f and h are analytic in the real
    variables. Operations that drop the imaginary part (``abs``,
    ``np.linalg.norm``, ``np.vdot``, ``np.real``, ``np.angle``) give a
    derivative of 0 through them. So the first three Jacobians of f, and
    of h, in each run are checked row by row against central differences
    along each component, and a function that fails the check (a range by
    ``np.linalg.norm``, a pseudorange ``np.linalg.norm(p - s) + b`` with a
    clock bias b) is differentiated by finite differences from then on;
    after them, only an output whose whole derivative comes out faint is
    checked again. A function that drops the imaginary part at some states
    and not at the first three (behind a branch on x), or whose dropped
    part is hidden by its curvature over a thousandth of the belief's
    spread, can give a wrong derivative silently. Pass analytic Jacobians for
    such functions, or write them analytically (``np.sqrt`` of a sum of
    squares) for exact derivatives.

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
                 "state_angles", "measurement_angles", "dt", "p", "names")

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
        dt: float | None = None,
        p: int | None = None,
        names=None,
    ) -> None:
        for name, fn, required in (("f", f, True), ("h", h, True),
                                   ("f_jacobian", f_jacobian, False),
                                   ("h_jacobian", h_jacobian, False)):
            if (fn is not None or required) and not callable(fn):
                raise TypeError(f"`{name}` must be callable; got {type(fn).__name__}.")
        Q = as_matrix("Q", Q, None, None, row_name="n")  # ((m, n) it said: audit TT3)
        if Q.shape[-1] != Q.shape[-2]:
            raise ValueError(f"`Q` must be square, of shape (n, n) or (T, n, n); got shape {Q.shape}.")
        R = as_matrix("R", R, None, None, col_name="m")
        if R.shape[-1] != R.shape[-2]:
            raise ValueError(f"`R` must be square, of shape (m, m) or (T, m, m); got shape {R.shape}.")
        Q, R = check_psd("Q", Q), check_psd("R", R)
        if Q.ndim == 3 and R.ndim == 3 and Q.shape[0] != R.shape[0]:
            raise ValueError(
                f"time-varying matrices must all have the same number of steps; "
                f"`Q` has {Q.shape[0]}, `R` has {R.shape[0]}."
            )
        flag("vectorized", vectorized)
        Q.setflags(write=False)
        R.setflags(write=False)
        values = dict(
            f=f, h=h, Q=Q, R=R, f_jacobian=f_jacobian, h_jacobian=h_jacobian,
            vectorized=bool(vectorized),
            state_angles=component_mask("state_angles", state_angles, Q.shape[-1]),
            measurement_angles=component_mask("measurement_angles", measurement_angles, R.shape[-1]),
        )
        for name, value in values.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "dt", None if dt is None else real("dt", dt, positive=True))
        object.__setattr__(self, "p", None if p is None else integer("p", p, minimum=0))
        object.__setattr__(self, "names", check_names(names, Q.shape[-1], None))

    def __reduce__(self):
        # Pickled and copied by its arguments, rebuilt (validated, read-only) by the constructor.
        # f, h and the Jacobians pickle as themselves: a lambda or a closure raises pickle's own
        # error; a module-level function, a partial of one or a picklable callable object works.
        angles = {name: tuple(np.flatnonzero(getattr(self, name)).tolist())
                  for name in ("state_angles", "measurement_angles")}
        return (functools.partial(type(self), **angles, dt=self.dt, p=self.p, names=self.names),
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
        """``(Q, R)`` in force at step k.

        Parameters
        ----------
        k : int
            The step, from 0 (below :attr:`steps` for a time-varying model);
            a time-invariant matrix is the same at every step.

        Returns
        -------
        Q : ndarray of shape (n, n)
            Process-noise covariance.
        R : ndarray of shape (m, m)
            Measurement-noise covariance.

        Raises
        ------
        TypeError, ValueError
            When `k` is not an integer, or not a step of the model.
        """
        k = check_step(k, self.steps)
        return tuple(a[k] if a.ndim == 3 else a for a in (self.Q, self.R))

    def __repr__(self) -> str:
        return f"NonlinearModel(n={self.n}, m={self.m}, vectorized={self.vectorized})"

    # -- evaluation with checked shapes ------------------------------------

    def transition(self, X: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """``f`` at the states X of shape (n,) or (k, n); returns the same shape.

        Parameters
        ----------
        X : ndarray of shape (n,) or (k, n)
            A state, or a stack of k states.
        u : ndarray, optional
            The control, passed to f as its second argument (the same for
            every state of the stack); f takes only x when None.

        Returns
        -------
        ndarray of shape (n,) or (k, n)
            ``f(x[, u])`` for each state, its shape checked.
        """
        args = () if u is None else (u,)
        return _evaluate("f", self.f, X, args, self.n, self.vectorized)

    def measurement(self, X: np.ndarray) -> np.ndarray:
        """``h`` at the states X of shape (n,) or (k, n); returns (m,) or (k, m).

        Parameters
        ----------
        X : ndarray of shape (n,) or (k, n)
            A state, or a stack of k states.

        Returns
        -------
        ndarray of shape (m,) or (k, m)
            ``h(x)`` for each state, its shape checked.
        """
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
    return call_each(name, fn, X, args, size)
