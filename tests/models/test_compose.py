"""`model(motion, sensor, dt)`: combining a motion and a sensor into a filterable model."""

from __future__ import annotations

import contextlib
import doctest
import importlib
import io
import pickle

import numpy as np
import pytest

import gaussfuse as gf
import gaussfuse._linalg
from gaussfuse.linearize.taylor import jacobian

compose_module = importlib.import_module("gaussfuse.models.compose")


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("dt", [0.1, 1.5])
def test_linear_combination_equals_the_one_call_models(dim, dt):
    q, r = 0.7, 0.3
    built = gf.model(gf.ConstantVelocity(dim, q), gf.Position(dim, r), dt)
    assert isinstance(built, gf.LinearModel)
    ref = gf.constant_velocity(dt, q, r, dim)
    for name in ("F", "H", "Q", "R"):
        np.testing.assert_array_equal(getattr(built, name), getattr(ref, name))
    assert built.B is None and ref.B is None
    # ... and the closed forms, independently: per axis F = [[1, dt], [0, 1]], Q = q [[dt³/3, dt²/2], [dt²/2, dt]].
    eye = np.eye(dim)
    np.testing.assert_allclose(built.F, np.kron([[1, dt], [0, 1]], eye), rtol=1e-15)
    np.testing.assert_allclose(built.Q, q * np.kron([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]], eye), rtol=1e-14)
    np.testing.assert_array_equal(built.H, np.hstack([eye, np.zeros((dim, dim))]))
    np.testing.assert_array_equal(built.R, r * eye)
    acc = gf.model(gf.ConstantAcceleration(dim, q), gf.Position(dim, r), dt)
    ref = gf.constant_acceleration(dt, q, r, dim)
    for name in ("F", "H", "Q", "R"):
        np.testing.assert_array_equal(getattr(acc, name), getattr(ref, name))


def test_linear_combination_with_control_and_general_sensor():
    dt = 0.4
    model = gf.model(gf.ForceInput(q=0.1, dim=2), gf.LinearSensor(np.eye(4)[2:], 0.2 * np.eye(2)), dt)
    assert isinstance(model, gf.LinearModel)
    np.testing.assert_array_equal(model.B, gf.ForceInput(dim=2).control(dt))
    np.testing.assert_array_equal(model.H, np.eye(4)[2:])
    assert (model.n, model.m, model.p) == (4, 2, 2)


def test_linear_motion_with_nonlinear_sensor():
    dt = 0.5
    motion = gf.ConstantVelocity(dim=2, q=0.3)
    sensor = gf.RangeBearing(r_range=2.0, r_bearing=1e-3, origin=(1.0, 2.0))
    model = gf.model(motion, sensor, dt)
    assert isinstance(model, gf.NonlinearModel)
    F, Q = motion.transition(dt)
    x = np.array([10.0, -4.0, 1.0, 2.0])
    np.testing.assert_allclose(model.f(x), F @ x, rtol=1e-15)
    np.testing.assert_array_equal(model.f_jacobian(x), F)
    np.testing.assert_array_equal(model.h(x), sensor.h(x))
    np.testing.assert_array_equal(model.h_jacobian(x), sensor.jacobian(x))
    np.testing.assert_array_equal(model.Q, Q)
    np.testing.assert_array_equal(model.R, sensor.R)
    np.testing.assert_array_equal(model.measurement_angles, [False, True])
    np.testing.assert_array_equal(model.state_angles, [False] * 4)
    # Stacks of states, as sigma-point filters pass them.
    X = np.stack([x, 2 * x, -x])
    np.testing.assert_allclose(model.transition(X), X @ F.T, rtol=1e-15)
    np.testing.assert_array_equal(model.measurement(X), sensor.h(X))


def test_controlled_linear_motion_with_nonlinear_sensor_takes_u():
    dt = 0.5
    motion = gf.ForceInput(q=0.0, dim=2)
    model = gf.model(motion, gf.BearingOnly(), dt)
    assert isinstance(model, gf.NonlinearModel)
    F, _ = motion.transition(dt)
    B = motion.control(dt)
    x, u = np.array([1.0, 2.0, 3.0, 4.0]), np.array([0.5, -1.0])
    np.testing.assert_allclose(model.f(x, u), F @ x + B @ u, rtol=1e-15)
    np.testing.assert_allclose(model.transition(x, u), F @ x + B @ u, rtol=1e-15)
    np.testing.assert_array_equal(model.f_jacobian(x, u), F)
    np.testing.assert_array_equal(model.measurement_angles, [True])


def test_nonlinear_motion_with_linear_sensor():
    dt = 1.0
    motion = gf.CoordinatedTurn(q_acc=0.5, q_turn=0.02)
    model = gf.model(motion, gf.Position(dim=2, r=0.25), dt)
    assert isinstance(model, gf.NonlinearModel)
    x = np.array([1.0, 2.0, 3.0, 4.0, 0.3])
    np.testing.assert_array_equal(model.f(x), motion.f(x, dt))
    np.testing.assert_array_equal(model.f_jacobian(x), motion.jacobian(x, dt))
    np.testing.assert_array_equal(model.h(x), [1.0, 2.0])
    np.testing.assert_array_equal(model.h_jacobian(x), np.eye(2, 5))
    np.testing.assert_array_equal(model.Q, motion.noise(dt))
    np.testing.assert_array_equal(model.R, 0.25 * np.eye(2))
    assert not model.state_angles.any() and not model.measurement_angles.any()


@pytest.mark.parametrize("sensor", [gf.RangeBearing(origin=(3.0, -1.0)), gf.BearingOnly(origin=(-2.0, 4.0))],
                         ids=["rb", "bo"])
def test_nonlinear_combination_jacobians_match_automatic_ones(sensor):
    dt = 0.7
    model = gf.model(gf.CoordinatedTurn(), sensor, dt)
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = np.r_[rng.normal(scale=20, size=2), rng.normal(scale=5, size=2), rng.normal(scale=0.5)]
        Jf = jacobian("f", model.f, x, (), 5, vectorized=True)
        Jh = jacobian("h", model.h, x, (), model.m, vectorized=True)
        np.testing.assert_allclose(model.f_jacobian(x), Jf, rtol=0, atol=1e-8 * max(1.0, np.max(np.abs(Jf))))
        np.testing.assert_allclose(model.h_jacobian(x), Jh, rtol=1e-8, atol=1e-8 * np.max(np.abs(Jh)))


def test_three_dimensional_combination():
    model = gf.model(gf.ConstantVelocity(dim=3, q=1.0), gf.RangeBearingElevation(), 1.0)
    x = np.array([3.0, 4.0, 12.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(model.h(x)[0], 13.0, rtol=1e-15)
    assert (model.n, model.m) == (6, 3)
    np.testing.assert_array_equal(model.measurement_angles, [False, True, False])


# -- an EKF on a simulated coordinated-turn track ---------------------------------------


def simulate(motion, sensor, dt, T, x0, seed):
    rng = np.random.default_rng(seed)
    Q = motion.noise(dt)
    xs, zs = np.empty((T, 5)), np.empty((T, sensor.m))
    x = x0
    for k in range(T):
        x = motion.f(x, dt) + rng.multivariate_normal(np.zeros(5), Q)
        xs[k] = x
        zs[k] = sensor.h(x) + rng.multivariate_normal(np.zeros(sensor.m), sensor.R)
    zs[:, 1] = gf._linalg.wrap_angle(zs[:, 1])
    return xs, zs


@pytest.fixture(scope="module")
def turn_track():
    dt, T = 1.0, 120
    motion = gf.CoordinatedTurn(q_acc=0.05, q_turn=1e-6)
    sensor = gf.RangeBearing(r_range=4.0, r_bearing=1e-4, origin=(0.0, 0.0))
    x0 = np.array([-250.0, -400.0, 5.0, 10.0, 0.02])  # a turn that takes the track across the -x axis
    xs, zs = simulate(motion, sensor, dt, T, x0, seed=11)
    prior = gf.Gaussian(x0 + np.array([5.0, -5.0, 1.0, -1.0, 0.01]), np.diag([100.0, 100.0, 4.0, 4.0, 1e-3]))
    return motion, sensor, dt, xs, zs, prior


def test_ekf_tracks_a_coordinated_turn(turn_track):
    motion, sensor, dt, xs, zs, prior = turn_track
    # The bearing crosses ±π during the run: the angle flag must do its job.
    assert np.any(np.abs(np.diff(zs[:, 1])) > np.pi)
    model = gf.model(motion, sensor, dt)
    res = gf.filter(model, prior, zs, method="ekf")
    err = np.hypot(*(res.means[20:, :2] - xs[20:, :2]).T)
    # Raw measurements converted to positions, for scale.
    raw = np.c_[zs[:, 0] * np.cos(zs[:, 1]), zs[:, 0] * np.sin(zs[:, 1])]
    raw_err = np.hypot(*(raw[20:] - xs[20:, :2]).T)
    rmse, raw_rmse = np.sqrt(np.mean(err**2)), np.sqrt(np.mean(raw_err**2))
    assert rmse < 0.6 * raw_rmse
    assert rmse < 4.5
    np.testing.assert_allclose(res.means[-1, 4], xs[-1, 4], atol=3e-3)  # the turn rate is learnt
    assert np.isfinite(res.loglik)


def test_ekf_uses_the_analytic_jacobians(turn_track, monkeypatch):
    motion, sensor, dt, xs, zs, prior = turn_track
    calls = {"f": 0, "h": 0}
    f_jac, h_jac = gf.CoordinatedTurn.jacobian, gf.RangeBearing.jacobian

    def counted_f(self, x, dt):
        calls["f"] += 1
        return f_jac(self, x, dt)

    def counted_h(self, x):
        calls["h"] += 1
        return h_jac(self, x)

    monkeypatch.setattr(gf.CoordinatedTurn, "jacobian", counted_f)
    monkeypatch.setattr(gf.RangeBearing, "jacobian", counted_h)
    model = gf.model(motion, sensor, dt)
    analytic = gf.filter(model, prior, zs, method="ekf")
    assert calls == {"f": len(zs), "h": len(zs)}
    # The same model with automatic Jacobians gives the same filter.
    automatic = gf.NonlinearModel(model.f, model.h, model.Q, model.R, vectorized=True,
                                  state_angles=np.flatnonzero(model.state_angles),
                                  measurement_angles=np.flatnonzero(model.measurement_angles))
    auto = gf.filter(automatic, prior, zs, method="ekf")
    assert calls == {"f": len(zs), "h": len(zs)}  # not called by the automatic run
    np.testing.assert_allclose(analytic.means, auto.means, rtol=0, atol=1e-8 * np.max(np.abs(auto.means)))
    np.testing.assert_allclose(analytic.covs, auto.covs, rtol=0, atol=1e-8 * np.max(np.abs(auto.covs)))
    np.testing.assert_allclose(analytic.loglik, auto.loglik, rtol=1e-10)


def test_sigma_point_filters_run_on_built_models(turn_track):
    """The vectorized functions serve the UKF and CKF too, and they agree with the EKF here."""
    motion, sensor, dt, xs, zs, prior = turn_track
    model = gf.model(motion, sensor, dt)
    ekf = gf.filter(model, prior, zs, method="ekf")
    for method in ("ukf", "ckf"):
        res = gf.filter(model, prior, zs, method=method)
        assert np.sqrt(np.mean(np.sum((res.means[20:, :2] - xs[20:, :2]) ** 2, axis=1))) < 4.5
        np.testing.assert_allclose(res.means[20:, :2], ekf.means[20:, :2], atol=1.0)


# -- validation ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "error", "match"),
    [
        (("cv", gf.Position(), 1.0), TypeError,
         r"^`motion` must be a LinearMotion or NonlinearMotion \(e\.g\. gaussfuse\.ConstantVelocity\(\)\); got str\.$"),
        ((gf.ConstantVelocity(), gf.LinearModel(1, 1, 1, 1), 1.0), TypeError,
         r"^`sensor` must be a LinearSensor or NonlinearSensor \(e\.g\. gaussfuse\.Position\); got LinearModel\.$"),
        ((gf.ConstantVelocity(dim=1), gf.RangeBearing(), 1.0), ValueError,
         r"^`sensor` reads 2 position components but `motion` has 1 spatial axis\.$"),
        ((gf.ConstantVelocity(dim=1), gf.Position(dim=2), 1.0), ValueError,
         r"^`sensor` reads 2 position components but `motion` has 1 spatial axis\.$"),
        ((gf.CoordinatedTurn(), gf.RangeBearingElevation(), 1.0), ValueError,
         r"^`sensor` reads 3 position components but `motion` has 2 spatial axes\.$"),
        # a level and its slope are no position: RangeBearing read them as x, y (audit TT4)
        ((gf.LocalLinearTrend(), gf.RangeBearing(), 1.0), ValueError,
         r"^`sensor` reads 2 position components, but LocalLinearTrend's state \('level', 'slope'\) has no spatial "
         r"axes; measure it with a LinearSensor \(H picks what is measured\)\.$"),
        ((gf.LocalLinearTrend(), gf.Position(dim=2), 1.0), ValueError, r"^`sensor` reads 2 position components, but"),
        ((gf.LocalLevel(), gf.Position(dim=1), 1.0), ValueError,
         r"^`sensor` reads 1 position component, but LocalLevel's state \('level',\) has no spatial axes"),
        ((gf.RandomWalk(n=1), gf.BearingOnly(), 1.0), ValueError,
         r"^`sensor` reads 2 position components but the state of `motion` has only 1\.$"),
        ((gf.ConstantVelocity(dim=2), gf.LinearSensor([[1, 0, 0]], 1.0), 1.0), ValueError,
         r"^`sensor` has `H` of shape \(1, 3\), which does not fit the state of `motion` \(n = 4\); "
         r"`H` must have 4 columns\.$"),
        ((gf.ConstantVelocity(dim=2), gf.Position(dim=2, n=6), 1.0), ValueError,
         r"^`sensor` has `H` of shape \(2, 6\)"),
        ((gf.ConstantVelocity(), gf.Position(), 0.0), ValueError, r"^`dt` must be a positive number; got 0\.0\.$"),
        ((gf.CoordinatedTurn(), gf.RangeBearing(), 0.0), ValueError, r"^`dt` must be a positive number; got 0\.0\.$"),
        ((gf.CoordinatedTurn(), gf.RangeBearing(), -1.0), ValueError, r"^`dt` must be a positive number; got -1\.0\.$"),
        ((gf.CoordinatedTurn(), gf.RangeBearing(), "1"), TypeError, r"^`dt` must be a positive number; got '1'\.$"),
    ],
)
def test_model_validation(args, error, match):
    with pytest.raises(error, match=match):
        gf.model(*args)


def test_position_sensor_on_fewer_axes_is_allowed():
    """Measuring x only of a 2-D motion is a legitimate (partial) sensor."""
    model = gf.model(gf.ConstantVelocity(dim=2), gf.Position(dim=1), 1.0)
    np.testing.assert_array_equal(model.H, [[1.0, 0.0, 0.0, 0.0]])


def test_exported():
    for name in ("model", "van_loan", "LinearMotion", "NonlinearMotion", "ConstantPosition", "ConstantVelocity",
                 "ConstantAcceleration", "ForceInput", "Singer", "RandomWalk", "LocalLevel", "LocalLinearTrend",
                 "LinearSDE", "CoordinatedTurn", "LinearSensor", "Position", "NonlinearSensor", "RangeBearing",
                 "RangeBearingElevation", "BearingOnly"):
        assert name in gf.__all__ and hasattr(gf, name)
        assert name in gf.models.__all__
    assert gf.model is gf.models.model


def test_docstring_examples():
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        result = doctest.testmod(compose_module, optionflags=doctest.NORMALIZE_WHITESPACE, report=True)
    assert result.attempted >= 2
    assert result.failed == 0, out.getvalue()


# ---------------------------------------------------------------------------
# Built models pickle: f, h and their Jacobians are no closures
# ---------------------------------------------------------------------------


class Heading(gf.NonlinearSensor):
    """A user's sensor: the heading of a 2-D constant-velocity state, atan2(vy, vx)."""

    __slots__ = ("r",)

    def __init__(self, r: float = 1e-3) -> None:
        self._set(r=r)

    m = property(lambda self: 1)
    names = property(lambda self: ("heading",))
    measurement_angles = property(lambda self: (0,))
    R = property(lambda self: np.array([[self.r]]))

    def h(self, x):
        x = np.asarray(x)
        return np.arctan2(x[..., 3], x[..., 2])[..., None]

    def jacobian(self, x):
        v2 = x[2] ** 2 + x[3] ** 2
        return np.array([[0.0, 0.0, -x[3] / v2, x[2] / v2]])


class Drift(gf.NonlinearMotion):
    """A user's motion: a level that decays towards 1, x' = 1 + (x - 1) e^{-dt}."""

    __slots__ = ()
    n = property(lambda self: 1)
    names = property(lambda self: ("level",))

    def f(self, x, dt):
        return 1.0 + (np.asarray(x) - 1.0) * np.exp(-dt)

    def jacobian(self, x, dt):
        return np.array([[np.exp(-dt)]])

    def noise(self, dt):
        return np.array([[0.1 * dt]])


BUILT = {
    "cv+range-bearing": (gf.ConstantVelocity(dim=2, q=0.5), gf.RangeBearing(origin=(-3.0, 1.0)), None),
    "cv+bearing-only": (gf.ConstantVelocity(dim=2, q=0.5), gf.BearingOnly(origin=(-3.0, 1.0)), None),
    "ca+range-bearing-elevation": (gf.ConstantAcceleration(dim=3, q=0.5), gf.RangeBearingElevation(), None),
    "force-input+range-bearing": (gf.ForceInput(q=0.1, dim=2), gf.RangeBearing(origin=(-3.0, 1.0)), 2),
    "cv+user-sensor": (gf.ConstantVelocity(dim=2, q=0.5), Heading(), None),
    "turn+position": (gf.CoordinatedTurn(), gf.Position(dim=2, r=0.1), None),
    "turn+range-bearing": (gf.CoordinatedTurn(), gf.RangeBearing(origin=(-3.0, 1.0)), None),
    "user-motion+position": (Drift(), gf.Position(dim=1, r=0.1), None),
}


@pytest.mark.parametrize("name", list(BUILT))
def test_nonlinear_built_models_pickle_and_filter_the_same(name):
    motion, sensor, p = BUILT[name]
    built = gf.model(motion, sensor, dt=0.5)
    assert isinstance(built, gf.NonlinearModel)
    back = pickle.loads(pickle.dumps(built))
    for attr in ("Q", "R", "state_angles", "measurement_angles"):
        np.testing.assert_array_equal(getattr(back, attr), getattr(built, attr))
        assert not getattr(back, attr).flags.writeable
    assert back.vectorized is built.vectorized is True
    rng = np.random.default_rng(4)
    prior = gf.Gaussian(np.full(built.n, 2.0), 0.1 * np.eye(built.n))
    zs = built.measurement(np.full(built.n, 2.0)) + 0.01 * rng.normal(size=(10, built.m))
    us = None if p is None else rng.normal(size=(10, p))
    for method in ("ekf", "ukf"):
        want = gf.filter(built, prior, zs, us, method)
        got = gf.filter(back, prior, zs, us, method)
        np.testing.assert_array_equal(got.means, want.means)
        np.testing.assert_array_equal(got.covs, want.covs)


def test_a_linear_sensor_whose_R_does_not_fit_its_H_names_both():
    with pytest.raises(ValueError, match=r"^`R` must have shape \(2, 2\), because `H` has 2 rows; got shape \(\)\. A number "
                                         r"is a 1 × 1 matrix only; for 1 times the identity give 1 \* np\.eye\(2\)\.$"):
        gf.model(gf.ConstantVelocity(dim=1, q=1.0), gf.LinearSensor(H=[[1, 0], [0, 1]], R=1.0), dt=1.0)


# ---------------------------------------------------------------------------
# Several sensors read as one
# ---------------------------------------------------------------------------


def test_stacked_linear_sensors_are_one_linear_sensor():
    motion = gf.ConstantVelocity(dim=2, q=0.5)
    stacked = gf.stack_sensors({"gps": gf.Position(dim=2, r=0.5), "v": gf.LinearSensor([[0, 0, 1, 0]], 0.1)}, motion)
    assert isinstance(stacked, gf.LinearSensor) and stacked.names == ("gps.x", "gps.y", "v.z0")
    H, R = stacked.linear(4)
    np.testing.assert_array_equal(H, [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])
    np.testing.assert_array_equal(R, np.diag([0.5, 0.5, 0.1]))


def test_stacked_nonlinear_sensors_stack_h_jacobians_noise_and_angles():
    motion = gf.ConstantVelocity(dim=2, q=0.5)
    gps, radar = gf.Position(dim=2, r=0.5), gf.RangeBearing(r_range=0.2, r_bearing=1e-3, origin=(1.0, -1.0))
    stacked = gf.stack_sensors({"gps": gps, "radar": radar}, motion)
    assert isinstance(stacked, gf.Stacked) and stacked.m == 4 and stacked.measurement_angles == (3,)
    assert stacked.slots == {"gps": slice(0, 2), "radar": slice(2, 4)}
    x = np.array([3.0, 2.0, 1.0, -1.0])
    np.testing.assert_allclose(stacked.h(x), np.concatenate([x[:2], radar.h(x)]))
    np.testing.assert_allclose(stacked.h(np.stack([x, 2 * x])), [stacked.h(x), stacked.h(2 * x)])
    np.testing.assert_allclose(stacked.jacobian(x), np.vstack([np.eye(2, 4), radar.jacobian(x)]))
    np.testing.assert_array_equal(stacked.R, np.diag([0.5, 0.5, 0.2, 1e-3]))
    model = gf.model(motion, stacked, dt=0.5)  # the composition takes it like any sensor
    np.testing.assert_allclose(model.measurement(x), stacked.h(x))


@pytest.mark.parametrize("sensors, error, match", [
    ({}, TypeError, r"`sensors` must be a non-empty dict"),
    ({1: gf.Position()}, TypeError, r"`sensors` must have str keys"),
    ({"a": 3}, TypeError, r"`sensors\['a'\]` must be a sensor"),
    ({"a": gf.Position(dim=3)}, ValueError, r"`sensors\['a'\]` reads 3 position components but `motion` has 2"),
])
def test_stack_sensors_validation(sensors, error, match):
    with pytest.raises(error, match=match):
        gf.stack_sensors(sensors, gf.ConstantVelocity(dim=2))


@pytest.mark.parametrize("motion, given", [("CT", "str"), (None, "NoneType"),
                                           (gf.CoordinatedTurn, r"the class CoordinatedTurn itself \(make one: "
                                                                r"CoordinatedTurn\(\)\)")])
def test_stack_sensors_names_a_motion_that_is_not_one(motion, given):
    """A str or None gave AttributeError ("has no attribute 'n'"), the class itself a comparison TypeError."""
    with pytest.raises(TypeError, match=rf"^`motion` must be a LinearMotion or NonlinearMotion .*; got {given}\.$"):
        gf.stack_sensors({"gps": gf.Position(dim=2)}, motion)
    with pytest.raises(TypeError, match=rf"^`motion` must be a LinearMotion or NonlinearMotion .*; got {given}\.$"):
        gf.model(motion, gf.Position(dim=2), dt=1.0)


def test_sensors_stacked_for_another_motion_are_refused_as_the_sensors_alone_would_be():
    """A Stacked sensor skipped the fit check: the turn model's UKF read its vx as a height (stacked for a 3-D
    Singer motion), another motion's filter failed in NumPy's matmul (stacked for n = 5, used with n = 4)."""
    radar = gf.stack_sensors({"radar": gf.RangeBearingElevation(), "rb": gf.RangeBearing()}, gf.Singer(dim=3))
    with pytest.raises(ValueError, match=r"^`sensor` stacks sensors of a state of n = 9 .* \(n = 5\)"):
        gf.model(gf.CoordinatedTurn(), radar, dt=1.0)
    turn = gf.stack_sensors({"rb": gf.RangeBearing(), "gps": gf.Position(dim=2)}, gf.CoordinatedTurn())
    with pytest.raises(ValueError, match=r"^`sensors\['s'\]` stacks sensors of a state of n = 5"):
        gf.fuse_timeline(gf.ConstantVelocity(dim=2), {"s": turn}, gf.Gaussian(np.zeros(4), np.eye(4)), 0.0,
                         [(1.0, "s", [1.0, 0.1, 1.0, 0.0])])
    # the same size of state, fewer axes: each stacked sensor is checked as it would be alone
    three_d = gf.stack_sensors({"radar": gf.RangeBearingElevation()}, gf.ConstantVelocity(dim=3))
    with pytest.raises(ValueError, match=r"^`sensor`\['radar'\] reads 3 position components but `motion` has 2"):
        gf.model(gf.ConstantAcceleration(dim=2), three_d, dt=1.0)
    assert gf.model(gf.Singer(dim=3), radar, dt=1.0).n == 9  # its own motion still fits
    with pytest.raises(ValueError, match=r"^`x` must have shape \(n,\) or \(k, n\) with n = 5 .* got shape \(4,\)"):
        turn.h(np.ones(4))
    with pytest.raises(ValueError, match=r"^`x` must have shape \(n,\) with n = 5 .* got shape \(3, 5\)"):
        turn.jacobian(np.ones((3, 5)))


@pytest.mark.parametrize("dt", [np.timedelta64(100_000_000, "ns"), np.timedelta64(100, "ms"),
                                __import__("datetime").timedelta(milliseconds=100)])
def test_a_duration_is_not_a_number_of_seconds(dt):
    """np.timedelta64 is an np.integer: 100 ms in nanoseconds became dt = 1e8 s silently, in ms a bare float()
    TypeError that named nothing."""
    with pytest.raises(TypeError, match=r"^`dt` must be a positive number; got .*, a duration: give it in seconds"):
        gf.model(gf.ConstantVelocity(dim=1, q=1.0), gf.Position(dim=1, r=1.0), dt=dt)


def test_a_control_input_with_a_nonlinear_sensor_needs_us_of_its_width():
    """The filter called f without u (a TypeError quoting a private helper) or with u of another width (NumPy's
    matmul message), where a linear sensor's model says `us` is required."""
    prior = gf.Gaussian(np.zeros(4), np.eye(4))
    zs = np.array([[10.0, 0.5], [10.2, 0.52]])
    fixed = gf.model(gf.ForceInput(dim=2), gf.RangeBearing(), dt=1.0)
    timed = gf.model(gf.ForceInput(dim=2), gf.RangeBearing())
    for model, times in ((fixed, None), (timed, [0.0, 1.0, 2.0])):
        with pytest.raises(ValueError, match=r"^`us` is required: the model has a control input with p = 2\.$"):
            gf.filter(model, prior, zs, times=times, method="ekf")
        with pytest.raises(ValueError, match=r"`us` must have"):
            gf.filter(model, prior, zs, np.ones((2, 3)), times=times, method="ekf")
        got = gf.filter(model, prior, zs, np.ones((2, 2)), times=times, method="ekf")
        assert np.isfinite(got.means).all()
    with pytest.raises(ValueError, match=r"^`us` was given but the motion has no control input\.$"):
        gf.filter(gf.model(gf.ConstantVelocity(dim=2), gf.RangeBearing()), prior, zs, np.ones((2, 2)),
                  times=[0.0, 1.0, 2.0], method="ekf")


def test_a_timed_model_is_not_refused_for_a_step_it_is_never_given():
    """gf.model(motion, sensor) without dt checked the pair by discretising it over 1 s: an unstable SDE that is
    fine over the milliseconds it is used for was refused ("a step of dt = 1 s is too long")."""
    sde = gf.LinearSDE([[800.0]], [1.0], 1.0)
    timed = gf.model(sde, gf.LinearSensor([[1.0]], 1.0))
    got = gf.filter(timed, gf.Gaussian([0.0], [[1.0]]), [1.0, 2.0], times=[0.0, 1e-3, 2e-3])
    F, Q = sde.transition(1e-3)
    assert F[0, 0] == pytest.approx(np.exp(0.8), rel=1e-14) and Q[0, 0] == pytest.approx(np.expm1(1.6) / 1600, rel=1e-13)
    assert np.isfinite(got.means).all()
    with pytest.raises(ValueError, match=r"^a step of dt = 1 s is too long for LinearSDE"):
        gf.filter(timed, gf.Gaussian([0.0], [[1.0]]), [1.0, 2.0], times=[0.0, 1.0, 2.0])


@pytest.mark.parametrize("dts, error, message", [
    ([[0.5, 1.0]], ValueError, r"^`dts` must have shape \(T,\) with T >= 1, one step size per step; got shape \(1, 2\)"),
    ([], ValueError, r"^`dts` must have shape \(T,\) with T >= 1.*got shape \(0,\)"),
    (0.5, ValueError, r"^`dts` must have shape \(T,\).*got shape \(\)"),
    ([True, True], TypeError, r"^`dts` must be an array of numbers; got booleans"),
    (["a"], TypeError, r"^`dts` must be an array of numbers"),
    ([0.5, -1.0], ValueError, r"^`dts` must be positive step sizes; got -1.0 at index 1"),
])
@pytest.mark.parametrize("timed", ["linear", "nonlinear"])
def test_timed_model_at_checks_its_step_sizes(timed, dts, error, message):
    """2-D step sizes made a LinearModel with a 4-D F (sample_posterior then failed in matmul), booleans were
    steps of 1, and an empty list or a scalar gave NumPy's "need at least one array to stack" or an IndexError
    (audit M)."""
    timed = gf.model(gf.ConstantVelocity(), gf.Position()) if timed == "linear" else \
        gf.model(gf.CoordinatedTurn(), gf.RangeBearing())
    with pytest.raises(error, match=message):
        timed.at(dts)


@pytest.mark.parametrize("angles", [(-1,), (False, True), (1,)])
def test_stacked_sensors_place_each_sensors_angles_as_a_model_reads_them(angles):
    """A sensor's measurement_angles may be indices counted from its end, or a boolean mask, as a model takes
    them: stacked after a GPS, -1 flagged the GPS's y and a mask both the range and the bearing (audit S)."""
    class Heading(gf.NonlinearSensor):
        __slots__ = ("angles",)

        def __init__(self, angles):
            self._set(angles=angles)

        m = property(lambda self: 2)
        names = property(lambda self: ("range", "bearing"))
        R = property(lambda self: np.diag([1.0, 1e-4]))
        measurement_angles = property(lambda self: self.angles)

        def h(self, x):
            return gf.RangeBearing().h(x)

        def jacobian(self, x):
            return gf.RangeBearing().jacobian(x)

    cv = gf.ConstantVelocity(dim=2)
    assert gf.model(cv, Heading(angles), dt=1.0).measurement_angles.tolist() == [False, True]
    stacked = gf.model(cv, gf.stack_sensors({"gps": gf.Position(dim=2), "h": Heading(angles)}, cv), dt=1.0)
    assert stacked.measurement_angles.tolist() == [False, False, False, True]


@pytest.mark.parametrize("us, error, message", [
    (np.ones((3, 2)), ValueError, r"^`us` must have shape \(T, p\) = \(2, 2\) or \(N, 2, 2\), one row of the motion's "
                                  r"control input per step; got shape \(3, 2\)\.$"),
    ([["a", "b"], ["c", "d"]], TypeError, r"^`us` must be an array of numbers; got strings\.$"),
    ([[1.0, 2.0], [3.0]], TypeError, r"^`us` must be a rectangular array of real numbers"),
    ([[True, False], [True, True]], TypeError, r"^`us` must be an array of numbers; got booleans\.$"),
    (np.full((2, 2), 1 + 5j), TypeError, r"^`us` must be real; got complex values\.$"),
    ([[np.nan, 1.0], [1.0, 1.0]], ValueError, r"^`us` must be finite; got a non-finite .* at index \(0, 0\)\.$"),
])
def test_a_stepped_model_checks_its_controls(us, error, message):
    """A linear motion with a control input and a nonlinear sensor, over steps of two sizes: `us` went to NumPy
    unchecked (a broadcasting error for the wrong length, booleans read as 0 and 1, the imaginary part dropped,
    a NaN named at its index in [dt, u]; audit S)."""
    timed = gf.model(gf.ForceInput(dim=2), gf.RangeBearing())
    with pytest.raises(error, match=message):
        timed.at([1.0, 2.0], us)
    model, controls = timed.at([1.0, 2.0], [[0.5, -0.5], [1.0, 0.0]])
    np.testing.assert_array_equal(controls, [[1.0, 0.5, -0.5], [2.0, 1.0, 0.0]])


@pytest.mark.parametrize("make, error, message", [
    (lambda: gf.Stacked({"a": "not a sensor"}, 4), TypeError, r"^`sensors\['a'\]` must be a sensor"),
    (lambda: gf.Stacked([1, 2, 3], 4), TypeError, r"^`sensors` must be a non-empty dict mapping names to sensors"),
    (lambda: gf.Stacked({1: gf.RangeBearing()}, 4), TypeError, r"^`sensors` must have str keys"),
    (lambda: gf.Stacked({"a": gf.RangeBearing()}, 0), ValueError, r"^`n` must be"),
    (lambda: gf.Stacked({"a": gf.LinearSensor(np.eye(3), np.eye(3))}, 4), ValueError, r"has `H` of shape \(3, 3\)"),
    (lambda: gf.stack_sensors({"gps": gf.Position(2), "radar": gf.RangeBearing()}, gf.ConstantVelocity(dim=2)).h(
        np.array(["1", "2", "3", "4"])), TypeError, r"^`x` must be an array of numbers"),
    (lambda: gf.stack_sensors({"gps": gf.Position(2), "radar": gf.RangeBearing()}, gf.ConstantVelocity(dim=2)).h(
        [True, False, True, True]), TypeError, r"^`x` must be an array of numbers; got booleans\.$"),
])
def test_stacked_checks_what_it_is_given(make, error, message):
    """Stacked, a public class, took anything (a str as a sensor failed later in `.m`), and its h passed strings
    and booleans to NumPy (audit S)."""
    with pytest.raises(error, match=message):
        make()


@pytest.mark.parametrize("build, names", [
    (lambda: gf.constant_velocity(0.1, 1.0, 0.25, dim=2), ("x", "y", "vx", "vy")),
    (lambda: gf.constant_acceleration(0.1, 1.0, 0.25), ("x", "vx", "ax")),
    (lambda: gf.model(gf.CoordinatedTurn(), gf.RangeBearing(), dt=1.0), ("x", "y", "vx", "vy", "omega")),
])
def test_a_model_at_a_fixed_dt_keeps_the_motions_state_names(build, names):
    """Y3: gf.model without dt labelled its results x, vx; with dt (and gf.constant_velocity) x0, x1."""
    model = build()
    assert model.names == names
    assert pickle.loads(pickle.dumps(model)).names == names
    prior = gf.Gaussian(np.arange(model.n) + 1.0, np.eye(model.n))
    zs = np.asarray(gf.simulate(model, prior, 6, rng=np.random.default_rng(0)).measurements)
    for result in (gf.filter(model, prior, zs), gf.smooth(model, prior, zs)):
        frame = result.to_pandas()
        assert list(frame.columns) == [*names, *(f"{name}_sd" for name in names)]
    assert list(gf.forecast(model, prior, 2).to_pandas(of="states").columns)[:model.n] == list(names)
    if isinstance(model, gf.LinearModel):
        fit = gf.fit(model, prior, zs, iterations=2, tol=0)
        assert fit.model.names == names


@pytest.mark.parametrize("make", [
    lambda names: gf.LinearModel(np.eye(2), [1.0, 0.0], np.eye(2), 1.0, names=names),
    lambda names: gf.NonlinearModel(lambda x: x, lambda x: x[:1], np.eye(2), 1.0, names=names),
])
def test_a_models_names_are_checked_and_default_to_none(make):
    assert make(None).names is None
    assert make(["a", "b"]).names == ("a", "b")
    with pytest.raises(ValueError, match=r"`names` must have 2 entries, one per component; got 3"):
        make(["a", "b", "c"])
    with pytest.raises(TypeError, match=r"`names` must be a sequence of 2 strings"):
        make("ab")
    for bad in (["x", "x"], ["", "v"]):  # they label columns, which to_pandas would refuse later (review R13)
        with pytest.raises(ValueError, match=r"`names` must be distinct and non-empty"):
            make(bad)
    with pytest.raises(ValueError, match=r"`names` must not hold a name with '_sd' after another.*got 'x_sd'"):
        make(["x", "x_sd"])  # (review R14)


def test_a_timed_model_takes_names_and_keeps_them_at_every_step():
    """Review R14: a model file's states named its fixed-dt model but not the model for irregular times."""
    timed = gf.model(gf.ConstantVelocity(), gf.Position(r=1.0), names=["pos", "vel"])
    assert timed.names == ("pos", "vel") and "names=('pos', 'vel')" in repr(timed)
    assert pickle.loads(pickle.dumps(timed)).names == ("pos", "vel")
    assert "names" not in repr(gf.model(gf.ConstantVelocity(), gf.Position(r=1.0)))  # the motion's, by default
    for times in ([0.0, 1.0, 3.0], [0.0, 1.0, 2.0]):  # irregular, and one step (a model at that dt)
        frame = gf.filter(timed, gf.Gaussian([0.0, 1.0], np.eye(2)), [1.0, 2.0, 2.5], times=times).to_pandas()
        assert list(frame.columns) == ["pos", "vel", "pos_sd", "vel_sd"]
    assert gf.model(gf.ConstantVelocity(), gf.Position(r=1.0), 0.5, names=["pos", "vel"]).names == ("pos", "vel")
    with pytest.raises(ValueError, match=r"`names` must have 2 entries"):
        gf.model(gf.ConstantVelocity(), gf.Position(r=1.0), names=["pos"])


@pytest.mark.parametrize("first", [gf.LinearSensor([[1.0, 0.0, 0.0, 0.0]], 1.0, names=["bearing"]), gf.BearingOnly()],
                         ids=["linear", "nonlinear"])
def test_stacked_names_that_join_to_one_name_are_refused_naming_the_sensors(first):
    """Review R14: sensors "a.b" with component "bearing" and "a" with "b.bearing" both give "a.b.bearing"; the
    error blamed `names`, which nobody gave (and the nonlinear Stacked sensor did not check them)."""
    sensors = {"a.b": first, "a": gf.LinearSensor([[0.0, 1.0, 0.0, 0.0]], 1.0, names=["b.bearing"])}
    with pytest.raises(ValueError, match=r"`sensors` join to the name 'a\.b\.bearing' twice"):
        gf.stack_sensors(sensors, gf.ConstantVelocity(dim=2))


def test_a_users_sensor_without_r_or_with_an_r_of_another_size_is_named():
    """Audit TT5: a NonlinearSensor subclass without R raised a bare AttributeError in model(); one with m = 3 and
    a 2 x 2 R was stacked as 5 components over a 4 x 4 R, and the filter failed later on h's shape."""
    from gaussfuse.models.sensors import NonlinearSensor

    class NoR(NonlinearSensor):
        __slots__ = ()
        m, names = 2, ("a", "b")

        def h(self, x):
            return np.zeros(np.shape(x)[:-1] + (2,))

        def jacobian(self, x):
            return np.zeros((2, np.shape(x)[-1]))

    class WrongM(NoR):
        __slots__ = ()
        m, R = 3, np.eye(2)

    turn = gf.CoordinatedTurn()
    with pytest.raises(TypeError, match=r"^`sensor` must give its measurement size `m` and noise covariance `R`, "
                                        r"of shape \(m, m\), as a NonlinearSensor does; NoR has no `R`\.$"):
        gf.model(turn, NoR(), 1.0)
    message = r"^`sensors\['w'\]` has m = 3 components but its `R` has shape \(2, 2\); it must be \(3, 3\)\.$"
    with pytest.raises(ValueError, match=message):
        gf.stack_sensors({"w": WrongM(), "p": gf.Position(2)}, turn)
    with pytest.raises(ValueError, match=message.replace(r"`sensors\['w'\]`", "`sensor`")):
        gf.model(turn, WrongM(), 1.0)
