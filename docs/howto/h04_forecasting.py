r"""
Forecasting with intervals
==========================

How do I predict the next k values of a series, with intervals? Filter the
data, then call ``gf.forecast(model, result, steps=k)``. It starts from the
filter's last belief and runs the prediction step k times without updates.
The result holds the predicted states (``.means``, ``.covs``) and the
predicted measurements (``.measurement_means``, ``.measurement_covs``, which
include the measurement noise R). ``.interval(0.95)`` gives the central 95%
interval of each future measurement (``of="states"`` for the states).
"""

from statistics import NormalDist

import matplotlib.pyplot as plt
import numpy as np

import gaussfuse as gf
from gaussfuse.datasets import nile
from gaussfuse.plotting import plot_series

# %%
# Filter, then forecast
# ---------------------
#
# A local linear trend: the state is a level and its slope, both drifting,
# and we measure the level with noise of variance 4. We simulate 100 steps,
# filter them, and forecast 30 steps past the last one.

F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
Q, R = np.diag([0.5, 0.01]), np.array([[4.0]])
model = gf.LinearModel(F=F, H=H, Q=Q, R=R)
prior = gf.Gaussian([10.0, 0.3], np.diag([4.0, 0.1]))
T, k = 100, 30
zs = gf.simulate(model, prior, T, rng=5).measurements

filtered = gf.filter(model, prior, zs)
fc = gf.forecast(model, filtered, steps=k)
lower, upper = fc.interval(0.95)
print("shapes:", fc.means.shape, fc.covs.shape, fc.measurement_means.shape, fc.measurement_covs.shape)
print("1, 10 and 30 steps ahead:")
for j in (0, 9, 29):
    print(f"  {j + 1:2d}: measurement {fc.measurement_means[j, 0]:7.2f}, "
          f"95% interval [{lower[j, 0]:7.2f}, {upper[j, 0]:7.2f}]")

# %%
# The same numbers by hand
# ------------------------
#
# Without updates, j steps from the belief :math:`N(m, P)` are
#
# .. math::
#
#    m_j = F^j m, \qquad
#    P_j = F^j P (F^j)^\top + \sum_{i=0}^{j-1} F^i Q (F^i)^\top, \qquad
#    \hat z_j = H m_j, \qquad S_j = H P_j H^\top + R,
#
# and the 95% interval is :math:`\hat z_j \pm 1.96 \sqrt{S_j}`. The code
# computes these from the filter's last belief and checks that they agree
# with the forecast to 1e-10.

m, P = filtered.last_mean, filtered.last_cov
noise = np.zeros((2, 2))
for j in range(1, k + 1):
    Fj = np.linalg.matrix_power(F, j)
    noise += np.linalg.matrix_power(F, j - 1) @ Q @ np.linalg.matrix_power(F, j - 1).T
    mean_j, cov_j = Fj @ m, Fj @ P @ Fj.T + noise
    assert np.allclose(fc.means[j - 1], mean_j, rtol=1e-10, atol=1e-10)
    assert np.allclose(fc.covs[j - 1], cov_j, rtol=1e-10, atol=1e-10)
    assert np.allclose(fc.measurement_means[j - 1], H @ mean_j, rtol=1e-10, atol=1e-10)
    assert np.allclose(fc.measurement_covs[j - 1], H @ cov_j @ H.T + R, rtol=1e-10, atol=1e-10)
z95 = NormalDist().inv_cdf(0.975)
assert np.allclose(upper[:, 0], fc.measurement_means[:, 0] + z95 * np.sqrt(fc.measurement_covs[:, 0, 0]),
                   rtol=1e-12)
print(f"the hand computation agrees; the 95% half-width is {z95:.4f} standard deviations")

# %%
# The forecast fan
# ----------------
#
# The figure shows the measurements, the filtered level with its ±2σ band,
# and the forecast: the predicted level, the 95% interval of the level, and
# the wider 95% interval of a new measurement, which adds the measurement
# noise R.

steps, ahead = np.arange(1, T + 1), np.arange(T + 1, T + k + 1)
level_lower, level_upper = fc.interval(0.95, of="states")
fig, ax = plt.subplots(figsize=(7.5, 3.8), layout="constrained")
plot_series(steps, filtered.means, filtered.covs, zs=zs, ax=ax, label="filtered level",
            xlabel="step", ylabel="level")
ax.plot(ahead, fc.means[:, 0], color="C1", label="forecast level")
ax.fill_between(ahead, level_lower[:, 0], level_upper[:, 0], color="C1", alpha=0.35, label="95%, level")
ax.fill_between(ahead, lower[:, 0], upper[:, 0], color="C1", alpha=0.15, label="95%, new measurement")
ax.legend(loc="lower left", fontsize="small")
ax.set_title(f"A {k}-step forecast from the filter's last belief")
plt.show()

# %%
# Agreement with statsmodels
# --------------------------
#
# statsmodels forecasts state-space models with ``get_forecast``. We compare
# the two on the Nile's annual flow (``gaussfuse.datasets.nile``) with a
# local level model, using the variances Durbin & Koopman estimate for it
# (*Time Series Analysis by State Space Methods*, 2nd ed., 2012, section
# 2.10): :math:`\sigma^2_\varepsilon = 15099` for the measurement and
# :math:`\sigma^2_\eta = 1469.1` for the level. statsmodels starts
# ``UnobservedComponents`` with an exact diffuse state when
# ``use_exact_diffuse=True``; ``prior="diffuse"`` is the same start in
# gaussfuse. The code checks that the predicted means, variances and 95%
# intervals of the next ten years agree to 1e-6 (relative).

years, flow = nile()
sigma2_eps, sigma2_eta = 15099.0, 1469.1
local_level = gf.LinearModel(F=1.0, H=1.0, Q=sigma2_eta, R=sigma2_eps)
ours = gf.forecast(local_level, gf.filter(local_level, "diffuse", flow), steps=10)
ours_lower, ours_upper = ours.interval(0.95)

try:
    import statsmodels.api as sm
except ImportError:
    print("statsmodels is not installed: no comparison")
else:
    uc = sm.tsa.UnobservedComponents(flow, "local level", use_exact_diffuse=True)
    assert uc.param_names == ["sigma2.irregular", "sigma2.level"]  # the order of the variances below
    theirs = uc.smooth([sigma2_eps, sigma2_eta]).get_forecast(steps=10)
    assert np.allclose(ours.measurement_means[:, 0], theirs.predicted_mean, rtol=1e-6, atol=0)
    assert np.allclose(ours.measurement_covs[:, 0, 0], theirs.var_pred_mean, rtol=1e-6, atol=0)
    assert np.allclose(np.column_stack([ours_lower[:, 0], ours_upper[:, 0]]), theirs.conf_int(alpha=0.05),
                       rtol=1e-6, atol=0)
    gap = np.max(np.abs(ours.measurement_means[:, 0] - theirs.predicted_mean) / np.abs(theirs.predicted_mean))
    print(f"largest relative difference from statsmodels in the predicted flow: {gap:.1e}")

print(f"flow in {years[-1] + 1}: {ours.measurement_means[0, 0]:.1f}, "
      f"95% interval [{ours_lower[0, 0]:.1f}, {ours_upper[0, 0]:.1f}] (10⁸ m³)")
