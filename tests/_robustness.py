"""Problems on which the covariance form of the Kalman filter loses its accuracy, and how to measure it.

Each problem is a time-invariant linear model, a prior and measurements
simulated from the model (seeded), small enough for the 50-digit reference
of :mod:`_mp_oracle`. :func:`errors` measures a float64 result against that
reference: the largest relative error of a variance, the largest error of
a mean in standard deviations, and the steps whose covariance has a
negative eigenvalue (computed exactly, with 50 digits).

Used by ``tests/inference/test_forms.py`` and by
``benchmarks/robustness.py``, which prints the table of every problem, form
and engine.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from _mp_oracle import smallest_eigenvalue

__all__ = ["Problem", "PROBLEMS", "errors", "Errors"]


class Problem(NamedTuple):
    name: str
    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    m0: np.ndarray
    P0: np.ndarray
    zs: np.ndarray


def _simulate(F, H, Q, R, x0, T, rng) -> np.ndarray:
    """Measurements (T, m) of the model from the state x0 one step before the first."""
    x, out = np.asarray(x0, float), []
    for _ in range(T):
        x = F @ x + _draw(Q, rng)
        out.append(H @ x + _draw(R, rng))
    return np.array(out)


def _draw(cov, rng) -> np.ndarray:
    vals, vecs = np.linalg.eigh(cov)
    return vecs @ (np.sqrt(np.clip(vals, 0.0, None)) * rng.standard_normal(len(vals)))


def _cv(dt: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A constant-velocity transition (position, velocity) and its white-acceleration noise shape."""
    F = np.array([[1.0, dt], [0.0, 1.0]])
    return F, np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])


def huge_prior_precise_sensor(T: int = 40) -> Problem:
    """The issue's problem: position and velocity, P0 = 1e12·I, R = 1e-6, Q = 0."""
    F, _ = _cv()
    H, Q, R = np.array([[1.0, 0.0]]), np.zeros((2, 2)), np.array([[1e-6]])
    zs = _simulate(F, H, Q, R, [2.0, 1.0], T, np.random.default_rng(1))
    return Problem("P0 = 1e12 I, R = 1e-6, Q = 0 (1-D position and velocity)", F, H, Q, R, np.zeros(2),
                   1e12 * np.eye(2), zs)


def huge_prior_precise_sensors_2d(T: int = 40) -> Problem:
    """Positions and velocities in the plane, both positions measured: P0 = 1e12·I, R = 1e-6·I, small Q."""
    F1, W = _cv()
    F = np.kron(np.eye(2), F1)
    Q = np.kron(np.eye(2), 1e-4 * W)
    H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    R = 1e-6 * np.eye(2)
    zs = _simulate(F, H, Q, R, [3.0, 1.0, -2.0, 0.5], T, np.random.default_rng(2))
    return Problem("P0 = 1e12 I, R = 1e-6 I, 2-D", F, H, Q, R, np.zeros(4), 1e12 * np.eye(4), zs)


def rank_deficient_q(T: int = 60) -> Problem:
    """Position and velocity driven by one acceleration: Q = g gᵀ of rank 1; a precise sensor."""
    F, _ = _cv()
    g = np.array([[0.5], [1.0]])
    Q, H, R = 1e-2 * g @ g.T, np.array([[1.0, 0.0]]), np.array([[1e-8]])
    zs = _simulate(F, H, Q, R, [0.0, 1.0], T, np.random.default_rng(3))
    return Problem("rank-1 Q, R = 1e-8", F, H, Q, R, np.zeros(2), 1e6 * np.eye(2), zs)


def mixed_scales(T: int = 60) -> Problem:
    """Two coupled states on scales 1e-6 and 1e6 at once, measured separately and together."""
    F = np.array([[0.99, 1e-13], [1e11, 0.98]])
    Q = np.diag([1e-14, 1e10])
    H = np.array([[1.0, 0.0], [0.0, 1.0], [1e6, 1e-6]])
    R = np.diag([1e-16, 1e8, 1e-4])
    zs = _simulate(F, H, Q, R, [1e-6, 1e6], T, np.random.default_rng(4))
    return Problem("states on scales 1e-6 and 1e6", F, H, Q, R, np.zeros(2), np.diag([1e-8, 1e16]), zs)


def nearly_unobservable(T: int = 60) -> Problem:
    """A constant bias seen only through a 1e-7 coupling, next to a random walk measured precisely."""
    F, Q = np.eye(2), np.diag([1e-2, 0.0])
    H, R = np.array([[1.0, 1e-7]]), np.array([[1e-6]])
    zs = _simulate(F, H, Q, R, [0.0, 3.0], T, np.random.default_rng(5))
    return Problem("a nearly unobservable bias (coupling 1e-7)", F, H, Q, R, np.zeros(2), np.diag([1.0, 1e6]), zs)


PROBLEMS = (huge_prior_precise_sensor, huge_prior_precise_sensors_2d, rank_deficient_q, mixed_scales,
            nearly_unobservable)


class Errors(NamedTuple):
    variance: float        # max |P_ii - P*_ii| / P*_ii over steps and components
    mean: float            # max |m_i - m*_i| / sqrt(P*_ii)
    negative_steps: int    # steps whose covariance has an eigenvalue below 0 (exactly)
    symmetric: bool        # every covariance exactly symmetric


def errors(means: np.ndarray, covs: np.ndarray, ref_means: np.ndarray, ref_covs: np.ndarray) -> Errors:
    """How far a float64 result is from the 50-digit reference (see the module notes)."""
    var = np.diagonal(ref_covs, axis1=1, axis2=2)
    got = np.diagonal(covs, axis1=1, axis2=2)
    negative = sum(smallest_eigenvalue(P) < 0.0 for P in covs)
    return Errors(float(np.max(np.abs(got - var) / var)), float(np.max(np.abs(means - ref_means) / np.sqrt(var))),
                  int(negative), bool(np.array_equal(covs, np.swapaxes(covs, 1, 2))))
