"""filterpy's textbook Kalman filter loop, ported line for line to gaussfuse's online filter
=========================================================================================

The filterpy lines are in the comments (Labbe, "Kalman and Bayesian Filters in
Python", chapter 6: a dog's position, measured with noise, constant
velocity). The differences: the model's matrices go into a `LinearModel`, and
the belief into a `Gaussian`. Everything else (`x`, `P *= 1000`, `predict()`,
`update(z)`, `update(None)` for a missing reading, a per-call `R=`, and `y`,
`S`, `K`, `log_likelihood`, `mahalanobis` after an update) reads the same.

With filterpy installed, the same loop runs in both and the largest
difference of every quantity is printed (round-off, a few 1e-15).

    python examples/port_from_filterpy.py
"""

import numpy as np

import gaussfuse as gf

dt, var = 0.1, 0.13
q = var * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])  # filterpy's Q_discrete_white_noise(2, dt, var)
rng = np.random.default_rng(1)
zs = list(np.arange(40) * 1.0 + rng.normal(scale=np.sqrt(5.0), size=40))
zs[17] = None                                   # a reading that never came
NOISY = 30                                      # one reading from a worse sensor, R = 50

# f = KalmanFilter(dim_x=2, dim_z=1)
# f.x = np.array([2., 0.])
# f.F = np.array([[1., 1.], [0., 1.]])
# f.H = np.array([[1., 0.]])
# f.R = 5.
# f.Q = Q_discrete_white_noise(dim=2, dt=0.1, var=0.13)
model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[[1.0, 0.0]], Q=q, R=5.0)
kf = gf.KalmanFilter(model, gf.Gaussian([2.0, 0.0], np.eye(2)))
kf.P *= 1000.0                                  # f.P *= 1000.

ours = []
for k, z in enumerate(zs):
    kf.predict()                                # f.predict()
    if k == NOISY:
        kf.update(z, R=50.0)                    # f.update(z, R=50.)
    else:
        kf.update(z)                            # f.update(z)
    ours.append((kf.x.copy(), kf.P.copy(), kf.y.copy(), kf.S.copy(), kf.K.copy(), kf.log_likelihood,
                 kf.mahalanobis))

print(f"gaussfuse: final x = {np.round(kf.x, 4)}, total log-likelihood {kf.loglik:.4f}")

try:
    from filterpy.kalman import KalmanFilter
except ImportError:
    print("filterpy is not installed: pip install filterpy to compare")
else:
    f = KalmanFilter(dim_x=2, dim_z=1)
    f.x = np.array([2.0, 0.0])
    f.F = np.array([[1.0, 1.0], [0.0, 1.0]])
    f.H = np.array([[1.0, 0.0]])
    f.P *= 1000.0
    f.R = 5.0
    f.Q = q
    worst = dict.fromkeys(["x", "P", "y", "S", "K", "log_likelihood", "mahalanobis"], 0.0)
    for k, z in enumerate(zs):
        f.predict()
        if k == NOISY:
            f.update(z, R=50.0)
        else:
            f.update(z)
        if z is None:  # filterpy leaves y, S, K and the likelihood of the last update there
            continue
        theirs = (f.x, f.P, f.y, f.S, f.K, f.log_likelihood, f.mahalanobis)
        for name, a, b in zip(worst, ours[k], theirs):
            worst[name] = max(worst[name], float(np.max(np.abs(np.asarray(a) - np.asarray(b)))))
    print("largest difference from filterpy: " + ", ".join(f"{name} {value:.1e}" for name, value in worst.items()))
