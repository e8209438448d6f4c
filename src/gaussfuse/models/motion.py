"""Motion models with position measurements, built for a given time step."""

from __future__ import annotations

from math import factorial

import numpy as np

from .linear import LinearModel

__all__ = ["constant_velocity", "constant_acceleration", "state_names"]

_AXES = ("x", "y", "z")
_PREFIX = ("", "v", "a")


def _check(name: str, value, positive: bool) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"`{name}` must be a number; got {value!r}.")
    value = float(value)
    if not np.isfinite(value) or value < 0 or (positive and value == 0):
        raise ValueError(f"`{name}` must be {'positive' if positive else 'non-negative'}; got {value}.")
    return value


def _integrated_white_noise(order: int, dt: float, q: float, r: float, dim: int) -> LinearModel:
    r"""The order-K integrated white-noise model per axis, stacked over `dim` axes.

    Per axis the state is (position, its first K derivatives) and the K-th
    derivative is driven by continuous white noise of spectral density q:

    .. math::

        F_{ij} = \frac{\Delta t^{j-i}}{(j-i)!} \ (j \ge i), \qquad
        Q_{ij} = q \frac{\Delta t^{2K+1-i-j}}{(2K+1-i-j)\,(K-i)!\,(K-j)!}.

    The full state orders all positions first, then all velocities, and so on.
    """
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or not 1 <= dim <= 3:
        raise ValueError(f"`dim` must be 1, 2 or 3; got {dim!r}.")
    dt = _check("dt", dt, positive=True)
    q = _check("q", q, positive=False)
    r = _check("r", r, positive=True)
    K = order
    idx = np.arange(K + 1)
    i, j = np.meshgrid(idx, idx, indexing="ij")
    fact = np.vectorize(factorial)
    F1 = np.where(j >= i, dt ** np.abs(j - i) / fact(np.abs(j - i)), 0.0)
    power = 2 * K + 1 - i - j
    Q1 = q * dt**power / (power * fact(K - i) * fact(K - j))
    eye = np.eye(dim)
    H = np.hstack([eye, np.zeros((dim, K * dim))])
    return LinearModel(F=np.kron(F1, eye), H=H, Q=np.kron(Q1, eye), R=r * eye)


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
    Per axis :math:`F = [[1, Δt], [0, 1]]` and
    :math:`Q = q [[Δt^3/3, Δt^2/2], [Δt^2/2, Δt]]`.

    Examples
    --------
    >>> import gaussfuse as gf
    >>> gf.constant_velocity(dt=0.1, q=1.0, r=0.25, dim=2)
    LinearModel(n=4, m=2, p=0)
    """
    return _integrated_white_noise(1, dt, q, r, dim)


def constant_acceleration(dt: float, q: float, r: float, dim: int = 1) -> LinearModel:
    """Nearly-constant-acceleration model (white-noise jerk) measuring position.

    Parameters are those of :func:`constant_velocity`, with `q` the spectral
    density of the jerk. The state is positions, then velocities, then
    accelerations (size 3·dim).

    Notes
    -----
    Per axis :math:`F = [[1, Δt, Δt^2/2], [0, 1, Δt], [0, 0, 1]]` and
    :math:`Q = q [[Δt^5/20, Δt^4/8, Δt^3/6], [Δt^4/8, Δt^3/3, Δt^2/2], [Δt^3/6, Δt^2/2, Δt]]`.
    """
    return _integrated_white_noise(2, dt, q, r, dim)


def state_names(order: int, dim: int) -> list[str]:
    """Names of the states of an order-K model in `dim` axes: x, y, vx, vy, ..."""
    return [_PREFIX[k] + _AXES[a] for k in range(order + 1) for a in range(dim)]
