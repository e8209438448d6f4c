r"""The Kalman equations: the one place they are written.

Every filter in gaussfuse is this affine Gaussian algebra, fed by a different
way of turning a model into an affine map around the current belief. With a
belief :math:`x \sim N(m, P)`:

* the dynamics are approximated as :math:`x' = A x + b + w`, :math:`w \sim N(0, Q)`;
* the measurement as :math:`z = H x + d + v`, :math:`v \sim N(0, R)`.

For a linear model :math:`A = F`, :math:`b = B u`, :math:`d = 0`; for the
extended and sigma-point filters the linearisation supplies them (and adds its
own error covariance to :math:`Q` and :math:`R`).

The functions here are pure: arrays in, arrays out. Covariances are kept
symmetric, the update uses the Joseph form, and every matrix "inverse" is a
Cholesky solve.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["predict", "update", "rts_step", "fuse_moments", "Update", "cholesky", "semidefinite_cholesky",
           "wrap_angle", "wrap_components"]

_LOG_2PI = np.log(2.0 * np.pi)


class Update(NamedTuple):
    """What one measurement update returns.

    Attributes
    ----------
    mean : array of shape (n,)
        Posterior mean.
    cov : array of shape (n, n)
        Posterior covariance.
    innovation : array of shape (m,)
        ``z - (H m + d)``; NaN in the components that were not observed.
    innovation_cov : array of shape (m, m)
        ``S = H P Hᵀ + R`` over all m components.
    loglik : float
        ``log N(z_o; H_o m + d_o, S_o)`` over the observed components ``o``
        (0.0 when nothing was observed).
    """

    mean: np.ndarray
    cov: np.ndarray
    innovation: np.ndarray
    innovation_cov: np.ndarray
    loglik: float


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles in radians to [-π, π)."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def wrap_components(diff: np.ndarray, angles: np.ndarray | None) -> np.ndarray:
    """`diff` with its angle components wrapped (a copy when any are)."""
    if angles is None or not angles.any():
        return diff
    diff = diff.copy()
    diff[angles] = wrap_angle(diff[angles])
    return diff


def symmetrize(cov: np.ndarray) -> np.ndarray:
    """Return ``(P + Pᵀ) / 2``, removing round-off asymmetry."""
    return 0.5 * (cov + cov.swapaxes(-1, -2))


def cho_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A⁻¹ b`` for ``A = L Lᵀ``: two solves with the Cholesky factor, no inverse.

    (NumPy's solver on the small triangular factors; SciPy's triangular
    solvers cost more in call overhead than they save at these sizes.)
    """
    return np.linalg.solve(L.T, np.linalg.solve(L, b))


def cholesky(mat: np.ndarray, name: str) -> np.ndarray:
    """Lower Cholesky factor of `mat`, or a ``LinAlgError`` naming the matrix.

    Raises
    ------
    numpy.linalg.LinAlgError
        When `mat` is not positive definite; the message names `name` and
        shows the matrix, so a driver can prefix the time step.
    """
    try:
        return np.linalg.cholesky(mat)
    except np.linalg.LinAlgError:
        with np.printoptions(precision=4, threshold=36):
            shown = np.array2string(np.asarray(mat), separator=", ").replace("\n", "")
        raise np.linalg.LinAlgError(
            f"{name} is not positive definite, so it cannot be factorised: {shown}"
        ) from None


def semidefinite_cholesky(cov: np.ndarray) -> np.ndarray:
    r"""Lower-triangular L with ``L Lᵀ = cov`` for a positive semi-definite `cov`.

    The Cholesky recursion, column by column, in which a pivot (the variance
    of component j left after conditioning on components 0..j-1) at most
    ``n ε cov[j, j]`` is zero: component j is, to round-off, an affine
    function of the earlier ones, and column j of L is zero. The test is
    relative to each component's own variance, so it does not depend on
    units.

    Where ``numpy.linalg.cholesky`` just succeeds or just fails (a pivot at
    round-off level, of either sign), the two factors differ only in that
    column, by about the square root of the round-off: sigma points drawn
    from either agree to second order. (A root from the eigendecomposition
    would turn every point.) For a positive definite `cov` it is the
    Cholesky factor.

    Raises
    ------
    numpy.linalg.LinAlgError
        When `cov` has an eigenvalue below ``-1e-9 λ_max``: it is not
        positive semi-definite.
    """
    vals = np.linalg.eigvalsh(cov)
    top = max(vals[-1], 0.0)
    if vals[0] < -1e-9 * max(top, 1e-300):
        raise np.linalg.LinAlgError(
            f"the covariance is not positive semi-definite (smallest eigenvalue {vals[0]:.3g}), "
            "so it has no square root"
        )
    n = cov.shape[0]
    tol = n * np.finfo(np.float64).eps
    L = np.zeros_like(cov, dtype=np.float64)
    for j in range(n):
        pivot = cov[j, j] - L[j, :j] @ L[j, :j]
        if pivot <= tol * cov[j, j]:
            continue
        L[j, j] = np.sqrt(pivot)
        L[j + 1:, j] = (cov[j + 1:, j] - L[j + 1:, :j] @ L[j, :j]) / L[j, j]
    return L


def predict(
    mean: np.ndarray,
    cov: np.ndarray,
    A: np.ndarray,
    Q: np.ndarray,
    b: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Propagate a Gaussian belief through affine dynamics.

    Parameters
    ----------
    mean : array of shape (n,)
        Current mean :math:`m`.
    cov : array of shape (n, n)
        Current covariance :math:`P`.
    A : array of shape (n, n)
        Transition matrix (``F`` for a linear model).
    Q : array of shape (n, n)
        Process-noise covariance (plus any linearisation error).
    b : array of shape (n,), optional
        Offset, ``B u`` for a control input.

    Returns
    -------
    mean : array of shape (n,)
    cov : array of shape (n, n)

    Notes
    -----
    .. math::

        m^- = A m + b, \qquad P^- = A P A^\top + Q.
    """
    m_pred = A @ mean
    if b is not None:
        m_pred = m_pred + b
    return m_pred, symmetrize(A @ cov @ A.T + Q)


def update(
    mean: np.ndarray,
    cov: np.ndarray,
    z: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    d: np.ndarray | None = None,
    angles: np.ndarray | None = None,
) -> Update:
    r"""Condition a Gaussian belief on a measurement (Joseph form).

    Parameters
    ----------
    mean : array of shape (n,)
        Predicted mean :math:`m^-`.
    cov : array of shape (n, n)
        Predicted covariance :math:`P^-`.
    z : array of shape (m,)
        Measurement; NaN components are missing.
    H : array of shape (m, n)
        Measurement matrix.
    R : array of shape (m, m)
        Measurement-noise covariance (plus any linearisation error).
    d : array of shape (m,), optional
        Measurement offset.
    angles : array of bool, shape (m,), optional
        Components that are angles: their innovation is wrapped to [-π, π).

    Returns
    -------
    Update
        Posterior mean and covariance, innovation, innovation covariance and
        the log-likelihood contribution of the observed components.

    Notes
    -----
    With ``o`` the observed components,

    .. math::

        v &= z_o - (H_o m^- + d_o), \qquad S = H_o P^- H_o^\top + R_{oo}, \\
        K &= P^- H_o^\top S^{-1}, \qquad m = m^- + K v, \\
        P &= (I - K H_o) P^- (I - K H_o)^\top + K R_{oo} K^\top, \\
        \ell &= -\tfrac12 \left(v^\top S^{-1} v + \log\det S + |o| \log 2\pi\right).

    :math:`S^{-1}` is never formed: with :math:`S = L L^\top`,
    :math:`K^\top = S^{-1} H_o P^-` is a Cholesky solve. The Joseph form is
    the covariance of the estimator for *any* gain, so it stays symmetric
    positive semi-definite under round-off. It is the gain that minimises
    :math:`\operatorname{tr} P` that gives :math:`K` above; the update is the
    product of the predicted Gaussian and the measurement likelihood.

    All-missing ``z`` returns the prediction unchanged with ``loglik = 0``.
    """
    pred_z = H @ mean
    if d is not None:
        pred_z = pred_z + d
    innovation = wrap_components(z - pred_z, angles)
    S_full = symmetrize(H @ cov @ H.T + R)
    observed = ~np.isnan(z)
    if not observed.any():
        return Update(mean, cov, innovation, S_full, 0.0)
    if observed.all():
        H_o, R_o, v, S = H, R, innovation, S_full
    else:
        H_o, R_o, v = H[observed], R[np.ix_(observed, observed)], innovation[observed]
        S = S_full[np.ix_(observed, observed)]
    L = cholesky(S, "the innovation covariance S = H P Hᵀ + R")
    K = cho_solve(L, H_o @ cov).T
    I_KH = np.eye(mean.shape[0]) - K @ H_o
    post_cov = symmetrize(I_KH @ cov @ I_KH.T + K @ R_o @ K.T)
    white = np.linalg.solve(L, v)
    loglik = -0.5 * (white @ white + 2.0 * np.sum(np.log(np.diag(L))) + v.shape[0] * _LOG_2PI)
    return Update(mean + K @ v, post_cov, innovation, S_full, float(loglik))


def rts_step(
    filt_mean: np.ndarray,
    filt_cov: np.ndarray,
    pred_mean: np.ndarray,
    pred_cov: np.ndarray,
    next_mean: np.ndarray,
    next_cov: np.ndarray,
    cross_cov: np.ndarray,
    angles: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""One backward step of the Rauch–Tung–Striebel smoother.

    Parameters
    ----------
    filt_mean, filt_cov : arrays of shape (n,), (n, n)
        Filtered belief at step k, :math:`(m_k, P_k)`.
    pred_mean, pred_cov : arrays of shape (n,), (n, n)
        Prediction for step k+1 from step k, :math:`(m^-_{k+1}, P^-_{k+1})`.
    next_mean, next_cov : arrays of shape (n,), (n, n)
        Smoothed belief at step k+1, :math:`(m^s_{k+1}, P^s_{k+1})`.
    cross_cov : array of shape (n, n)
        :math:`C_{k+1} = \operatorname{Cov}(x_k, x_{k+1} \mid z_{1:k})`;
        :math:`P_k A^\top` for affine dynamics.
    angles : array of bool, shape (n,), optional
        State components that are angles: ``m^s_{k+1} - m^-_{k+1}`` is wrapped.

    Returns
    -------
    mean : array of shape (n,)
    cov : array of shape (n, n)
    gain : array of shape (n, n)
        The smoother gain :math:`G_k`.

    Notes
    -----
    .. math::

        G_k &= C_{k+1} (P^-_{k+1})^{-1}, \\
        m^s_k &= m_k + G_k (m^s_{k+1} - m^-_{k+1}), \\
        P^s_k &= P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top.

    The gain is a Cholesky solve with :math:`P^-_{k+1}`; when that is
    singular (no process noise on a degenerate belief) it is the
    minimum-norm least-squares solution, which is still the exact
    conditional.
    """
    try:
        L = np.linalg.cholesky(pred_cov)
        gain = cho_solve(L, cross_cov.T).T
    except np.linalg.LinAlgError:
        gain = np.linalg.lstsq(pred_cov, cross_cov.T, rcond=None)[0].T
    mean = filt_mean + gain @ wrap_components(next_mean - pred_mean, angles)
    cov = symmetrize(filt_cov + gain @ (next_cov - pred_cov) @ gain.T)
    return mean, cov, gain


def fuse_moments(
    mean_a: np.ndarray, cov_a: np.ndarray, mean_b: np.ndarray, cov_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    r"""Moments of the (normalised) product of two Gaussians on one variable.

    Notes
    -----
    The product :math:`N(x; a, A)\, N(x; b, B)` is proportional to a Gaussian;
    it is the Kalman update of :math:`N(a, A)` by a direct measurement
    :math:`z = b` with :math:`H = I`, :math:`R = B`:

    .. math::

        K = A (A + B)^{-1}, \quad \mu = a + K (b - a), \quad
        \Sigma = (I - K) A (I - K)^\top + K B K^\top .

    In one dimension :math:`\mu = \mu_1 + \sigma_1^2 (\mu_2 - \mu_1) / (\sigma_1^2 + \sigma_2^2)`
    and :math:`\sigma^2 = \sigma_1^2 - \sigma_1^4 / (\sigma_1^2 + \sigma_2^2)`.
    """
    post = update(mean_a, cov_a, mean_b, np.eye(mean_a.shape[0]), cov_b)
    return post.mean, post.cov
