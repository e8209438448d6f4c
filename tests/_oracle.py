"""A dense joint-Gaussian reference for the linear-Gaussian state-space model.

Written independently of gaussfuse: only numpy and scipy. Nothing here runs a
Kalman recursion. For

    x_k = F_k x_{k-1} + B_k u_k + w_k,   w_k ~ N(0, Q_k),
    z_k = H_k x_k + v_k,                 v_k ~ N(0, R_k),     k = 1..T,

with x_0 ~ N(m0, P0) one step *before* the first measurement, every x_k and
z_k is an affine function of the independent Gaussians

    e = (x_0, w_1, ..., w_T, v_1, ..., v_T),

so y = (x_1..x_T, z_1..z_T) = M e + c is jointly Gaussian with mean
M E[e] + c and covariance M Cov(e) Mᵀ. Every filtered, predicted and smoothed
belief is that joint Gaussian conditioned on a set of observed measurement
components, by the textbook formula

    E[a | o] = μ_a + Σ_ao Σ_oo⁻¹ (y_o - μ_o),  Cov[a | o] = Σ_aa - Σ_ao Σ_oo⁻¹ Σ_oa,

with Σ_oo⁻¹ applied as a dense symmetric-positive-definite solve.

Arrays with a leading time axis are time-varying; index k - 1 of such an
array is used at step k (0-based index k into the results).

The second half of the module draws random well-conditioned models for the
property-based tests.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.linalg import LinAlgWarning, block_diag, solve
from scipy.stats import multivariate_normal

__all__ = ["JointGaussian", "reference", "random_spd", "random_transition", "random_problem"]


def _at(a: np.ndarray | None, k: int) -> np.ndarray | None:
    """Entry of a possibly time-varying matrix at 0-based step k."""
    if a is None:
        return None
    return a[k] if a.ndim == 3 else a


class JointGaussian:
    """The joint Gaussian of (x_1..x_T, z_1..z_T) of a linear-Gaussian model."""

    def __init__(self, F, H, Q, R, m0, P0, T, B=None, us=None):
        F, H, Q, R = (np.asarray(a, dtype=float) for a in (F, H, Q, R))
        m0, P0 = np.asarray(m0, dtype=float), np.asarray(P0, dtype=float)
        B = None if B is None else np.asarray(B, dtype=float)
        us = None if us is None else np.asarray(us, dtype=float)
        n, m = m0.shape[0], H.shape[-2]
        self.n, self.m, self.T = n, m, T

        # Independent sources e = (x_0, w_1..w_T, v_1..v_T).
        ne = n + T * n + T * m
        mu_e = np.zeros(ne)
        mu_e[:n] = m0
        cov_e = block_diag(P0, *[_at(Q, k) for k in range(T)], *[_at(R, k) for k in range(T)])

        def w_cols(k):
            return slice(n + k * n, n + (k + 1) * n)

        def v_cols(k):
            return slice(n + T * n + k * m, n + T * n + (k + 1) * m)

        # x_k = Mx[k] e + cx[k], z_k = Mz[k] e + cz[k].
        Mx, cx = np.zeros((T, n, ne)), np.zeros((T, n))
        Mz, cz = np.zeros((T, m, ne)), np.zeros((T, m))
        M_prev = np.zeros((n, ne))
        M_prev[:, :n] = np.eye(n)
        c_prev = np.zeros(n)
        for k in range(T):
            Fk, Hk = _at(F, k), _at(H, k)
            Mk = Fk @ M_prev
            Mk[:, w_cols(k)] += np.eye(n)
            ck = Fk @ c_prev
            if B is not None:
                ck = ck + _at(B, k) @ us[k]
            Mx[k], cx[k] = Mk, ck
            Mz[k] = Hk @ Mk
            Mz[k][:, v_cols(k)] += np.eye(m)
            cz[k] = Hk @ ck
            M_prev, c_prev = Mk, ck

        M = np.vstack([Mx.reshape(T * n, ne), Mz.reshape(T * m, ne)])
        c = np.concatenate([cx.ravel(), cz.ravel()])
        self.mean = M @ mu_e + c
        self.cov = M @ cov_e @ M.T

    # -- index helpers ------------------------------------------------------

    def x_index(self, k: int) -> np.ndarray:
        """Positions of x_{k+1} (0-based k) in y."""
        return np.arange(k * self.n, (k + 1) * self.n)

    def z_index(self, k: int) -> np.ndarray:
        """Positions of z_{k+1} (0-based k) in y."""
        start = self.T * self.n + k * self.m
        return np.arange(start, start + self.m)

    def observed(self, zs: np.ndarray, upto: int) -> tuple[np.ndarray, np.ndarray]:
        """Positions in y and values of the non-NaN components of zs[:upto]."""
        idx, vals = [], []
        for k in range(upto):
            keep = ~np.isnan(zs[k])
            idx.append(self.z_index(k)[keep])
            vals.append(zs[k][keep])
        if not idx:
            return np.zeros(0, dtype=int), np.zeros(0)
        return np.concatenate(idx), np.concatenate(vals)

    # -- conditioning -------------------------------------------------------

    def condition(self, zs: np.ndarray, upto: int) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance of all of y given the observed zs[:upto]."""
        o, vals = self.observed(zs, upto)
        if o.size == 0:
            return self.mean.copy(), self.cov.copy()
        C_oo = self.cov[np.ix_(o, o)]
        C_ao = self.cov[:, o]
        # Σ_oo⁻¹ Σ_oa as a dense SPD solve.
        gain_t = solve(C_oo, C_ao.T, assume_a="pos")
        mean = self.mean + gain_t.T @ (vals - self.mean[o])
        cov = self.cov - C_ao @ gain_t
        return mean, 0.5 * (cov + cov.T)

    def loglik(self, zs: np.ndarray) -> float:
        """log N(z_obs; mean_obs, cov_obs) over every observed component."""
        o, vals = self.observed(zs, self.T)
        if o.size == 0:
            return 0.0
        return float(multivariate_normal(self.mean[o], self.cov[np.ix_(o, o)]).logpdf(vals))


def reference(F, H, Q, R, m0, P0, zs, B=None, us=None) -> dict[str, np.ndarray | float]:
    """Every quantity a filter and an RTS smoother report, from the joint Gaussian.

    Parameters are those of the model, the prior (m0, P0), measurements zs of
    shape (T, m) with NaN for missing components, and controls us (T, p).

    Returns a dict with ``means, covs`` (filtered), ``predicted_means,
    predicted_covs``, ``innovations, innovation_covs``, ``smoothed_means,
    smoothed_covs``, ``gains`` (T - 1, n, n) and ``loglik``.
    """
    zs = np.asarray(zs, dtype=float)
    T, m = zs.shape
    J = JointGaussian(F, H, Q, R, m0, P0, T, B=B, us=us)
    n = J.n
    out = {
        "means": np.empty((T, n)),
        "covs": np.empty((T, n, n)),
        "predicted_means": np.empty((T, n)),
        "predicted_covs": np.empty((T, n, n)),
        "innovations": np.empty((T, m)),
        "innovation_covs": np.empty((T, m, m)),
        "smoothed_means": np.empty((T, n)),
        "smoothed_covs": np.empty((T, n, n)),
        "gains": np.empty((max(T - 1, 0), n, n)),
    }
    # conditioned[j] = the joint given z_1..z_j (j = 0..T).
    conditioned = [J.condition(zs, j) for j in range(T + 1)]
    for k in range(T):
        xi, zi = J.x_index(k), J.z_index(k)
        mean_f, cov_f = conditioned[k + 1]
        out["means"][k] = mean_f[xi]
        out["covs"][k] = cov_f[np.ix_(xi, xi)]
        mean_p, cov_p = conditioned[k]
        out["predicted_means"][k] = mean_p[xi]
        out["predicted_covs"][k] = cov_p[np.ix_(xi, xi)]
        out["innovations"][k] = zs[k] - mean_p[zi]
        out["innovation_covs"][k] = cov_p[np.ix_(zi, zi)]
        mean_s, cov_s = conditioned[T]
        out["smoothed_means"][k] = mean_s[xi]
        out["smoothed_covs"][k] = cov_s[np.ix_(xi, xi)]
        if k < T - 1:
            # G_k = Cov(x_k, x_{k+1} | z_1..z_k) Cov(x_{k+1} | z_1..z_k)⁻¹.
            xn = J.x_index(k + 1)
            cross = cov_f[np.ix_(xi, xn)]
            pred_next = cov_f[np.ix_(xn, xn)]
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("error", LinAlgWarning)
                    out["gains"][k] = solve(pred_next, cross.T, assume_a="pos").T
            except (np.linalg.LinAlgError, LinAlgWarning):  # a singular prediction: no unique gain, the least-norm one
                out["gains"][k] = (np.linalg.pinv(pred_next, hermitian=True) @ cross.T).T
    out["loglik"] = J.loglik(zs)
    return out


# ---------------------------------------------------------------------------
# Random well-conditioned models
# ---------------------------------------------------------------------------


def random_spd(rng: np.random.Generator, n: int, low: float = 0.1, high: float = 10.0) -> np.ndarray:
    """A Aᵀ + c I with its eigenvalues in [low, high]."""
    A = rng.normal(size=(n, n))
    S = A @ A.T
    top = np.linalg.eigvalsh(S)[-1]
    S *= rng.uniform(0.1, 1.0) * (high - low) / top
    S = S + low * np.eye(n)
    return 0.5 * (S + S.T)


def random_transition(rng: np.random.Generator, n: int, radius: float = 1.2) -> np.ndarray:
    """A random n x n matrix with spectral radius in [0.3, radius]."""
    F = rng.normal(size=(n, n))
    rho = np.max(np.abs(np.linalg.eigvals(F)))
    return F * rng.uniform(0.3, radius) / rho


def random_problem(
    rng: np.random.Generator,
    n: int,
    m: int,
    T: int,
    p: int = 0,
    varying: frozenset[str] | set[str] = frozenset(),
    mask: np.ndarray | None = None,
) -> dict:
    """A random model, prior, controls and measurements drawn from the model.

    `varying` names the matrices among F, H, Q, R, B given a time axis of
    length T; `p = 0` means no control input. `mask` (T, m) of booleans marks
    the *missing* measurement components (set to NaN).
    """

    def draw(name, make):
        if name in varying:
            return np.stack([make() for _ in range(T)])
        return make()

    F = draw("F", lambda: random_transition(rng, n))
    H = draw("H", lambda: rng.normal(size=(m, n)))
    Q = draw("Q", lambda: random_spd(rng, n))
    R = draw("R", lambda: random_spd(rng, m))
    B = draw("B", lambda: rng.normal(size=(n, p))) if p else None
    us = rng.normal(size=(T, p)) if p else None
    m0 = rng.normal(size=n)
    P0 = random_spd(rng, n)

    # Simulate the model so the measurements are plausible.
    x = rng.multivariate_normal(m0, P0)
    zs = np.empty((T, m))
    for k in range(T):
        x = _at(F, k) @ x + rng.multivariate_normal(np.zeros(n), _at(Q, k))
        if B is not None:
            x = x + _at(B, k) @ us[k]
        zs[k] = _at(H, k) @ x + rng.multivariate_normal(np.zeros(m), _at(R, k))
    if mask is not None:
        zs[np.asarray(mask, dtype=bool)] = np.nan
    return {"F": F, "H": H, "Q": Q, "R": R, "B": B, "us": us, "m0": m0, "P0": P0, "zs": zs}
