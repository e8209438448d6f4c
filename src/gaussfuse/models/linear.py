"""Linear-Gaussian state-space models."""

from __future__ import annotations

import numpy as np

from .._validation import as_matrix, check_psd, real
from ._base import Frozen, check_names, check_step

__all__ = ["LinearModel"]


class LinearModel(Frozen):
    r"""A linear-Gaussian state-space model with optional control input.

    .. math::

        x_k = F_k x_{k-1} + B_k u_k + w_k, \quad w_k \sim N(0, Q_k), \\
        z_k = H_k x_k + v_k, \quad v_k \sim N(0, R_k).

    Parameters
    ----------
    F : array_like of shape (n, n) or (T, n, n)
        State-transition matrix.
    H : array_like of shape (m, n) or (T, m, n)
        Measurement matrix; a 1-D array of length n is a single row.
    Q : array_like of shape (n, n) or (T, n, n)
        Process-noise covariance, symmetric positive semi-definite.
    R : array_like of shape (m, m) or (T, m, m)
        Measurement-noise covariance, symmetric positive semi-definite; a
        scalar when m = 1.
    B : array_like of shape (n, p) or (T, n, p), optional
        Control-input matrix; a 1-D array of length n is a single column.
    dt : float, optional
        The time step the matrices are for, when they come from one (as
        :func:`gaussfuse.model` records): `times` given to a filter must
        then be that regular.
    names : sequence of n str, optional
        The state components' names, which results' ``to_pandas`` use
        (:func:`gaussfuse.model` records its motion's, such as
        ``("x", "vx")``); default x0, x1, ....

    Notes
    -----
    Any matrix with a leading time axis is time-varying: its entry ``[k]`` is
    used at step k (the transition into, and the measurement of, the k-th
    state). All time-varying matrices must have the same number of steps T,
    and a series filtered with the model must have T steps.

    The model is immutable: its arrays are read-only. It pickles and copies
    (``copy.copy``, ``copy.deepcopy``) as a new, equally immutable model.

    Examples
    --------
    >>> import gaussfuse as gf
    >>> model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=[[1, 0], [0, 3]], R=10)
    >>> model.n, model.m, model.p
    (2, 1, 0)
    """

    __slots__ = ("F", "H", "Q", "R", "B", "dt", "names")

    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    B: np.ndarray | None
    dt: float | None
    names: tuple[str, ...] | None

    def __init__(self, F, H, Q, R, B=None, dt: float | None = None, names=None) -> None:
        F = as_matrix("F", F, None, None, row_name="n")
        if F.shape[-1] != F.shape[-2]:
            raise ValueError(
                f"`F` must be square, of shape (n, n) or (T, n, n); got shape {F.shape}."
            )
        n = F.shape[-1]
        states = f"`F` is {n} × {n} ({n} state component{'s' if n > 1 else ''})"
        H = as_matrix("H", H, None, n, row_vector_ok=True, because=states)
        m = H.shape[-2]
        Q = check_psd("Q", as_matrix("Q", Q, n, n, because=states))
        R = check_psd("R", as_matrix("R", R, m, m, because=f"`H` has {m} row{'s' if m > 1 else ''} "
                                                         f"({m} measurement component{'s' if m > 1 else ''})"))
        if B is not None:
            B = as_matrix("B", B, n, None, column_vector_ok=True, col_name="p", because=states)
        given = {"F": F, "H": H, "Q": Q, "R": R, "B": B}
        steps = {name: a.shape[0] for name, a in given.items() if a is not None and a.ndim == 3}
        if len(set(steps.values())) > 1:
            listed = ", ".join(f"`{k}` has {v}" for k, v in steps.items())
            raise ValueError(
                f"time-varying matrices must all have the same number of steps; {listed}."
            )
        for name, a in given.items():
            if a is not None:
                a.setflags(write=False)
            object.__setattr__(self, name, a)
        object.__setattr__(self, "dt", None if dt is None else real("dt", dt, positive=True))
        object.__setattr__(self, "names", check_names(names, n, None))

    @classmethod
    def _indexed(cls, distinct: LinearModel, index: np.ndarray) -> LinearModel:
        """The model whose step k has the matrices of `distinct`'s step ``index[k]``.

        `distinct` (time-varying, one step per distinct set of matrices) has
        been checked by the constructor; the T steps are taken from it
        without checking each again (a long series of a few distinct steps
        would otherwise pay an eigenvalue test per step).
        """
        out = object.__new__(cls)
        for name in ("F", "H", "Q", "R", "B"):
            a = getattr(distinct, name)
            if a is not None and a.ndim == 3:
                a = a[index]
                a.setflags(write=False)
            object.__setattr__(out, name, a)
        object.__setattr__(out, "dt", None)
        object.__setattr__(out, "names", distinct.names)
        return out

    def _replace(self, **changes) -> LinearModel:
        """The model with the given arguments (of the constructor: matrices, `dt`, `names`) changed and the
        others kept, checked as the constructor checks them (as a NamedTuple's ``_replace``)."""
        return type(self)(**{**{name: getattr(self, name) for name in self.__slots__}, **changes})

    def __reduce__(self):
        # Pickled and copied by its arguments: the constructor validates them again and
        # makes the arrays read-only, which the default protocol (setattr) cannot.
        return type(self), (self.F, self.H, self.Q, self.R, self.B, self.dt, self.names)

    @property
    def n(self) -> int:
        """State dimension."""
        return self.F.shape[-1]

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.H.shape[-2]

    @property
    def p(self) -> int:
        """Control dimension (0 without a control input)."""
        return 0 if self.B is None else self.B.shape[-1]

    @property
    def steps(self) -> int | None:
        """Number of steps T of a time-varying model, ``None`` if time-invariant."""
        for a in (self.F, self.H, self.Q, self.R, self.B):
            if a is not None and a.ndim == 3:
                return a.shape[0]
        return None

    def at(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """The matrices ``(F, H, Q, R, B)`` in force at step k.

        Parameters
        ----------
        k : int
            The step, from 0 (below :attr:`steps` for a time-varying model);
            a time-invariant matrix is the same at every step.

        Returns
        -------
        F : ndarray of shape (n, n)
            Transition matrix.
        H : ndarray of shape (m, n)
            Measurement matrix.
        Q : ndarray of shape (n, n)
            Process-noise covariance.
        R : ndarray of shape (m, m)
            Measurement-noise covariance.
        B : ndarray of shape (n, p) or None
            Control matrix; None without a control input.

        Raises
        ------
        TypeError, ValueError
            When `k` is not an integer, or not a step of the model.
        """
        k = check_step(k, self.steps)
        return tuple(None if a is None else (a[k] if a.ndim == 3 else a)
                     for a in (self.F, self.H, self.Q, self.R, self.B))

    def __repr__(self) -> str:
        tv = "" if self.steps is None else f", time-varying over {self.steps} steps"
        dt = "" if self.dt is None else f", dt={self.dt:g}"
        return f"LinearModel(n={self.n}, m={self.m}, p={self.p}{tv}{dt})"
