"""Input validation: the validators themselves and every error of gf.filter / gf.smooth.

Each message names the argument in backticks, the expected shape and what was
given; the tests pin them with anchored regular expressions.
"""

from __future__ import annotations

import datetime
import re

import numpy as np
import pytest

import gaussfuse as gf
from gaussfuse import diagnostics
from gaussfuse._validation import (as_array, as_matrix, as_vector, call_checked, call_each, check_psd, integer,
                                   shape_error, size_reason)
from gaussfuse.errors import ModelFunctionError

FRONTS = [gf.filter, gf.smooth]
front = pytest.mark.parametrize("run", FRONTS, ids=["filter", "smooth"])


# ---------------------------------------------------------------------------
# The validators
# ---------------------------------------------------------------------------


def test_shape_error_template():
    err = shape_error("x", "(2, 3)", (4,))
    assert isinstance(err, ValueError)
    assert str(err) == "`x` must have shape (2, 3); got shape (4,)."


def test_as_array_returns_a_float64_copy():
    src = np.array([1, 2, 3])
    out = as_array("x", src)
    assert out.dtype == np.float64
    out[0] = 10
    assert src[0] == 1


@pytest.mark.parametrize(
    ("value", "kwargs", "error", "match"),
    [
        ("abc", {}, TypeError, r"^`x` must be an array of numbers; got str\.$"),
        (b"abc", {}, TypeError, r"^`x` must be an array of numbers; got bytes\.$"),
        (None, {}, TypeError, r"^`x` must be an array of numbers; got NoneType\.$"),
        ([1.0, "a"], {}, TypeError, r"^`x` must be an array of numbers; got strings\.$"),
        ([[1.0], [1.0, 2.0]], {}, TypeError,
         r"^`x` must be a rectangular array of real numbers; got rows of different lengths \(1, 2\)\.$"),
        ([1.0, 1j], {}, TypeError, r"^`x` must be real; got complex values\.$"),
        (np.array([1.0, 1j]), {}, TypeError, r"^`x` must be real; got complex values\.$"),
        (np.complex128(1j), {}, TypeError, r"^`x` must be real; got complex values\.$"),
        ([1.0, np.nan], {}, ValueError, r"^`x` must be finite; got a non-finite \(NaN or inf\) value at index \(1,\)\.$"),
        ([[1.0, -np.inf]], {}, ValueError, r"^`x` must be finite; got a non-finite \(NaN or inf\) value at index \(0, 1\)\.$"),
        ([np.nan, np.inf], {"allow_nan": True}, ValueError, r"^`x` must be finite; got an infinite value at index \(1,\)\.$"),
    ],
)
def test_as_array_errors(value, kwargs, error, match):
    with pytest.raises(error, match=match):
        as_array("x", value, **kwargs)


def test_as_array_allows_nan_when_asked():
    out = as_array("x", [1.0, np.nan], allow_nan=True)
    assert np.isnan(out[1])


def test_as_vector():
    np.testing.assert_array_equal(as_vector("v", 3.0), [3.0])
    np.testing.assert_array_equal(as_vector("v", [1, 2], size=2), [1.0, 2.0])
    with pytest.raises(ValueError, match=r"^`v` must have shape \(3,\); got shape \(2,\)\.$"):
        as_vector("v", [1, 2], size=3)
    with pytest.raises(ValueError, match=r"^`v` must have shape \(2,\); got shape \(\)\.$"):
        as_vector("v", 1.0, size=2)
    with pytest.raises(ValueError, match=r"^`v` must have shape \(n,\) with n >= 1; got shape \(2, 2\)\.$"):
        as_vector("v", np.eye(2))


def _one_by_one(name, fn, X, size):
    """What call_each replaces: call_checked at each point in turn, stacked (or the first error's message)."""
    try:
        return np.stack([call_checked(name, fn, x, (), (size,), size_reason(name, size)) for x in X])
    except ModelFunctionError as exc:
        return str(exc)


def _together(name, fn, X, size, finite=True):
    try:
        return call_each(name, fn, X, (), size, finite)
    except ModelFunctionError as exc:
        return str(exc)


def _at(bad_point, value):
    """h of two outputs that returns `value` at point `bad_point` (a callable value raises)."""
    def h(x):
        if x[0] == bad_point:
            return value(x) if callable(value) else value
        return np.array([x[0] * 2.0, np.sin(x[1])])
    return h


X5 = np.column_stack([np.arange(5.0), np.linspace(-1.0, 1.0, 5)])


@pytest.mark.parametrize("h", [
    _at(-1, None),                                   # every point fine
    _at(2, [1, 2]),                                   # integers: cast, as one by one
    _at(2, np.array([1.0, np.nan])),                  # non-finite
    _at(2, np.array([1.0, np.inf])),
    _at(1, np.array([1.0, 2.0, 3.0])),                # wrong shape
    _at(3, np.array([[1.0, 2.0]])),                   # (1, 2): wrong shape, not squeezed
    _at(0, np.array([1.0 + 1j, 2.0])),                # complex
    _at(4, np.array([True, False])),                  # booleans
    _at(2, "text"),
    _at(2, [1.0, [2.0]]),                             # ragged
    _at(3, lambda x: 1 / 0),                          # raises
    _at(2, lambda x: np.array([1.0, np.nan]) if x[0] == 2 else 1 / 0),
])
def test_call_each_is_call_checked_at_each_point_in_turn(h):
    """The stacked outputs, or the error of the first bad point, as call_checked one point at a time gives."""
    expected = _one_by_one("h", h, X5, 2)
    got = _together("h", h, X5, 2)
    if isinstance(expected, str):
        assert got == expected
    else:
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == np.float64 and got.shape == (5, 2)


def test_call_each_reports_the_first_bad_point_before_a_later_exception():
    def h(x):
        if x[0] == 1:
            return np.array([1.0])  # wrong shape at point 1
        if x[0] == 3:
            raise RuntimeError("boom")
        return x * 1.0

    assert _together("h", h, X5, 2) == _one_by_one("h", h, X5, 2)
    assert "must return shape (2,)" in _together("h", h, X5, 2)


def test_call_each_passes_non_finite_values_when_asked():
    h = _at(2, np.array([1.0, np.nan]))
    out = _together("h", h, X5, 2, finite=False)
    assert np.isnan(out[2, 1]) and np.isfinite(np.delete(out, 2, axis=0)).all()
    # a wrong shape is still an error
    assert "must return shape" in _together("h", _at(1, np.array([1.0])), X5, 2, finite=False)


def test_call_each_of_a_size_one_output_takes_scalars():
    np.testing.assert_array_equal(call_each("h", lambda x: float(x[0]), X5, (), 1), X5[:, :1])
    np.testing.assert_array_equal(call_each("h", lambda x: x[:1], X5[:0], (), 1), np.empty((0, 1)))


def test_as_matrix_forms():
    assert as_matrix("M", 2.0, 1, 1).shape == (1, 1)
    assert as_matrix("M", [1.0, 2.0], None, 2, row_vector_ok=True).shape == (1, 2)
    assert as_matrix("M", [1.0, 2.0], 2, None, column_vector_ok=True).shape == (2, 1)
    assert as_matrix("M", np.ones((4, 2, 3)), 2, 3, steps=4).shape == (4, 2, 3)


@pytest.mark.parametrize(
    ("value", "args", "kwargs", "match"),
    [
        (np.ones((2, 3)), (3, 3), {}, r"^`M` must have shape \(3, 3\) or, time-varying, \(T, 3, 3\); got shape \(2, 3\)\.$"),
        (np.ones(3), (None, None), {}, r"^`M` must have shape \(m, n\) or, time-varying, \(T, m, n\); got shape \(3,\)\.$"),
        (np.ones(3), (None, None), {"row_name": "n"}, r"^`M` must have shape \(n, n\) or, time-varying, \(T, n, n\); got shape \(3,\)\.$"),
        (np.ones((2, 2)), (3, None), {"col_name": "p"}, r"^`M` must have shape \(3, p\) or, time-varying, \(T, 3, p\); got shape \(2, 2\)\.$"),
        (np.ones((5, 2, 2)), (2, 2), {"steps": 4}, r"^`M` must have shape \(2, 2\) or, time-varying, \(4, 2, 2\); got shape \(5, 2, 2\)\.$"),
        (np.ones((1, 2, 2, 2)), (2, 2), {}, r"^`M` must have shape \(2, 2\) or, time-varying, \(T, 2, 2\); got shape \(1, 2, 2, 2\)\.$"),
        (np.ones((3, 2, 2)), (2, 2), {"time_varying": False}, r"^`M` must have shape \(2, 2\); got shape \(3, 2, 2\)\.$"),
        # (filterpy's users write R = 5: audit Y3)
        (5.0, (2, 2), {}, r"^`M` must have shape \(2, 2\) or, time-varying, \(T, 2, 2\); got shape \(\)\. A number is a "
                          r"1 × 1 matrix only; for 5 times the identity give 5 \* np\.eye\(2\)\.$"),
        (5.0, (2, 3), {}, r"^`M` must have shape \(2, 3\) or, time-varying, \(T, 2, 3\); got shape \(\)\.$"),
        (np.ones((0, 2)), (None, 2), {}, r"^`M` must have shape \(m, 2\) or, time-varying, \(T, m, 2\); got shape \(0, 2\)\.$"),
        (np.ones((0, 2, 2)), (2, 2), {}, r"^`M` must have shape \(2, 2\) or, time-varying, \(T, 2, 2\); got shape \(0, 2, 2\)\.$"),
    ],
)
def test_as_matrix_errors(value, args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        as_matrix("M", value, *args, **kwargs)


def test_a_variance_rounded_to_zero_among_subnormals_is_round_off():
    """A motion's own Q at q = 1e-300 was refused when it built a model (naming `Q`, which the user never gave):
    c_00 = 3.3e-325 rounds to 0 beside c_01 = 5e-317, and a subnormal variance of 2.8e-320 carries a relative
    round-off of 1e-4 (audit BB1). The spacing of subnormals, 2**-1074, is an entry's least round-off."""
    for motion, dt in ((gf.ConstantVelocity(q=1e-300), 1e-8), (gf.ConstantAcceleration(q=1e-300), 1e-8),
                       (gf.ConstantAcceleration(q=1e-300, noise="piecewise"), 1e-3)):
        Q = motion.transition(dt)[1]
        np.testing.assert_array_equal(check_psd("Q", Q), Q)
        assert np.array_equal(gf.model(motion, gf.Position(), dt).Q, Q)
    u = 5e-324  # a covariance of u beside variances of 0 is their round-off; 2 u is not, for any n (review R20)
    check_psd("Q", np.array([[0.0, u], [u, 0.0]]))
    for n in (2, 50):
        wrong = np.zeros((n, n))
        wrong[0, 1] = wrong[1, 0] = 2 * u
        with pytest.raises(ValueError, match="`Q` must be positive semi-definite"):
            check_psd("Q", wrong)
    # what is past that round-off is still refused, at every scale; an indefinite block beside a tiny variance too
    # (review R19: the allowance was scaled by the smallest variance, and took those in)
    block = np.zeros((4, 4))
    block[:3, :3] = 2.3e-308 * (np.full((3, 3), -0.525) + 1.525 * np.eye(3))  # eigenvalues down to -0.05 of it
    block[3, 3] = 48 * np.finfo(np.float64).eps * 2.3e-308
    for wrong in ([[1e-320, 2e-320], [2e-320, 1e-320]], [[-1e-320]], [[1e-310, 0.0], [0.0, -1e-318]],
                  [[0.0, 1e-200], [1e-200, 1e-300]], [[1e10, 0.0], [0.0, -0.5]], np.diag([-1e-310, 5e-324]), block):
        with pytest.raises(ValueError, match="`Q` must be positive semi-definite"):
            check_psd("Q", np.array(wrong))


def test_check_psd():
    sym = check_psd("P", np.array([[1.0, 0.5 + 1e-12], [0.5, 1.0]]))
    np.testing.assert_array_equal(sym, sym.T)
    np.testing.assert_array_equal(check_psd("P", np.zeros((2, 2))), np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"^`P` must be symmetric; its entries \[0, 1\] and \[1, 0\] differ, 0\.5 and "
                                         r"0\.4\.$"):
        check_psd("P", np.array([[1.0, 0.5], [0.4, 1.0]]))
    with pytest.raises(ValueError, match=r"^`P` must be positive semi-definite; its smallest eigenvalue is -1\.$"):
        check_psd("P", np.diag([1.0, -1.0]))
    stack = np.stack([np.eye(2), np.eye(2), np.diag([1.0, -0.5])])
    with pytest.raises(ValueError, match=r"^`P` must be positive semi-definite; its smallest eigenvalue is -0\.5 at time step 2\.$"):
        check_psd("P", stack)
    stack[1, 0, 1] = 0.3
    with pytest.raises(ValueError, match=r"^`P` must be symmetric; its entries \[0, 1\] and \[1, 0\] differ, 0\.3 and "
                                         r"0\.0 at time step 1\.$"):
        check_psd("P", stack)


def test_check_psd_judges_relative_to_scale():
    # Round-off on a large matrix is accepted; a real negative direction is not.
    big = 1e8 * np.array([[1.0, 1.0], [1.0, 1.0]])
    big_off = big.copy()
    big_off[0, 1] += 1e-3
    check_psd("P", big_off)
    with pytest.raises(ValueError, match="positive semi-definite"):
        check_psd("P", np.array([[1.0, 0.0], [0.0, -1e-6]]))


def test_check_psd_judges_each_entry_on_its_components_scale():
    """A negative variance or an asymmetry passed when it was small next to another component's variance."""
    for bad, what in ((np.diag([1e10, -0.5]), "positive semi-definite"), (np.diag([1e10, -1e-4]), "positive"),
                      (np.array([[1e10, 0.5], [0.0, 1.0]]), "symmetric"),
                      (np.array([[1e10, 1e5], [1e5, 0.999]]), "positive")):  # a correlation just above 1
        with pytest.raises(ValueError, match=what):
            check_psd("Q", bad)
        with pytest.raises(ValueError, match=what):
            gf.Gaussian([0.0, 0.0], bad)
    rng = np.random.default_rng(0)
    for _ in range(50):  # G Gᵀ with rows 1e-150 to 1e150 apart, of rank 1 to 4: PSD, whatever the round-off
        G = 10.0 ** rng.uniform(-150, 150, (4, 1)) * rng.standard_normal((4, rng.integers(1, 5)))
        check_psd("Q", G @ G.T)
    check_psd("Q", np.diag([1.0, -1e-20]))  # a zero variance computed to round-off of the largest entry
    # a variance judged on the largest scale still bounds its covariances: correlation 3.16 passed, and the
    # filter then gave a variance of -8.99 without a word
    with pytest.raises(ValueError, match=r"entry \[0, 1\] is larger than the variances \[0, 0\] and \[1, 1\] allow"):
        gf.Gaussian([0.0, 0.0], [[1.0, 1e-8], [1e-8, 1e-17]])
    check_psd("Q", np.array([[1.0, 1e-17], [1e-17, 0.0]]))  # a covariance at round-off beside a zero variance


# ---------------------------------------------------------------------------
# filter / smooth
# ---------------------------------------------------------------------------


def _model(**kw):
    base = {"F": np.eye(2), "H": [1.0, 0.0], "Q": np.eye(2), "R": 1.0}
    return gf.LinearModel(**(base | kw))


PRIOR = gf.Gaussian([0.0, 0.0], np.eye(2))


@front
@pytest.mark.parametrize(
    ("m", "zs", "match"),
    [
        (1, np.ones((3, 2)), r"^`zs` must have shape \(T, 1\) or \(T,\), or \(N, T, 1\) for N series, with T >= 1 and N >= 1; got shape \(3, 2\)\.$"),
        (1, np.ones((0, 1)), r"^`zs` must have shape \(T, 1\) or \(T,\), or \(N, T, 1\) for N series, with T >= 1 and N >= 1; got shape \(0, 1\)\.$"),
        (1, np.ones(0), r"^`zs` must have shape \(T, 1\) or \(T,\), or \(N, T, 1\) for N series, with T >= 1 and N >= 1; got shape \(0,\)\.$"),
        (1, 5.0, r"^`zs` must have shape \(T, 1\) or \(T,\), or \(N, T, 1\) for N series, with T >= 1 and N >= 1; got shape \(\)\.$"),
        (1, np.ones((2, 3, 4, 1)), r"^`zs` must have shape \(T, 1\) or \(T,\), or \(N, T, 1\) for N series, with T >= 1 and N >= 1; got shape \(2, 3, 4, 1\)\.$"),
        (2, np.ones(4), r"^`zs` must have shape \(T, 2\), or \(N, T, 2\) for N series, with T >= 1 and N >= 1; got shape \(4,\)\.$"),
        (2, np.ones((4, 3)), r"^`zs` must have shape \(T, 2\), or \(N, T, 2\) for N series, with T >= 1 and N >= 1; got shape \(4, 3\)\.$"),
        (2, np.ones((2, 4, 3)), r"^`zs` must have shape \(T, 2\), or \(N, T, 2\) for N series, with T >= 1 and N >= 1; got shape \(2, 4, 3\)\.$"),
        # an empty batch (it raised IndexError)
        (1, np.ones((0, 5, 1)), r"^`zs` must have shape \(T, 1\) or \(T,\), or \(N, T, 1\) for N series, with T >= 1 and N >= 1; got shape \(0, 5, 1\)\.$"),
        (2, np.ones((0, 0, 2)), r"^`zs` must have shape \(T, 2\), or \(N, T, 2\) for N series, with T >= 1 and N >= 1; got shape \(0, 0, 2\)\.$"),
    ],
)
def test_measurements_of_wrong_shape(run, m, zs, match):
    model = _model(H=np.eye(m, 2), R=np.eye(m))
    with pytest.raises(ValueError, match=match):
        run(model, PRIOR, zs)


@front
def test_measurements_must_be_numbers_without_inf(run):
    with pytest.raises(ValueError, match=r"^`zs` must be finite; got an infinite value at index \(2,\)\.$"):
        run(_model(), PRIOR, [1.0, np.nan, -np.inf])
    with pytest.raises(TypeError, match=r"^`zs` must be an array of numbers; got str\.$"):
        run(_model(), PRIOR, "123")


@front
def test_ragged_measurements_are_caught_by_the_validator(run):
    """Series of different lengths were "`zs` must be an array of real numbers; got [array([[1.],\n ..." (the
    array's repr over several lines): the lengths are named, and how to pad them."""
    model = _model(H=np.eye(2), R=np.eye(2))
    with pytest.raises(TypeError, match=r"^`zs` must be a rectangular array of real numbers; got rows of different "
                                        r"lengths \(2, 1\); pad the shorter series at the end with NaN"):
        run(model, PRIOR, [[1.0, 2.0], [3.0]])
    with pytest.raises(TypeError, match=r"got rows of different lengths \(5, 3\); pad"):
        run(model, PRIOR, [np.ones((5, 2)), np.ones((3, 2))])


@front
def test_controls_required_when_model_has_B(run):
    with pytest.raises(ValueError, match=r"^`us` is required: the model has a control input with p = 1\.$"):
        run(_model(B=[1.0, 0.0]), PRIOR, [1.0, 2.0])


@front
def test_controls_rejected_without_B(run):
    with pytest.raises(ValueError, match=r"^`us` was given but the model has no control input; give the model `B`\.$"):
        run(_model(), PRIOR, [1.0, 2.0], us=[0.0, 0.0])


@front
@pytest.mark.parametrize(
    ("zs", "us", "match"),
    [
        ([1.0, 2.0], [1.0, 2.0, 3.0], r"^`us` must have shape \(T, p\) = \(2, 1\) or \(1, 2, 1\), matching `zs`; got shape \(3,\)\.$"),
        ([1.0, 2.0], np.ones((2, 2)), r"^`us` must have shape \(T, p\) = \(2, 1\) or \(1, 2, 1\), matching `zs`; got shape \(2, 2\)\.$"),
        (np.ones((3, 2, 1)), np.ones((2, 2, 1)), r"^`us` must have shape \(T, p\) = \(2, 1\) or \(3, 2, 1\), matching `zs`; got shape \(2, 2, 1\)\.$"),
        ([1.0, 2.0], np.ones((1, 1, 2, 1)), r"^`us` must have shape \(T, p\) = \(2, 1\) or \(1, 2, 1\), matching `zs`; got shape \(1, 1, 2, 1\)\.$"),
    ],
)
def test_controls_of_wrong_shape(run, zs, us, match):
    with pytest.raises(ValueError, match=match):
        run(_model(B=[1.0, 0.0]), PRIOR, zs, us=us)


@front
def test_controls_must_be_finite(run):
    with pytest.raises(ValueError, match=r"^`us` must be finite; got a non-finite \(NaN or inf\) value at index \(1,\)\.$"):
        run(_model(B=[1.0, 0.0]), PRIOR, [1.0, 2.0], us=[0.0, np.nan])


@front
def test_controls_broadcast_over_series(run):
    # (T, p) controls are shared by every one of N series, (1, T, p) too.
    model = _model(B=[1.0, 0.0])
    zs = np.arange(6.0).reshape(3, 2, 1)
    a = run(model, PRIOR, zs, us=[0.5, -0.5])
    b = run(model, PRIOR, zs, us=np.array([0.5, -0.5]).reshape(1, 2, 1))
    np.testing.assert_array_equal(a.means, b.means)
    assert a.means.shape == (3, 2, 2)


@front
def test_prior_of_wrong_type(run):
    with pytest.raises(TypeError, match=r"^`prior` must be a gaussfuse.Gaussian\(mean, cov\) or 'diffuse'; got tuple\.$"):
        run(_model(), (np.zeros(2), np.eye(2)), [1.0])
    with pytest.raises(TypeError, match=r"^`prior` must be a gaussfuse.Gaussian\(mean, cov\) or 'diffuse'; got 'flat'\.$"):
        run(_model(), "flat", [1.0])


@front
def test_prior_of_wrong_dimension(run):
    with pytest.raises(ValueError, match=r"^`prior` must have dimension 2 \(the model's state\); got 3\.$"):
        run(_model(), gf.Gaussian(np.zeros(3), np.eye(3)), [1.0])


@front
def test_time_varying_model_length_must_match_T(run):
    model = _model(F=np.stack([np.eye(2)] * 3))
    with pytest.raises(ValueError, match=r"^the model is time-varying over 3 steps but `zs` has 2 steps; they must agree\.$"):
        run(model, PRIOR, [1.0, 2.0])
    with pytest.raises(ValueError, match=r"but `zs` has 4 steps"):
        run(model, PRIOR, np.ones((5, 4, 1)))
    assert run(model, PRIOR, [1.0, 2.0, 3.0]).means.shape[0] == 3


def test_time_varying_matrices_must_agree_in_length():
    with pytest.raises(ValueError, match=r"^time-varying matrices must all have the same number of steps; `F` has 3, `R` has 4\.$"):
        _model(F=np.stack([np.eye(2)] * 3), R=np.ones((4, 1, 1)))


@front
def test_unknown_method(run):
    with pytest.raises(ValueError, match=r"^`method` must be one of \[('[a-z]+', )*'kf'(, '[a-z]+')*\]; got 'no-such-method'\.$"):
        run(_model(), PRIOR, [1.0], method="no-such-method")


@front
def test_unknown_option(run):
    with pytest.raises(TypeError, match=r"^unknown option\(s\) \['alpha', 'bogus'\] for method 'kf'; valid options are none\. "
                                        r"\(`alpha` is an option of method\(s\) \['ukf'\]; `\w+` has no argument `bogus`\)$"):
        run(_model(), PRIOR, [1.0], alpha=1.0, bogus=2)


@pytest.mark.parametrize("call, kwargs, note", [
    (gf.filter, dict(gatee=0.9), "did you mean `gate` for `gatee`?"),
    (gf.smooth, dict(keep="last"), "`smooth` has no argument `keep`"),  # (a filter's argument)
    (gf.filter, dict(tol=1e-3), "`tol` is an option of method(s) ['iekf', 'iplf']"),
    (gf.KalmanFilter, dict(chekc="off"), "did you mean `check` for `chekc`?"),
])
def test_an_unknown_keyword_is_explained(call, kwargs, note):
    """Each unknown keyword said only "valid options are none" for method 'kf' (audit Y3): now whose option it
    is, the argument a misspelt one is close to, or that the function has no such argument."""
    args = (_model(), PRIOR) if call is gf.KalmanFilter else (_model(), PRIOR, [1.0])
    with pytest.raises(TypeError, match=re.escape(f"for method 'kf'; valid options are none. ({note})")):
        call(*args, **kwargs)


@front
@pytest.mark.parametrize("model", [None, {"F": np.eye(2)}, "model"], ids=["None", "dict", "str"])
def test_wrong_model_type(run, model):
    """Every kind of model filter and smooth take is named, whatever the method (audit GG6: the message named
    "a LinearModel, NonlinearModel", not TimedModel, and with a method, the method)."""
    expected = (rf"^`model` must be a gaussfuse.LinearModel, NonlinearModel or TimedModel; got "
                rf"{type(model).__name__}\.$")
    with pytest.raises(TypeError, match=expected):
        run(model, PRIOR, [1.0])
    with pytest.raises(TypeError, match=expected):
        run(model, PRIOR, [1.0], method="kf")


@front
@pytest.mark.parametrize("part", [gf.ConstantVelocity(dim=1, q=1.0), gf.Position(dim=1, r=1.0)],
                         ids=["motion", "sensor"])
def test_a_motion_or_a_sensor_for_a_model_is_told_how_to_make_one(run, part):
    kind = "motion" if isinstance(part, gf.ConstantVelocity) else "sensor"
    with pytest.raises(TypeError, match=rf"; got {type(part).__name__} \(a {kind} model: "
                                        r"gaussfuse.model\(motion, sensor\) makes the model of both"):
        run(part, PRIOR, [1.0])


@front
def test_no_numpy_broadcasting_errors_leak(run):
    # A sample of malformed inputs: each must be caught by a validator, whose
    # message starts with a backticked argument name or names the model.
    model = _model(B=[1.0, 0.0])
    cases = [
        lambda: run(model, PRIOR, np.ones((3, 2)), us=np.ones(3)),
        lambda: run(model, PRIOR, [[1.0], [2.0]], us=[[1.0, 2.0]]),
        lambda: run(model, PRIOR, np.ones((2, 3, 1)), us=np.ones((3, 3, 1))),
    ]
    for case in cases:
        with pytest.raises((ValueError, TypeError), match=r"`"):
            case()


@pytest.mark.parametrize("value", [True, [True, False], np.array([[True]])])
def test_booleans_are_not_numbers(value):
    from gaussfuse._validation import as_array

    with pytest.raises(TypeError, match=r"`x` must be an array of numbers; got booleans"):
        as_array("x", value)
    with pytest.raises(TypeError, match=r"`R` must be an array of numbers; got booleans"):
        gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[1.0]], R=value if np.ndim(value) != 1 else [value[:1]])


@pytest.mark.parametrize("bad", ["0.5", True, None, [0.5]])
def test_motion_parameters_must_be_numbers(bad):
    with pytest.raises(TypeError, match=r"`dt` must be a positive number"):
        gf.constant_velocity(dt=bad, q=1.0, r=1.0)


# ---------------------------------------------------------------------------
# Masked arrays and dates
# ---------------------------------------------------------------------------


def test_as_array_masked_entries_are_missing():
    src = np.ma.array([[1, 2], [3, 4]], mask=[[0, 1], [0, 0]])
    out = as_array("zs", src, allow_nan=True, copy=False)
    np.testing.assert_array_equal(out, [[1.0, np.nan], [3.0, 4.0]])
    assert src.data[0, 1] == 2 and src.mask[0, 1]  # the caller's array is untouched
    unmasked = np.ma.array([1.0, 2.0], mask=False)
    np.testing.assert_array_equal(as_array("F", unmasked), [1.0, 2.0])
    with pytest.raises(ValueError, match=r"^`F` must not have masked entries \(only measurements may be missing\); "
                                         r"got a masked entry at index \(0, 1\)\.$"):
        as_array("F", src)


@pytest.mark.parametrize("value", [np.array(["2024-01-01", "2024-01-02"], dtype="datetime64[D]"),
                                   np.array([1, 2], dtype="timedelta64[s]"),
                                   [np.datetime64("2024-01-01T00:00")]])
def test_as_array_refuses_dates_and_times(value):
    """Not cast to counts of days, seconds or nanoseconds."""
    with pytest.raises(TypeError, match=r"^`F` must be an array of numbers; got (datetime64|timedelta64) values"):
        as_array("F", value)


@pytest.mark.parametrize("engine", ["python", "numba"])
@front
def test_masked_measurements_are_missing(run, engine):
    model = gf.LinearModel(F=[[1, 1], [0, 1]], H=np.eye(2), Q=0.1 * np.eye(2), R=np.eye(2))
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    data = np.array([[1.0, 1.1], [2.1, 0.9], [3.0, 1.0], [3.9, 1.2]])
    mask = np.zeros_like(data, dtype=bool)
    mask[1, 0] = mask[2] = True
    zs = np.ma.array(data, mask=mask)
    got = run(model, prior, zs, engine=engine)
    want = run(model, prior, np.where(mask, np.nan, data), engine=engine)
    np.testing.assert_array_equal(got.means, want.means)
    assert got.loglik == want.loglik
    np.testing.assert_array_equal(zs.data, data)  # not modified
    np.testing.assert_array_equal(zs.mask, mask)
    batch = run(model, prior, np.ma.stack([zs, zs]), engine=engine)
    np.testing.assert_array_equal(batch.means[1], want.means)


def test_masked_measurements_in_fit_and_online_filter():
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    prior = gf.Gaussian(0.0, 10.0)
    data = np.array([1.0, 1e6, 2.0, 2.5, 1.5, 3.0])  # the masked outlier would dominate if it were used
    zs = np.ma.array(data, mask=[0, 1, 0, 0, 0, 0])
    nan = np.where(zs.mask, np.nan, data)
    fitted, ref = gf.fit(model, prior, zs, iterations=5, tol=0.0), gf.fit(model, prior, nan, iterations=5, tol=0.0)
    assert fitted.loglik == pytest.approx(ref.loglik, rel=1e-12)
    kf = gf.KalmanFilter(model, prior)
    kf.predict()
    kf.update(np.ma.array([5.0], mask=[True]))
    np.testing.assert_array_equal(kf.belief.mean, [0.0])  # nothing observed


@front
def test_datetimes_are_not_measurements(run):
    model = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
    times = np.array(["2024-01-01", "2024-01-02"], dtype="datetime64[D]")
    with pytest.raises(TypeError, match=r"^`zs` must be an array of numbers; got datetime64\[D\] values: "
                                        r"datetimes are not measurements\.$"):
        run(model, gf.Gaussian(0.0, 1.0), times)
    with pytest.raises(TypeError, match=r"^`us` must be an array of numbers; got timedelta64 values"):
        run(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0, B=1.0), gf.Gaussian(0.0, 1.0), [1.0, 2.0],
            np.array([1, 2], dtype="timedelta64[s]"))
    for name, kwargs in (("F", {"F": times[:1].reshape(1, 1)}), ("Q", {"Q": np.array([[1]], dtype="m8[s]")})):
        with pytest.raises(TypeError, match=rf"^`{name}` must be an array of numbers; got"):
            gf.LinearModel(**({"F": 1.0, "H": 1.0, "Q": 1.0, "R": 1.0} | kwargs))
    with pytest.raises(TypeError, match=r"^`mean` must be an array of numbers; got datetime64"):
        gf.Gaussian(times, np.eye(2))


@pytest.mark.parametrize("call", [lambda: gf.constant_velocity(10**400, 1.0, 1.0),
                                  lambda: gf.ConstantVelocity(q=-10**400),
                                  lambda: gf.Fuser(gf.ConstantVelocity(), {"gps": gf.Position()},
                                                   gf.Gaussian([0.0, 0.0], np.eye(2)), t0=10**400)])
def test_an_integer_beyond_float64_is_named(call):
    """float(10**400) raised OverflowError (a traceback and exit status 1 from a model file's dt), and
    np.isfinite of an int past 64 bits a TypeError naming nothing."""
    with pytest.raises(ValueError, match=r"must be a .*number; got an integer of 401 digits, beyond float64"):
        call()


def test_an_integer_of_more_digits_than_str_converts_is_counted():
    """Its digits were counted with str(), which refuses an int of over 4300 digits: the error named nothing
    (review R54)."""
    with pytest.raises(ValueError, match=r"^`dim` must be 1, 2 or 3; got an integer of 5001 digits\.$"):
        gf.ConstantVelocity(dim=10**5000)
    with pytest.raises(ValueError, match=r"^`n` must be a positive integer; got an integer of 5000 digits\.$"):
        integer("n", -(10**5000 - 1))


@pytest.mark.parametrize("F, error, message", [
    (np.array([[1, None], [0, 1]], dtype=object), ValueError, r"must be an array of numbers; got None at index \(0, 1\)"),
    (np.array([[True, 0], [0, 1]], dtype=object), TypeError, r"must be an array of numbers; got booleans"),
    (np.array([[1, "2"], [0, 1]], dtype=object), TypeError, r"must be an array of numbers; got the text '2' at index "
                                                            r"\(0, 1\)\.$"),
    (np.array([[1, 0], [b"0", 1]], dtype=object), TypeError, r"must be an array of numbers; got the text b'0' at index "
                                                             r"\(1, 0\)\.$"),
    (np.array([[1, 0], [0, 1 + 5j]], dtype=object), TypeError, r"must be real; got the complex value \(1\+5j\) at "
                                                               r"index \(1, 1\)\.$"),
    (np.array([[1, 0], [0, np.complex128(1)]], dtype=object), TypeError, r"must be real; got the complex value"),
    (np.array([[1, np.datetime64("2020-01-01")], [0, 1]], dtype=object), TypeError,
     r"must be an array of numbers; got the date or time 2020-01-01 at index \(0, 1\) \(dates and times are not"),
    (np.array([[1, 0], [datetime.timedelta(seconds=1), 1]], dtype=object), TypeError,
     r"must be an array of numbers; got the date or time 0:00:01 at index \(1, 0\)"),
])
def test_an_object_array_says_what_its_bad_entry_is(F, error, message):
    """None was "a non-finite (NaN or inf) value"; booleans in an object array were read as 1 and 0 (a list of
    them was refused); text was read as the number it spells, a date as a count of days, and a complex value lost
    its imaginary part with a ComplexWarning (audit GG3: a text column of a pandas table taken out by to_numpy is
    an object array)."""
    with pytest.raises(error, match=rf"^`F` {message}"):
        gf.LinearModel(F, np.eye(2), np.eye(2), np.eye(2))
    model, prior = gf.LinearModel(np.eye(2), np.eye(2), np.eye(2), np.eye(2)), gf.Gaussian([0.0, 0.0], np.eye(2))
    if F[0, 1] is None:  # a measurement of None is missing, as NaN
        assert np.isnan(gf.filter(model, prior, F).innovations[0, 1])
    else:
        with pytest.raises(error, match=rf"^`zs` {message}"):
            gf.filter(model, prior, F)


_CV = gf.constant_velocity(dt=0.5, q=0.2, r=1.0, dim=2)
_CV_PRIOR = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))


@pytest.mark.parametrize("call, message", [
    (lambda res: gf.imm_filter([_CV], _CV_PRIOR, [[1.0, 2.0]], [[1.0]], method=["ukf"]), r"^`method` must be one of"),
    (lambda res: gf.forecast(_CV, _CV_PRIOR, 2).interval(0.9, of=np.eye(2)), r"^`of` must be 'measurements' or"),
    (lambda res: gf.KalmanFilter(_CV, _CV_PRIOR).update([1.0, 2.0], gate=0.9, gate_by=np.eye(2)),
     r"^`gate_by` must be 'measurement' or 'component'"),
    (lambda res: diagnostics.DivergenceMonitor(check=np.array(["warn"])), r"^`check` must be 'warn', 'raise' or 'off'"),
    (lambda res: diagnostics.consistency(res, lags=0), r"^`lags` must be an integer in \[1, 59\]"),
])
def test_a_choice_given_as_an_array_or_a_list_is_named(call, message):
    """A list for `method` gave "unhashable type: 'list'", an array for `of` or `gate_by` NumPy's "truth value of
    an array is ambiguous", and lags=0 silently became the default 10 lags (audit Z)."""
    res = gf.filter(_CV, _CV_PRIOR, np.random.default_rng(0).standard_normal((60, 2)))
    with pytest.raises(ValueError, match=message):
        call(res)


def test_a_timedelta_is_not_an_integer():
    """Audit VV2: NumPy's timedelta64 is an integer type, and its count of its own units was taken for a size:
    continuous_white_noise(order=np.timedelta64(2)) gave a 3 x 3 Q, a dim of timedelta64(2) four states, and
    sample(np.timedelta64(2)) two draws. Each is refused as the argument's type."""
    td = np.timedelta64(2)
    with pytest.raises(TypeError, match=r"^`order` must be"):
        gf.continuous_white_noise(order=td, dt=1.0, q=1.0)
    with pytest.raises(TypeError, match=r"^`dim` must be an integer 1, 2 or 3; got np\.timedelta64\(2\)"):
        gf.ConstantVelocity(dim=td)
    with pytest.raises(TypeError, match=r"^`size` must be None or a non-negative integer"):
        gf.Gaussian(0.0, 1.0).sample(td)
    with pytest.raises(TypeError, match=r"^`k` must be a non-negative integer"):
        gf.LinearModel(np.ones((3, 1, 1)), 1.0, 1.0, 1.0).at(np.timedelta64(1))


@pytest.mark.parametrize("make", [lambda names: gf.LinearModel(1.0, 1.0, 1.0, 1.0, names=names),
                                  lambda names: gf.LinearSDE([[0.0]], [[1.0]], 1.0, names=names)])
def test_names_of_a_0d_array_are_refused_naming_them(make):
    """A 0-d array has __iter__, and NumPy's own "iteration over a 0-d array" named nothing (audit VV5); a str
    array's names were kept as NumPy's str_ (printed np.str_('a'))."""
    for bad in (np.array("a"), np.array(1.0)):
        with pytest.raises(TypeError, match=r"^`names` must be a sequence of 1 strings; got array\("):
            make(bad)
    names = gf.LinearModel(np.eye(2), [1.0, 0.0], np.eye(2), 1.0, names=np.array(["a", "b"])).names
    assert names == ("a", "b") and all(type(name) is str for name in names)
