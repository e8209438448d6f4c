"""User code as the README writes it, for `mypy --strict` (tests/test_typing.py): it must type-check as it is."""

import numpy as np

import gaussfuse as gf


def textbook() -> float:
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([1.0, 3.0]), R=10)
    prior = gf.Gaussian([0, 1], 500 * np.eye(2))
    res = gf.filter(model, prior, [1.0, 2.0, 3.0, 2.0, 1.0])
    sm = gf.smooth(model, prior, [1.0, 2.0, 3.0, 2.0, 1.0])
    last: np.ndarray = res.means[-1]
    spread: np.ndarray = np.sqrt(np.diagonal(sm.covs, axis1=1, axis2=2))
    return float(last[0] + spread[0, 0] + res.innovations[0, 0] + sm.filtered.predicted_covs[0, 0, 0])


def online() -> np.ndarray:
    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    kf = gf.KalmanFilter(model, gf.Gaussian(np.zeros(4), np.eye(4)))
    kf.predict()
    kf.update(np.array([0.1, 0.2]))
    return kf.x


def fused() -> float:
    both = gf.fuse(gf.Gaussian(1.0, 4.0), gf.Gaussian(2.0, 1.0))
    return float(both.mean[0])


def timed_and_sensors() -> gf.Fused:
    track = gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=4.0))
    res = gf.filter(track, gf.Gaussian([0, 0, 1, 0.5], 10 * np.eye(4)), np.zeros((3, 2)), times=[0.0, 1.0, 3.0])
    assert res.covs.shape == (3, 4, 4)
    motion = gf.ConstantVelocity(dim=2, q=0.1)
    sensors = {"gps": gf.Position(dim=2, r=4.0), "radar": gf.RangeBearing(r_range=1.0, r_bearing=1e-4)}
    events = [gf.Measurement(0.5, "gps", [1.0, 2.0]), gf.Measurement(0.8, "radar", [2.3, 1.1])]
    return gf.fuse_timeline(motion, sensors, gf.Gaussian([1, 0, 1, 1], 10 * np.eye(4)), 0.0, events)


def learn_and_forecast() -> tuple[float, np.ndarray]:
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    zs = np.cumsum(np.random.default_rng(0).normal(size=50))
    fit = gf.fit(model, gf.Gaussian(0.0, 10.0), zs, method="em", iterations=3, tol=0)
    fc = gf.forecast(fit.model, gf.filter(fit.model, fit.prior, zs), steps=5)
    lower, upper = fc.interval(0.95)
    return fit.loglik, upper - lower
