"""Asynchronous multi-sensor fusion: gf.fuse_timeline (batch) and gf.Fuser (online)."""

from __future__ import annotations

import copy
import doctest
import pickle
import re

import numpy as np
import pytest
from scipy.linalg import block_diag

import _oracle
import gaussfuse as gf
import gaussfuse.fusion

R_POS = 0.5 * np.eye(2)
R_VEL = np.array([[0.04, 0.01], [0.01, 0.09]])
H_VEL = np.hstack([np.zeros((2, 2)), np.eye(2)])


def _motion():
    return gf.ConstantVelocity(dim=2, q=0.3)


def _sensors():
    return {"pos": gf.Position(dim=2, r=0.5), "vel": gf.LinearSensor(H=H_VEL, R=R_VEL)}


def _prior():
    return gf.Gaussian([0.0, 1.0, 1.0, -0.5], np.diag([4.0, 4.0, 1.0, 1.0]))


def _scenario(seed: int = 0):
    """Position at 1 Hz and velocity at 3.3 Hz, each with a gap, and one simultaneous pair.

    Returns the measurements (time-ordered, as Measurement tuples) and the
    output times.
    """
    rng = np.random.default_rng(seed)
    pos_times = [float(t) for t in range(1, 13) if t not in (5, 6, 7)]
    vel_times = [k / 3.3 for k in range(1, 40) if not 12 <= k <= 18]  # 33 / 3.3 == 10.0
    events = sorted([(t, "pos") for t in pos_times] + [(t, "vel") for t in vel_times],
                    key=lambda e: (e[0], e[1]))
    assert sum(t == 10.0 for t, _ in events) == 2  # the simultaneous pair
    motion, x, t_prev = _motion(), rng.multivariate_normal(_prior().mean, _prior().cov), 0.0
    measurements = []
    for t, name in events:
        if t > t_prev:
            F, Q = motion.transition(t - t_prev)
            x = F @ x + rng.multivariate_normal(np.zeros(4), Q)
            t_prev = t
        if name == "pos":
            z = x[:2] + rng.multivariate_normal(np.zeros(2), R_POS)
        else:
            z = x[2:] + rng.multivariate_normal(np.zeros(2), R_VEL)
        measurements.append(gf.Measurement(t, name, z))
    # One position with its y component missing.
    t, name, z = measurements[3]
    assert name == "pos"
    measurements[3] = gf.Measurement(t, name, np.array([z[0], np.nan]))
    outputs = [2.5, 5.5, 6.2, 12.5]  # between measurements, in both gaps, and after the last
    return measurements, outputs


def _dense_reference(measurements, outputs):
    """The stacked time-varying model written out by hand, conditioned densely (tests/_oracle.py)."""
    times = sorted({m.t for m in measurements} | set(outputs))
    zs = np.full((len(times), 4), np.nan)
    for t, name, z in measurements:
        cols = slice(0, 2) if name == "pos" else slice(2, 4)
        zs[times.index(t), cols] = z
    dts = np.diff(times, prepend=0.0)
    F = np.stack([_motion().transition(dt)[0] for dt in dts])
    Q = np.stack([_motion().transition(dt)[1] for dt in dts])
    H = np.vstack([np.hstack([np.eye(2), np.zeros((2, 2))]), H_VEL])
    R = block_diag(R_POS, R_VEL)
    prior = _prior()
    return np.array(times), _oracle.reference(F, H, Q, R, prior.mean, prior.cov, zs)


@pytest.fixture(scope="module")
def dense():
    measurements, outputs = _scenario()
    return measurements, outputs, *_dense_reference(measurements, outputs)


@pytest.mark.parametrize("smooth", [False, True])
def test_batch_equals_dense_joint_gaussian(smooth, dense):
    measurements, outputs, times, ref = dense
    shuffled = [measurements[i] for i in np.random.default_rng(1).permutation(len(measurements))]
    out = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0, shuffled, times=outputs, smooth=smooth)
    np.testing.assert_array_equal(out.times, times)
    key = "smoothed_" if smooth else ""
    np.testing.assert_allclose(out.means, ref[key + "means"], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(out.covs, ref[key + "covs"], rtol=1e-8, atol=1e-8)
    assert out.loglik == pytest.approx(ref["loglik"], rel=1e-8, abs=1e-8)
    assert isinstance(out.result, gf.SmoothResult if smooth else gf.FilterResult)
    k = int(np.flatnonzero(out.times == 10.0)[0])
    assert sorted(out.sources[k]) == ["pos", "vel"]  # one step, in the order given
    assert [out.sources[int(np.flatnonzero(out.times == t)[0])] for t in outputs] == [None] * 4
    assert out.sources[:4] == ["vel", "vel", "vel", "pos"]
    # Output times, read back.
    means, covs = out.at(outputs)
    idx = [times.tolist().index(t) for t in outputs]
    np.testing.assert_allclose(means, ref[key + "means"][idx], rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(covs, ref[key + "covs"][idx], rtol=1e-8, atol=1e-8)


def _online(measurements, outputs, motion=None, sensors=None, prior=None, method=None):
    """Run a Fuser over the events in time order; the belief after each event, by time."""
    fuser = gf.Fuser(motion or _motion(), sensors or _sensors(), prior or _prior(), 0.0, method=method)
    beliefs = {}
    events = sorted([(m.t, 0, m) for m in measurements] + [(t, 1, None) for t in outputs],
                    key=lambda e: (e[0], e[1]))
    for t, _, m in events:
        belief = fuser.predict(t) if m is None else fuser.update(*m)
        assert belief is fuser.belief and fuser.t == t
        beliefs[t] = belief
    return fuser, beliefs


def test_online_equals_batch():
    measurements, outputs = _scenario()
    out = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0, measurements, times=outputs)
    fuser, beliefs = _online(measurements, outputs)
    assert len(beliefs) == len(out.times)
    for k, t in enumerate(out.times):
        np.testing.assert_allclose(beliefs[t].mean, out.means[k], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(beliefs[t].cov, out.covs[k], rtol=1e-12, atol=1e-12)
    assert fuser.loglik == pytest.approx(out.loglik, rel=1e-12)


def test_sequential_equals_joint_update():
    z_pos, z_vel = np.array([0.3, 1.4]), np.array([0.9, -0.2])
    joint = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0,
                             [(0.7, "pos", z_pos), (0.7, "vel", z_vel)])
    assert joint.times.tolist() == [0.7] and joint.sources == [("pos", "vel")]
    fuser = gf.Fuser(_motion(), _sensors(), _prior(), 0.0)
    fuser.update(0.7, "vel", z_vel)
    fuser.update(0.7, "pos", z_pos)  # the other order, too
    np.testing.assert_allclose(fuser.belief.mean, joint.means[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fuser.belief.cov, joint.covs[0], rtol=1e-12, atol=1e-12)
    assert fuser.loglik == pytest.approx(joint.loglik, rel=1e-12)
    # The joint update by hand: the stacked measurement with the block-diagonal noise.
    F, Q = _motion().transition(0.7)
    H = np.vstack([np.hstack([np.eye(2), np.zeros((2, 2))]), H_VEL])
    m, P = F @ _prior().mean, F @ _prior().cov @ F.T + Q
    S = H @ P @ H.T + block_diag(R_POS, R_VEL)
    K = np.linalg.solve(S, H @ P).T
    np.testing.assert_allclose(joint.means[0], m + K @ (np.r_[z_pos, z_vel] - H @ m), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(joint.covs[0], P - K @ S @ K.T, rtol=1e-10, atol=1e-12)


def test_online_rejects_out_of_order():
    fuser = gf.Fuser(_motion(), _sensors(), _prior(), 0.0)
    fuser.update(2.0, "pos", [0.0, 1.0])
    before = fuser.belief
    msg = ("`t` = 1.5 is earlier than the fuser's current time 2.0: an online Fuser cannot go back "
           "in time (out-of-order measurement); fuse_timeline sorts measurements by time instead.")
    with pytest.raises(ValueError, match=re.escape(msg)):
        fuser.update(1.5, "vel", [1.0, 0.0])
    with pytest.raises(ValueError, match=re.escape(msg)):
        fuser.predict(1.5)
    assert fuser.belief is before and fuser.t == 2.0 and fuser.loglik != 0.0
    with pytest.raises(ValueError, match=r"`t` = -1.0 is earlier than the fuser's current time 0.0"):
        gf.Fuser(_motion(), _sensors(), _prior(), 0.0).predict(-1.0)


def test_an_update_that_fails_leaves_the_fuser_as_it_was(monkeypatch):
    """A sensor that measures nothing with R = 0 has an innovation covariance of 0: the update raises, and it had
    already moved the fuser to its time, so that a measurement at an earlier time was refused as out of order
    (audit X1)."""
    sensors = {"p": gf.Position(dim=1, r=1.0), "nil": gf.LinearSensor(H=[[0.0, 0.0]], R=[[0.0]])}
    fuser = gf.Fuser(gf.ConstantVelocity(dim=1, q=0.5), sensors, gf.Gaussian([0.0, 1.0], np.diag([4.0, 1.0])), 0.0)
    fuser.update(1.0, "p", 0.5)
    before, loglik = fuser.belief, fuser.loglik
    with pytest.raises(np.linalg.LinAlgError):
        fuser.update(5.0, "nil", 1.0)
    assert fuser.belief is before and fuser.t == 1.0 and fuser.loglik == loglik
    with monkeypatch.context() as patch:  # Ctrl-C during the correction
        patch.setattr(gaussfuse.fusion.kalman, "correct", lambda *args, **kwargs: (_ for _ in ()).throw(
            KeyboardInterrupt))
        with pytest.raises(KeyboardInterrupt):
            fuser.update(5.0, "p", 1.0)
    assert fuser.belief is before and fuser.t == 1.0 and fuser.loglik == loglik
    after = fuser.update(2.0, "p", 1.0)
    twin = gf.Fuser(gf.ConstantVelocity(dim=1, q=0.5), sensors, gf.Gaussian([0.0, 1.0], np.diag([4.0, 1.0])), 0.0)
    twin.update(1.0, "p", 0.5)
    np.testing.assert_array_equal(after.mean, twin.update(2.0, "p", 1.0).mean)


def test_batch_sorts_stably():
    measurements, _ = _scenario()
    ordered = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0, measurements)
    reversed_ = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0, (m for m in measurements[::-1]))
    np.testing.assert_array_equal(reversed_.times, ordered.times)
    np.testing.assert_allclose(reversed_.means, ordered.means, rtol=1e-12, atol=1e-12)
    # The same sensor twice at one time: two steps at that time, in the order given.
    z1, z2 = [0.1, 0.9], [0.4, 1.3]
    twice = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0,
                             [(1.0, "vel", [1.0, -0.4]), (1.0, "pos", z1), (1.0, "pos", z2)])
    assert twice.times.tolist() == [1.0, 1.0] and twice.sources == [("vel", "pos"), "pos"]
    first = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0, [(1.0, "vel", [1.0, -0.4]), (1.0, "pos", z1)])
    np.testing.assert_allclose(twice.means[0], first.means[0], rtol=1e-12, atol=1e-12)
    mean, cov = twice.at(1.0)  # after everything at that time
    np.testing.assert_array_equal(mean, twice.means[1])
    fuser = gf.Fuser(_motion(), _sensors(), _prior(), 0.0)
    for name, z in (("vel", [1.0, -0.4]), ("pos", z1), ("pos", z2)):
        fuser.update(1.0, name, z)
    np.testing.assert_allclose(fuser.belief.mean, mean, rtol=1e-12, atol=1e-12)


def test_output_times_between_measurements():
    motion, sensors, prior = _motion(), _sensors(), _prior()
    meas = [(1.0, "pos", [1.0, 0.5]), (3.0, "pos", [2.9, -0.4])]
    out = gf.fuse_timeline(motion, sensors, prior, 0.0, meas, times=[0.0, 1.0, 2.2, 4.0, 2.2])
    assert out.times.tolist() == [0.0, 1.0, 2.2, 3.0, 4.0]
    assert out.sources == [None, "pos", None, "pos", None]
    # At t0 the belief is the prior; between measurements, the prediction.
    np.testing.assert_allclose(out.means[0], prior.mean, rtol=0, atol=0)
    np.testing.assert_allclose(out.covs[0], prior.cov, rtol=0, atol=0)
    F, Q = motion.transition(1.2)
    np.testing.assert_allclose(out.means[2], F @ out.means[1], rtol=1e-12)
    np.testing.assert_allclose(out.covs[2], F @ out.covs[1] @ F.T + Q, rtol=1e-12)
    means, covs = out.at([4.0, 2.2])
    assert means.shape == (2, 4) and covs.shape == (2, 4, 4)
    np.testing.assert_array_equal(means[1], out.means[2])
    mean, cov = out.at(1.0)
    assert mean.shape == (4,) and cov.shape == (4, 4)
    with pytest.raises(ValueError, match=re.escape(
            "`times` must be times of the timeline (measurement times, or output times passed to "
            "fuse_timeline(times=...)); got [2.0, 5.0], which are not.")):
        out.at([1.0, 2.0, 5.0])
    # Smoothed: a step without measurements is smoothed like any other.
    sm = gf.fuse_timeline(motion, sensors, prior, 0.0, meas, times=[2.2], smooth=True)
    assert np.trace(sm.covs[1]) < np.trace(out.covs[2])
    # Only output times: pure prediction from the prior, loglik 0.
    pred = gf.fuse_timeline(motion, sensors, prior, 0.0, [], times=[2.0])
    np.testing.assert_allclose(pred.means[0], motion.transition(2.0)[0] @ prior.mean, rtol=1e-12)
    assert pred.loglik == 0.0 and pred.sources == [None]


def test_fused_is_immutable():
    out = gf.fuse_timeline(_motion(), _sensors(), _prior(), 0.0, [(1.0, "pos", [1.0, 0.5])])
    with pytest.raises(AttributeError):
        out.means = None
    with pytest.raises(ValueError):
        out.means[0, 0] = 1.0


# ---------------------------------------------------------------------------
# Nonlinear motion and sensors
# ---------------------------------------------------------------------------


def _turning_scenario(seed: int = 3):
    motion = gf.CoordinatedTurn(q_acc=0.1, q_turn=1e-3)
    sensors = {"radar": gf.RangeBearing(r_range=1.0, r_bearing=1e-4, origin=(-50.0, 20.0)),
               "gps": gf.Position(dim=2, r=4.0)}
    prior = gf.Gaussian([0.0, 0.0, 8.0, 1.0, 0.05], np.diag([4.0, 4.0, 1.0, 1.0, 1e-3]))
    rng = np.random.default_rng(seed)
    x, t_prev, meas = rng.multivariate_normal(prior.mean, prior.cov), 0.0, []
    # No two at one time: a nonlinear sequential update is not the joint one.
    events = sorted([(0.5 * k, "radar") for k in range(1, 30)] + [(1.3 * k + 0.07, "gps") for k in range(10)])
    for t, name in events:
        x = motion.f(x, t - t_prev)
        t_prev = t
        sensor = sensors[name]
        hx = sensor.h(x) if name == "radar" else x[:2]
        R = sensor.R if name == "radar" else 4.0 * np.eye(2)
        meas.append((t, name, hx + rng.multivariate_normal(np.zeros(2), R)))
    return motion, sensors, prior, meas


@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_nonlinear_online_equals_batch(method):
    motion, sensors, prior, meas = _turning_scenario()
    out = gf.fuse_timeline(motion, sensors, prior, 0.0, meas, times=[3.14], method=method)
    assert isinstance(out.result, gf.FilterResult)
    fuser, beliefs = _online([gf.Measurement(*m) for m in meas], [3.14], motion, sensors, prior, method)
    for k, t in enumerate(out.times):
        np.testing.assert_allclose(beliefs[t].mean, out.means[k], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(beliefs[t].cov, out.covs[k], rtol=1e-10, atol=1e-10)
    assert fuser.loglik == pytest.approx(out.loglik, rel=1e-10)
    assert np.isfinite(out.loglik)


def test_nonlinear_default_is_ekf_and_smoother_runs():
    motion, sensors, prior, meas = _turning_scenario()
    default = gf.fuse_timeline(motion, sensors, prior, 0.0, meas)
    ekf = gf.fuse_timeline(motion, sensors, prior, 0.0, meas, method="ekf")
    np.testing.assert_array_equal(default.means, ekf.means)
    sm = gf.fuse_timeline(motion, sensors, prior, 0.0, meas, smooth=True, method="ukf", alpha=0.5)
    assert isinstance(sm.result, gf.SmoothResult)
    assert np.all(np.trace(sm.covs, axis1=1, axis2=2) <= np.trace(
        gf.fuse_timeline(motion, sensors, prior, 0.0, meas, method="ukf", alpha=0.5).covs, axis1=1, axis2=2
    ) + 1e-9)


def _scaled_scenario(c):
    """A position fix, then a range and bearing: every length times c, every covariance times c² (bearings
    unchanged), so that the result is the c = 1 result scaled, exactly."""
    sensors = {"pos": gf.Position(dim=2, r=0.5 * c * c),
               "rb": gf.RangeBearing(r_range=c * c, r_bearing=1e-3, origin=(5.0 * c, -3.0 * c))}
    events = [(1.0, "pos", c * np.array([1.2, 0.4])), (1.3, "rb", np.array([6.0 * c, 2.5]))]
    prior = gf.Gaussian(c * np.array([0.0, 1.0, 1.0, -0.5]), c * c * np.diag([4.0, 4.0, 1.0, 1.0]))
    return gf.ConstantVelocity(dim=2, q=0.3 * c * c), sensors, prior, events


@pytest.mark.parametrize("form", ["cov", "sqrt"])
@pytest.mark.parametrize("c", [1e-18, 1e-20, 1e-100, 1e100])
def test_units_of_any_size_give_the_same_fusion(c, form):
    """Ranges of 1e-20 beside bearings of 1: the innovation covariance's factor had rows on scales 1e17 apart, and
    its solves exchanged rows (LU with pivoting, not substitution); the range update raised var(x) from 0.615 to
    7.03 (exact: 0.215) in the covariance form, and the square-root form's mean was off by 7e-2 (audit X1)."""
    ref = gf.fuse_timeline(*_scaled_scenario(1.0)[:3], 0.0, _scaled_scenario(1.0)[3], method="ekf", form=form)
    motion, sensors, prior, events = _scaled_scenario(c)
    out = gf.fuse_timeline(motion, sensors, prior, 0.0, events, method="ekf", form=form)
    np.testing.assert_allclose(out.means / c, ref.means, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(out.covs / c / c, ref.covs, rtol=1e-12, atol=1e-14)
    if form == "cov":  # the online fuser's form
        fuser = gf.Fuser(motion, sensors, prior, 0.0, method="ekf")
        for event in events:
            fuser.update(*event)
        np.testing.assert_allclose(fuser.belief.cov / c / c, ref.covs[-1], rtol=1e-12, atol=1e-14)


def test_bearing_innovation_is_wrapped():
    # A target due west of the radar: bearings near ±π on both sides of the cut.
    sensors = {"radar": gf.RangeBearing(r_range=1.0, r_bearing=1e-4)}
    prior = gf.Gaussian([-100.0, 0.0, 0.0, 0.0, 0.0], np.diag([1.0, 1.0, 0.01, 0.01, 1e-6]))
    meas = [(1.0, "radar", [100.0, np.pi - 0.001]), (2.0, "radar", [100.0, -np.pi + 0.001])]
    out = gf.fuse_timeline(gf.CoordinatedTurn(q_acc=0.01, q_turn=1e-6), sensors, prior, 0.0, meas)
    assert np.all(np.abs(out.means[:, 1]) < 0.5)
    assert np.all(np.abs(out.result.innovations[:, 1]) < 0.01)


# ---------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------


def _call(**changes):
    args = dict(motion=_motion(), sensors=_sensors(), prior=_prior(), t0=0.0,
                measurements=[(1.0, "pos", [0.0, 0.0])])
    args.update(changes)
    return gf.fuse_timeline(**args)


@pytest.mark.parametrize("changes, error, message", [
    (dict(motion="cv"), TypeError,
     "`motion` must be a motion model (a LinearMotion or NonlinearMotion, e.g. "
     "gaussfuse.ConstantVelocity); got str."),
    (dict(motion=gf.ForceInput(q=0.1, dim=2)), ValueError,
     "`motion` has a control input (ForceInput); fusion takes no controls"),
    (dict(sensors={}), TypeError, "`sensors` must be a non-empty dict mapping names to sensors; got {}."),
    (dict(sensors={"pos": "gps"}), TypeError,
     "`sensors['pos']` must be a sensor (a LinearSensor, Position or NonlinearSensor, e.g. "
     "gaussfuse.RangeBearing); got str."),
    (dict(sensors={1: gf.Position(dim=2)}), TypeError, "`sensors` must have str keys (sensor names); got 1."),
    (dict(sensors={"p3": gf.Position(dim=3)}), ValueError,
     "`sensors['p3']` reads 3 position components but `motion` has 2 spatial axes."),
    (dict(motion=gf.RandomWalk(n=1), sensors={"rb": gf.RangeBearing()}), ValueError,
     "`sensors['rb']` reads 2 position components but the state of `motion` has only 1."),
    (dict(sensors={"v": gf.LinearSensor(H=[[0.0, 1.0]], R=[[1.0]])}), ValueError,
     "`sensors['v']` has `H` of shape (1, 2), which does not fit the state of `motion` (n = 4); `H` must have 4 columns."),
    (dict(prior=gf.Gaussian([0.0, 0.0], np.eye(2))), ValueError,
     "`prior` must have dimension 4 (the model's state); got 2."),
    (dict(t0="0"), TypeError, "`t0` must be a real number of seconds or a datetime; got '0'."),
    (dict(t0=np.nan), ValueError, "`t0` must be a finite number; got nan."),
    (dict(measurements=5), TypeError,
     "`measurements` must be an iterable of Measurement(t, sensor, z) or (t, sensor, z) tuples; got int."),
    (dict(measurements=[(1.0, "pos")]), TypeError,
     "`measurements[0]` must be a Measurement(t, sensor, z) or a (t, sensor, z) tuple; got (1.0, 'pos')."),
    (dict(measurements=[(1.0, "pos", [0, 0]), (-0.5, "vel", [0, 0])]), ValueError,
     "`measurements[1].t` must not be earlier than `t0` = 0.0 (the prior's time); got -0.5."),
    (dict(measurements=[(1.0, "lidar", [0, 0])]), ValueError,
     "`measurements[0].sensor` must be one of ['pos', 'vel']; got 'lidar'."),
    (dict(measurements=[(1.0, "pos", [0, 0, 0])]), ValueError,
     "`measurements[0].z` must have shape (2,) for sensor 'pos'; got shape (3,)."),
    (dict(measurements=[(1.0, "pos", [0, np.inf])]), ValueError,
     "`measurements[0].z` must be finite; got an infinite value at index (1,)."),
    (dict(measurements=[(None, "pos", [0, 0])]), TypeError,
     "`measurements[0].t` must be a real number of seconds or a datetime; got None."),
    (dict(times=[[1.0]]), ValueError, "`times` must have shape () or (k,); got shape (1, 1)."),
    (dict(times=[2.0, -1.0]), ValueError,
     "`times` must not be earlier than `t0` = 0.0 (the prior's time); got -1.0."),
    (dict(measurements=[]), ValueError,
     "`measurements` and `times` are both empty: there is nothing to estimate."),
    (dict(smooth="yes"), TypeError, "`smooth` must be True or False; got 'yes'."),
    (dict(keep="last"), TypeError, "`keep` is not an option of fuse_timeline: it returns every step."),
    # gf.filter's own arguments, which the timeline sets: a bare "multiple values" TypeError, and `steady` an error
    # about a time-varying `model` the caller never passed (audit AA1)
    (dict(us=[1.0]), TypeError, "`us` is not an option of fuse_timeline: the motions it takes have no control input."),
    (dict(zs=[1.0]), TypeError, "`zs` is not an option of fuse_timeline: the measurements are `measurements`"),
    (dict(model=None), TypeError, "`model` is not an option of fuse_timeline: the model is the motion and the sensors"),
    (dict(steady=True), TypeError, "`steady` is not an option of fuse_timeline: each step has its own dt"),
    (dict(method="ekf"), TypeError, "method 'ekf' does not apply to a LinearModel; valid methods for it are ['kf']."),
    (dict(alpha=0.5), TypeError, "unknown option(s) ['alpha'] for method 'kf'; valid options are none."),
    # `engine` is gf.filter's (numba for long timelines; checked equal to python to 1e-15 by hand).
    (dict(engine="gpu"), ValueError, "`engine` must be one of ['auto', 'python', 'numba']; got 'gpu'."),
])
def test_fuse_timeline_validation(changes, error, message):
    with pytest.raises(error, match=re.escape(message)):
        _call(**changes)


def test_fuser_validation():
    fuser = gf.Fuser(_motion(), _sensors(), _prior(), 0.0)
    with pytest.raises(ValueError, match=re.escape("`sensor` must be one of ['pos', 'vel']; got 'gps'.")):
        fuser.update(1.0, "gps", [0.0, 0.0])
    with pytest.raises(ValueError, match=re.escape("`z` must have shape (2,) for sensor 'vel'; got shape ().")):
        fuser.update(1.0, "vel", 3.0)
    with pytest.raises(TypeError, match=re.escape("`t` must be a real number of seconds or a datetime; got '1'.")):
        fuser.predict("1")
    assert fuser.t == 0.0 and fuser.loglik == 0.0  # nothing happened
    motion, sensors, prior, _ = _turning_scenario()
    with pytest.raises(ValueError, match=re.escape(
            "`method` 'iekf' iterates over the whole series; the online Fuser takes "
            "'kf', 'ekf', 'ukf', 'ckf' or 'ghkf'.")):
        gf.Fuser(motion, sensors, prior, 0.0, method="iekf")
    with pytest.raises(TypeError, match=re.escape("unknown option(s) ['order'] for method 'ekf'")):
        gf.Fuser(motion, sensors, prior, 0.0, order=3)
    with pytest.raises(TypeError, match=re.escape("`prior` must be a gaussfuse.Gaussian(mean, cov); got list.")):
        gf.Fuser(_motion(), _sensors(), [0.0] * 4, 0.0)


def test_a_fusers_belief_and_time_are_checked_when_set():
    """Audit HH2: they were plain attributes, and a wrong one failed at the next update with NumPy's matmul error
    (a 3-state belief), an AttributeError (a tuple) or a comparison of a float with a str (a time of 'noon')."""
    fuser = gf.Fuser(_motion(), _sensors(), _prior(), 0.0)
    with pytest.raises(ValueError, match=re.escape("`belief` must have dimension 4 (the model's state); got 3.")):
        fuser.belief = gf.Gaussian(np.zeros(3), np.eye(3))
    with pytest.raises(TypeError, match=re.escape("`belief` must be a gaussfuse.Gaussian(mean, cov); got tuple.")):
        fuser.belief = (np.zeros(4), np.eye(4))
    with pytest.raises(TypeError, match=re.escape("`t` must be a real number of seconds or a datetime; got 'noon'.")):
        fuser.t = "noon"
    with pytest.raises(TypeError, match=re.escape("`t` must be a real number of seconds, as `t0` is")):
        fuser.t = np.datetime64("2026-01-01")
    assert fuser.t == 0.0 and fuser.belief is not None
    restarted = gf.Gaussian(np.ones(4), 2.0 * np.eye(4))  # a track restarted by hand, at 5 s
    fuser.belief, fuser.t = restarted, 5
    fresh = gf.Fuser(_motion(), _sensors(), restarted, 5.0)
    for f in (fuser, fresh):
        f.update(6.0, "pos", [1.0, 2.0])
    np.testing.assert_array_equal(fuser.belief.mean, fresh.belief.mean)
    assert fuser.t == 6.0 and isinstance(fuser.t, float)


def test_a_motion_that_overflows_over_one_second_fuses_steps_of_milliseconds():
    """Audit HH1: fuse_timeline and Fuser built a model over 1 s first, which a LinearSDE of rate 800/s overflows
    (StepOverflowError naming a step of 1 s nobody gave), where filter(times=...) and KalmanFilter take it."""
    motion, sensor = gf.LinearSDE([[800.0]], [1.0], 1.0), gf.LinearSensor(H=1.0, R=1.0)
    prior, ts, zs = gf.Gaussian([0.0], [[1.0]]), 1e-3 * np.arange(1, 6), np.array([0.1, 0.2, 0.3, 0.5, 0.8])
    want = gf.filter(gf.model(motion, sensor), prior, zs, times=np.r_[0.0, ts])
    timeline = gf.fuse_timeline(motion, {"s": sensor}, prior, 0.0, [(t, "s", z) for t, z in zip(ts, zs)])
    np.testing.assert_allclose(timeline.means, want.means, rtol=1e-13)
    fuser = gf.Fuser(motion, {"s": sensor}, prior, 0.0)
    for t, z in zip(ts, zs):
        fuser.update(t, "s", z)
    np.testing.assert_allclose(fuser.belief.mean, want.last_mean, rtol=1e-13)
    np.testing.assert_allclose(fuser.belief.cov, want.last_cov, rtol=1e-13)
    calls = []
    real = gaussfuse.fusion._Timeline.model_over
    fuser._timeline.model_over = lambda dt: calls.append(dt) or real(fuser._timeline, dt)
    fuser.update(6e-3, "s", 1.0)
    assert 1.0 not in calls  # the step that overflowed is found once, not tried again at each update (review R43)


def test_a_fuser_pickled_with_plain_belief_and_time_attributes_unpickles_with_them():
    """Review R43: `belief` and `t` became properties; a Fuser pickled before kept them in its __dict__."""
    fuser = gf.Fuser(_motion(), _sensors(), _prior(), 0.0)
    fuser.update(1.0, "pos", [1.0, 2.0])
    state = dict(fuser.__dict__)
    state["belief"], state["t"] = state.pop("_belief"), state.pop("_t")  # as pickled before
    old = gf.Fuser.__new__(gf.Fuser)
    old.__setstate__(state)
    assert old.t == 1.0 and old.belief is fuser.belief
    old.update(2.0, "pos", [1.0, 2.0])


def test_scalar_sensor_and_nan_component():
    motion = gf.ConstantVelocity(dim=1, q=0.1)
    sensors = {"gps": gf.Position(dim=1, r=4.0), "both": gf.LinearSensor(H=np.eye(2), R=np.eye(2))}
    prior = gf.Gaussian([0.0, 1.0], np.diag([10.0, 1.0]))
    out = gf.fuse_timeline(motion, sensors, prior, 0.0, [(1.0, "gps", 1.2), (2.0, "both", [np.nan, 0.8])])
    # The second step observed only the velocity component of "both".
    only_vel = gf.fuse_timeline(motion, {**sensors, "v": gf.LinearSensor(H=[[0.0, 1.0]], R=[[1.0]])}, prior,
                                0.0, [(1.0, "gps", 1.2), (2.0, "v", 0.8)])
    np.testing.assert_allclose(out.means, only_vel.means, rtol=1e-12, atol=1e-12)
    assert out.loglik == pytest.approx(only_vel.loglik, rel=1e-12)
    fuser = gf.Fuser(motion, sensors, prior, 0.0)
    fuser.update(1.0, "gps", 1.2)
    fuser.update(2.0, "both", [np.nan, 0.8])
    np.testing.assert_allclose(fuser.belief.mean, out.means[-1], rtol=1e-12, atol=1e-12)


def test_docstring_examples():
    result = doctest.testmod(gaussfuse.fusion, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("method", ["ekf", "ukf"])
def test_a_pickled_or_copied_fuser_carries_on_where_the_original_left_off(method):
    sensors = {"gps": gf.Position(dim=2, r=0.5), "radar": gf.RangeBearing(r_range=0.1, r_bearing=1e-3)}
    fuser = gf.Fuser(gf.ConstantVelocity(dim=2, q=0.1), sensors,
                     gf.Gaussian([1.0, 0.0, 1.0, 1.0], 4.0 * np.eye(4)), 0.0, method=method)
    fuser.update(1.0, "radar", [1.9, 0.5])
    others = [pickle.loads(pickle.dumps(fuser)), copy.copy(fuser), copy.deepcopy(fuser)]
    for f in [fuser, *others]:
        f.update(1.5, "gps", [2.4, 0.9])
        f.update(2.0, "radar", [2.9, 0.6])
    for other in others:
        assert other.t == fuser.t == 2.0
        np.testing.assert_array_equal(other.belief.mean, fuser.belief.mean)
        np.testing.assert_array_equal(other.belief.cov, fuser.belief.cov)
        assert other.loglik == fuser.loglik


def test_datetimes_in_any_zone_give_the_fusion_in_seconds_from_t0():
    """fuse_timeline and Fuser take datetime, numpy.datetime64 and pandas.Timestamp (any time zone): the same
    numbers as the seconds from t0 they stand for; the result's times are the UTC instants, exactly."""
    import datetime

    import pandas as pd

    motion, sensors = gf.ConstantVelocity(dim=1, q=0.1), {"gps": gf.Position(dim=1, r=1.0)}
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    t0 = pd.Timestamp("2026-03-29 03:00:00", tz="Europe/Paris")  # just after the change to summer time
    utc = np.datetime64("2026-03-29T01:00:00", "ns")
    seconds = [1.0, 2.5, 4.0]
    stamped = [(t0 + pd.Timedelta(seconds=s), "gps", s + 0.1) for s in seconds]
    plain = [(s, "gps", s + 0.1) for s in seconds]
    a = gf.fuse_timeline(motion, sensors, prior, t0, stamped)
    b = gf.fuse_timeline(motion, sensors, prior, 0.0, plain)
    np.testing.assert_allclose(a.means, b.means, rtol=1e-15)
    assert a.times.dtype.kind == "M"  # in the Timestamps' own resolution
    np.testing.assert_array_equal(a.times, utc + (np.array(seconds) * 1e9).astype("timedelta64[ns]"))
    fuser = gf.Fuser(motion, sensors, prior, datetime.datetime(2026, 3, 29, 1, 0, 0))  # t0 in UTC, naive
    fuser.update(np.datetime64("2026-03-29T01:00:01"), "gps", 1.1)
    online = gf.Fuser(motion, sensors, prior, 0.0)
    online.update(1.0, "gps", 1.1)
    np.testing.assert_allclose(fuser.belief.mean, online.belief.mean, rtol=1e-15)
    assert fuser.t == np.datetime64("2026-03-29T01:00:01") and fuser.t.dtype == np.dtype("datetime64[us]")
    with pytest.raises(TypeError, match="a real number of seconds or a datetime"):
        gf.Fuser(motion, sensors, prior, "2026-01-01")
    # output times and Fused.at take them too ("`times` must be an array of real numbers" before)
    outputs = [t0 + pd.Timedelta(seconds=3.0), np.datetime64("2026-03-29T01:00:05")]
    c = gf.fuse_timeline(motion, sensors, prior, t0, stamped, times=outputs)
    d = gf.fuse_timeline(motion, sensors, prior, 0.0, plain, times=[3.0, 5.0])
    np.testing.assert_allclose(c.means, d.means, rtol=1e-15)
    for when, seconds_ in ((outputs[0], 3.0), (outputs[1], 5.0), (stamped[1][0].to_pydatetime(), 2.5)):
        np.testing.assert_allclose(c.at(when)[0], d.at(seconds_)[0], rtol=1e-15)
    np.testing.assert_allclose(c.at(pd.DatetimeIndex(outputs[:1]))[0], d.at([3.0])[0], rtol=1e-15)
    with pytest.raises(ValueError, match=r"got \['2026-03-29T01:00:03.000000001'\], which are not"):
        c.at(utc + np.timedelta64(3_000_000_001, "ns"))


def test_datetimes_and_seconds_are_not_mixed():
    """A number among datetimes (or a datetime among seconds) was read as seconds since 1970: a step of 56 years."""
    motion, sensors = gf.ConstantVelocity(dim=1, q=0.1), {"gps": gf.Position(dim=1, r=1.0)}
    prior, day = gf.Gaussian([0.0, 1.0], np.eye(2)), np.datetime64("2026-01-01T00:00:00")
    with pytest.raises(TypeError, match=r"^`measurements\[0\]\.t` must be a datetime, as `t0` is; got 1\.0\.$"):
        gf.fuse_timeline(motion, sensors, prior, day, [(1.0, "gps", 1.0)])
    with pytest.raises(TypeError, match=r"^`measurements\[0\]\.t` must be a real number of seconds, as `t0` is"):
        gf.fuse_timeline(motion, sensors, prior, 0.0, [(day, "gps", 1.0)])
    with pytest.raises(TypeError, match=r"^`times\[0\]` must be a datetime, as `t0` is"):
        gf.fuse_timeline(motion, sensors, prior, day, [(day, "gps", 1.0)], times=[2.0])
    out = gf.fuse_timeline(motion, sensors, prior, 0.0, [(1.0, "gps", 1.0)])
    with pytest.raises(TypeError, match=r"^`times` must be a real number of seconds, as `t0` is"):
        out.at(day)
    fuser = gf.Fuser(motion, sensors, prior, day)
    with pytest.raises(TypeError, match=r"^`t` must be a datetime, as `t0` is; got 5\.$"):
        fuser.update(5, "gps", 1.0)
    with pytest.raises(TypeError, match=r"^`t` must be a datetime, as `t0` is"):
        fuser.predict(5.0)


@pytest.mark.parametrize("step", [1e-3, 1e-5, 1e-7])
def test_datetime_steps_are_exact_long_after_1970(step):
    """Datetimes were float seconds since 1970, resolved to 2.4e-7 s in 2026: each 1 ms step was off by up to
    2.4e-4 of itself, a 10 µs step by 2.4%, and 100 ns steps fell onto one time. Against the same fusion on
    seconds from t0, whose steps are exact to round-off."""
    pd = pytest.importorskip("pandas")
    motion, sensors = gf.ConstantVelocity(dim=1, q=4.0), {"a": gf.Position(dim=1, r=1e-6)}
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    rng = np.random.default_rng(5)
    counts = np.cumsum(rng.integers(1, 4, size=200))  # 1 to 3 steps apart
    zs = np.cumsum(rng.normal(size=200)) * step
    base = pd.Timestamp("2026-11-30 17:45:12.123456789")
    nanoseconds = int(round(step * 1e9))
    stamped = [(base + pd.Timedelta(int(c) * nanoseconds, "ns"), "a", z) for c, z in zip(counts, zs)]
    plain = [(int(c) * nanoseconds / 1e9, "a", z) for c, z in zip(counts, zs)]
    for smooth in (False, True):
        got = gf.fuse_timeline(motion, sensors, prior, base, stamped, smooth=smooth)
        want = gf.fuse_timeline(motion, sensors, prior, 0.0, plain, smooth=smooth)
        assert got.times.size == want.times.size == 200
        np.testing.assert_allclose(got.means, want.means, rtol=1e-9, atol=1e-12 * np.abs(want.means).max())
        np.testing.assert_allclose(got.covs, want.covs, rtol=1e-9, atol=0)
        assert abs(got.loglik - want.loglik) <= 1e-9 * abs(want.loglik)
    online, seconds = gf.Fuser(motion, sensors, prior, base), gf.Fuser(motion, sensors, prior, 0.0)
    for (t, _, z), (s, _, _) in zip(stamped, plain):
        online.update(t, "a", z)
        seconds.update(s, "a", z)
    np.testing.assert_allclose(online.belief.mean, seconds.belief.mean, rtol=1e-9)
    assert online.t == np.datetime64(stamped[-1][0].to_datetime64())


def test_a_divergence_warning_points_at_the_caller():
    """It was attributed to gaussfuse/fusion.py, where gf.filter's points at the caller's line."""
    motion, sensors = gf.ConstantVelocity(dim=1, q=0.001), {"gps": gf.Position(dim=1, r=0.01)}
    quadratic = [(float(t), "gps", float(t) ** 2) for t in range(1, 60)]
    with pytest.warns(gf.DivergenceWarning) as caught:
        gf.fuse_timeline(motion, sensors, gf.Gaussian([0.0, 0.0], np.eye(2)), 0.0, quadratic)
    assert caught[0].filename == __file__
    with pytest.raises(gf.DivergenceWarning):
        gf.fuse_timeline(motion, sensors, gf.Gaussian([0.0, 0.0], np.eye(2)), 0.0, quadratic, check="raise")
    with pytest.raises(ValueError, match="`check` must be one of"):
        gf.fuse_timeline(motion, sensors, gf.Gaussian([0.0, 0.0], np.eye(2)), 0.0, quadratic, check="loud")


@pytest.mark.parametrize("t0, t", [(np.datetime64("2300-05-01"), np.datetime64("2300-05-02")),
                                   (np.datetime64("2262-01-01"), np.datetime64("2262-06-01")),
                                   (__import__("datetime").datetime(1600, 5, 1), __import__("datetime").datetime(1600, 5, 2))])
def test_datetimes_outside_the_nanosecond_range_are_read_in_their_own_unit(t0, t):
    """Every datetime went through int64 nanoseconds, which wrap outside 1678-2262: 2300-05-02 came back as
    1715, 1600 as 2184, and a span across 2262-04-11 was "earlier than t0". Against the same fusion in seconds."""
    motion, sensors = gf.ConstantVelocity(dim=1, q=0.5), {"a": gf.Position(dim=1, r=1.0)}
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    got = gf.fuse_timeline(motion, sensors, prior, t0, [(t, "a", 1.0)])
    span = (np.datetime64(t, "D") - np.datetime64(t0, "D")) / np.timedelta64(1, "s")
    want = gf.fuse_timeline(motion, sensors, prior, 0.0, [(span, "a", 1.0)])
    assert got.times[0] == np.datetime64(t)
    np.testing.assert_allclose(got.means, want.means, rtol=1e-12)


def test_a_timestamps_nanoseconds_and_bad_times_are_read_or_named():
    """A pandas Timestamp's nanoseconds were dropped (fixes 200 ns and 700 ns after t0 both landed on t0); NaT
    gave a bare NumPy error and a timedelta64 a TypeError naming nothing."""
    pd = pytest.importorskip("pandas")
    motion, sensors = gf.ConstantVelocity(dim=1, q=0.5), {"a": gf.Position(dim=1, r=1.0)}
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    base = pd.Timestamp("2026-05-01 12:00:00")
    out = gf.fuse_timeline(motion, sensors, prior, base, [(base + pd.Timedelta(200, "ns"), "a", 0.0),
                                                          (base + pd.Timedelta(700, "ns"), "a", 0.0)])
    assert out.times.size == 2 and np.diff(out.times)[0] == np.timedelta64(500, "ns")
    with pytest.raises(ValueError, match=r"^`measurements\[0\]\.t` must be a time; got NaT\.$"):
        gf.fuse_timeline(motion, sensors, prior, base, [(pd.NaT, "a", 0.0)])
    with pytest.raises(TypeError, match=r"a duration, not a time"):
        gf.fuse_timeline(motion, sensors, prior, 0.0, [(np.timedelta64(1, "s"), "a", 0.0)])
    with pytest.raises(ValueError, match=r"`measurements\[0\]\.t` holds 2300-01-01T00:00:00, which "
                                         r"datetime64\[ns\] \(the finest resolution among the times\) cannot hold"):
        gf.fuse_timeline(motion, sensors, prior, np.datetime64("2026-05-01T12:00:00.000000001"),
                         [(np.datetime64("2300-01-01T00:00:00"), "a", 0.0)])


def test_an_online_fuser_keeps_a_bounded_number_of_models():
    """It made and kept one model for each distinct step length: 5,000 updates kept 5,001 (5 MB)."""
    fuser = gf.Fuser(gf.ConstantVelocity(dim=1, q=0.5), {"a": gf.Position(dim=1, r=1.0)},
                     gf.Gaussian([0.0, 1.0], np.eye(2)), t0=0.0)
    t = 0.0
    for k in range(600):
        t += 1.0 + k * 1e-3
        fuser.update(t, "a", t)
    assert len(fuser._timeline._models) <= gaussfuse.fusion._KEPT


def test_a_fusers_divergence_warning_names_datetime_times_in_full():
    """The window was printed with {:g}: seconds since 1970 showed as 1.77764e+09 at both ends; now the datetimes."""
    pd = pytest.importorskip("pandas")
    base = pd.Timestamp("2026-05-01 12:00:00")
    fuser = gf.Fuser(gf.ConstantVelocity(dim=1, q=0.01), {"a": gf.Position(dim=1, r=0.01)},
                     gf.Gaussian([0.0, 0.0], 0.01 * np.eye(2)), base)
    with pytest.warns(gf.DivergenceWarning) as caught:
        for i in range(1, 70):
            fuser.update(base + pd.Timedelta(seconds=0.5 * i), "a", float(i * i))  # a target it cannot follow
    start, stop = (np.datetime64(t) for t in re.search(r"times (\S+) to (\S+)", str(caught[0].message)).groups())
    assert base.to_datetime64() < start < stop <= base.to_datetime64() + np.timedelta64(35, "s")


def test_times_further_apart_than_the_largest_float_are_named():
    """-1e308 s then 1e308 s gave "`dt` must be a positive number; got inf", naming an argument nobody passed
    (audit F); `filter(times=...)` named the step."""
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    motion, sensors = gf.ConstantVelocity(dim=1, q=0.5), {"a": gf.Position(dim=1, r=1.0)}
    message = r"^the times -1e\+308 s and 1e\+308 s are further apart than the largest float64 \(dt = inf s\)"
    with pytest.raises(ValueError, match=message):
        gf.fuse_timeline(motion, sensors, prior, -1e308, [(1e308, "a", 1.0)])
    with pytest.raises(ValueError, match=message):
        gf.Fuser(motion, sensors, prior, -1e308).update(1e308, "a", 1.0)


def test_datetimes_of_two_dimensions_are_a_shape_error():
    """A 2-D array of datetimes as `times` (fuse_timeline, Fused.at) raised "`times[0]` must be a real number of
    seconds or a datetime; got array([...])"; numbers gave the shape error (audit F)."""
    t0 = np.datetime64("2026-01-01T00:00:00")
    query = np.array([[t0]])
    motion, sensors = gf.ConstantVelocity(dim=1, q=0.5), {"a": gf.Position(dim=1, r=1.0)}
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    message = re.escape("`times` must have shape () or (k,); got shape (1, 1).")
    with pytest.raises(ValueError, match=message):
        gf.fuse_timeline(motion, sensors, prior, t0, [(t0 + np.timedelta64(1, "s"), "a", 1.0)], times=query)
    fused = gf.fuse_timeline(motion, sensors, prior, t0, [(t0 + np.timedelta64(1, "s"), "a", 1.0)])
    with pytest.raises(ValueError, match=message):
        fused.at(query)


def test_a_motion_counting_steps_refuses_dated_times_in_fusion():
    """Audit MM1, as in gf.filter: a LocalLevel fused at daily dates stepped by 86400 of its steps a day."""
    days = np.arange("2024-01-01", "2024-01-06", dtype="datetime64[D]")
    sensors, prior = {"a": gf.LinearSensor([[1.0]], 1.0)}, gf.Gaussian([0.0], [[1.0]])
    with pytest.raises(ValueError, match=r"^`t0` gives dates or durations, but LocalLevel counts steps"):
        gf.fuse_timeline(gf.LocalLevel(q=0.5), sensors, prior, days[0], [(d, "a", [1.0]) for d in days[1:]])
    with pytest.raises(ValueError, match=r"^`t0` gives dates or durations, but LocalLevel counts steps"):
        gf.Fuser(gf.LocalLevel(q=0.5), sensors, prior, days[0])
    fused = gf.fuse_timeline(gf.LocalLevel(q=0.5), sensors, prior, 0.0, [(k, "a", [1.0]) for k in range(1, 5)])
    want = gf.filter(gf.model(gf.LocalLevel(q=0.5), sensors["a"], dt=1), prior, np.ones(4))
    np.testing.assert_allclose(fused.means, want.means, rtol=1e-15)
