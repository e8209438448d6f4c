"""NonlinearModel: construction, validation and checked evaluation."""

import copy
import pickle

import numpy as np
import pytest

import gaussfuse as gf
from gaussfuse.errors import ModelFunctionError


def f(x):
    return x


def h(x):
    return x[:1]


def test_dimensions_and_time_varying_noise():
    model = gf.NonlinearModel(f, h, np.stack([np.eye(2)] * 5), 0.5)
    assert (model.n, model.m, model.steps) == (2, 1, 5)
    Q, R = model.noise(3)
    np.testing.assert_array_equal(Q, np.eye(2))
    np.testing.assert_array_equal(R, [[0.5]])
    assert repr(model) == "NonlinearModel(n=2, m=1, vectorized=False)"


def test_immutable():
    model = gf.NonlinearModel(f, h, np.eye(2), 1.0)
    with pytest.raises(AttributeError, match="immutable"):
        model.Q = np.eye(2)
    with pytest.raises(ValueError, match="read-only"):
        model.Q[0, 0] = 2.0
    with pytest.raises(AttributeError, match=r"^NonlinearModel is immutable; build a new one instead\.$"):
        del model.Q  # (it went: audit GG1)
    np.testing.assert_array_equal(model.Q, np.eye(2))


def test_the_noise_at_a_step_that_is_not_one_of_the_model_is_refused_naming_k():
    """Audit GG5 (as LinearModel.at): noise(-1) read a time-varying Q from its end, noise(T) raised IndexError."""
    model = gf.NonlinearModel(f, h, np.stack([np.eye(2), 2 * np.eye(2)]), 1.0)
    np.testing.assert_array_equal(model.noise(1)[0], 2 * np.eye(2))
    with pytest.raises(ValueError, match=r"^`k` must be a step of the model, 0 to 1 \(it is time-varying over 2 steps\); "
                                         r"got 2\.$"):
        model.noise(2)
    with pytest.raises(ValueError, match="non-negative integer; got -1"):
        model.noise(-1)
    with pytest.raises(TypeError, match="non-negative integer; got 0.0"):
        model.noise(0.0)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(f=1), TypeError, r"`f` must be callable; got int"),
        (dict(h=None), TypeError, r"`h` must be callable; got NoneType"),
        (dict(f_jacobian="J"), TypeError, r"`f_jacobian` must be callable; got str"),
        (dict(Q=np.ones((2, 3))), ValueError, r"`Q` must be square, of shape \(n, n\) or \(T, n, n\); got shape \(2, 3\)"),
        (dict(R=np.ones((1, 2))), ValueError, r"`R` must be square, of shape \(m, m\) or \(T, m, m\); got shape \(1, 2\)"),
        (dict(Q=[[1.0, 2.0], [2.0, 1.0]]), ValueError, r"`Q` must be positive semi-definite; its smallest eigenvalue is -1"),
        (dict(R=[[1.0, 0.5], [0.0, 1.0]]), ValueError, r"`R` must be symmetric"),
        (dict(Q=np.stack([np.eye(2)] * 3), R=np.ones((4, 1, 1))), ValueError,
         r"same number of steps; `Q` has 3, `R` has 4"),
        (dict(vectorized="yes"), TypeError, r"`vectorized` must be True or False; got 'yes'"),
        (dict(state_angles=[2]), ValueError,
         r"`state_angles` must hold component indices in \[-2, 2\) \(negative ones count from the end\) or be a boolean mask of length 2; got \[2\]"),
        (dict(measurement_angles=[0.5]), ValueError, r"`measurement_angles` must hold component indices in \[-1, 1\)"),
    ],
)
def test_validation(kwargs, error, match):
    args = dict(f=f, h=h, Q=np.eye(2), R=1.0) | kwargs
    with pytest.raises(error, match=match):
        gf.NonlinearModel(**args)


def test_checked_evaluation():
    model = gf.NonlinearModel(lambda x: 2 * x, lambda x: float(x[0]), np.eye(2), 1.0)
    np.testing.assert_array_equal(model.transition(np.array([1.0, 2.0])), [2.0, 4.0])
    np.testing.assert_array_equal(model.measurement(np.ones((3, 2))), np.ones((3, 1)))  # a scalar return is (1,)
    bad = gf.NonlinearModel(lambda x: "text", h, np.eye(2), 1.0)
    with pytest.raises(ModelFunctionError, match=r"`f` must return an array of real numbers; got str 'text'"):
        bad.transition(np.zeros(2))
    raising = gf.NonlinearModel(lambda x, u: x + u, h, np.eye(2), 1.0)
    with pytest.raises(ModelFunctionError, match=r"`f` raised TypeError on an input of shape \(2,\)"):
        raising.transition(np.zeros(2))  # called without the control it requires


@pytest.mark.parametrize("method, engine", [("ekf", "python"), ("ukf", "python"), ("ukf", "numba")])
def test_a_transition_of_a_control_without_us_says_so(method, engine):
    """f(x, u) called as f(x) said only "missing 1 required positional argument: 'u'" (audit Y3)."""
    model = gf.NonlinearModel(lambda x, u: x + u, lambda x: x[:1], np.eye(2), 1.0)
    with pytest.raises(ModelFunctionError, match=r"'u' \(without `us`, f is called as f\(x\); f\(x, u\) needs `us`"):
        gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.0], method=method, engine=engine)
    three = gf.NonlinearModel(lambda x, u, extra: x + u, lambda x: x[:1], np.eye(2), 1.0)  # with `us`, no such hint
    with pytest.raises(ModelFunctionError, match=r"required positional argument: 'extra'$"):
        gf.filter(three, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.0], us=np.ones((2, 1)), method=method,
                  engine=engine)

    def helper(a, b):
        return a

    inside = gf.NonlinearModel(lambda x: helper(x), lambda x: x[:1], np.eye(2), 1.0)  # f takes x: not that (R10)
    with pytest.raises(ModelFunctionError, match=r"helper\(\) missing 1 required positional argument: 'b'$"):
        gf.filter(inside, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.0], method=method, engine=engine)


def test_pickles_and_copies_as_an_equal_immutable_model():
    model = gf.NonlinearModel(f, h, np.stack([np.eye(2)] * 3), 0.5, f_jacobian=None, h_jacobian=h,
                              vectorized=True, state_angles=[1], measurement_angles=(0,))
    for back in (pickle.loads(pickle.dumps(model)), copy.copy(model), copy.deepcopy(model)):
        assert (back.f, back.h, back.f_jacobian, back.h_jacobian) == (f, h, None, h)
        assert back.vectorized is True
        for name in ("Q", "R", "state_angles", "measurement_angles"):
            np.testing.assert_array_equal(getattr(back, name), getattr(model, name))
            assert not getattr(back, name).flags.writeable
        with pytest.raises(AttributeError, match="immutable"):
            back.Q = np.eye(2)


def test_a_lambda_model_copies_but_does_not_pickle_and_says_why():
    model = gf.NonlinearModel(lambda x: 2 * x, h, np.eye(2), 1.0)
    assert copy.deepcopy(model).f is model.f  # functions are copied by reference
    with pytest.raises((pickle.PicklingError, AttributeError)) as info:  # pickle's own error
        pickle.dumps(model)
    assert "lambda" in str(info.value) and "immutable" not in str(info.value)


@pytest.mark.parametrize(
    "angles, mask",
    [([True, False, False], [1, 0, 0]), (np.array([False, True, True]), [0, 1, 1]), ([1], [0, 1, 0]),
     ((0, -1), [1, 0, 1]), ([], [0, 0, 0]), (None, [0, 0, 0]), (np.array([2]), [0, 0, 1]),
     ([np.True_, np.False_, np.True_], [1, 0, 1])],
)
def test_angles_are_a_boolean_mask_or_indices(angles, mask):
    """[True, False, False] marks component 0 only: a mask, not the indices 1 and 0."""
    model = gf.NonlinearModel(f, lambda x: x.copy(), np.eye(3), np.eye(3), state_angles=angles,
                              measurement_angles=angles)
    np.testing.assert_array_equal(model.state_angles, np.array(mask, dtype=bool))
    np.testing.assert_array_equal(model.measurement_angles, np.array(mask, dtype=bool))
    # A model's own mask is accepted back.
    again = gf.NonlinearModel(f, lambda x: x.copy(), np.eye(3), np.eye(3), state_angles=model.state_angles)
    np.testing.assert_array_equal(again.state_angles, model.state_angles)


@pytest.mark.parametrize(
    "angles, match",
    [([True, False], r"`state_angles` as a boolean mask must have length 3, one entry per component; got length 2"),
     ([True, 2], r"`state_angles` must be a boolean mask of length 3 or a sequence of component indices, "
                 r"not a mix of booleans and numbers; got \[True, 2\]"),
     ([1.0], r"`state_angles` must hold component indices in \[-3, 3\) \(negative ones count from the end\) or be a boolean mask of length 3; got \[1.0\]"),
     ([3], r"`state_angles` must hold component indices in \[-3, 3\)")],
)
def test_ambiguous_angles_are_refused(angles, match):
    with pytest.raises(ValueError, match=match):
        gf.NonlinearModel(f, h, np.eye(3), 1.0, state_angles=angles)


@pytest.mark.parametrize(
    "out, what",
    [(np.array([1.0 + 0.0j]), "complex"), (np.array([True]), "boolean"), (True, "boolean"), (1j, "complex"),
     (np.array(["2020-01-01"], dtype="datetime64[D]"), "datetime64")],
)
def test_complex_or_boolean_outputs_are_refused(out, what):
    """Not cast: a complex output would lose its imaginary part, a boolean become 0.0 or 1.0."""
    model = gf.NonlinearModel(f, lambda x: out, np.eye(2), 1.0)
    with pytest.raises(ModelFunctionError,
                       match=rf"`h` must return an array of real numbers; got {what} values for an input of shape \(2,\)"):
        model.measurement(np.zeros(2))
    for method in ("ekf", "ukf"):
        with pytest.raises(ModelFunctionError, match=rf"^at step 0: `h` must return an array of real numbers; got {what}"):
            gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0], method=method)
    model = gf.NonlinearModel(lambda x: np.where(x > 0, x, x + 0j), h, np.eye(2), 1.0)
    with pytest.raises(ModelFunctionError, match=r"`f` must return an array of real numbers; got complex values"):
        model.transition(np.zeros(2))


def test_wrong_output_size_names_the_noise_that_fixes_it():
    """h returning 2 values with a scalar R: the message names both h and R (f and Q likewise)."""
    model = gf.NonlinearModel(lambda x: x[:1], lambda x: x.copy(), np.eye(2), 1.0,
                              h_jacobian=lambda x: np.eye(2))
    with pytest.raises(ModelFunctionError, match=r"^`h` must return shape \(1,\) for an input of shape \(2,\), "
                                                 r"because `R` is 1 × 1; got shape \(2,\)\.$"):
        model.measurement(np.zeros(2))
    with pytest.raises(ModelFunctionError, match=r"^`f` must return shape \(2,\) for an input of shape \(2,\), "
                                                 r"because `Q` is 2 × 2; got shape \(1,\)\.$"):
        model.transition(np.zeros(2))
    fine = gf.NonlinearModel(f, h, np.eye(2), 1.0, h_jacobian=lambda x: np.eye(2))
    with pytest.raises(ModelFunctionError, match=r"^at step 0: `h_jacobian` must return shape \(1, 2\) for an input of "
                                                 r"shape \(2,\), because `R` is 1 × 1 and `Q` is 2 × 2; got shape \(2, 2\)"):
        gf.filter(fine, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0], method="ekf")


@pytest.mark.parametrize("Q, R, match", [
    ([1.0, 2.0], 1.0, r"^`Q` must have shape \(n, n\) or, time-varying, \(T, n, n\); got shape \(2,\)"),
    (np.eye(2), [1.0, 2.0], r"^`R` must have shape \(m, m\) or, time-varying, \(T, m, m\); got shape \(2,\)"),
    (np.zeros((0, 0)), 1.0, r"^`Q` must have shape \(n, n\)"),
])
def test_a_noise_of_the_wrong_shape_is_named_with_its_own_shape(Q, R, match):
    """Audit TT3: Q's and R's shape errors said (m, n), the default of a measurement matrix."""
    with pytest.raises(ValueError, match=match):
        gf.NonlinearModel(f, h, Q, R)
