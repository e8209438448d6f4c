"""Motion models: constant velocity and constant acceleration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.linalg import expm

import gaussfuse as gf

DIMS = [1, 2, 3]
STEPS = [0.1, 0.5, 1.0, 2.5]


def cv_axis(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    F = np.array([[1.0, dt], [0.0, 1.0]])
    Q = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    return F, Q


def ca_axis(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    F = np.array([[1.0, dt, dt**2 / 2], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    Q = q * np.array([
        [dt**5 / 20, dt**4 / 8, dt**3 / 6],
        [dt**4 / 8, dt**3 / 3, dt**2 / 2],
        [dt**3 / 6, dt**2 / 2, dt],
    ])
    return F, Q


def axis_block(M: np.ndarray, order: int, dim: int, a: int, b: int) -> np.ndarray:
    """The (order+1) x (order+1) block of M coupling axis a with axis b.

    The state lists all positions, then all velocities, ...: component
    k * dim + a is the k-th derivative along axis a.
    """
    ia = [k * dim + a for k in range(order + 1)]
    ib = [k * dim + b for k in range(order + 1)]
    return M[np.ix_(ia, ib)]


CASES = [(gf.constant_velocity, 1, cv_axis), (gf.constant_acceleration, 2, ca_axis)]
CASE_IDS = ["cv", "ca"]


@pytest.mark.parametrize(("make", "order", "closed"), CASES, ids=CASE_IDS)
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("dt", STEPS)
def test_matrices_match_closed_forms(make, order, closed, dim, dt):
    q, r = 0.7, 0.3
    model = make(dt=dt, q=q, r=r, dim=dim)
    n = (order + 1) * dim
    assert (model.n, model.m, model.p, model.steps) == (n, dim, 0, None)
    F1, Q1 = closed(dt, q)
    for a in range(dim):
        for b in range(dim):
            if a == b:
                np.testing.assert_allclose(axis_block(model.F, order, dim, a, a), F1, rtol=1e-14, atol=0)
                np.testing.assert_allclose(axis_block(model.Q, order, dim, a, a), Q1, rtol=1e-14, atol=0)
            else:  # the axes are independent
                np.testing.assert_array_equal(axis_block(model.F, order, dim, a, b), 0.0)
                np.testing.assert_array_equal(axis_block(model.Q, order, dim, a, b), 0.0)
    # The measurement is the positions, the first `dim` components.
    np.testing.assert_array_equal(model.H, np.hstack([np.eye(dim), np.zeros((dim, order * dim))]))
    np.testing.assert_array_equal(model.R, r * np.eye(dim))


def _continuous(order: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Drift A and noise gain L of the continuous-time integrated white-noise model."""
    A1 = np.diag(np.ones(order), k=1)  # d/dt of each derivative is the next one
    L1 = np.zeros((order + 1, 1))
    L1[-1, 0] = 1.0  # white noise drives the highest derivative
    return np.kron(A1, np.eye(dim)), np.kron(L1, np.eye(dim))


@pytest.mark.parametrize(("make", "order"), [(gf.constant_velocity, 1), (gf.constant_acceleration, 2)], ids=CASE_IDS)
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("dt", [0.1, 1.0, 2.5])
def test_discretisation_matches_numerical_integration(make, order, dim, dt):
    q = 1.3
    model = make(dt=dt, q=q, r=1.0, dim=dim)
    A, L = _continuous(order, dim)
    np.testing.assert_allclose(model.F, expm(A * dt), rtol=1e-12, atol=1e-14)

    def integrand(s):
        E = expm(A * s)
        return E @ L @ L.T @ E.T

    Q, err = quad_vec(integrand, 0.0, dt, epsabs=1e-14, epsrel=1e-13)
    assert err < 1e-11
    np.testing.assert_allclose(model.Q, q * Q, rtol=0, atol=1e-10)
    # ... and not trivially: Q is not small compared with the tolerance.
    assert np.max(np.abs(model.Q)) > 1e-4


def test_zero_process_noise_is_allowed():
    model = gf.constant_velocity(dt=1.0, q=0.0, r=1.0, dim=2)
    np.testing.assert_array_equal(model.Q, np.zeros((4, 4)))


def test_default_dim_is_one_and_numpy_integers_work():
    assert gf.constant_velocity(dt=1.0, q=1.0, r=1.0).n == 2
    assert gf.constant_acceleration(dt=1.0, q=1.0, r=1.0, dim=np.int64(2)).n == 6


@pytest.mark.parametrize("make", [gf.constant_velocity, gf.constant_acceleration], ids=CASE_IDS)
@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"dt": 0.0}, ValueError, r"^`dt` must be positive; got 0\.0\.$"),
        ({"dt": -0.1}, ValueError, r"^`dt` must be positive; got -0\.1\.$"),
        ({"dt": np.nan}, ValueError, r"^`dt` must be positive; got nan\.$"),
        ({"dt": np.inf}, ValueError, r"^`dt` must be positive; got inf\.$"),
        ({"dt": "fast"}, TypeError, r"^`dt` must be a number; got 'fast'\.$"),
        ({"dt": None}, TypeError, r"^`dt` must be a number; got None\.$"),
        ({"q": -1.0}, ValueError, r"^`q` must be non-negative; got -1\.0\.$"),
        ({"q": [1.0, 2.0]}, TypeError, r"^`q` must be a number; got \[1\.0, 2\.0\]\.$"),
        ({"r": 0.0}, ValueError, r"^`r` must be positive; got 0\.0\.$"),
        ({"r": -2.0}, ValueError, r"^`r` must be positive; got -2\.0\.$"),
        ({"dim": 0}, ValueError, r"^`dim` must be 1, 2 or 3; got 0\.$"),
        ({"dim": 4}, ValueError, r"^`dim` must be 1, 2 or 3; got 4\.$"),
        ({"dim": 2.0}, ValueError, r"^`dim` must be 1, 2 or 3; got 2\.0\.$"),
        ({"dim": "2"}, ValueError, r"^`dim` must be 1, 2 or 3; got '2'\.$"),
        ({"dim": True}, ValueError, r"^`dim` must be 1, 2 or 3; got True\.$"),
    ],
)
def test_invalid_arguments(make, kwargs, error, match):
    with pytest.raises(error, match=match):
        make(**({"dt": 0.1, "q": 1.0, "r": 1.0, "dim": 2} | kwargs))
