"""When the covariance is kept as the fixed point (kalman.settled), and how far the kept one is from the exact fixed point.

    python benchmarks/fixed_point.py
"""
import sys
sys.path.insert(0, "benchmarks")
import numpy as np
import gaussfuse as gf
from gaussfuse import kalman
from workloads import random_linear_model, simulate_linear, long_series


def kept_from(covs):
    last = covs[-1]
    k = len(covs) - 1
    while k > 0 and np.array_equal(covs[k - 1], last):
        k -= 1
    return k


model, prior, zs = long_series(2000)
print("W1 kept from step", kept_from(gf.filter(model, prior, zs, engine="python").covs))
m2 = gf.constant_velocity(dt=1.0, q=0.1, r=1.0, dim=1)
zs2 = np.random.default_rng(0).normal(size=(200, 1))
print("W2 kept from step", kept_from(gf.filter(m2, gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2)), zs2, engine="python").covs))
for n in (8, 32, 64, 128):
    rng = np.random.default_rng(500 + n)
    model = random_linear_model(n, rng)
    _, zs = simulate_linear(model.F, model.H, model.Q, model.R, np.zeros(n), 300, rng)
    print(f"W5 n={n} kept from step", kept_from(gf.filter(model, gf.Gaussian(np.zeros(n), np.eye(n)), zs,
                                                           engine="python").covs))
# A random walk: x_k = x_{k-1} + w (variance q), z = x + v (variance 1). The predicted variance's fixed
# point solves p^2 = q p + q; the filtered one is p / (1 + p); the recursion contracts by 1 / (1 + p).
for q in (1e-2, 1e-4, 1e-6):
    p = (q + np.sqrt(q * q + 4 * q)) / 2
    exact, rho = p / (1 + p), 1 / (1 + p)
    T = int(40 / (1 - rho))
    model = gf.LinearModel(1.0, 1.0, q, 1.0)
    kept = gf.filter(model, gf.Gaussian([0.0], [[1.0]]), np.zeros((T, 1)), engine="python").covs[:, 0, 0]
    full = gf.filter(gf.LinearModel(np.ones((T, 1, 1)), 1.0, q, 1.0), gf.Gaussian([0.0], [[1.0]]),
                     np.zeros((T, 1)), engine="python").covs[:, 0, 0]
    print(f"random walk q={q:g}, 1-rho={1 - rho:.1e}: kept from step {kept_from(kept)}, relative error of the kept "
          f"{abs(kept[-1] - exact) / exact:.1e}, of every step computed {abs(full[-1] - exact) / exact:.1e}, "
          f"bound SETTLED/(1-rho) {kalman.SETTLED / (1 - rho):.1e}")
