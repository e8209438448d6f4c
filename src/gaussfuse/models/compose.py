r"""Combining a motion and a sensor into a state-space model for a time step.

:func:`constant_velocity` and :func:`constant_acceleration` build such a
model, measuring the positions, in one call.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from functools import partial

import numpy as np

from .._validation import StepOverflowError, as_array, as_numbers, call_checked, component_mask, integer, real, shape_error
from ._base import Frozen, check_names, check_step_sizes
from .linear import LinearModel
from .motion import ConstantAcceleration, ConstantVelocity, LinearMotion, LocalLevel, LocalLinearTrend, NonlinearMotion
from .nonlinear import NonlinearModel
from .sensors import LinearSensor, NonlinearSensor, Position

__all__ = ["model", "TimedModel", "constant_velocity", "constant_acceleration", "stack_sensors", "Stacked"]


def model(motion, sensor, dt: float | None = None, *, names=None) -> LinearModel | NonlinearModel | TimedModel:
    r"""The state-space model of a motion observed by a sensor, stepped every dt.

    Parameters
    ----------
    motion : LinearMotion or NonlinearMotion
        What the state does, e.g. :class:`~gaussfuse.ConstantVelocity` or
        :class:`~gaussfuse.CoordinatedTurn`.
    sensor : LinearSensor or NonlinearSensor
        What is measured, e.g. :class:`~gaussfuse.Position` or
        :class:`~gaussfuse.RangeBearing`.
    dt : float, optional
        Time step, > 0. Without it, a :class:`TimedModel`: the filters
        discretise it for each step's own dt, from their `times`.
    names : sequence of n str, optional
        The state components' names, which results' ``to_pandas`` use;
        default the motion's (``motion.names``, such as ``("x", "vx")``).

    Returns
    -------
    LinearModel or NonlinearModel or TimedModel
        A :class:`LinearModel` ``(F, H, Q, R, B)`` when both are linear (B
        from ``motion.control(dt)``, if any); otherwise a
        :class:`NonlinearModel` with the analytic Jacobians of both, the
        angle components of both, and ``vectorized=True`` (the functions
        take a stack of states). Either records `dt`. Without `dt`, a
        :class:`TimedModel`.

    Raises
    ------
    TypeError
        If `motion` or `sensor` is not a motion or a sensor model.
    ValueError
        If the sensor does not fit the motion's state (a geometric sensor
        reading more spatial axes than the motion has, a matrix H of the
        wrong width, or sensors stacked for a state of another size), or dt
        is not positive.

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
    LinearModel(n=4, m=2, p=0, dt=0.1)
    >>> gf.model(gf.CoordinatedTurn(), gf.RangeBearing(), dt=1.0)
    NonlinearModel(n=5, m=2, vectorized=True)
    """
    _check_motion(motion)
    if not isinstance(sensor, (LinearSensor, NonlinearSensor)):
        raise TypeError(
            f"`sensor` must be a LinearSensor or NonlinearSensor (e.g. gaussfuse.Position); "
            f"got {type(sensor).__name__}."
        )
    n = motion.n
    _check_fit(motion, sensor, n)
    names = check_names(names, n, tuple(motion.names))
    if dt is None:
        return TimedModel(motion, sensor, names)

    if isinstance(motion, LinearMotion):
        F, Q = motion.transition(dt)
        B = motion.control(dt)
    else:
        Q = motion.noise(real("dt", dt, positive=True))  # noise() accepts dt = 0; a model's step must be positive

    if isinstance(motion, LinearMotion) and isinstance(sensor, LinearSensor):
        H, R = sensor.linear(n)
        return LinearModel(F=F, H=H, Q=Q, R=R, B=B, dt=dt, names=names)

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
                          measurement_angles=sensor.measurement_angles, dt=dt,
                          p=B.shape[1] if isinstance(motion, LinearMotion) and B is not None else 0,
                          names=names)


def probe_step(build: Callable[[float], object]) -> tuple[object, float]:
    """``(build(dt), dt)`` for a step of dt = 1 s, or for steps 2**-32 times shorter where that overflows.

    For what does not depend on the step's length (dimensions, the sensor,
    the method): a motion whose F or Q overflows over 1 s (a LinearSDE's
    rate of 800/s: audit DD3) may serve steps of milliseconds.
    """
    dt = 1.0
    while True:
        try:
            return build(dt), dt
        except StepOverflowError:
            if dt < 1e-290:
                raise
            dt *= 2.0**-32


class TimedModel(Frozen):
    r"""A motion observed by a sensor, discretised for each step's own time step (:func:`model` without dt).

    The filters, smoothers, :func:`gaussfuse.fit`, :func:`gaussfuse.forecast`
    and :func:`gaussfuse.simulate` take it with their `times`; step k then
    uses ``motion.transition(dt_k)`` (or ``motion.f(x, dt_k)`` and
    ``motion.noise(dt_k)``) for :math:`dt_k = t_k - t_{k-1}`: the exact
    discretisation of the continuous model over that step.

    Parameters
    ----------
    motion : LinearMotion or NonlinearMotion
    sensor : LinearSensor or NonlinearSensor
    names : sequence of n str, optional
        The state components' names (default the motion's; see :func:`model`).

    Attributes
    ----------
    n, m : int
        State and measurement dimensions.

    Examples
    --------
    >>> import gaussfuse as gf
    >>> track = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=0.1))
    >>> track
    TimedModel(motion=ConstantVelocity(dim=2, q=0.5, noise='continuous'), sensor=Position(dim=2, r=0.1, n=None))
    >>> track.at([0.5, 2.0])[0].F[:, 0, 2]  # dt of each step
    array([0.5, 2. ])
    """

    __slots__ = ("motion", "sensor", "names")

    def __init__(self, motion, sensor, names=None) -> None:
        probe_step(partial(model, motion, sensor))  # checks that they fit, as model() does
        self._set(motion=motion, sensor=sensor, names=check_names(names, motion.n, tuple(motion.names)))

    def __repr__(self) -> str:
        named = "" if self.names == tuple(self.motion.names) else f", names={self.names!r}"
        return f"TimedModel(motion={self.motion!r}, sensor={self.sensor!r}{named})"

    @property
    def n(self) -> int:
        """State dimension, the motion's n."""
        return self.motion.n

    @property
    def m(self) -> int:
        """Measurement dimension, the sensor's m."""
        return self.sensor.m

    @property
    def linear(self) -> bool:
        """Whether it discretises to a LinearModel."""
        return isinstance(self.motion, LinearMotion) and isinstance(self.sensor, LinearSensor)

    def at(self, dts, us=None) -> tuple[LinearModel | NonlinearModel, np.ndarray | None]:
        """The model of steps of sizes `dts` (T,), and the controls to filter it with.

        A linear motion and sensor give a :class:`LinearModel` whose F, Q
        (and B) vary with the step (one set per distinct dt; a
        time-invariant model when every dt is the same). Otherwise a
        :class:`NonlinearModel` whose f takes ``u_k = [dt_k, *controls_k]``,
        returned with those controls.

        Parameters
        ----------
        dts : array_like of shape (T,)
            The step sizes :math:`dt_k`, > 0.
        us : array_like of shape (T, p) or (N, T, p), optional
            The controls of the steps (of N series), for a motion with a
            control input.

        Returns
        -------
        model : LinearModel or NonlinearModel
            The model of the T steps.
        controls : ndarray or None
            The controls to filter it with: `us` as given when the model is
            a LinearModel or one built by :func:`model` for the single dt
            of all steps (it records that ``dt``); otherwise the
            ``u_k = [dt_k, *us_k]`` its f takes, of shape (T, 1 + p), or
            (N, T, 1 + p) for N series ((T, 1) without `us`).
        """
        dts = check_step_sizes(dts, "(T,) with T >= 1, one step size per step", empty=False)
        unique, index = np.unique(dts, return_inverse=True)
        if unique.shape[0] == 1 and (self.linear or us is None) and isinstance(self.motion, LinearMotion):
            return model(self.motion, self.sensor, float(unique[0]), names=self.names), us
        n = self.n
        if isinstance(self.motion, LinearMotion):
            Fs, Qs = self.motion.transitions(unique)
            if self.linear:  # checked once per distinct dt, then indexed by step
                H, R = self.sensor.linear(n)
                first = self.motion.control(float(unique[0]))
                controls = None if first is None else np.stack([self.motion.control(float(d)) for d in unique])
                distinct = LinearModel(Fs, H, Qs, R, controls, names=self.names)
                return LinearModel._indexed(distinct, index), us
            Q = Qs[index]
        else:
            Q = np.stack([self.motion.noise(float(d)) for d in unique])[index]
        if unique.shape[0] == 1:
            Q = Q[0]  # one dt: the same Q at every step (f still takes dt as its control)
        if isinstance(self.sensor, LinearSensor):
            H, R = self.sensor.linear(n)
            H.setflags(write=False)
            h, h_jacobian = partial(_linear, H), partial(_constant, H)
        else:
            R, h, h_jacobian = self.sensor.R, self.sensor.h, self.sensor.jacobian
        stepped = _Stepped(self.motion)
        B = self.motion.control(float(unique[0])) if isinstance(self.motion, LinearMotion) else None
        p = 0 if B is None else B.shape[1]
        if p and us is None:
            raise ValueError(f"`us` is required: the model has a control input with p = {p}.")
        if us is not None:
            if not p:
                raise ValueError("`us` was given but the motion has no control input.")
            us = as_array("us", us)  # real and finite, named (strings, booleans, complex and ragged rows too)
            given = us.shape
            us = us[:, None] if us.ndim == 1 and p == 1 else us
            if us.ndim not in (2, 3) or us.shape[-2:] != (dts.shape[0], p):
                raise shape_error("us", f"(T, p) = ({dts.shape[0]}, {p}) or (N, {dts.shape[0]}, {p}), one row of the "
                                  "motion's control input per step", given)
        controls = dts[:, None] if us is None else np.concatenate(
            [np.broadcast_to(dts[:, None], (*np.shape(us)[:-1], 1)), np.asarray(us, dtype=np.float64)], axis=-1)
        return NonlinearModel(stepped, h, Q, R, f_jacobian=stepped.jacobian, h_jacobian=h_jacobian,
                              vectorized=True, state_angles=self.motion.state_angles,
                              measurement_angles=self.sensor.measurement_angles, p=1 + p,
                              names=self.names), controls


class _Stepped:
    """f(x, u) of a motion over the step ``u[0]`` (with controls ``u[1:]`` for a linear motion's B)."""

    def __init__(self, motion) -> None:
        self.motion = motion
        self._dt, self._matrices = None, None

    def __reduce__(self):
        return type(self), (self.motion,)

    def _at(self, dt: float):
        if dt != self._dt:  # the sigma points of a step share their dt: computed once
            F, _ = self.motion.transition(dt)
            self._dt, self._matrices = dt, (F, self.motion.control(dt))
        return self._matrices

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        if isinstance(self.motion, NonlinearMotion):
            return self.motion.f(x, float(u[0]))
        F, B = self._at(float(u[0]))
        return x @ F.T if B is None else x @ F.T + B @ u[1:]

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        if isinstance(self.motion, NonlinearMotion):
            return self.motion.jacobian(x, float(u[0]))
        return self._at(float(u[0]))[0]


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


def _check_motion(motion) -> None:
    if not isinstance(motion, (LinearMotion, NonlinearMotion)):
        given = f"the class {motion.__name__} itself (make one: {motion.__name__}())" if isinstance(motion, type) \
            else type(motion).__name__
        raise TypeError(
            f"`motion` must be a LinearMotion or NonlinearMotion (e.g. gaussfuse.ConstantVelocity()); got {given}."
        )


def _check_fit(motion, sensor, n: int, label: str = "`sensor`") -> None:
    """Raise ValueError if the sensor (called `label` in messages) cannot observe the motion's state.

    A :class:`Stacked` sensor was built for a state of its own size, and
    each of its sensors must fit this motion as it would alone.
    """
    if isinstance(sensor, Stacked):
        if sensor.n != n:
            raise ValueError(
                f"{label} stacks sensors of a state of n = {sensor.n} (the `motion` given to stack_sensors), "
                f"which does not fit the state of `motion` (n = {n}); stack them for this motion."
            )
        for name, inner in sensor.sensors:
            _check_fit(motion, inner, n, f"{label}[{name!r}]")
        return
    if isinstance(sensor, NonlinearSensor):  # a user's own, whose R and m its class sets (audit TT5)
        R, m = getattr(sensor, "R", None), getattr(sensor, "m", None)
        if R is None or m is None:
            raise TypeError(f"{label} must give its measurement size `m` and noise covariance `R`, of shape (m, m), "
                            f"as a NonlinearSensor does; {type(sensor).__name__} has no "
                            f"{'`R`' if R is None else '`m`'}.")
        if np.shape(R) != (m, m):
            raise ValueError(f"{label} has m = {m} components but its `R` has shape {np.shape(R)}; it must be "
                             f"({m}, {m}).")
    if isinstance(sensor, LinearSensor) and sensor.H is not None and sensor.H.shape[1] != n:
        raise ValueError(
            f"{label} has `H` of shape {sensor.H.shape}, which does not fit the state of `motion` "
            f"(n = {n}); `H` must have {n} columns."
        )
    reads = getattr(sensor, "dim", None)
    if reads is None:
        return
    axes = getattr(motion, "dim", None)
    if isinstance(motion, (LocalLevel, LocalLinearTrend)):  # (RangeBearing read a level and its slope as x, y:
        raise ValueError(                                    # audit TT4)
            f"{label} reads {reads} position component{'s' if reads > 1 else ''}, but {type(motion).__name__}'s "
            f"state {motion.names} has no spatial axes; measure it with a LinearSensor (H picks what is measured).")
    if axes is not None and reads > axes:
        raise ValueError(
            f"{label} reads {reads} position components but `motion` has {axes} spatial "
            f"{'axis' if axes == 1 else 'axes'}."
        )
    if reads > n:
        raise ValueError(
            f"{label} reads {reads} position components but the state of `motion` has only {n}."
        )


# ---------------------------------------------------------------------------
# Several sensors read as one
# ---------------------------------------------------------------------------


def stack_sensors(sensors, motion) -> LinearSensor | NonlinearSensor:
    """Several named sensors of one motion's state, read as one sensor: their measurements stacked.

    Parameters
    ----------
    sensors : dict of str to LinearSensor or NonlinearSensor
        The sensors by name; the stacked measurement vector holds their
        components in this order.
    motion : LinearMotion or NonlinearMotion
        The motion whose state they measure.

    Returns
    -------
    LinearSensor or Stacked
        A LinearSensor ``(H, R)`` with H and R stacked (block-diagonal R)
        when every sensor is linear, otherwise a :class:`Stacked` sensor.
        Component names are ``"<sensor>.<component>"``.

    Raises
    ------
    TypeError, ValueError
        For a mapping that is empty or not a dict of sensors by str name, a
        `motion` that is not one, or a sensor that does not fit the motion's
        state, naming it.
    """
    checked = _check_sensors(sensors, motion)
    if all(isinstance(sensor, LinearSensor) for sensor in checked.values()):
        n = motion.n
        parts = [sensor.linear(n) for sensor in checked.values()]
        return LinearSensor(np.vstack([H for H, _ in parts]), _block_diagonal([R for _, R in parts]),
                            names=_stacked_names(checked))
    return Stacked(checked, motion.n)


def _check_sensors(sensors, motion) -> dict:
    _check_motion(motion)
    checked = _sensor_mapping(sensors)
    for name, sensor in checked.items():
        _check_fit(motion, sensor, motion.n, f"`sensors[{name!r}]`")
    return checked


def _sensor_mapping(sensors) -> dict:
    """`sensors` as a dict of sensors by str name, checked."""
    if not isinstance(sensors, Mapping) or not sensors:
        raise TypeError(f"`sensors` must be a non-empty dict mapping names to sensors; got {sensors!r:.80}.")
    for name, sensor in sensors.items():
        if not isinstance(name, str):
            raise TypeError(f"`sensors` must have str keys (sensor names); got {name!r}.")
        if not isinstance(sensor, (LinearSensor, NonlinearSensor)):
            raise TypeError(
                f"`sensors[{name!r}]` must be a sensor (a LinearSensor, Position or NonlinearSensor, "
                f"e.g. gaussfuse.RangeBearing); got {type(sensor).__name__}."
            )
    joined = _stacked_names(sensors)
    twice = next((name for i, name in enumerate(joined) if name in joined[:i]), None)
    if twice is not None:  # (review R14: the stacked sensor's own check blamed `names`, which nobody gave)
        raise ValueError(f"`sensors` join to the name {twice!r} twice (\"<sensor>.<component>\"): rename a sensor.")
    return dict(sensors)


def _stacked_names(sensors: dict) -> tuple[str, ...]:
    return tuple(f"{name}.{component}" for name, sensor in sensors.items() for component in sensor.names)


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    size = sum(b.shape[0] for b in blocks)
    out, start = np.zeros((size, size)), 0
    for b in blocks:
        out[start:start + b.shape[0], start:start + b.shape[0]] = b
        start += b.shape[0]
    return out


class Stacked(NonlinearSensor):
    """Several named sensors, at least one nonlinear, read as one (see :func:`stack_sensors`).

    Parameters
    ----------
    sensors : dict of str to sensor
    n : int
        The state dimension of the motion they measure.

    Attributes
    ----------
    sensors : tuple of (str, sensor)
        The sensors by name, in order.
    slots : dict of str to slice
        Each sensor's components in the stacked measurement vector.
    """

    __slots__ = ("sensors", "n")

    def __init__(self, sensors, n: int) -> None:
        sensors, n = _sensor_mapping(sensors), integer("n", n)
        for name, sensor in sensors.items():  # (the motion's axes are stack_sensors' to check)
            _check_fit(None, sensor, n, f"`sensors[{name!r}]`")
        self._set(sensors=tuple(sensors.items()), n=n)  # (name, sensor) pairs

    def __reduce__(self):
        return Stacked, (dict(self.sensors), self.n)

    @property
    def slots(self) -> dict[str, slice]:
        """Each sensor's components in the stacked measurement vector, by name."""
        out, start = {}, 0
        for name, sensor in self.sensors:
            out[name] = slice(start, start + sensor.m)
            start += sensor.m
        return out

    @property
    def m(self) -> int:
        """Measurement dimension, the sum of the sensors' m."""
        return sum(sensor.m for _, sensor in self.sensors)

    @property
    def names(self) -> tuple[str, ...]:
        """The stacked components' names, ``"<sensor>.<component>"``."""
        return _stacked_names(dict(self.sensors))

    @property
    def R(self) -> np.ndarray:
        """Block-diagonal measurement-noise covariance of shape (m, m), the sensors' R in order."""
        return _block_diagonal([np.asarray(sensor.R, dtype=float) for _, sensor in self.sensors])

    @property
    def measurement_angles(self) -> tuple[int, ...]:
        """The sensors' angle components, as indices into the stacked measurement vector.

        Each sensor's own may be indices (negative ones count from its end) or a boolean mask, as a model's:
        they were taken as indices from its start (-1 flagged the sensor before it, a mask every component).
        """
        return tuple(slot.start + int(i) for (name, sensor), slot in zip(self.sensors, self.slots.values())
                     for i in np.flatnonzero(component_mask(f"the measurement_angles of sensor {name!r}",
                                                            sensor.measurement_angles, sensor.m)))

    def _state(self, x, shapes: str, stack: bool = True) -> np.ndarray:
        x = as_numbers("x", x)  # real or complex (a complex step), named: not strings, booleans or objects
        if x.ndim not in ((1, 2) if stack else (1,)) or x.shape[-1] != self.n:
            raise ValueError(f"`x` must have shape {shapes} with n = {self.n} (the state the sensors were stacked "
                             f"for); got shape {x.shape}.")
        return x

    def h(self, x) -> np.ndarray:
        """Every sensor's noise-free measurement of x (n,) or of each state of a stack (k, n), stacked.

        Parameters
        ----------
        x : array_like of shape (n,) or (k, n)
            A state, or a stack of k states.

        Returns
        -------
        ndarray of shape (m,) or (k, m)
            The sensors' measurements, in the order of :attr:`slots`.
        """
        x = self._state(x, "(n,) or (k, n)")
        out = np.empty((*x.shape[:-1], self.m), dtype=np.result_type(x, np.float64))
        for slot, (name, sensor) in zip(self.slots.values(), self.sensors):
            if isinstance(sensor, LinearSensor):
                out[..., slot] = x @ sensor.linear(self.n)[0].T
            else:
                shape = (*x.shape[:-1], slot.stop - slot.start)
                out[..., slot] = call_checked(f"sensors[{name!r}].h", sensor.h, x, (), shape)
        return out

    def jacobian(self, x) -> np.ndarray:
        """The stacked Jacobian at x (n,), shape (m, n).

        Parameters
        ----------
        x : array_like of shape (n,)
            The state at which it is taken.

        Returns
        -------
        ndarray of shape (m, n)
            The sensors' Jacobians (H for a linear one), stacked by rows.
        """
        x = self._state(x, "(n,)", stack=False)
        out = np.empty((self.m, self.n))
        for slot, (name, sensor) in zip(self.slots.values(), self.sensors):
            if isinstance(sensor, LinearSensor):
                out[slot] = sensor.linear(self.n)[0]
            else:
                out[slot] = call_checked(f"sensors[{name!r}].jacobian", sensor.jacobian, x, (),
                                         (slot.stop - slot.start, self.n))
        return out


def constant_velocity(dt: float, q: float, r: float, dim: int = 1) -> LinearModel:
    """Nearly-constant-velocity model (white-noise acceleration) measuring position.

    Parameters
    ----------
    dt : float
        Time step, > 0.
    q : float
        Spectral density of the white-noise acceleration, >= 0.
    r : float
        Variance of each position measurement, >= 0.
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
    LinearModel(n=4, m=2, p=0, dt=0.1)
    """
    return model(ConstantVelocity(dim=dim, q=q), Position(dim=dim, r=r), real("dt", dt, positive=True))


def constant_acceleration(dt: float, q: float, r: float, dim: int = 1) -> LinearModel:
    """Nearly-constant-acceleration model (white-noise jerk) measuring position.

    The state is positions, then velocities, then accelerations (size 3·dim).

    Parameters
    ----------
    dt : float
        Time step (positive).
    q : float
        Spectral density of the jerk (the white noise driving each axis's
        acceleration), in units² / s⁵.
    r : float
        Variance of each position measurement.
    dim : int, default 1
        Number of axes (1, 2 or 3).

    Returns
    -------
    LinearModel
        The model, with ``dt`` recorded.

    Notes
    -----
    ``model(ConstantAcceleration(dim, q), Position(dim, r), dt)``: per axis
    :math:`F = [[1, Δt, Δt^2/2], [0, 1, Δt], [0, 0, 1]]` and
    :math:`Q = q [[Δt^5/20, Δt^4/8, Δt^3/6], [Δt^4/8, Δt^3/3, Δt^2/2], [Δt^3/6, Δt^2/2, Δt]]`.
    """
    return model(ConstantAcceleration(dim=dim, q=q), Position(dim=dim, r=r), real("dt", dt, positive=True))
