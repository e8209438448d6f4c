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
symmetric (a variance that is zero to the round-off of the terms it was
computed from, but below 0, is 0 with its row and column:
:func:`gaussfuse._linalg.clip_variances`), the update uses the Joseph form,
and every matrix "inverse" is a Cholesky solve.

They are the filters' inner loop, and take their arguments as the front
functions (:func:`gaussfuse.filter`, :class:`gaussfuse.Gaussian`,
:class:`gaussfuse.LinearModel`) have checked them: float arrays of matching
shapes, covariances symmetric positive semi-definite and finite. They do
not check them again: a vector R, a scalar Q, a non-symmetric P or an
infinite z give numbers that mean nothing, or NumPy's errors. Build the
arrays with those classes (``Gaussian(m, P)``, ``LinearModel(F, H, Q, R)``
and their attributes) when calling these directly.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._linalg import (PSD_RTOL, abs_congruence_diagonal, back_substitute, cho_solve, cholesky, clip_variances,
                      correlation_root, downdate, eye, factor_solve, in_pivot_order, log_det, log_density, near,
                      pivot_order, psd_solve, semidefinite_cholesky, sqrt_cov, symmetrize, tria, unseen_directions,
                      shown, whiten, with_slopes, wrap_components, zero_pivots, indefinite_error)
from .errors import ModelFunctionError, not_finite

__all__ = ["predict", "predict_mean", "update", "gain", "apply_gain", "observed_components", "rts_step",
           "fuse_moments", "SqrtUpdate", "cov_factor", "predict_sqrt", "update_sqrt", "rts_step_sqrt", "joint_factor", "singular_pivots", "backward_conditional", "SqrtGain",
           "sqrt_gain", "Factors", "transition_factors", "measurement_factors", "forecast_sqrt", "correct_sqrt", "step_sqrt", "Update", "Gain",
           "Step", "Gate", "SteadyState", "SETTLED", "STEADY_TOL", "settled", "step", "forecast", "correct", "check_finite",
           "iterate_changed"]

_S_NAME = "the innovation covariance S = H P Hᵀ + R"
_S_WHY = ("(S is singular to round-off where a component measured without noise, R = 0 or below the round-off of "
          "H P Hᵀ, meets a state already known exactly, or another such component measuring the same: give R a "
          "variance above round-off.)")
_S_NEGATIVE = ("(S is indefinite: it has a negative variance, or an eigenvalue below round-off on its components' "
               "scales, which positive semi-definite P and R cannot give.)")


def _innovation_error(message: str, S: np.ndarray) -> np.linalg.LinAlgError:
    """The LinAlgError `message` for an innovation covariance `S` with no Cholesky factor, with why: singular to
    round-off, or indefinite (``.indefinite``, which a negative sigma-point weight can cause)."""
    return indefinite_error(message, S, _S_WHY, _S_NEGATIVE)


class Update(NamedTuple):
    r"""What one measurement update returns.

    Parameters
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
    gain : ndarray of shape (n, k), or None
        The gain applied, over the k observed components ``o`` (None when
        nothing was observed).
    nis : float
        The normalised innovation squared :math:`v^\top S_{oo}^{-1} v`, χ² with
        k degrees of freedom for a consistent filter (NaN when nothing was
        observed).
    rejected : ndarray of bool, shape (m,), or None
        With a :class:`Gate`: the components it rejected (treated as
        missing). None without a gate.
    """

    mean: np.ndarray
    cov: np.ndarray
    innovation: np.ndarray
    innovation_cov: np.ndarray
    loglik: float
    gain: np.ndarray | None = None
    nis: float = np.nan
    rejected: np.ndarray | None = None


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
    return predict_mean(mean, A, b), clip_variances(
        symmetrize(A @ cov @ A.T + Q), lambda: abs_congruence_diagonal(A, cov) + np.abs(np.diagonal(Q)))


def predict_mean(mean: np.ndarray, A: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
    """The mean half of :func:`predict`: ``A m + b``.

    Parameters
    ----------
    mean : array of shape (n,)
        Mean :math:`m`.
    A : array of shape (r, n)
        Linear map: the transition matrix (r = n), or H for the predicted
        measurement.
    b : array of shape (r,), optional
        Offset; none is added when None.

    Returns
    -------
    array of shape (r,)
        ``A m + b``.
    """
    return A @ mean if b is None else A @ mean + b


def update(
    mean: np.ndarray,
    cov: np.ndarray,
    z: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
    d: np.ndarray | None = None,
    angles: np.ndarray | None = None,
    gain: np.ndarray | None = None,
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
    gain : array of shape (n, m), optional
        A gain to apply instead of the optimal one (its columns for missing
        components are not used): the result is the mean and the exact
        covariance of that (suboptimal) estimator.

    Returns
    -------
    Update
        Posterior mean and covariance, innovation, innovation covariance and
        the log-likelihood contribution of the observed components. With
        nothing observed the posterior is the prediction: its mean and
        covariance are `mean` and `cov` themselves, not copies.

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
    the covariance of the estimator for *any* gain: symmetric by
    construction, and insensitive to first order to round-off in the gain.
    Measured against a 50-digit filter (``tests/test_kalman.py``), it is about
    100 times closer than the symmetrised ``P - K H P`` when the prior
    variance is 10⁸ times the sensor's (1.5e-10 relative), but it is not proof
    against round-off: with a prior of 10¹² and a sensor variance of 10⁻⁶,
    the first update is accurate but its variances drift from the second on,
    to 74% off by the 40th step, the covariance indefinite (use
    :func:`update_sqrt` there). The update is the product of the predicted
    Gaussian and the measurement likelihood.

    For any gain :math:`K` the estimator :math:`m^- + K v` has the error
    :math:`(I - K H_o)(x - m^-) - K v_{noise}`, whose covariance is the
    Joseph form above; expanding it around the optimal gain :math:`K^*`,

    .. math::

        \operatorname{tr} P(K^* + \Delta) = \operatorname{tr} P(K^*)
        + \operatorname{tr}(\Delta S \Delta^\top),

    so :math:`K^* = P^- H_o^\top S^{-1}` minimises the trace (the mean
    squared error), and any other gain (`gain`) adds :math:`\Delta S \Delta^\top`.

    All-missing ``z`` returns the prediction unchanged with ``loglik = 0``.
    """
    g = _covariance_half(cov, H, R, observed_components(z), gain)
    post_mean, innovation, loglik, nis = apply_gain(g, mean, z, H, d, angles)
    return Update(post_mean, g.cov, innovation, g.innovation_cov, loglik, g.K, nis)


class Gain(NamedTuple):
    """The half of an update that does not depend on the measured values.

    It depends on the predicted covariance, H, R and which components are
    observed; :func:`apply_gain` applies it to a prediction and a measurement.

    Parameters
    ----------
    K : ndarray of shape (n, m_o), or None
        The gain, over the observed components (None when none is).
    cov : ndarray of shape (n, n)
        The posterior covariance.
    innovation_cov : ndarray of shape (m, m)
        ``S = H P Hᵀ + R`` over all m components.
    factor : ndarray of shape (m_o, m_o), or None
        The Cholesky factor of the observed block of S.
    logdet : float
        Its log-determinant, ``log det S_oo``.
    observed : ndarray of bool, shape (m,), or None
        The observed components; None when all are.
    """

    K: np.ndarray | None
    cov: np.ndarray
    innovation_cov: np.ndarray
    factor: np.ndarray | None
    logdet: float
    observed: np.ndarray | None


def observed_components(z: np.ndarray) -> np.ndarray | None:
    """The components of `z` that are not NaN: None when all are (the common case), else a mask.

    Parameters
    ----------
    z : array of shape (m,)
        Measurement; NaN components are missing.

    Returns
    -------
    ndarray of bool, shape (m,), or None
        True where `z` is not NaN; None when no component is NaN and there
        is one (an empty `z` observes nothing: its mask is empty).
    """
    total = z.sum()
    return None if total == total and z.shape[0] else ~np.isnan(z)


def gain(cov: np.ndarray, H: np.ndarray, R: np.ndarray, observed: np.ndarray | None = None,
         K: np.ndarray | None = None) -> Gain:
    """The covariance half of :func:`update` (see its Notes), over the `observed` components (all if None).

    With `K` (n, m), that gain's columns for the observed components are
    applied instead of the optimal gain; the Joseph form is the covariance of
    the estimator it gives.

    Parameters
    ----------
    cov : array of shape (n, n)
        Predicted covariance :math:`P^-`.
    H : array of shape (m, n)
        Measurement matrix.
    R : array of shape (m, m)
        Measurement-noise covariance.
    observed : array of bool, shape (m,), optional
        The observed components (:func:`observed_components`); None: all.
    K : array of shape (n, m), optional
        A gain to apply instead of the optimal one.

    Returns
    -------
    Gain
        The gain, the posterior covariance and the innovation covariance;
        with nothing observed, no gain and `cov` unchanged.

    Raises
    ------
    numpy.linalg.LinAlgError
        When S (of the observed components) is not positive definite.
    FloatingPointError
        When it holds inf or NaN: the step overflowed.
    """
    HP = H @ cov
    S_full = symmetrize(HP @ H.T + R)
    if observed is None:
        H_o, R_o, S, HP_o = H, R, S_full, HP
    elif not observed.any():
        return Gain(None, cov, S_full, None, 0.0, observed)
    else:
        H_o, R_o, HP_o = H[observed], R[np.ix_(observed, observed)], HP[observed]
        S = S_full[np.ix_(observed, observed)]
    try:
        L = cholesky(S, _S_NAME, resolved=True)
    except np.linalg.LinAlgError as exc:
        if not np.isfinite(S).all():  # an overflow upstream, not a covariance that is indefinite
            raise FloatingPointError(not_finite("filtered")) from None
        raise _innovation_error(str(exc), S) from None
    if K is None:
        K = cho_solve(L, HP_o).T                  # Kᵀ = S⁻¹ H_o P⁻
    elif observed is not None:
        K = K[:, observed]
    I_KH = eye(cov.shape[0]) - K @ H_o
    post_cov = clip_variances(symmetrize(I_KH @ cov @ I_KH.T + K @ R_o @ K.T),
                              lambda: abs_congruence_diagonal(I_KH, cov) + abs_congruence_diagonal(K, R_o))
    return Gain(K, post_cov, S_full, L, log_det(L), observed)


_covariance_half = gain  # `update` has a parameter named `gain`


def _innovation(mean, z, H, d, angles, observed) -> tuple[np.ndarray, np.ndarray]:
    """``z - (H m + d)``, wrapped for angles, and its observed components."""
    innovation = z - predict_mean(mean, H, d)
    if angles is not None:
        innovation = wrap_components(innovation, angles)
    return innovation, innovation if observed is None else innovation[observed]


def apply_gain(g: Gain | SqrtGain, mean: np.ndarray, z: np.ndarray, H: np.ndarray, d: np.ndarray | None = None,
               angles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float, float]:
    r"""The mean half of :func:`update` and :func:`update_sqrt`: the posterior mean, the innovation, the
    log-likelihood term and the NIS.

    With a :class:`SqrtGain` the mean is :math:`m^- + \bar K (L_S^{-1} v)`, from the
    factors; with a :class:`Gain`, :math:`m^- + K v`.

    Parameters
    ----------
    g : Gain or SqrtGain
        The covariance half (:func:`gain` or :func:`sqrt_gain`), computed
        for the components `z` observes.
    mean : array of shape (n,)
        Predicted mean :math:`m^-`.
    z : array of shape (m,)
        Measurement; NaN components are missing.
    H : array of shape (m, n)
        Measurement matrix.
    d : array of shape (m,), optional
        Measurement offset.
    angles : array of bool, shape (m,), optional
        Components that are angles: their innovation is wrapped to [-π, π).

    Returns
    -------
    mean : array of shape (n,)
        Posterior mean (`mean` itself when nothing was observed).
    innovation : array of shape (m,)
        ``z - (H m + d)``; NaN in the missing components.
    loglik : float
        Log-likelihood term of the observed components (0.0 when none is).
    nis : float
        Normalised innovation squared (NaN when nothing was observed).
    """
    sqrt = isinstance(g, SqrtGain)
    innovation, v = _innovation(mean, z, H, d, angles, g.observed)
    L = g.factor_S if sqrt else g.factor
    if L is None:
        return mean, innovation, 0.0, np.nan
    white = whiten(L, v)
    step = g.Kbar @ white if sqrt else g.K @ v
    return mean + step, innovation, float(log_density(white, L, None if sqrt else g.logdet)), float(white @ white)


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
    `pred_mean`, `next_mean` and `next_cov` may be stacks, (N, n) and
    (N, n, n), of beliefs that share the prediction's covariance and the
    cross-covariance, as the series of a batch do at the prior's time; the
    mean and covariance are then stacks too, and the gain is shared.

    .. math::

        G_k &= C_{k+1} (P^-_{k+1})^{-1}, \\
        m^s_k &= m_k + G_k (m^s_{k+1} - m^-_{k+1}), \\
        P^s_k &= P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top.

    The gain is a Cholesky solve with :math:`P^-_{k+1}`; when that is
    singular (no process noise on a degenerate belief) it is a
    least-squares solution, on :math:`P^-_{k+1}` scaled to unit diagonal
    so that states on small scales are kept (:func:`gaussfuse._linalg.psd_solve`),
    which is still the exact conditional. A singular :math:`P^-_{k+1}` fixes
    the gain only on its range (:math:`G_k P^-_{k+1} = C_{k+1}`), which is all
    the mean and covariance use; off it, the gain depends on whether a pivot
    of round-off is taken for zero.
    """
    gain = psd_solve(pred_cov, cross_cov.T).T
    diff = wrap_components(next_mean - pred_mean, angles)
    mean = filt_mean + (gain @ diff if diff.ndim == 1 else diff @ gain.T)
    cov = clip_variances(symmetrize(filt_cov + gain @ (next_cov - pred_cov) @ gain.T), lambda: np.abs(
        np.diagonal(filt_cov)) + abs_congruence_diagonal(gain, np.abs(next_cov) + np.abs(pred_cov)))
    return mean, cov, gain


def fuse_moments(
    mean_a: np.ndarray, cov_a: np.ndarray, mean_b: np.ndarray, cov_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    r"""Moments of the (normalised) product of two Gaussians on one variable.

    Parameters
    ----------
    mean_a, cov_a : arrays of shape (n,), (n, n)
        The first Gaussian, :math:`N(a, A)`.
    mean_b, cov_b : arrays of shape (n,), (n, n)
        The second, :math:`N(b, B)`.

    Returns
    -------
    mean : array of shape (n,)
        :math:`\mu`.
    cov : array of shape (n, n)
        :math:`\Sigma`, exactly symmetric, and positive semi-definite to
        round-off (the rounding of :math:`L L^\top`: an eigenvalue of about
        :math:`-\epsilon \lVert\Sigma\rVert` where Σ is singular).

    Raises
    ------
    numpy.linalg.LinAlgError
        When :math:`A + B` is singular: both are certain in a common direction.

    Notes
    -----
    The product :math:`N(x; a, A)\, N(x; b, B)` is proportional to a Gaussian;
    it is the Kalman update of :math:`N(a, A)` by a direct measurement
    :math:`z = b` with :math:`H = I`, :math:`R = B`:

    .. math::

        K = A (A + B)^{-1}, \quad \mu = a + K (b - a), \quad
        \Sigma = (I - K) A (I - K)^\top + K B K^\top .

    It is computed in the square-root form (:func:`update_sqrt`, from
    factors :math:`L_A`, :math:`L_B`), whose triangularisation never forms
    :math:`A + B`: moments from it lost the digits that :math:`A + B`
    rounds away (15% of the result for a belief certain in one direction
    next to one 1e17 times wider, and :math:`A + B` overflows for
    variances of 1e308). The narrower belief (by trace) is taken as a, so
    that K is small and b's digits are kept (from the wider one a precise
    -14.66 fused with a vague mean of 1.5e19 came out 0.0, exact -14.66);
    ties are broken by their bytes, so ``fuse(a, b)`` and ``fuse(b, a)``
    are the same numbers.

    In one dimension :math:`\mu = (\sigma_2^2 \mu_1 + \sigma_1^2 \mu_2) / (\sigma_1^2 + \sigma_2^2)`
    and :math:`\sigma^2 = \sigma_1^2 \sigma_2^2 / (\sigma_1^2 + \sigma_2^2)`, to round-off.
    """
    # The narrower belief first (by trace; by bytes on a tie): μ = a + K (b - a) with K = A (A + B)⁻¹ small.
    # From the wider one, μ is a - K' a + K' b with K' near 1, and b is lost to the rounding of a (a
    # precise 14.66 fused with a vague mean of 1.5e19 came out 0.0).
    if (np.trace(cov_b), cov_b.tobytes(), mean_b.tobytes()) < (np.trace(cov_a), cov_a.tobytes(), mean_a.tobytes()):
        mean_a, cov_a, mean_b, cov_b = mean_b, cov_b, mean_a, cov_a
    g = sqrt_gain(cov_factor(cov_a, "a.cov"), eye(mean_a.shape[0]), cov_factor(cov_b, "b.cov"))
    # a + K (b - a), not a + K̄ L_S⁻¹ (b - a): the whitened difference overflows for means 1e308 standard
    # deviations apart, and b - a itself for means near ±1e308 of opposite signs, where μ need not
    with np.errstate(over="ignore", invalid="ignore"):
        d = mean_b - mean_a
    if np.isfinite(d).all():
        mean = mean_a + g.K @ d
    else:  # halved and doubled: exact (bar subnormal means, which cannot be this far apart)
        mean = 2.0 * (0.5 * mean_a + g.K @ (0.5 * mean_b - 0.5 * mean_a))
    return mean, symmetrize(g.factor @ g.factor.T)


# ---------------------------------------------------------------------------
# Gating: measurements too far from the prediction are treated as missing
# ---------------------------------------------------------------------------


def _check_gate(probability, by, names: tuple[str, str]) -> None:
    """Refuse a gate's probability or kind, naming them `names` (the constructor's, or the front functions' `gate`
    and `gate_by`: audit OO4)."""
    if isinstance(probability, bool) or not isinstance(probability, (int, float, np.integer, np.floating)):
        raise TypeError(f"`{names[0]}` must be a probability in (0, 1), such as 0.99; got "
                        f"{type(probability).__name__} {probability!r}.")
    if not 0.0 < probability < 1.0:
        raise ValueError(f"`{names[0]}` must be a probability in (0, 1), such as 0.99; got {probability!r}.")
    if not isinstance(by, str) or by not in ("measurement", "component"):  # a choice: a ValueError, as `method`'s
        raise ValueError(f"`{names[1]}` must be 'measurement' or 'component'; got {by!r}.")


class Gate:
    r"""A validation gate on the innovations, at a chi-square probability.

    Parameters
    ----------
    probability : float
        In (0, 1): a measurement from the model itself passes with this
        probability against a consistent prediction (0.99 rejects 1% of good
        measurements there). In a filter each rejection leaves the next
        predictions less certain than they claim, so more follow, in runs:
        over 10,000-step series drawn from the model itself, 0.99 rejected
        1.3-1.4% (a local level, q/r = 100, up to 8 in a row), 2.0% (the
        README's 2-D constant velocity) and 5.7% (constant velocity, q = 10;
        24% in one series, with 1,878 good measurements rejected in a row).
        The divergence check names the steps where it rejected at least half
        (:func:`gaussfuse.diagnostics.rejections`).
    by : {"measurement", "component"}, default "measurement"
        Reject the whole measurement when its normalised innovation squared
        :math:`v_o^\top S_{oo}^{-1} v_o` exceeds the `probability` quantile of
        :math:`\chi^2_{|o|}`; or each component i whose
        :math:`v_i^2 / S_{ii}` exceeds that of :math:`\chi^2_1` (the others
        are kept).

    Notes
    -----
    A rejected component is treated as missing: the update conditions on
    the others only, and its log-likelihood term is not counted. The
    quantiles come from :func:`scipy.special.chdtri`, once per number of
    degrees of freedom.
    """

    __slots__ = ("probability", "by", "_quantiles")

    def __init__(self, probability: float, by: str = "measurement") -> None:
        _check_gate(probability, by, ("probability", "by"))
        self.probability, self.by = float(probability), by
        self._quantiles: dict[int, float] = {}

    def __repr__(self) -> str:
        return f"Gate({self.probability!r}, by={self.by!r})"

    def quantile(self, dof: int) -> float:
        """The `probability` quantile of χ² with `dof` degrees of freedom.

        Parameters
        ----------
        dof : int
            Degrees of freedom, >= 1.

        Returns
        -------
        float
            The quantile, computed once per `dof`.
        """
        if dof not in self._quantiles:
            from scipy.special import chdtri  # SciPy only once a gate is used

            self._quantiles[dof] = float(chdtri(dof, 1.0 - self.probability))
        return self._quantiles[dof]

    @classmethod
    def of(cls, probability: float | None, by: str = "measurement") -> Gate | None:
        """The gate of a `gate=`/`gate_by=` pair of arguments, or None without `probability` (`by` checked even then).

        Parameters
        ----------
        probability : float or None
            The `gate=` argument, in (0, 1); None for no gate.
        by : {"measurement", "component"}, default "measurement"
            The `gate_by=` argument.

        Returns
        -------
        Gate or None
            The gate; None when `probability` is None.
        """
        _check_gate(0.5 if probability is None else probability, by, ("gate", "gate_by"))  # the front's names
        return None if probability is None else cls(probability, by)

    def __call__(self, z: np.ndarray, predicted: np.ndarray, S: np.ndarray,
                 angles: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`z` with the rejected components set to NaN, and the mask of those rejected.

        `predicted` is the predicted measurement ``H m + d`` and `S` its
        covariance, over all m components (:func:`predict` through the
        measurement map); the innovation is wrapped for `angles`.
        """
        innovation = wrap_components(z - predicted, angles)
        observed = ~np.isnan(z)
        rejected = np.zeros(z.shape[0], dtype=bool)
        if not observed.any():
            return z, rejected
        if self.by == "component":
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                d2 = np.where(innovation == 0.0, 0.0, innovation**2 / np.diagonal(S))  # 0 of 0: it agrees
            rejected = observed & ~(d2 <= self.quantile(1))  # a zero variance and a nonzero innovation: out
        else:
            v = innovation[observed]
            L = cholesky(S[np.ix_(observed, observed)], _S_NAME, resolved=True)
            white = whiten(L, v)
            if not white @ white <= self.quantile(int(observed.sum())):
                rejected = observed
        if rejected.any():
            z = np.where(rejected, np.nan, z)
        return z, rejected


# ---------------------------------------------------------------------------
# The square-root form: the same algebra on Cholesky factors
# ---------------------------------------------------------------------------


class SqrtUpdate(NamedTuple):
    r"""What one square-root update returns: :class:`Update` with the posterior's factor.

    Parameters
    ----------
    mean : ndarray of shape (n,)
        Posterior mean.
    factor : ndarray of shape (n, n)
        Lower triangular, :math:`P = L L^\top`.
    innovation : ndarray of shape (m,)
        As :class:`Update`'s.
    innovation_cov : ndarray of shape (m, m)
        As :class:`Update`'s.
    loglik : float
        As :class:`Update`'s.
    gain : ndarray of shape (n, k), or None
        :math:`K = \bar K L_S^{-1}` over the k observed components.
    nis : float
        :math:`e^\top e`, the normalised innovation squared (NaN when nothing was observed).
    rejected : ndarray of bool, shape (m,), or None
        As :class:`Update`'s.
    """

    mean: np.ndarray
    factor: np.ndarray
    innovation: np.ndarray
    innovation_cov: np.ndarray
    loglik: float
    gain: np.ndarray | None = None
    nis: float = np.nan
    rejected: np.ndarray | None = None


def cov_factor(cov: np.ndarray, name: str = "the covariance") -> np.ndarray:
    r"""A lower-triangular square root of a positive semi-definite covariance (Cholesky, or its semi-definite form).

    Parameters
    ----------
    cov : array of shape (n, n)
        Symmetric positive semi-definite covariance.
    name : str, default "the covariance"
        What `cov` is, for the error message.

    Returns
    -------
    ndarray of shape (n, n)
        Lower triangular L with ``L Lᵀ = cov``: each entry to round-off of
        its components' scales :math:`\sqrt{c_{ii} c_{jj}}` where the
        (semi-definite) Cholesky factor gives that; else the closer of it and
        :func:`gaussfuse._linalg.correlation_root`, to
        :data:`gaussfuse._linalg.PSD_RTOL` on those scales, as a Gaussian or
        a model accepts a covariance (a rank-2 Q accepted by ``LinearModel``
        was refused here, in one case in 80). A variance below 0 by no more
        than the round-off of the largest entry, with a row as small, is
        taken as 0 first, as a Gaussian or a model takes it
        (``diag(1e12, 1, -1e-3)`` was accepted there and refused here).

    Raises
    ------
    numpy.linalg.LinAlgError
        When `cov` is not finite, not symmetric, or not positive
        semi-definite on the scale of its own components (a variance of 1
        in an indefinite block beside one of 1e12 was altered to 4, and an
        infinite variance taken for a zero one); the message names it.
    """
    cov = np.asarray(cov, dtype=np.float64)
    if not np.isfinite(cov).all():
        raise np.linalg.LinAlgError(f"{name} is not finite (inf or NaN): a factor needs finite variances.")
    # A variance below 0 within round-off of the largest entry t, whose covariances are within round-off of t and
    # the other component's variance, is 0, as check_psd accepts it: clip_variances' bound 16 n ε √(t_i t_j) on
    # halves of t (that row) and of |c_ii| (the others) is check_psd's 8 n ε √(t |c_ii|)
    # A variance of exactly 0 is taken so too, with covariances of round-off (-2.8e-17, as an exact measurement
    # leaves them: audit VV1), which a Gaussian accepts and the factor's check then divided by 0.
    diag = np.diagonal(cov)
    cov = clip_variances(cov, lambda: 0.5 * np.where(diag <= 0.0, np.max(np.abs(cov)), np.abs(diag)), zero=True)
    try:
        L = sqrt_cov(cov)[0]
        failure = f"{name} is not symmetric positive semi-definite on the scale of its components: no factor L " \
                  "with L Lᵀ equal to it."
    except np.linalg.LinAlgError as exc:
        L, failure = None, f"{name} {exc.args[0].removeprefix('the covariance ')}"
    # L Lᵀ must give back cov, each entry to round-off of its components' scales: else cov was not
    # symmetric, or not PSD there
    residual = np.inf if L is None else _residual(L, cov)
    if residual <= 16 * cov.shape[0] * np.finfo(float).eps:
        return L
    root = correlation_root(cov)
    residual, L = min((residual, L), (_residual(root, cov), root), key=lambda pair: pair[0])
    if residual <= PSD_RTOL:  # PSD to what a Gaussian or a model accepts
        return L
    raise np.linalg.LinAlgError(failure)


def _residual(L: np.ndarray, cov: np.ndarray) -> float:
    """The largest ``|L Lᵀ - cov|`` on each entry's components' scale, ``√(c_ii c_jj)`` (inf off a zero one)."""
    d = np.sqrt(np.abs(np.diagonal(cov)))
    scale = np.outer(d, d)
    error = np.abs(L @ L.T - cov)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.max(np.where(error > 0.0, error / scale, 0.0), initial=0.0))


def predict_sqrt(mean: np.ndarray, factor: np.ndarray, A: np.ndarray, Q_factor: np.ndarray,
                 b: np.ndarray | None = None, Q_minus: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    r""":func:`predict` on factors: the prediction's mean and the Cholesky factor of its covariance.

    Parameters
    ----------
    mean : array of shape (n,)
    factor : array of shape (n, n)
        :math:`L` with :math:`P = L L^\top`.
    A : array of shape (n, n)
    Q_factor : array of shape (n, q)
        :math:`L_Q` with :math:`Q = L_Q L_Q^\top` (:func:`cov_factor`).
    b : array of shape (n,), optional
    Q_minus : array of shape (n, r), optional
        :math:`D_Q`, when the noise is :math:`L_Q L_Q^\top - D_Q D_Q^\top`
        (a sigma-point regression with negative weights,
        :func:`gaussfuse.linearize.slr_sqrt`).

    Returns
    -------
    mean : array of shape (n,)
    factor : array of shape (n, n)
        Lower triangular, :math:`L^-`.

    Notes
    -----
    .. math::

        m^- = A m + b, \qquad
        L^- = \operatorname{tria}\left[\, A L \;\; L_Q \,\right],

    since :math:`[A L \;\, L_Q][A L \;\, L_Q]^\top = A P A^\top + Q`;
    ``tria`` (:func:`gaussfuse._linalg.tria`) triangularises by an
    orthogonal transformation, so :math:`P^-` is never formed. With
    :math:`D_Q`, :math:`L^-` is then downdated by its columns
    (:func:`gaussfuse._linalg.downdate`, hyperbolic rotations).
    """
    pL = tria(np.concatenate([A @ factor, Q_factor], axis=1))
    if Q_minus is not None:
        pL = downdate(pL, Q_minus, "the predicted covariance")
    return predict_mean(mean, A, b), pL


def update_sqrt(mean: np.ndarray, factor: np.ndarray, z: np.ndarray, H: np.ndarray, R_factor: np.ndarray,
                d: np.ndarray | None = None, angles: np.ndarray | None = None,
                R_minus: np.ndarray | None = None) -> SqrtUpdate:
    r""":func:`update` on factors: the array (QR) form of the measurement update.

    Parameters
    ----------
    mean : array of shape (n,)
        Predicted mean :math:`m^-`.
    factor : array of shape (n, n)
        :math:`L^-` with :math:`P^- = L^- L^{-\top}`.
    z : array of shape (m,)
        Measurement; NaN components are missing.
    H : array of shape (m, n)
    R_factor : array of shape (m, r)
        :math:`L_R` with :math:`R = L_R L_R^\top`.
    d : array of shape (m,), optional
    angles : array of bool, shape (m,), optional
        Components that are angles: their innovation is wrapped to [-π, π).
    R_minus : array of shape (m, r'), optional
        :math:`D_R`, when the noise is :math:`L_R L_R^\top - D_R D_R^\top`
        (see :func:`predict_sqrt`).

    Returns
    -------
    SqrtUpdate
        The posterior mean and factor, as :func:`update`'s; with nothing
        observed they are `mean` and `factor` themselves, not copies.

    Raises
    ------
    numpy.linalg.LinAlgError
        When the innovation covariance of the observed components is
        singular.

    Notes
    -----
    With ``o`` the observed components, triangularise the pre-array
    (:math:`L_{R,o}` a factor of :math:`R_{oo}`, ``tria`` of the observed
    rows of :math:`L_R`):

    .. math::

        \operatorname{tria}\begin{bmatrix} L_{R,o} & H_o L^- \\ 0 & L^- \end{bmatrix}
        = \begin{bmatrix} L_S & 0 \\ \bar K & L \end{bmatrix} .

    Multiplying each side by its transpose shows
    :math:`L_S L_S^\top = H_o P^- H_o^\top + R_{oo} = S`,
    :math:`\bar K = P^- H_o^\top L_S^{-\top}` (so :math:`K = \bar K L_S^{-1}`)
    and :math:`L L^\top = P^- - \bar K \bar K^\top = P^- - K S K^\top`, the
    posterior. Then, with the whitened innovation :math:`e = L_S^{-1} v`,

    .. math::

        m = m^- + \bar K e, \qquad
        \ell = -\tfrac12 \left(e^\top e + 2 \textstyle\sum_i \log (L_S)_{ii} + |o| \log 2\pi\right).

    Only orthogonal transformations and one triangular solve touch the
    factors, so the result is as accurate as the factors' own condition
    (the square root of the covariances'), and :math:`L L^\top` is positive
    semi-definite and symmetric by construction. Where :math:`L_S` shows
    the measurements out of the order of column pivoting
    (:func:`gaussfuse._linalg.in_pivot_order`), the array is triangularised
    again with them in that order, and :math:`[L_S; \bar K]` turned back to
    theirs by one more orthogonal transformation: Householder QR is row-wise
    stable with its columns sorted and pivoted, not sorted alone.

    With :math:`D_R`, the triangularised post-array, a factor of the joint
    covariance of the measurement and the state, is downdated by the
    columns :math:`[D_{R,o};\, 0]` (:func:`gaussfuse._linalg.downdate`)
    before its blocks are read.
    """
    g = sqrt_gain(factor, H, R_factor, observed_components(z), R_minus)
    post_mean, innovation, loglik, nis = apply_gain(g, mean, z, H, d, angles)
    return SqrtUpdate(post_mean, g.factor, innovation, g.innovation_cov, loglik, g.K, nis)


class SqrtGain(NamedTuple):
    r"""The half of :func:`update_sqrt` that does not depend on the measured values (as :class:`Gain`).

    Parameters
    ----------
    Kbar : ndarray of shape (n, m_o), or None
        :math:`\bar K = P^- H_o^\top L_S^{-\top}` (None when nothing is observed).
    factor_S : ndarray of shape (m_o, m_o), or None
        :math:`L_S`.
    factor : ndarray of shape (n, n)
        The posterior factor L.
    innovation_cov : ndarray of shape (m, m)
        ``S = H P Hᵀ + R`` over all m components.
    observed : ndarray of bool, shape (m,), or None
        The observed components; None when all are.
    K : ndarray of shape (n, m_o), or None
        :math:`\bar K L_S^{-1}`.
    """

    Kbar: np.ndarray | None
    factor_S: np.ndarray | None
    factor: np.ndarray
    innovation_cov: np.ndarray
    observed: np.ndarray | None
    K: np.ndarray | None


def sqrt_gain(factor: np.ndarray, H: np.ndarray, R_factor: np.ndarray, observed: np.ndarray | None = None,
              R_minus: np.ndarray | None = None) -> SqrtGain:
    r"""The factor half of :func:`update_sqrt` (see its Notes), over the `observed` components (all if None).

    Parameters
    ----------
    factor : array of shape (n, n)
        :math:`L^-`, the factor of the predicted covariance.
    H : array of shape (m, n)
        Measurement matrix.
    R_factor : array of shape (m, r)
        :math:`L_R` with :math:`R = L_R L_R^\top`.
    observed : array of bool, shape (m,), optional
        The observed components (:func:`observed_components`); None: all.
    R_minus : array of shape (m, r'), optional
        :math:`D_R`, when the noise is :math:`L_R L_R^\top - D_R D_R^\top`.

    Returns
    -------
    SqrtGain
        The gain and the posterior factor; with nothing observed, no gain
        and `factor` unchanged.

    Raises
    ------
    numpy.linalg.LinAlgError
        When the innovation covariance of the observed components is not
        positive definite.
    """
    HL = H @ factor
    noise = R_factor @ R_factor.T if R_minus is None else R_factor @ R_factor.T - R_minus @ R_minus.T
    innovation_cov = symmetrize(HL @ HL.T + noise)
    D_o = R_minus
    if observed is None:
        HL_o, LR_o = HL, (R_factor if R_factor.shape[1] <= R_factor.shape[0] else tria(R_factor))
    elif not observed.any():
        return SqrtGain(None, None, factor, innovation_cov, observed, None)
    else:
        HL_o, LR_o = HL[observed], tria(R_factor[observed])
        D_o = None if R_minus is None else R_minus[observed]
    mo, n = HL_o.shape[0], factor.shape[0]
    pre = np.zeros((mo + n, mo + n))
    pre[:mo, :LR_o.shape[1]] = LR_o
    pre[:mo, mo:] = HL_o
    pre[mo:, mo:] = factor
    post = tria(pre)
    moved = not in_pivot_order(post[:mo, :mo])
    if moved:  # the measurements in the order of column pivoting (see pivot_order), and again
        order = pivot_order(pre[:mo])
        pre[:mo] = pre[order]
        D_o = None if D_o is None else D_o[order]
        post = tria(pre)
    if D_o is not None:
        rows = np.arange(H.shape[0]) if observed is None else np.flatnonzero(observed)  # (review R30: named by row)
        post = downdate(post, np.concatenate([D_o, np.zeros((n, D_o.shape[1]))]),
                        (("the innovation covariance", rows[order] if moved else rows), ("the filtered covariance", n)))
    L_S, Kbar = post[:mo, :mo], post[mo:, :mo]
    if not np.all(np.diagonal(L_S) > 0.0) or zero_pivots(L_S).any() and (
            D_o is not None or _dependent(R_factor if observed is None else R_factor[observed], HL_o, factor)):
        S = innovation_cov if observed is None else innovation_cov[np.ix_(observed, observed)]
        raise _innovation_error(f"{_S_NAME} is not positive definite: {shown(S)}", S)
    if moved:  # back to the measurements' order: [L_S; K̄] turned by one orthogonal Θ, so L_S L_Sᵀ and K̄ L_Sᵀ stay
        back = tria(np.concatenate([L_S[np.argsort(order)], Kbar]))
        L_S, Kbar = back[:mo, :mo], back[mo:, :mo]
    return SqrtGain(Kbar, L_S, np.ascontiguousarray(post[mo:, mo:]), innovation_cov, observed,
                    back_substitute(L_S, Kbar.T).T)  # K = K̄ L_S⁻¹


def _dependent(R_factor: np.ndarray, HL: np.ndarray, factor: np.ndarray) -> bool:
    r"""Whether :math:`S = [L_R\; HL][L_R\; HL]^\top` is singular to the round-off of :func:`sqrt_gain`'s array.

    A pivot of :math:`L_S` at round-off of its row (:func:`gaussfuse._linalg.zero_pivots`)
    is either a copy of an earlier measurement (two components with the
    same noise: S is singular and the pivot is noise) or a real one: a
    measurement whose own noise is tiny beside a prior spread it shares
    with an earlier one (a prior 1e15 times R gives a pivot 1e-15 of its
    row, all of it information). The pivot's size cannot tell them apart;
    its array can. :func:`gaussfuse._linalg.tria` sorts the columns, and
    Householder triangularisation is then exact for the array with each
    column changed by about ε of its norm (Cox and Higham's row-wise
    stability). So the rows of :math:`B = [L_{R,o}\; H_o L^-]` are asked
    whether they are dependent with each column of B scaled by the norm of
    that column of the whole array :math:`[[L_{R,o}, H_o L^-], [0, L^-]]`
    and each row then to unit norm: dependent when the smallest singular
    value is at most :math:`8 c \epsilon` for c columns. The rows of
    `R_factor` are used as given, not triangularised, which would leave a
    round-off column of its own.
    """
    top = np.concatenate([R_factor, HL], axis=1)
    scale = np.concatenate([np.linalg.norm(R_factor, axis=0), np.hypot(np.linalg.norm(HL, axis=0),
                                                                        np.linalg.norm(factor, axis=0))])
    used = scale > 0.0
    B = top[:, used] / scale[used]
    rows = np.linalg.norm(B, axis=1)
    if B.shape[1] < B.shape[0] or not rows.all():
        return True
    return bool(np.linalg.svd(B / rows[:, None], compute_uv=False)[-1] <= 8 * top.shape[1] * np.finfo(float).eps)


def rts_step_sqrt(filt_mean: np.ndarray, filt_factor: np.ndarray, next_mean: np.ndarray, next_factor: np.ndarray,
                  A: np.ndarray, Q_factor: np.ndarray, b: np.ndarray | None = None,
                  angles: np.ndarray | None = None,
                  Q_minus: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r""":func:`rts_step` on factors, for affine dynamics ``x_{k+1} = A x_k + b + w``, ``w ~ N(0, L_Q L_Qᵀ)``.

    Parameters
    ----------
    filt_mean, filt_factor : arrays of shape (n,), (n, n)
        Filtered belief at step k, :math:`(m_k, L_k)`.
    next_mean, next_factor : arrays of shape (n,), (n, n)
        Smoothed belief at step k+1, :math:`(m^s_{k+1}, L^s_{k+1})`.
    A, Q_factor : arrays of shape (n, n), (n, q)
        The transition out of step k.
    b : array of shape (n,), optional
    angles : array of bool, shape (n,), optional
        State components that are angles: ``m^s_{k+1} - m^-_{k+1}`` is wrapped.
    Q_minus : array of shape (n, r), optional
        :math:`D_Q`, when the noise is :math:`L_Q L_Q^\top - D_Q D_Q^\top`:
        the joint factor is downdated by :math:`[D_Q;\, 0]`.

    Returns
    -------
    mean : array of shape (n,)
    factor : array of shape (n, n)
        Lower triangular, :math:`L^s_k`.
    gain : array of shape (n, n)
        :math:`G_k`.

    Notes
    -----
    The prediction and the gain come from one triangularisation of the
    joint factor of :math:`(x_{k+1}, x_k)`:

    .. math::

        \operatorname{tria}\begin{bmatrix} L_Q & A L_k \\ 0 & L_k \end{bmatrix}
        = \begin{bmatrix} L^-_{k+1} & 0 \\ Y & X \end{bmatrix},

    so that :math:`L^- L^{-\top} = P^-_{k+1}`, :math:`Y L^{-\top} = P_k A^\top`
    (the gain is :math:`G_k = Y (L^-)^{-1}`) and
    :math:`X X^\top = P_k - G_k P^-_{k+1} G_k^\top`, the covariance of
    :math:`x_k` given :math:`x_{k+1}`. Then

    .. math::

        m^s_k = m_k + Y (L^-)^{-1} (m^s_{k+1} - m^-_{k+1}), \qquad
        L^s_k = \operatorname{tria}\left[\, X \;\; Y (L^-)^{-1} L^s_{k+1} \,\right],

    :math:`P^s_k = P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top` as a sum of
    squares. Nothing is subtracted: where :math:`P^-` is nearly singular
    (no process noise, a huge prior) :math:`I - G_k A` would be the
    difference of nearly equal matrices. The solves with :math:`L^-` are
    triangular; where it is singular (a pivot zero to round-off that can
    be zero, :func:`singular_pivots`), least-squares (the vectors it is
    applied to lie in its range), and the columns :math:`Y_0` of Y at its
    zero pivots join X: they are spread of :math:`x_k` that
    :math:`x_{k+1}` does not see, :math:`P_k - G_k P^- G_k^\top = X X^\top
    + Y_0 Y_0^\top` (a state that copies another, for example).

    With negative terms in the noise (a sigma-point regression's negative
    centre weight), the joint covariance is positive semi-definite only
    where :math:`L_Q L_Q^\top - D_Q D_Q^\top` is, which the prediction does
    not need. Where the downdate of the joint factor finds it indefinite,
    the prediction's factor is downdated alone, :math:`Y = P_k A^\top
    (L^-)^{-\top}`, and :math:`L^s_k` is :math:`\operatorname{tria}[L_k,\;
    G_k L^s_{k+1}]` downdated by the columns of Y at non-zero pivots:
    :math:`P^s_k = P_k + G_k (P^s_{k+1} - P^-_{k+1}) G_k^\top`, the
    covariance form's step, which raises only where that is not positive
    semi-definite.
    """
    n = filt_mean.shape[0]
    try:
        pred_mean, pred_factor, Y, X = joint_factor(filt_mean, filt_factor, A, Q_factor, b, Q_minus)
    except np.linalg.LinAlgError:
        if Q_minus is None:
            raise
        pred_mean, pred_factor, Y, X = _prediction_factor(filt_mean, filt_factor, A, Q_factor, b, Q_minus)
    zero = singular_pivots(pred_factor, filt_factor, A, Q_minus)
    rhs = np.concatenate([wrap_components(next_mean - pred_mean, angles)[:, None], next_factor, eye(n)], axis=1)
    steps = Y @ factor_solve(pred_factor, rhs, zero)  # Y (L⁻)⁻¹ [m^s - m⁻, L^s, I]
    mean = filt_mean + steps[:, 0]
    if X is None:  # P_k - G P⁻ Gᵀ = L_k L_kᵀ - Y_1 Y_1ᵀ, Y_1 the columns of Y at the non-zero pivots of L⁻
        factor = downdate(tria(np.concatenate([filt_factor, steps[:, 1:n + 1]], axis=1)), Y[:, ~zero],
                          "the smoothed covariance")
        return mean, factor, steps[:, n + 1:]
    # Y's columns at zero pivots of L⁻ are spread of x_k that x_{k+1} does not see: P_k - G P⁻ Gᵀ = X Xᵀ + Y_0 Y_0ᵀ
    factor = tria(np.concatenate([X, Y[:, zero], steps[:, 1:n + 1]], axis=1))
    return mean, factor, steps[:, n + 1:]


def _prediction_factor(filt_mean, filt_factor, A, Q_factor, b, Q_minus):
    """:func:`joint_factor`'s prediction and Y, with X None, where the joint covariance is indefinite (see rts_step_sqrt)."""
    pred_factor = downdate(tria(np.concatenate([A @ filt_factor, Q_factor], axis=1)), Q_minus,
                           "the predicted covariance")
    zero = singular_pivots(pred_factor, filt_factor, A, Q_minus)
    Y = factor_solve(pred_factor, (A @ filt_factor) @ filt_factor.T, zero).T  # Y (L⁻)ᵀ = P_k Aᵀ
    return predict_mean(filt_mean, A, b), pred_factor, Y, None


def singular_pivots(pred_factor: np.ndarray, filt_factor: np.ndarray, A: np.ndarray,
                    Q_minus: np.ndarray | None = None) -> np.ndarray:
    r"""The pivots of the prediction's factor :math:`L^-` that are zero: where the prediction is singular.

    Parameters
    ----------
    pred_factor, filt_factor : arrays of shape (n, n)
        :math:`L^-_{k+1}` and :math:`L_k`.
    A : array of shape (n, n)
        The transition between them.
    Q_minus : array of shape (n, r), optional
        The negative terms of the noise (see :func:`rts_step_sqrt`).

    Returns
    -------
    array of bool, shape (n,)

    Notes
    -----
    A pivot of :math:`L^-` smaller than the round-off of its row
    (:func:`gaussfuse._linalg.zero_pivots`) is zero, unless the prediction
    cannot be singular: :math:`P^- \succeq A P_k A^\top`, which is
    non-singular when :math:`A` and :math:`L_k` both are (and the noise
    has no negative terms). That case is a real pivot far below its row's
    size, as after a huge prior with no process noise (the variance of the
    velocity given the position is 1 where each is :math:`10^{30}`): the
    triangular solve with it is what the exact answer needs.
    """
    zero = zero_pivots(pred_factor)
    if zero.any() and Q_minus is None and not zero_pivots(filt_factor).any() and not zero_pivots(tria(A)).any():
        return np.zeros_like(zero)
    return zero


def joint_factor(filt_mean: np.ndarray, filt_factor: np.ndarray, A: np.ndarray, Q_factor: np.ndarray,
                 b: np.ndarray | None = None, Q_minus: np.ndarray | None = None):
    r"""The prediction out of a filtered belief, and the state given the prediction, from one factor.

    Parameters
    ----------
    filt_mean, filt_factor : arrays of shape (n,), (n, n)
        :math:`(m_k, L_k)`.
    A, Q_factor, b, Q_minus :
        The transition out of step k (see :func:`rts_step_sqrt`).

    Returns
    -------
    pred_mean : array of shape (n,)
        :math:`m^-_{k+1} = A m_k + b`.
    pred_factor : array of shape (n, n)
        :math:`L^-_{k+1}`.
    Y : array of shape (n, n)
        With :math:`Y L^{-\top} = P_k A^\top`: the gain is :math:`G_k = Y (L^-)^{-1}`.
    X : array of shape (n, n)
        Lower triangular, :math:`X X^\top = P_k - G_k P^-_{k+1} G_k^\top`, the
        covariance of :math:`x_k` given :math:`x_{k+1}`.

    Notes
    -----
    :math:`\operatorname{tria}\begin{bmatrix} L_Q & A L_k \\ 0 & L_k \end{bmatrix}
    = \begin{bmatrix} L^- & 0 \\ Y & X \end{bmatrix}`: the lower-triangular
    factor of the joint covariance of :math:`(x_{k+1}, x_k)`, read in blocks
    (downdated by :math:`[D_Q;\, 0]` when the noise has negative terms).
    The RTS smoother (:func:`rts_step_sqrt`) and the posterior sampler
    (:func:`gaussfuse.sample_posterior`) condition on :math:`x_{k+1}` with it.
    """
    n = filt_mean.shape[0]
    q = Q_factor.shape[1]
    pre = np.zeros((2 * n, q + n))
    pre[:n, :q] = Q_factor
    pre[:n, q:] = A @ filt_factor
    pre[n:, q:] = filt_factor
    post = tria(pre)
    if Q_minus is not None:
        post = downdate(post, np.concatenate([Q_minus, np.zeros((n, Q_minus.shape[1]))]),
                        "the joint covariance of the prediction and the state")
    return predict_mean(filt_mean, A, b), post[:n, :n], post[n:, :n], post[n:, n:]


def backward_conditional(filt_mean: np.ndarray, filt_factor: np.ndarray, next_states: np.ndarray, A: np.ndarray,
                         Q_factor: np.ndarray, b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""The law of :math:`x_k` given the filter up to k and :math:`x_{k+1}`, for each of several next states.

    Parameters
    ----------
    filt_mean, filt_factor : arrays of shape (n,), (n, n)
        :math:`(m_k, L_k)`.
    next_states : array of shape (s, n)
        Values of :math:`x_{k+1}`.
    A, Q_factor, b :
        The transition out of step k (see :func:`rts_step_sqrt`).

    Returns
    -------
    means : array of shape (s, n)
        :math:`m_k + G_k (x_{k+1} - m^-_{k+1})`, one row per next state.
    factor : array of shape (n, n)
        :math:`X`, with :math:`X X^\top = P_k - G_k P^-_{k+1} G_k^\top`, the
        same for every next state (with the columns of Y at zero pivots of
        :math:`L^-` where the prediction is singular; see :func:`rts_step_sqrt`).

    Notes
    -----
    From :func:`joint_factor`: :math:`G_k = Y (L^-)^{-1}`, applied as a
    triangular solve; the step of backward sampling (:func:`gaussfuse.sample_posterior`).
    """
    pred_mean, pred_factor, Y, X = joint_factor(filt_mean, filt_factor, A, Q_factor, b)
    zero = singular_pivots(pred_factor, filt_factor, A)  # as in rts_step_sqrt: spread that x_{k+1} does not see
    steps = Y @ factor_solve(pred_factor, (next_states - pred_mean).T, zero)
    return filt_mean + steps.T, tria(np.concatenate([X, Y[:, zero]], axis=1)) if zero.any() else X


# ---------------------------------------------------------------------------
# The step every driver calls: predict, then update, through a linearisation
# ---------------------------------------------------------------------------


class Step(NamedTuple):
    """What one :func:`step` returns.

    Parameters
    ----------
    predicted_mean, predicted_cov : ndarray of shape (n,), (n, n)
        The prediction :math:`(m^-_k, P^-_k)`.
    update : Update
        The posterior, innovation and log-likelihood term of step k.
    passes : int
        The updates made (1 unless iterated).
    converged : bool
        False when an iterated update made all its passes without meeting its tolerance.
    """

    predicted_mean: np.ndarray
    predicted_cov: np.ndarray
    update: Update
    passes: int
    converged: bool


def step(lin, k: int, mean: np.ndarray, cov: np.ndarray, z: np.ndarray, iterations: int = 1,
         tol: float | None = None, state_angles=None, measurement_angles=None,
         steady: SteadyState | None = None, gate: Gate | None = None) -> Step:
    r"""Step k of a filter: :func:`forecast`, then :func:`correct`.

    Parameters
    ----------
    lin : linearisation strategy
        ``lin.transition(k, m, P) -> (A, b, Q)`` and
        ``lin.measurement(k, m, P) -> (H, d, R)``: step k's model made affine
        around a belief (see :mod:`gaussfuse.linearize`). A strategy whose
        slopes exist only where the belief has spread (a regression) says so
        with ``lin.needs_spread``: an iterated update keeps its previous
        pass's slope where the posterior has none (:func:`correct`).
    k : int
        The step: the transition into the k-th state, and its measurement.
    mean, cov : ndarray of shape (n,), (n, n)
        The belief after step k - 1.
    z : ndarray of shape (m,)
        The measurement; NaN components are missing.
    iterations, tol :
        See :func:`correct`.
    state_angles, measurement_angles : ndarray of bool, optional
        Components that are angles: wrapped to [-π, π).
    steady : SteadyState, optional
        For a strategy whose covariance recursion does not depend on the
        step or the belief (``lin.invariant``): what this step may reuse
        from the last ones (see :class:`SteadyState`); the driver keeps one
        per series. Not used with `iterations` > 1.
    gate : Gate, optional
        Measurement components it rejects are treated as missing
        (``update.rejected`` says which).

    Returns
    -------
    Step

    Raises
    ------
    numpy.linalg.LinAlgError
        When the innovation covariance is not positive definite.
    FloatingPointError
        When the prediction or the posterior is not finite (an overflow).
    """
    pm, pc = forecast(lin, k, mean, cov, state_angles, check=False, steady=steady)
    try:
        post, passes, converged = correct(lin, k, pm, pc, z, iterations, tol, state_angles, measurement_angles,
                                          steady, gate)
    except (FloatingPointError, np.linalg.LinAlgError, ModelFunctionError):
        check_finite("predicted", pm, pc)  # when the prediction overflowed first, that is the error
        raise
    return Step(pm, pc, post, passes, converged)


class Factors:
    """The factors of Q and R a square-root filter uses: each computed once per matrix object.

    A time-invariant model hands its strategy's :meth:`transition` and
    :meth:`measurement` the same Q and R at every step, so they are
    factored once (:func:`cov_factor`); a time-varying one, at every step.
    """

    __slots__ = ("_covs", "_factors")

    def __init__(self) -> None:
        self._covs: dict[str, np.ndarray] = {}
        self._factors: dict[str, np.ndarray] = {}

    def __call__(self, name: str, cov: np.ndarray) -> np.ndarray:
        """The factor of `cov`, the matrix named `name` ("Q" or "R")."""
        if self._covs.get(name) is not cov:
            self._factors[name] = cov_factor(cov, name)
            self._covs[name] = cov
        return self._factors[name]


def transition_factors(lin, k: int, mean: np.ndarray, factor: np.ndarray, factors: Factors):
    r"""Step k's transition for the square-root form: ``(A, b, L_Q, D_Q)``, the noise :math:`L_Q L_Q^\top - D_Q D_Q^\top`.

    A strategy that reads the belief's covariance reads its factor instead
    (``lin.transition_sqrt``: sigma points regress on it, Taylor scales its
    finite-difference steps by it); for the others, ``L_Q`` is the factor of
    their Q (:class:`Factors`) and ``D_Q`` is None.

    Parameters
    ----------
    lin : linearisation strategy
        Step k's model made affine around a belief, as for :func:`step`.
    k : int
        The step.
    mean : array of shape (n,)
        The belief's mean after step k - 1.
    factor : array of shape (n, n)
        The Cholesky factor of its covariance.
    factors : Factors
        The cache of the factors of Q.
    """
    if hasattr(lin, "transition_sqrt"):
        return lin.transition_sqrt(k, mean, factor, factors)
    A, b, Q = lin.transition(k, mean, None)
    return A, b, factors("Q", Q), None


def measurement_factors(lin, k: int, mean: np.ndarray, factor: np.ndarray, factors: Factors):
    """Step k's measurement for the square-root form: ``(H, d, L_R, D_R)`` (see :func:`transition_factors`).

    Parameters
    ----------
    lin : linearisation strategy
        Step k's model made affine around a belief, as for :func:`step`.
    k : int
        The step.
    mean : array of shape (n,)
        The predicted mean of step k.
    factor : array of shape (n, n)
        The Cholesky factor of the predicted covariance.
    factors : Factors
        The cache of the factors of R.
    """
    if hasattr(lin, "measurement_sqrt"):
        return lin.measurement_sqrt(k, mean, factor, factors)
    H, d, R = lin.measurement(k, mean, None)
    return H, d, factors("R", R), None


def forecast_sqrt(lin, k: int, mean: np.ndarray, factor: np.ndarray, factors: Factors,
                  angles=None, steady: SteadyState | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The prediction of step k on factors: :func:`predict_sqrt` through ``lin.transition`` (see :func:`step_sqrt`).

    With `steady` (:class:`SteadyState`, holding factors), a factor at its
    fixed point predicts to the fixed point's prediction. A prediction that
    is not finite, or whose covariance ``L Lᵀ`` is not, raises
    FloatingPointError (a prediction too large to square can still give a
    finite posterior factor, all its precision lost, which the posterior's
    own check would not catch).

    Parameters
    ----------
    lin : linearisation strategy
        Step k's model made affine around a belief, as for :func:`step`.
    k : int
        The step.
    mean : array of shape (n,)
        The belief's mean after step k - 1.
    factor : array of shape (n, n)
        The Cholesky factor of its covariance.
    factors : Factors
        The cache of the factors of Q.
    angles : array of bool, shape (n,), optional
        State components that are angles: the predicted mean's are wrapped
        to [-π, π).
    steady : SteadyState, optional
        What may be reused at a fixed point.

    Returns
    -------
    mean : array of shape (n,)
        The predicted mean.
    factor : array of shape (n, n)
        The Cholesky factor of the predicted covariance.
    """
    A, b, LQ, DQ = transition_factors(lin, k, mean, factor, factors)
    if steady is not None and factor is steady.cov:
        pm, pL = predict_mean(mean, A, b), steady.predicted_cov
    else:
        pm, pL = predict_sqrt(mean, factor, A, LQ, b, DQ)
        if steady is not None:
            steady.previous, steady.predicted = factor, pL
    check_finite("predicted", pm, pL, factor=True)
    return (pm if angles is None else wrap_components(pm, angles)), pL


def correct_sqrt(lin, k: int, mean: np.ndarray, factor: np.ndarray, z: np.ndarray, factors: Factors,
                 state_angles=None, measurement_angles=None, steady: SteadyState | None = None,
                 gate: Gate | None = None) -> SqrtUpdate:
    """The update of step k on factors: :func:`update_sqrt` through ``lin.measurement`` (see :func:`step_sqrt`).

    With `steady`, the fixed point's gain is reused for the prediction it
    made, and a fixed point is recorded when the posterior's covariance
    ``L Lᵀ`` is the one the prediction started from (:meth:`SteadyState.holds`).
    With `gate` (:class:`Gate`), the components it rejects are missing.

    Parameters
    ----------
    lin : linearisation strategy
        Step k's model made affine around a belief, as for :func:`step`.
    k : int
        The step.
    mean : array of shape (n,)
        The predicted mean.
    factor : array of shape (n, n)
        The Cholesky factor of the predicted covariance.
    z : array of shape (m,)
        The measurement; NaN components are missing.
    factors : Factors
        The cache of the factors of R.
    state_angles, measurement_angles : array of bool, optional
        Components that are angles: wrapped to [-π, π).
    steady : SteadyState, optional
        What may be reused at a fixed point.
    gate : Gate, optional
        Measurement components it rejects are treated as missing
        (``rejected`` says which).

    Returns
    -------
    SqrtUpdate
        The posterior, its mean wrapped to the state angles; with nothing
        observed, `mean` and `factor` themselves, not copies.
    """
    H, d, LR, DR = measurement_factors(lin, k, mean, factor, factors)
    rejected = None
    if gate is not None:  # the measurement's prediction, on factors: L_z L_zᵀ = H P⁻ Hᵀ + R
        predicted, L_z = predict_sqrt(mean, factor, H, LR, d, DR)
        z, rejected = gate(z, predicted, symmetrize(L_z @ L_z.T), measurement_angles)
    observed = observed_components(z)
    reused = steady is not None and factor is steady.predicted_cov and _same(observed, steady.observed)
    if reused:
        g = steady.gain
    else:
        g = sqrt_gain(factor, H, LR, observed, DR)
        if (steady is not None and factor is steady.predicted
                and steady.holds(g.factor @ g.factor.T, steady.previous @ steady.previous.T)):
            steady.cov, steady.predicted_cov, steady.gain, steady.observed = g.factor, factor, g, observed
    post_mean, innovation, loglik, nis = apply_gain(g, mean, z, H, d, measurement_angles)
    if state_angles is not None:
        post_mean = wrap_components(post_mean, state_angles)
    post = SqrtUpdate(post_mean, g.factor, innovation, g.innovation_cov, loglik, g.K, nis, rejected)
    check_finite("filtered", post.mean, post.factor, post.loglik, factor=True)
    return post


def step_sqrt(lin, k: int, mean: np.ndarray, factor: np.ndarray, z: np.ndarray, factors: Factors,
              state_angles=None, measurement_angles=None, steady: SteadyState | None = None,
              gate: Gate | None = None) -> Step:
    r"""Step k of a square-root filter: :func:`forecast_sqrt`, then :func:`correct_sqrt`.

    As :func:`step` (one pass, for a strategy that does not read the
    covariance: exact or Taylor linearisation), with the Cholesky factor
    `factor` of the belief's covariance. The returned :class:`Step` holds
    factors: ``predicted_cov`` is :math:`L^-_k` and ``update`` a
    :class:`SqrtUpdate`.

    Parameters
    ----------
    lin : linearisation strategy
        Step k's model made affine around a belief, as for :func:`step`.
    k : int
        The step.
    mean : array of shape (n,)
        The belief's mean after step k - 1.
    factor : array of shape (n, n)
        The Cholesky factor of its covariance.
    z : array of shape (m,)
        The measurement; NaN components are missing.
    factors : Factors
        The cache of the factors of Q and R.
    state_angles, measurement_angles : array of bool, optional
        Components that are angles: wrapped to [-π, π).
    steady : SteadyState, optional
        What may be reused at a fixed point (see :func:`step`).
    gate : Gate, optional
        Measurement components it rejects are treated as missing.

    Returns
    -------
    Step
        With ``passes`` 1 and ``converged`` True.

    Raises
    ------
    numpy.linalg.LinAlgError
        When the innovation covariance is singular, or Q or R is not
        positive semi-definite.
    FloatingPointError
        When the prediction or the posterior is not finite.
    """
    pm, pL = forecast_sqrt(lin, k, mean, factor, factors, state_angles, steady)  # checked before the update
    post = correct_sqrt(lin, k, pm, pL, z, factors, state_angles, measurement_angles, steady, gate)
    return Step(pm, pL, post, 1, True)


class SteadyState:
    r"""What :func:`forecast` and :func:`correct` reuse once the covariances reach a fixed point.

    For a strategy whose ``A``, ``Q``, ``H`` and ``R`` depend neither on the
    step nor on the belief (``lin.invariant``: a time-invariant linear
    model; the offsets ``b = B u_k`` and ``d`` may vary), a step's
    covariances, :math:`P_{k-1} \to P^-_k \to (K_k, S_k, P_k)`, depend on
    nothing but :math:`P_{k-1}` and which components of :math:`z_k` are
    observed. Once a step leaves the posterior covariance unchanged to
    round-off (:func:`settled`), every following step with the same observed
    components would compute the same covariances, gain and factor again,
    up to round-off: they are reused, and only the means are computed (a
    few products instead of a Cholesky factorisation and the Joseph form).

    Parameters
    ----------
    target : ndarray of shape (n, n), optional
        The stationary filtered covariance, for the steady-state filter
        (see the attribute `target`).
    tol : float, optional
        The tolerance of the fixed-point test; ``SETTLED`` by default.

    Notes
    -----
    In float64 the recursion seldom reaches a fixed point bit for bit: past
    a few states its covariance keeps changing in its last bits (measured
    on random models with n = 8 to 128 states: by up to 2.6 to 6.9 units
    of round-off per step, for thousands of steps). A step that changes no
    entry by more than ``SETTLED`` relative to its scale is at the fixed
    point as closely as the recursion itself can resolve it. If the
    recursion contracts by a factor :math:`\rho` per step, the covariance
    that is kept is within about ``SETTLED`` / (1 - ρ) of the exact fixed
    point, about ten times the round-off that computing every step carries
    anyway (a random walk with 1 - ρ = 0.01: 9.3e-14 relative against
    6.8e-15; ``benchmarks/fixed_point.py``).
    This is not the approximate steady-state filter, whose gain is fixed
    before the covariance has converged.

    Attributes
    ----------
    cov : ndarray or None
        The fixed-point posterior covariance (the very object the step
        returns while reusing it), or None before one is found.
    predicted_cov : ndarray or None
        Its prediction, :math:`A P A^\top + Q`.
    gain : Gain or None
        The update's covariance half from it.
    observed : ndarray or None
        The observed components the gain is for (None: all).
    previous, predicted : ndarray or None
        The covariance the last full prediction started from and the one it
        returned (an update of `predicted` back to `previous`, to
        round-off, is a fixed point).
    target : ndarray or None
        For the steady-state filter (``filter(..., steady=True)``): the
        stationary filtered covariance (:func:`gaussfuse.steady_state`). A
        posterior within `tol` of it (:func:`settled`) is held, instead of
        one that stops changing.
    tol : float
        The tolerance of that test: ``SETTLED`` without a target.
    """

    __slots__ = ("cov", "predicted_cov", "gain", "observed", "previous", "predicted", "target", "tol")

    def __init__(self, target: np.ndarray | None = None, tol: float | None = None) -> None:
        self.cov = self.predicted_cov = self.gain = self.observed = self.previous = self.predicted = None
        self.target = target
        self.tol = SETTLED if tol is None else tol

    def holds(self, cov: np.ndarray, previous: np.ndarray | None = None) -> bool:
        """Whether the posterior `cov`, updated from :attr:`predicted`, is the one to hold (see the attributes).

        `previous` is the covariance the prediction started from, when
        :attr:`previous` holds its factor (the square-root form).

        Parameters
        ----------
        cov : ndarray of shape (n, n)
            The posterior covariance.
        previous : ndarray of shape (n, n), optional
            The covariance the prediction started from; the attribute
            `previous` by default. Not used with a `target`, which `cov` is
            compared with instead.

        Returns
        -------
        bool
            Whether `cov` equals `target` (or else the previous
            covariance) to within `tol` (:func:`settled`).
        """
        old = (self.previous if previous is None else previous) if self.target is None else self.target
        return settled(cov, old, self.tol)


SETTLED = 8.0 * np.finfo(float).eps
"""The largest change of a covariance entry, relative to its scale, that :func:`settled` takes for none."""

STEADY_TOL = 1e-10
"""The steady-state filter's test: a posterior within this of the stationary one (relative, :func:`settled`)."""


def settled(new: np.ndarray, old: np.ndarray, tol: float = SETTLED) -> bool:
    r"""Whether covariance `new` equals `old` to round-off (or to `tol`): :class:`SteadyState`'s fixed-point test.

    Parameters
    ----------
    new, old : ndarray of shape (n, n)
    tol : float, default SETTLED

    Returns
    -------
    bool
        True when :math:`|P_{ij} - P'_{ij}| \le \epsilon_s \sqrt{P_{ii}} \sqrt{P_{jj}}`
        for every i, j, with :math:`P` = `new` and :math:`\epsilon_s` = `tol`
        (by default ``SETTLED``, 8 machine epsilons). The bound scales with each entry's variances, so
        the test does not depend on the states' units; a component with zero
        variance must not change at all, and NaN is never settled.
    """
    s = np.sqrt(np.abs(np.diagonal(new)))
    return bool(np.all(np.abs(new - old) <= tol * (s[:, None] * s[None, :])))


def forecast(lin, k: int, mean: np.ndarray, cov: np.ndarray, angles=None, check: bool = True,
             steady: SteadyState | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The prediction of step k: :func:`predict` through ``lin.transition`` (see :func:`step`).

    With `check`, a prediction that is not finite raises FloatingPointError
    (:func:`step` checks it only when the update fails, which it then does).
    With `steady` (see :class:`SteadyState`), a covariance at its fixed point
    predicts to the fixed point's prediction, without computing it again.

    Parameters
    ----------
    lin : linearisation strategy
        Step k's model made affine around a belief, as for :func:`step`.
    k : int
        The step.
    mean : array of shape (n,)
        The belief's mean after step k - 1.
    cov : array of shape (n, n)
        Its covariance.
    angles : array of bool, shape (n,), optional
        State components that are angles: the predicted mean's are wrapped
        to [-π, π).
    check : bool, default True
        Raise FloatingPointError for a prediction that is not finite.
    steady : SteadyState, optional
        What may be reused at a fixed point.

    Returns
    -------
    mean : array of shape (n,)
        The predicted mean.
    cov : array of shape (n, n)
        The predicted covariance.
    """
    A, b, Q = lin.transition(k, mean, cov)
    if steady is not None and cov is steady.cov:
        m, P = predict_mean(mean, A, b), steady.predicted_cov
    else:
        m, P = predict(mean, cov, A, Q, b)
        if steady is not None:
            steady.previous, steady.predicted = cov, P
    if angles is not None:
        m = wrap_components(m, angles)
    if check:
        check_finite("predicted", m, P)
    return m, P


def correct(lin, k: int, mean: np.ndarray, cov: np.ndarray, z: np.ndarray, iterations: int = 1,
            tol: float | None = None, state_angles=None, measurement_angles=None,
            steady: SteadyState | None = None, gate: Gate | None = None) -> tuple[Update, int, bool]:
    """The update of step k through ``lin.measurement``, iterated when asked.

    Pass i linearises the measurement at the previous posterior ``x_{i-1}``
    (``x_0`` the prediction `mean`) and conditions the prediction
    ``N(mean, cov)`` on `z` again: the iterated EKF's Gauss–Newton steps, or
    posterior linearisation. With one iteration this is the plain update.
    With more, it stops after the first pass whose change
    ``‖x_i - x_{i-1}‖`` in the norm of `cov` (:func:`iterate_changed`) is at
    most `tol`, or after `iterations` passes.

    With `steady` and one iteration (see :class:`SteadyState`), the
    fixed point's gain is reused for the prediction it made, and a fixed
    point is recorded when this update brings the covariance back to the
    one the prediction started from.

    With `gate` (:class:`Gate`), the components it rejects at the first
    linearisation (at the prediction) are missing for every pass.

    Parameters
    ----------
    lin : linearisation strategy
        Step k's model made affine around a belief, as for :func:`step`.
    k : int
        The step.
    mean : array of shape (n,)
        The predicted mean.
    cov : array of shape (n, n)
        The predicted covariance.
    z : array of shape (m,)
        The measurement; NaN components are missing.
    iterations : int, default 1
        The most passes.
    tol : float, optional
        Stop after the first pass whose change is at most `tol`; None: all
        `iterations` passes are made.
    state_angles, measurement_angles : array of bool, optional
        Components that are angles: wrapped to [-π, π).
    steady : SteadyState, optional
        What may be reused at a fixed point; used with one iteration only.
    gate : Gate, optional
        Measurement components it rejects are treated as missing
        (``post.rejected`` says which).

    Returns
    -------
    post : Update
        The last pass's update, its mean wrapped to the state angles; with
        nothing observed, `mean` and `cov` themselves, not copies.
    passes : int
    converged : bool
        False when `iterations` > 1 passes were made without meeting `tol`
        (given); True otherwise.
    """
    if iterations == 1:  # the plain update
        return _correct_once(lin, k, mean, cov, z, state_angles, measurement_angles, steady, gate)[0], 1, True
    rejected = None
    if gate is not None:
        H, d, R = lin.measurement(k, mean, cov)
        z, rejected = gate(z, *predict(mean, cov, H, R, d), measurement_angles)
    post_mean, post_cov = mean, cov
    changed = iterate_changed(cov, mean) if tol is not None else None
    passes, converged = iterations, changed is None
    slope = None
    regresses, scale = getattr(lin, "needs_spread", False), np.sqrt(np.diagonal(cov).clip(min=0.0))
    for i in range(iterations):
        # linearised at the previous posterior on the prediction's side of ±π: the affine map is applied to the
        # prediction, and one made at the wrapped point would be 2π off there
        point = near(post_mean, mean, state_angles)
        try:
            H, d, R = lin.measurement(k, point, post_cov)
            unseen = unseen_directions(point, post_cov, scale) if slope is not None and regresses else None
            if unseen is not None:  # a slope the posterior cannot see (a regression's): the previous pass's
                H, d = with_slopes(H, d, slope, point, unseen)
            slope = H
            post = update(mean, cov, z, H, R, d, measurement_angles)
            previous, post_mean, post_cov = post_mean, post.mean, post.cov
            if state_angles is not None:
                post_mean = wrap_components(post_mean, state_angles)
            if i and not np.all(np.isfinite(post_mean)):
                raise FloatingPointError(not_finite("filtered"))
        except (ModelFunctionError, FloatingPointError, np.linalg.LinAlgError) as exc:
            if not i:
                raise
            raise type(exc)(  # (audit DD4: h's overflow named neither the iterations nor where they had gone)
                f"{exc} This was pass {i + 1} of the iterated update, linearised at x = {shown(point)} (the "
                f"prediction: {shown(mean)}): the iterations moved away, as Gauss-Newton steps can from a prior "
                "far from the data. Try iterations=1 (the plain update), another method, or a prior nearer the "
                "data.") from exc
        if changed is not None and changed(post_mean, previous, state_angles) <= tol:
            passes, converged = i + 1, True
            break
    if post_mean is not post.mean or rejected is not None:
        post = post._replace(mean=post_mean, rejected=rejected)
    check_finite("filtered", post.mean, post.cov, post.loglik)
    return post, passes, converged


def _correct_once(lin, k: int, mean: np.ndarray, cov: np.ndarray, z: np.ndarray, state_angles,
                  measurement_angles, steady: SteadyState | None = None,
                  gate: Gate | None = None) -> tuple[Update, Gain]:
    """The plain update of step k through ``lin.measurement``, and its :class:`Gain` (see :func:`correct`)."""
    H, d, R = lin.measurement(k, mean, cov)
    rejected = None
    if gate is not None:
        z, rejected = gate(z, *predict(mean, cov, H, R, d), measurement_angles)
    observed = observed_components(z)
    reused = steady is not None and cov is steady.predicted_cov and _same(observed, steady.observed)
    if reused:
        g = steady.gain
    else:
        g = gain(cov, H, R, observed)
        if steady is not None and cov is steady.predicted and steady.holds(g.cov):
            steady.cov, steady.predicted_cov, steady.gain, steady.observed = g.cov, cov, g, observed
    post_mean, innovation, loglik, nis = apply_gain(g, mean, z, H, d, measurement_angles)
    if state_angles is not None:
        post_mean = wrap_components(post_mean, state_angles)
    post = Update(post_mean, g.cov, innovation, g.innovation_cov, loglik, g.K, nis, rejected)
    if reused:  # the fixed point's covariance is finite: only the mean and loglik can have overflowed
        total = post_mean.sum() + loglik
        if total - total != 0.0:
            raise FloatingPointError(not_finite("filtered"))
    else:
        check_finite("filtered", post.mean, post.cov, post.loglik)
    return post, g


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return a is b or (a is not None and b is not None and np.array_equal(a, b))


def check_finite(stage: str, mean: np.ndarray, cov: np.ndarray, loglik: float = 0.0, factor: bool = False) -> None:
    """Raise FloatingPointError when the mean, the covariance's diagonal or `loglik` is inf or NaN.

    With `factor`, `cov` is a covariance factor L (square-root form), and
    the trace of the covariance it stands for, the sum of its squared
    entries, is checked: a finite factor of a covariance too large to
    represent is an overflow too.

    One sum, ``Σ mean + tr P + loglik``, is checked: it is not finite exactly
    when one of its terms is not (or, for a belief within a factor 2 of the
    largest float, 1.8e308, when their sum overflows: then the next step
    would). An inf or NaN covariance has one on its diagonal.

    Parameters
    ----------
    stage : str
        "predicted", "filtered" or "smoothed", for the error message.
    mean : array of shape (n,)
        The belief's mean.
    cov : array of shape (n, n)
        Its covariance, or with `factor` its factor L.
    loglik : float, default 0.0
        A log-likelihood term, checked too.
    factor : bool, default False
        Whether `cov` is a covariance factor.

    Raises
    ------
    FloatingPointError
        When the sum is not finite.
    """
    total = mean.sum() + ((cov * cov).sum() if factor else cov.trace()) + loglik
    if total - total != 0.0:
        raise FloatingPointError(not_finite(stage))


def iterate_changed(cov: np.ndarray, start: np.ndarray | None = None):
    r"""The change of an iterate in the norm of `cov`: a function ``(new, old, angles) -> float``.

    .. math::

        \lVert x_i - x_{i-1} \rVert_{P} = \sqrt{(x_i - x_{i-1})^\top P^{-1} (x_i - x_{i-1})},

    with ``P = L Lᵀ`` (Cholesky, or the semi-definite factor of
    :func:`gaussfuse._linalg.semidefinite_cholesky` on the range of a singular
    P, where the iterates move). It is scale-free: the change in standard
    deviations of P. A component that changed by no more than its round-off,
    ``4 ε max(|new|, |old|, |start|)``, counts as unchanged, so that a
    component whose variance is itself round-off, or iterates that cycle in
    their last bits, do not keep the iteration going.

    Parameters
    ----------
    cov : array of shape (n, n)
        The covariance P of the norm, positive semi-definite.
    start : array of shape (n,), optional
        The mean the iterates are computed from (an update's ``m⁻``, to
        which ``K v`` is added): their round-off is relative to it too.

    Returns
    -------
    callable
        ``changed(new, old, angles=None) -> float``, with `new` and `old`
        of shape (n,) and `angles` the state components whose difference
        is wrapped to [-π, π).
    """
    try:
        L = np.linalg.cholesky(cov)
        rows = slice(None)
    except np.linalg.LinAlgError:
        L = semidefinite_cholesky(cov)
        rows = np.diag(L) > 0.0
        L = L[np.ix_(rows, rows)]
    eps4 = 4.0 * np.finfo(np.float64).eps
    floor = 0.0 if start is None else np.abs(start)  # the same for every iterate

    def changed(new: np.ndarray, old: np.ndarray, angles=None) -> float:
        delta = wrap_components(new - old, angles)
        size = np.maximum(np.maximum(np.abs(new), np.abs(old)), floor)
        delta = np.where(np.abs(delta) <= eps4 * size, 0.0, delta)[rows]
        if not delta.any():
            return 0.0
        white = whiten(L, delta)
        return float(np.sqrt(white @ white))

    return changed
