"""A 50-digit reference Kalman filter, written with mpmath only (nothing of gaussfuse).

For problems where float64 round-off matters (huge prior variances, very
precise sensors), the filter computed with 50 significant digits is exact to
far more digits than float64 holds, so it is the reference the float64
results are measured against. The inputs are float64 arrays, read exactly;
the outputs are rounded to float64 once, at the end of each step.
"""

from __future__ import annotations

import mpmath as mp
import numpy as np

__all__ = ["filter_50_digits", "smooth_50_digits", "smallest_eigenvalue"]


def _to_float(a) -> np.ndarray:
    return np.array(a.tolist(), dtype=float)


def _forward(F, H, Q, R, m0, P0, zs):
    """The 50-digit filter's predictions and posteriors, as mpmath matrices (call inside ``mp.workdps(50)``).

    predict m⁻ = F m, P⁻ = F P Fᵀ + Q; update with K = P⁻ Hᵀ (H P⁻ Hᵀ + R)⁻¹,
    m = m⁻ + K (z - H m⁻), P = P⁻ - K H P⁻ (in 50 digits every form agrees).
    Returns the transition F and the lists of (m⁻, P⁻) and (m, P).
    """
    F, H, Q, R = (mp.matrix(np.atleast_2d(a).tolist()) for a in (F, H, Q, R))
    m = mp.matrix(np.asarray(m0, float).tolist())
    P = mp.matrix(np.asarray(P0, float).tolist())
    pred, filt = [], []
    for z in np.asarray(zs, float).reshape(len(zs), -1):
        pm, pP = F * m, F * P * F.T + Q
        K = pP * H.T * mp.inverse(H * pP * H.T + R)
        m = pm + K * (mp.matrix(z.tolist()) - H * pm)
        P = pP - K * H * pP
        P = (P + P.T) / 2
        pred.append((pm, pP))
        filt.append((m, P))
    return F, pred, filt


def filter_50_digits(F, H, Q, R, m0, P0, zs, digits: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """Filtered means (T, n) and covariances (T, n, n) of a time-invariant linear model, prior one step before z_1.

    x_k = F x_{k-1} + w_k, w_k ~ N(0, Q); z_k = H x_k + v_k, v_k ~ N(0, R) (see :func:`_forward`). A
    prior variance of 1e300 against R = 1 needs more than 600 `digits`: 50 lose R altogether.
    """
    with mp.workdps(digits):
        filt = _forward(F, H, Q, R, m0, P0, zs)[2]
        return (np.array([_to_float(m).ravel() for m, _ in filt]), np.array([_to_float(P) for _, P in filt]))


def smooth_50_digits(F, H, Q, R, m0, P0, zs) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed means (T, n) and covariances (T, n, n): the 50-digit filter, then the RTS backward pass.

    G_k = P_k Fᵀ (P⁻_{k+1})⁻¹, m^s_k = m_k + G_k (m^s_{k+1} - m⁻_{k+1}),
    P^s_k = P_k + G_k (P^s_{k+1} - P⁻_{k+1}) G_kᵀ, all in 50 digits.
    """
    with mp.workdps(50):
        F, pred, filt = _forward(F, H, Q, R, m0, P0, zs)
        sm_m, sm_P = filt[-1]
        means, covs = [_to_float(sm_m).ravel()], [_to_float(sm_P)]
        for k in range(len(filt) - 2, -1, -1):
            m, P = filt[k]
            pm, pP = pred[k + 1]
            G = P * F.T * mp.inverse(pP)
            sm_m = m + G * (sm_m - pm)
            sm_P = P + G * (sm_P - pP) * G.T
            sm_P = (sm_P + sm_P.T) / 2
            means.append(_to_float(sm_m).ravel())
            covs.append(_to_float(sm_P))
    return np.array(means[::-1]), np.array(covs[::-1])


def smallest_eigenvalue(P: np.ndarray) -> float:
    """The smallest eigenvalue of the float64 matrix P (read exactly), computed with 50 digits.

    NumPy's own eigenvalues of an ill-conditioned covariance carry round-off
    of about ε‖P‖ and can be negative for a positive definite P; these
    cannot.
    """
    with mp.workdps(50):
        return float(min(mp.eigsy(mp.matrix(np.asarray(P, float).tolist()), eigvals_only=True)))
