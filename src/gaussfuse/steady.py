r"""The steady state of a time-invariant filter: the stationary covariances and gain.

For a time-invariant linear model the covariance recursion of the Kalman
filter does not depend on the measurements, and (when the model is
detectable and its noise reaches every unstable mode) it converges to the
stabilising solution of the discrete algebraic Riccati equation,

.. math::

    P^- = F P^- F^\top - F P^- H^\top (H P^- H^\top + R)^{-1} H P^- F^\top + Q,

whatever the prior. :func:`steady_state` solves it with SciPy
(:func:`scipy.linalg.solve_discrete_are`) and completes the update with
:func:`gaussfuse.kalman.gain`. ``gf.filter(..., steady=True)`` uses the
result to stop computing covariances once the filter has reached it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from . import kalman
from ._frozen import reduce_frozen, shapes_repr
from ._linalg import symmetrize
from .models.linear import LinearModel

__all__ = ["Stationary", "steady_state"]


@dataclass(frozen=True, eq=False)
class Stationary:
    """The steady state of a time-invariant filter (:func:`steady_state`); its arrays are read-only.

    Attributes
    ----------
    predicted_cov : ndarray of shape (n, n)
        :math:`P^-_\\infty`, the stationary covariance of the prediction.
    cov : ndarray of shape (n, n)
        :math:`P_\\infty`, the stationary filtered covariance (Joseph form).
    gain : ndarray of shape (n, m)
        :math:`K_\\infty = P^-_\\infty H^\\top S_\\infty^{-1}`.
    innovation_cov : ndarray of shape (m, m)
        :math:`S_\\infty = H P^-_\\infty H^\\top + R`.
    """

    predicted_cov: np.ndarray
    cov: np.ndarray
    gain: np.ndarray
    innovation_cov: np.ndarray

    __reduce__ = reduce_frozen  # pickles and copies keep read-only arrays read-only
    __repr__ = shapes_repr


def steady_state(model: LinearModel) -> Stationary:
    r"""The stationary covariances and gain of a time-invariant linear model's filter.

    Parameters
    ----------
    model : LinearModel
        With F, H, Q and R the same at every step (B does not matter).

    Returns
    -------
    Stationary
        ``predicted_cov``, ``cov``, ``gain`` and ``innovation_cov``.

    Raises
    ------
    TypeError
        When `model` is not a LinearModel.
    ValueError
        When it is time-varying, or when the Riccati equation has no
        stabilising solution (an unstable mode that the measurements do not
        see, or one that the process noise does not reach while R is
        singular): then the filter's covariance has no steady state to
        converge to. Also when the steady state has a singular innovation
        covariance (no noise reaches a measured component and R is zero
        there), which leaves the gain undefined.

    Notes
    -----
    The predicted covariance solves the discrete algebraic Riccati equation
    (module notes), as ``c solve_discrete_are(Fᵀ, Hᵀ, Q / c, R / c)``:
    scaling Q and R together scales the solution and leaves the gain as it
    is, so it is solved with c a power of two within a factor 2 of their
    largest entry, whatever their scale. Then, as in
    :func:`gaussfuse.kalman.update`,

    .. math::

        S_\infty = H P^-_\infty H^\top + R, \qquad
        K_\infty = P^-_\infty H^\top S_\infty^{-1}, \qquad
        P_\infty = (I - K_\infty H) P^-_\infty (I - K_\infty H)^\top + K_\infty R K_\infty^\top .

    Examples
    --------
    >>> import numpy as np, gaussfuse as gf
    >>> ss = gf.steady_state(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0))
    >>> round(float(ss.predicted_cov[0, 0]), 6)  # the golden ratio: p² = p + 1
    1.618034
    """
    if not isinstance(model, LinearModel):
        raise TypeError(f"`model` must be a gaussfuse.LinearModel; got {type(model).__name__}.")
    if any(a.ndim == 3 for a in (model.F, model.H, model.Q, model.R)):
        raise ValueError("`model` is time-varying (F, H, Q or R has a time axis): a steady state needs the "
                         "same matrices at every step.")
    from scipy.linalg import solve_discrete_are  # SciPy on first use: `import gaussfuse` loads NumPy only

    # P scales with Q and R together, but SciPy's solver is not scale-free (its residual checks and pencil
    # are absolute): solve at unit scale, by a power of two, which is exact.
    scale = np.ldexp(1.0, int(np.frexp(max(np.abs(model.Q).max(), np.abs(model.R).max()))[1]))
    try:
        P = scale * solve_discrete_are(model.F.T, model.H.T, model.Q / scale, model.R / scale)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(
            "the filter of `model` has no steady state: the Riccati equation has no stabilising solution "
            f"(SciPy: {exc}). Check that every unstable mode of F is seen through H and reached by Q, and that "
            "R is positive definite where Q does not reach."
        ) from None
    P = symmetrize(P)
    try:
        g = kalman.gain(P, model.H, model.R)
    except np.linalg.LinAlgError:
        raise ValueError(
            "the filter of `model` has no steady gain: its stationary innovation covariance S = H P Hᵀ + R is "
            f"singular ({np.array2string(symmetrize(model.H @ P @ model.H.T + model.R), separator=', ')}): the "
            "state is known exactly in the long run and R = 0 where it is measured. Give R a positive variance."
        ) from None
    out = Stationary(P, g.cov, g.K, g.innovation_cov)
    for f in fields(out):
        getattr(out, f.name).setflags(write=False)
    return out
