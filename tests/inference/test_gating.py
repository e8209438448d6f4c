"""Outlier gating (`gate=`): against the chi-square test computed independently, and the filter with those
measurements missing."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import gaussfuse as gf


def _track(seed: int = 0, T: int = 300):
    model = gf.constant_velocity(dt=1.0, q=0.1, r=1.0, dim=2)
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))
    sim = gf.simulate(model, prior, T, rng=seed)
    zs = sim.measurements.copy()
    zs[[40, 41, 150], 0] += 30.0   # a glitch on the x sensor
    zs[200] += [-20.0, 25.0]       # both at once
    zs[90, 1] = np.nan             # a missing component
    return model, prior, zs, sim.states


@pytest.mark.parametrize("by", ["measurement", "component"])
@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_the_gate_is_the_chi_square_test_and_a_rejection_is_a_missing_value(by, form):
    """Each step's rejection is what scipy's chi-square quantile says of the innovation against the filter's own
    prediction; and the gated filter is exactly the filter with the rejected components made missing."""
    model, prior, zs, _ = _track()
    p = 0.999
    res = gf.filter(model, prior, zs, gate=p, gate_by=by, form=form)
    for k in range(zs.shape[0]):
        o = ~np.isnan(zs[k])
        v = zs[k] - model.H @ res.predicted_means[k]
        S = model.H @ res.predicted_covs[k] @ model.H.T + model.R
        if by == "measurement":
            nis = v[o] @ np.linalg.inv(S[np.ix_(o, o)]) @ v[o]
            want = o & (nis > stats.chi2.ppf(p, o.sum()))
        else:
            want = o & (v**2 / np.diag(S) > stats.chi2.ppf(p, 1))
        np.testing.assert_array_equal(res.rejected[k], want, err_msg=f"step {k}")
    assert res.rejected[[40, 41, 150], 0].all() and res.rejected[200].all()
    missing = np.where(res.rejected, np.nan, zs)
    plain = gf.filter(model, prior, missing, form=form)
    np.testing.assert_array_equal(res.means, plain.means)
    np.testing.assert_array_equal(res.covs, plain.covs)
    assert res.loglik == plain.loglik


@pytest.mark.parametrize("batch", [False, True])
def test_keep_last_keeps_nothing_per_step_with_a_gate_either(batch):
    """Audit GG4: keep="last" kept the gate's per-step `rejected` (T, m), where its documentation promises nothing
    per step, so that memory does not grow with T; its final belief and log-likelihood are the full run's."""
    model, prior, zs, _ = _track(seed=3)
    zs = np.stack([zs, zs[::-1]]) if batch else zs
    full = gf.filter(model, prior, zs, gate=0.999)
    last = gf.filter(model, prior, zs, gate=0.999, keep="last")
    assert full.rejected.any() and last.rejected is None
    np.testing.assert_array_equal(last.last_mean, full.last_mean)
    np.testing.assert_array_equal(last.loglik, full.loglik)


def test_gating_removes_the_outliers_damage():
    model, prior, zs, truth = _track(seed=3)
    gated = gf.smooth(model, prior, zs, gate=0.999)
    plain = gf.smooth(model, prior, zs)
    err = [np.sqrt(np.mean((r.means[:, :2] - truth[:, :2]) ** 2)) for r in (gated, plain)]
    assert err[0] < 0.8 * err[1]
    rejected = gated.filtered.rejected.any(axis=1)
    assert rejected[[40, 41, 150, 200]].all()
    assert rejected.sum() - 4 <= 3  # and a few of the 296 good measurements at most (this draw: 2)


def test_the_online_filter_gates_like_the_batch_filter():
    model, prior, zs, _ = _track()
    batch = gf.filter(model, prior, zs, gate=0.99, gate_by="component")
    kf = gf.KalmanFilter(model, prior)
    for k, z in enumerate(zs):
        kf.predict()
        kf.update(z, gate=0.99, gate_by="component")
        np.testing.assert_array_equal(kf.rejected, batch.rejected[k])
        np.testing.assert_array_equal(kf.x, batch.means[k])
    kf.update(zs[0])
    assert kf.rejected is None


def test_a_nonlinear_filter_and_an_iterated_one_gate_too():
    dt = 0.05
    model = gf.NonlinearModel(lambda x: np.array([x[0] + dt * x[1], x[1] - 9.81 * dt * np.sin(x[0])]),
                              lambda x: np.array([np.sin(x[0])]), 0.01 * np.eye(2), np.array([[0.01]]))
    zs = np.sin(np.cos(np.arange(1, 81) * dt * 3.0))[:, None]
    zs[30] += 5.0
    for method in ("ukf", "iekf"):
        res = gf.smooth(model, gf.Gaussian([1.0, 0.0], 0.1 * np.eye(2)), zs, method=method, gate=0.999)
        assert res.filtered.rejected[30, 0] and res.filtered.rejected.sum() == 1, method


@pytest.mark.parametrize("kwargs, error, message", [
    ({"gate": 1.0}, ValueError, r"`gate` must be a probability in \(0, 1\)"),
    ({"gate": "0.9"}, TypeError, r"`gate` must be a probability in \(0, 1\), such as 0\.99; got str '0\.9'"),
    ({"gate": 0.9, "gate_by": "all"}, ValueError, "`gate_by` must be 'measurement' or 'component'"),
    ({"gate_by": "all"}, ValueError, "`gate_by` must be 'measurement' or 'component'"),
    ({"gate": 0.9, "engine": "numba"}, ValueError, "cannot run gate=0.9"),
])
def test_bad_gates_are_named(kwargs, error, message):
    model, prior, zs, _ = _track()
    with pytest.raises(error, match=message):
        gf.filter(model, prior, zs, **kwargs)
    with pytest.raises(ValueError, match="not available with a 'diffuse' prior"):
        gf.filter(model, "diffuse", zs, gate=0.9)


def test_a_component_that_agrees_exactly_with_a_zero_variance_is_not_rejected():
    """v = 0 over S_ii = 0 is 0/0 = NaN, which the component gate rejected: it agrees exactly, so the gated filter
    meets what the ungated one meets (a singular S, documented as an error) rather than silently dropping it."""
    model = gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=np.zeros((2, 2)), R=np.diag([0.0, 1.0]))
    prior = gf.Gaussian([2.0, 0.0], np.diag([0.0, 1.0]))
    zs = [[2.0, 0.1], [2.0, 0.2]]
    with pytest.raises(np.linalg.LinAlgError) as ungated:
        gf.filter(model, prior, zs, check="off")
    with pytest.raises(np.linalg.LinAlgError) as gated:
        gf.filter(model, prior, zs, gate=0.99, gate_by="component", check="off")
    assert str(gated.value) == str(ungated.value)
    z, rejected = gf.kalman.Gate(0.99, "component")(np.array([2.0, 5.0]), np.array([2.0, 0.0]), np.diag([0.0, 1.0]))
    np.testing.assert_array_equal(rejected, [False, True])  # 5 standard deviations out: rejected
