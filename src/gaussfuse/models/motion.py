r"""Motion models: what the state does over a time step.

A motion model is a small immutable description of continuous- or
discrete-time dynamics that gives, for any time step dt, the transition and
the process noise:

- :class:`LinearMotion`: ``transition(dt) -> (F, Q)`` and
  ``control(dt) -> B or None``, for :math:`x_k = F x_{k-1} + B u_k + w_k`;
- :class:`NonlinearMotion`: ``f(x, dt)``, ``jacobian(x, dt)`` and
  ``noise(dt)``, for :math:`x_k = f(x_{k-1}) + w_k`.

Kinematic states list all positions first (x, y[, z]), then all velocities
(vx, vy[, vz]), then all accelerations; the axes are independent and share
the noise settings. Combine a motion with a sensor into a filterable model
with :func:`gaussfuse.model`."""

from __future__ import annotations

from math import factorial

import numpy as np

from .._validation import finite_step, integer, real
from ._base import Frozen, check_dim, check_names, check_noise_kind, check_state, check_step_sizes
from .noise import continuous_white_noise, piecewise_white_noise, sde_arrays, van_loan, white_noise_chains

__all__ = [
    "LinearMotion",
    "NonlinearMotion",
    "ConstantPosition",
    "ConstantVelocity",
    "ConstantAcceleration",
    "ForceInput",
    "Singer",
    "RandomWalk",
    "LocalLevel",
    "LocalLinearTrend",
    "LinearSDE",
    "CoordinatedTurn",
]

_AXES = ("x", "y", "z")
_PREFIX = ("", "v", "a")

def _checked_steps(cls: type, results: dict[str, str]) -> None:
    """Wrap the step methods a motion class defines in :func:`gaussfuse._validation.finite_step`.

    Done for every subclass, a user's own too, as it is defined: a step long
    enough to overflow F, Q or B is the "step too long" ValueError, however
    the motion is called (directly, or through :func:`gaussfuse.model`).
    """
    for name, result in results.items():
        if name in cls.__dict__:
            setattr(cls, name, finite_step(result)(cls.__dict__[name]))


class LinearMotion(Frozen):
    r"""Base class of linear motion models, :math:`x_k = F x_{k-1} + B u_k + w_k`.

    Subclasses give the state size `n`, the component `names` and
    :meth:`transition`; those with a control input override :meth:`control`.
    A step so long that F, Q or B overflows float64 is a ValueError naming
    it, for every subclass.

    Attributes
    ----------
    n : int
        State dimension.
    names : tuple of str
        Names of the n state components.
    state_angles : tuple of int
        Always empty: a linear model has no angle components.
    """

    __slots__ = ()

    n: int
    names: tuple[str, ...]

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        _checked_steps(cls, {"transition": "F or Q", "control": "B"})

    @property
    def state_angles(self) -> tuple[int, ...]:
        """Components that are angles: none for a linear motion."""
        return ()

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(F, Q)``, each of shape (n, n), over a time step ``dt > 0``.

        Parameters
        ----------
        dt : float
            Time step, > 0.

        Returns
        -------
        F : ndarray of shape (n, n)
            Transition matrix.
        Q : ndarray of shape (n, n)
            Process-noise covariance.

        Raises
        ------
        ValueError
            When `dt` is not positive, or so long that F or Q overflows
            float64.
        """
        raise NotImplementedError

    def transitions(self, dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`transition` of each of several step sizes, stacked.

        One call of :meth:`transition` a step here; a motion with closed forms
        computes them together, to the same bits.

        Parameters
        ----------
        dts : ndarray of shape (k,)
            Time steps, > 0.

        Returns
        -------
        F : ndarray of shape (k, n, n)
        Q : ndarray of shape (k, n, n)
        """
        pairs = [self.transition(float(dt)) for dt in check_step_sizes(dts)]
        if not pairs:
            return np.zeros((0, self.n, self.n)), np.zeros((0, self.n, self.n))
        return np.stack([F for F, _ in pairs]), np.stack([Q for _, Q in pairs])

    def control(self, dt: float) -> np.ndarray | None:
        """The control matrix B of shape (n, p) over a time step ``dt > 0``; None without control.

        Parameters
        ----------
        dt : float
            Time step, > 0 (checked even when there is no control input).

        Returns
        -------
        ndarray of shape (n, p) or None
            B; this base method returns None (no control input), and
            motions with one (:class:`ForceInput`) override it.
        """
        real("dt", dt, positive=True)
        return None


class NonlinearMotion(Frozen):
    r"""Base class of nonlinear motion models, :math:`x_k = f(x_{k-1}; \Delta t) + w_k`.

    Attributes
    ----------
    n : int
        State dimension.
    names : tuple of str
        Names of the n state components.
    state_angles : tuple of int
        Components that are angles in radians (wrapped to [-π, π) in residuals).

    Notes
    -----
    Subclasses implement ``f(x, dt)`` (x of shape (n,) or a stack (k, n)),
    ``jacobian(x, dt)`` of shape (n, n) and ``noise(dt)`` of shape (n, n).
    """

    __slots__ = ()

    n: int
    names: tuple[str, ...]

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        _checked_steps(cls, {"noise": "Q"})

    @property
    def state_angles(self) -> tuple[int, ...]:
        """Components that are angles (none unless a subclass says so)."""
        return ()

    def f(self, x, dt: float) -> np.ndarray:
        """The state after a time step dt from x.

        Parameters
        ----------
        x : array_like of shape (n,) or (k, n)
            A state, or a stack of k states.
        dt : float
            Time step.

        Returns
        -------
        ndarray of shape (n,) or (k, n)
            The state (or each state of the stack) after the step.
        """
        raise NotImplementedError

    def jacobian(self, x, dt: float) -> np.ndarray:
        """The Jacobian of :meth:`f` with respect to x, shape (n, n).

        Parameters
        ----------
        x : array_like of shape (n,)
            The state at which it is taken.
        dt : float
            Time step.

        Returns
        -------
        ndarray of shape (n, n)
            ∂f/∂x at `x`.
        """
        raise NotImplementedError

    def noise(self, dt: float) -> np.ndarray:
        """The process-noise covariance Q over a time step dt, shape (n, n).

        Parameters
        ----------
        dt : float
            Time step.

        Returns
        -------
        ndarray of shape (n, n)
            Q.
        """
        raise NotImplementedError


# ---------------------------------------------------------------------------
# Integrated white noise: constant position / velocity / acceleration
# ---------------------------------------------------------------------------


def _kinematic_transitions(order: int, dts: np.ndarray) -> np.ndarray:
    r"""Per axis :math:`F_{ij} = \Delta t^{j-i}/(j-i)!` for j >= i (Taylor series of the position), for each
    step size of `dts` (k,): (k, order + 1, order + 1)."""
    ahead = np.subtract.outer(np.arange(order + 1), np.arange(order + 1))
    ahead = np.where(ahead <= 0, -ahead, 0)  # j - i on and above the diagonal
    fact = np.array([float(factorial(j)) for j in range(order + 1)])
    F = dts[:, None, None] ** ahead / fact[ahead]
    return np.where(np.tri(order + 1, dtype=bool).T, F, 0.0)


class _IntegratedWhiteNoise(LinearMotion):
    __slots__ = ("dim", "q", "noise")
    _order: int = 0

    def __init__(self, dim: int = 1, q: float = 1.0, noise: str = "continuous") -> None:
        self._set(dim=check_dim(dim), q=real("q", q, nonnegative=True), noise=check_noise_kind(noise))

    @property
    def n(self) -> int:
        """State dimension, (order + 1) · dim."""
        return (self._order + 1) * self.dim

    @property
    def names(self) -> tuple[str, ...]:
        """``x, y, z`` then ``vx, vy, vz`` then ``ax, ay, az`` (as far as the order and dim go)."""
        return tuple(state_names(self._order, self.dim))

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(F, Q)``, each of shape (n, n), over a time step ``dt > 0``.

        Parameters
        ----------
        dt : float
            Time step, > 0.

        Returns
        -------
        F : ndarray of shape (n, n)
            Transition matrix: per axis, the Taylor series of the position
            to the model's order.
        Q : ndarray of shape (n, n)
            Process-noise covariance, of the `noise` kind, scaled by `q`.
        """
        dt = real("dt", dt, positive=True)
        K = self._order
        noise = continuous_white_noise if self.noise == "continuous" else piecewise_white_noise
        eye = np.eye(self.dim)
        return np.kron(_kinematic_transitions(K, np.array([dt]))[0], eye), np.kron(noise(K, dt, self.q), eye)

    def transitions(self, dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # transition's formulas on the stack of steps, the same bits; the base's loop names a step that overflows
        dts = check_step_sizes(dts)
        if self.noise != "continuous" or not dts.size:
            return super().transitions(dts)
        K, d, k = self._order, self.dim, dts.shape[0]
        with np.errstate(over="ignore", invalid="ignore"):
            F = _kinematic_transitions(K, dts)
        Q = white_noise_chains(K, dts, self.q)
        if not (np.isfinite(F).all() and np.isfinite(Q).all()):
            return super().transitions(dts)
        eye = np.eye(d)
        return (np.einsum("kij,ab->kiajb", F, eye).reshape(k, (K + 1) * d, (K + 1) * d),
                np.einsum("kij,ab->kiajb", Q, eye).reshape(k, (K + 1) * d, (K + 1) * d))

    transitions.__doc__ = LinearMotion.transitions.__doc__


class ConstantPosition(_IntegratedWhiteNoise):
    r"""A position that drifts as a random walk (order 0).

    Parameters
    ----------
    dim : {1, 2, 3}
        Number of spatial axes; the state is ``[x, (y, z)]``.
    q : float, default 1.0
        With ``noise="continuous"`` the spectral density of the white-noise
        velocity; with ``noise="piecewise"`` the variance of a velocity held
        constant over each step. >= 0.
    noise : {"continuous", "piecewise"}
        See :func:`~gaussfuse.models.noise.continuous_white_noise` and
        :func:`~gaussfuse.models.noise.piecewise_white_noise`.

    Notes
    -----
    Per axis :math:`F = 1` and :math:`Q = q \Delta t` (continuous) or
    :math:`Q = q \Delta t^2` (piecewise).

    Examples
    --------
    >>> from gaussfuse.models.motion import ConstantPosition
    >>> ConstantPosition(dim=2, q=0.5).transition(2.0)[1]
    array([[1., 0.],
           [0., 1.]])
    """

    __slots__ = ()
    _order = 0


class ConstantVelocity(_IntegratedWhiteNoise):
    r"""Nearly constant velocity: white-noise acceleration (order 1).

    Parameters
    ----------
    dim : {1, 2, 3}
        Number of spatial axes; the state is ``[x, (y, z,) vx, (vy, vz)]``,
        of size 2·dim.
    q : float, default 1.0
        With ``noise="continuous"`` the spectral density of the white-noise
        acceleration (units² / time³); with ``noise="piecewise"`` the variance
        of an acceleration held constant over each step. >= 0.
    noise : {"continuous", "piecewise"}

    Notes
    -----
    Per axis :math:`F = \begin{bmatrix} 1 & \Delta t \\ 0 & 1 \end{bmatrix}` and

    .. math::

        Q_\text{continuous} = q \begin{bmatrix} \Delta t^3/3 & \Delta t^2/2 \\
        \Delta t^2/2 & \Delta t \end{bmatrix}, \qquad
        Q_\text{piecewise} = q\, g g^T, \quad g = [\Delta t^2/2, \Delta t]^T.

    Examples
    --------
    >>> from gaussfuse.models.motion import ConstantVelocity
    >>> cv = ConstantVelocity(dim=2, q=3.0)
    >>> cv.names
    ('x', 'y', 'vx', 'vy')
    >>> F, Q = cv.transition(dt=2.0)
    >>> F
    array([[1., 0., 2., 0.],
           [0., 1., 0., 2.],
           [0., 0., 1., 0.],
           [0., 0., 0., 1.]])
    >>> Q[::2, ::2]  # the x axis
    array([[8., 6.],
           [6., 6.]])
    """

    __slots__ = ()
    _order = 1


class ConstantAcceleration(_IntegratedWhiteNoise):
    r"""Nearly constant acceleration: white-noise jerk (order 2).

    Parameters
    ----------
    dim : {1, 2, 3}
        Number of spatial axes; the state is positions, velocities, then
        accelerations, of size 3·dim.
    q : float, default 1.0
        Spectral density of the white-noise jerk (``noise="continuous"``) or
        the variance of a jerk held constant over each step (``"piecewise"``).
    noise : {"continuous", "piecewise"}

    Notes
    -----
    Per axis :math:`F = \begin{bmatrix} 1 & \Delta t & \Delta t^2/2 \\ 0 & 1 & \Delta t
    \\ 0 & 0 & 1 \end{bmatrix}` and

    .. math::

        Q_\text{continuous} = q \begin{bmatrix}
        \Delta t^5/20 & \Delta t^4/8 & \Delta t^3/6 \\
        \Delta t^4/8 & \Delta t^3/3 & \Delta t^2/2 \\
        \Delta t^3/6 & \Delta t^2/2 & \Delta t \end{bmatrix}, \qquad
        Q_\text{piecewise} = q\, g g^T, \quad g = [\Delta t^3/6, \Delta t^2/2, \Delta t]^T.

    Examples
    --------
    >>> from gaussfuse.models.motion import ConstantAcceleration
    >>> ConstantAcceleration(dim=1).transition(2.0)[0]
    array([[1., 2., 2.],
           [0., 1., 2.],
           [0., 0., 1.]])
    """

    __slots__ = ()
    _order = 2


class ForceInput(LinearMotion):
    r"""A mass pushed by a known force: constant velocity with acceleration input u = f / m.

    Parameters
    ----------
    q : float, default 0.0
        Variance of an unknown acceleration held constant over each step
        (piecewise white noise), >= 0.
    dim : {1, 2, 3}
        Number of spatial axes; the state is ``[x, (y, z,) vx, (vy, vz)]``
        and the control ``u = [ax, (ay, az)]``, the known acceleration
        (force over mass) during the step.

    Notes
    -----
    With the acceleration u constant over the step, per axis

    .. math::

        x_k = \begin{bmatrix} 1 & \Delta t \\ 0 & 1 \end{bmatrix} x_{k-1}
        + \begin{bmatrix} \Delta t^2/2 \\ \Delta t \end{bmatrix} u_k + w_k,
        \qquad w_k \sim N(0, q\, g g^T), \quad g = [\Delta t^2/2, \Delta t]^T,

    which is exact kinematics: an unknown acceleration enters exactly as the
    known one does.

    Examples
    --------
    >>> from gaussfuse.models.motion import ForceInput
    >>> ForceInput().control(2.0)
    array([[2.],
           [2.]])
    """

    __slots__ = ("q", "dim")

    def __init__(self, q: float = 0.0, dim: int = 1) -> None:
        self._set(q=real("q", q, nonnegative=True), dim=check_dim(dim))

    @property
    def n(self) -> int:
        """State dimension, 2 · dim."""
        return 2 * self.dim

    @property
    def names(self) -> tuple[str, ...]:
        """Positions then velocities."""
        return tuple(state_names(1, self.dim))

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(F, Q)``, each of shape (2·dim, 2·dim), over a time step ``dt > 0``.

        Parameters
        ----------
        dt : float
            Time step, > 0.

        Returns
        -------
        F : ndarray of shape (2·dim, 2·dim)
            The constant-velocity transition.
        Q : ndarray of shape (2·dim, 2·dim)
            Piecewise white noise of variance `q`: ``q g gᵀ`` per axis,
            ``g = [dt²/2, dt]``.
        """
        dt = real("dt", dt, positive=True)
        eye = np.eye(self.dim)
        return (np.kron(_kinematic_transitions(1, np.array([dt]))[0], eye),
                np.kron(piecewise_white_noise(1, dt, self.q), eye))

    def control(self, dt: float) -> np.ndarray:
        """B of shape (2·dim, dim): ``[dt²/2, dt]`` per axis.

        Parameters
        ----------
        dt : float
            Time step, > 0.

        Returns
        -------
        ndarray of shape (2·dim, dim)
            B, which maps the acceleration u to the change of position and
            velocity over the step.
        """
        dt = real("dt", dt, positive=True)
        return np.kron(np.array([[dt**2 / 2], [dt]]), np.eye(self.dim))


class Singer(LinearMotion):
    r"""Singer's model: the acceleration is a first-order Markov (Ornstein–Uhlenbeck) process.

    Parameters
    ----------
    dim : {1, 2, 3}
        Number of spatial axes; the state is positions, velocities, then
        accelerations, of size 3·dim.
    tau : float, default 1.0
        Time constant (correlation time) of the acceleration, > 0.
    sigma : float, default 1.0
        Standard deviation of the stationary acceleration, >= 0.

    Raises
    ------
    ValueError
        For a `tau` or `sigma` out of range, or one that makes 1/τ or
        2σ²/τ overflow float64 (τ = 1e-310, say), or a positive σ whose
        σ² or density 2σ²/τ falls below float64's normal numbers, where
        it has lost digits (σ = 1e-155 with τ = 1e10: Q 1e-5 off; with
        τ = 1e50, Q was 0), or a positive σ with σ·τ below 1e-150: under a fast rate the
        discretisation's variances over its shortest sub-step, about σ²τ²,
        fall below float64's normal numbers and Q loses its digits
        (στ = 1e-160 left entries 1e-3 off, smaller products all of them),
        or a positive σ with a τ below 1e-150, whose sub-steps' transition
        entries, about τ², do the same (τ = 1e-175 left the
        position-acceleration entry 43% off). The bounds are conservative:
        a slow rate takes some smaller products exactly (τ = 1 with σ =
        1e-151). Above them, over τ from 1e-150 to 1e50, σ from 1e-150 to
        1e60 and dt from 1e-6 to 1e6, the entries in float64's normal range
        were within 3.7e-15 of Singer's closed form.

    Notes
    -----
    Per axis, with :math:`\alpha = 1/\tau`,

    .. math::

        d\begin{bmatrix} p \\ v \\ a \end{bmatrix} =
        \begin{bmatrix} 0 & 1 & 0 \\ 0 & 0 & 1 \\ 0 & 0 & -\alpha \end{bmatrix}
        \begin{bmatrix} p \\ v \\ a \end{bmatrix} dt +
        \begin{bmatrix} 0 \\ 0 \\ 1 \end{bmatrix} d\beta, \qquad
        E[d\beta^2] = \frac{2\sigma^2}{\tau} dt,

    discretised exactly (to round-off: 2.5e-14 at :math:`\tau = \Delta t` =
    1e9 s) by :func:`~gaussfuse.models.noise.van_loan` [1]_:
    :math:`F = e^{A\Delta t}` has
    :math:`F_{02} = \tau^2 (e^{-\Delta t/\tau} - 1 + \Delta t/\tau)`,
    :math:`F_{12} = \tau (1 - e^{-\Delta t/\tau})`,
    :math:`F_{22} = e^{-\Delta t/\tau}`.
    As :math:`\tau \to \infty` with :math:`2\sigma^2/\tau = q` fixed it tends
    to :class:`ConstantAcceleration` (q); as :math:`\tau \to 0` with
    :math:`2\sigma^2\tau = q` fixed, its position–velocity part tends to
    :class:`ConstantVelocity` (q).

    References
    ----------
    .. [1] R. A. Singer, "Estimating optimal tracking filter performance for
       manned maneuvering targets", IEEE Trans. AES 6(4), 1970.

    Examples
    --------
    >>> import numpy as np
    >>> from gaussfuse.models.motion import Singer
    >>> F, Q = Singer(tau=2.0, sigma=1.0).transition(1.0)
    >>> bool(np.isclose(F[2, 2], np.exp(-0.5)))
    True
    """

    __slots__ = ("dim", "tau", "sigma")

    def __init__(self, dim: int = 1, tau: float = 1.0, sigma: float = 1.0) -> None:
        tau, sigma = real("tau", tau, positive=True), real("sigma", sigma, nonnegative=True)
        with np.errstate(over="ignore", divide="ignore"):
            if not (np.isfinite(1.0 / np.float64(tau)) and np.isfinite(2.0 * np.float64(sigma) ** 2 / tau)):
                raise ValueError(f"the noise density 2 sigma² / tau and the rate 1 / tau must be finite in float64; "
                                 f"got sigma = {sigma:g} and tau = {tau:g}.")
            tiny = np.finfo(np.float64).tiny
            if sigma > 0.0 and (np.float64(sigma) ** 2 < tiny or 2.0 * np.float64(sigma) ** 2 / tau < tiny):
                raise ValueError(f"sigma² and the noise density 2 sigma² / tau must be at least float64's smallest "
                                 f"normal number, {tiny:.3g}, or sigma 0: below it they have lost digits; got sigma = "
                                 f"{sigma:g} and tau = {tau:g}. Measure time or distance in other units.")  # (R44)
            if sigma > 0.0 and tau < 1e-150:  # (review R46; without noise F is exact: review R47)
                raise ValueError(f"tau must be at least 1e-150, or sigma 0: below it the transition's entries over the "
                                 f"discretisation's shortest step, about tau², fall below float64's normal numbers "
                                 f"and Q loses its digits; got tau = {tau:g}. Measure time in other units.")
            if sigma > 0.0 and sigma * tau < 1e-150:  # (audit MM3)
                raise ValueError(f"sigma * tau must be at least 1e-150, or sigma 0: below it Q's terms over the "
                                 f"discretisation's shortest step, about (sigma tau)², are lost to float64's "
                                 f"underflow; got sigma = {sigma:g} and tau = {tau:g}. Measure time or distance "
                                 "in other units.")
        self._set(dim=check_dim(dim), tau=tau, sigma=sigma)

    @property
    def n(self) -> int:
        """State dimension, 3 · dim."""
        return 3 * self.dim

    @property
    def names(self) -> tuple[str, ...]:
        """Positions, velocities, accelerations."""
        return tuple(state_names(2, self.dim))

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(F, Q)``, each of shape (3·dim, 3·dim), over a time step ``dt > 0``.

        Parameters
        ----------
        dt : float
            Time step, > 0.

        Returns
        -------
        F : ndarray of shape (3·dim, 3·dim)
            Transition matrix, ``exp(A dt)`` per axis.
        Q : ndarray of shape (3·dim, 3·dim)
            Process-noise covariance (Van Loan's method).
        """
        dt = real("dt", dt, positive=True)
        A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / self.tau]])
        F1, Q1 = van_loan(A, [0.0, 0.0, 1.0], 2.0 * self.sigma**2 / self.tau, dt)
        eye = np.eye(self.dim)
        return np.kron(F1, eye), np.kron(Q1, eye)


class RandomWalk(LinearMotion):
    r"""n independent random walks: :math:`F = I`, :math:`Q = q \Delta t\, I`.

    Parameters
    ----------
    n : int, default 1
        State dimension, >= 1. The components are named ``x0, x1, ...``.
    q : float, default 1.0
        Spectral density (variance per unit time) of each walk, >= 0.

    Notes
    -----
    :math:`dx = d\beta`, :math:`E[d\beta\, d\beta^T] = q I\, dt`, so over a step
    :math:`x_k = x_{k-1} + w_k`, :math:`w_k \sim N(0, q \Delta t\, I)`.

    Examples
    --------
    >>> from gaussfuse.models.motion import RandomWalk
    >>> RandomWalk(n=2, q=0.5).transition(4.0)[1]
    array([[2., 0.],
           [0., 2.]])
    """

    __slots__ = ("n", "q")

    def __init__(self, n: int = 1, q: float = 1.0) -> None:
        self._set(n=integer("n", n), q=real("q", q, nonnegative=True))

    @property
    def names(self) -> tuple[str, ...]:
        """``x0, x1, ...``."""
        return tuple(f"x{i}" for i in range(self.n))

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(I, q·dt·I)`` of shape (n, n).

        Parameters
        ----------
        dt : float
            Time step, > 0.

        Returns
        -------
        F : ndarray of shape (n, n)
            The identity.
        Q : ndarray of shape (n, n)
            ``q·dt·I``.
        """
        dt = real("dt", dt, positive=True)
        return np.eye(self.n), self.q * dt * np.eye(self.n)


class LocalLevel(LinearMotion):
    r"""The local-level (random walk) model of Durbin & Koopman; dt counts steps.

    Parameters
    ----------
    q : float, default 1.0
        Variance of the level's disturbance per step, >= 0.

    Notes
    -----
    :math:`\mu_k = \mu_{k-1} + \eta_k`, :math:`\eta_k \sim N(0, q\,\Delta t)`:
    F = [[1]], Q = [[q·dt]] (dt = 1 for consecutive observations) [1]_.

    References
    ----------
    .. [1] J. Durbin and S. J. Koopman, *Time Series Analysis by State Space
       Methods*, 2nd ed., Oxford University Press, 2012, ch. 2.

    Examples
    --------
    >>> from gaussfuse.models.motion import LocalLevel
    >>> LocalLevel(q=1469.1).transition(1)
    (array([[1.]]), array([[1469.1]]))
    """

    _counts_steps = True  # dt is a number of steps, not seconds: dated times have none (timing.resolve)
    __slots__ = ("q",)

    def __init__(self, q: float = 1.0) -> None:
        self._set(q=real("q", q, nonnegative=True))

    n = property(lambda self: 1, doc="State dimension, 1.")
    names = property(lambda self: ("level",), doc="``('level',)``.")

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``([[1]], [[q·dt]])``.

        Parameters
        ----------
        dt : float
            Time step in steps (1 for consecutive observations), > 0.

        Returns
        -------
        F : ndarray of shape (1, 1)
            ``[[1]]``.
        Q : ndarray of shape (1, 1)
            ``[[q·dt]]``.
        """
        dt = real("dt", dt, positive=True)
        return np.ones((1, 1)), np.full((1, 1), self.q * dt)


def _product(*factors: float) -> float:
    """The product of `factors`, overflowing or underflowing only where it does, not on the way: the mantissas'
    product times 2 to the exponents' sum (LocalLinearTrend's d (d - 1) (2d - 1) overflowed at dt = 1e104 before
    q_slope = 1e-200 brought it back to 3e111: audit VV3)."""
    mantissas, exponents = np.frexp(np.array(factors, dtype=np.float64))
    return float(np.ldexp(np.prod(mantissas), int(np.sum(exponents))))


class LocalLinearTrend(LinearMotion):
    r"""The local linear trend model of Durbin & Koopman; dt counts steps.

    Parameters
    ----------
    q_level : float, default 1.0
        Variance of the level's disturbance per step, >= 0.
    q_slope : float, default 1.0
        Variance of the slope's disturbance per step, >= 0.

    Notes
    -----
    One step is

    .. math::

        \mu_k = \mu_{k-1} + \nu_{k-1} + \xi_k, \qquad
        \nu_k = \nu_{k-1} + \zeta_k,

    :math:`F = \begin{bmatrix} 1 & 1 \\ 0 & 1 \end{bmatrix}`,
    :math:`Q = \mathrm{diag}(q_\text{level}, q_\text{slope})`, and ``dt``
    steps are that step ``dt`` times: :math:`F = \begin{bmatrix} 1 & d \\ 0 & 1
    \end{bmatrix}` and :math:`Q = \sum_{i=0}^{d-1} F^i\,
    \mathrm{diag}(q_\text{level}, q_\text{slope})\, F^{iT}`, with
    :math:`d = \Delta t`,

    .. math::

        Q = \begin{bmatrix}
            d\, q_\text{level} + \frac{d (d-1)(2d-1)}{6} q_\text{slope} &
            \frac{d (d-1)}{2} q_\text{slope} \\
            \frac{d (d-1)}{2} q_\text{slope} & d\, q_\text{slope}
        \end{bmatrix},

    so a gap of two steps equals two steps with the measurement between
    them missing. The same polynomial composes for any real d (Q over
    a + b is Q over a carried by F over b, plus Q over b) and is a
    covariance for every :math:`d \ge 1`. Under a step it is one only when
    :math:`q_\text{level} \ge q_\text{slope} (1 - d^2) / 12` (it is then the
    integrated random walk with level noise that matches one step); for
    smaller ``q_level`` a fraction of a step is refused.

    Examples
    --------
    >>> from gaussfuse.models.motion import LocalLinearTrend
    >>> LocalLinearTrend(q_level=2.0, q_slope=0.5).transition(1)[1]
    array([[2. , 0. ],
           [0. , 0.5]])
    >>> LocalLinearTrend(q_level=2.0, q_slope=0.5).transition(2)[1]
    array([[4.5, 0.5],
           [0.5, 1. ]])
    """

    _counts_steps = True  # dt is a number of steps, not seconds: dated times have none (timing.resolve)
    __slots__ = ("q_level", "q_slope")

    def __init__(self, q_level: float = 1.0, q_slope: float = 1.0) -> None:
        self._set(q_level=real("q_level", q_level, nonnegative=True),
                  q_slope=real("q_slope", q_slope, nonnegative=True))

    n = property(lambda self: 2, doc="State dimension, 2.")
    names = property(lambda self: ("level", "slope"), doc="``('level', 'slope')``.")

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(F, Q)`` of shape (2, 2).

        Parameters
        ----------
        dt : float
            Time step in steps (1 for consecutive observations), > 0.

        Returns
        -------
        F : ndarray of shape (2, 2)
            ``[[1, dt], [0, 1]]``.
        Q : ndarray of shape (2, 2)
            The noise of ``dt`` steps (see the class notes).

        Raises
        ------
        ValueError
            For a fraction of a step (dt < 1) over which Q would not be a
            covariance (``q_level < q_slope (1 - dt²) / 12``).
        """
        d = real("dt", dt, positive=True)
        ql, qs = self.q_level, self.q_slope
        if d < 1.0 and ql < qs * (1.0 - d * d) / 12.0:
            raise ValueError(
                f"`dt` = {d:g} is a fraction of a step, over which LocalLinearTrend(q_level={ql:g}, "
                f"q_slope={qs:g}) has no noise covariance (it needs q_level >= q_slope (1 - dt²) / 12 = "
                f"{qs * (1.0 - d * d) / 12.0:g}): the model counts whole steps.")
        cross = _product(qs, d, d - 1.0, 0.5)
        return (np.array([[1.0, d], [0.0, 1.0]]),
                np.array([[d * ql + _product(qs, d, d - 1.0, 2.0 * d - 1.0, 1.0 / 6.0), cross], [cross, d * qs]]))


class LinearSDE(LinearMotion):
    r"""Any linear time-invariant SDE :math:`dx = A x\,dt + L\,d\beta`, discretised exactly (to round-off).

    Parameters
    ----------
    A : array_like of shape (n, n)
        Drift matrix.
    L : array_like of shape (n, s)
        Noise gain; a 1-D array of length n is a single column.
    Qc : array_like of shape (s, s)
        Spectral density of β, symmetric positive semi-definite; a scalar
        when s = 1.
    names : sequence of n str, optional
        Component names; ``x0, x1, ...`` by default.

    Notes
    -----
    ``transition(dt)`` is :func:`~gaussfuse.models.noise.van_loan`:
    :math:`F = e^{A\Delta t}`,
    :math:`Q = \int_0^{\Delta t} e^{As} L Q_c L^T e^{A^Ts} ds`, each entry
    to its own round-off for a drift that is not stiff; a stiff one's slow
    modes lose digits (see van_loan's Notes for figures).

    Examples
    --------
    A damped oscillator driven by white-noise force:

    >>> from gaussfuse.models.motion import LinearSDE
    >>> sde = LinearSDE([[0, 1], [-4, -0.4]], [0, 1], 0.1, names=("x", "v"))
    >>> sde.n, sde.names
    (2, ('x', 'v'))
    """

    __slots__ = ("A", "L", "Qc", "names")

    def __init__(self, A, L, Qc, names=None) -> None:
        A, L, Qc = sde_arrays(A, L, Qc)
        n = A.shape[0]
        self._set(A=A, L=L, Qc=Qc, names=check_names(names, n, tuple(f"x{i}" for i in range(n))))

    @property
    def n(self) -> int:
        """State dimension."""
        return self.A.shape[0]

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(F, Q)`` of shape (n, n) by Van Loan's method.

        Parameters
        ----------
        dt : float
            Time step, > 0.

        Returns
        -------
        F : ndarray of shape (n, n)
            Transition matrix ``exp(A dt)``.
        Q : ndarray of shape (n, n)
            Process-noise covariance over the step.
        """
        return van_loan(self.A, self.L, self.Qc, dt)

    def __repr__(self) -> str:
        return f"LinearSDE(n={self.n}, s={self.L.shape[1]}, names={self.names!r})"


# ---------------------------------------------------------------------------
# Coordinated turn
# ---------------------------------------------------------------------------

_SERIES = 0.1  # |ω dt| below which the turn functions are evaluated by their Taylor series
_TERMS = 8


def _turn_functions(theta):
    r"""``(sin θ/θ, (1 - cos θ)/θ)`` and their θ-derivatives, smooth through θ = 0.

    Taylor series for small |θ| (no cancellation), closed forms elsewhere;
    elementwise on real or complex arrays:

    .. math::

        \frac{\sin\theta}{\theta} = \sum_k \frac{(-1)^k \theta^{2k}}{(2k+1)!}, \qquad
        \frac{1 - \cos\theta}{\theta} = \sum_k \frac{(-1)^k \theta^{2k+1}}{(2k+2)!}.
    """
    theta = np.asarray(theta)
    small = np.abs(theta.real) < _SERIES
    t = np.where(small, theta, 0.0)
    t2 = t * t
    s = c = ds = dc = np.zeros_like(t)
    power = np.ones_like(t)  # θ^(2k)
    for k in range(_TERMS):
        sign = -1.0 if k % 2 else 1.0
        s = s + sign * power / factorial(2 * k + 1)
        c = c + sign * power * t / factorial(2 * k + 2)
        dc = dc + sign * (2 * k + 1) * power / factorial(2 * k + 2)
        power = power * t2
    power = t  # d/dθ sin θ/θ = Σ_{k>=1} (-1)^k 2k θ^(2k-1) / (2k+1)!
    for k in range(1, _TERMS + 1):
        sign = -1.0 if k % 2 else 1.0
        ds = ds + sign * 2 * k * power / factorial(2 * k + 1)
        power = power * t2
    big = np.where(small, 1.0, theta)
    sin, cos = np.sin(big), np.cos(big)
    one_minus_cos = 2.0 * np.sin(0.5 * big) ** 2
    return (np.where(small, s, sin / big),
            np.where(small, c, one_minus_cos / big),
            np.where(small, ds, (cos - sin / big) / big),  # (over big², which overflowed past 1.3e154 to 0)
            np.where(small, dc, (sin - one_minus_cos / big) / big))


class CoordinatedTurn(NonlinearMotion):
    r"""Coordinated turn with unknown turn rate: constant speed along a circular arc.

    Parameters
    ----------
    q_acc : float, default 1.0
        Spectral density of the white-noise acceleration along x and y
        (as :class:`ConstantVelocity` with ``dim=2``), >= 0.
    q_turn : float, default 0.01
        Spectral density of the turn rate's random walk (rad²/s³), >= 0.

    Attributes
    ----------
    n : int
        5: the state is ``[x, y, vx, vy, omega]``, omega the turn rate in
        rad/s (not an angle: it is never wrapped).
    dim : int
        2, the number of spatial axes.

    Notes
    -----
    The velocity rotates at the rate ω, :math:`\dot p = v`, :math:`\dot v =
    \omega J v` with :math:`J = [[0, -1], [1, 0]]`, :math:`\dot\omega = 0`.
    Over a step, with :math:`\theta = \omega \Delta t`,
    :math:`S = \sin\theta`, :math:`C = \cos\theta`,

    .. math::

        f(x) = \begin{bmatrix}
        x + \frac{S}{\omega} v_x - \frac{1 - C}{\omega} v_y \\
        y + \frac{1 - C}{\omega} v_x + \frac{S}{\omega} v_y \\
        C v_x - S v_y \\
        S v_x + C v_y \\
        \omega \end{bmatrix},

    whose limit as ω → 0 is the constant-velocity transition; the functions
    :math:`S/\omega = \Delta t \,\mathrm{sinc}` and :math:`(1 - C)/\omega`
    and their ω-derivatives (in the analytic Jacobian) are evaluated by
    their Taylor series for :math:`|\theta| < 0.1`, so f and its Jacobian
    are smooth and accurate through ω = 0. The process noise is

    .. math::

        Q = \mathrm{blockdiag}\left(q_\text{acc}
        \begin{bmatrix} \Delta t^3/3 & \Delta t^2/2 \\ \Delta t^2/2 & \Delta t
        \end{bmatrix} \otimes I_2,\; q_\text{turn} \Delta t\right).

    See Bar-Shalom, Li and Kirubarajan [1]_, section 11.7.

    References
    ----------
    .. [1] Y. Bar-Shalom, X. R. Li and T. Kirubarajan, *Estimation with
       Applications to Tracking and Navigation*, Wiley, 2001.

    Examples
    --------
    A quarter turn at 1 m/s with ω = π/2 rad/s over 1 s:

    >>> import numpy as np
    >>> from gaussfuse.models.motion import CoordinatedTurn
    >>> ct = CoordinatedTurn()
    >>> np.round(ct.f([0.0, 0.0, 1.0, 0.0, np.pi / 2], dt=1.0), 6)
    array([0.63662 , 0.63662 , 0.      , 1.      , 1.570796])
    """

    __slots__ = ("q_acc", "q_turn")

    def __init__(self, q_acc: float = 1.0, q_turn: float = 0.01) -> None:
        self._set(q_acc=real("q_acc", q_acc, nonnegative=True),
                  q_turn=real("q_turn", q_turn, nonnegative=True))

    n = property(lambda self: 5, doc="State dimension, 5.")
    dim = property(lambda self: 2, doc="Number of spatial axes, 2.")
    names = property(lambda self: ("x", "y", "vx", "vy", "omega"),
                     doc="``('x', 'y', 'vx', 'vy', 'omega')``.")

    def f(self, x, dt: float) -> np.ndarray:
        """The state after dt: x of shape (5,) or (k, 5), real or complex; dt >= 0 (0 is the identity).

        Parameters
        ----------
        x : array_like of shape (5,) or (k, 5)
            A state ``[x, y, vx, vy, omega]``, or a stack of k states; real
            or complex.
        dt : float
            Time step, >= 0.

        Returns
        -------
        ndarray of shape (5,) or (k, 5)
            The state (or each state of the stack) after the turn.
        """
        x = check_state(x, 5)
        dt = real("dt", dt, nonnegative=True)
        px, py, vx, vy, w = (x[..., i] for i in range(5))
        theta = w * dt
        s, c, _, _ = _turn_functions(theta)
        s, c = s * dt, c * dt  # sin(ω dt)/ω and (1 - cos(ω dt))/ω
        sin, cos = np.sin(theta), np.cos(theta)
        return np.stack([px + s * vx - c * vy,
                         py + c * vx + s * vy,
                         cos * vx - sin * vy,
                         sin * vx + cos * vy,
                         w], axis=-1)

    @finite_step("Jacobian")  # (noise's error, where it was Python's OverflowError past dt = 1.3e154: audit TT1)
    def jacobian(self, x, dt: float) -> np.ndarray:
        """∂f/∂x of shape (5, 5) (or (k, 5, 5) for a stack of states).

        Parameters
        ----------
        x : array_like of shape (5,) or (k, 5)
            The state (or stack of k states) at which it is taken; real or
            complex.
        dt : float
            Time step, >= 0.

        Returns
        -------
        ndarray of shape (5, 5) or (k, 5, 5)
            The Jacobian of :meth:`f` at each state.

        Raises
        ------
        ValueError
            Where an entry overflows float64 (a step that long: its ∂/∂ω
            entries grow as dt²), as :meth:`noise` does.
        """
        x = check_state(x, 5)
        dt = real("dt", dt, nonnegative=True)
        vx, vy, w = x[..., 2], x[..., 3], x[..., 4]
        theta = w * dt
        s, c, ds, dc = _turn_functions(theta)
        s, c = s * dt, c * dt
        ds, dc = ds * dt * dt, dc * dt * dt  # d/dω of s and c (dt**2 of a Python float raises OverflowError)
        sin, cos = np.sin(theta), np.cos(theta)
        J = np.zeros(x.shape[:-1] + (5, 5), dtype=np.result_type(x.dtype, np.float64))
        J[..., 0, 0] = J[..., 1, 1] = J[..., 4, 4] = 1.0
        J[..., 0, 2], J[..., 0, 3], J[..., 0, 4] = s, -c, ds * vx - dc * vy
        J[..., 1, 2], J[..., 1, 3], J[..., 1, 4] = c, s, dc * vx + ds * vy
        J[..., 2, 2], J[..., 2, 3], J[..., 2, 4] = cos, -sin, -dt * (sin * vx + cos * vy)
        J[..., 3, 2], J[..., 3, 3], J[..., 3, 4] = sin, cos, dt * (cos * vx - sin * vy)
        return J

    def noise(self, dt: float) -> np.ndarray:
        """Q of shape (5, 5): the CV block for x, y, vx, vy and q_turn·dt for omega (dt >= 0).

        Parameters
        ----------
        dt : float
            Time step, >= 0 (0 gives a zero Q).

        Returns
        -------
        ndarray of shape (5, 5)
            The process-noise covariance over the step.
        """
        dt = real("dt", dt, nonnegative=True)
        Q = np.zeros((5, 5))
        if dt > 0:
            Q[:4, :4] = np.kron(continuous_white_noise(1, dt, self.q_acc), np.eye(2))
            Q[4, 4] = self.q_turn * dt
        return Q


# ---------------------------------------------------------------------------
# One-call models (kept for backwards compatibility)
# ---------------------------------------------------------------------------


def state_names(order: int, dim: int) -> list[str]:
    """Names of the states of an order-K model in `dim` axes: x, y, vx, vy, ..."""
    return [_PREFIX[k] + _AXES[a] for k in range(order + 1) for a in range(dim)]
