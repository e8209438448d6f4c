"""The online gf.KalmanFilter: one predict or update at a time."""

from __future__ import annotations

import copy
import pickle
import re
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import _oracle
import gaussfuse as gf


def _model_prior(problem):
    model = gf.LinearModel(problem["F"], problem["H"], problem["Q"], problem["R"], problem["B"])
    return model, gf.Gaussian(problem["m0"], problem["P0"])


@settings(max_examples=30, deadline=None)
@given(
    st.integers(1, 4), st.integers(1, 3), st.integers(1, 8), st.sampled_from([0, 1, 2]),
    st.sets(st.sampled_from(["F", "H", "Q", "R", "B"])), st.integers(0, 2**32 - 1),
)
def test_stepping_equals_batch_filter(n, m, T, p, varying, seed):
    rng = np.random.default_rng(seed)
    mask = rng.random(size=(T, m)) < 0.3
    mask[rng.random(size=T) < 0.2] = True  # some whole rows missing
    problem = _oracle.random_problem(rng, n, m, T, p, varying if p else varying - {"B"}, mask)
    model, prior = _model_prior(problem)
    zs, us = problem["zs"], problem["us"]
    res = gf.filter(model, prior, zs, us)

    kf = gf.KalmanFilter(model, prior)
    assert kf.step == 0 and kf.loglik == 0.0
    for k in range(T):
        predicted = kf.predict(None if us is None else us[k])
        assert isinstance(predicted, gf.Gaussian)
        np.testing.assert_allclose(predicted.mean, res.predicted_means[k], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(predicted.cov, res.predicted_covs[k], rtol=1e-12, atol=1e-12)
        updated = kf.update(zs[k])
        assert updated is kf.belief
        np.testing.assert_allclose(kf.x, res.means[k], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(kf.P, res.covs[k], rtol=1e-12, atol=1e-12)
        assert kf.step == k + 1
    assert kf.loglik == pytest.approx(res.loglik, rel=1e-12, abs=1e-12)


def test_scalar_measurement_and_control():
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=0.1 * np.eye(2), R=2.0, B=[0.5, 1.0])
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    zs, us = [1.0, np.nan, 2.5], [0.1, -0.2, 0.3]
    res = gf.filter(model, prior, zs, us)
    kf = gf.KalmanFilter(model, prior)
    for z, u in zip(zs, us):
        kf.predict(u)
        kf.update(z)
    np.testing.assert_allclose(kf.x, res.means[-1], rtol=1e-12)
    assert kf.loglik == pytest.approx(res.loglik, rel=1e-12)


def test_missing_update_changes_nothing():
    model = gf.constant_velocity(dt=1.0, q=0.5, r=1.0, dim=2)
    kf = gf.KalmanFilter(model, gf.Gaussian(np.zeros(4), np.eye(4)))
    before = kf.predict()
    after = kf.update([np.nan, np.nan])
    np.testing.assert_array_equal(after.mean, before.mean)
    np.testing.assert_array_equal(after.cov, before.cov)
    assert kf.loglik == 0.0


@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_the_factor_handed_out_is_read_only(form):
    """``L = kf.L; L *= 10`` changed the square-root form's next step (P's diagonal [0.995, 20.5] for
    [0.6875, 0.4993]) while ``kf.P`` showed the old belief (audit U); in the covariance form L Lᵀ no longer
    equalled P. Also after a pickle, which does not keep the flag."""
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[[1, 0]], Q=0.1 * np.eye(2), R=1.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([0, 0], np.eye(2)), form=form, check="off")
    kf.predict()
    kf.update(0.3)
    for f in (kf, pickle.loads(pickle.dumps(kf))):
        with pytest.raises(ValueError, match="read-only"):
            f.L[1, 1] = 10.0
        np.testing.assert_allclose(f.L @ f.L.T, f.P, rtol=1e-15)


def test_the_belief_is_immutable_and_x_and_P_are_the_users_to_change():
    """filterpy's idioms: ``kf.P *= 1000``, ``kf.x[0] = 3``, ``kf.x = ...``; the next step starts from them."""
    model = gf.constant_velocity(dt=1.0, q=0.5, r=1.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)))
    kf.predict()
    kf.update(1.0)
    with pytest.raises(ValueError, match="read-only"):
        kf.belief.mean[0] = 3.0
    kf.P *= 1000.0
    kf.x[0] = 3.0
    assert kf.x is kf.x  # the same copy until the belief changes
    np.testing.assert_array_equal(kf.belief.mean, [3.0, kf.x_post[1]])
    np.testing.assert_array_equal(kf.belief.cov, 1000.0 * kf.P_post)
    want = gf.KalmanFilter(model, gf.Gaussian(kf.belief.mean, kf.belief.cov))
    kf.predict()
    want.predict()
    np.testing.assert_array_equal(kf.x, want.x)
    kf.x = [1.0, 2.0]
    np.testing.assert_array_equal(kf.belief.mean, [1.0, 2.0])
    kf.P[0, 1] = 5.0  # not symmetric: refused when the next step reads it
    with pytest.raises(ValueError, match="`P` must be symmetric"):
        kf.update(1.0)
    with pytest.raises(ValueError, match="`P` must be positive semi-definite"):
        kf.P = [[1.0, 2.0], [2.0, 1.0]]


# ---------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------


def _with_control():
    model = gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=np.eye(2), R=np.eye(2), B=[[1.0], [0.0]])
    return gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)))


def test_control_required_when_model_has_B():
    kf = _with_control()
    with pytest.raises(ValueError, match=r"^`u` is required: the model has a control input with p = 1\.$"):
        kf.predict()
    assert kf.step == 0  # nothing happened


def test_control_rejected_without_B():
    kf = gf.KalmanFilter(gf.constant_velocity(dt=1.0, q=1.0, r=1.0), gf.Gaussian([0.0, 0.0], np.eye(2)))
    with pytest.raises(ValueError, match=r"^`u` was given but the model has no control input; give the model `B`\.$"):
        kf.predict([1.0])
    assert kf.step == 0


@pytest.mark.parametrize(("u", "shape"), [([1.0, 2.0], r"\(2,\)"), ([[1.0]], r"\(1, 1\)")])
def test_control_of_wrong_shape(u, shape):
    kf = _with_control()
    with pytest.raises(ValueError, match=rf"^`u` must have shape \(1,\); got shape {shape}\.$"):
        kf.predict(u)


def test_control_must_be_finite():
    with pytest.raises(ValueError, match=r"^`u` must be finite"):
        _with_control().predict([np.nan])


@pytest.mark.parametrize(("z", "shape"), [([1.0, 2.0, 3.0], r"\(3,\)"), ([[1.0, 2.0]], r"\(1, 2\)"), (1.0, r"\(1,\)")])
def test_measurement_of_wrong_shape(z, shape):
    kf = _with_control()
    kf.predict([0.0])
    with pytest.raises(ValueError, match=rf"^`z` must have shape \(2,\); got shape {shape}\."):
        kf.update(z)


def test_measurement_must_not_be_infinite_or_text():
    kf = _with_control()
    kf.predict([0.0])
    with pytest.raises(ValueError, match=r"^`z` must be finite; got an infinite value at index \(1,\)\.$"):
        kf.update([0.0, np.inf])
    with pytest.raises(TypeError, match=r"^`z` must be an array of numbers; got str\.$"):
        kf.update("12")


def test_stepping_past_the_end_of_a_time_varying_model():
    model = gf.LinearModel(F=np.stack([np.eye(2), 2 * np.eye(2)]), H=[1.0, 0.0], Q=np.eye(2), R=1.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([1.0, 1.0], np.eye(2)))
    kf.predict()
    kf.update(1.0)
    kf.predict()
    np.testing.assert_allclose(kf.x[1], 2.0)  # F[1] was used at the second step
    kf.update(1.0)
    with pytest.raises(ValueError, match=r"^the time-varying model has 2 steps; step 2 is beyond it\.$"):
        kf.predict()
    assert kf.step == 2


def test_the_step_is_checked_when_set():
    """Audit HH5: `step` was a plain attribute: -3 was taken, and a time-invariant model predicted from it."""
    kf = gf.KalmanFilter(gf.LinearModel(np.ones((3, 1, 1)), 1.0, 1.0, 1.0), gf.Gaussian([0.0], [[1.0]]))
    for bad, error in ((-3, ValueError), (1.5, TypeError), (None, TypeError)):
        with pytest.raises(error, match=rf"^`step` must be a non-negative integer; got {bad!r}\.$"):
            kf.step = bad
    assert kf.step == 0
    kf.predict()
    kf.step = 0  # the time-varying model's first step again
    kf.predict()
    assert kf.step == 1 and repr(kf).count("step=1") == 1
    assert pickle.loads(pickle.dumps(kf)).step == 1
    state = kf.__getstate__()
    state["step"] = state.pop("_step")  # as pickled before `step` was a property
    old = gf.KalmanFilter.__new__(gf.KalmanFilter)
    old.__setstate__(state)
    assert old.step == 1


def test_constructor_checks_model_and_prior():
    # (it said "a LinearModel, NonlinearModel", leaving out the TimedModel it takes: audit WW3)
    with pytest.raises(TypeError, match=r"^`model` must be a gaussfuse\.LinearModel, NonlinearModel or TimedModel; "
                                        r"got dict\.$"):
        gf.KalmanFilter({}, gf.Gaussian([0.0], [[1.0]]))
    with pytest.raises(TypeError, match=r"got ConstantVelocity \(a motion model: gaussfuse\.model\(motion, sensor\)"):
        gf.KalmanFilter(gf.ConstantVelocity(), gf.Gaussian([0.0, 0.0], np.eye(2)))
    model = gf.constant_velocity(dt=1.0, q=1.0, r=1.0)
    with pytest.raises(ValueError, match=r"^`prior` must have dimension 2 \(the model's state\); got 1\.$"):
        gf.KalmanFilter(model, gf.Gaussian([0.0], [[1.0]]))
    with pytest.raises(TypeError, match=r"^`prior` must be a gaussfuse.Gaussian\(mean, cov\); got tuple\.$"):
        gf.KalmanFilter(model, (np.zeros(2), np.eye(2)))


def test_singular_innovation_names_the_step():
    model = gf.LinearModel(F=np.eye(1), H=np.eye(1), Q=np.zeros((1, 1)), R=np.zeros((1, 1)))
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0], [[0.0]]))
    kf.predict()
    with pytest.raises(np.linalg.LinAlgError, match=r"^at step 0: the innovation covariance S"):
        kf.update(1.0)


def test_a_pickled_or_copied_filter_carries_on_where_the_original_left_off():
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.eye(2), R=2.0, B=[[0.5], [1.0]])
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 1.0], 10.0 * np.eye(2)))
    for z in (1.0, 2.5):
        kf.predict([0.1])
        kf.update(z)
    others = [pickle.loads(pickle.dumps(kf)), copy.copy(kf), copy.deepcopy(kf)]
    for f in [kf, *others]:
        f.predict([0.2])
        f.update(3.0)
    for other in others:
        assert other.step == kf.step == 3
        np.testing.assert_array_equal(other.x, kf.x)
        np.testing.assert_array_equal(other.P, kf.P)
        assert other.loglik == kf.loglik
        assert not other.belief.mean.flags.writeable and other.x.flags.writeable


def test_a_shallow_copy_steps_on_its_own():
    """copy.copy shared the handed-out x, the divergence monitor and the steady state with the original: changing the
    copy's x in place changed the original's, and wild updates of the copy made the original's 20 perfect ones raise."""
    model = gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[0.01]], R=[[1.0]])
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0], [[1.0]]), check="raise")
    kf.x  # handed out
    other = copy.copy(kf)
    other.x[0] = 1234.0
    assert kf.x[0] == 0.0
    for k in range(30):
        other.predict()
        other.update(1000.0 * (-1) ** k)
    for _ in range(60):  # every innovation zero: no window of its own can fail
        kf.predict()
        kf.update(kf.x[0])
    fuser = gf.Fuser(gf.ConstantVelocity(dim=1, q=0.1), {"gps": gf.Position(dim=1, r=0.25)},
                     gf.Gaussian([0.0, 0.0], np.eye(2)), t0=0.0, check="raise")
    twin = copy.copy(fuser)
    for k in range(1, 31):
        twin.update(float(k), "gps", 1000.0 * (-1) ** k)
    for k in range(1, 61):
        fuser.update(float(k), "gps", fuser.predict(float(k)).mean[0])
    assert fuser.t == 60.0 and twin.t == 30.0


def test_the_online_gate_names_a_lost_track():
    """gf.filter named the steps where its gate rejected at least half; the online filter, with the same gate, said
    nothing while its estimate stayed at 0 and the data moved to 100. A consistent gated run stays silent."""
    model = gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[0.01]], R=[[1.0]])
    prior = gf.Gaussian([0.0], [[1.0]])
    zs = np.r_[np.zeros(20), np.full(180, 100.0)]
    with pytest.warns(gf.DivergenceWarning, match=r"The gate rejected 180 of 200 over steps 0-199"):
        gf.filter(model, prior, zs, gate=0.99)
    kf = gf.KalmanFilter(model, prior, check="raise")
    with pytest.raises(gf.DivergenceWarning, match=r"The gate rejected 30 of 50 over steps 0-49 of the measurements"):
        for z in zs:
            kf.predict()
            kf.update(z, gate=0.99)
    assert kf.step == 50 and kf.x[0] == pytest.approx(0.0, abs=1.0)
    by_component = gf.KalmanFilter(gf.LinearModel(np.eye(2), np.eye(2), 0.01 * np.eye(2), np.eye(2)),
                                   gf.Gaussian([0.0, 0.0], np.eye(2)), check="raise")
    with pytest.raises(gf.DivergenceWarning, match=r"The gate rejected 50 of 100 over steps 25-74 of the components"):
        for z in zs:
            by_component.predict()
            by_component.update([0.0, z], gate=0.99, gate_by="component")
    rng = np.random.default_rng(2)
    clean = gf.KalmanFilter(model, prior, check="raise")  # about 1% rejected, in runs: never half of a window
    x, rejected = 0.0, 0
    for _ in range(5000):
        x += 0.1 * rng.standard_normal()
        clean.predict()
        clean.update(x + rng.standard_normal(), gate=0.99)
        rejected += int(clean.rejected.any())
    assert 10 < rejected < 200  # the gate did reject, a consistent filter's share


def test_online_filter_reuses_the_fixed_point_and_equals_the_batch_filter_bitwise():
    """The online filter reaches the same covariance fixed point as gf.filter, and every belief is bitwise the same."""
    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))
    zs = np.cumsum(np.random.default_rng(4).normal(size=(300, 2)), axis=0) * 0.1
    zs[200, 1] = np.nan  # a partly missing step leaves the fixed point, and it is found again
    batch = gf.filter(model, prior, zs, engine="python")
    kf = gf.KalmanFilter(model, prior)
    for k, z in enumerate(zs):
        kf.predict()
        kf.update(z)
        np.testing.assert_array_equal(kf.x, batch.means[k])
        np.testing.assert_array_equal(kf.P, batch.covs[k])
    assert kf._steady.cov is kf.belief.cov  # at the fixed point, reused
    assert kf.loglik == batch.loglik


def test_a_belief_set_by_hand_between_predict_and_update_is_not_taken_for_a_fixed_point():
    """After predict(), a user-set belief is updated in full, and the next steps still equal a fresh filter's."""
    model = gf.constant_velocity(0.1, 1.0, 0.25)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    kf = gf.KalmanFilter(model, prior)
    for z in np.linspace(0.0, 3.0, 200):
        kf.predict()
        kf.update([z])
    assert kf._steady.cov is kf.belief.cov
    kf.predict()
    other = gf.Gaussian(kf.x, 2.0 * kf.P)
    kf.belief = other
    kf.update([3.0])
    fresh = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)))
    fresh.belief = other
    fresh.step = kf.step
    fresh.update([3.0])
    np.testing.assert_array_equal(kf.P, fresh.P)
    for z in (3.1, 3.2, 3.3):
        for f in (kf, fresh):
            f.predict()
            f.update([z])
        np.testing.assert_array_equal(kf.x, fresh.x)
        np.testing.assert_array_equal(kf.P, fresh.P)


def test_the_online_filter_checks_for_divergence_as_it_goes():
    """A sensor fault at steps 200-259 is named when the window ending at step 224 fails; a clean run is silent."""
    model = gf.constant_velocity(0.1, 1.0, 0.25)
    rng = np.random.default_rng(0)
    zs = 0.1 * np.arange(400) + 0.5 * rng.standard_normal(400)
    clean = gf.KalmanFilter(model, gf.Gaussian([0.0, 1.0], np.eye(2)), check="raise")
    for z in zs:
        clean.predict()
        clean.update(z)
    zs[200:260] += 5.0
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 1.0], np.eye(2)))
    with pytest.warns(gf.DivergenceWarning, match=r"over steps 175-224 \(1 expected") as caught:
        for z in zs:
            kf.predict()
            kf.update(z)
    assert len(caught) == 1  # the failing windows that follow are one episode: reported once
    quiet = gf.KalmanFilter(model, gf.Gaussian([0.0, 1.0], np.eye(2)), check="off")
    with warnings.catch_warnings():
        warnings.simplefilter("error", gf.DivergenceWarning)
        for z in zs:
            quiet.predict()
            quiet.update(z)
    np.testing.assert_array_equal(quiet.x, kf.x)
    with pytest.raises(ValueError, match="`check` must be one of"):
        gf.KalmanFilter(model, gf.Gaussian([0.0, 1.0], np.eye(2)), check=True)


def test_the_fuser_names_the_times_of_a_divergence():
    motion = gf.ConstantVelocity(dim=1, q=0.1)
    fuser = gf.Fuser(motion, {"gps": gf.Position(dim=1, r=0.25)}, gf.Gaussian([0.0, 1.0], np.eye(2)), t0=0.0)
    rng = np.random.default_rng(1)
    with pytest.warns(gf.DivergenceWarning, match=r"over times \d+(\.\d+)? to \d+(\.\d+)?"):
        for k in range(1, 200):
            t = 0.5 * k
            fuser.update(t, "gps", t + 0.5 * rng.standard_normal() + (8.0 if k > 120 else 0.0))


# ---------------------------------------------------------------------------
# filterpy's interface: per-call matrices, update(None), y, S, K, the likelihood
# ---------------------------------------------------------------------------


def test_a_filterpy_loop_with_per_call_matrices_gives_filterpys_numbers():
    """predict(F=, Q=), update(z, R=, H=), update(None), and every attribute filterpy has after a step, to 1e-10."""
    from filterpy.kalman import KalmanFilter as FilterpyKF

    rng = np.random.default_rng(3)
    F, H = np.array([[1.0, 0.5], [0.0, 1.0]]), np.array([[1.0, 0.0], [0.0, 1.0]])
    Q, R = np.diag([0.01, 0.1]), np.diag([1.0, 0.5])
    kf = gf.KalmanFilter(gf.LinearModel(F, H, Q, R), gf.Gaussian([0.0, 1.0], 10.0 * np.eye(2)))
    f = FilterpyKF(dim_x=2, dim_z=2)
    f.x, f.P, f.F, f.H, f.Q, f.R = np.array([0.0, 1.0]), 10.0 * np.eye(2), F.copy(), H.copy(), Q.copy(), R.copy()
    for k in range(30):
        z = rng.normal(size=2) + [0.5 * k, 1.0]
        calls = {}
        if k % 7 == 3:
            calls = {"F": np.array([[1.0, 0.8], [0.0, 0.95]]), "Q": 3.0 * Q}
        kf.predict(**calls)
        f.predict(**calls)
        np.testing.assert_allclose(kf.x_prior, f.x_prior, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(kf.P_prior, f.P_prior, rtol=1e-12, atol=1e-12)
        if k % 9 == 4:
            kf.update(None)
            f.update(None)
            assert kf.step == k + 1 and np.isnan(kf.y).all()
        else:
            kw = {"R": np.diag([4.0, 2.0])} if k % 5 == 1 else {}
            kf.update(z, **kw)
            f.update(z, **kw)
            for name in ("y", "S", "K", "log_likelihood", "mahalanobis"):
                np.testing.assert_allclose(getattr(kf, name), getattr(f, name), rtol=1e-10, atol=1e-12,
                                           err_msg=f"step {k}: {name}")
        np.testing.assert_allclose(kf.x, f.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(kf.P, f.P, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(kf.x_post, kf.belief.mean)


def test_another_sensor_for_one_update_is_the_missing_component_update():
    """update(z_0, H=H[:1], R=R[:1, :1]) is update([z_0, NaN]) exactly (same algebra over the observed component)."""
    model = gf.constant_velocity(dt=1.0, q=0.3, r=1.0, dim=2)
    prior = gf.Gaussian([0.0, 0.0, 1.0, 1.0], np.eye(4))
    a, b = gf.KalmanFilter(model, prior), gf.KalmanFilter(model, prior)
    for kf in (a, b):
        kf.predict()
    a.update([0.7], H=model.H[:1], R=model.R[:1, :1])
    b.update([0.7, np.nan])
    np.testing.assert_allclose(a.x, b.x, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(a.K, b.K[:, :1], rtol=1e-14, atol=1e-15)
    assert a.log_likelihood == pytest.approx(b.log_likelihood, rel=1e-14)
    with pytest.raises(ValueError, match="`R` is required with an `H` of 1 rows"):
        a.update([0.1], H=model.H[:1])
    with pytest.raises(ValueError, match=r"`z` must have shape \(1,\)"):
        a.update([0.1, 0.2], H=model.H[:1], R=[[1.0]])
    with pytest.raises(ValueError, match="`Q` must be symmetric"):
        a.predict(Q=[[1.0, 2.0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
    with pytest.raises(ValueError, match=r"`F` must have shape \(4, 4\)"):
        a.predict(F=np.eye(2))


@pytest.mark.parametrize("method, form", [("ukf", "cov"), ("ekf", "cov"), ("ckf", "sqrt"), ("iekf", "cov")])
def test_a_nonlinear_model_online_is_the_batch_filter(method, form):
    """KalmanFilter(NonlinearModel, method=...): every belief bitwise gf.filter's; Q= and R= per call; F= refused."""
    dt = 0.05
    model = gf.NonlinearModel(lambda x: np.array([x[0] + dt * x[1], x[1] - 9.81 * dt * np.sin(x[0])]),
                              lambda x: np.array([np.sin(x[0])]), 0.01 * np.eye(2), np.array([[0.1]]))
    prior = gf.Gaussian([1.0, 0.0], 0.5 * np.eye(2))
    zs = np.sin(np.cos(np.arange(1, 41) * dt * 3.0))[:, None]
    zs[10] = np.nan
    batch = gf.filter(model, prior, zs, method=method, form=form)
    kf = gf.KalmanFilter(model, prior, method=method, form=form)
    for k, z in enumerate(zs):
        kf.predict()
        kf.update(z)
        np.testing.assert_array_equal(kf.x, batch.means[k])
        np.testing.assert_array_equal(kf.P, batch.covs[k])
    assert kf.loglik == batch.loglik
    other = gf.NonlinearModel(model.f, model.h, 0.02 * np.eye(2), np.array([[0.3]]))
    a, b = gf.KalmanFilter(model, prior, method=method, form=form), gf.KalmanFilter(other, prior, method=method,
                                                                                   form=form)
    a.predict(Q=0.02 * np.eye(2))
    a.update(zs[0], R=[[0.3]])
    b.predict()
    b.update(zs[0])
    np.testing.assert_array_equal(a.x, b.x)
    with pytest.raises(TypeError, match="replaces a LinearModel's matrix"):
        a.predict(F=np.eye(2))


def test_controls_of_a_nonlinear_model_go_to_f_only_when_given():
    seen = []

    def f(x, u=None):
        seen.append(u)
        return x if u is None else x + u

    model = gf.NonlinearModel(f, lambda x: x[:1], 0.1 * np.eye(2), np.array([[1.0]]))
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), method="ekf")
    kf.predict()
    assert set(map(type, seen)) == {type(None)}
    kf.predict(u=[1.0, 2.0])
    assert seen[-1] is not None and np.array_equal(seen[-1], [1.0, 2.0])


@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_a_settled_filter_and_its_copies_equal_the_batch_filter_bitwise(form):
    """The square-root form handed its factor to the step as a view, never the object that holds the fixed point,
    and a copy or pickle rebuilt the belief's arrays: both computed every step in full, 4e-16 off the batch filter
    and the original (audit DD3)."""
    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))
    zs = np.cumsum(np.random.default_rng(4).normal(size=(400, 2)), axis=0) * 0.1
    batch = gf.filter(model, prior, zs, engine="python", form=form)
    kf = gf.KalmanFilter(model, prior, form=form)
    for k in range(200):
        kf.predict()
        kf.update(zs[k])
    assert kf._steady.cov is (kf._factor[1] if form == "sqrt" else kf.belief.cov)  # held
    others = [pickle.loads(pickle.dumps(kf)), copy.copy(kf), copy.deepcopy(kf)]
    for f in [kf, *others]:
        for k in range(200, 400):
            f.predict()
            f.update(zs[k])
            np.testing.assert_array_equal(f.x, batch.means[k])
            np.testing.assert_array_equal(f.P, batch.covs[k])
        assert f.loglik == batch.loglik


def test_a_timed_model_too_fast_for_a_step_of_one_second_filters_online():
    """Its form over 1 s, which the filter read the dimensions from, overflowed: the filter could not be made
    (audit DD3). The oracle is the batch filter at the same times."""
    timed = gf.model(gf.LinearSDE([[800.0]], [1.0], 1.0), gf.LinearSensor(H=1.0, R=1.0))
    prior = gf.Gaussian([0.0], [[1.0]])
    batch = gf.filter(timed, prior, [1.0, 2.0, 3.0], times=[0.0, 0.001, 0.002, 0.003])
    kf = gf.KalmanFilter(timed, prior)
    assert kf.model is timed  # as given, not the model of the last step
    for k, z in enumerate([1.0, 2.0, 3.0]):
        kf.predict(dt=0.001)
        kf.update(z)
        np.testing.assert_array_equal(kf.x, batch.means[k])
    assert kf.model is timed and kf.F[0, 0] == pytest.approx(np.exp(0.8), rel=1e-14)


def test_the_controls_of_a_timed_nonlinear_model_are_checked_as_u():
    """They failed inside f, or were named `us` with a shape the user never gave (audit DD3)."""
    prior = gf.Gaussian([10.0, 5.0, 0.0, 0.0], np.eye(4))
    pushed = gf.KalmanFilter(gf.model(gf.ForceInput(q=0.1, dim=2), gf.RangeBearing()), prior, method="ekf")
    with pytest.raises(ValueError, match=r"`u` is required: the model has a control input with p = 2"):
        pushed.predict(dt=1.0)
    with pytest.raises(ValueError, match=r"`u` must have shape \(2,\); got shape \(3,\)"):
        pushed.predict([1.0, 2.0, 3.0], dt=1.0)
    pushed.predict([0.5, -0.5], dt=1.0)
    drifting = gf.KalmanFilter(gf.model(gf.ConstantVelocity(dim=2), gf.RangeBearing()), prior)
    with pytest.raises(ValueError, match="`u` was given but the model has no control input"):
        drifting.predict([1.0], dt=1.0)


def test_reprs_say_what_the_filter_is_without_its_arrays():
    kf = gf.KalmanFilter(gf.constant_velocity(dt=1.0, q=1.0, r=1.0), gf.Gaussian([0.0, 0.0], np.eye(2)))
    kf.predict()
    kf.update(1.0)
    text = repr(kf)
    assert text.startswith("KalmanFilter(LinearModel(n=2, m=1, p=0, dt=1), method='kf', form='cov', step=1, loglik=")
    assert "[" not in text


@pytest.mark.parametrize("motion, sensor, method, prior, zs", [
    (gf.ConstantVelocity(q=0.5), gf.Position(r=0.1), None, gf.Gaussian([0.0, 1.0], np.eye(2)),
     np.array([[1.0], [3.1], [3.4]])),
    (gf.CoordinatedTurn(q_acc=0.1, q_turn=1e-3), gf.RangeBearing(origin=(-5.0, 0.0)), "ukf",
     gf.Gaussian([0.0, 0.0, 1.0, 0.5, 0.05], np.diag([1.0, 1.0, 0.1, 0.1, 0.01])),
     np.array([[5.0, 0.1], [6.0, 0.12], [8.0, 0.2]])),
])
def test_predict_dt_steps_a_timed_model_as_the_batch_filter_does(motion, sensor, method, prior, zs):
    """KalmanFilter(gf.model(motion, sensor)) with predict(dt=...): gf.filter with the same `times`, bitwise."""
    timed = gf.model(motion, sensor)
    times = np.array([0.0, 1.0, 3.0, 3.5])
    batch = gf.filter(timed, prior, zs, times=times, method=method)
    kf = gf.KalmanFilter(timed, prior, method=method)
    for k, (dt, z) in enumerate(zip(np.diff(times), zs)):
        kf.predict(dt=dt)
        kf.update(z)
        np.testing.assert_array_equal(kf.x, batch.means[k])
        np.testing.assert_array_equal(kf.P, batch.covs[k])
    assert repr(kf).startswith("KalmanFilter(TimedModel(")
    with pytest.raises(ValueError, match="`dt` is required"):
        kf.predict()
    with pytest.raises(ValueError, match="`dt` is for a model built by gf.model"):
        gf.KalmanFilter(gf.constant_velocity(1.0, 1.0, 1.0), gf.Gaussian([0.0, 1.0], np.eye(2))).predict(dt=1.0)


def test_errors_in_x_and_p_name_x_and_p():
    """filterpy's names in the messages, whether x and P are set or changed in place."""
    kf = gf.KalmanFilter(gf.LinearModel(F=np.eye(2), H=[1.0, 0.0], Q=np.eye(2), R=1.0), gf.Gaussian([0, 0], np.eye(2)))
    with pytest.raises(ValueError, match=r"`x` must have shape \(2,\); got shape \(3,\)"):
        kf.x = [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match=r"`P` must have shape \(2, 2\); got shape \(3, 3\)"):
        kf.P = np.eye(3)
    kf.x[0] = np.nan
    with pytest.raises(ValueError, match="`x` must be finite"):
        kf.predict()


@pytest.mark.parametrize("name, hint", [("Q", r"kf\.predict\(Q=\.\.\.\)"), ("R", r"kf\.update\(z, R=\.\.\.\)"),
                                        ("F", r"kf\.predict\(F=\.\.\.\)"), ("H", r"kf\.update\(z, H=\.\.\.\)"),
                                        ("B", "make a new KalmanFilter"), ("model", "make a new KalmanFilter"),
                                        ("form", "make a new KalmanFilter"), ("method", "make a new KalmanFilter")])
def test_assigning_a_model_matrix_says_where_it_goes(name, hint):
    """filterpy is configured by assignment (f.Q = ...): here kf.Q = ... made an unused attribute and the
    estimates were those of the old Q, silently; kf.model = ... was half taken (predict used the old Q)."""
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([1.0, 3.0]), R=10.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([0, 1], np.eye(2)))
    before = getattr(kf, name)
    with pytest.raises(AttributeError, match=rf"^`{name}` of a KalmanFilter cannot be assigned .*{hint}"):
        setattr(kf, name, 1e6 * np.eye(2))
    assert getattr(kf, name) is before
    if name in "FHQR":
        np.testing.assert_array_equal(getattr(kf, name), getattr(model, name))  # read as filterpy's are


@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_a_prediction_that_overflows_raises_naming_its_step_and_keeps_the_belief(form):
    """The square-root form's predict returned a mean of inf and P = inf·I (F = 1e200 I), or P = L Lᵀ of inf from
    a finite factor (Q = 5e307 I, two steps), with only NumPy's RuntimeWarning; the next update named step 1."""
    H = np.array([[1.0, 0.0]])
    kf = gf.KalmanFilter(gf.LinearModel(1e200 * np.eye(2), H, np.eye(2), 1.0),
                         gf.Gaussian([1e200, 0.0], 1e200 * np.eye(2)), check="off", form=form)
    with pytest.raises(FloatingPointError, match=r"^at step 0: the predicted mean or covariance is not finite"):
        kf.predict()
    assert kf.step == 0 and kf.x[0] == 1e200
    kf = gf.KalmanFilter(gf.LinearModel(np.eye(2), H, 5e307 * np.eye(2), 1.0), gf.Gaussian([0.0, 0.0], np.eye(2)),
                         check="off", form=form)
    kf.predict()
    with pytest.raises(FloatingPointError, match=r"^at step 1: the predicted mean or covariance is not finite"):
        kf.predict()
    assert kf.step == 1 and np.isfinite(kf.P).all()


def test_a_nonlinear_models_control_width_is_checked_online():
    """Audit AA1: the online filter checked `u` against a LinearModel's p only. A NonlinearModel with p = 1 took
    `u` of width 2 without a word, and without `u` failed inside f; the batch filter refuses both."""
    def f(x, u):
        return x + u[0]

    model = gf.NonlinearModel(f, lambda x: x[:1], 0.1 * np.eye(2), 1.0, p=1)
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    with pytest.raises(ValueError, match=re.escape("`u` must have shape (1,); got shape (2,).")):
        gf.KalmanFilter(model, prior, method="ekf").predict([1.0, 99.0])
    with pytest.raises(ValueError, match=re.escape("`u` is required: the model has a control input with p = 1.")):
        gf.KalmanFilter(model, prior, method="ukf").predict()
    without = gf.NonlinearModel(lambda x: x, lambda x: x[:1], 0.1 * np.eye(2), 1.0, p=0)
    with pytest.raises(ValueError, match=re.escape("`u` was given but the model has no control input.")):
        gf.KalmanFilter(without, prior).predict([1.0])
    for p in (1, None):  # a width given, and none: u is passed to f as it is
        kf = gf.KalmanFilter(gf.NonlinearModel(f, lambda x: x[:1], 0.1 * np.eye(2), 1.0, p=p), prior, method="ekf")
        kf.predict([2.0])
        np.testing.assert_array_equal(kf.x, [2.0, 2.0])


def test_in_place_changes_through_x_count_after_p_or_the_belief_is_read():
    """Audit AA1: reading `P` took in a change made through a saved `x`, then stopped tracking that `x`, so its
    next change was lost. Both handles keep counting until the belief moves on."""
    model = gf.LinearModel(F=np.eye(2), H=[1.0, 0.0], Q=np.zeros((2, 2)), R=1.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)))
    x = kf.x
    x[0] = 5.0
    P = kf.P
    x[1] = 3.0
    P[1, 1] = 9.0
    kf.predict()
    np.testing.assert_array_equal(kf.x_prior, [5.0, 3.0])
    np.testing.assert_array_equal(kf.P_prior, [[1.0, 0.0], [0.0, 9.0]])
    x = kf.x
    x[0] = 1.0
    assert kf.belief.mean[0] == 1.0
    x[1] = 7.0
    kf.predict()
    np.testing.assert_array_equal(kf.x_prior, [1.0, 7.0])


def test_setting_the_belief_to_something_else_names_the_belief():
    """Audit AA1: the error named `prior`."""
    kf = gf.KalmanFilter(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0), gf.Gaussian([0.0], [[1.0]]))
    with pytest.raises(TypeError, match=re.escape("`belief` must be a gaussfuse.Gaussian(mean, cov); got 'x'.")):
        kf.belief = "x"
    with pytest.raises(ValueError, match=re.escape("`belief` must have dimension 1 (the model's state); got 2.")):
        kf.belief = gf.Gaussian([0.0, 0.0], np.eye(2))


@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_the_innovation_covariance_handed_out_cannot_change_later_ones(form):
    """Audit LL1: once the covariances settle, every update's S is the steady state's own array; `kf.S *= 7` at one
    step made every later S seven times too large (the estimates stayed right). It is read-only now, as x_prior
    and the others are, and each later S is still H P⁻ Hᵀ + R."""
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.01, 0.01]), R=4.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), form=form)
    for z in np.sin(np.arange(80.0)):
        kf.predict()
        kf.update(z)
        with pytest.raises(ValueError, match="read-only"):
            kf.S *= 7.0
        want = model.H @ kf.P_prior @ model.H.T + model.R
        np.testing.assert_allclose(kf.S, want, rtol=1e-12)


@pytest.mark.parametrize("name, hint", [("alpha", "fading memory"), ("M", "cross-covariance"), ("inv", "Cholesky")])
def test_filterpys_settings_that_are_not_offered_say_so(name, hint):
    """Audit LL2: `kf.alpha = 1.05` (filterpy's fading memory) made an attribute nothing reads, and P went on as
    before (2.818 where filterpy's is 2.947 after three steps); M and inv likewise."""
    kf = gf.KalmanFilter(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0), gf.Gaussian([0.0], [[1.0]]))
    with pytest.raises(AttributeError, match=rf"^a KalmanFilter has no `{name}`: .*{hint}"):
        setattr(kf, name, 1.05)
    assert not hasattr(kf, name)
    assert name not in vars(kf)


def test_an_h_for_a_nonlinear_model_is_refused_before_its_r_and_z_are_checked():
    """Audit LL3: an H of two rows was first told to bring its R, then a z of two components, and only then that a
    NonlinearModel's h is a function."""
    model = gf.NonlinearModel(lambda x: x, lambda x: x[:1], np.eye(2), 1.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)))
    kf.predict()
    for z, extra in [(1.0, {}), (1.0, {"R": np.eye(2)}), ([1.0, 2.0], {"R": np.eye(2)})]:
        with pytest.raises(TypeError, match=r"^`H` replaces a LinearModel's matrix"):
            kf.update(z, H=np.eye(2), **extra)
    with pytest.raises(TypeError, match=r"^`F` replaces a LinearModel's matrix"):
        kf.predict(F=np.eye(3))


def test_a_failed_step_of_a_timed_model_keeps_the_matrices_of_the_last_one():
    """Audit LL4: `predict(dt=7, Q=<3 x 3>)` raised and kept the belief and step, but F and Q became those of a
    7 s step, where the docs say they are those of the last step predicted."""
    kf = gf.KalmanFilter(gf.model(gf.ConstantVelocity(1, q=0.5), gf.Position(1, r=2.0)),
                         gf.Gaussian([0.0, 1.0], np.eye(2)))
    kf.predict(dt=0.5)
    F, Q, belief = kf.F.copy(), kf.Q.copy(), kf.belief
    with pytest.raises(ValueError, match=r"`Q` must have shape \(2, 2\)"):
        kf.predict(dt=7.0, Q=np.eye(3))
    np.testing.assert_array_equal(kf.F, F)
    np.testing.assert_array_equal(kf.Q, Q)
    assert kf.step == 1 and kf.belief is belief
    kf.update(0.3)  # the update of the step predicted, with its H and R
    again = gf.KalmanFilter(gf.model(gf.ConstantVelocity(1, q=0.5), gf.Position(1, r=2.0)),
                            gf.Gaussian([0.0, 1.0], np.eye(2)))
    again.predict(dt=0.5)
    again.update(0.3)
    np.testing.assert_array_equal(kf.x, again.x)
    np.testing.assert_array_equal(kf.P, again.P)


def test_a_filter_pickled_with_a_writable_s_unpickles_it_read_only():
    """Review R44: a KalmanFilter pickled before S was read-only kept it writable and shared with the steady
    state, so kf.S *= 7 changed every later S (audit LL1's defect, for good)."""
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.01, 0.01]), R=4.0)
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)))
    for z in np.sin(np.arange(80.0)):
        kf.predict()
        kf.update(z)
    state = kf.__getstate__()
    state["S"] = np.array(kf.S)  # as an old pickle held it: a writable array, not among the read-only names
    state["_readonly"] = [name for name in state["_readonly"] if name != "S"]
    old = gf.KalmanFilter.__new__(gf.KalmanFilter)
    old.__setstate__(state)
    assert not old.S.flags.writeable
    np.testing.assert_array_equal(old.S, kf.S)
