"""The steady state: the Riccati equation's solution, and the steady-state filter."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

import _oracle
import gaussfuse as gf


def _riccati_limit(F, H, Q, R, steps=20000):
    """The predicted covariance after iterating the Riccati map from the identity (written here, with solves)."""
    P = np.eye(F.shape[0])
    for _ in range(steps):
        S = H @ P @ H.T + R
        P = F @ (P - P @ H.T @ np.linalg.solve(S, H @ P)) @ F.T + Q
        P = 0.5 * (P + P.T)
    return P


def test_the_scalar_random_walk_is_the_golden_ratio():
    """F = H = Q = R = 1: p = p·1/(p + 1) + 1 gives p² = p + 1."""
    ss = gf.steady_state(gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0))
    phi = (1 + np.sqrt(5)) / 2
    assert ss.predicted_cov[0, 0] == pytest.approx(phi, rel=1e-14)
    assert ss.cov[0, 0] == pytest.approx(phi - 1, rel=1e-14)
    assert ss.gain[0, 0] == pytest.approx(phi / (phi + 1), rel=1e-14)
    assert ss.innovation_cov[0, 0] == pytest.approx(phi + 1, rel=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_steady_state_is_the_limit_of_the_recursion(seed):
    rng = np.random.default_rng(seed)
    n, m = 4, 2
    F = _oracle.random_transition(rng, n, radius=0.95)
    H, Q, R = rng.normal(size=(m, n)), _oracle.random_spd(rng, n), _oracle.random_spd(rng, m)
    ss = gf.steady_state(gf.LinearModel(F, H, Q, R))
    P = _riccati_limit(F, H, Q, R)
    np.testing.assert_allclose(ss.predicted_cov, P, rtol=1e-9, atol=1e-12)
    S = H @ P @ H.T + R
    np.testing.assert_allclose(ss.gain, P @ H.T @ np.linalg.inv(S), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ss.cov, P - P @ H.T @ np.linalg.solve(S, H @ P), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("scale", [1e-150, 1e-36, 1e-24, 1e32, 1e150])
def test_scaling_q_and_r_together_scales_the_covariances_and_keeps_the_gain(scale):
    """Q and R times c: the same gain, covariances times c (SciPy's solver alone returned zeros at 1e-100 and
    refused at 1e32); and filter(steady=True) at that scale equals the full filter."""
    F, H, Q, R = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]]), np.diag([0.1, 0.2]), np.array([[0.5]])
    ref = gf.steady_state(gf.LinearModel(F, H, Q, R))
    model = gf.LinearModel(F, H, scale * Q, scale * R)
    ss = gf.steady_state(model)
    np.testing.assert_allclose(ss.gain, ref.gain, rtol=1e-13)
    for name in ("predicted_cov", "cov", "innovation_cov"):
        np.testing.assert_allclose(getattr(ss, name) / scale, getattr(ref, name), rtol=1e-13, err_msg=name)
    prior = gf.Gaussian([0.0, 0.0], scale * np.eye(2))
    zs = np.sqrt(scale) * np.random.default_rng(0).normal(size=300).cumsum()
    steady, full = (gf.filter(model, prior, zs, steady=s, check="off", engine="python") for s in (True, False))
    np.testing.assert_allclose(steady.covs / scale, full.covs / scale, rtol=0, atol=1e-9)
    np.testing.assert_allclose(steady.means, full.means, rtol=0, atol=1e-9 * np.abs(full.means).max())


def _joseph_limit(F, H, Q, R, steps=5000):
    """The predicted covariance as the limit of the Riccati map in Joseph form (written here), from Q: until a
    step changes it by round-off."""
    P = Q.copy()
    for _ in range(steps):
        K = np.linalg.solve(H @ P @ H.T + R, H @ P).T
        A = np.eye(len(P)) - K @ H
        P, before = F @ (A @ P @ A.T + K @ R @ K.T) @ F.T + Q, P
        P = 0.5 * (P + P.T)
        if np.abs(P - before).max() <= 1e-15 * np.abs(P).max():
            break
    return P


@pytest.mark.parametrize("radius, ratio", [(0.81, r) for r in (1e-100, 1e4, 1e8, 1e12, 0.7e20, 1e100)]
                         + [(1.3, r) for r in (1e-100, 1e4, 1e8, 1e12)])
def test_r_far_larger_or_smaller_than_q(radius, ratio):
    """R of 0.7e20 beside a Q of order 1 gave a P wrong in sign (its smallest eigenvalue -178), solved in units
    of R; an unstable F needs those units (in Q's, 1e8 gave 5e-8 relative errors). The oracle iterates the
    Riccati map to its fixed point, where it converges in float64 (the unstable model up to a ratio of 1e12)."""
    rng = np.random.default_rng(5)
    F, H, A = rng.normal(size=(3, 3)), rng.normal(size=(1, 3)), rng.normal(size=(3, 3))
    F *= radius / np.max(np.abs(np.linalg.eigvals(F)))
    Q, R = A @ A.T, np.array([[ratio]])
    P = gf.steady_state(gf.LinearModel(F, H, Q, R)).predicted_cov
    want = _joseph_limit(F, H, Q, R)
    np.testing.assert_allclose(P, want, rtol=0, atol=1e-12 * np.abs(want).max())
    assert np.linalg.eigvalsh(P)[0] >= -1e-14 * np.abs(P).max()


def test_no_process_noise_and_a_stable_f_is_known_exactly():
    """P = 0 solves the equation (and stabilises: F does); then R = 0 leaves S singular, which is said so (SciPy
    failed there, reported as a missing stabilising solution)."""
    ss = gf.steady_state(gf.LinearModel(F=0.5 * np.eye(2), H=np.eye(2), Q=np.zeros((2, 2)), R=np.eye(2)))
    assert not ss.predicted_cov.any() and not ss.cov.any() and not ss.gain.any()
    with pytest.raises(ValueError, match="no steady gain: its stationary innovation covariance S"):
        gf.steady_state(gf.LinearModel(F=0.5 * np.eye(2), H=np.eye(2), Q=np.zeros((2, 2)), R=np.zeros((2, 2))))


def test_an_unstable_but_observed_model_has_a_steady_state():
    """Constant velocity (F has a double eigenvalue 1): the filter still converges, to the filter's own limit."""
    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    ss = gf.steady_state(model)
    res = gf.filter(model, gf.Gaussian(np.zeros(4), np.eye(4)), np.zeros((400, 2)), engine="python")
    np.testing.assert_allclose(ss.cov, res.covs[-1], rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(ss.predicted_cov, res.predicted_covs[-1], rtol=1e-9, atol=1e-14)


def test_models_without_a_steady_state_are_named():
    with pytest.raises(TypeError, match="gaussfuse.LinearModel"):
        gf.steady_state(gf.NonlinearModel(lambda x: x, lambda x: x, np.eye(1), np.eye(1)))
    with pytest.raises(ValueError, match="time-varying"):
        gf.steady_state(gf.LinearModel(np.ones((3, 1, 1)), 1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="no steady state"):  # x grows by 2 a step and nothing measures it
        gf.steady_state(gf.LinearModel([[2.0, 0.0], [0.0, 0.5]], [[0.0, 1.0]], np.eye(2), [[1.0]]))
    # no noise at all: P∞ = 0 and S∞ = 0, so there is no gain (this raised the update's LinAlgError about S)
    ca = gf.LinearModel([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]], np.zeros((3, 3)), 0.0)
    with pytest.raises(ValueError, match=r"no steady gain: its stationary innovation covariance S .* is singular") as e:
        gf.steady_state(ca)
    assert type(e.value) is ValueError


def test_a_stable_model_whose_measured_component_settles_to_no_noise_has_no_steady_gain():
    """Audit KK1: F = 0.5 I, H = [0, 1], Q = diag(1, 0), R = 0. The measured component has no process noise, so
    its variance falls to 0 (P∞ = diag(4/3, 0)) and S with it. SciPy fails there and the doubling needs R
    positive definite: the error blamed an unstable mode of F (it has none) instead of the singular S."""
    model = gf.LinearModel(F=np.diag([0.5, 0.5]), H=[[0.0, 1.0]], Q=np.diag([1.0, 0.0]), R=0.0)
    with pytest.raises(ValueError, match=r"no steady gain: its stationary innovation covariance S .* is singular "
                                         r"\(\[\[0\.\]\]\)") as e:
        gf.steady_state(model)
    assert "unstable" not in str(e.value)
    # the filter itself: from any prior the innovation variance falls to 0 (within two steps, the update on an
    # exact measurement leaving the component known)
    res = gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros((1, 1)), engine="python")
    assert res.covs[-1][1, 1] == 0.0
    # the same model with the measured component driven has its steady state
    driven = gf.steady_state(gf.LinearModel(F=np.diag([0.5, 0.5]), H=[[0.0, 1.0]], Q=np.eye(2), R=0.0))
    np.testing.assert_allclose(driven.predicted_cov, np.diag([4 / 3, 1.0]), rtol=1e-12)


def test_the_largest_scales_solve_without_a_warning():
    """Audit KK2: SciPy's unit, a power of two within a factor 2 of Q = 1e308, was 2**1024: NumPy's overflow
    warning (the answer came from the doubling)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ss = gf.steady_state(gf.LinearModel(F=1.0, H=1.0, Q=1e308, R=1e-308))
    assert ss.predicted_cov[0, 0] == 1e308 and ss.gain[0, 0] == 1.0


def test_two_sensors_repeating_one_measurement_are_named_as_such():
    """Audit HH4: two sensors of one state with fully correlated noise (R singular, S singular at every step) were
    said to be a state "known exactly in the long run" with "R = 0 where it is measured", neither of which holds."""
    model = gf.LinearModel(F=1.0, H=[[1.0], [2.0]], Q=1.0, R=[[1.0, 2.0], [2.0, 4.0]])
    with pytest.raises(ValueError, match=r"or repeats another measurement with the same noise \(two sensors of one "
                                         r"component with fully correlated noise\)\. Give R a positive definite"):
        gf.steady_state(model)


@pytest.mark.parametrize("engine", ["python", "numba"])
def test_the_steady_state_filter_equals_the_full_filter_after_convergence(engine):
    """Held from the first step within 1e-10 of the stationary covariance: the full filter to 1e-9, sooner."""
    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    prior = gf.Gaussian(np.zeros(4), 1e4 * np.eye(4))
    zs = np.cumsum(np.random.default_rng(0).normal(size=(3000, 2)), axis=0) * 0.1
    zs[1500, 0] = np.nan  # a partly missing step is computed in full, and the steady state found again
    steady = gf.filter(model, prior, zs, engine=engine, steady=True)
    full = gf.filter(model, prior, zs, engine=engine)
    for name in ("means", "covs", "predicted_covs", "innovations"):
        a, b = getattr(steady, name), getattr(full, name)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.nanmax(np.abs(b)), err_msg=name)
    assert steady.loglik == pytest.approx(full.loglik, rel=1e-10)  # 3,000 terms, each within about 1e-10

    def held_from(covs):
        return next(k for k in range(len(covs) - 1) if all(np.array_equal(covs[k], c) for c in covs[k:1500]))

    assert held_from(steady.covs) < held_from(full.covs)
    np.testing.assert_allclose(steady.covs[-1], gf.steady_state(model).cov, rtol=1e-9)


def test_steady_is_checked():
    model = gf.constant_velocity(0.1, 1.0, 0.25)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    with pytest.raises(TypeError, match="`steady` must be True or False"):
        gf.filter(model, prior, np.zeros((5, 1)), steady="yes")
    with pytest.raises(ValueError, match="covariance form"):
        gf.filter(model, prior, np.zeros((5, 1)), steady=True, form="sqrt")
    with pytest.raises(ValueError, match="time-varying"):
        gf.filter(gf.LinearModel(np.ones((5, 1, 1)), 1.0, 1.0, 1.0), gf.Gaussian([0.0], [[1.0]]), np.zeros((5, 1)),
                  steady=True)
    timed = gf.model(gf.ConstantVelocity(), gf.Position())  # (the message named a time axis the user never gave)
    with pytest.raises(ValueError, match="`steady=True` needs one time step, and the steps between the times"):
        gf.filter(timed, prior, np.ones((3, 1)), times=[0.0, 1.0, 2.5, 3.0], steady=True)
    regular = gf.filter(timed, prior, np.ones((3, 1)), times=[0.0, 1.0, 2.0, 3.0], steady=True)
    np.testing.assert_array_equal(regular.means, gf.filter(timed, prior, np.ones((3, 1)), times=[0, 1, 2, 3]).means)
    stamps = pd.Timestamp("2026-01-01") + pd.to_timedelta(np.arange(4) / 30, unit="s")  # 33333333 or ...4 ns
    thirty = gf.filter(timed, prior, pd.DataFrame(np.ones((4, 1)), index=stamps), steady=True)  # (review R33)
    fixed = gf.filter(gf.model(gf.ConstantVelocity(), gf.Position(), float(np.diff(stamps.asi8).mean()) / 1e9),
                      prior, np.ones((4, 1)), steady=True)
    np.testing.assert_allclose(thirty.means, fixed.means, rtol=1e-8)  # (dt to a nanosecond)
    np.testing.assert_array_equal(gf.filter(timed, prior, np.ones((3, 1)), times=[0, 1, 2, 3], steady=np.True_).means,
                                  regular.means)  # (review R34: NumPy's True took the old path)
    turning = gf.model(gf.CoordinatedTurn(q_acc=0.1, q_turn=1e-3), gf.RangeBearing())  # still the method's refusal
    with pytest.raises(ValueError, match="`steady=True` is for method 'kf'"):
        gf.filter(turning, gf.Gaussian(np.zeros(5), np.eye(5)), np.ones((3, 2)), times=[0, 1, 2, 3], method="ekf",
                  steady=True)
    with pytest.raises(TypeError, match="`zs` must be a rectangular array"):  # (not NumPy's error: review R34)
        gf.filter(timed, prior, [[1.0], [1.0, 2.0], [1.0]], times=[0, 1, 2, 3], steady=True)
    with pytest.raises(ValueError, match="time-varying"):  # a time-varying model at regular times (review R28)
        gf.filter(gf.LinearModel(np.ones((5, 1, 1)), 1.0, 1.0, 1.0), gf.Gaussian([0.0], [[1.0]]), np.zeros((5, 1)),
                  steady=True, times=np.arange(5.0))


def test_a_step_with_missing_components_after_the_steady_point_stays_near_the_full_filter():
    """The documented exception to 1e-10: a step computed in full from the stationary prediction, with 2 of 3
    components missing, differs by 1.8e-9 of the variances, and the difference decays after it."""
    rng = np.random.default_rng(7)
    for n, m, T in [(2, 1, 50), (3, 2, 40), (1, 1, 30), (2, 3, 25)]:  # the last one is the case
        F, H = _oracle.random_transition(rng, n, 0.95), rng.normal(size=(m, n))
        Q, R = _oracle.random_spd(rng, n), _oracle.random_spd(rng, m)
        m0, P0 = rng.normal(size=n), _oracle.random_spd(rng, n)
        zs = rng.normal(size=(3, T, m)) * 2
        zs[1][rng.random((T, m)) < 0.2] = np.nan
    model, prior, z = gf.LinearModel(F=F, H=H, Q=Q, R=R), gf.Gaussian(m0, P0), zs[1]
    full = gf.filter(model, prior, z, check="off")
    steady = gf.filter(model, prior, z, steady=True, check="off")
    sd = np.sqrt(np.diagonal(full.covs, axis1=1, axis2=2))
    rel = np.max(np.abs(steady.covs - full.covs) / (sd[:, :, None] * sd[:, None, :]), axis=(1, 2))
    assert 1e-9 < rel.max() <= 5e-9  # the case: 1.8e-9
    assert np.all(rel[-5:] <= 1e-10)



@pytest.mark.parametrize("F, q, r", [(1.5, 1e-30, 1.0), (1.5, 1e-100, 1.0), (2.0, 1e-200, 1.0), (1.5, 1e-150, 1e150)])
def test_an_unstable_model_with_tiny_process_noise_has_its_steady_state(F, q, r):
    """SciPy's solver fails when Q is 1e-30 of R or less, though the stabilising solution exists (and the
    filter converges to it): it was refused as "no stabilising solution". The filter's own recursion is run
    to its fixed point there. Against the scalar Riccati equation's positive root, p² + (r(1 - F²) - q) p - q r = 0."""
    b = r * (1 - F**2) - q
    exact = (-b + np.sqrt(b * b + 4 * q * r)) / 2
    got = gf.steady_state(gf.LinearModel(F=F, H=1.0, Q=q, R=r))
    assert got.predicted_cov[0, 0] == pytest.approx(exact, rel=1e-13, abs=0.0)
    assert got.gain[0, 0] == pytest.approx(exact / (exact + r), rel=1e-13, abs=0.0)


def test_an_unstable_mode_the_measurements_do_not_see_is_still_refused():
    with pytest.raises(ValueError, match=r"no steady state: the Riccati equation has no stabilising solution"):
        gf.steady_state(gf.LinearModel(F=[[1.5, 0.0], [0.0, 1.0]], H=[[0.0, 1.0]], Q=np.eye(2), R=1.0))


@pytest.mark.parametrize("F, Q, H", [
    (1.0, 0.0, 1.0),                                                    # a constant
    ([[1.0, 1.0], [0.0, 1.0]], [[0.1, 0.0], [0.0, 0.0]], [[1.0, 0.0]]),  # a constant velocity
])
def test_a_constant_without_process_noise_is_named_as_such(F, Q, H):
    """F = 1, Q = 0: the filter's variance falls to 0 as 1/k, with no steady gain; the error blamed unstable
    modes unseen or R singular, neither of which the model has (audit M)."""
    model = gf.LinearModel(F=F, H=H, Q=Q, R=1.0)
    with pytest.raises(ValueError, match=r"no steady state: F has a mode on the unit circle \(eigenvalue 1\+0j\) "
                                         r"that Q does not drive"):
        gf.steady_state(model)
    n = np.atleast_2d(F).shape[0]
    with pytest.raises(ValueError, match="mode on the unit circle"):
        gf.filter(model, gf.Gaussian(np.zeros(n), np.eye(n)), np.zeros(50), steady=True)



@pytest.mark.parametrize("angle", [0.1, 0.3, 0.5, 1.0, 2.0])
def test_a_rotation_without_process_noise_has_no_steady_state_at_every_angle(angle):
    """An oscillator (F a rotation) with Q = 0: its modes lie on the unit circle and Q does not drive them. At
    0.1 and 0.3 rad the closed loop's pole computed as 0.9999999999999996 and 0.9999999999999999, inside the
    circle by round-off, and P⁻ = 0 came back as a steady state (audit AA2); at 0.5 rad the error was raised. A
    damped rotation (modulus 0.999) does have one: P⁻ = 0."""
    c, s = np.cos(angle), np.sin(angle)
    F = np.array([[c, -s], [s, c]])
    model = gf.LinearModel(F=F, H=[[1.0, 0.0]], Q=np.zeros((2, 2)), R=1.0)
    with pytest.raises(ValueError, match=r"no steady state: F has a mode on the unit circle .* that Q does not drive"):
        gf.steady_state(model)
    with pytest.raises(ValueError, match="mode on the unit circle"):
        gf.filter(model, gf.Gaussian(np.zeros(2), np.eye(2)), np.zeros(20), steady=True)
    damped = gf.steady_state(gf.LinearModel(F=0.999 * F, H=[[1.0, 0.0]], Q=np.zeros((2, 2)), R=1.0))
    assert not damped.predicted_cov.any() and not damped.gain.any()


@pytest.mark.parametrize("q", [1e-33, 1e-40, 1e-100])
def test_a_random_walk_driven_below_round_off_is_named_as_such(q):
    """F = H = R = 1 with Q below about 1e-32: the stable gain, √Q, leaves the filter's pole 1 - 1e-16 or closer,
    which float64 rounds to 1. The error said to check that every unstable mode is seen and reached, which this
    model satisfies (audit AA2); it now names the faint noise. At Q = 1e-32 the closed form still holds."""
    with pytest.raises(ValueError, match=r"no steady state that float64 can hold: F has a mode on the unit circle "
                                         r"\(eigenvalue 1\+0j\) that Q drives with 1e-\d+, beside R's 1"):
        gf.steady_state(gf.LinearModel(1.0, 1.0, q, 1.0))
    assert gf.steady_state(gf.LinearModel(1.0, 1.0, 1e-32, 1.0)).predicted_cov[0, 0] == pytest.approx(
        _scalar_root(1.0, 1e-32, 1.0), rel=3e-8, abs=0.0)

def _scalar_root(a, q, r):
    """The positive root of p = a² p r / (p + r) + q (the scalar Riccati equation), without cancellation."""
    b = r - a * a * r - q
    return 2 * q * r / (b + np.sqrt(b * b + 4 * q * r)) if b > 0 else (-b + np.sqrt(b * b + 4 * q * r)) / 2


@pytest.mark.parametrize("a, q, r, rel", [(1.01, 1e-25, 1.0, 1e-12), (1.5, 1e-30, 2.0, 1e-12), (1.5, 1e-25, 1.0, 1e-12),
                                          (1.0, 1e-24, 1.0, 3e-8), (1.0, 1e-28, 1.0, 3e-8), (1.0, 1.0, 1e20, 3e-8),
                                          (-1.0, 1e-20, 1.0, 3e-8), (0.5, 1e-25, 1.0, 1e-12),
                                          (1.0, 1e-21, 1.0, 3e-8), (1.0, 1e-16, 1.0, 3e-8)])
def test_a_tiny_q_beside_r_gives_the_stabilising_solution(a, q, r, rel):
    """SciPy returned solutions that are not the stabilising one (F = 1.01, Q = 1e-25: P = 22304 for 0.0201, gain
    0.99996), or a negative one, named as "S singular ([[-1048574.]]) ... give R a positive variance"; a random walk
    with Q = 1e-24 gave 9e-9 for 1e-12, and one with Q = 1e-28 "no stabilising solution". With Q = 1e-21 SciPy's
    answer, 2.3e-6 off, was kept over the doubling's, 8e-9 off: both solve the equation to round-off of P (audit AA2).
    Against the closed-form root (to 3e-8 where the filter's pole is within 1e-8 of the unit circle, where the
    equation's terms cancel)."""
    ss = gf.steady_state(gf.LinearModel(a, 1.0, q, r))
    p = _scalar_root(a, q, r)
    assert ss.predicted_cov[0, 0] == pytest.approx(p, rel=rel, abs=0.0)
    assert ss.gain[0, 0] == pytest.approx(p / (p + r), rel=rel, abs=0.0)


def test_an_unstable_pair_with_tiny_noise_gets_a_stabilising_gain():
    """F = [[1.2, 0.1], [0, 1.1]], Q = 1e-30 I: the gain returned left |eig(F - F K H)| = 1.0999. Against the
    covariance recursion in plain NumPy, run to its fixed point."""
    F, H, R = np.array([[1.2, 0.1], [0.0, 1.1]]), np.array([[1.0, 0.0]]), np.array([[1.0]])
    Q = 1e-30 * np.eye(2)
    P = np.eye(2)
    for _ in range(3000):
        S = H @ P @ H.T + R
        P = F @ (P - P @ H.T @ np.linalg.solve(S, H @ P)) @ F.T + Q
        P = (P + P.T) / 2
    ss = gf.steady_state(gf.LinearModel(F, H, Q, R))
    np.testing.assert_allclose(ss.predicted_cov, P, rtol=1e-12)
    loop = F @ (np.eye(2) - ss.gain @ H)
    assert np.abs(np.linalg.eigvals(loop)).max() < 1.0
    zs = np.random.default_rng(1).normal(size=(400, 1))  # filter(steady=True) raised the negative-S error
    held = gf.filter(gf.LinearModel(1.5, 1.0, 1e-25, 1.0), gf.Gaussian([0.0], [[1.0]]), zs, steady=True)
    full = gf.filter(gf.LinearModel(1.5, 1.0, 1e-25, 1.0), gf.Gaussian([0.0], [[1.0]]), zs)
    np.testing.assert_allclose(held.means, full.means, rtol=1e-9, atol=1e-9)


def test_a_zero_on_the_unit_circle_with_a_noise_free_sensor_is_named():
    """A constant velocity with piecewise noise (Q = g gᵀ), its position measured with R = 0: the filter's P⁻
    converges to Q, but only as 1/k, and the gain there leaves F (I - K H) an eigenvalue of -1 (the noise reaches
    the measurement through a zero at -1). The refusal listed conditions that all hold here (audit U); it names
    this case."""
    F, g = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[0.5], [1.0]])
    model = gf.LinearModel(F=F, H=[[1.0, 0.0]], Q=g @ g.T, R=0.0)
    with pytest.raises(ValueError, match=r"with R singular, the process noise may reach a measurement through a "
                                         r"zero on the unit circle .* give R a positive variance\.$"):
        gf.steady_state(model)
    kf = gf.KalmanFilter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), check="off")
    for k in range(1, 1001):
        kf.predict()
        kf.update(0.0)
    assert 0.1 / k < np.abs(kf.P_prior - model.Q).max() < 1.0 / k
    closed = F @ (np.eye(2) - np.array([[1.0], [2.0]]) @ model.H)  # the gain at P⁻ = Q
    np.testing.assert_allclose(sorted(np.linalg.eigvals(closed).real), [-1.0, 0.0], atol=1e-15)


def test_modes_near_or_on_the_unit_circle_are_judged_on_their_own_round_off():
    """Review R16 of the rotation fix: judged against Q's largest entry, Q = diag(1, 1e-13) did not drive F = I's
    second mode; within 1e-9 of the circle, F = 1 ± 1e-10 with Q = 0 was refused though its steady state is P = 0
    or (F² - 1) R; the faint-Q message blamed Q where an unstable mode was unseen; and a Jordan block in
    coordinates that are not triangular, whose eigenvalue is computed only to about 1e-8, escaped the check and
    got a loop with a pole of 1 - 7e-16. Each mode's eigenvalue is now judged to its own round-off."""
    two = gf.steady_state(gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=np.diag([1.0, 1e-13]), R=np.eye(2)))
    for i, q in enumerate((1.0, 1e-13)):
        assert two.predicted_cov[i, i] == pytest.approx(_scalar_root(1.0, q, 1.0), rel=1e-8, abs=0.0)
    assert not gf.steady_state(gf.LinearModel(F=1 - 1e-10, H=1.0, Q=0.0, R=1.0)).predicted_cov.any()
    grows = gf.steady_state(gf.LinearModel(F=1 + 1e-10, H=1.0, Q=0.0, R=1.0)).predicted_cov[0, 0]
    assert grows == pytest.approx((1 + 1e-10) ** 2 - 1, rel=1e-5, abs=0.0)
    with pytest.raises(ValueError, match="Check that every unstable mode of F is seen through H") as info:
        gf.steady_state(gf.LinearModel(F=np.diag([1.0, 1.5]), H=[[1.0, 0.0]], Q=1e-30 * np.eye(2), R=1.0))
    assert "float64 can hold" not in str(info.value)
    T = np.random.default_rng(0).normal(size=(2, 2))
    F = T @ np.array([[1.0, 1.0], [0.0, 1.0]]) @ np.linalg.inv(T)  # a constant velocity, its velocity undriven
    with pytest.raises(ValueError, match="mode on the unit circle .* that Q does not drive"):
        gf.steady_state(gf.LinearModel(F=F, H=np.array([[1.0, 0.0]]) @ np.linalg.inv(T),
                                       Q=T @ np.diag([1.0, 0.0]) @ T.T, R=1.0))


def test_the_unit_circle_check_takes_a_badly_scaled_f_and_a_repeated_eigenvalue():
    """Review R17: F = [[0.5, 1e7], [0, 0.9]], whose eigenvalues are exact, was refused as having a mode on the
    unit circle: the first-order bound on an eigenvalue's round-off, ε ‖F‖ κ, reached past 0.5 (now on the
    balanced F, and at most 1e-6). And F = I with Q = 1 1ᵀ never drives x1 - x2, which neither eigenvector SciPy
    returns for the repeated eigenvalue shows: a P came back whose loop has a pole at 1 - 1e-13 (as on 2f40a13);
    the least-driven direction of the eigenspace is now judged."""
    F, H = np.array([[0.5, 1e7], [0.0, 0.9]]), np.array([[1.0, 0.0]])
    assert not gf.steady_state(gf.LinearModel(F=F, H=H, Q=np.zeros((2, 2)), R=1.0)).predicted_cov.any()
    driven = gf.steady_state(gf.LinearModel(F=F, H=H, Q=np.diag([1.0, 0.0]), R=1.0)).predicted_cov
    p = _scalar_root(0.5, 1.0, 1.0)  # the second state is never driven: the first is a scalar AR(1)
    np.testing.assert_allclose(driven, [[p, 0.0], [0.0, 0.0]], rtol=1e-12, atol=0.0)
    with pytest.raises(ValueError, match=r"mode on the unit circle \(eigenvalue 1\+0j\) that Q does not drive"):
        gf.steady_state(gf.LinearModel(F=np.eye(2), H=np.eye(2), Q=np.ones((2, 2)), R=1e-3 * np.eye(2)))
    turns = np.kron(np.eye(2), [[0.0, -1.0], [1.0, 0.0]])  # two rotations by 90 degrees, driven alike
    with pytest.raises(ValueError, match="mode on the unit circle .* that Q does not drive"):
        gf.steady_state(gf.LinearModel(F=turns, H=np.eye(4), Q=np.kron(np.ones((2, 2)), np.eye(2)), R=np.eye(4)))
    both = gf.steady_state(gf.LinearModel(F=turns, H=np.eye(4), Q=np.eye(4), R=np.eye(4))).predicted_cov
    np.testing.assert_allclose(both, _scalar_root(1.0, 1.0, 1.0) * np.eye(4), rtol=1e-12)


@pytest.mark.parametrize("dt", [1e-6, 1e-8])
def test_a_fast_constant_velocity_with_piecewise_noise_has_its_steady_state(dt):
    """Review R18: a clock's phase and drift tracked at 1 MHz (F = [[1, dt], [0, 1]], Q = q g gᵀ, rank one) was
    refused as having an undriven mode: the eigenvalue's bound (1e-6) was used to count the eigenspace, so the
    Jordan block's coupling dt made it two-dimensional. Against SciPy."""
    from scipy.linalg import solve_discrete_are

    F, H, g = np.array([[1.0, dt], [0.0, 1.0]]), np.array([[1.0, 0.0]]), np.array([[dt * dt / 2], [dt]])
    Q, R = 1e6 * g @ g.T, np.array([[1e-4]])
    got = gf.steady_state(gf.LinearModel(F, H, Q, R)).predicted_cov
    np.testing.assert_allclose(got, solve_discrete_are(F.T, H.T, Q, R), rtol=1e-8)


@pytest.mark.parametrize("F, Q, R, match", [
    (np.diag([2.0, 0.5]), np.eye(2), 1.7e308, "has no steady state: the Riccati equation has no stabilising solution"),
    (1.0, 1e-280, 1e308, "has no steady state that float64 can hold"),
])
def test_the_fallback_recursion_at_the_largest_scales_keeps_the_models_message(F, Q, R, match):
    """Review R44: the recursion's new start, Q + s I with s the largest of Q and R, overflowed S beside an R near
    the largest float64, and the filter step's FloatingPointError escaped in place of steady_state's message."""
    H = [[0.0, 1.0]] if np.ndim(F) else 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=match):
            gf.steady_state(gf.LinearModel(F=F, H=H, Q=Q, R=R))


def test_the_fallback_recursion_starts_from_a_prior_that_knows_no_component_exactly():
    """Review R46: the start of the recursion SciPy's failures fall back to (Q + s I since audit KK1) was pinned by
    no test. A measured component driven only through F (Q = diag(1, 0), R = 0) has a steady state, but from
    P⁻ = Q its first S is 0, and the recursion blamed the model for having no steady gain. Oracle: the fixed point
    of the Riccati map, written here in NumPy."""
    from gaussfuse.steady import _iterated

    F, H, Q = np.array([[0.5, 0.0], [1.0, 0.5]]), np.array([[0.0, 1.0]]), np.diag([1.0, 0.0])
    P = _iterated(gf.LinearModel(F=F, H=H, Q=Q, R=0.0))
    S = H @ P @ H.T
    posterior = P - P @ H.T @ np.linalg.solve(S, H @ P)
    np.testing.assert_allclose(F @ posterior @ F.T + Q, P, rtol=0, atol=1e-14)
    np.testing.assert_allclose(P, [[1.25, 0.5], [0.5, 1.0]], rtol=1e-14)  # x2 = x1 + 0.5 x2: var 1 + 0.25


def _rotation(angle):
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


@pytest.mark.parametrize("F, H, Q, unseen, how", [
    (_rotation(0.3), [[0.0, 0.0]], np.eye(2), [1.0, 0.0], "grows without bound, driven by Q"),
    (_rotation(3.0), [[0.0, 0.0]], np.eye(2), [0.0, 1.0], "grows without bound, driven by Q"),
    (np.eye(2), [[1.0, 0.0]], np.eye(2), [0.0, 1.0], "grows without bound, driven by Q"),  # a repeated eigenvalue
    (np.eye(2), [[1.0, 1.0]], np.eye(2), [0.5 ** 0.5, -(0.5 ** 0.5)], "grows without bound, driven by Q"),
    (np.diag([1.0, 0.5]), [[0.0, 1.0]], np.diag([0.0, 1.0]), [1.0, 0.0], "stays at the prior's, whatever it is"),
])
def test_a_mode_on_the_unit_circle_that_h_does_not_measure_has_no_steady_state(F, H, Q, unseen, how):
    """A rotation that H never measures, driven by Q: its covariance grows as P0 + k Q (the recursion, iterated
    below), but steady_state returned a variance of 1.7e16, its closed loop's radius computed as 1 - 1.1e-16
    (audit WW1); undriven, the variance stays at the prior's, and the message said it falls to 0 as 1/k and
    advised giving Q a variance there, which makes it grow (audit WW2)."""
    model = gf.LinearModel(F=F, H=H, Q=Q, R=1.0)
    P = 7.0 * np.eye(2)
    for _ in range(1000):  # the oracle: the predicted covariance, step by step
        S = model.H @ P @ model.H.T + model.R
        P = model.F @ (P - P @ model.H.T @ np.linalg.solve(S, model.H @ P)) @ model.F.T + model.Q
    variance = np.asarray(unseen) @ P @ np.asarray(unseen)  # along the mode H does not see
    assert variance > 1000.0 if "grows" in how else variance == pytest.approx(7.0, rel=1e-12)
    with pytest.raises(ValueError, match=r"^the filter of `model` has no steady state: F has a mode on the unit "
                                         rf"circle \(eigenvalue .*\) that H does not measure.*{how}"):
        gf.steady_state(model)


def test_unit_circle_modes_that_h_measures_keep_their_steady_state():
    """The same F with H seeing every mode: the stabilising solution, as SciPy's."""
    from scipy.linalg import solve_discrete_are

    for F, H in ((_rotation(0.3), [[1.0, 0.0]]), (np.eye(2), np.eye(2)), (np.diag([1.0, 0.5]), [[1.0, 1.0]])):
        model = gf.LinearModel(F=F, H=H, Q=np.eye(2), R=np.eye(np.shape(H)[0]))
        want = solve_discrete_are(model.F.T, model.H.T, model.Q, model.R)
        np.testing.assert_allclose(gf.steady_state(model).predicted_cov, want, rtol=1e-12)


def test_modes_near_the_unit_circle_that_h_measures_are_not_lumped_with_it():
    """The eigenspace of a unit-circle mode was every singular value of F - λI up to 1e-10: a constant velocity
    sampled at 1e-10 s and a mode at 1 - 1e-11 beside a random walk were taken for a repeated eigenvalue whose
    unmeasured direction refused them, detectable as they are (review R53). The oracles: SciPy's solution, and
    the closed forms of a random walk (Q = R = 1: the golden ratio) and of an AR(1) nobody measures, 1 / (1 - a²)."""
    from scipy.linalg import solve_discrete_are

    dt = 1e-10
    cv = gf.LinearModel(F=[[1.0, dt], [0.0, 1.0]], H=[[1.0, 0.0]], R=1.0,
                        Q=[[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    want = solve_discrete_are(cv.F.T, cv.H.T, cv.Q, cv.R)
    np.testing.assert_allclose(np.diag(gf.steady_state(cv).predicted_cov), np.diag(want), rtol=1e-4)
    a = 1.0 - 1e-11
    pair = gf.LinearModel(F=np.diag([1.0, a]), H=[[1.0, 0.0]], Q=np.eye(2), R=1.0)
    np.testing.assert_allclose(np.diag(gf.steady_state(pair).predicted_cov), [(1 + 5 ** 0.5) / 2, 1 / (1 - a * a)],
                               rtol=1e-4)
    assert gf.filter(pair, gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros(3), steady=True).means.shape == (3, 2)
