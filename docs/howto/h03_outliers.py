r"""
Rejecting outliers
==================

How do I stop a few wild measurements from dragging the estimate away? Pass
``gate=0.99`` to :func:`gaussfuse.filter` or :func:`gaussfuse.smooth`. Before
each update, the filter compares the measurement with its prediction. If the
normalised innovation squared :math:`v^\top S^{-1} v` is beyond the 0.99
quantile of the chi-square distribution, the measurement is treated as
missing (:class:`gaussfuse.kalman.Gate` does the test). ``result.rejected``
(shape (T, m)) says which components were rejected. With
``gate_by="component"`` each component is tested on its own
(:math:`v_i^2 / S_{ii}` against :math:`\chi^2_1`), so a glitch in x does not
throw away a good y.

A gate at 0.99 rejects 1% of good measurements tested against a consistent
prediction: that is the price of the test. In a filter, each rejection makes
the next predictions more confident than they should be, so on long series
it rejects more (about 2% for this page's model), sometimes several in a
row. It relies on the filter's own covariances, so it needs a model
whose Q and R are about right (see
:ref:`Tuning Q and R <sphx_glr_auto_howto_h02_tuning_q_and_r.py>`).
"""

import matplotlib.pyplot as plt
import numpy as np

import gaussfuse as gf
from gaussfuse.diagnostics import rmse
from gaussfuse.plotting import plot_series

# %%
# A track with glitches
# ---------------------
#
# A target moves in the plane with nearly constant velocity, and a sensor
# measures its position every second with a standard deviation of 1 m. We add
# 15 glitches of 10 to 30 m: some in x only, some in y only, some in both.

model = gf.model(gf.ConstantVelocity(dim=2, q=0.1), gf.Position(dim=2, r=1.0), dt=1.0)
prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.diag([1.0, 1.0, 0.1, 0.1]))
T = 300
sim = gf.simulate(model, prior, T, rng=1)
truth, zs = sim.states, sim.measurements.copy()

rng = np.random.default_rng(2)
glitches = np.sort(rng.choice(np.arange(5, T), size=15, replace=False))
hit = np.zeros((T, 2), dtype=bool)                      # which components are glitched
for k, axes in zip(glitches, rng.integers(0, 3, size=15)):
    hit[k] = [axes != 1, axes != 0]                     # 0: x only, 1: y only, 2: both
    zs[k] += np.where(hit[k], rng.choice([-1.0, 1.0], 2) * rng.uniform(10.0, 30.0, 2), 0.0)
print("glitches at steps", glitches)

# %%
# With and without the gate
# -------------------------
#
# Without the gate, the glitches make the filter's innovations too large for
# its covariances, and its divergence check would warn. That warning is
# right, but here we want to measure the error, so we pass ``check="off"`` to
# the runs without a gate. The code checks that the gate lowers the RMSE of
# the position, for the filter and for the smoother.

plain = gf.filter(model, prior, zs, check="off")
gated = gf.filter(model, prior, zs, gate=0.99)
by_component = gf.filter(model, prior, zs, gate=0.99, gate_by="component")
plain_smooth = gf.smooth(model, prior, zs, check="off")
gated_smooth = gf.smooth(model, prior, zs, gate=0.99)

errors = {
    "filter, no gate": rmse(plain.means[:, :2], truth[:, :2]),
    "filter, gate by measurement": rmse(gated.means[:, :2], truth[:, :2]),
    "filter, gate by component": rmse(by_component.means[:, :2], truth[:, :2]),
    "smoother, no gate": rmse(plain_smooth.means[:, :2], truth[:, :2]),
    "smoother, gate by measurement": rmse(gated_smooth.means[:, :2], truth[:, :2]),
    "raw measurements": rmse(zs, truth[:, :2]),
}
for name, value in errors.items():
    print(f"{name:<30} RMSE {value:6.3f} m")
assert errors["filter, gate by measurement"] < errors["filter, no gate"]
assert errors["filter, gate by component"] < errors["filter, no gate"]
assert errors["smoother, gate by measurement"] < errors["smoother, no gate"]

# %%
# What was rejected
# -----------------
#
# Gating by measurement rejects both components of a step together. Every
# glitch is caught (checked), and a few good measurements are rejected as
# well, as a gate at 0.99 must. Gating by component tests 600 components
# instead of 300 measurements, so it rejects a few more good ones, but at a
# glitch in one coordinate it keeps the other (checked).

for name, res, bad in [("by measurement", gated, hit.any(axis=1)), ("by component", by_component, hit)]:
    rejected = res.rejected if res is by_component else res.rejected.any(axis=1)
    unit = "measurements" if rejected.ndim == 1 else "components"
    print(f"gate {name}: {np.sum(rejected & bad)} of {np.sum(bad)} glitched {unit} rejected, "
          f"{np.sum(rejected & ~bad)} of {np.sum(~bad)} good {unit} rejected")
    assert np.all(rejected[bad])

assert np.sum(by_component.rejected & ~hit) > np.sum(gated.rejected.any(axis=1) & ~hit.any(axis=1))
assert np.array_equal(gated.rejected[:, 0], gated.rejected[:, 1])
one_axis = glitches[hit[glitches].sum(axis=1) == 1]
print("steps glitched in one coordinate:", one_axis)
print("rejected there, by component (x, y):", by_component.rejected[one_axis].astype(int).tolist())
assert np.array_equal(by_component.rejected[one_axis], hit[one_axis])

# %%
# The online filter takes the same gate in ``update(z, gate=0.99)`` and
# reports ``rejected`` after each update. The code checks that it rejects
# the same measurements as the batch filter.

online = gf.KalmanFilter(model, prior)
online_rejected = []
for z in zs:
    online.predict()
    online.update(z, gate=0.99)
    online_rejected.append(online.rejected)
assert np.array_equal(np.array(online_rejected), gated.rejected)

# %%
# The figure shows the x coordinate over 90 steps. The filter without a gate
# jumps towards each glitch in x and needs several steps to recover; the
# gated filter ignores it. The gate rejects whole measurements, so the steps
# glitched in y only are circled too, with a good x.

window = slice(20, 110)
steps = np.arange(T)[window]
fig, ax = plt.subplots(figsize=(7.5, 3.8), layout="constrained")
plot_series(steps, plain.means[window], plain.covs[window], ax=ax, label="no gate")
plot_series(steps, gated.means[window], gated.covs[window], zs=zs[window], truth=truth[window], ax=ax,
            label="gate=0.99", xlabel="step", ylabel="x", unit="m")
out = gated.rejected[window, 0]
ax.plot(steps[out], zs[window][out, 0], "o", mfc="none", color="crimson", markersize=9, label="rejected")
ax.legend(loc="upper left", fontsize="small")
ax.set_title("Outlier gating: x coordinate")
plt.show()
