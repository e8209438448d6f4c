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

__all__ = ["filter_50_digits", "smooth_50_digits", "smooth_dense_50_digits", "smallest_eigenvalue"]


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


def smooth_dense_50_digits(F, H, Q, R, m0, P0, zs) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed means (T, n) and covariances (T, n, n) by dense joint-Gaussian conditioning, in 50 digits.

    No recursion and no inverse of a state covariance, so a singular P⁻ (a state that copies another) is
    valid input: with the independent sources e = (x_0, w_1..w_T, v_1..v_T), x = M_x e + c_x and
    z = M_z e + c_z; then E[x | z] = c_x + Σ_xz Σ_zz⁻¹ (z - c_z), Cov[x | z] = Σ_xx - Σ_xz Σ_zz⁻¹ Σ_zx,
    where only Σ_zz (positive definite for R > 0) is inverted. Time-invariant models only.
    """
    zs = np.asarray(zs, float).reshape(len(zs), -1)
    F, H, Q, R, P0 = (np.atleast_2d(np.asarray(a, float)) for a in (F, H, Q, R, P0))
    T, n, m = len(zs), F.shape[0], H.shape[0]
    ne = n + T * n + T * m
    with mp.workdps(50):
        Fm, Hm = mp.matrix(F.tolist()), mp.matrix(H.tolist())
        cov_e = mp.zeros(ne, ne)
        for (block, start) in [(P0, 0)] + [(Q, n + k * n) for k in range(T)] + [(R, n + T * n + k * m)
                                                                                 for k in range(T)]:
            for i, j in np.ndindex(block.shape):
                cov_e[start + i, start + j] = block[i, j]
        MX, MZ = mp.zeros(T * n, ne), mp.zeros(T * m, ne)
        cX, cZ = mp.zeros(T * n, 1), mp.zeros(T * m, 1)
        M_prev, c_prev = mp.zeros(n, ne), mp.matrix(np.asarray(m0, float).tolist())
        for i in range(n):
            M_prev[i, i] = 1
        for k in range(T):
            M_k, c_k = Fm * M_prev, Fm * c_prev
            for i in range(n):
                M_k[i, n + k * n + i] += 1
            Z_k, d_k = Hm * M_k, Hm * c_k
            for i in range(m):
                Z_k[i, n + T * n + k * m + i] += 1
            for i in range(n):
                cX[k * n + i] = c_k[i]
                for j in range(ne):
                    MX[k * n + i, j] = M_k[i, j]
            for i in range(m):
                cZ[k * m + i] = d_k[i]
                for j in range(ne):
                    MZ[k * m + i, j] = Z_k[i, j]
            M_prev, c_prev = M_k, c_k
        S_xz = MX * cov_e * MZ.T
        gain = S_xz * mp.inverse(MZ * cov_e * MZ.T)
        mean = cX + gain * (mp.matrix(zs.ravel().tolist()) - cZ)
        cov = MX * cov_e * MX.T - gain * S_xz.T
        means = _to_float(mean).reshape(T, n)
        full = _to_float(cov)
    covs = np.array([full[k * n:(k + 1) * n, k * n:(k + 1) * n] for k in range(T)])
    return means, (covs + covs.transpose(0, 2, 1)) / 2


def smallest_eigenvalue(P: np.ndarray) -> float:
    """The smallest eigenvalue of the float64 matrix P (read exactly), computed with 50 digits.

    NumPy's own eigenvalues of an ill-conditioned covariance carry round-off
    of about ε‖P‖ and can be negative for a positive definite P; these
    cannot.
    """
    with mp.workdps(50):
        return float(min(mp.eigsy(mp.matrix(np.asarray(P, float).tolist()), eigvals_only=True)))
