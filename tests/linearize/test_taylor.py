"""Automatic Jacobians against analytic ones."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import gaussfuse as gf
from gaussfuse.linearize.taylor import (
    Taylor,
    complex_step_jacobian,
    finite_difference_jacobian,
    jacobian,
)
from gaussfuse.errors import ModelFunctionError
from gaussfuse.models.nonlinear import NonlinearModel


def smooth(x):
    return np.array([np.sin(x[0]) * np.exp(x[1]), np.log(x[0]) * x[1] ** 3, x[0] / (1 + x[1] ** 2)])


def smooth_jacobian(x):
    return np.array([
        [np.cos(x[0]) * np.exp(x[1]), np.sin(x[0]) * np.exp(x[1])],
        [x[1] ** 3 / x[0], 3 * np.log(x[0]) * x[1] ** 2],
        [1 / (1 + x[1] ** 2), -2 * x[0] * x[1] / (1 + x[1] ** 2) ** 2],
    ])


def range_bearing(x):
    """Rejects complex input: arctan2 has no complex version."""
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def range_bearing_jacobian(x):
    r2 = x[0] ** 2 + x[1] ** 2
    r = np.sqrt(r2)
    return np.array([[x[0] / r, x[1] / r], [-x[1] / r2, x[0] / r2]])


def _relerr(J, J_true):
    return np.max(np.abs(J - J_true)) / np.max(np.abs(J_true))


@settings(max_examples=50, deadline=None)
@given(x0=st.floats(0.05, 5.0), x1=st.floats(-2.0, 2.0))
def test_complex_step_is_exact_on_smooth_functions(x0, x1):
    x = np.array([x0, x1])
    J = jacobian("g", smooth, x, (), 3)
    assert _relerr(J, smooth_jacobian(x)) <= 1e-10


@settings(max_examples=30, deadline=None)
@given(x0=st.floats(0.2, 50.0), x1=st.floats(-50.0, 50.0))
def test_finite_difference_fallback_for_functions_rejecting_complex(x0, x1):
    x = np.array([x0, x1])
    with pytest.raises(Exception):
        complex_step_jacobian("h", range_bearing, x, (), 2)
    J = jacobian("h", range_bearing, x, (), 2)
    assert _relerr(J, range_bearing_jacobian(x)) <= 1e-10


def test_finite_differences_on_smooth_functions():
    x = np.array([0.7, -0.3])
    assert _relerr(finite_difference_jacobian("g", smooth, x, (), 3), smooth_jacobian(x)) <= 1e-10


def test_vectorized_complex_step_uses_one_call():
    calls = []

    def f(X):
        calls.append(X.shape)
        return np.stack([X[:, 0] * X[:, 1], np.cos(X[:, 0])], axis=-1)

    J = jacobian("f", f, np.array([0.3, 2.0]), (), 2, vectorized=True, check="faint")
    np.testing.assert_allclose(J, [[2.0, 0.3], [-np.sin(0.3), 0.0]], rtol=1e-14)
    assert calls == [(2, 2)]
    calls.clear()  # checking every row against differences costs four more calls per component, of one state each
    np.testing.assert_array_equal(jacobian("f", f, np.array([0.3, 2.0]), (), 2, vectorized=True), J)
    assert calls == [(2, 2)] + [(1, 2)] * 8


def test_taylor_strategy_uses_given_jacobians_and_controls():
    model = NonlinearModel(
        f=lambda x, u: np.array([x[0] + u[0] * x[1], x[1]]),
        h=lambda x: np.array([x[0] ** 2]),
        Q=np.eye(2), R=1.0,
        h_jacobian=lambda x: np.array([[2 * x[0], 0.0]]),
    )
    lin = Taylor(model, us=np.array([[0.5], [2.0]]))
    A, b, Q = lin.transition(1, np.array([1.0, 3.0]), np.eye(2))
    np.testing.assert_allclose(A, [[1.0, 2.0], [0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(A @ [1.0, 3.0] + b, [7.0, 3.0])
    H, d, R = lin.measurement(0, np.array([3.0, 0.0]), np.eye(2))
    np.testing.assert_allclose(H, [[6.0, 0.0]])
    np.testing.assert_allclose(H @ [3.0, 0.0] + d, [9.0])


def test_bad_user_jacobian_shape_is_named():
    model = NonlinearModel(f=lambda x: x, h=lambda x: x[:1], Q=np.eye(2), R=1.0,
                           f_jacobian=lambda x: np.eye(3))
    with pytest.raises(ModelFunctionError, match=r"`f_jacobian` must return shape \(2, 2\).*got shape \(3, 3\)"):
        Taylor(model).transition(0, np.zeros(2), np.eye(2))


SCALES = [(1e-99, 1.0), (1.0, 1e-250), (1e99, 1e250), (1e-99, 1e-250), (1e99, 1e-100), (1e-60, 1e120)]


@pytest.mark.parametrize("s, c", SCALES)
def test_derivatives_hold_at_tiny_and_huge_scales(s, c):
    """``c g(x / s)`` has the Jacobian ``c J_g / s``. A complex step of 1e-100 in absolute terms was 1.5% off for
    states of size 1e-99, and its imaginary part underflowed for outputs of 1e-250; finite differences too."""
    u = np.array([0.7, -0.3])
    exact = c * smooth_jacobian(u) / s
    scaled = lambda x: c * smooth(x / s)  # noqa: E731
    for J in (jacobian("g", scaled, u * s, (), 3), finite_difference_jacobian("g", scaled, u * s, (), 3)):
        assert np.all(np.abs(J - exact) <= 1e-9 * np.abs(exact).max(axis=1, keepdims=True))
    np.testing.assert_allclose(complex_step_jacobian("g", scaled, u * s, (), 3), exact, rtol=1e-13)


def _mixed(x):
    """Outputs that do not depend on some components, one of them 0 at the point, beside a large derivative."""
    return np.array([x[0] * x[2], 1e8 * np.sin(x[1]), x[2] ** 3])


def test_a_derivative_that_is_zero_does_not_keep_shrinking_the_steps():
    """Its estimates are round-off, which a relative test never accepts: the steps used to shrink through all of
    SciPy's iterations, the round-off growing with them, to 2.5e-4 of the row's largest derivative here."""
    x, spread = np.array([0.0, 1e-8, 3.0]), np.array([1.0, 1e-9, 0.1])
    J = finite_difference_jacobian("h", _mixed, x, (), 3, spread=spread)
    exact = np.array([[3.0, 0.0, 0.0], [0.0, 1e8 * np.cos(1e-8), 0.0], [0.0, 0.0, 27.0]])
    assert np.all(np.abs(J - exact) <= 1e-12 * np.abs(exact).max(axis=1, keepdims=True))


def _h_real_only(x):
    """Rejects complex input (math.sin): finite differences."""
    return np.array([x[0], math.sin(x[1])])


@pytest.mark.parametrize("form", ["cov", "sqrt"])
def test_finite_difference_steps_follow_each_components_scale(form):
    """A bearing of 0.3 rad beside a range of 1e6: stepped on its own scale (the state's used to give a step of
    1e4 rad and d sin / dx = 0.009 instead of 0.955); the EKF equals the one with the analytic Jacobian."""
    x, cov = np.array([1e6, 0.3]), np.diag([100.0, 0.01])
    H, _, _ = Taylor(NonlinearModel(lambda s: s, _h_real_only, np.eye(2), np.eye(2))).measurement(0, x, cov)
    # To round-off: an entry's error is about ε |h_i| / step_j (ε 1e6 / 1e-4 here), a 1e-7 part of h's noise
    np.testing.assert_allclose(H, [[1.0, 0.0], [0.0, math.cos(0.3)]], rtol=1e-10, atol=1e-5)
    assert H[1, 1] == pytest.approx(math.cos(0.3), rel=1e-10)
    Q, R = np.diag([1.0, 1e-4]), np.diag([1.0, 1e-4])
    prior = gf.Gaussian(x, cov)
    zs = np.array([[1e6 + 3, math.sin(0.32)], [1e6 + 5, math.sin(0.31)]])
    auto = gf.filter(NonlinearModel(lambda s: s, _h_real_only, Q, R), prior, zs, method="ekf", form=form,
                     check="off")
    exact = gf.filter(NonlinearModel(lambda s: s, _h_real_only, Q, R,
                                     h_jacobian=lambda s: np.array([[1.0, 0.0], [0.0, math.cos(s[1])]])),
                      prior, zs, method="ekf", form=form, check="off")
    sd = np.sqrt(np.diagonal(exact.covs, axis1=1, axis2=2))
    assert np.all(np.abs(auto.means - exact.means) <= 1e-6 * sd)  # within 1e-6 standard deviations
    assert np.all(np.abs(auto.covs - exact.covs) <= 1e-6 * sd[:, :, None] * sd[:, None, :])  # and correlations


def test_finite_differences_call_a_vectorized_function_on_stacks():
    """A vectorized f that rejects complex input is differenced on stacks (k, n), never on one state (n,)."""
    shapes = []

    def f(X):
        shapes.append(X.shape)
        out = np.empty((X.shape[0], 2))  # float: a complex argument cannot be stored
        out[:, 0] = X[:, 0] + X[:, 1]
        out[:, 1] = X[:, 1]
        return out

    model = NonlinearModel(f, lambda X: X[:, :1], 0.1 * np.eye(2), 0.5, vectorized=True)
    prior, zs = gf.Gaussian([0.1, 1.0], np.eye(2)), [1.0, 2.0, 3.0]
    ekf = gf.filter(model, prior, zs, method="ekf", check="off")
    kf = gf.filter(gf.LinearModel([[1.0, 1.0], [0.0, 1.0]], [1.0, 0.0], 0.1 * np.eye(2), 0.5), prior, zs,
                   check="off")
    np.testing.assert_allclose(ekf.means, kf.means, rtol=1e-10)
    np.testing.assert_allclose(ekf.covs, kf.covs, rtol=1e-10)
    assert all(len(s) == 2 for s in shapes)


def test_finite_differences_across_the_angle_cut_are_the_analytic_jacobian():
    """f wrapping its angle, and a bearing by arctan2, reject complex steps; their finite differences straddled ±π
    and jumped by 2π: an angle variance of 2.7e8, a bearing slope of 1e8. The oracle is the analytic Jacobian."""
    wrap = lambda a: (a + np.pi) % (2 * np.pi) - np.pi  # noqa: E731
    f = lambda x: np.array([wrap(x[0] + 0.1 * x[1]), x[1]])  # noqa: E731
    F = np.array([[1.0, 0.1], [0.0, 1.0]])
    prior = gf.Gaussian([np.pi - 0.1 - 1e-10, 1.0], 0.01 * np.eye(2))
    for jac in (None, lambda x: F):
        got = gf.filter(gf.NonlinearModel(f, lambda x: np.sin(x[:1]), 1e-4 * np.eye(2), [[0.01]], state_angles=[0],
                                          f_jacobian=jac), prior, [[np.nan]], method="ekf", check="off")
        np.testing.assert_allclose(np.diag(got.covs[0]), [0.0102, 0.0101], rtol=1e-8)
    bearing = lambda x: np.array([np.arctan2(x[1], x[0])])  # noqa: E731
    slope = lambda x: np.array([[-x[1], x[0]]]) / (x[0] ** 2 + x[1] ** 2)  # noqa: E731
    prior = gf.Gaussian([-1.0, 1e-9], 1e-4 * np.eye(2))
    runs = [gf.filter(gf.NonlinearModel(lambda x: x, bearing, np.zeros((2, 2)), [[1e-4]], measurement_angles=[0],
                                        h_jacobian=jac), prior, [[np.pi - 0.001]], method="ekf", check="off")
            for jac in (None, slope)]
    np.testing.assert_allclose(runs[0].means, runs[1].means, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(runs[0].covs, runs[1].covs, rtol=1e-7, atol=1e-11 * np.abs(runs[1].covs).max())


def test_finite_differences_step_on_the_beliefs_spread_and_refuse_to_linearise_where_they_do_not_converge():
    """A range to a beacon 10 m away in Earth-centred metres (np.linalg.norm: no complex steps) was stepped by
    6.4e5 m, a tenth of |x|: SciPy stopped unconverged and the EKF used a slope 92% off, silently. Steps are on
    the belief's spread now; where SciPy's estimate does not converge the error names the function."""
    from gaussfuse.linearize import jacobian

    beacon = np.array([6378137.0 + 6.0, 8.0])
    h = lambda x: np.array([np.linalg.norm(x - beacon)])  # noqa: E731
    x = np.array([6378137.0, 0.0])
    np.testing.assert_allclose(jacobian("h", h, x, (), 1, spread=np.ones(2)), [[-0.6, -0.8]], rtol=1e-6)
    with pytest.raises(gf.ModelFunctionError, match=r"^the finite-difference Jacobian of `h` did not converge"):
        jacobian("h", h, x, (), 1)  # no spread: the state's scale, 6.4e5 m
    ekf = gf.filter(gf.NonlinearModel(lambda x: x, h, np.zeros((2, 2)), [[0.01]]), gf.Gaussian(x, np.eye(2)),
                    [[9.0]], method="ekf", check="off")
    exact = gf.filter(gf.NonlinearModel(lambda x: x, h, np.zeros((2, 2)), [[0.01]],
                                        h_jacobian=lambda x: ((x - beacon) / np.linalg.norm(x - beacon))[None]),
                      gf.Gaussian(x, np.eye(2)), [[9.0]], method="ekf", check="off")
    np.testing.assert_allclose(ekf.covs, exact.covs, rtol=1e-5)  # variances 0.64 and 0.37; were 1.0 and 0.019


@pytest.mark.parametrize("vectorized", [False, True])
@pytest.mark.parametrize("lost", ["norm", "vdot", "abs", "real"])
def test_an_output_that_drops_the_imaginary_part_is_differentiated_by_finite_differences(lost, vectorized):
    """Beside an output that keeps it, a range by np.linalg.norm (or vdot, abs, real) got a complex-step
    derivative of exactly 0: the EKF ignored the range, silently (audit CC1: posterior variance 4 for 0.00998).
    The oracle is the analytic Jacobian."""
    beacon = np.array([10.0, 0.0])
    distance = {"norm": lambda d: np.linalg.norm(d, axis=-1), "vdot": lambda d: np.sqrt(np.sum(d * d.conj(), axis=-1)),
              "abs": lambda d: np.sqrt(np.abs(d[..., 0]) ** 2 + np.abs(d[..., 1]) ** 2),
              "real": lambda d: np.sqrt(np.real(np.sum(d * d, axis=-1)))}[lost]

    def h(x):
        return np.stack([distance(x - beacon), x[..., 1]], axis=-1)

    def h_jacobian(x):
        d = x - beacon
        return np.array([d / np.sqrt(d @ d), [0.0, 1.0]])

    x = np.array([0.5, -0.3])
    J = jacobian("h", h, x, (), 2, vectorized=vectorized, spread=np.array([2.0, 2.0]))
    np.testing.assert_allclose(J, h_jacobian(x), rtol=1e-9, atol=1e-9)
    model = NonlinearModel(lambda x: x, h, np.zeros((2, 2)), np.diag([0.01, 1.0]), vectorized=vectorized)
    exact = NonlinearModel(lambda x: x, h, np.zeros((2, 2)), np.diag([0.01, 1.0]), vectorized=vectorized,
                           f_jacobian=lambda x: np.eye(2), h_jacobian=h_jacobian)
    prior = gf.Gaussian([0.0, 0.0], 4.0 * np.eye(2))
    got, want = (gf.filter(m, prior, [[7.0, 0.1]], method="ekf") for m in (model, exact))
    np.testing.assert_allclose(got.covs, want.covs, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(got.means, want.means, rtol=1e-8, atol=1e-12)


def test_an_output_that_does_not_depend_on_the_state_keeps_the_complex_step():
    """A constant output's row of zeros is checked (it stays 0) and the others keep the complex step's exact
    derivative."""
    h = lambda x: np.array([x[0] ** 3 + x[1], 5.0 + 0.0 * x[0]])  # noqa: E731
    x = np.array([0.7, -2.0])
    J = jacobian("h", h, x, (), 2, spread=np.array([1.0, 1.0]))
    np.testing.assert_array_equal(J, [[3 * 0.7**2, 1.0], [0.0, 0.0]])


def test_a_component_known_exactly_is_not_stepped_by_finite_differences():
    """A component of 0 with a variance of 0 was stepped by a tenth of the state's largest (1e5 beside 1e6):
    exp overflowed and the filter failed, though that column is never read (audit CC1). The oracle is the
    analytic Jacobian."""
    h = lambda x: np.array([math.exp(x[0]) * x[1]])  # noqa: E731 (math.exp refuses the complex step)
    analytic = lambda x: np.array([[math.exp(x[0]) * x[1], math.exp(x[0])]])  # noqa: E731
    prior = gf.Gaussian([0.0, 1e6], np.diag([0.0, 1.0]))
    models = [NonlinearModel(lambda x: x, h, np.diag([0.0, 1.0]), 1.0, **kw) for kw in ({}, {"h_jacobian": analytic})]
    got, want = (gf.filter(m, prior, [[1e6 + 0.5], [1e6 - 0.3]], method="ekf") for m in models)
    np.testing.assert_allclose(got.means, want.means, rtol=1e-12)
    np.testing.assert_allclose(got.covs, want.covs, rtol=1e-6, atol=1e-12)
    J = finite_difference_jacobian("h", h, np.array([0.0, 1e6]), (), 1, spread=np.array([0.0, 1.0]))
    assert J[0, 0] == 0.0 and J[0, 1] == pytest.approx(1.0, rel=1e-4)


@pytest.mark.parametrize("lost", ["norm", "vdot", "abs"])
def test_a_dropped_range_is_found_whatever_the_offset(lost):
    """Checked along one direction, a range whose offset from its beacon was perpendicular to it did not change
    either way, and kept its row of 0 (review R23: x = (4, 3) under a spread of 1). The oracle is analytic."""
    distance = {"norm": np.linalg.norm, "vdot": lambda d: np.sqrt(np.vdot(d, d)),
                "abs": lambda d: np.abs(d[0] + 1j * d[1])}[lost]
    h = lambda x: np.array([distance(x[:2]), x[1]])  # noqa: E731
    for x in ([4.0, 3.0], [3.0, -4.0], [6.0, 5.0], [1.0, 1.0], [-2.0, 7.5]):
        x = np.array(x)
        J = jacobian("h", h, x, (), 2, spread=np.array([1.0, 1.0]))
        np.testing.assert_allclose(J, [x / np.hypot(*x), [0.0, 1.0]], rtol=1e-9, atol=1e-9)


_BEACONS = np.array([[10.0, 0.0], [0.0, 12.0], [-7.0, -3.0]])


def _pseudoranges(x):
    """Ranges to three beacons through np.linalg.norm (which drops a complex step), plus a clock bias x[2]."""
    return np.array([np.linalg.norm(x[:2] - b) + x[2] for b in _BEACONS])


def _pseudorange_jacobian(x):
    d = x[:2] - _BEACONS
    return np.hstack([d / np.linalg.norm(d, axis=1)[:, None], np.ones((3, 1))])


def test_a_dropped_range_beside_a_derivative_that_is_kept_is_found():
    """The bias kept its derivative of 1, so no row was faint and the ranges' slopes were 0, silently: the EKF was
    1.99 off the filter with the analytic Jacobian after 5 steps. The oracle is analytic."""
    x = np.array([1.0, 2.0, 0.5])
    J = jacobian("h", _pseudoranges, x, (), 3, spread=np.ones(3))
    np.testing.assert_allclose(J, _pseudorange_jacobian(x), rtol=1e-9, atol=1e-9)
    exact = jacobian("h", _pseudoranges, x, (), 3, spread=np.ones(3), check="faint")  # (the rows not checked)
    np.testing.assert_array_equal(exact[:, :2], 0.0)

    kw = dict(f=lambda x: x, h=_pseudoranges, Q=0.01 * np.eye(3), R=0.1 * np.eye(3))
    models = [NonlinearModel(**kw), NonlinearModel(**kw, f_jacobian=lambda x: np.eye(3), h_jacobian=_pseudorange_jacobian)]
    zs = np.array([_pseudoranges(np.array([1.0, 2.0, 0.5])) + 0.1 * k for k in range(5)])
    prior = gf.Gaussian([0.0, 0.0, 0.0], np.eye(3))
    for method in ("ekf", "iekf"):
        got, want = (gf.filter(m, prior, zs, method=method) for m in models)
        np.testing.assert_allclose(got.means, want.means, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(got.covs, want.covs, rtol=1e-8, atol=1e-10)


def test_a_function_is_checked_at_its_first_jacobians_and_remembered():
    """One that refuses complex input is not offered it again; one that drops it is differenced from then on."""
    offered = []

    def h(x):
        offered.append(np.iscomplexobj(x))
        if np.iscomplexobj(x):
            raise TypeError("real only")
        return np.array([math.sin(x[0])])

    model = NonlinearModel(lambda x: x, h, np.eye(1), np.eye(1), f_jacobian=lambda x: np.eye(1))
    gf.filter(model, gf.Gaussian([0.1], [[1.0]]), np.zeros((6, 1)), method="ekf")
    assert sum(offered) == 1 and len(offered) > 6
    moved = []

    def f(x):  # a smoother's passes are one run (review R33: the backward pass had a record of its own)
        moved.append(np.iscomplexobj(x))
        if np.iscomplexobj(x):
            raise TypeError("real only")
        return np.array([0.9 * x[0] + math.sin(x[0])])

    smoothing = NonlinearModel(f, lambda x: x, np.eye(1), np.eye(1), h_jacobian=lambda x: np.eye(1))
    gf.smooth(smoothing, gf.Gaussian([0.1], [[1.0]]), np.zeros((6, 1)), method="ekf")
    assert sum(moved) == 1 and len(moved) > 12
    lin = Taylor(NonlinearModel(lambda x: x, _pseudoranges, np.eye(3), np.eye(3)))
    for x in ([1.0, 2.0, 0.5], [3.0, -1.0, 0.0]):
        H = lin.measurement(0, np.array(x), np.eye(3))[0]
        np.testing.assert_allclose(H, _pseudorange_jacobian(np.array(x)), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("h, x, spread", [
    (lambda x: x**3, [0.0], [1.0]),  # a stationary point: the central difference's cubic term is not J m = 0
    (lambda x: np.sin(x) - x, [0.0], [1.0]),
    (lambda x: x**2 + x**3, [0.0], None),  # a state of zeros, no spread
    (lambda x: np.sin(1000 * x), [0.3], [1.0]),  # curved over a thousandth of the spread
    (lambda x: np.sin(1000 * x), [0.3], [3.0]),  # ... of a third of it (review R29: finite differences then failed)
    (lambda x: np.tanh(x / 1e-3), [0.0], [10.0]),
    (lambda x: np.arctan(x), [0.0], [1e4]),
    (lambda x: x * np.exp(-x**2), [0.0], [3e3]),  # (finite differences gave a slope of 3e-153 for 1)
    (lambda x: 1e8 + x + np.sin(x), [3.0], [3e3]),  # a step lost in round-off confirmed a drop (review R31)
    (lambda x: 1e10 + np.sin(10 * x), [0.0], [316.0]),
    (lambda x: np.exp(x), [1.0], [300.0]),
    (lambda x: 1 / (1 + x / 1e-16), [1.0], [1.0]),
    (lambda x: x**2, [1e-150], [1e-151]),
    (lambda x: x**2, [1e150], [1e149]),
])
def test_checking_every_row_keeps_the_complex_step_of_an_analytic_function(h, x, spread):
    """The first Jacobian's check compared one central difference with J m within 1%, and took the truncation
    error of a curved function, or a cubic term at a stationary point, for a dropped derivative: the run was
    differenced from then on (sin(1000 x) came out 4.9 off, x³ from a mean of 0 failed; review R28)."""
    x, spread = np.array(x), None if spread is None else np.array(spread)
    J = complex_step_jacobian("h", h, x, (), 1, spread=spread, check="faint")
    np.testing.assert_array_equal(jacobian("h", h, x, (), 1, spread=spread), J)


def test_an_ekf_with_a_strongly_curved_sensor_keeps_the_exact_derivative():
    """The oracle is the same filter with the analytic Jacobian (review R28: 4.88 off, silently)."""
    kw = dict(f=lambda x: x, h=lambda x: np.sin(1000 * x), Q=0.01 * np.eye(1), R=0.01 * np.eye(1))
    models = [NonlinearModel(**kw), NonlinearModel(**kw, h_jacobian=lambda x: np.array([[1000 * np.cos(1000 * x[0])]]))]
    zs = 0.5 + 0.05 * np.random.default_rng(1).standard_normal((50, 1))
    got, want = (gf.filter(m, gf.Gaussian([0.3], [[1.0]]), zs, method="ekf", check="off") for m in models)
    np.testing.assert_allclose(got.means, want.means, rtol=1e-13, atol=1e-15)


def test_a_dropped_range_is_found_beside_a_far_wider_clock_bias():
    """Checked along two mixed directions, a position spread of 100 m moved the ranges by 0.03% of the bias's
    3e5 m, within the check's 1%: the position columns stayed 0 (review R28). Each component is now checked on its
    own. The oracle is the analytic Jacobian."""
    stations = np.array([[20e6, 0, 0], [0, 20e6, 0], [0, 0, 20e6], [12e6, 12e6, 12e6]])

    def h(x):
        return np.array([np.linalg.norm(x[:3] - s) + x[3] for s in stations])

    def h_jacobian(x):
        d = x[:3] - stations
        return np.hstack([d / np.linalg.norm(d, axis=1)[:, None], np.ones((4, 1))])

    truth = np.array([1e5, -2e5, 3e5, 1e3])
    zs = h(truth) + 5 * np.random.default_rng(0).standard_normal((5, 4))
    prior = gf.Gaussian(truth + [100, -100, 50, 3e5], np.diag([1e4, 1e4, 1e4, 9e10]))
    kw = dict(f=lambda x: x, h=h, Q=np.eye(4), R=25 * np.eye(4))
    got, want = (gf.filter(NonlinearModel(**kw, **extra), prior, zs, method="ekf")
                 for extra in ({}, {"h_jacobian": h_jacobian}))
    np.testing.assert_allclose(got.means, want.means, rtol=1e-9, atol=1e-4)


def test_a_dropped_slope_hidden_at_the_first_state_is_found_at_the_next():
    """An odometer |v| + b first linearised at v = 0, where |v| has no slope either way: the first check found
    nothing, and v was never updated (review R28). The first few Jacobians are checked; the oracle is the
    analytic Jacobian."""
    f = lambda x: np.array([x[0] + 0.5, x[1]])  # noqa: E731
    h = lambda x: np.array([np.abs(x[0]) + x[1], x[1]])  # noqa: E731
    h_jacobian = lambda x: np.array([[np.sign(x[0]), 1.0], [0.0, 1.0]])  # noqa: E731
    v = 0.5 * np.arange(1, 61) + 0.7
    zs = np.c_[v + 0.3, np.full(60, 0.3)]
    kw = dict(f=f, h=h, Q=np.diag([0.01, 1e-4]), R=np.diag([0.01, 1.0]))
    prior = gf.Gaussian([-0.5, 0.0], np.eye(2))
    got, want = (gf.filter(NonlinearModel(**kw, **extra), prior, zs, method="ekf", check="off")
                 for extra in ({}, {"h_jacobian": h_jacobian}))
    np.testing.assert_allclose(got.means, want.means, rtol=1e-8, atol=1e-8)


def test_an_online_filter_keeps_its_record_of_checks_across_calls_with_their_own_noise():
    """kf.update(z, R=...) makes a strategy for the call, which checked every row again (review R28: 350 calls of
    h over 50 steps for 154)."""
    calls = []

    def h(x):
        calls.append(1)
        return np.array([np.sqrt(x[0] ** 2 + 1.0), x[1]])

    model = NonlinearModel(lambda x: x, h, 0.01 * np.eye(2), np.eye(2))
    counts = []
    for per_call in (False, True):
        calls.clear()
        kf = gf.KalmanFilter(model, gf.Gaussian([1.0, 1.0], np.eye(2)), method="ekf")
        for _ in range(50):
            kf.predict()
            kf.update([1.5, 1.5], R=np.eye(2) if per_call else None)
        counts.append(len(calls))
    assert counts[1] == counts[0]


def test_a_drop_found_after_the_first_checks_is_remembered():
    """|x0| held at 0 for the first three Jacobians hides its dropped slope; found at a later one, it was checked
    and differenced again at every step (review R29)."""
    lin = Taylor(NonlinearModel(lambda x: x, lambda x: np.array([np.abs(x[0]), x[1]]), np.eye(2), np.eye(2)))
    for x0 in (0.0, 0.0, 0.0, 0.5, -0.7):
        H = lin.measurement(0, np.array([x0, 1.0]), np.eye(2))[0]
        np.testing.assert_allclose(H, [[np.sign(x0), 0.0], [0.0, 1.0]], atol=1e-9)
    assert lin.checks == {"h": -1}


@pytest.mark.parametrize("offset", [1e6, 1e8, 1e10])
def test_a_dropped_slope_of_an_output_far_larger_than_its_change_is_found(offset):
    """At steps 1e-3 as short the change of 1e8 + |x0| is within its round-off: the confirmation found no
    disagreement there, and the slope of 0 was kept (review R30: an ENU pseudorange of 2e7 m never moved the
    position). No evidence at the shorter step keeps the longer one's. The oracle is analytic."""
    h = lambda x: np.array([offset + np.abs(x[0]), x[1]])  # noqa: E731
    J = jacobian("h", h, np.array([0.7, 1.0]), (), 2, spread=np.array([1.0, 1.0]))
    np.testing.assert_allclose(J, [[1.0, 0.0], [0.0, 1.0]], rtol=0, atol=1e-3)


def test_the_check_argument_is_checked():
    with pytest.raises(ValueError, match="`check` must be 'all' or 'faint'; got 'none'"):
        jacobian("h", _pseudoranges, np.array([1.0, 2.0, 0.5]), (), 3, check="none")


def test_a_dropped_output_beside_a_domains_edge_is_found_from_the_side_that_has_it():
    """The check's central difference had no evidence where f raised a step behind x, and kept a row of 0."""
    def h(x):
        if x[0] < 1.0:
            raise ValueError("domain: x0 >= 1")
        return np.array([np.linalg.norm(x - np.array([10.0, 0.0])), x[1]])

    with pytest.raises(ModelFunctionError, match="domain: x0 >= 1"):  # (finite differences step across it too)
        jacobian("h", h, np.array([1.0, 0.5]), (), 2, spread=np.array([1.0, 1.0]))


def test_a_stationary_output_beside_a_domains_edge_keeps_the_complex_step():
    """One side's difference saw the quadratic term of an output at a stationary point, fell back to finite
    differences, and those stepped past the edge (review R24: ModelFunctionError for an exact [[0, 0], [0, 1]])."""
    def h(z):
        if np.real(z[0]) < 0:
            raise ValueError("domain: x0 >= 0")
        return np.array([5.0 + z[0] ** 2, z[1]])

    J = jacobian("h", h, np.array([0.0, 1.0]), (), 2, spread=np.array([0.1, 0.1]))
    np.testing.assert_array_equal(J, [[0.0, 0.0], [0.0, 1.0]])

    def narrow(z):  # a domain narrower than the check's two steps: its one step still finds a dropped range
        if not 0.0 <= np.real(z[0]) <= 1.5e-4:  # (review R25: no evidence, and a silent row of 0)
            raise ValueError("domain: 0 <= x0 <= 1.5e-4")
        return np.array([np.linalg.norm(z - np.array([10.0, 0.0])), z[1]])

    with pytest.raises(ModelFunctionError, match="domain: 0 <= x0"):  # (finite differences step out of it)
        jacobian("h", narrow, np.array([0.0, 1.0]), (), 2, spread=np.array([0.1, 0.1]))

    def narrow_stationary(z):  # ... where a stationary point keeps its exact derivative (review R26: it fell back)
        if not 0.0 <= np.real(z[0]) <= 1.5e-4:
            raise ValueError("domain: 0 <= x0 <= 1.5e-4")
        return np.array([5.0 + z[0] ** 2, z[1]])

    J = jacobian("h", narrow_stationary, np.array([0.0, 1.0]), (), 2, spread=np.array([0.1, 0.1]))
    np.testing.assert_array_equal(J, [[0.0, 0.0], [0.0, 1.0]])


def test_a_stationary_output_keeps_the_complex_step():
    """At a stationary point the one-sided real check saw the quadratic term and fell back to finite
    differences (27 calls for 2; review R22): the check is a central difference. A vectorized output of the
    wrong shape met in the check is the library's error, not an IndexError."""
    calls = []

    def h(x):
        calls.append(1)
        return np.array([np.sin(x[0]), -np.cos(x[0])])

    J = jacobian("h", h, np.array([0.0]), (), 2, spread=np.array([0.3]))
    np.testing.assert_array_equal(J, [[1.0], [0.0]])
    assert len(calls) <= 5  # the complex step's, and the check's two directions (finite differences took 27)
    with pytest.raises(ModelFunctionError, match=r"`h` must return shape \(1, 1\) .* got shape \(1,\)"):  # (IndexError)
        jacobian("h", lambda X: np.sum(np.abs(X - 10.0) ** 2, axis=-1) ** 0.5, np.array([0.5, -0.3]), (), 1,
                 vectorized=True, spread=np.array([1.0, 1.0]))
