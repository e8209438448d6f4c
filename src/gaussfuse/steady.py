r"""The steady state of a time-invariant filter: the stationary covariances and gain.

For a time-invariant linear model the covariance recursion of the Kalman
filter does not depend on the measurements, and (when the model is
detectable and its noise reaches every unstable mode) it converges to the
stabilising solution of the discrete algebraic Riccati equation,

.. math::

    P^- = F P^- F^\top - F P^- H^\top (H P^- H^\top + R)^{-1} H P^- F^\top + Q,

whatever the prior. :func:`steady_state` solves it with SciPy
(:func:`scipy.linalg.solve_discrete_are`) and the doubling algorithm,
keeps what proves to be the stabilising solution, and completes the update
with :func:`gaussfuse.kalman.gain`. ``gf.filter(..., steady=True)`` uses the
result to stop computing covariances once the filter has reached it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from . import kalman
from ._frozen import reduce_frozen, shapes_repr
from ._linalg import cholesky, general_solve, is_positive_definite, shown, symmetrize, whiten
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
        singular, or, with R singular, a zero on the unit circle of the
        system from the process noise to the measurements: a constant
        velocity with piecewise noise measured with R = 0 has one at -1):
        then the filter's covariance has no steady state to converge to, or
        converges to one only as 1/k, at which the filter is not stable;
        or a mode on the unit circle (to its eigenvalue's round-off, at most
        1e-6, so that a rotation is one whatever round-off makes of it)
        that Q does not drive beyond round-off (a constant estimated without
        process noise: its variance falls to 0 as 1/k, and the gain with
        it), or drives so faintly beside R that the filter's pole at 1,
        about 1 - √(Q/R), rounds to 1 (a random walk with Q below about
        1e-32 R). Also when the steady state has a singular innovation
        covariance (no noise reaches a measured component and R is zero
        there), which leaves the gain undefined.

    Notes
    -----
    The predicted covariance solves the discrete algebraic Riccati equation
    (module notes). Its candidates are ``c solve_discrete_are(Fᵀ, Hᵀ, Q / c,
    R / c)`` with c a power of two within a factor 2 of Q's largest entry and
    of the largest of Q's and R's (scaling Q and R together scales the
    solution and leaves the gain; R far larger than Q needs the first for a
    stable F, the second for an unstable one), and the filter's own
    recursion from 0 doubled until it settles (the structure-preserving
    doubling algorithm, with R positive definite). A candidate counts only
    when it is the stabilising solution: symmetric positive semi-definite,
    satisfying the equation to 1e-8 of its size, with every eigenvalue of
    :math:`F (I - K H)` inside the unit circle (SciPy returns other
    solutions where Q is tiny beside R); of those the one that satisfies it
    most closely is kept, and the recursion is run step by step where none
    does. Near the unit circle the answer is as exact as the equation's
    terms allow: a random walk with Q 1e-20 of R (pole 1 - 1e-10) within
    about 1e-8 of the closed form. That is on the scale of the largest
    entries: a mode whose variance is far below them is exact only to their
    round-off (with Q of condition 2e17, mixing 1e-9 and 1e8, a random-walk
    mode got 5.0e-10 where the exact inputs give 2.1e-5; either fits Q to
    its round-off). Then, as in
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
        raise _no_steady_gain(model, P) from None
    out = Stationary(P, g.cov, g.K, g.innovation_cov)
    for f in fields(out):
        getattr(out, f.name).setflags(write=False)
    return out


def _no_steady_gain(model: LinearModel, P: np.ndarray) -> ValueError:
    """The error for a filter whose predicted covariance `P` leaves S = H P Hᵀ + R singular: no gain to hold."""
    S = symmetrize(model.H @ P @ model.H.T + model.R)
    return ValueError(
        "the filter of `model` has no steady gain: its stationary innovation covariance S = H P Hᵀ + R is "
        f"singular ({shown(S)}): a combination of the measurements has no noise (R is "
        "singular on it) and measures what the state knows exactly in the long run, or repeats another "
        "measurement with the same noise (two sensors of one component with fully correlated noise). Give R a "
        "positive definite covariance, or leave out the repeated measurement.")


def _riccati_solution(model: LinearModel) -> np.ndarray:
    """The stabilising solution of the Riccati equation (module notes), from the candidates that prove to be one.

    P scales with Q and R together, but SciPy's solver is not scale-free (its residual checks and pencil are
    absolute), so it solves at unit scale, by a power of two (exact). Which unit matters where R is far larger
    than Q: in units of R a stable model's P (of Q's size) is lost in round-off (a ratio of 1e20 gave P wrong in
    sign), in units of Q an unstable one's (of R's size) is. Beside those two, the doubling algorithm
    (:func:`_doubled`) gives a third candidate. SciPy also returns solutions that are not the stabilising one
    where Q is tiny beside R (F = 1.01, Q = 1e-25: P = 22304 for 0.0201): a candidate is kept only when it
    :func:`_stabilises`, and of those the one that satisfies the equation most closely. With no process noise
    and a stable F, P = 0 exactly.
    """
    from scipy.linalg import solve_discrete_are  # SciPy on first use: `import gaussfuse` loads NumPy only

    F, H, Q, R = model.F, model.H, model.Q, model.R
    q, r = np.abs(Q).max(), np.abs(R).max()
    unit = _unit_circle_modes(F, Q, H)
    unseen = [(v, drive > noise) for v, drive, noise, seen in unit if not seen]
    if unseen:  # (before the candidates, which a closed loop at 1 - 1.1e-16 passed: audit WW1)
        v, driven = unseen[0]
        raise ValueError(
            f"the filter of `model` has no steady state: F has a mode on the unit circle (eigenvalue {v:.3g}) that "
            "H does not measure, so nothing the filter sees settles it: its variance "
            + ("grows without bound, driven by Q" if driven else "stays at the prior's, whatever it is")
            + ". Measure that mode (a row of H that sees it), or filter without steady=True.")
    still = [v for v, drive, noise, _ in unit if drive <= noise]
    if not still and not Q.any() and max(abs(v) for v in np.linalg.eigvals(F)) < 1.0:
        return np.zeros_like(Q)
    found, error = [], None
    for scale in dict.fromkeys((max(q, r), q if q > 0.0 else r)):
        scale = np.ldexp(1.0, int(np.frexp(scale)[1]) - 1)  # at most the scale: 2**1024 is past float64
        try:
            with np.errstate(invalid="ignore", over="ignore"):  # SciPy's own casts, where it fails; a unit that
                # overflows R / c (Q 1e-280 beside R 1e308) fails SciPy, its candidate with it
                found.append(symmetrize(scale * solve_discrete_are(F.T, H.T, Q / scale, R / scale)))
        except (np.linalg.LinAlgError, ValueError) as exc:
            error = exc
    found.append(_doubled(model))
    kept = [P for P in found if P is not None and _stabilises(model, P)]
    known = [P for P in found if P is not None and _covariance(P) and _residual(model, P) == np.inf]
    if not kept and known:  # a solution whose S is singular: steady_state names it
        return known[0]
    if still:  # whatever the candidates: a rotation's pole computed as 1 - 4e-16 passed their test (audit AA2)
        raise ValueError(
            f"the filter of `model` has no steady state: F has a mode on the unit circle (eigenvalue "
            f"{still[0]:.3g}) that Q does not drive, as a constant estimated without process noise: its "
            "variance falls to 0 as 1/k, and the gain with it, with no steady gain to hold. Give Q a "
            "variance there, or filter without steady=True.")
    if not kept:
        iterated = _iterated(model)
        if iterated is not None and _stabilises(model, iterated):
            return iterated
        why = f" (SciPy: {error})" if error is not None else ""
        faint = [(v, drive) for v, drive, _, _ in unit if drive < 1e-31 * r]
        if faint:  # the gain, about √(Q/R) there, and the loop's distance from the circle are round-off
            raise ValueError(
                f"the filter of `model` has no steady state that float64 can hold: F has a mode on the unit "
                f"circle (eigenvalue {faint[0][0]:.3g}) that Q drives with {faint[0][1]:.3g}, beside R's "
                f"{r:.3g}: its steady gain, about √(Q/R), leaves the filter's pole at 1 to round-off. Give Q a "
                "larger variance there, or filter without steady=True.") from None
        raise ValueError(
            f"the filter of `model` has no steady state: the Riccati equation has no stabilising solution{why}. "
            "Check that every unstable mode of F is seen through H and reached by Q, and that R is positive "
            "definite where Q does not reach; with R singular, the process noise may reach a measurement through "
            "a zero on the unit circle (as a constant velocity with piecewise noise and R = 0, at -1), where the "
            "covariance converges only as 1/k, to no stable gain: give R a positive variance."
        ) from None
    return min(kept, key=lambda P: (_residual(model, P) > _ROUND_OFF, _balance(model, P)))


def _unit_circle_modes(F: np.ndarray, Q: np.ndarray, H: np.ndarray) -> list[tuple[complex, float, float, bool]]:
    """The modes of F on the unit circle, to each eigenvalue's round-off: (λ, how much Q drives it, w* Q w for
    the left eigenvector w, that drive's own round-off, and whether H sees it).

    H sees a mode where ‖H x‖ of its unit right eigenvector x (the one H sees least, in a repeated eigenvalue's
    eigenspace: :func:`_least`) is above its round-off. One it does not see stays in the closed loop
    F (I - K H) whatever the gain, so there is no stabilising solution; computed, the loop's radius came out
    1 - 1.1e-16 and a rotation H never measured had a "steady" variance of 1.7e16 (audit WW1).

    An eigenvalue is computed to about ε ‖F‖ times its condition number 1 / |yᴴ x| (y and x its unit left and
    right eigenvectors): a rotation's is exact to 1e-16, so that a stable mode at 1 - 1e-10 is told from it, and a
    Jordan block's, in coordinates that are not triangular, only to about 1e-8 (its condition number near 1e8).
    A drive within the round-off of Q's entries along w is none: Q = diag(1, 1e-13) drives both of F = I's
    modes (review R16: judged against Q's largest entry, the second was not driven).
    """
    from scipy.linalg import eig, matrix_balance

    B, (scale, _) = matrix_balance(F, permute=False, separate=True)  # B = D⁻¹ F D, as LAPACK balances
    vals, left, right = eig(B, left=True, right=True)
    size, eps = max(np.abs(B).max(), 1.0), float(np.finfo(np.float64).eps)
    modes = []
    for v, y, x in zip(vals, left.T, right.T):
        condition = 1.0 / max(abs(np.vdot(y, x)), 1e-300)
        # at most 1e-6 off the circle: a badly scaled F's first-order bound can reach past 0.5 (review R17)
        tol = min(64.0 * eps * size * condition, 1e-6)
        if abs(abs(v) - 1.0) <= tol:
            # its eigenspace: the singular values of F - v I that are round-off, not a Jordan block's coupling of 1e-6
            # (a clock's phase and drift at 1 MHz was refused when the eigenvalue's bound was used: review R18)
            w = _least(F, Q, complex(v), 1e-10 * max(np.abs(F).max(), 1.0), y / scale, left=True)
            drive, noise = abs(np.conj(w) @ Q @ w), 64.0 * eps * (np.abs(w) @ np.abs(Q) @ np.abs(w))
            # the eigenspace to round-off only: at 1e-10, a constant velocity sampled at 1e-10 s (F - I's singular
            # value 1e-10) and a mode at 1 - 1e-11 beside one at 1 counted as a repeated eigenvalue, whose
            # unmeasured direction refused them, detectable as they are (review R53)
            u = _least(F, H.T @ H, complex(v), 64.0 * eps * max(np.abs(F).max(), 1.0), x * scale, left=False)
            seen = np.linalg.norm(H @ u) > 64.0 * eps * np.linalg.norm(np.abs(H) @ np.abs(u))
            modes.append((complex(v), float(drive), float(noise), bool(seen)))
    return modes


def _least(F: np.ndarray, A: np.ndarray, v: complex, tol: float, x: np.ndarray, left: bool) -> np.ndarray:
    """The unit left (`left`) or right eigenvector u for `v`, in F's eigenspace there (singular values of F - v I up
    to `tol`), with the least uᴴ A u; or `x` normalised where the eigenspace is one direction.

    A repeated eigenvalue's eigenvectors are any basis of its eigenspace: with F = I and Q = 1 1ᵀ, neither
    returned one shows that Q never drives x1 - x2 (review R17, A = Q on the left), nor with H = [1, 0] that H
    never sees x2 (A = HᵀH on the right)."""
    U, sv, Vh = np.linalg.svd(F - v * np.eye(F.shape[0]))
    space = U[:, sv <= tol] if left else Vh[sv <= tol].conj().T
    if space.shape[1] < 2:
        return x / np.linalg.norm(x)
    _, vecs = np.linalg.eigh(space.conj().T @ A @ space)  # within the eigenspace, least first
    least = space @ vecs[:, 0]
    return least / np.linalg.norm(least)


_ROUND_OFF = 1e-14  # a residual relative to P's size that is round-off: candidates within it are told apart by
#                    _balance


def _balance(model: LinearModel, P: np.ndarray) -> float:
    """The Riccati equation's residual as two balances, ``(F P Fᵀ - P) + (Q - F K S Kᵀ Fᵀ)``, relative to the larger
    of Q and the information term ``F K S Kᵀ Fᵀ``.

    Near the unit circle, F P Fᵀ ≈ P and both Q and the information a step gains are far below P, so the residual
    relative to P (:func:`_residual`) is round-off for any candidate near the solution: for a random walk with
    Q = 1e-21 R, SciPy's answer 2.3e-6 off and the doubling's 8e-9 off both had 0 (audit AA2). Measured against
    the terms that balance, they differ by those errors.
    """
    g = kalman.gain(P, model.H, model.R)
    info = model.F @ (g.K @ g.innovation_cov @ g.K.T) @ model.F.T
    scale = max(np.abs(model.Q).max(), np.abs(info).max())
    if scale == 0.0:
        return 0.0
    return float(np.abs((model.F @ P @ model.F.T - P) + (model.Q - info)).max() / scale)


def _stabilises(model: LinearModel, P: np.ndarray) -> bool:
    """Whether P is a covariance that solves the Riccati equation and whose gain makes the filter stable.

    Symmetric positive semi-definite to round-off, S = H P Hᵀ + R positive definite, the equation satisfied to
    1e-8 of P's size, and the closed loop of the prediction error, F (I - K H), with every eigenvalue inside the
    unit circle: what singles out the stabilising solution among the equation's solutions.
    """
    if not _covariance(P):
        return False
    try:
        g = kalman.gain(P, model.H, model.R)
    except np.linalg.LinAlgError:
        return False
    if _residual(model, P) > 1e-8:
        return False
    loop = model.F @ (np.eye(P.shape[0]) - g.K @ model.H)
    return bool(np.max(np.abs(np.linalg.eigvals(loop))) < 1.0)


def _covariance(P: np.ndarray) -> bool:
    """Whether P is finite, symmetric positive semi-definite to round-off of its largest entry."""
    return bool(np.isfinite(P).all() and np.linalg.eigvalsh(P).min() >= -1e-12 * np.abs(P).max())


def _doubled(model: LinearModel, most: int = 200) -> np.ndarray | None:
    r"""The Riccati recursion from :math:`P^- = 0` doubled until it settles (the structure-preserving doubling
    algorithm); None without a positive definite R, or when it does not settle or overflows.

    The filter's recursion is :math:`P \mapsto F P (I + G P)^{-1} F^\top + Q` with
    :math:`G = H^\top R^{-1} H`. With :math:`A_0 = F^\top`, :math:`G_0 = G`, :math:`X_0 = Q`, each step

    .. math::

        W = I + G_k X_k, \quad
        A_{k+1} = A_k W^{-1} A_k, \quad
        G_{k+1} = G_k + A_k W^{-1} G_k A_k^\top, \quad
        X_{k+1} = X_k + A_k^\top X_k W^{-1} A_k

    gives in :math:`X_k` the recursion's covariance after :math:`2^k` steps (Chu, Fan & Lin, 2005), so a
    filter whose covariance settles only after 1e12 steps (Q 1e-24 of R, a random walk) is solved in about
    40. From 0 it reaches the minimal solution, which is the stabilising one when every unstable mode is
    reached by Q; the caller checks that it is (:func:`_stabilises`).
    """
    F, H, Q, R = model.F, model.H, model.Q, model.R
    if not is_positive_definite(R):
        return None
    whitened = whiten(cholesky(R, "R"), H)  # L⁻¹ H: G = Hᵀ R⁻¹ H without inverting R
    A, G, X = F.T.copy(), symmetrize(whitened.T @ whitened), Q.copy()
    eye = np.eye(F.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(most):
            W = eye + G @ X
            try:
                WA, WG = general_solve(W, A), general_solve(W, G)
            except np.linalg.LinAlgError:
                return None
            X_next = symmetrize(X + A.T @ X @ WA)
            G = symmetrize(G + A @ WG @ A.T)
            A = A @ WA
            if not (np.isfinite(X_next).all() and np.isfinite(A).all() and np.isfinite(G).all()):
                return None
            if np.array_equal(X_next, X) or (kalman.settled(X_next, X) and not np.abs(A).max() > 1e-8):
                return X_next
            X = X_next
    return None


def _iterated(model: LinearModel, steps: int = 10_000) -> np.ndarray | None:
    """The filter's own predicted covariance from a positive definite P⁻, run to its fixed point; None if it does
    not settle.

    Where SciPy's solver fails on a badly scaled problem (an unstable F with Q 1e-30 of R), the recursion
    still converges to the stabilising solution when there is one (from any P⁻ ⪰ 0, for a model whose
    unstable modes are seen and reached); without one it grows without bound, or does not settle within
    `steps` steps. It starts from ``Q + s I``, s the largest entry of Q and R, a prior that knows no
    component exactly: a filter that reaches a singular S from there has no steady gain, and the
    ValueError of :func:`_no_steady_gain` says so (F = 0.5 I with H = [0, 1], Q = diag(1, 0) and R = 0: the
    measured component's variance falls to 0, and S with it, whatever the prior). A prior of 0 could reach
    one only because it knows the state exactly at the start.
    """
    size = max(np.abs(model.Q).max(), np.abs(model.R).max())
    P = model.Q + (size if size > 0.0 else 1.0) * np.eye(model.Q.shape[0])
    for _ in range(steps):
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                new = _riccati_map(model, P)
        except np.linalg.LinAlgError:
            raise _no_steady_gain(model, P) from None
        except FloatingPointError:  # S overflows (R near the largest float64): the caller's message (review R44)
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
