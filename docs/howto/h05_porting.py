r"""
Porting from filterpy, pykalman and statsmodels
===============================================

How do I move code from filterpy, pykalman or statsmodels to gaussfuse? The
model's matrices go into a :class:`gaussfuse.LinearModel`, and the initial
belief into a :class:`gaussfuse.Gaussian`. A filterpy loop then runs almost
unchanged on :class:`gaussfuse.KalmanFilter`, which uses filterpy's names.
Whole series go to :func:`gaussfuse.filter` and :func:`gaussfuse.smooth`.
Watch *when* the initial belief holds: gaussfuse and filterpy put it one
step before the first measurement, pykalman and statsmodels at it.
"""

import numpy as np

import gaussfuse as gf

# %%
# Equivalent calls
# ----------------
#
# .. list-table::
#    :header-rows: 1
#    :widths: 14 22 22 22 20
#
#    * - Task
#      - filterpy ``KalmanFilter``
#      - pykalman ``KalmanFilter``
#      - statsmodels
#      - gaussfuse
#    * - Model
#      - ``KalmanFilter(dim_x, dim_z)``, then set ``F``, ``H``, ``Q``, ``R``, ``B``
#      - ``KalmanFilter(transition_matrices=F, observation_matrices=H, transition_covariance=Q,
#        observation_covariance=R)``
#      - ``MLEModel(endog, k_states)`` with ``mod["transition"]``, ``["design"]``, ``["state_cov"]``,
#        ``["selection"]``, ``["obs_cov"]``; or ``UnobservedComponents(endog, "local level")``
#      - ``gf.LinearModel(F, H, Q, R, B)``
#    * - Initial belief
#      - ``kf.x``, ``kf.P``, one step *before* the first measurement
#      - ``initial_state_mean``, ``initial_state_covariance``, *at* the first measurement
#      - ``initialize_known(a1, P1)``, *at* the first measurement; ``initialization="diffuse"``
#        or ``use_exact_diffuse=True``
#      - ``gf.Gaussian(mean, cov)``, one step *before* the first measurement; or ``"diffuse"``
#    * - Offsets
#      - ``B @ u``
#      - ``transition_offsets`` b, ``observation_offsets`` d
#      - ``["state_intercept"]`` c, ``["obs_intercept"]`` d
#      - ``B=np.eye(n)`` with the offsets as ``us``, shifted by one as time-varying matrices are (``us[k]`` is
#        pykalman's ``transition_offsets[k - 1]``); take d off the data: ``zs - d``
#    * - One step
#      - ``predict(u, F=, Q=)``, ``update(z, R=, H=)``
#      - ``filter_update(mean, cov, observation)`` (a predict and an update)
#      - none
#      - ``gf.KalmanFilter(model, prior)``: ``predict(u, F=, Q=)``, ``update(z, R=, H=)``; ``x``,
#        ``P``, ``y``, ``S``, ``K``, ``log_likelihood``, ``mahalanobis``
#    * - Filter a series
#      - ``batch_filter(zs)``: means, covariances, predictions
#      - ``filter(X)``: means, covariances
#      - ``mod.filter(params)``: ``filtered_state`` (n, T), ``filtered_state_cov`` (n, n, T)
#      - ``gf.filter(model, prior, zs)``: ``.means`` (T, n), ``.covs`` (T, n, n),
#        ``.predicted_means``, ``.predicted_covs``
#    * - Smooth
#      - ``rts_smoother(means, covs)``
#      - ``smooth(X)``
#      - ``mod.smooth(params)``: ``smoothed_state``, ``smoothed_state_cov``
#      - ``gf.smooth(model, prior, zs)``
#    * - Learn Q, R, ...
#      - none
#      - ``em(X, n_iter, em_vars)``
#      - ``mod.fit()`` (maximum likelihood)
#      - ``gf.fit(model, prior, zs, learn=("Q", "R"), method="em")`` or ``method="mle"``
#    * - Forecast
#      - ``get_prediction()`` (one step)
#      - none
#      - ``results.get_forecast(steps)``
#      - ``gf.forecast(model, result, steps)``
#    * - Missing value
#      - ``None``
#      - a masked entry (``np.ma``)
#      - NaN
#      - NaN (``None`` also in ``KalmanFilter.update``)
#    * - Log-likelihood
#      - ``log_likelihood`` (of the last update)
#      - ``loglikelihood(X)``
#      - ``results.llf``
#      - ``result.loglik`` (``kf.loglik`` online)
#
# Every log-likelihood here includes the :math:`-\tfrac12 \log 2\pi` of each
# observed component. simdkalman's leaves it out: with nothing missing,
# gaussfuse's is simdkalman's minus :math:`T m \cdot \tfrac12 \log 2\pi`
# (simdkalman's initial state is at the first measurement, as pykalman's is:
# convert it as below). Under an exact diffuse prior, KFAS leaves it out for
# the observations that identify the first state.
#
# **Converting the initial belief.** pykalman's first measurement
# :math:`z_0` observes :math:`x_0 \sim N(\mu_0, \Sigma_0)` directly (its
# ``KalmanFilter`` docstring: :math:`z_t = C_t x_t + \dots`), and statsmodels'
# ``initialize_known(a1, P1)`` is also the state at the first measurement.
# From a gaussfuse prior :math:`N(m_0, P_0)`, give them the first prediction,
# :math:`F m_0` and :math:`F P_0 F^\top + Q`: ``gf.forecast(model, prior,
# 1).means[0]`` and ``.covs[0]``. From their :math:`N(\mu_0, \Sigma_0)`, skip
# the first ``predict`` online, or make the first step a no-op with a
# time-varying model (``F[0]`` the identity, ``Q[0]`` zero). Time-varying
# matrices shift by one too: gaussfuse's ``F[k]`` leads *into* step k,
# pykalman's ``transition_matrices[t]`` *out of* step t. A pykalman series
# whose first observation is masked, as in its robot dataset
# (``pykalman.datasets.load_robot``), already starts one step before its
# first measurement: drop that row and use the initial state as the prior,
# with no time-varying first step, which ``gf.fit`` could not learn Q
# through. gaussfuse's filter, smoother and 50 EM iterations then equal the
# dataset's published ones: means, covariances and Q and R to 2e-12, the
# log-likelihoods to 1e-15 relative (its test suite checks them).

# %%
# The same loop in filterpy and gaussfuse
# ---------------------------------------
#
# A position measured with noise, with a constant-velocity model. The loop
# has a missing reading (``None``), one reading from a worse sensor
# (``R=25`` for that update) and one step with more process noise
# (``Q=`` for that prediction). The gaussfuse lines are filterpy's, with the
# matrices in a ``LinearModel`` and the belief in a ``Gaussian``.

F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
Q, R = 0.05 * np.array([[0.25, 0.5], [0.5, 1.0]]), np.array([[4.0]])
rng = np.random.default_rng(3)
zs = [float(z) for z in 0.8 * np.arange(50) + rng.normal(scale=2.0, size=50)]
zs[12] = None

ours = gf.KalmanFilter(gf.LinearModel(F=F, H=H, Q=Q, R=R), gf.Gaussian([0.0, 0.0], np.eye(2)))
ours.P *= 100.0


def run(kf):
    """The loop, written once for both libraries; what each update leaves behind."""
    out = []
    for k, z in enumerate(zs):
        kf.predict(Q=10 * Q if k == 30 else None)        # None: the filter's own Q
        kf.update(z, R=25.0 if k == 40 else None)
        out.append([np.copy(kf.x), np.copy(kf.P), np.copy(kf.y), np.copy(kf.S), np.copy(kf.K),
                    kf.log_likelihood, kf.mahalanobis])
    return out


mine = run(ours)

# %%
# With filterpy installed, the same function runs its filter, and the code
# checks every quantity after every update to 1e-10. At the missing reading
# filterpy sets ``y`` to zero and leaves the previous ``S`` and ``K`` in
# place, so only ``x`` and ``P`` are compared there. The total log-likelihood, ``ours.loglik``,
# is the sum of filterpy's per-update terms (checked).

try:
    from filterpy.kalman import KalmanFilter
except ImportError:
    print("filterpy is not installed: no comparison")
else:
    theirs = KalmanFilter(dim_x=2, dim_z=1)
    theirs.x, theirs.P, theirs.F, theirs.H, theirs.Q, theirs.R = np.zeros(2), np.eye(2), F, H, Q, R
    theirs.P *= 100.0
    reference = run(theirs)
    names = ["x", "P", "y", "S", "K", "log_likelihood", "mahalanobis"]
    worst = dict.fromkeys(names, 0.0)
    for k, (a, b) in enumerate(zip(mine, reference)):
        for name, u, v in list(zip(names, a, b))[: 2 if zs[k] is None else 7]:
            worst[name] = max(worst[name], float(np.max(np.abs(np.ravel(u) - np.ravel(v)))))
    print("largest difference from filterpy:", ", ".join(f"{n} {v:.1e}" for n, v in worst.items()))
    assert max(worst.values()) < 1e-10
    assert abs(ours.loglik - sum(b[5] for k, b in enumerate(reference) if zs[k] is not None)) < 1e-10

# %%
# pykalman, after converting the prior
# ------------------------------------
#
# The whole series through :func:`gaussfuse.filter` and :func:`gaussfuse.smooth`
# (a missing value is NaN), and through pykalman with the first prediction as
# its initial state (a missing value is masked). The code checks that the
# filtered and smoothed means and covariances and the log-likelihood agree to
# 1e-10. It then goes the other way, from pykalman's initial state
# :math:`N(\mu_0, \Sigma_0)`: as the prior of a gaussfuse model whose first
# step is the identity with no noise, and online, with no ``predict`` before
# the first ``update`` (both checked).

model = gf.LinearModel(F=F, H=H, Q=Q, R=R)
prior = gf.Gaussian([0.0, 0.0], 100.0 * np.eye(2))
data = np.array([np.nan if z is None else z for z in zs])
filtered, smoothed = gf.filter(model, prior, data), gf.smooth(model, prior, data)

try:
    from pykalman import KalmanFilter as PyKalmanFilter
except ImportError:
    print("pykalman is not installed: no comparison")
else:
    def pykalman(mean, cov):
        return PyKalmanFilter(transition_matrices=F, observation_matrices=H, transition_covariance=Q,
                              observation_covariance=R, initial_state_mean=mean, initial_state_covariance=cov)

    first = gf.forecast(model, prior, 1)             # the first prediction
    pk = pykalman(first.means[0], first.covs[0])
    masked = np.ma.masked_invalid(data[:, None])
    for a, b in zip([*pk.filter(masked), *pk.smooth(masked)],
                    [filtered.means, filtered.covs, smoothed.means, smoothed.covs]):
        assert np.max(np.abs(a - b)) < 1e-10
    assert abs(pk.loglikelihood(masked) - filtered.loglik) < 1e-10
    print(f"pykalman agrees; log-likelihood {filtered.loglik:.6f}")

    mu0, sigma0 = np.array([1.0, 0.5]), np.diag([3.0, 0.2])
    pk_means = pykalman(mu0, sigma0).filter(masked)[0]
    Fs, Qs = np.repeat(F[None], len(data), axis=0), np.repeat(Q[None], len(data), axis=0)
    Fs[0], Qs[0] = np.eye(2), 0.0
    shifted = gf.filter(gf.LinearModel(F=Fs, H=H, Q=Qs, R=R), gf.Gaussian(mu0, sigma0), data)
    assert np.max(np.abs(pk_means - shifted.means)) < 1e-10
    online = gf.KalmanFilter(model, gf.Gaussian(mu0, sigma0))
    for k, z in enumerate(zs):
        if k > 0:
            online.predict()
        online.update(z)
        assert np.max(np.abs(online.x - pk_means[k])) < 1e-10

# %%
# Models of several axes, from Stone Soup or filterpy
# ---------------------------------------------------
#
# A gaussfuse motion orders its state by derivative, then by axis:
# ``[x, y, vx, vy]`` (its ``names``). Stone Soup's combined constant-velocity
# models and filterpy's ``Q_continuous_white_noise(2, dt, q, block_size=2)``
# order it by axis: ``[x, vx, y, vy]``. The blocks are the same, so permute
# the rows and columns (checked below against filterpy). Sensors give
# ``[range, bearing]`` and ``[range, bearing, elevation]``; Stone Soup's
# ``CartesianToBearingRange`` gives ``[bearing, range]`` and
# ``CartesianToElevationBearingRange`` ``[elevation, bearing, range]``.
# Stone Soup's ``Singer(damping_coeff=K, noise_diff_coeff=q)`` is
# ``gf.Singer(tau=1 / K, sigma=np.sqrt(q / (2 * K)))``. One ``q`` serves all
# axes of a gaussfuse motion, and a sensor has an ``origin`` but no rotation.

dt, q = 0.7, 2.0
cv = gf.ConstantVelocity(dim=2, q=q)
F2, Q2 = cv.transition(dt)
by_axis = [0, 2, 1, 3]  # x, vx, y, vy
print(cv.names, "->", [cv.names[i] for i in by_axis])
try:
    from filterpy.common import Q_continuous_white_noise
except ImportError:
    print("filterpy is not installed: no comparison")
else:
    assert np.allclose(Q2[np.ix_(by_axis, by_axis)], Q_continuous_white_noise(2, dt, q, block_size=2), rtol=1e-14)
    print("filterpy's Q, ordered by axis, agrees")

