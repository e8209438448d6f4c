"""NonlinearModel: construction, validation and checked evaluation."""

import copy
import pickle

import numpy as np
import pytest

import gaussfuse as gf
from gaussfuse.models.nonlinear import ModelFunctionError


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
        (dict(state_angles=[2]), ValueError, r"`state_angles` must hold component indices in \[0, 2\); got \[2\]"),
        (dict(measurement_angles=[0.5]), ValueError, r"`measurement_angles` must hold component indices in \[0, 1\)"),
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
