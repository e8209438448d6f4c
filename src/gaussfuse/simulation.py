r"""Draws from a model: simulated series, and whole state trajectories from the smoothing distribution.

:func:`simulate` draws from the model itself: :math:`x_0` from the prior
(one step before the first measurement), then

.. math::

    x_k = f_k(x_{k-1}, u_k) + w_k, \quad w_k \sim N(0, Q_k), \qquad
    z_k = h_k(x_k) + v_k, \quad v_k \sim N(0, R_k),

(:math:`f_k(x, u) = F_k x + B_k u_k`, :math:`h_k(x) = H_k x` for a
LinearModel). Each Gaussian draw is :math:`L \varepsilon` with
:math:`\varepsilon` standard normal and :math:`L` a lower-triangular
square root of the covariance (:func:`gaussfuse.kalman.cov_factor`), so a
zero or singular covariance is drawn exactly: a component without noise
gets none.

:func:`sample_posterior` draws whole trajectories :math:`x_{1:T}` from
:math:`p(x_{1:T} \mid z_{1:T})` of a LinearModel, by forward filtering,
backward sampling: the filter gives :math:`N(m_k, P_k)`; then
:math:`x_T \sim N(m_T, P_T)` and, going back,

.. math::

    x_k \mid x_{k+1} \sim N\left(m_k + G_k (x_{k+1} - m^-_{k+1}),\;
    P_k - G_k P^-_{k+1} G_k^\top\right),

the conditional of the joint Gaussian of :math:`(x_{k+1}, x_k)` given the
data up to k, with the RTS gain :math:`G_k`. Its factor and the gain come
from one triangularisation (:func:`gaussfuse.kalman.backward_conditional`), so the
conditional covariance is never a difference of covariances. The
trajectories' mean and covariance at each step are the RTS smoother's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kalman
from ._linalg import wrap_components
from ._frozen import reduce_frozen, shapes_repr
from ._validation import generator, integer
from .errors import ModelFunctionError, at_step
from .inference import drivers, frames
from .inference import filter as run_filter
from .inference.results import stack
from .inference.timing import resolve
from .inference.validation import check_controls, check_measurements, check_model, check_prior, check_steps
from .models.compose import TimedModel
from .models.linear import LinearModel

__all__ = ["simulate", "Simulation", "sample_posterior"]


@dataclass(frozen=True, eq=False)
class Simulation:
    """The output of :func:`simulate`; its arrays are read-only.

    Attributes
    ----------
    states : ndarray of shape (T, n), or (size, T, n)
        :math:`x_1, \\dots, x_T`.
    measurements : ndarray of shape (T, m), or (size, T, m)
        :math:`z_1, \\dots, z_T`.
    initial : ndarray of shape (n,), or (size, n)
        :math:`x_0`, drawn from the prior.
    """

    states: np.ndarray
    measurements: np.ndarray
    initial: np.ndarray

    __reduce__ = reduce_frozen
    __repr__ = shapes_repr


def _draw(rng: np.random.Generator, factor: np.ndarray, size: int) -> np.ndarray:
    """`size` draws of N(0, L Lᵀ), as rows."""
    return rng.standard_normal((size, factor.shape[1])) @ factor.T


def simulate(model, prior, T: int, us=None, *, times=None, size: int | None = None, rng=None) -> Simulation:
    """Draw states and measurements from a model.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
    prior : Gaussian
        The state one step before the first measurement, as in :func:`gaussfuse.filter`.
    T : int
        Steps to draw, at least 1 (a time-varying model's own number of steps).
    us : array_like of shape (T, p), optional
        Controls, when the model has ``B`` (or its ``f`` takes them).
    times : array_like of shape (T,) or (T + 1,), optional
        The steps' times, as in :func:`gaussfuse.filter`: a TimedModel
        (:func:`gaussfuse.model` without dt) is discretised for each step.
    size : int, optional
        Draw this many independent series at once (a leading axis);
        default one series, without the axis.
    rng : None, int or numpy.random.Generator
        The source of randomness; an integer seeds a new Generator (anything
        else :func:`numpy.random.default_rng` takes is taken, a
        ``RandomState`` too). The draws are made a step at a time for all
        series together, so a seed's first series depends on `size` (``size=1``
        gives the series of ``size=None``).

    Returns
    -------
    Simulation
        The components the model declares as angles (``state_angles``,
        ``measurement_angles``) in [-π, π), as a filter reports its means
        and a sensor its readings.

    Raises
    ------
    TypeError, ValueError
        For bad arguments, named.
    numpy.linalg.LinAlgError
        When a covariance made per step (a model given per step, or
        discretised for each dt) is not positive semi-definite; a fixed Q, R
        or prior covariance is refused (ValueError) when the model or the
        Gaussian is made.
    ModelFunctionError
        When a NonlinearModel's f or h fails (see :class:`gaussfuse.NonlinearModel`).

    Examples
    --------
    >>> import gaussfuse as gf
    >>> sim = gf.simulate(gf.constant_velocity(dt=1.0, q=0.1, r=1.0), gf.Gaussian([0, 1], [[1, 0], [0, 1]]), 50,
    ...                   rng=0)
    >>> sim.states.shape, sim.measurements.shape
    ((50, 2), (50, 1))
    """
    T = integer("T", T)
    check_model(model)
    model, us = resolve(model, times, T, us, rows=False)  # (no rows: simulate takes no `zs`, audit DD6)
    prior = check_prior(prior, model.n)
    check_steps(model, T, "`T` asks for")
    count = 1 if size is None else integer("size", size)
    us = check_controls(us, model, 1, T, matching="`T`")
    u = None if us is None else us[0]
    rng = generator(rng)
    n, m = model.n, model.m
    states, measurements = np.empty((count, T, n)), np.empty((count, T, m))
    state_angles, measurement_angles = (getattr(model, name, None) for name in ("state_angles", "measurement_angles"))
    with np.errstate(over="ignore", invalid="ignore"):
        x0 = wrap_components(prior.mean + _draw(rng, kalman.cov_factor(prior.cov, "the prior covariance"), count),
                             state_angles)
    x = x0
    roots = kalman.Factors()
    linear = isinstance(model, LinearModel)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is raised below
        for k in range(T):
            try:  # (f and h are checked at each row; their errors name the step, as a filter's do)
                if linear:
                    F, H, Q, R, B = model.at(k)
                    x = x @ F.T + (0.0 if B is None else B @ u[k])
                else:
                    Q, R = model.noise(k)
                    x = model.transition(x, None if u is None else u[k])
                x = wrap_components(x + _draw(rng, roots("Q", Q), count), state_angles)
                z = x @ H.T if linear else model.measurement(x)
            except ModelFunctionError as exc:
                raise at_step(exc, k) from None
            states[:, k] = x
            measurements[:, k] = wrap_components(z + _draw(rng, roots("R", R), count), measurement_angles)
    if not (np.all(np.isfinite(states)) and np.all(np.isfinite(measurements))):
        raise FloatingPointError("the simulation overflowed: its states or measurements are not finite.")
    out = (states, measurements, x0) if size is not None else (states[0], measurements[0], x0[0])
    for a in out:
        a.setflags(write=False)
    return Simulation(*out)


def sample_posterior(model: LinearModel, prior, zs, n: int, us=None, *, times=None, rng=None, form: str = "cov",
                     check: str = "warn") -> np.ndarray:
    """Draw n state trajectories from the smoothing distribution, by forward filtering, backward sampling.

    Parameters
    ----------
    model : LinearModel
    prior : Gaussian
        As in :func:`gaussfuse.filter`, but a Gaussian: a diffuse prior
        ("diffuse") is refused.
    zs : array_like of shape (T, m) or (T,)
        One series of measurements (a pandas Series or DataFrame too);
        NaN = missing.
    n : int
        How many trajectories, at least 1.
    us : array_like of shape (T, p), optional
        Controls, when the model has ``B``.
    times : array_like of shape (T,) or (T + 1,), optional
        The measurements' times, as in :func:`gaussfuse.filter` (a pandas
        `zs` with a DatetimeIndex supplies them): a TimedModel of a linear
        motion and sensor steps by them.
    rng : None, int or numpy.random.Generator
        As for :func:`simulate`: the draws are made a step at a time for all
        `n` trajectories together, so a seed's first one depends on `n`.
    form : {"cov", "sqrt"}, default "cov"
        The filter's form (see :func:`gaussfuse.filter`): ``"sqrt"`` where
        the covariance form loses its accuracy (a huge prior with a precise
        sensor); its factors are then used as they are.
    check : {"warn", "raise", "off"}, default "warn"
        The filter's divergence test (see :func:`gaussfuse.filter`).

    Returns
    -------
    ndarray of shape (n, T, state dimension)
        Independent draws of :math:`x_{1:T} \\mid z_{1:T}`; their mean and
        covariance at each step converge to the RTS smoother's, to the
        precision of the filter's factors: with no process noise and
        dynamics that squeeze a direction below round-off, the spread along
        it is lost at the late steps and magnified at the early ones (the
        squeezing example of docs/accuracy.md over 6 steps: one variance 17-20% low
        with ``"cov"``, right to sampling error with ``"sqrt"``; over 12 steps
        ``"cov"`` up to 21% low and ``"sqrt"`` up to 1.32 times too large,
        its means 0.005 to 0.27 standard deviations off over six data seeds,
        as far as the smoother's own means, up to 0.29). A process noise of
        1e-16 of the variances removes it (both forms then right to sampling
        error there, over 6 and 12 steps).

    Raises
    ------
    TypeError, ValueError
        For bad arguments, named (a NonlinearModel, a batch of series).

    Notes
    -----
    See the module notes. The filter is :func:`gaussfuse.filter` (its
    divergence check included); each backward step triangularises the
    joint factor once and draws all n trajectories together.

    Examples
    --------
    >>> import numpy as np
    >>> import gaussfuse as gf
    >>> model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    >>> draws = gf.sample_posterior(model, gf.Gaussian([0.0], [[1.0]]), [1.0, 2.0, np.nan, 3.0], 1000, rng=0)
    >>> draws.shape
    (1000, 4, 1)
    """
    given = type(model).__name__

    def refuse(of: str = "") -> TypeError:
        return TypeError("`model` must be a gaussfuse.LinearModel: backward sampling is exact for linear-Gaussian "
                         f"models only; got {given}{of}.")

    if not isinstance(model, (LinearModel, TimedModel)):
        raise refuse()
    zs, times, table = frames.unpack(zs, times, model)  # a pandas index supplies the times, as in filter
    us = frames.controls(us, table)
    if times is not None or isinstance(model, TimedModel):  # (audit AA3: a TimedModel was refused as not linear)
        model, us = resolve(model, times, check_measurements(zs, model.m, one=True), us,
                            name="times" if table is None else table.times_name)
    if not isinstance(model, LinearModel):
        raise refuse(" (a TimedModel of a nonlinear motion or sensor)")
    prior = check_prior(prior, model.n)
    count = integer("n", n)
    arr = check_measurements(zs, model.m, one=True)
    T = arr.shape[1]
    check_steps(model, T)
    us = check_controls(us, model, 1, T)
    u = None if us is None else us[0]
    rng = generator(rng)
    check = drivers.checked(check)
    filt = run_filter(model, prior, arr[0], u, form=form, check="off")
    drivers.check_divergence(stack([filt]), check)  # here, so that a warning points at the caller's line
    roots = kalman.Factors()
    factors = (filt.cov_factors if filt.cov_factors is not None
               else [kalman.cov_factor(P, "a filtered covariance") for P in filt.covs])
    draws = np.empty((count, T, model.n))
    with np.errstate(over="ignore", invalid="ignore"):
        draws[:, -1] = filt.means[-1] + _draw(rng, factors[-1], count)
        for k in range(T - 2, -1, -1):  # x_k | x_{k+1}, through the transition into step k + 1
            F, _, Q, _, B = model.at(k + 1)
            b = None if B is None else B @ u[k + 1]
            means, X = kalman.backward_conditional(filt.means[k], factors[k], draws[:, k + 1], F, roots("Q", Q), b)
            draws[:, k] = means + _draw(rng, X, count)
    if not np.all(np.isfinite(draws)):
        raise FloatingPointError("the posterior draws overflowed: they are not finite.")
    return draws
