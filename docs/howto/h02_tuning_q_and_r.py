r"""
Tuning Q and R
==============

How do I choose the process noise Q and the measurement noise R? There are
three ways, and they work best together. First, derive them from the
physics: R from the sensor's accuracy, Q from how much the motion can
change over a step (for a constant-velocity model, one number q). Second,
check the choice on data with the normalised innovation squared (NIS): a
filter whose Q and R are right has an average NIS inside a chi-square
interval, one whose Q is too small lies above it and one whose Q is too
large below it. Third, when there is enough data, learn them by maximum
likelihood with :func:`gaussfuse.fit`.
"""

import matplotlib.pyplot as plt
import numpy as np

import gaussfuse as gf
from gaussfuse.diagnostics import chi2_interval, consistency, divergence, nis
from gaussfuse.plotting import plot_consistency

# %%
# From the physics
# ----------------
#
# R is the variance of the sensor's error: a position sensor good to a
# standard deviation of 1 m has ``r = 1`` (m²).
#
# A constant-velocity model drives the velocity with white-noise
# acceleration of spectral density q (m²/s³). Over a time :math:`\tau` the
# velocity then changes by a random amount of variance :math:`q \tau`. So if
# the speed wanders by about 0.3 m/s over 0.5 s, take
# :math:`q \approx 0.3^2 / 0.5 \approx 0.2`. Integrated over a step
# :math:`\Delta t`, this gives the process noise
#
# .. math::
#
#    Q = q \begin{bmatrix} \Delta t^3/3 & \Delta t^2/2 \\
#        \Delta t^2/2 & \Delta t \end{bmatrix}.
#
# ``gf.constant_velocity(dt, q, r)`` builds the model, and
# ``gf.continuous_white_noise(1, dt, q)`` gives Q alone. The code checks that
# the two agree with the formula.

dt, q, r = 0.5, 0.2, 1.0
model = gf.constant_velocity(dt, q, r)
by_hand = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
assert np.allclose(model.Q, by_hand, rtol=1e-14, atol=0)
assert np.allclose(gf.continuous_white_noise(1, dt, q), by_hand, rtol=1e-14, atol=0)
print(f"Q =\n{model.Q}\nR = {model.R}")

# %%
# Checking with the NIS
# ---------------------
#
# At each step the filter predicts the measurement with a covariance
# :math:`S_k`. If the model is right, the innovation :math:`v_k` (measurement
# minus prediction) is :math:`N(0, S_k)`, so the NIS
# :math:`v_k^\top S_k^{-1} v_k` is chi-square with m degrees of freedom
# (here m = 1) and averages 1. The average over K independent values has a
# known 95% interval, :func:`~gaussfuse.diagnostics.chi2_interval`.
#
# We simulate 10 runs of 100 steps from the model above, then filter them
# with q a hundred times too small, right, and a hundred times too large.
# The filters' own divergence check would warn for the too-small q; here we
# want to measure that ourselves, so we pass ``check="off"``.

prior = gf.Gaussian([0.0, 1.0], np.diag([1.0, 0.25]))
sim = gf.simulate(model, prior, 100, size=10, rng=3)
candidates = {"q / 100": q / 100, "q": q, "100 q": 100 * q}
results = {name: gf.filter(gf.constant_velocity(dt, value, r), prior, sim.measurements, check="off")
           for name, value in candidates.items()}

# %%
# :func:`~gaussfuse.diagnostics.consistency` averages the NIS over every step
# and run and compares it with the interval. The values are those of
# ``res.nis``, which :func:`~gaussfuse.diagnostics.nis` recomputes from the
# innovations (checked). :func:`~gaussfuse.diagnostics.divergence` is the
# test behind the filters' warning: it lists the windows of 50 steps whose
# NIS is too large for a consistent filter.

low, high = chi2_interval(1, count=sim.measurements.shape[0] * sim.measurements.shape[1])
print(f"95% interval of the average NIS: [{low:.3f}, {high:.3f}]")
print(f"{'model':>8} {'NIS':>7}  verdict        series flagged by divergence()")
reports = {}
for name, res in results.items():
    assert np.allclose(nis(res.innovations, res.innovation_covs), res.nis, rtol=1e-12)
    report = reports[name] = consistency(res)
    assert np.isclose(report.nis_interval[0], low) and np.isclose(report.nis_interval[1], high)
    verdict = "consistent" if report.nis_ok else "overconfident" if report.nis > high else "too cautious"
    flagged = {series for series, *_ in divergence(res.nis, np.ones_like(res.nis))}
    print(f"{name:>8} {report.nis:7.3f}  {verdict:<14} {len(flagged)} of {res.nis.shape[0]}")

# %%
# The code checks the three verdicts: the right q is inside the interval,
# the small one above it (the filter trusts its prediction too much) and the
# large one below (it trusts it too little).

assert reports["q"].nis_ok
assert reports["q / 100"].nis > high
assert reports["100 q"].nis < low

# %%
# :func:`~gaussfuse.plotting.plot_consistency` draws the NIS of each step
# (averaged over the 10 runs), its overall average and the interval. The
# interval is that of the overall average of 1,000 values; the average of
# each step, over only 10 values, scatters much more widely, as it should.

fig, axes = plt.subplots(3, 1, figsize=(7, 7.5), sharex=True, layout="constrained")
for ax, (name, res) in zip(axes, results.items()):
    plot_consistency(res.nis, (low, high), kind=f"NIS, {name}", ax=ax)
plt.show()

# %%
# Learning q and r from the data
# ------------------------------
#
# :func:`gaussfuse.fit` with ``method="mle"`` maximises the log-likelihood of
# the measurements. By default (``learn=("Q", "R")``) it learns every entry
# of Q and R. Here we want only the two numbers q and r, so we give it
# ``params``: a function from a parameter vector to the model. Logarithms
# keep both positive. The 10 runs are pooled into one fit, starting from
# q = 1, r = 3.


def cv_model(theta):
    return gf.constant_velocity(dt, np.exp(theta[0]), np.exp(theta[1]))


fit = gf.fit(cv_model(np.log([1.0, 3.0])), prior, sim.measurements, method="mle",
             params=cv_model, x0=np.log([1.0, 3.0]))
assert fit.converged

# %%
# The standard errors are those of the logarithms, so the 95% intervals are
# :math:`\exp(\hat\theta \pm 1.96\, \mathrm{se})`. The code checks that each
# interval holds the true value.

print(f"{'':>3} {'truth':>7} {'fitted':>8} {'95% interval':>20}")
for i, (name, true) in enumerate([("q", q), ("r", r)]):
    theta, se = fit.params[f"theta[{i}]"], fit.bse[f"theta[{i}]"]
    lo, hi = np.exp(theta - 1.96 * se), np.exp(theta + 1.96 * se)
    print(f"{name:>3} {true:7.3f} {np.exp(theta):8.3f} {f'[{lo:.3f}, {hi:.3f}]':>20}")
    assert lo <= true <= hi
