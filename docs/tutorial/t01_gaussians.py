"""
A belief is a Gaussian
======================

A Kalman filter never holds a single number for the quantity it estimates. It
holds a *belief*: a Gaussian :math:`N(m, P)` whose mean :math:`m` is the best
guess and whose variance (or covariance matrix) :math:`P` says how uncertain
that guess is. This page shows the one operation everything else is built on:
fusing two independent Gaussian beliefs about the same quantity, which is
their product, normalised. The Kalman update on the next page is this fusion
of a prediction with a measurement.
"""

import matplotlib.pyplot as plt
import numpy as np
from scipy.stats import norm

import gaussfuse as gf

# %%
# Two thermometers
# ----------------
#
# Two thermometers read the temperature of the same room. The first is cheap:
# it reads 20.0 °C with a standard deviation of 2 °C (variance 4). The second
# reads 22.5 °C with a standard deviation of 1 °C (variance 1). Each reading,
# taken alone, is a belief about the true temperature :math:`x`:
# :math:`N(m_1, P_1)` and :math:`N(m_2, P_2)`.
#
# If the two errors are independent, the probability of both readings given
# :math:`x` is the product of the two densities. As a function of :math:`x`,
# that product is again proportional to a Gaussian, with
#
# .. math::
#
#    m = \frac{m_1 P_2 + m_2 P_1}{P_1 + P_2}, \qquad
#    P = \frac{P_1 P_2}{P_1 + P_2},
#
# or, in *information form* (the inverse variance is the information),
#
# .. math::
#
#    \frac{1}{P} = \frac{1}{P_1} + \frac{1}{P_2}, \qquad
#    \frac{m}{P} = \frac{m_1}{P_1} + \frac{m_2}{P_2}.
#
# Information adds up. The mean is a weighted average in which each reading is
# weighted by the *other* one's variance: the precise thermometer counts more.
# We compute the formulas by hand, then with :func:`gaussfuse.fuse`, and check
# that the two agree and that the information form gives the same variance.

m1, P1 = 20.0, 4.0
m2, P2 = 22.5, 1.0

m_hand = (m1 * P2 + m2 * P1) / (P1 + P2)
P_hand = P1 * P2 / (P1 + P2)

fused = gf.fuse(gf.Gaussian(m1, P1), gf.Gaussian(m2, P2))
print(fused)
print(f"by hand: m = {m_hand:.4f}, P = {P_hand:.4f}")
print(f"information form: 1/P = {1 / P_hand:.4f} = 1/P1 + 1/P2 = {1 / P1 + 1 / P2:.4f}")

assert np.isclose(fused.mean[0], m_hand, rtol=1e-12)
assert np.isclose(fused.cov[0, 0], P_hand, rtol=1e-12)
assert np.isclose(1 / P_hand, 1 / P1 + 1 / P2, rtol=1e-12)

# %%
# The fused variance, 0.8, is smaller than both 4 and 1: two measurements
# together say more than the better one alone, whatever their values. This
# holds for any two positive variances: :math:`P = P_1 \cdot P_2 / (P_1 + P_2)`
# is below :math:`P_1` because :math:`P_2 / (P_1 + P_2) < 1`, and below
# :math:`P_2` for the same reason.

assert fused.cov[0, 0] < min(P1, P2)
print(f"fused std {fused.std[0]:.3f} °C, against {np.sqrt(P1):.3f} and {np.sqrt(P2):.3f} °C")

# %%
# The product of the densities
# ----------------------------
#
# We draw the two densities and their pointwise product. The product is
# normalised numerically (divided by its integral over the grid) and drawn
# against the density of the fused Gaussian: the two curves coincide, which
# the code checks to 1e-6.

x = np.linspace(12.0, 30.0, 2001)
p1 = norm.pdf(x, m1, np.sqrt(P1))
p2 = norm.pdf(x, m2, np.sqrt(P2))
product = p1 * p2
product /= np.trapezoid(product, x)
p_fused = norm.pdf(x, fused.mean[0], fused.std[0])
assert np.max(np.abs(product - p_fused)) < 1e-6

fig, ax = plt.subplots(figsize=(7.0, 3.5), layout="constrained")
ax.plot(x, p1, label=f"thermometer 1: N({m1}, {P1})")
ax.plot(x, p2, label=f"thermometer 2: N({m2}, {P2})")
ax.plot(x, p_fused, color="black", label=f"fused: N({fused.mean[0]:.2f}, {fused.cov[0, 0]:.2f})")
ax.plot(x[::80], product[::80], "o", color="black", markersize=3, label="product of the two, normalised")
ax.set_xlabel("temperature (°C)")
ax.set_ylabel("density (1/°C)")
ax.set_title("Fusing two readings: the product of two Gaussians")
ax.legend(fontsize="small")

# %%
# Two dimensions
# --------------
#
# The same holds for a vector. Two sensors locate an object in a plane; each
# gives a mean :math:`m_i` (in metres) and a 2 × 2 covariance :math:`P_i`. The
# first is precise along x and poor along y, the second the other way round.
# The fused belief is
#
# .. math::
#
#    K = P_1 (P_1 + P_2)^{-1}, \qquad
#    m = m_1 + K (m_2 - m_1) = (I - K)\, m_1 + K\, m_2, \qquad
#    P = (I - K) P_1,
#
# and again, in information form,
# :math:`P^{-1} = P_1^{-1} + P_2^{-1}` and
# :math:`P^{-1} m = P_1^{-1} m_1 + P_2^{-1} m_2`.
#
# The *gain* :math:`K` is the matrix of weights: the fused mean takes
# :math:`K` of the second sensor and :math:`I - K` of the first. In one
# dimension :math:`K = P_1 / (P_1 + P_2)`, the scalar weight above. A matrix
# weight can do more than a scalar one: it takes x mostly from the sensor
# that is good at x, and y from the one that is good at y.

m1 = np.array([1.0, 2.0])
P1 = np.array([[0.2, 0.1], [0.1, 3.0]])
m2 = np.array([1.8, 0.5])
P2 = np.array([[2.5, -0.4], [-0.4, 0.3]])

K = np.linalg.solve(P1 + P2, P1).T          # P1 (P1 + P2)^-1, both symmetric
m_hand = m1 + K @ (m2 - m1)
P_hand = (np.eye(2) - K) @ P1

fused = gf.fuse(gf.Gaussian(m1, P1), gf.Gaussian(m2, P2))
print("gain K =\n", K.round(4))
print("fused mean:", fused.mean.round(4))
print("fused covariance:\n", fused.cov.round(4))

assert np.allclose(fused.mean, m_hand, rtol=1e-12, atol=1e-12)
assert np.allclose(fused.cov, P_hand, rtol=1e-12, atol=1e-12)
info = np.linalg.inv(P1) + np.linalg.inv(P2)
assert np.allclose(np.linalg.inv(info), fused.cov, rtol=1e-10, atol=1e-12)
assert np.allclose(np.linalg.solve(info, np.linalg.solve(P1, m1) + np.linalg.solve(P2, m2)), fused.mean,
                   rtol=1e-10, atol=1e-12)

# %%
# The gain's diagonal is near 0 for x (keep the first sensor's x) and near 1
# for y (take the second sensor's y). The fused covariance is again smaller
# than each input: :math:`P_1 - P` and :math:`P_2 - P` are positive
# semi-definite, which the code checks through their eigenvalues. The figure
# draws the 2σ ellipse of each belief.

for name, P_in in (("P1 - P", P1), ("P2 - P", P2)):
    eigenvalues = np.linalg.eigvalsh(P_in - fused.cov)
    print(f"eigenvalues of {name}: {eigenvalues.round(4)}")
    assert eigenvalues.min() > -1e-12

angle = np.linspace(0.0, 2 * np.pi, 200)
circle = np.stack([np.cos(angle), np.sin(angle)])
fig, ax = plt.subplots(figsize=(5.5, 5.0), layout="constrained")
for label, mean, cov in (("sensor 1", m1, P1), ("sensor 2", m2, P2), ("fused", fused.mean, fused.cov)):
    ellipse = mean[:, None] + 2.0 * np.linalg.cholesky(cov) @ circle
    (line,) = ax.plot(*ellipse, label=f"{label} (2σ)")
    ax.plot(*mean, "o", color=line.get_color())
ax.set(xlabel="x (m)", ylabel="y (m)", aspect="equal", title="Fusing two 2-D beliefs")
ax.legend(fontsize="small")
