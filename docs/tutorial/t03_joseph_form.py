r"""
Why this gain, and the Joseph form
==================================

The update of the previous page moves the prediction by :math:`K v`, with the
gain :math:`K = P^- H^\top S^{-1}`. Any other matrix :math:`K` would also give
an estimate :math:`m^- + K v`; this page shows in what sense the Kalman gain is
the best one, and why gaussfuse computes the posterior covariance in the
longer *Joseph form* rather than the short :math:`(I - K H) P^-`.
"""

from fractions import Fraction

import matplotlib.pyplot as plt
import numpy as np

import gaussfuse as gf
from gaussfuse import kalman

# %%
# The covariance of any gain
# --------------------------
#
# Let the prediction error :math:`e^- = x - m^-` have covariance :math:`P^-`,
# and the measurement :math:`z = H x + w` a noise :math:`w \sim N(0, R)`
# independent of it. The estimate :math:`m = m^- + K (z - H m^-)` has the
# error :math:`x - m = (I - K H) e^- - K w`, a sum of two independent terms,
# so its covariance is, for *any* gain :math:`K`,
#
# .. math::
#
#    P(K) = (I - K H) P^- (I - K H)^\top + K R K^\top.
#
# This is the Joseph form. Expanding it, with :math:`S = H P^- H^\top + R`,
#
# .. math::
#
#    \operatorname{tr} P(K) = \operatorname{tr} P^- - 2 \operatorname{tr}(K H P^-)
#    + \operatorname{tr}(K S K^\top).
#
# The trace is the expected squared error :math:`E\lVert x - m \rVert^2`.
# Using :math:`\partial \operatorname{tr}(K A) / \partial K = A^\top` and
# :math:`\partial \operatorname{tr}(K S K^\top) / \partial K = 2 K S` for a
# symmetric :math:`S`,
#
# .. math::
#
#    \frac{\partial \operatorname{tr} P(K)}{\partial K} = -2 P^- H^\top + 2 K S = 0
#    \quad\Longrightarrow\quad K^* = P^- H^\top S^{-1}.
#
# It is the minimum, since :math:`S` is positive definite: for any change
# :math:`\Delta` of the gain the cross terms cancel (:math:`K^* S = P^- H^\top`)
# and :math:`\operatorname{tr} P(K^* + \Delta) = \operatorname{tr} P(K^*)
# + \operatorname{tr}(\Delta S \Delta^\top)`.
#
# We check this on page 2's first prediction, with a sensor of both position
# (variance 10) and velocity (variance 2), along three directions :math:`D`.
# :func:`gaussfuse.kalman.update` takes a ``gain=`` to apply instead of the
# optimal one, and returns its Joseph-form covariance (checked).

P_pred, m_pred = np.array([[1001.0, 500.0], [500.0, 503.0]]), np.array([1.0, 1.0])
H, R, z = np.eye(2), np.diag([10.0, 2.0]), np.array([1.5, 0.8])
S = H @ P_pred @ H.T + R
K_opt = kalman.update(m_pred, P_pred, z, H, R).gain
frac = np.vectorize(Fraction, otypes=[object])  # exact rational copies of float64 arrays


def joseph(K, P=P_pred, H=H, R=R):
    I_KH = np.eye(len(P), dtype=P.dtype) - K @ H  # also on Fraction (object) arrays
    return I_KH @ P @ I_KH.T + K @ R @ K.T


D_wrong = np.array([[0.1, -0.2], [0.3, 0.05]])
assert np.allclose(kalman.update(m_pred, P_pred, z, H, R, gain=K_opt + D_wrong).cov, joseph(K_opt + D_wrong))

eps = np.linspace(-0.3, 0.3, 121)
directions = {"position gain": np.diag([1.0, 0.0]), "velocity gain": np.diag([0.0, 1.0]),
              "mixed": np.array([[0.5, -1.0], [0.8, 0.3]]) / np.sqrt(1.98)}
fig, ax = plt.subplots(figsize=(7.0, 3.8), layout="constrained")
for name, D in directions.items():
    traces = np.array([np.trace(joseph(K_opt + e * D)) for e in eps])
    assert eps[np.argmin(traces)] == 0.0
    assert np.allclose(traces, np.trace(joseph(K_opt)) + eps**2 * np.trace(D @ S @ D.T), rtol=1e-10)
    ax.plot(eps, traces, label=f"{name}: curvature tr(D S Dᵀ) = {np.trace(D @ S @ D.T):.0f}")
ax.axvline(0.0, color="0.5", linestyle=":")
ax.set(xlabel="ε (gain K* + ε D)", ylabel="trace of P(K)",
       title="The Kalman gain minimises the expected squared error")
ax.legend(fontsize="small")

# %%
# Each curve is a parabola with its minimum at :math:`\varepsilon = 0`
# (checked on the grid, and every point equals :math:`\operatorname{tr} P(K^*)
# + \varepsilon^2 \operatorname{tr}(D S D^\top)` to 1e-10). A simulation of
# 200,000 states and noises confirms that the Joseph form is the error
# covariance of a wrong gain :math:`K^* + \Delta` (checked: every entry
# within 2 % of its trace); the short form :math:`(I - K H) P^-` is not, and
# is not even symmetric.

rng, K_bad = np.random.default_rng(0), K_opt + D_wrong
x, w = rng.multivariate_normal(m_pred, P_pred, 200_000), rng.multivariate_normal(np.zeros(2), R, 200_000)
errors = x - (m_pred + (x @ H.T + w - H @ m_pred) @ K_bad.T)
sample_cov = np.cov(errors.T)
for name, C in (("sample covariance", sample_cov), ("Joseph form", joseph(K_bad)),
                ("short form", (np.eye(2) - K_bad @ H) @ P_pred)):
    print(f"{name:17s}", C.round(2).tolist())
assert np.abs(sample_cov - joseph(K_bad)).max() < 0.02 * np.trace(joseph(K_bad))

# %%
# With the optimal gain the two forms agree in exact arithmetic (a term
# cancels), but a computed gain is never exactly optimal, and that matters.
#
# A gain wrong in the last digits
# -------------------------------
#
# An ill-conditioned update: prior variances of :math:`10^{12}` on two
# correlated components, and a sensor of variance :math:`10^{-6}` on the
# first. Both forms get the float64 gain with its entries multiplied by
# :math:`1 + \delta` and :math:`1 - \delta` (:math:`\delta = 0`: the gain as
# computed). The reference, the true error covariance of that gain, is its
# Joseph form in exact rational arithmetic (:class:`fractions.Fraction`, on
# the same float64 inputs). The eigenvalue is that of :math:`(P + P^\top)/2`.

P_big, H1, R1 = 1e12 * np.array([[1.0, 0.9], [0.9, 1.0]]), np.array([[1.0, 0.0]]), np.array([[1e-6]])
K_big = kalman.update(np.zeros(2), P_big, np.zeros(1), H1, R1).gain

print(" delta   form    P[0,0]     P[0,1]     P[1,0]  asymmetry  min eigenvalue  max error")
for delta in (1e-6, 1e-12, 0.0):
    K = K_big * np.array([[1.0 + delta], [1.0 - delta]])
    exact = joseph(frac(K), frac(P_big), frac(H1), frac(R1)).astype(float)
    short = (np.eye(2) - K @ H1) @ P_big
    for name, P in (("short", short), ("Joseph", joseph(K, P_big, H1, R1))):
        lam = np.linalg.eigvalsh((P + P.T) / 2).min()
        print(f"{delta:6.0e} {name:6s} {P[0, 0]:10.3e} {P[0, 1]:10.3e} {P[1, 0]:10.3e} "
              f"{abs(P[0, 1] - P[1, 0]):10.3e} {lam:15.3e} {np.abs(P - exact).max():10.3e}")
        if name == "Joseph":
            assert abs(P[0, 1] - P[1, 0]) <= 1e-15 * np.abs(P).max() and lam > 0
            assert np.allclose(P[0, :], exact[0, :], rtol=1e-6)
    print(f"{'':6s} exact  {exact[0, 0]:10.3e} {exact[0, 1]:10.3e} {exact[1, 0]:10.3e}")
    assert abs(short[0, 0] - exact[0, 0]) >= 0.99 * exact[0, 0]  # the short form's variance: 99-100 % off
    if delta > 0:
        assert np.linalg.eigvalsh((short + short.T) / 2).min() < 0
        assert abs(short[0, 1] - short[1, 0]) > 1000 * abs(exact[0, 1])

# %%
# With :math:`\delta = 10^{-6}` the gain error costs a position variance of
# about :math:`\delta^2 P^-_{00} = 1`: the Joseph form reports it, like the
# exact computation; the short form reports about :math:`-10^6`, a negative
# variance. With :math:`\delta = 10^{-12}` it reports about -1 for a true
# :math:`10^{-6}`, and with the float64 gain exactly 0, a position known
# perfectly (here with two different off-diagonal entries). Checked: the
# short form's position variance is at least 99 % off at every
# :math:`\delta`, and for :math:`\delta > 0` the matrix is indefinite and
# asymmetric by over 1000 times the exact off-diagonal entry; the Joseph form
# is symmetric to round-off (:math:`10^{-15}` of its largest entry), positive
# definite, and its first row within a relative :math:`10^{-6}` of the exact
# one. The reason: a gain error :math:`\Delta` changes the short form by
# :math:`-\Delta H P^-` (first order), the Joseph form by
# :math:`\Delta S \Delta^\top` (second order), as the parabola showed.
#
# What gaussfuse does
# -------------------
#
# :func:`gaussfuse.kalman.update`, used (as written, or compiled) by every
# covariance-form filter in the library, computes the gain by Cholesky solves with :math:`S` (never an explicit
# inverse) and the posterior in the Joseph form, symmetrised. It is not proof
# against every round-off: see :doc:`/accuracy` and the README's section "When
# covariances are not accurate enough", whose example (:math:`P_0 = 10^{12} I`,
# :math:`R = 10^{-6}`, :math:`Q = 0`) we run in both forms against the exact
# filter. ``form="sqrt"`` propagates Cholesky factors by orthogonal
# transformations, so no covariance is ever formed or subtracted.

F = np.array([[1.0, 1.0], [0.0, 1.0]])
model, zs = gf.LinearModel(F=F, H=H1, Q=np.zeros((2, 2)), R=R1), [3.0, 4.0, 5.0, 6.0]
prior = gf.Gaussian([0.0, 0.0], 1e12 * np.eye(2))
cov_form = gf.filter(model, prior, zs)
sqrt_form = gf.filter(model, prior, zs, form="sqrt")

P, Ff, Hf, Rf = frac(prior.cov), frac(F), frac(H1), frac(R1)
rel_err = {"cov": [], "sqrt": []}
print("step  exact variances          rel. error, cov form   rel. error, sqrt form")
for k in range(len(zs)):
    P = Ff @ P @ Ff.T
    Kf = P @ Hf.T / (Hf @ P @ Hf.T + Rf)[0, 0]
    P = P - Kf @ Hf @ P
    exact = np.diag(P.astype(float))
    for form, res in (("cov", cov_form), ("sqrt", sqrt_form)):
        rel_err[form].append(np.abs(np.diag(res.covs[k]) - exact) / exact)
    print(f"{k + 1:4d}  {exact[0]:.3e} {exact[1]:.3e}    {rel_err['cov'][k][0]:.1e} {rel_err['cov'][k][1]:.1e}"
          f"             {rel_err['sqrt'][k][0]:.1e} {rel_err['sqrt'][k][1]:.1e}")
for form, res in (("cov", cov_form), ("sqrt", sqrt_form)):
    print(f"smallest eigenvalues, {form} form:", [f"{np.linalg.eigvalsh(C).min():.1e}" for C in res.covs])
assert np.max(rel_err["cov"]) > 0.1 and np.max(rel_err["sqrt"]) < 1e-5
assert all(np.linalg.eigvalsh(C).min() > 0 for C in sqrt_form.covs)

# %%
# The first update is right in both forms. From the second on, the covariance
# form's velocity variance is tens of percent off (checked: over 10 %) and,
# here, its smallest eigenvalue is slightly negative; the square-root form
# stays within :math:`10^{-5}` of the exact variances and positive definite
# (checked). Keep the default ``form="cov"``, which is faster, unless the
# prior variance is many orders of magnitude above the sensor's.
