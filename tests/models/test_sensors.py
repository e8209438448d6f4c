"""Sensor models: values, analytic Jacobians, angle flags and validation."""

from __future__ import annotations

import contextlib
import doctest
import io
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import gaussfuse as gf
from gaussfuse.linearize.taylor import jacobian
from gaussfuse.models import sensors as sensors_module

# -- linear sensors ------------------------------------------------------------------


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("extra", [0, 1, 4])
def test_position_builds_H_for_a_state_size(dim, extra):
    n = dim + extra
    sensor = gf.Position(dim=dim, r=0.3)
    H, R = sensor.linear(n)
    np.testing.assert_array_equal(H, np.hstack([np.eye(dim), np.zeros((dim, extra))]))
    np.testing.assert_array_equal(R, 0.3 * np.eye(dim))
    assert (sensor.m, sensor.names, sensor.measurement_angles) == (dim, ("x", "y", "z")[:dim], ())
    assert sensor.H is None  # no state size given
    assert isinstance(sensor, gf.LinearSensor)
    fixed = gf.Position(dim=dim, r=0.3, n=n)
    np.testing.assert_array_equal(fixed.H, H)
    np.testing.assert_array_equal(fixed.linear(n)[0], H)


def test_position_measures_positions_of_a_kinematic_state():
    x = np.array([1.0, 2.0, 3.0, -1.0, -2.0, -3.0])  # x, y, z, vx, vy, vz
    H, _ = gf.Position(dim=3).linear(6)
    np.testing.assert_array_equal(H @ x, [1.0, 2.0, 3.0])


def test_linear_sensor():
    sensor = gf.LinearSensor([[0, 0, 1, 0], [0, 0, 0, 1]], [[0.2, 0.05], [0.05, 0.1]], names=("vx", "vy"))
    assert (sensor.m, sensor.names, sensor.measurement_angles) == (2, ("vx", "vy"), ())
    H, R = sensor.linear(4)
    np.testing.assert_array_equal(H, [[0, 0, 1, 0], [0, 0, 0, 1]])
    np.testing.assert_array_equal(R, [[0.2, 0.05], [0.05, 0.1]])
    with pytest.raises(ValueError, match="read-only"):
        sensor.H[0, 0] = 1.0
    # A row vector and a scalar variance for one measured component.
    one = gf.LinearSensor([1.0, -1.0], 0.5)
    assert one.H.shape == (1, 2) and one.R.shape == (1, 1) and one.names == ("z0",)


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: gf.Position(dim=0), ValueError, r"^`dim` must be 1, 2 or 3; got 0\.$"),
        (lambda: gf.Position(r=-1e-300), ValueError, r"^`r` must be a non-negative number; got -1e-300\.$"),
        (lambda: gf.Position(r="1"), TypeError, r"^`r` must be a non-negative number; got '1'\.$"),
        (lambda: gf.Position(dim=2, n=1), ValueError, r"^`n` must be an integer >= 2; got 1\.$"),
        (lambda: gf.Position(dim=2).linear(1), ValueError, r"^`n` must be an integer >= 2; got 1\.$"),
        (lambda: gf.Position(dim=2, n=4).linear(6), ValueError, r"^`n` must be 4, as given to `Position`; got 6\.$"),
        (lambda: gf.LinearSensor([[1, 0]], [[1, 0], [0, 1]]), ValueError,
         r"^`R` must have shape \(1, 1\), because `H` has 1 row; got shape \(2, 2\)\.$"),
        (lambda: gf.LinearSensor([[1, 0]], -1.0), ValueError, r"^`R` must be positive semi-definite"),
        (lambda: gf.LinearSensor(np.zeros((2, 2, 2)), np.eye(2)), ValueError, r"^`H` must have shape \(m, n\)"),
        (lambda: gf.LinearSensor([[1, 0]], 1.0, names=("a", "b")), ValueError,
         r"^`names` must have 1 entries, one per component; got 2\.$"),
        (lambda: gf.LinearSensor([[1, 0]], 1.0).linear(3), ValueError,
         r"^`n` must be 2, the number of columns of `H`; got 3\.$"),
        (lambda: gf.RangeBearing(r_range=-1.0), ValueError, r"^`r_range` must be a non-negative number; got -1\.0\.$"),
        (lambda: gf.RangeBearing(r_bearing=-1.0), ValueError, r"^`r_bearing` must be a non-negative number; got -1\.0\.$"),
        (lambda: gf.RangeBearing(origin=(0, 0, 0)), ValueError, r"^`origin` must have shape \(2,\); got shape \(3,\)\.$"),
        (lambda: gf.RangeBearing(origin=(0, np.nan)), ValueError, r"^`origin` must be finite"),
        (lambda: gf.RangeBearingElevation(r_elevation=np.inf), ValueError,
         r"^`r_elevation` must be a non-negative number; got inf\.$"),
        (lambda: gf.RangeBearingElevation(origin=(0, 0)), ValueError,
         r"^`origin` must have shape \(3,\); got shape \(2,\)\.$"),
        (lambda: gf.BearingOnly(r_bearing=None), TypeError, r"^`r_bearing` must be a non-negative number; got None\.$"),
        (lambda: gf.BearingOnly(origin="here"), TypeError, r"^`origin` must be an array of numbers; got str\.$"),
    ],
)
def test_sensor_validation(make, error, match):
    with pytest.raises(error, match=match):
        make()


# -- nonlinear sensors ---------------------------------------------------------------


def test_range_bearing_values():
    sensor = gf.RangeBearing(r_range=4.0, r_bearing=1e-3, origin=(1.0, -1.0))
    x = np.array([4.0, 3.0, 9.0, 9.0])  # 3-4-5 triangle from the origin
    np.testing.assert_allclose(sensor.h(x), [5.0, np.arctan2(4.0, 3.0)], rtol=1e-15)
    np.testing.assert_array_equal(sensor.R, np.diag([4.0, 1e-3]))
    assert (sensor.m, sensor.names, sensor.measurement_angles) == (2, ("range", "bearing"), (1,))
    # Bearings cover the full circle, in (-π, π].
    for angle in (0.0, 0.5, 2.0, np.pi, -0.5, -3.0):
        z = sensor.h([1.0 + 2.0 * np.cos(angle), -1.0 + 2.0 * np.sin(angle)])
        np.testing.assert_allclose(z, [2.0, angle], rtol=0, atol=1e-14)


def test_range_bearing_elevation_values():
    sensor = gf.RangeBearingElevation(1.0, 2e-4, 3e-4, origin=(1.0, 1.0, 1.0))
    x = np.array([1.0 + 3.0, 1.0 + 4.0, 1.0 - 12.0, 0.0, 0.0, 0.0])  # 3-4 horizontally, 12 down
    np.testing.assert_allclose(sensor.h(x), [13.0, np.arctan2(4.0, 3.0), -np.arctan2(12.0, 5.0)], rtol=1e-15)
    np.testing.assert_array_equal(sensor.R, np.diag([1.0, 2e-4, 3e-4]))
    assert (sensor.m, sensor.measurement_angles) == (3, (1,))
    assert sensor.names == ("range", "bearing", "elevation")
    # Elevation lies in (-π/2, π/2).
    up = sensor.h([1.0 + 1e-9, 1.0, 50.0])
    assert 0 < up[2] < np.pi / 2


def test_bearing_only_values():
    sensor = gf.BearingOnly(r_bearing=5e-4, origin=(2.0, 2.0))
    np.testing.assert_allclose(sensor.h([2.0, 5.0, 1.0, 1.0]), [np.pi / 2], rtol=1e-15)
    np.testing.assert_allclose(sensor.h([0.0, 2.0]), [np.pi], rtol=1e-15)
    np.testing.assert_array_equal(sensor.R, [[5e-4]])
    assert (sensor.m, sensor.names, sensor.measurement_angles) == (1, ("bearing",), (0,))


NONLINEAR = [
    (gf.RangeBearing(origin=(0.5, -2.0)), 2),
    (gf.RangeBearingElevation(origin=(0.5, -2.0, 1.0)), 3),
    (gf.BearingOnly(origin=(-3.0, 1.0)), 2),
]
NONLINEAR_IDS = ["rb", "rbe", "bo"]

coordinate = st.floats(-100, 100).filter(lambda v: abs(v) > 1e-3)


@pytest.mark.parametrize(("sensor", "k"), NONLINEAR, ids=NONLINEAR_IDS)
@settings(max_examples=30, deadline=None)
@given(position=st.tuples(coordinate, coordinate, coordinate), extra=st.integers(0, 3))
def test_analytic_jacobians_match_automatic_ones(sensor, k, position, extra):
    x = np.r_[np.array(position[:k]) + sensor.origin, np.linspace(1.0, 2.0, extra)]
    assert isinstance(sensor, gf.NonlinearSensor)
    J = sensor.jacobian(x)
    assert J.shape == (sensor.m, k + extra)
    np.testing.assert_array_equal(J[:, k:], 0.0)  # only the position is read
    J_auto = jacobian("h", sensor.h, x, (), sensor.m)
    np.testing.assert_allclose(J, J_auto, rtol=1e-8, atol=1e-8 * np.max(np.abs(J_auto)))


@pytest.mark.parametrize(("sensor", "k"), NONLINEAR, ids=NONLINEAR_IDS)
def test_jacobian_at_fixed_points_against_central_differences(sensor, k):
    x = np.array([7.0, -3.0, 2.0, 1.0, 1.0, 1.0])
    h = 1e-6
    J_fd = np.stack([(sensor.h(x + h * e) - sensor.h(x - h * e)) / (2 * h) for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(sensor.jacobian(x), J_fd, rtol=1e-7, atol=1e-10)


@pytest.mark.parametrize(("sensor", "k"), NONLINEAR, ids=NONLINEAR_IDS)
def test_sensors_evaluate_stacks_of_states(sensor, k):
    X = np.random.default_rng(1).normal(size=(6, 4)) * 10
    np.testing.assert_array_equal(sensor.h(X), np.stack([sensor.h(x) for x in X]))
    np.testing.assert_array_equal(sensor.jacobian(X), np.stack([sensor.jacobian(x) for x in X]))
    assert sensor.h(X).shape == (6, sensor.m)


@pytest.mark.parametrize(("sensor", "k"), NONLINEAR, ids=NONLINEAR_IDS)
def test_sensors_reject_bad_states(sensor, k):
    with pytest.raises(ValueError, match=rf"^`x` must have shape \(n,\) or \(j, n\) with n >= {k} "
                                         r"\(the position comes first\); got shape \(1,\)\.$"):
        sensor.h([1.0])
    with pytest.raises(ValueError, match=r"got shape \(2, 2, 4\)"):
        sensor.jacobian(np.ones((2, 2, 4)))
    with pytest.raises(TypeError, match=r"^`x` must be an array of numbers; got <U1 values\.$"):
        sensor.h(["a", "b", "c"])


def test_jacobian_at_the_sensor_is_not_finite():
    """Undefined there: the model machinery reports non-finite Jacobians rather than guessing."""
    J = gf.RangeBearing().jacobian(np.zeros(4))
    assert not np.all(np.isfinite(J))


def test_sensors_are_immutable_and_pickle():
    for sensor in [gf.Position(dim=2, r=0.4), gf.LinearSensor([[1.0, 0.0]], 2.0)] + [s for s, _ in NONLINEAR]:
        with pytest.raises(AttributeError, match="is immutable"):
            sensor.R = np.eye(2)
        back = pickle.loads(pickle.dumps(sensor))
        np.testing.assert_array_equal(back.R, sensor.R)
        assert type(back) is type(sensor)
        assert repr(back) == repr(sensor)
    with pytest.raises(ValueError, match="read-only"):
        gf.RangeBearing().origin[0] = 1.0


def test_docstring_examples():
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        result = doctest.testmod(sensors_module, optionflags=doctest.NORMALIZE_WHITESPACE, report=True)
    assert result.attempted >= 5
    assert result.failed == 0, out.getvalue()


@pytest.mark.parametrize("scale", [1e-300, 1e-170, 1.0, 1e200, 1e300])
def test_jacobians_at_any_scale(scale):
    """Sums of squares overflowed beyond 1e154 (a range row of 0) and underflowed below 1e-154 (inf); the oracle
    is the same derivatives in 60-digit arithmetic."""
    import mpmath

    mpmath.mp.dps = 60
    x, y, z = (mpmath.mpf(v) * mpmath.mpf(scale) for v in (3, 4, 12))
    rxy, r = mpmath.sqrt(x * x + y * y), mpmath.sqrt(x * x + y * y + z * z)
    want = {
        "rb": [[x / rxy, y / rxy], [-y / rxy**2, x / rxy**2]],
        "bearing": [[-y / rxy**2, x / rxy**2]],
        "rbe": [[x / r, y / r, z / r], [-y / rxy**2, x / rxy**2, 0],
                [-x * z / (r**2 * rxy), -y * z / (r**2 * rxy), rxy / r**2]],
    }
    got = {
        "rb": gf.RangeBearing().jacobian(np.array([3.0, 4.0]) * scale),
        "bearing": gf.BearingOnly().jacobian(np.array([3.0, 4.0]) * scale),
        "rbe": gf.RangeBearingElevation().jacobian(np.array([3.0, 4.0, 12.0]) * scale),
    }
    for name, J in got.items():
        exact = np.array([[float(v) for v in row] for row in want[name]])
        np.testing.assert_allclose(J, exact, rtol=1e-14, atol=0, err_msg=name)


@pytest.mark.parametrize("engine", ["python", "numba"])
@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_a_sensor_with_zero_variance_measures_exactly(form, engine):
    """A zero variance is valid input (LinearSensor took R = 0; Position, RangeBearing and the others refused
    it as "must be a positive number"). Position(r=0): the filtered positions are the measurements, with no
    spread; RangeBearing with zero variances: the EKF's update conditions its linearisation exactly,
    J (m⁺ - m⁻) = z - h(m⁻) and J P⁺ Jᵀ = 0 (the Kalman update with R = 0)."""
    zs = np.array([[1.0, 2.0], [1.5, 2.7], [2.2, 3.1]])
    prior = gf.Gaussian(np.zeros(4), 10.0 * np.eye(4))
    got = gf.filter(gf.model(gf.ConstantVelocity(dim=2), gf.Position(dim=2, r=0.0), dt=1.0), prior, zs,
                    form=form, engine=engine)
    np.testing.assert_allclose(got.means[:, :2], zs, rtol=1e-14)
    assert np.abs(got.covs[:, :2, :2]).max() <= 1e-28  # round-off of variances of order 10
    if engine == "python":
        sensor = gf.RangeBearing(r_range=0.0, r_bearing=0.0)
        m0 = np.array([3.0, 4.0, 0.0, 0.0])
        z = np.array([5.1, 0.93])
        post = gf.filter(gf.model(gf.ConstantVelocity(dim=2), sensor, dt=1.0), gf.Gaussian(m0, np.eye(4)), [z],
                         method="ekf", form=form)
        J = sensor.jacobian(m0[:2])
        np.testing.assert_allclose(J @ (post.means[0, :2] - m0[:2]), z - sensor.h(m0[:2]), rtol=1e-13)
        assert np.abs(J @ post.covs[0, :2, :2] @ J.T).max() <= 1e-14


def test_the_range_bearing_elevation_jacobian_is_nan_where_its_docstring_says():
    sensor = gf.RangeBearingElevation(origin=(1.0, 2.0, 3.0))
    above = sensor.jacobian(np.array([1.0, 2.0, 8.0, 0.0]))  # on the vertical: bearing and elevation in x and y
    np.testing.assert_array_equal(np.isnan(above), [[0, 0, 0, 0], [1, 1, 0, 0], [1, 1, 0, 0]])
    np.testing.assert_array_equal(above[0], [0, 0, 1, 0])
    at = sensor.jacobian(np.array([1.0, 2.0, 3.0, 0.0]))  # at the sensor: the range's row, the elevation's z too
    np.testing.assert_array_equal(np.isnan(at), [[1, 1, 1, 0], [1, 1, 0, 0], [1, 1, 1, 0]])


@pytest.mark.parametrize("scale", [1.0, 1e200, 1e-200])
def test_geometric_sensors_take_a_complex_step(scale):
    """NumPy's hypot and arctan2 have no complex loop, so h refused a complex state and a NonlinearModel built on
    a sensor's h (or a stacked one's) fell back to finite differences, 1e-11 off where a complex step is exact
    (audit TT2). The complex step of h now equals the analytic Jacobian to round-off at any scale; real input
    takes NumPy's own functions, bit for bit."""
    from gaussfuse.models.compose import stack_sensors

    motion = gf.ConstantVelocity(dim=3)
    x = scale * np.array([3.0, -4.0, 1.5, 0.3, 0.1, -0.2])
    sensors = [gf.RangeBearing(origin=(-scale, 0.0)), gf.BearingOnly(), gf.RangeBearingElevation(),
               stack_sensors({"rb": gf.RangeBearing(), "p": gf.Position(dim=3)}, motion)]
    h = 1e-20 * scale
    for sensor in sensors:
        J = sensor.jacobian(x)
        stepped = np.stack([np.imag(sensor.h(x + 1j * h * e)) / h for e in np.eye(x.size)], axis=-1)
        np.testing.assert_allclose(stepped * scale, J * scale, rtol=1e-14, atol=1e-15 * np.abs(J * scale).max())
        np.testing.assert_allclose(np.real(sensor.h(x + 1j * h * np.eye(x.size)[0])), sensor.h(x), rtol=1e-15)
    dx, dy = x[0] + scale, x[1]
    np.testing.assert_array_equal(sensors[0].h(x), [np.hypot(dx, dy), np.arctan2(dy, dx)])
