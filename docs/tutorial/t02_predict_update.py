"""
The Kalman filter: predict and update
=====================================

A Kalman filter tracks a state that changes in time, such as the position and
velocity of a cart, from noisy measurements of part of it. It keeps a
Gaussian belief :math:`N(m, P)` about the state and repeats two steps for
every measurement: *predict* moves the belief forward through the dynamics
and makes it less certain; *update* fuses the prediction with the
measurement, as two Gaussians were fused on the previous page, and makes it
more certain. This page writes out both steps, runs them on the textbook
position–velocity example, and checks one step by hand.
"""

import matplotlib.pyplot as plt
import numpy as np

import gaussfuse as gf
from gaussfuse import cli, kalman
from gaussfuse.plotting import plot_measurements

# %%
# The model
# ---------
#
# The state :math:`x_k` holds the position and the velocity at step k. Over
# one time step the position grows by the velocity; a control input
# :math:`u_k` (here a commanded acceleration) can push both; and a random
# disturbance :math:`w_k \sim N(0, Q)` covers what the model leaves out. A
# sensor measures the position with noise :math:`v_k \sim N(0, R)`:
#
# .. math::
#
#    x_k = F x_{k-1} + B u_k + w_k, \qquad z_k = H x_k + v_k.
#
# The textbook example (the one ``gaussfuse demo`` prints,
# :func:`gaussfuse.cli.textbook_example`) has no control input:
# :math:`F = [[1, 1], [0, 1]]`, :math:`H = [1, 0]`, :math:`Q = \mathrm{diag}(1, 3)`,
# :math:`R = 10`, the prior :math:`N([0, 1], 500 I)` and the measurements
# 1, 2, 3, 2, 1. The prior describes the state one step *before* the first
# measurement, so every step is predict, then update.

F = np.array([[1.0, 1.0], [0.0, 1.0]])
H = np.array([[1.0, 0.0]])
Q = np.diag([1.0, 3.0])
R = np.array([[10.0]])
model = gf.LinearModel(F=F, H=H, Q=Q, R=R)
prior = gf.Gaussian(mean=[0.0, 1.0], cov=500.0 * np.eye(2))
zs = np.array([1.0, 2.0, 3.0, 2.0, 1.0])

res = gf.filter(model, prior, zs)

print(" step     z  position  velocity  std(position)")
for k, (z, m, P) in enumerate(zip(zs, res.means, res.covs), start=1):
    print(f"{k:5d} {z:5.1f} {m[0]:9.4f} {m[1]:9.4f} {np.sqrt(P[0, 0]):14.4f}")

zs_cli, res_cli = cli.textbook_example()
assert np.array_equal(zs_cli, zs)
assert np.allclose(res.means, res_cli.means, rtol=0, atol=1e-12)
assert np.allclose(res.covs, res_cli.covs, rtol=0, atol=1e-12)
assert np.all(np.sqrt(res.covs[:, 0, 0]) < np.sqrt(R[0, 0]))  # below one measurement's std
assert np.allclose(res.innovations[:3], 0.0) and res.means[-1, 1] < 0

# %%
# The filter's numbers equal those of :func:`gaussfuse.cli.textbook_example`
# (checked). The first three measurements lie exactly on the line the prior
# predicts (a velocity of 1: the innovations are 0, checked), so the estimate
# does not leave it; the fourth and fifth pull it back, and the velocity
# estimate turns negative (checked).
# The position's standard deviation falls from the prior's
# :math:`\sqrt{500} \approx 22` to below the sensor's
# :math:`\sqrt{R} \approx 3.16` at every step (checked): the filter knows
# more than any single measurement.
#
# Predict
# -------
#
# The predicted belief about :math:`x_k` follows from the linear map:
#
# .. math::
#
#    m^-_k = F m_{k-1} + B u_k, \qquad P^-_k = F P_{k-1} F^\top + Q.
#
# Update
# ------
#
# The measurement is compared with its prediction :math:`H m^-_k`; the
# difference is the *innovation* :math:`v_k = z_k - H m^-_k`, with covariance
# :math:`S_k = H P^-_k H^\top + R`. Then
#
# .. math::
#
#    K_k = P^-_k H^\top S_k^{-1}, \qquad
#    m_k = m^-_k + K_k v_k, \qquad
#    P_k = (I - K_k H) P^-_k.
#
# With :math:`H = I` this is exactly the fusion of two Gaussians from the
# previous page. (gaussfuse computes :math:`P_k` in the equivalent Joseph
# form, the subject of the next page.) We do the first step by hand with
# NumPy and check it against the filter's first step, and against
# :func:`gaussfuse.kalman.predict` and :func:`gaussfuse.kalman.update`.


def step_by_hand(m, P, z):
    m_pred = F @ m
    P_pred = F @ P @ F.T + Q
    v = z - H @ m_pred
    S = H @ P_pred @ H.T + R
    K = P_pred @ H.T @ np.linalg.inv(S)
    return m_pred, P_pred, m_pred + K @ v, (np.eye(2) - K @ H) @ P_pred, K


m_pred, P_pred, m1, P1, K1 = step_by_hand(prior.mean, prior.cov, zs[:1])
print("predicted mean", m_pred, "\npredicted covariance\n", P_pred)
print("gain", K1.ravel().round(5), "\nfiltered mean", m1, "\nfiltered covariance\n", P1.round(5))

assert np.allclose(m_pred, res.predicted_means[0], rtol=1e-12)
assert np.allclose(P_pred, res.predicted_covs[0], rtol=1e-12)
assert np.allclose(m1, res.means[0], rtol=1e-12)
assert np.allclose(P1, res.covs[0], rtol=1e-10)

# The same step with the library's two functions (arrays in, arrays out).
m_pred2, P_pred2 = kalman.predict(prior.mean, prior.cov, F, Q)
up = kalman.update(m_pred2, P_pred2, zs[:1], H, R)
print("kalman.update: mean", up.mean, "innovation", up.innovation, "S", up.innovation_cov.ravel())
assert np.allclose(m_pred2, m_pred) and np.allclose(P_pred2, P_pred)
assert np.allclose(up.mean, m1, rtol=1e-12) and np.allclose(up.cov, P1, rtol=1e-10)
assert np.allclose(up.gain, K1, rtol=1e-12)

# %%
# In this first step the innovation is 0, so only the covariance changes.
# The fourth step has a real innovation (the measurement 2 against a
# predicted 4); the same function, started from the filter's third belief,
# gives its fourth.

*_, m4, P4, K4 = step_by_hand(res.means[2], res.covs[2], zs[3:4])
print("step 4: innovation", res.innovations[3], "gain", K4.ravel().round(4), "mean", m4.round(4))
assert np.allclose(m4, res.means[3], rtol=1e-10) and np.allclose(P4, res.covs[3], rtol=1e-10)

# %%
# The gain is a trust weight
# --------------------------
#
# The gain decides how far the estimate moves towards the measurement. Take
# the first step's prediction and vary the sensor's variance R: a precise
# sensor (small R) gives a position gain near 1, so the estimate jumps to the
# measurement; a poor one (large R) gives a gain near 0, and the prediction
# is kept (checked: from above 0.99 down to below 0.01 as R grows). The
# velocity, which is not measured, is corrected through its covariance with
# the position. The position gain is :math:`P^-_{00} / (P^-_{00} + R)`, the
# weight of page 1's fusion.

position_gains = []
for r in (0.1, 10.0, 1000.0, 1e5):
    K = kalman.update(m_pred, P_pred, zs[:1], H, np.array([[r]])).gain.ravel()
    position_gains.append(K[0])
    print(f"R = {r:8g}: gain on position {K[0]:.4f}, on velocity {K[1]:.4f}")
assert position_gains[0] > 0.99 and position_gains[-1] < 0.01 and np.all(np.diff(position_gains) < 0)

# %%
# A control input
# ---------------
#
# With a known input, give the model its matrix ``B`` and the filter the
# inputs ``us``. Here :math:`u_k` is a commanded acceleration (m/s²) over a
# step of 1 s, so :math:`B = [1/2, 1]^\top`. The prediction of step k is
# :math:`F m_{k-1} + B u_k` (checked at step 4, the first with a nonzero
# input); with all inputs zero the filter is the textbook one again
# (checked).

controlled = gf.LinearModel(F=F, H=H, Q=Q, R=R, B=[0.5, 1.0])
us = np.array([0.0, 0.0, 0.0, -1.0, -1.0])
res_u = gf.filter(controlled, prior, zs, us=us)
print("with braking at steps 4 and 5: positions", res_u.means[:, 0].round(3))
assert np.allclose(res_u.predicted_means[3], F @ res_u.means[2] + np.array([0.5, 1.0]) * us[3])
assert np.allclose(gf.filter(controlled, prior, zs, us=np.zeros(5)).means, res.means, atol=1e-12)

# %%
# Measurements against estimates
# ------------------------------
#
# :func:`gaussfuse.plotting.plot_measurements` draws the measurements with
# the estimated measurement :math:`H m_k` and its band of
# :math:`\pm 2\sqrt{H P_k H^\top}`.

fig = plot_measurements(np.arange(1, 6), zs, res.means, res.covs, model.H, label="filtered",
                        names=["position"], units="m", time_unit="s",
                        title="Textbook example: position measurements and filtered estimates")
