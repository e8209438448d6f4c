"""gf.LinearModel: forms of input, time variation, immutability and validation."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

import gaussfuse as gf

F2 = np.array([[1.0, 1.0], [0.0, 1.0]])


def test_dimensions_and_convenient_forms():
    model = gf.LinearModel(F=F2, H=[1.0, 0.0], Q=np.eye(2), R=10.0, B=[0.5, 1.0])
    assert (model.n, model.m, model.p, model.steps) == (2, 1, 1, None)
    assert model.H.shape == (1, 2)  # a 1-D H is one row
    assert model.R.shape == (1, 1)  # a scalar R is 1 x 1
    assert model.B.shape == (2, 1)  # a 1-D B is one column
    assert repr(model) == "LinearModel(n=2, m=1, p=1)"
    assert gf.LinearModel(F=F2, H=np.eye(2), Q=np.eye(2), R=np.eye(2)).p == 0


def test_scalar_model():
    model = gf.LinearModel(F=0.9, H=2.0, Q=0.1, R=0.5)
    assert (model.n, model.m, model.p) == (1, 1, 0)
    for a in (model.F, model.H, model.Q, model.R):
        assert a.shape == (1, 1) and a.dtype == np.float64
    assert model.B is None


def test_time_varying_matrices_are_indexed_by_step():
    Fs = np.stack([F2, 2 * F2, 3 * F2])
    Rs = np.array([1.0, 2.0, 3.0]).reshape(3, 1, 1)
    model = gf.LinearModel(F=Fs, H=[1.0, 0.0], Q=np.eye(2), R=Rs)
    assert model.steps == 3
    assert repr(model) == "LinearModel(n=2, m=1, p=0, time-varying over 3 steps)"
    for k in range(3):
        F, H, Q, R, B = model.at(k)
        np.testing.assert_array_equal(F, Fs[k])
        np.testing.assert_array_equal(R, Rs[k])
        np.testing.assert_array_equal(H, [[1.0, 0.0]])
        np.testing.assert_array_equal(Q, np.eye(2))
        assert B is None


def test_time_varying_B_alone_makes_the_model_time_varying():
    Bs = np.arange(8.0).reshape(4, 2, 1)
    model = gf.LinearModel(F=F2, H=[1.0, 0.0], Q=np.eye(2), R=1.0, B=Bs)
    assert model.steps == 4 and model.p == 1
    np.testing.assert_array_equal(model.at(2)[4], Bs[2])


def test_covariances_are_symmetrised():
    Q = np.array([[1.0, 0.2 + 1e-14], [0.2, 1.0]])
    model = gf.LinearModel(F=F2, H=[1.0, 0.0], Q=Q, R=1.0)
    np.testing.assert_array_equal(model.Q, model.Q.T)


def test_model_is_immutable():
    F = F2.copy()
    model = gf.LinearModel(F=F, H=[1.0, 0.0], Q=np.eye(2), R=1.0, B=[1.0, 0.0])
    with pytest.raises(AttributeError, match=r"^LinearModel is immutable; build a new one instead\.$"):
        model.F = np.eye(2)
    with pytest.raises(AttributeError, match="immutable"):
        model.other = 1
    for name in ("F", "H", "Q", "R", "B"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(model, name)[0, 0] = 5.0
    F[0, 0] = 7.0  # the caller's array is not aliased
    assert model.F[0, 0] == 1.0
    with pytest.raises(AttributeError, match=r"^LinearModel is immutable; build a new one instead\.$"):
        del model.F  # (it went, and the model could no longer filter, print or pickle: audit GG1)
    assert model.F[0, 0] == 1.0 and repr(model) == "LinearModel(n=2, m=1, p=1)"


def test_the_matrices_at_a_step_that_is_not_one_of_the_model_are_refused_naming_k():
    """Audit GG5: a time-varying model's at(-1) gave its last step, at(T) NumPy's IndexError, at(None) F with two
    axes more; a time-invariant model's at("x") gave its matrices."""
    Fs = np.stack([F2, 2 * F2, 3 * F2])
    varying = gf.LinearModel(F=Fs, H=[1.0, 0.0], Q=np.eye(2), R=1.0)
    fixed = gf.LinearModel(F=F2, H=[1.0, 0.0], Q=np.eye(2), R=1.0)
    np.testing.assert_array_equal(varying.at(np.int64(2))[0], Fs[2])
    np.testing.assert_array_equal(fixed.at(10**9)[0], F2)  # the same at every step
    np.testing.assert_array_equal(fixed.at(np.uint64(2**64 - 1))[0], F2)  # (k + 1 wrapped: review R43)
    with pytest.raises(ValueError, match=r"^`k` must be a step of the model, 0 to 2 \(it is time-varying over 3 steps\); "
                                         r"got 3\.$"):
        varying.at(3)
    with pytest.raises(ValueError, match=r"^`k` must be a non-negative integer; got -1\.$"):
        varying.at(-1)
    for model in (varying, fixed):
        for k in (None, 1.0, "x", True):
            with pytest.raises(TypeError, match=rf"^`k` must be a non-negative integer; got {k!r:.4}"):
                model.at(k)


# ---------------------------------------------------------------------------
# Validation: the message names the argument, the expected and the received shape
# ---------------------------------------------------------------------------

GOOD = {"F": F2, "H": [1.0, 0.0], "Q": np.eye(2), "R": 1.0}


INVALID = [
    ({"F": np.ones((2, 3))}, ValueError, r"^`F` must be square, of shape \(n, n\) or \(T, n, n\); got shape \(2, 3\)\.$"),
    ({"F": np.ones((4, 2, 3))}, ValueError, r"^`F` must be square, of shape \(n, n\) or \(T, n, n\); got shape \(4, 2, 3\)\.$"),
    ({"F": [1.0, 2.0, 3.0]}, ValueError, r"^`F` must have shape \(n, n\) or, time-varying, \(T, n, n\); got shape \(3,\)\.$"),
    ({"F": np.ones((1, 1, 2, 2))}, ValueError, r"^`F` must have shape \(n, n\) or, time-varying, \(T, n, n\); got shape \(1, 1, 2, 2\)\.$"),
    ({"F": np.zeros((0, 0))}, ValueError, r"^`F` must have shape \(n, n\) or, time-varying, \(T, n, n\); got shape \(0, 0\)\.$"),
    ({"F": [[1.0, np.nan], [0.0, 1.0]]}, ValueError, r"^`F` must be finite; got a non-finite \(NaN or inf\) value at index \(0, 1\)\.$"),
    ({"F": "eye"}, TypeError, r"^`F` must be an array of numbers; got str\.$"),
    ({"H": [1.0, 0.0, 0.0]}, ValueError, r"^`H` must have shape \(m, 2\) or, time-varying, \(T, m, 2\), because `F` is 2 × 2 \(2 state components\); got shape \(3,\)\.$"),
    ({"H": np.ones((2, 3))}, ValueError, r"^`H` must have shape \(m, 2\) or, time-varying, \(T, m, 2\), because `F` is 2 × 2 \(2 state components\); got shape \(2, 3\)\.$"),
    ({"H": None}, TypeError, r"^`H` must be an array of numbers; got NoneType\.$"),
    ({"Q": np.eye(3)}, ValueError, r"^`Q` must have shape \(2, 2\) or, time-varying, \(T, 2, 2\), because `F` is 2 × 2 \(2 state components\); got shape \(3, 3\)\.$"),
    ({"Q": 1.0}, ValueError, r"^`Q` must have shape \(2, 2\) or, time-varying, \(T, 2, 2\), because `F` is 2 × 2 \(2 state components\); got shape \(\)\. A number is a 1 × 1 matrix only; "
     r"for 1 times the identity give 1 \* np\.eye\(2\)\.$"),
    ({"Q": [[1.0, 0.5], [0.0, 1.0]]}, ValueError, r"^`Q` must be symmetric; its entries \[0, 1\] and \[1, 0\] differ, 0\.5 and 0\.0\.$"),
    ({"Q": -np.eye(2)}, ValueError, r"^`Q` must be positive semi-definite; its smallest eigenvalue is -1\.$"),
    ({"Q": np.stack([np.eye(2), [[1.0, 2.0], [0.0, 1.0]]])}, ValueError, r"^`Q` must be symmetric; its entries \[0, 1\] and \[1, 0\] differ, 2\.0 and 0\.0 at time step 1\.$"),
    ({"Q": np.stack([np.eye(2), np.eye(2), -np.eye(2)])}, ValueError, r"^`Q` must be positive semi-definite; its smallest eigenvalue is -1 at time step 2\.$"),
    ({"R": np.eye(2)}, ValueError, r"^`R` must have shape \(1, 1\) or, time-varying, \(T, 1, 1\), because `H` has 1 row \(1 measurement component\); got shape \(2, 2\)\.$"),
    ({"R": -1.0}, ValueError, r"^`R` must be positive semi-definite; its smallest eigenvalue is -1\.$"),
    ({"R": np.inf}, ValueError, r"^`R` must be finite; got a non-finite \(NaN or inf\) value at index \(\)\.$"),
    ({"B": np.ones((3, 1))}, ValueError, r"^`B` must have shape \(2, p\) or, time-varying, \(T, 2, p\), because `F` is 2 × 2 \(2 state components\); got shape \(3, 1\)\.$"),
    ({"B": [1.0, 2.0, 3.0]}, ValueError, r"^`B` must have shape \(2, p\) or, time-varying, \(T, 2, p\), because `F` is 2 × 2 \(2 state components\); got shape \(3,\)\.$"),
    ({"B": "B"}, TypeError, r"^`B` must be an array of numbers; got str\.$"),
    # H with two rows and a scalar R: R is what is wrong, because of H (it was reported as a wrong R alone)
    ({"H": np.eye(2), "R": 1.0}, ValueError,
     r"^`R` must have shape \(2, 2\) or, time-varying, \(T, 2, 2\), because `H` has 2 rows \(2 measurement "
     r"components\); got shape \(\)\. A number is a 1 × 1 matrix only; "
     r"for 1 times the identity give 1 \* np\.eye\(2\)\.$"),
    ({"H": np.eye(2), "R": np.eye(3)}, ValueError, r"^`R` must have shape \(2, 2\).*because `H` has 2 rows"),
    ({"F": np.stack([F2] * 3), "H": np.ones((4, 1, 2))}, ValueError,
     r"^time-varying matrices must all have the same number of steps; `F` has 3, `H` has 4\.$"),
    ({"Q": np.stack([np.eye(2)] * 2), "B": np.ones((5, 2, 1))}, ValueError,
     r"^time-varying matrices must all have the same number of steps; `Q` has 2, `B` has 5\.$"),
]


@pytest.mark.parametrize(
    ("changes", "error", "match"), INVALID,
    ids=[f"{i}-{'+'.join(changes)}" for i, (changes, _, _) in enumerate(INVALID)],
)
def test_invalid_model(changes, error, match):
    with pytest.raises(error, match=match):
        gf.LinearModel(**(GOOD | changes))


def test_psd_singular_noise_is_allowed():
    model = gf.LinearModel(F=F2, H=[1.0, 0.0], Q=np.zeros((2, 2)), R=0.0)
    np.testing.assert_array_equal(model.Q, np.zeros((2, 2)))


def test_pickles_and_copies_as_an_equal_immutable_model():
    model = gf.LinearModel(F=np.stack([F2, 2 * F2]), H=[1.0, 0.0], Q=np.eye(2), R=1.0, B=[1.0, 0.0])
    copies = [pickle.loads(pickle.dumps(model, p)) for p in range(2, pickle.HIGHEST_PROTOCOL + 1)]
    for back in copies + [copy.copy(model), copy.deepcopy(model)]:
        assert type(back) is gf.LinearModel and back.steps == 2
        for name in ("F", "H", "Q", "R", "B"):
            np.testing.assert_array_equal(getattr(back, name), getattr(model, name))
            assert not getattr(back, name).flags.writeable
        with pytest.raises(AttributeError, match="immutable"):
            back.F = np.eye(2)
