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
        there), which leaves the gain undefined. (Where SciPy's solver
        fails on a badly scaled problem, an unstable F with Q 1e-30 of R,
        the filter's own covariance recursion is run to its fixed point
        instead; the error comes when that does not settle in 10,000 steps.)

    Notes
    -----
    The predicted covariance solves the discrete algebraic Riccati equation
    (module notes), as ``c solve_discrete_are(Fᵀ, Hᵀ, Q / c, R / c)``:
    scaling Q and R together scales the solution and leaves the gain as it
    is, so it is solved with c a power of two within a factor 2 of Q's
    largest entry and of the largest of Q's and R's, and the solution that
    satisfies the equation more closely is kept (R far larger than Q needs
    the first for a stable F, the second for an unstable one). Then, as in
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
    P = _riccati_solution(model)
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


def _riccati_solution(model: LinearModel) -> np.ndarray:
    """The stabilising solution of the Riccati equation (module notes), as accurate as SciPy can give it.

    P scales with Q and R together, but SciPy's solver is not scale-free (its residual checks and pencil are
    absolute), so it solves at unit scale, by a power of two (exact). Which unit matters where R is far larger
    than Q: in units of R a stable model's P (of Q's size) is lost in round-off (a ratio of 1e20 gave P wrong in
    sign), in units of Q an unstable one's (of R's size) is. Both are solved, and the one that satisfies the
    equation more closely is kept. With no process noise and a stable F, P = 0 exactly.
    """
    from scipy.linalg import solve_discrete_are  # SciPy on first use: `import gaussfuse` loads NumPy only

    F, H, Q, R = model.F, model.H, model.Q, model.R
    if not Q.any() and np.max(np.abs(np.linalg.eigvals(F))) < 1.0:
        return np.zeros_like(Q)
    q, r = np.abs(Q).max(), np.abs(R).max()
    found, error = [], None
    for unit in dict.fromkeys((max(q, r), q if q > 0.0 else r)):
        unit = np.ldexp(1.0, int(np.frexp(unit)[1]))
        try:
            with np.errstate(invalid="ignore"):  # SciPy's own casts, where it fails
                found.append(symmetrize(unit * solve_discrete_are(F.T, H.T, Q / unit, R / unit)))
        except (np.linalg.LinAlgError, ValueError) as exc:
            error = exc
    if not found:
        iterated = _iterated(model)
        if iterated is not None:
            return iterated
        raise ValueError(
            "the filter of `model` has no steady state: the Riccati equation has no stabilising solution "
            f"(SciPy: {error}). Check that every unstable mode of F is seen through H and reached by Q, and that "
            "R is positive definite where Q does not reach."
        ) from None
    return min(found, key=lambda P: _residual(model, P))


def _iterated(model: LinearModel, steps: int = 10_000) -> np.ndarray | None:
    """The filter's own predicted covariance from P⁻ = Q, run to its fixed point; None if it does not settle.

    Where SciPy's solver fails on a badly scaled problem (an unstable F with Q 1e-30 of R), the recursion
    still converges to the stabilising solution when there is one (from any P⁻ ⪰ 0, for a model whose
    unstable modes are seen and reached); without one it grows without bound, or does not settle within
    `steps` steps.
    """
    P = model.Q.copy()
    for _ in range(steps):
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                new = _riccati_map(model, P)
        except np.linalg.LinAlgError:
            return None
        if not np.isfinite(new).all():
            return None
        if kalman.settled(new, P):
            return new
        P = new
    return None


def _riccati_map(model: LinearModel, P: np.ndarray) -> np.ndarray:
    """One step of the filter's predicted covariance, ``F P⁺ Fᵀ + Q`` with P⁺ updated from P (kalman's algebra).

    Raises numpy.linalg.LinAlgError where S is singular.
    """
    return kalman.predict(np.zeros(P.shape[0]), kalman.gain(P, model.H, model.R).cov, model.F, model.Q)[1]


def _residual(model: LinearModel, P: np.ndarray) -> float:
    """How far P is from solving the Riccati equation, relative to its size: max |F P⁺ Fᵀ + Q - P| / max |P|."""
    try:
        predicted = _riccati_map(model, P)
    except np.linalg.LinAlgError:  # a singular S: left to the caller's message
        return np.inf
    size = np.abs(P).max()
    return float(np.abs(predicted - P).max() / size) if size > 0.0 else 0.0
