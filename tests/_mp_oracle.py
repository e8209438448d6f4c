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
from scipy.linalg import block_diag

__all__ = ["filter_50_digits", "smooth_50_digits", "smooth_dense_50_digits", "smallest_eigenvalue"]


def _to_float(a) -> np.ndarray:
    return np.array(a.tolist(), dtype=float)


def _forward(F, H, Q, R, m0, P0, zs):
    """The 50-digit filter's predictions and posteriors, as mpmath matrices (call inside ``mp.workdps(50)``).

    predict m⁻ = F m, P⁻ = F P Fᵀ + Q; update with K = P⁻ Hᵀ (H P⁻ Hᵀ + R)⁻¹,
    m = m⁻ + K (z - H m⁻), P = P⁻ - K H P⁻ (in 50 digits every form agrees).
    R may be a stack (T, m, m), one per step. Returns the transition F and the lists of (m⁻, P⁻) and (m, P).
    """
    zs = np.asarray(zs, float).reshape(len(zs), -1)
    Rs = [mp.matrix(np.atleast_2d(a).tolist()) for a in (R if np.ndim(R) == 3 else [R] * len(zs))]
    F, H, Q = (mp.matrix(np.atleast_2d(a).tolist()) for a in (F, H, Q))
    m = mp.matrix(np.asarray(m0, float).tolist())
    P = mp.matrix(np.asarray(P0, float).tolist())
    pred, filt = [], []
    for z, R in zip(zs, Rs):
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


def smooth_50_digits(F, H, Q, R, m0, P0, zs, digits: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed means (T, n) and covariances (T, n, n): the 50-digit filter, then the RTS backward pass.

    G_k = P_k Fᵀ (P⁻_{k+1})⁻¹, m^s_k = m_k + G_k (m^s_{k+1} - m⁻_{k+1}),
    P^s_k = P_k + G_k (P^s_{k+1} - P⁻_{k+1}) G_kᵀ, all in 50 `digits`. Without process noise P⁻ can be
    nearly singular: with P0 = 1e12 I and R = 1e-12 a constant velocity's is of condition 4e24 from the second
    step, and the backward pass then cancels terms of 1e12 down to 1e-14, so 50 digits leave about 5 (a
    variance 1.4e-5 off); 80 leave 35.
    """
    with mp.workdps(digits):
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


def smooth_dense_50_digits(F, H, Q, R, m0, P0, zs, digits: int = 50, lag_one: bool = False) -> tuple:
    """Smoothed means (T, n) and covariances (T, n, n) by dense joint-Gaussian conditioning, in 50 digits.

    No recursion and no inverse of a state covariance, so a singular P⁻ (a state that copies another) is
    valid input: with the independent sources e = (x_0, w_1..w_T, v_1..v_T), x = M_x e + c_x and
    z = M_z e + c_z; then E[x | z] = c_x + Σ_xz Σ_zz⁻¹ (z - c_z), Cov[x | z] = Σ_xx - Σ_xz Σ_zz⁻¹ Σ_zx,
    where only Σ_zz (positive definite for R > 0) is inverted. Time-invariant models only. With `lag_one`, also
    the lag-one covariances Cov(x_k, x_{k+1} | z), (T - 1, n, n).
    """
    zs = np.asarray(zs, float).reshape(len(zs), -1)
    T, n, m = len(zs), np.shape(F)[0], np.atleast_2d(H).shape[0]
    ne = n + T * n + T * m
    with mp.workdps(digits):
        F, H, Q, R, P0 = (np.vectorize(mp.mpf, otypes=[object])(np.atleast_2d(np.asarray(a, float)))
                          for a in (F, H, Q, R, P0))
        cov_e = block_diag(P0, *[Q] * T, *[R] * T)
        MX, MZ = np.zeros((T, n, ne), object), np.zeros((T, m, ne), object)
        cX, cZ = np.zeros((T, n), object), np.zeros((T, m), object)
        M, c = np.eye(n, ne).astype(object), np.asarray(m0, float).astype(object)
        for k in range(T):
            M, c = F @ M, F @ c
            M[:, n + k * n:n + (k + 1) * n] += np.eye(n)
            MX[k], cX[k] = M, c
            MZ[k], cZ[k] = H @ M, H @ c
            MZ[k][:, n + T * n + k * m:n + T * n + (k + 1) * m] += np.eye(m)
        # the products in mpmath's matrices, which multiply faster than NumPy's object arrays
        MX, MZ, cov_e = (mp.matrix(a.tolist()) for a in (MX.reshape(T * n, ne), MZ.reshape(T * m, ne), cov_e))
        S_xz = MX * cov_e * MZ.T
        gain = S_xz * mp.inverse(MZ * cov_e * MZ.T)
        means = _to_float(mp.matrix(cX.ravel().tolist()) + gain * mp.matrix((zs.ravel() - cZ.ravel()).tolist()))
        means, full = means.reshape(T, n), _to_float(MX * cov_e * MX.T - gain * S_xz.T)
    covs = np.array([full[k * n:(k + 1) * n, k * n:(k + 1) * n] for k in range(T)])
    if lag_one:
        return means, (covs + covs.transpose(0, 2, 1)) / 2, np.array(
            [full[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] for k in range(T - 1)])
    return means, (covs + covs.transpose(0, 2, 1)) / 2


def smallest_eigenvalue(P: np.ndarray) -> float:
    """The smallest eigenvalue of the float64 matrix P (read exactly), computed with 50 digits.

    NumPy's own eigenvalues of an ill-conditioned covariance carry round-off
    of about ε‖P‖ and can be negative for a positive definite P; these
    cannot.
    """
    with mp.workdps(50):
        return float(min(mp.eigsy(mp.matrix(np.asarray(P, float).tolist()), eigvals_only=True)))
