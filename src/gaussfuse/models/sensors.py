r"""Sensor models: what a sensor measures of the state.

- :class:`LinearSensor` and :class:`Position`: :math:`z = H x + v`;
- :class:`NonlinearSensor` and :class:`RangeBearing`,
  :class:`RangeBearingElevation`, :class:`BearingOnly`: :math:`z = h(x) + v`,

with :math:`v \sim N(0, R)`. The geometric sensors read the target's
position from the first 2 (or 3) state components, the convention of the
kinematic motion models (positions first). Combine a sensor with a motion
into a filterable model with :func:`gaussfuse.model`.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_matrix, as_numbers, as_vector, check_psd, integer, real
from ._base import Frozen, check_dim, check_names

__all__ = [
    "LinearSensor",
    "Position",
    "NonlinearSensor",
    "RangeBearing",
    "RangeBearingElevation",
    "BearingOnly",
]


class LinearSensor(Frozen):
    r"""A linear sensor :math:`z = H x + v`, :math:`v \sim N(0, R)`.

    Parameters
    ----------
    H : array_like of shape (m, n)
        Measurement matrix; a 1-D array of length n is a single row.
    R : array_like of shape (m, m)
        Measurement-noise covariance, symmetric positive semi-definite; a
        scalar when m = 1.
    names : sequence of m str, optional
        Names of the measured components; ``z0, z1, ...`` by default.

    Attributes
    ----------
    m : int
        Measurement dimension.
    measurement_angles : tuple of int
        Always empty for a linear sensor.

    Examples
    --------
    >>> from gaussfuse.models.sensors import LinearSensor
    >>> speed = LinearSensor([[0, 0, 1, 0], [0, 0, 0, 1]], [[0.1, 0], [0, 0.1]], names=("vx", "vy"))
    >>> speed.m, speed.names
    (2, ('vx', 'vy'))
    """

    __slots__ = ("H", "R", "names")

    def __init__(self, H, R, names=None) -> None:
        H = as_matrix("H", H, None, None, row_vector_ok=True, time_varying=False)
        m = H.shape[0]
        R = check_psd("R", as_matrix("R", R, m, m, time_varying=False,
                                     because=f"`H` has {m} row{'s' if m > 1 else ''}"))
        self._set(H=H, R=R, names=check_names(names, m, tuple(f"z{i}" for i in range(m))))

    @property
    def m(self) -> int:
        """Measurement dimension."""
        return self.R.shape[0]

    @property
    def measurement_angles(self) -> tuple[int, ...]:
        """Components that are angles: none for a linear sensor."""
        return ()

    def linear(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(H, R)`` for a state of n components; H has shape (m, n), R (m, m).

        Parameters
        ----------
        n : int
            State dimension; must equal the number of columns of `H`.

        Returns
        -------
        H : ndarray of shape (m, n)
            Measurement matrix.
        R : ndarray of shape (m, m)
            Measurement-noise covariance.
        """
        n = integer("n", n)
        if self.H.shape[1] != n:
            raise ValueError(f"`n` must be {self.H.shape[1]}, the number of columns of `H`; got {n}.")
        return self.H, self.R

    def __repr__(self) -> str:
        return f"LinearSensor(m={self.m}, n={self.H.shape[1]}, names={self.names!r})"


class Position(LinearSensor):
    r"""Measures the positions, the first `dim` state components, each with variance r.

    Parameters
    ----------
    dim : {1, 2, 3}
        Number of position components measured (x, y, z).
    r : float, default 1.0
        Variance of each position measurement, >= 0 (0: measured exactly).
    n : int, optional
        State dimension, >= dim. When omitted, H is built for the state of
        the motion the sensor is combined with (:meth:`linear`), and the
        attribute `H` is None.

    Notes
    -----
    :math:`H = [I_\text{dim}\;\; 0]` of shape (dim, n) and
    :math:`R = r I_\text{dim}`.

    Examples
    --------
    >>> from gaussfuse.models.sensors import Position
    >>> H, R = Position(dim=2, r=0.5).linear(4)
    >>> H
    array([[1., 0., 0., 0.],
           [0., 1., 0., 0.]])
    >>> R
    array([[0.5, 0. ],
           [0. , 0.5]])
    """

    __slots__ = ("dim", "r", "n")

    def __init__(self, dim: int = 1, r: float = 1.0, n: int | None = None) -> None:
        dim = check_dim(dim)
        r = real("r", r, nonnegative=True)
        if n is not None:
            n = integer("n", n, minimum=dim)
        self._set(dim=dim, r=r, n=n)

    def __reduce__(self):
        return Position, (self.dim, self.r, self.n)

    @property
    def H(self) -> np.ndarray | None:
        """``[I, 0]`` of shape (dim, n), or None when n is not set."""
        return None if self.n is None else np.eye(self.dim, self.n)

    @property
    def R(self) -> np.ndarray:
        """``r I`` of shape (dim, dim)."""
        return self.r * np.eye(self.dim)

    @property
    def names(self) -> tuple[str, ...]:
        """``x, (y, z)``."""
        return ("x", "y", "z")[: self.dim]

    def linear(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(H, R)`` for a state of n >= dim components (n as given at construction, if it was).

        Parameters
        ----------
        n : int
            State dimension, >= dim; must equal the `n` given at
            construction, if one was.

        Returns
        -------
        H : ndarray of shape (dim, n)
            ``[I, 0]``: the first dim state components.
        R : ndarray of shape (dim, dim)
            ``r I``.
        """
        n = integer("n", n, minimum=self.dim)
        if self.n is not None and n != self.n:
            raise ValueError(f"`n` must be {self.n}, as given to `Position`; got {n}.")
        return np.eye(self.dim, n), self.R

    def __repr__(self) -> str:
        return f"Position(dim={self.dim}, r={self.r!r}, n={self.n!r})"


class NonlinearSensor(Frozen):
    r"""Base class of nonlinear sensors :math:`z = h(x) + v`, :math:`v \sim N(0, R)`.

    Attributes
    ----------
    m : int
        Measurement dimension.
    names : tuple of str
        Names of the m measured components.
    measurement_angles : tuple of int
        Components that are angles in radians (residuals wrapped to [-π, π)).
    R : ndarray of shape (m, m)
        Measurement-noise covariance.

    Notes
    -----
    Subclasses implement ``h(x)`` (x of shape (n,) or a stack (k, n),
    returning (m,) or (k, m)) and ``jacobian(x)`` of shape (m, n).
    """

    __slots__ = ()

    m: int
    names: tuple[str, ...]
    R: np.ndarray

    @property
    def measurement_angles(self) -> tuple[int, ...]:
        """Components that are angles (none unless a subclass says so)."""
        return ()

    def h(self, x) -> np.ndarray:
        """The noise-free measurement of x.

        Parameters
        ----------
        x : array_like of shape (n,) or (k, n)
            A state, or a stack of k states.

        Returns
        -------
        ndarray of shape (m,) or (k, m)
            The measurement of the state (or of each state of the stack).
        """
        raise NotImplementedError

    def jacobian(self, x) -> np.ndarray:
        """The Jacobian of :meth:`h` with respect to x, shape (m, n).

        Parameters
        ----------
        x : array_like of shape (n,)
            The state at which it is taken.

        Returns
        -------
        ndarray of shape (m, n)
            ∂h/∂x at `x`.
        """
        raise NotImplementedError


def _position(x, k: int) -> tuple[np.ndarray, int]:
    """The state as an array (n,) or (j, n), n >= k (the position components), real or complex."""
    arr = as_numbers("x", x)
    if arr.ndim not in (1, 2) or arr.shape[-1] < k:
        raise ValueError(
            f"`x` must have shape (n,) or (j, n) with n >= {k} (the position comes first); "
            f"got shape {arr.shape}."
        )
    return arr, arr.shape[-1]


def _hypot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    r"""``√(a² + b²)`` without overflow or underflow: NumPy's hypot for real input, and for complex input (a
    complex step) the same analytic function on the scale of the real parts, :math:`s \sqrt{(a/s)^2 + (b/s)^2}`
    (NumPy's hypot has no complex loop: a NonlinearModel built on a sensor's h lost the complex step, audit TT2)."""
    if not (np.iscomplexobj(a) or np.iscomplexobj(b)):
        return np.hypot(a, b)
    s = np.maximum(np.abs(np.real(a)), np.abs(np.real(b)))
    s = np.where(s > 0.0, s, 1.0)
    return s * np.sqrt((a / s) ** 2 + (b / s) ** 2)


def _arctan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    r"""The angle of (x, y): NumPy's arctan2 for real input, and for a complex step its first-order extension,
    :math:`\operatorname{atan2}(y_r, x_r) + i\,(x_r y_i - y_r x_i) / (x_r^2 + y_r^2)` (exact to the step's
    square, far below round-off; the division on the scale of r, whose square overflows beyond 1e154)."""
    if not (np.iscomplexobj(x) or np.iscomplexobj(y)):
        return np.arctan2(y, x)
    xr, yr, r = np.real(x), np.real(y), np.hypot(np.real(x), np.real(y))
    r = np.where(r > 0.0, r, 1.0)
    return np.arctan2(yr, xr) + 1j * ((xr / r) * np.imag(y) - (yr / r) * np.imag(x)) / r


def _origin(value, k: int) -> np.ndarray:
    return as_vector("origin", value, k)


class RangeBearing(NonlinearSensor):
    r"""Range and bearing (2-D) from a sensor at `origin`.

    Parameters
    ----------
    r_range : float, default 1.0
        Variance of the range, >= 0.
    r_bearing : float, default 1e-4
        Variance of the bearing (rad²), >= 0.
    origin : array_like of shape (2,), default (0, 0)
        Sensor position.

    Attributes
    ----------
    m : int
        2: ``[range, bearing]``; the bearing (component 1) is an angle.

    Notes
    -----
    With :math:`\delta = (x - o_x, y - o_y)` and :math:`\rho = \|\delta\|`,

    .. math::

        h(x) = \begin{bmatrix} \rho \\ \operatorname{atan2}(\delta_y, \delta_x)
        \end{bmatrix}, \qquad
        \frac{\partial h}{\partial (x, y)} = \begin{bmatrix}
        \delta_x/\rho & \delta_y/\rho \\ -\delta_y/\rho^2 & \delta_x/\rho^2
        \end{bmatrix},

    zero in the other columns; :math:`R = \mathrm{diag}(r_\text{range},
    r_\text{bearing})`. The Jacobian is undefined at the sensor (ρ = 0).

    Examples
    --------
    >>> from gaussfuse.models.sensors import RangeBearing
    >>> RangeBearing(origin=(1.0, 0.0)).h([1.0, 2.0, 0.3, 0.4])
    array([2.        , 1.57079633])
    """

    __slots__ = ("r_range", "r_bearing", "origin")

    def __init__(self, r_range: float = 1.0, r_bearing: float = 1e-4, origin=(0.0, 0.0)) -> None:
        self._set(r_range=real("r_range", r_range, nonnegative=True),
                  r_bearing=real("r_bearing", r_bearing, nonnegative=True),
                  origin=_origin(origin, 2))

    m = property(lambda self: 2, doc="Measurement dimension, 2.")
    dim = property(lambda self: 2, doc="Position components read, 2.")
    names = property(lambda self: ("range", "bearing"), doc="``('range', 'bearing')``.")
    measurement_angles = property(lambda self: (1,), doc="``(1,)``: the bearing.")

    @property
    def R(self) -> np.ndarray:
        """``diag(r_range, r_bearing)``."""
        return np.diag([self.r_range, self.r_bearing])

    def h(self, x) -> np.ndarray:
        """``[range, bearing]`` of shape (2,) (or (j, 2) for a stack of states).

        Parameters
        ----------
        x : array_like of shape (n,) or (j, n)
            A state, or a stack of j states, with the position ``(x, y)`` in
            its first 2 components (n >= 2).

        Returns
        -------
        ndarray of shape (2,) or (j, 2)
            The range and the bearing (radians) from `origin`.
        """
        x, _ = _position(x, 2)
        dx, dy = x[..., 0] - self.origin[0], x[..., 1] - self.origin[1]
        return np.stack([_hypot(dx, dy), _arctan2(dy, dx)], axis=-1)

    def jacobian(self, x) -> np.ndarray:
        """∂h/∂x of shape (2, n).

        Parameters
        ----------
        x : array_like of shape (n,) or (j, n)
            The state (or stack of j states) at which it is taken, position
            first (n >= 2).

        Returns
        -------
        ndarray of shape (2, n) or (j, 2, n)
            The Jacobian, zero past the first 2 columns; NaN at the sensor's
            own position, where it is undefined.
        """
        x, n = _position(x, 2)
        dx, dy = x[..., 0] - self.origin[0], x[..., 1] - self.origin[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.hypot(dx, dy)  # never dx² + dy²: it overflows beyond 1e154 and underflows below 1e-154
            ux, uy = dx / r, dy / r
            J = np.zeros(x.shape[:-1] + (2, n))
            J[..., 0, 0], J[..., 0, 1] = ux, uy
            J[..., 1, 0], J[..., 1, 1] = -uy / r, ux / r
        return J


class RangeBearingElevation(NonlinearSensor):
    r"""Range, bearing and elevation (3-D) from a sensor at `origin`.

    Parameters
    ----------
    r_range : float, default 1.0
        Variance of the range, >= 0.
    r_bearing : float, default 1e-4
        Variance of the bearing (rad²), >= 0.
    r_elevation : float, default 1e-4
        Variance of the elevation (rad²), >= 0.
    origin : array_like of shape (3,), default (0, 0, 0)
        Sensor position.

    Attributes
    ----------
    m : int
        3: ``[range, bearing, elevation]``; the bearing (component 1) is an
        angle; the elevation lies in [-π/2, π/2] (±π/2 straight above or
        below the sensor) and is not wrapped.

    Notes
    -----
    With :math:`\delta = p - o`, :math:`\rho = \|\delta\|`,
    :math:`\rho_{xy} = \sqrt{\delta_x^2 + \delta_y^2}`,

    .. math::

        h(x) = \begin{bmatrix} \rho \\ \operatorname{atan2}(\delta_y, \delta_x) \\
        \operatorname{atan2}(\delta_z, \rho_{xy}) \end{bmatrix}, \qquad
        \frac{\partial h}{\partial (x, y, z)} = \begin{bmatrix}
        \delta_x/\rho & \delta_y/\rho & \delta_z/\rho \\
        -\delta_y/\rho_{xy}^2 & \delta_x/\rho_{xy}^2 & 0 \\
        -\delta_x\delta_z/(\rho^2\rho_{xy}) & -\delta_y\delta_z/(\rho^2\rho_{xy}) & \rho_{xy}/\rho^2
        \end{bmatrix}.

    The Jacobian is undefined on the vertical through the sensor
    (:math:`\rho_{xy} = 0`).

    Examples
    --------
    >>> import numpy as np
    >>> from gaussfuse.models.sensors import RangeBearingElevation
    >>> np.round(RangeBearingElevation().h([1.0, 1.0, np.sqrt(2.0)]), 6)
    array([2.      , 0.785398, 0.785398])
    """

    __slots__ = ("r_range", "r_bearing", "r_elevation", "origin")

    def __init__(self, r_range: float = 1.0, r_bearing: float = 1e-4, r_elevation: float = 1e-4,
                 origin=(0.0, 0.0, 0.0)) -> None:
        self._set(r_range=real("r_range", r_range, nonnegative=True),
                  r_bearing=real("r_bearing", r_bearing, nonnegative=True),
                  r_elevation=real("r_elevation", r_elevation, nonnegative=True),
                  origin=_origin(origin, 3))

    m = property(lambda self: 3, doc="Measurement dimension, 3.")
    dim = property(lambda self: 3, doc="Position components read, 3.")
    names = property(lambda self: ("range", "bearing", "elevation"),
                     doc="``('range', 'bearing', 'elevation')``.")
    measurement_angles = property(lambda self: (1,), doc="``(1,)``: the bearing.")

    @property
    def R(self) -> np.ndarray:
        """``diag(r_range, r_bearing, r_elevation)``."""
        return np.diag([self.r_range, self.r_bearing, self.r_elevation])

    def h(self, x) -> np.ndarray:
        """``[range, bearing, elevation]`` of shape (3,) (or (j, 3)).

        Parameters
        ----------
        x : array_like of shape (n,) or (j, n)
            A state, or a stack of j states, with the position ``(x, y, z)``
            in its first 3 components (n >= 3).

        Returns
        -------
        ndarray of shape (3,) or (j, 3)
            The range, the bearing and the elevation (radians) from `origin`.
        """
        x, _ = _position(x, 3)
        dx, dy, dz = (x[..., i] - self.origin[i] for i in range(3))
        rxy = _hypot(dx, dy)
        return np.stack([_hypot(rxy, dz), _arctan2(dy, dx), _arctan2(dz, rxy)], axis=-1)

    def jacobian(self, x) -> np.ndarray:
        """∂h/∂x of shape (3, n).

        Parameters
        ----------
        x : array_like of shape (n,) or (j, n)
            The state (or stack of j states) at which it is taken, position
            first (n >= 3).

        Returns
        -------
        ndarray of shape (3, n) or (j, 3, n)
            The Jacobian, zero past the first 3 columns; on the vertical
            through the sensor, where the bearing and elevation are not
            differentiable in x and y, their x and y columns hold NaN; at
            the sensor itself, the range's row and the elevation's z
            column too.
        """
        x, n = _position(x, 3)
        dx, dy, dz = (x[..., i] - self.origin[i] for i in range(3))
        with np.errstate(divide="ignore", invalid="ignore"):
            rxy = np.hypot(dx, dy)  # never sums of squares: they overflow beyond 1e154 and underflow below 1e-154
            r = np.hypot(rxy, dz)
            cx, cy = dx / rxy, dy / rxy  # the bearing's cosine and sine
            J = np.zeros(x.shape[:-1] + (3, n))
            J[..., 0, 0], J[..., 0, 1], J[..., 0, 2] = dx / r, dy / r, dz / r
            J[..., 1, 0], J[..., 1, 1] = -cy / rxy, cx / rxy
            J[..., 2, 0] = -cx * (dz / r) / r
            J[..., 2, 1] = -cy * (dz / r) / r
            J[..., 2, 2] = (rxy / r) / r
        return J


class BearingOnly(NonlinearSensor):
    r"""Bearing only (2-D) from a sensor at `origin`.

    Parameters
    ----------
    r_bearing : float, default 1e-4
        Variance of the bearing (rad²), >= 0.
    origin : array_like of shape (2,), default (0, 0)
        Sensor position.

    Attributes
    ----------
    m : int
        1: ``[bearing]``, an angle.

    Notes
    -----
    .. math::

        h(x) = \operatorname{atan2}(y - o_y, x - o_x), \qquad
        \frac{\partial h}{\partial (x, y)} = \frac{[-\delta_y,\; \delta_x]}{\delta_x^2 + \delta_y^2}.

    Examples
    --------
    >>> from gaussfuse.models.sensors import BearingOnly
    >>> BearingOnly(origin=(1.0, 1.0)).h([0.0, 1.0])
    array([3.14159265])
    """

    __slots__ = ("r_bearing", "origin")

    def __init__(self, r_bearing: float = 1e-4, origin=(0.0, 0.0)) -> None:
        self._set(r_bearing=real("r_bearing", r_bearing, nonnegative=True), origin=_origin(origin, 2))

    m = property(lambda self: 1, doc="Measurement dimension, 1.")
    dim = property(lambda self: 2, doc="Position components read, 2.")
    names = property(lambda self: ("bearing",), doc="``('bearing',)``.")
    measurement_angles = property(lambda self: (0,), doc="``(0,)``: the bearing.")

    @property
    def R(self) -> np.ndarray:
        """``[[r_bearing]]``."""
        return np.array([[self.r_bearing]])

    def h(self, x) -> np.ndarray:
        """``[bearing]`` of shape (1,) (or (j, 1)).

        Parameters
        ----------
        x : array_like of shape (n,) or (j, n)
            A state, or a stack of j states, with the position ``(x, y)`` in
            its first 2 components (n >= 2).

        Returns
        -------
        ndarray of shape (1,) or (j, 1)
            The bearing (radians) from `origin`.
        """
        x, _ = _position(x, 2)
        dx, dy = x[..., 0] - self.origin[0], x[..., 1] - self.origin[1]
        return _arctan2(dy, dx)[..., None]

    def jacobian(self, x) -> np.ndarray:
        """∂h/∂x of shape (1, n).

        Parameters
        ----------
        x : array_like of shape (n,) or (j, n)
            The state (or stack of j states) at which it is taken, position
            first (n >= 2).

        Returns
        -------
        ndarray of shape (1, n) or (j, 1, n)
            The Jacobian, zero past the first 2 columns; NaN at the sensor's
            own position, where it is undefined.
        """
        x, n = _position(x, 2)
        dx, dy = x[..., 0] - self.origin[0], x[..., 1] - self.origin[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.hypot(dx, dy)  # never dx² + dy²: it overflows beyond 1e154 and underflows below 1e-154
            J = np.zeros(x.shape[:-1] + (1, n))
            J[..., 0, 0], J[..., 0, 1] = -(dy / r) / r, (dx / r) / r
        return J
