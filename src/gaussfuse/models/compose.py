r"""Combining a motion and a sensor into a state-space model for a time step.

:func:`constant_velocity` and :func:`constant_acceleration` build such a
model, measuring the positions, in one call.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from .._validation import real
from .linear import LinearModel
from .motion import ConstantAcceleration, ConstantVelocity, LinearMotion, NonlinearMotion
from .nonlinear import NonlinearModel
from .sensors import LinearSensor, NonlinearSensor, Position

__all__ = ["model", "constant_velocity", "constant_acceleration"]


def model(motion, sensor, dt: float) -> LinearModel | NonlinearModel:
    r"""The state-space model of a motion observed by a sensor, stepped every dt.

    Parameters
    ----------
    motion : LinearMotion or NonlinearMotion
        What the state does, e.g. :class:`~gaussfuse.ConstantVelocity` or
        :class:`~gaussfuse.CoordinatedTurn`.
    sensor : LinearSensor or NonlinearSensor
        What is measured, e.g. :class:`~gaussfuse.Position` or
        :class:`~gaussfuse.RangeBearing`.
    dt : float
        Time step, > 0.

    Returns
    -------
    LinearModel or NonlinearModel
        A :class:`LinearModel` ``(F, H, Q, R, B)`` when both are linear (B
        from ``motion.control(dt)``, if any); otherwise a
        :class:`NonlinearModel` with the analytic Jacobians of both, the
        angle components of both, and ``vectorized=True`` (the functions
        take a stack of states).

    Raises
    ------
    TypeError
        If `motion` or `sensor` is not a motion or a sensor model.
    ValueError
        If the sensor does not fit the motion's state (a geometric sensor
        reading more spatial axes than the motion has, or a matrix H of the
        wrong width), or dt is not positive.

    Notes
    -----
    With :math:`(F, Q) =` ``motion.transition(dt)`` or
    :math:`f(x) =` ``motion.f(x, dt)``, :math:`Q =` ``motion.noise(dt)``:

    .. math::

        x_k = f(x_{k-1}) \;[+\, B u_k] + w_k, \quad w_k \sim N(0, Q), \qquad
        z_k = h(x_k) + v_k, \quad v_k \sim N(0, R),

    where a linear motion has :math:`f(x) = F x` (Jacobian F) and a linear
    sensor :math:`h(x) = H x` (Jacobian H). A linear motion with a control
    input combined with a nonlinear sensor gives ``f(x, u) = F x + B u``:
    pass the controls to :func:`gaussfuse.filter` as `us`.

    Examples
    --------
    >>> import gaussfuse as gf
    >>> gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=0.1), dt=0.1)
    LinearModel(n=4, m=2, p=0)
    >>> gf.model(gf.CoordinatedTurn(), gf.RangeBearing(), dt=1.0)
    NonlinearModel(n=5, m=2, vectorized=True)
    """
    if not isinstance(motion, (LinearMotion, NonlinearMotion)):
        raise TypeError(
            f"`motion` must be a LinearMotion or NonlinearMotion (e.g. gaussfuse.ConstantVelocity); "
            f"got {type(motion).__name__}."
        )
    if not isinstance(sensor, (LinearSensor, NonlinearSensor)):
        raise TypeError(
            f"`sensor` must be a LinearSensor or NonlinearSensor (e.g. gaussfuse.Position); "
            f"got {type(sensor).__name__}."
        )
    n = motion.n
    _check_fit(motion, sensor, n)

    if isinstance(motion, LinearMotion):
        F, Q = motion.transition(dt)
        B = motion.control(dt)
    else:
        Q = motion.noise(real("dt", dt, positive=True))  # noise() accepts dt = 0; a model's step must be positive

    if isinstance(motion, LinearMotion) and isinstance(sensor, LinearSensor):
        H, R = sensor.linear(n)
        return LinearModel(F=F, H=H, Q=Q, R=R, B=B)

    # f, h and their Jacobians are partials of module-level functions (or a sensor's
    # bound methods), not closures, so that the model pickles.
    if isinstance(motion, LinearMotion):
        F.setflags(write=False)
        f_jacobian = partial(_constant, F)
        if B is None:
            f = partial(_linear, F)
        else:
            B.setflags(write=False)
            f = partial(_linear_with_control, F, B)
    else:
        f = partial(_over_dt, motion.f, dt)
        f_jacobian = partial(_over_dt, motion.jacobian, dt)

    if isinstance(sensor, LinearSensor):
        H, R = sensor.linear(n)
        H.setflags(write=False)
        h, h_jacobian = partial(_linear, H), partial(_constant, H)
    else:
        R = sensor.R
        h, h_jacobian = sensor.h, sensor.jacobian

    return NonlinearModel(f, h, Q, R, f_jacobian=f_jacobian, h_jacobian=h_jacobian, vectorized=True,
                          state_angles=motion.state_angles,
                          measurement_angles=sensor.measurement_angles)


def _linear(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``M x`` for a state (n,), or for each row of a stack of states (k, n)."""
    return x @ M.T


def _linear_with_control(F: np.ndarray, B: np.ndarray, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``F x + B u`` for a state (n,) or each row of a stack (k, n)."""
    return x @ F.T + B @ u


def _constant(M: np.ndarray, *x) -> np.ndarray:
    """The Jacobian of a linear map: M, wherever it is taken."""
    return M


def _over_dt(fn, dt: float, x: np.ndarray) -> np.ndarray:
    """``fn(x, dt)``: a nonlinear motion's f or Jacobian over the model's time step."""
    return fn(x, dt)


def _check_fit(motion, sensor, n: int) -> None:
    """Raise ValueError if the sensor cannot observe the motion's state."""
    if isinstance(sensor, LinearSensor) and sensor.H is not None and sensor.H.shape[1] != n:
        raise ValueError(
            f"`sensor` has `H` of shape {sensor.H.shape}, which does not fit the state of `motion` "
            f"(n = {n}); `H` must have {n} columns."
        )
    reads = getattr(sensor, "dim", None)
    if reads is None:
        return
    axes = getattr(motion, "dim", None)
    if axes is not None and reads > axes:
        raise ValueError(
            f"`sensor` reads {reads} position components but `motion` has {axes} spatial "
            f"{'axis' if axes == 1 else 'axes'}."
        )
    if reads > n:
        raise ValueError(
            f"`sensor` reads {reads} position components but the state of `motion` has only {n}."
        )


def constant_velocity(dt: float, q: float, r: float, dim: int = 1) -> LinearModel:
    """Nearly-constant-velocity model (white-noise acceleration) measuring position.

    Parameters
    ----------
    dt : float
        Time step, > 0.
    q : float
        Spectral density of the white-noise acceleration, >= 0.
    r : float
        Variance of each position measurement, > 0.
    dim : {1, 2, 3}
        Number of spatial axes.

    Returns
    -------
    LinearModel
        State ``[x, (y, z,) vx, (vy, vz)]`` of size 2·dim; measurement the positions.

    Notes
    -----
    ``model(ConstantVelocity(dim, q), Position(dim, r), dt)``: per axis
    :math:`F = [[1, Δt], [0, 1]]` and
    :math:`Q = q [[Δt^3/3, Δt^2/2], [Δt^2/2, Δt]]`.

    Examples
    --------
    >>> import gaussfuse as gf
    >>> gf.constant_velocity(dt=0.1, q=1.0, r=0.25, dim=2)
    LinearModel(n=4, m=2, p=0)
    """
    return model(ConstantVelocity(dim=dim, q=q), Position(dim=dim, r=r), dt)


def constant_acceleration(dt: float, q: float, r: float, dim: int = 1) -> LinearModel:
    """Nearly-constant-acceleration model (white-noise jerk) measuring position.

    Parameters are those of :func:`constant_velocity`, with `q` the spectral
    density of the jerk. The state is positions, then velocities, then
    accelerations (size 3·dim).

    Notes
    -----
    ``model(ConstantAcceleration(dim, q), Position(dim, r), dt)``: per axis
    :math:`F = [[1, Δt, Δt^2/2], [0, 1, Δt], [0, 0, 1]]` and
    :math:`Q = q [[Δt^5/20, Δt^4/8, Δt^3/6], [Δt^4/8, Δt^3/3, Δt^2/2], [Δt^3/6, Δt^2/2, Δt]]`.
    """
    return model(ConstantAcceleration(dim=dim, q=q), Position(dim=dim, r=r), dt)
