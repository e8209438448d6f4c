r"""Asynchronous multi-sensor fusion: several sensors, each on its own clock.

Every sensor reports at its own timestamps; the state moves between them by
a motion model (:mod:`gaussfuse.models.motion`) over the elapsed time. The
timeline of events becomes ONE state-space model over the event steps:

* the measurement vector stacks the components of every sensor,
  :math:`z = (z^{(1)}, \dots, z^{(S)})` with :math:`m = \sum_s m_s`, and the
  components of sensors that do not report at a step are NaN, so the core's
  missing-data update (:func:`gaussfuse.kalman.update`) conditions on exactly
  what was observed;
* step k's transition is the motion over :math:`\Delta t_k = t_k - t_{k-1}`
  (a zero step is the identity with no process noise).

:func:`fuse_timeline` runs that model through :func:`gaussfuse.filter` or
:func:`gaussfuse.smooth`; :class:`Fuser` takes the events one at a time.
"""

from __future__ import annotations

import copy
import datetime

from collections.abc import Iterable
from functools import partial
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from . import inference, kalman
from ._frozen import reduce_frozen, shapes_repr
from ._validation import as_array, flag, real, shape_error
from .diagnostics import DivergenceMonitor
from .gaussian import Gaussian
from .inference import FilterResult, SmoothResult
from .inference import drivers, timing
from .inference.registry import resolve_method
from .inference.results import stack
from .inference.validation import check_prior
from .models.compose import model as compose_model
from .models.compose import probe_step, stack_sensors
from .models.linear import LinearModel
from .models.motion import LinearMotion, NonlinearMotion
from .models.nonlinear import NonlinearModel
from .models.sensors import LinearSensor

__all__ = ["Measurement", "Fused", "fuse_timeline", "Fuser"]


class Measurement(NamedTuple):
    """One timestamped measurement from a named sensor.

    Parameters
    ----------
    t : float
        Time of the measurement.
    sensor : str
        Name of the sensor, a key of the ``sensors`` mapping.
    z : array_like of shape (m_s,)
        The measurement (a scalar when the sensor has m_s = 1); a NaN
        component is missing.
    """

    t: float
    sensor: str
    z: ArrayLike


@dataclass(frozen=True, eq=False)
class Fused:
    """The output of :func:`fuse_timeline`: one belief per event step.

    Attributes
    ----------
    times : ndarray of shape (K,)
        Time of each step, non-decreasing: float seconds, or, when `t0`
        was a datetime, ``datetime64`` (UTC) in the finest resolution among
        the times given. Measurements at the same time
        from different sensors share a step; a sensor reporting twice at the
        same time gives two steps at that time.
    means : ndarray of shape (K, n)
        Filtered (or, with ``smooth=True``, smoothed) means.
    covs : ndarray of shape (K, n, n)
        Their covariances.
    sources : list of length K
        What each step holds: the sensor's name, a tuple of names when
        several sensors report at that step, or None for an output time
        without measurements.
    loglik : float
        Log-likelihood of all the measurements.
    result : FilterResult or SmoothResult
        The underlying result over the K steps, in the stacked measurement
        vector (innovations and their covariances have ``m = Σ m_s``
        components, in the order of the ``sensors`` mapping).
    """

    times: np.ndarray
    means: np.ndarray
    covs: np.ndarray
    sources: list
    loglik: float
    result: FilterResult | SmoothResult

    __reduce__ = reduce_frozen  # pickles and copies keep the arrays read-only
    __repr__ = shapes_repr

    def at(self, times) -> tuple[np.ndarray, np.ndarray]:
        """The beliefs at the given times, after every measurement at each.

        Parameters
        ----------
        times : float or datetime, or array_like of shape (k,)
            Times that are steps of the timeline: measurement times, or
            output times passed to :func:`fuse_timeline` as ``times``
            (datetimes when its `t0` was one, else seconds).

        Returns
        -------
        means : ndarray of shape (n,) or (k, n)
        covs : ndarray of shape (n, n) or (k, n, n)

        Raises
        ------
        ValueError
            For a time that is not a step of the timeline, naming it.
        """
        dated = self.times.dtype.kind == "M"
        query = _times("times", times, dated)
        flat = np.atleast_1d(query)
        exact = np.ones(flat.shape, dtype=bool)
        if dated:  # on the timeline's clock; a time it cannot hold is not one of its steps
            on_clock = flat.astype(self.times.dtype)
            exact = on_clock.astype(flat.dtype) == flat
            flat, shown = on_clock, flat
        idx = np.searchsorted(self.times, flat, side="right") - 1
        ok = exact & (idx >= 0) & (self.times[np.clip(idx, 0, None)] == flat)
        if not ok.all():
            missing = [str(t) for t in shown[~ok]] if dated else flat[~ok].tolist()
            raise ValueError(
                f"`times` must be times of the timeline (measurement times, or output times "
                f"passed to fuse_timeline(times=...)); got {missing}, which are not."
            )
        if query.ndim == 0:
            return self.means[idx[0]], self.covs[idx[0]]
        return self.means[idx], self.covs[idx]


# ---------------------------------------------------------------------------
# The timeline as one model: the motion over each step, the sensors stacked
# ---------------------------------------------------------------------------


_KEPT = 256
"""How many models over distinct step lengths a timeline keeps (:meth:`_Timeline.model_over`)."""


class _Timeline:
    """The motion and the stacked sensors (:func:`gaussfuse.models.compose.stack_sensors`).

    Attributes
    ----------
    sensor : LinearSensor or Stacked
        The sensors read as one; ``slots[name]`` is each one's part of the
        stacked measurement vector.
    linear : bool
        Whether the motion and every sensor are linear.
    """

    def __init__(self, motion, sensors) -> None:
        if not isinstance(motion, (LinearMotion, NonlinearMotion)):
            raise TypeError(
                "`motion` must be a motion model (a LinearMotion or NonlinearMotion, "
                f"e.g. gaussfuse.ConstantVelocity); got {type(motion).__name__}."
            )
        if isinstance(motion, LinearMotion) and motion.control(1.0) is not None:
            raise ValueError(
                f"`motion` has a control input ({type(motion).__name__}); fusion takes no "
                "controls, so use a motion without one."
            )
        self.motion, self.n = motion, motion.n
        self.sensor = stack_sensors(sensors, motion)
        self.names = tuple(sensors)
        self.slots, start = {}, 0
        for name, sensor in sensors.items():
            self.slots[name] = slice(start, start + sensor.m)
            start += sensor.m
        self.m = start
        self.linear = isinstance(motion, LinearMotion) and isinstance(self.sensor, LinearSensor)
        self._models: dict[float, LinearModel | NonlinearModel] = {}
        self._probe: float | None = None  # the step model() takes the sensors' parts from (probe_step's)

    def model_over(self, dt: float) -> LinearModel | NonlinearModel:
        """:func:`gaussfuse.model` of the motion and the stacked sensors over `dt` > 0, made once per dt.

        At most :data:`_KEPT` of them are kept (the oldest dropped first): an online Fuser whose every
        step has its own dt kept one model per update, without bound.
        """
        model = self._models.get(dt)
        if model is None:
            if len(self._models) >= _KEPT:
                del self._models[next(iter(self._models))]
            model = self._models[dt] = compose_model(self.motion, self.sensor, dt)
        return model

    def model(self, dts: np.ndarray) -> tuple[LinearModel | NonlinearModel, np.ndarray | None]:
        """The model over steps of elapsed times `dts` (K,), and its controls (K, 1) or None.

        A step of zero duration has the identity transition and no process
        noise. A linear timeline is a time-varying LinearModel; otherwise a
        NonlinearModel whose ``f(x, u)`` moves x over ``dt = u[0]``.
        """
        if getattr(self, "_probe", None) is None:  # of 1 s, which overflowed a LinearSDE at 800/s (audit HH1)
            self._probe = probe_step(self.model_over)[1]
        probe = self.model_over(self._probe)
        Q = np.stack([self.model_over(float(dt)).Q if dt > 0 else np.zeros((self.n, self.n)) for dt in dts])
        if self.linear:
            F = np.stack([self.model_over(float(dt)).F if dt > 0 else np.eye(self.n) for dt in dts])
            return LinearModel(F, probe.H, Q, probe.R), None
        model = NonlinearModel(partial(_moved, self), probe.h, Q, probe.R, f_jacobian=partial(_moved_jacobian, self),
                               h_jacobian=probe.h_jacobian, vectorized=True, state_angles=probe.state_angles,
                               measurement_angles=probe.measurement_angles)
        return model, np.asarray(dts, dtype=float).reshape(-1, 1)

    def default_method(self) -> str:
        return "kf" if self.linear else "ekf"

    def measurement_vector(self, name: str, z) -> np.ndarray:
        """`z` of sensor `name` checked, as its slot of an otherwise-NaN stacked vector."""
        slot = self.slots[name]
        m = slot.stop - slot.start
        arr = as_array("z", z, allow_nan=True)
        if arr.shape != (m,) and not (m == 1 and arr.ndim == 0):
            raise shape_error("z", f"({m},) for sensor {name!r}" + (" or a scalar" if m == 1 else ""), arr.shape)
        full = np.full(self.m, np.nan)
        full[slot] = arr.reshape(m)
        return full

    def check_name(self, name, argument: str) -> str:
        if not isinstance(name, str) or name not in self.slots:
            raise ValueError(f"`{argument}` must be one of {list(self.names)}; got {name!r}.")
        return name


def _moved(timeline: _Timeline, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The states x (n,) or (k, n) after the motion over ``dt = u[0]`` (unchanged for dt = 0)."""
    dt = float(u[0])
    return x if dt == 0.0 else timeline.model_over(dt).f(x)


def _moved_jacobian(timeline: _Timeline, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    dt = float(u[0])
    return np.eye(timeline.n) if dt == 0.0 else timeline.model_over(dt).f_jacobian(x)


def _time(name: str, value, dated: bool | None = None):
    """A finite real time: float seconds, or a datetime as a naive UTC numpy.datetime64 in its own resolution.

    `dated` says whether `t0` was a datetime, in which case every time must
    be one, or not, in which case none may be (None: this is `t0`).
    """
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    when = timing.stamp(name, value)
    if when is None:
        if isinstance(value, (bool, np.bool_, np.timedelta64, datetime.timedelta)) or not isinstance(
                value, (int, float, np.integer, np.floating)):  # (a timedelta64 is an np.integer)
            what = " (a duration, not a time)" if isinstance(value, (np.timedelta64, datetime.timedelta)) else ""
            raise TypeError(f"`{name}` must be a real number of seconds or a datetime; got {value!r:.60}{what}.")
        when = real(name, value)
    if dated is not None and dated != isinstance(when, np.datetime64):
        kind = "a datetime" if dated else "a real number of seconds"
        raise TypeError(f"`{name}` must be {kind}, as `t0` is; got {value!r:.60}.")
    return when


def _times(name: str, values, dated: bool) -> np.ndarray:
    """Times of shape () or (k,): float seconds, or (`dated`) datetime64 in the finest unit among them."""
    if np.ndim(values) == 0:
        return np.asarray(_time(name, values, dated))
    if np.ndim(values) > 1:
        raise shape_error(name, "() or (k,)", np.shape(values))
    if not dated:
        kind = getattr(getattr(values, "dtype", None), "kind", None) or np.asarray(values, dtype=object).dtype.kind
        if kind == "O":  # a list: numbers, or something else to name
            kind = np.asarray(values).dtype.kind
        if kind in ("M", "O"):
            return np.array([_time(f"{name}[{i}]", v, dated) for i, v in enumerate(values)], dtype=float)
        return as_array(name, values)
    if hasattr(values, "tz_convert") or hasattr(values, "to_numpy"):
        values = list(values)  # pandas: each Timestamp with its zone
    read = [_time(f"{name}[{i}]", v, dated) for i, v in enumerate(values)]
    return _Clock.finest(read).array(name, read)


class _Clock(NamedTuple):
    """How a timeline counts its times: float seconds, or datetimes as int64 counts of one unit of at most a second."""

    unit: str | None  # the datetime64 unit, or None for seconds

    @classmethod
    def finest(cls, times) -> _Clock:
        """The clock of `times` (all seconds, or all datetime64): the finest unit among them."""
        units = [np.datetime_data(t.dtype)[0] for t in times if isinstance(t, np.datetime64)]
        return cls(timing.finest(units) if units else None)

    def count(self, name: str, when):
        """`when` on this clock: its float seconds, or its exact count of the unit (a Python int)."""
        return when if self.unit is None else int(timing.within(name, when, self.unit).astype(np.int64))

    def array(self, name: str, times) -> np.ndarray:
        """`times` as float seconds, or as datetime64 in the unit."""
        if self.unit is None:
            return np.array(times, dtype=float)
        return np.array([self.count(f"{name}[{i}]", t) for i, t in enumerate(times)], dtype=np.int64).view(
            f"datetime64[{self.unit}]")

    def steps(self, counts: np.ndarray) -> np.ndarray:
        """The seconds between consecutive `counts` (seconds or counts of the unit), each rounded once.

        Raises
        ------
        ValueError
            Where two float times are further apart than the largest float64.
        """
        if self.unit is None:
            with np.errstate(over="ignore"):
                dts = np.diff(counts)
            if np.isinf(dts).any():
                k = int(np.flatnonzero(np.isinf(dts))[0])
                raise ValueError(f"the times {counts[k]:g} s and {counts[k + 1]:g} s are further apart than the largest "
                                 "float64 (dt = inf s): times so far apart cannot be stepped.")
            return dts
        return timing.elapsed(counts.astype(np.int64), timing.per_second(self.unit))


def _parse(measurements, timeline: _Timeline, dated: bool) -> list[tuple[object, str, np.ndarray]]:
    """Checked measurements as (t, sensor, stacked z), in the order given."""
    if isinstance(measurements, (str, bytes)) or not isinstance(measurements, Iterable):
        raise TypeError(
            "`measurements` must be an iterable of Measurement(t, sensor, z) or (t, sensor, z) "
            f"tuples; got {type(measurements).__name__}."
        )
    events = []
    for i, item in enumerate(measurements):
        if not isinstance(item, tuple) or len(item) != 3:
            raise TypeError(
                f"`measurements[{i}]` must be a Measurement(t, sensor, z) or a (t, sensor, z) "
                f"tuple; got {item!r:.80}."
            )
        t = _time(f"measurements[{i}].t", item[0], dated)
        name = timeline.check_name(item[1], f"measurements[{i}].sensor")
        try:
            z = timeline.measurement_vector(name, item[2])
        except (TypeError, ValueError) as exc:
            raise type(exc)(str(exc).replace("`z`", f"`measurements[{i}].z`", 1)) from None
        events.append((t, name, z))
    return events


def _steps(events, outputs: np.ndarray, timeline: _Timeline):
    """Group time-sorted events into steps; add output-only steps.

    Measurements at one time share a step unless a sensor repeats, which
    starts another step at the same time. An output time with measurements
    needs no step of its own.
    """
    times, zs, sources = [], [], []
    for t, name, z in sorted(events, key=lambda e: e[0]):  # sorted() is stable
        if times and times[-1] == t and sources[-1] is not None and name not in sources[-1]:
            filled = timeline.slots[name]
            zs[-1][filled] = z[filled]
            sources[-1] = (*sources[-1], name)
        else:
            times.append(t)
            zs.append(z.copy())
            sources.append((name,))
    have = set(times)
    for t in np.unique(outputs).tolist():
        if t not in have:
            at = int(np.searchsorted(times, t, side="right"))
            times.insert(at, t)
            zs.insert(at, np.full(timeline.m, np.nan))
            sources.insert(at, None)
    sources = [s if s is None or len(s) > 1 else s[0] for s in sources]
    return np.array(times, dtype=outputs.dtype), np.array(zs, dtype=float).reshape(len(times), timeline.m), sources


_TIMELINE_OWN = {
    "keep": "it returns every step",
    "model": "the model is the motion and the sensors, discretised for each step",
    "zs": "the measurements are `measurements`, placed on the timeline",
    "us": "the motions it takes have no control input",
    "steady": "each step has its own dt, so the model is time-varying and has no steady state",
}


def fuse_timeline(motion, sensors, prior: Gaussian, t0: float, measurements, *, times=None,
                  smooth: bool = False, method: str | None = None, **options) -> Fused:
    r"""Fuse timestamped measurements from several sensors into one trajectory estimate.

    Parameters
    ----------
    motion : LinearMotion or NonlinearMotion
        How the state moves over an elapsed time (e.g.
        :class:`gaussfuse.ConstantVelocity`, :class:`gaussfuse.CoordinatedTurn`).
        Motions with a control input are not accepted.
    sensors : dict of str to sensor
        The sensors by name: :class:`gaussfuse.Position`,
        :class:`gaussfuse.LinearSensor` or a NonlinearSensor such as
        :class:`gaussfuse.RangeBearing`.
    prior : Gaussian
        Belief about the state at time `t0`, of the motion's dimension n.
    t0 : float or datetime
        Time of the prior; no measurement may be earlier. Times are numbers
        of seconds, or datetimes (``datetime``, ``numpy.datetime64``,
        ``pandas.Timestamp``; time zones taken to UTC), all of one kind, as
        `t0` is. Datetimes are kept exactly, each in its own resolution
        (a Timestamp's nanoseconds, a datetime's microseconds), and each
        step's dt is rounded once from the exact difference, so a 1 µs step
        in 2026 is as exact as one from 0; the result's times are then
        ``datetime64`` values.
    measurements : iterable of Measurement or of (t, sensor, z) tuples
        In any order: they are sorted by time (stably, so measurements at
        equal times keep their order). ``z`` has the sensor's shape (m_s,)
        (a scalar when m_s = 1); NaN components are missing.
    times : array_like of shape (k,), optional
        Extra output times (>= `t0`) at which to report the belief; steps
        without measurements are added for those not already measurement
        times. Read them back with :meth:`Fused.at`.
    smooth : bool, default False
        Return the smoothed beliefs (given every measurement) instead of the
        filtered ones (given those up to each step).
    method : str, optional
        The inference method (:data:`gaussfuse.METHODS`): ``"kf"`` when the
        motion and every sensor are linear (the default then); for a
        nonlinear motion or sensor ``"ekf"`` (the default here, with the
        models' analytic Jacobians), ``"ukf"``, ``"ckf"``, ``"ghkf"``,
        ``"iekf"`` or ``"iplf"``.
    **options
        Passed on to :func:`gaussfuse.filter` / :func:`gaussfuse.smooth`:
        the method's options, ``engine`` and ``form`` (``"sqrt"`` for the
        square-root form, whose factors are then in ``result.cov_factors``).

    Returns
    -------
    Fused
        ``times`` (K,), ``means`` (K, n), ``covs`` (K, n, n), ``sources``,
        ``loglik`` and :meth:`Fused.at`.

    Raises
    ------
    TypeError, ValueError
        For a bad motion, sensor, prior, time or measurement, naming it.

    Notes
    -----
    The K steps are the distinct measurement times (a sensor reporting
    twice at one time adds a step at that time) and the extra output
    times, in order, with :math:`t_0` before them. One model is built over
    them and run by :func:`gaussfuse.filter` or :func:`gaussfuse.smooth`:

    .. math::

        x_k &= f(x_{k-1}, \Delta t_k) + w_k, \quad w_k \sim N(0, Q(\Delta t_k)),
        \quad \Delta t_k = t_k - t_{k-1}, \\
        z_k &= \begin{pmatrix} h_1(x_k) \\ \vdots \\ h_S(x_k) \end{pmatrix} + v_k,
        \quad v_k \sim N(0, \operatorname{blockdiag}(R_1, \dots, R_S)),

    with :math:`f(x, 0) = x`, :math:`Q(0) = 0`, and NaN in the components of
    sensors that do not report at step k. For a linear motion and sensors it
    is a time-varying :class:`gaussfuse.LinearModel`
    (:math:`F_k = F(\Delta t_k)`); otherwise a
    :class:`gaussfuse.NonlinearModel` whose ``f(x, u)`` takes
    :math:`u_k = [\Delta t_k]` as its control.

    Because the update conditions on the observed components only, the
    sensors at a shared step are fused in one joint update, which equals
    updating with them one after another.

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> motion = gf.ConstantVelocity(dim=1, q=0.1)
    >>> sensors = {"gps": gf.Position(dim=1, r=4.0),
    ...            "speed": gf.LinearSensor(H=[[0.0, 1.0]], R=[[0.01]])}
    >>> prior = gf.Gaussian([0.0, 1.0], np.diag([10.0, 1.0]))
    >>> meas = [(1.0, "gps", 1.2), (1.5, "speed", 1.05), (2.0, "gps", 2.1), (2.0, "speed", 0.98)]
    >>> out = gf.fuse_timeline(motion, sensors, prior, 0.0, meas, times=[3.0])
    >>> out.times.tolist(), out.sources
    ([1.0, 1.5, 2.0, 3.0], ['gps', 'speed', ('gps', 'speed'), None])
    >>> mean, cov = out.at(3.0)
    >>> mean.shape, cov.shape
    ((2,), (2, 2))
    """
    timeline = _Timeline(motion, sensors)
    prior = check_prior(prior, timeline.n)
    t0 = _time("t0", t0)
    dated = isinstance(t0, np.datetime64)
    if dated:  # (every time is then a date)
        timing.no_dates_for_steps(motion, "t0")
    smooth = flag("smooth", smooth)
    for name in _TIMELINE_OWN.keys() & options.keys():  # filter's arguments that the timeline sets (audit AA1)
        raise TypeError(f"`{name}` is not an option of fuse_timeline: {_TIMELINE_OWN[name]}.")
    outputs = np.zeros(0)
    if times is not None:
        outputs = np.atleast_1d(_times("times", times, dated))
    events = _parse(measurements, timeline, dated)
    clock = _Clock.finest([t0, *(t for t, _, _ in events), *outputs])
    start = clock.count("t0", t0)
    for i, (t, name, z) in enumerate(events):
        events[i] = (clock.count(f"measurements[{i}].t", t), name, z)
        if events[i][0] < start:
            raise ValueError(f"`measurements[{i}].t` must not be earlier than `t0` = {t0} (the prior's time); "
                             f"got {t}.")
    given = outputs
    outputs = np.array([clock.count(f"times[{i}]", t) for i, t in enumerate(given)],
                       dtype=float if clock.unit is None else np.int64)
    if outputs.size and outputs.min() < start:
        raise ValueError(f"`times` must not be earlier than `t0` = {t0} (the prior's time); got "
                         f"{given[int(np.argmin(outputs))]}.")
    counts, zs, sources = _steps(events, outputs, timeline)
    if counts.size == 0:
        raise ValueError("`measurements` and `times` are both empty: there is nothing to estimate.")
    dts = clock.steps(np.concatenate([[start], counts]))
    step_times = counts if clock.unit is None else counts.view(f"datetime64[{clock.unit}]")
    model, us = timeline.model(dts)
    method = timeline.default_method() if method is None else method
    check = drivers.checked(options.pop("check", "warn"))
    run = inference.smooth if smooth else inference.filter
    res = run(model, prior, zs, us, method, check="off", **options)
    # checked here, so that a DivergenceWarning points at the caller's line, as gf.filter's does
    drivers.check_divergence(stack([res.filtered if smooth else res]), check)
    for a in (step_times, res.means, res.covs):
        a.setflags(write=False)
    return Fused(step_times, res.means, res.covs, sources, float(res.loglik), res)


class Fuser:
    r"""Online asynchronous fusion: take each measurement as it arrives.

    Parameters
    ----------
    motion : LinearMotion or NonlinearMotion
        How the state moves over an elapsed time.
    sensors : dict of str to sensor
        The sensors by name (see :func:`fuse_timeline`).
    prior : Gaussian
        Belief about the state at time `t0`.
    t0 : float or datetime
        Time of the prior (seconds, or a datetime, as in :func:`fuse_timeline`).
    method : str, optional
        ``"kf"`` (linear motion and sensors; the default then), or for a
        nonlinear motion or sensor ``"ekf"`` (the default), ``"ukf"``,
        ``"ckf"`` or ``"ghkf"``.
    check : {"warn", "raise", "off"}, default "warn"
        The divergence test over the updates as they come, as for
        :class:`gaussfuse.KalmanFilter`; the warning names the times.
    **options
        The method's options (e.g. ``alpha`` for ``"ukf"``).

    Attributes
    ----------
    belief : Gaussian
        The current belief, at time `t`. It may be set (to restart a
        track), to a Gaussian over the motion's state.
    t : float or numpy.datetime64
        The time of the belief: seconds, or (when `t0` was a datetime) a
        UTC datetime64 in the finest resolution given so far. It may be set,
        in the kind `t0` was given in.
    loglik : float
        Log-likelihood of the measurements taken so far.

    Notes
    -----
    :meth:`predict` moves the belief to a later time through the
    linearisation strategy of `method` (:class:`gaussfuse.linearize.Exact`,
    :class:`~gaussfuse.linearize.Taylor` or
    :class:`~gaussfuse.linearize.SigmaPoints`) and
    :func:`gaussfuse.kalman.forecast`; :meth:`update` conditions it with
    :func:`gaussfuse.kalman.correct`: the two halves of :func:`gaussfuse.kalman.step`. The same steps as :func:`fuse_timeline`
    on the same (time-ordered) measurements give the same beliefs. Several
    sensors at one time are updated one after another: for linear sensors
    that equals their joint update; for nonlinear ones each update is
    linearised at the belief left by the one before, so it differs from the
    joint update of :func:`fuse_timeline` by a linearisation error.

    Time only moves forward: a timestamp earlier than :attr:`t` is rejected
    (:func:`fuse_timeline` sorts its input instead).

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> fuser = gf.Fuser(gf.ConstantVelocity(dim=1, q=0.1), {"gps": gf.Position(dim=1, r=4.0)},
    ...                  gf.Gaussian([0.0, 1.0], np.diag([10.0, 1.0])), t0=0.0)
    >>> _ = fuser.update(1.0, "gps", 1.2)
    >>> _ = fuser.predict(1.5)
    >>> fuser.t, fuser.belief.dim
    (1.5, 2)

    A :class:`Measurement` is the arguments of :meth:`update`:

    >>> _ = fuser.update(*gf.Measurement(2.0, "gps", 2.1))
    >>> fuser
    Fuser(sensors=['gps'], method='kf', t=2.0, loglik=-4.26778)
    """

    def __init__(self, motion, sensors, prior: Gaussian, t0: float, method: str | None = None,
                 check: str = "warn", **options) -> None:
        self._monitor = DivergenceMonitor.for_check(check)
        self._timeline = _Timeline(motion, sensors)
        self._belief = check_prior(prior, self._timeline.n)
        self._t = _time("t0", t0)
        self._dated = isinstance(self._t, np.datetime64)
        if self._dated:
            timing.no_dates_for_steps(motion, "t0")
        self.loglik = 0.0
        probe, _ = self._timeline.model(np.zeros(1))
        method = self._timeline.default_method() if method is None else method
        self._spec, options = resolve_method(probe, method, options, type(self))
        if self._spec.iterated:
            raise ValueError(
                f"`method` {method!r} iterates over the whole series; the online Fuser takes "
                "'kf', 'ekf', 'ukf', 'ckf' or 'ghkf'."
            )
        self._method, self._options = method, options
        self._measure = self._strategy(probe, np.zeros(1))
        self._state_angles, self._measurement_angles = (
            mask if mask is not None and mask.any() else None
            for mask in (getattr(probe, "state_angles", None), getattr(probe, "measurement_angles", None)))

    @property
    def belief(self) -> Gaussian:
        """The current belief, at time :attr:`t`; set it (a Gaussian over the motion's state) to restart a track."""
        return self._belief

    @belief.setter
    def belief(self, value: Gaussian) -> None:  # (unchecked, a wrong one failed at the next update: audit HH2)
        self._belief = check_prior(value, self._timeline.n, name="belief")

    @property
    def t(self):
        """The time of the belief; set it (seconds, or a datetime where `t0` was one) with :attr:`belief`."""
        return self._t

    @t.setter
    def t(self, value) -> None:
        self._t = _time("t", value, self._dated)

    def __repr__(self) -> str:  # (the default named only the object's address: audit Y3)
        return (f"Fuser(sensors={list(self._timeline.names)}, method={self._method!r}, t={self.t!r}, "
                f"loglik={self.loglik:.6g})")

    def __copy__(self) -> Fuser:
        # a copy fuses on its own: a shallow one would share the divergence monitor with the original
        return copy.deepcopy(self)

    def __setstate__(self, state: dict) -> None:
        for name in ("belief", "t"):  # (pickled before they were checked properties)
            if name in state:
                state["_" + name] = state.pop(name)
        self.__dict__.update(state)

    def _strategy(self, model, dts):
        us = None if self._timeline.linear else np.asarray(dts, dtype=float).reshape(-1, 1)
        return self._spec.strategy(model, us, **self._options)

    def _advance(self, t, argument: str) -> None:
        clock = _Clock.finest([self.t, t])
        now, then = clock.count("the fuser's time", self.t), clock.count(argument, t)
        if then < now:
            raise ValueError(
                f"`{argument}` = {t} is earlier than the fuser's current time {self.t}: an online "
                "Fuser cannot go back in time (out-of-order measurement); fuse_timeline sorts "
                "measurements by time instead."
            )
        dt = float(clock.steps(np.array([now, then]))[0])
        t = t if clock.unit is None else np.int64(then).view(f"datetime64[{clock.unit}]")
        if dt > 0.0:
            model, _ = self._timeline.model(np.array([dt]))
            lin = self._strategy(model, [dt])
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow raises FloatingPointError
                self._belief = Gaussian._trusted(*kalman.forecast(lin, 0, self._belief.mean, self._belief.cov,
                                                                  self._state_angles))
        self._t = t

    def predict(self, t: float) -> Gaussian:
        """Move the belief to time `t` (>= the current time) and return it.

        Parameters
        ----------
        t : float or datetime
            The time to predict to, >= the current time :attr:`t` (seconds,
            or a datetime, as `t0`).

        Returns
        -------
        Gaussian
            The predicted belief, also in :attr:`belief`.
        """
        self._advance(_time("t", t, self._dated), "t")
        return self.belief

    def update(self, t: float, sensor: str, z) -> Gaussian:
        """Predict to time `t`, condition on `sensor`'s measurement `z` and return the belief.

        Parameters
        ----------
        t : float or datetime
            Time of the measurement, >= the current time (seconds, or a
            datetime, as `t0`).
        sensor : str
            Name of the sensor.
        z : array_like of shape (m_s,)
            The measurement (a scalar when m_s = 1); NaN components are missing.

        Returns
        -------
        Gaussian
            The updated belief, also in :attr:`belief`. An update that
            raises (an invalid argument, or an innovation covariance that is
            not positive definite) leaves the fuser as it was; the divergence
            check's ``DivergenceWarning`` (``check="raise"``) is raised after
            the update is taken.
        """
        t = _time("t", t, self._dated)
        name = self._timeline.check_name(sensor, "sensor")
        z = self._timeline.measurement_vector(name, z)
        before = self._belief, self._t
        self._advance(t, "t")
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow raises FloatingPointError
                post = kalman.correct(self._measure, 0, self.belief.mean, self.belief.cov, z,
                                      state_angles=self._state_angles, measurement_angles=self._measurement_angles)[0]
        except BaseException:  # a failed (or interrupted) update leaves the fuser as it was (it had moved to `t`)
            self._belief, self._t = before
            raise
        self._belief = Gaussian._trusted(post.mean, post.cov)
        self.loglik += post.loglik
        if self._monitor is not None:
            self._monitor.observe(post, self.t, "times {} to {}")
        return self.belief
