"""The compiled mirror (:mod:`gaussfuse._kernels._step`) computes what :mod:`gaussfuse.kalman` computes.

Each compiled function is called directly, on the inputs of its readable
twin, and compared with it: to round-off for well-conditioned inputs, and
to round-off relative to the scale of the result (the honest measure) for
singular, ill-conditioned and precise-sensor ones; with states large enough
that the products are BLAS calls (:data:`gaussfuse._kernels._dense.BLAS_FROM`)
as well as small ones.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import _oracle
from gaussfuse import kalman
from gaussfuse._kernels import _step
from gaussfuse._kernels._dense import BLAS_FROM

TOL = 1e-10


def close(actual, desired, what, scale=None):
    desired = np.asarray(desired)
    scale = max(1.0, float(np.max(np.abs(desired)))) if scale is None else scale
    np.testing.assert_allclose(actual, desired, rtol=TOL, atol=TOL * scale, equal_nan=True, err_msg=what)


def conditioned_cov(rng, n, condition):
    """A covariance with eigenvalues spread log-uniformly over `condition`."""
    U = np.linalg.qr(rng.standard_normal((n, n)))[0]
    vals = np.logspace(0, -np.log10(condition), n) if n > 1 else np.ones(1)
    P = (U * vals) @ U.T
    return 0.5 * (P + P.T)


def problem(seed, n, m, kind="random"):
    rng = np.random.default_rng(seed)
    mean = rng.standard_normal(n)
    cov = _oracle.random_spd(rng, n)
    if kind == "ill-conditioned":
        cov = conditioned_cov(rng, n, 1e10)
    elif kind == "singular":
        B = rng.standard_normal((n, max(n - 2, 0)))
        cov = B @ B.T
    H = rng.standard_normal((m, n))
    R = _oracle.random_spd(rng, m)
    if kind == "precise sensor":  # R of 1e-12 next to P of order 1: K H ≈ I on the measured directions
        R = 1e-12 * R
    z = H @ mean + rng.standard_normal(m)
    return rng, mean, cov, H, R, z


SIZES = [(1, 1), (2, 1), (3, 2), (4, 4), (6, 3), (BLAS_FROM, 3), (BLAS_FROM + 4, BLAS_FROM + 1), (40, 20)]
KINDS = ["random", "ill-conditioned", "singular", "precise sensor"]


def run_update(mean, cov, z, H, R, d=None, angles=None):
    n, m = mean.shape[0], z.shape[0]
    w = _step.workspace(n, m)
    d = np.zeros(m) if d is None else d
    angles = np.zeros(m, dtype=np.bool_) if angles is None else angles
    post_mean, post_cov, innov, S_full = np.empty(n), np.empty((n, n)), np.empty(m), np.empty((m, m))
    ok, loglik, observed = _step.update(w, mean, cov, z, H, R, d, angles, post_mean, post_cov, innov, S_full)
    return ok, loglik, observed, post_mean, post_cov, innov, S_full, w


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("n, m", SIZES)
def test_update_is_kalman_update(n, m, kind):
    _, mean, cov, H, R, z = problem(n * 100 + m, n, m, kind)
    want = kalman.update(mean, cov, z, H, R)
    ok, loglik, observed, post_mean, post_cov, innov, S_full, _ = run_update(mean, cov, z, H, R)
    assert ok and observed == m
    scale = float(np.max(np.abs(cov)))
    close(post_mean, want.mean, "mean")
    # held to the posterior's own size (and the prior's round-off): a precise sensor measuring every component
    # leaves a posterior of 1e-11 beside a prior of 8, which the prior's scale let be 0 or 10 times too large
    # (audit QQ3)
    close(post_cov, want.cov, "cov", float(np.max(np.abs(want.cov))) + 1e-5 * scale)
    close(innov, want.innovation, "innovation")
    close(S_full, want.innovation_cov, "innovation_cov", scale + float(np.max(np.abs(R))))
    close(loglik, want.loglik, "loglik")
    np.testing.assert_array_equal(post_cov, post_cov.T)


def test_a_precise_sensor_keeps_the_posterior_positive_semi_definite():
    """kalman's own case: the Joseph form's congruence keeps P ⪰ 0 where (I - KH) P would not."""
    cov = np.array([[4.0, 1.999999], [1.999999, 1.0]])
    H, R, z = np.array([[1.0, 0.0]]), np.array([[1e-12]]), np.array([1.0])
    want = kalman.update(np.zeros(2), cov, z, H, R)
    post = run_update(np.zeros(2), cov, z, H, R)[4]
    np.testing.assert_allclose(post, want.cov, rtol=1e-9, atol=1e-22)
    assert np.linalg.eigvalsh(post)[0] >= -1e-15
    assert post[0, 0] == pytest.approx(1e-12, rel=1e-3, abs=0.0)


@pytest.mark.parametrize("n, m", [(3, 3), (BLAS_FROM + 2, 5)])
def test_update_with_missing_components_offsets_and_angles(n, m):
    rng, mean, cov, H, R, z = problem(7, n, m)
    d = rng.standard_normal(m)
    angles = np.zeros(m, dtype=bool)
    angles[-1] = True
    z[-1] = 3.0  # far from the prediction: the innovation wraps
    for missing in ([], [0], list(range(m - 1))):
        zz = z.copy()
        zz[missing] = np.nan
        want = kalman.update(mean, cov, zz, H, R, d, angles)
        ok, loglik, observed, post_mean, post_cov, innov, S_full, _ = run_update(mean, cov, zz, H, R, d, angles)
        assert ok and observed == m - len(missing)
        close(post_mean, want.mean, "mean")
        close(post_cov, want.cov, "cov")
        close(innov, want.innovation, "innovation")
        close(S_full, want.innovation_cov, "innovation_cov")
        close(loglik, want.loglik, "loglik")


def test_nothing_observed_returns_the_prediction():
    _, mean, cov, H, R, z = problem(3, 3, 2)
    ok, loglik, observed, post_mean, post_cov, innov, S_full, _ = run_update(mean, cov, np.full(2, np.nan), H, R)
    assert ok and observed == 0 and loglik == 0.0
    np.testing.assert_array_equal(post_mean, mean)
    np.testing.assert_array_equal(post_cov, cov)
    assert np.isnan(innov).all()


@pytest.mark.parametrize("m", [1, 3, BLAS_FROM + 1])
def test_an_innovation_covariance_not_positive_definite_is_returned_not_raised(m):
    n = 4
    H, R = np.zeros((m, n)), np.zeros((m, m))
    R[0, 0] = 1.0  # S = R: singular when m > 1, zero-free when m = 1 ...
    if m == 1:
        R[0, 0] = -1.0  # ... so negative there
    z = np.ones(m)
    ok, _, observed, *_, w = run_update(np.zeros(n), np.eye(n), z, H, R)
    assert not ok and observed == m
    np.testing.assert_array_equal(w.S[:m, :m], R)
    with pytest.raises(np.linalg.LinAlgError):
        kalman.update(np.zeros(n), np.eye(n), z, H, R)


def test_wrap_is_wrap_angle_at_the_edges():
    """The compiled wrap mirrors _linalg.wrap_angle, the angles within round-off below -π too (which gave +π)."""
    from numba import njit

    wrap = njit(_step.wrap.py_func)  # (inlined where it is used: compiled here on its own)
    edge = np.concatenate([[np.nextafter(-np.pi, -np.inf), -np.pi, np.pi, 3 * np.pi, -3 * np.pi, 0.0, 1e300, -7.5],
                           -np.pi - np.random.default_rng(1).uniform(0.0, 1e-12, 200)])
    got = np.array([wrap(a) for a in edge])
    np.testing.assert_array_equal(got, _linalg_wrap(edge))
    assert (got >= -np.pi).all() and (got < np.pi).all()


def _linalg_wrap(a):
    from gaussfuse._linalg import wrap_angle

    return wrap_angle(a)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.sampled_from([1, 2, 4, 7, BLAS_FROM + 3]),
       kind=st.sampled_from(KINDS))
def test_predict_is_kalman_predict(seed, n, kind):
    rng, mean, cov, *_ = problem(seed, n, 1, kind)
    A = rng.standard_normal((n, n))
    Q = _oracle.random_spd(rng, n)
    b = rng.standard_normal(n)
    w = _step.workspace(n, 1)
    pm, pc = np.empty(n), np.empty((n, n))
    _step.predict(w, mean, cov, A, Q, b, pm, pc)
    want_mean, want_cov = kalman.predict(mean, cov, A, Q, b)
    close(pm, want_mean, "mean")
    close(pc, want_cov, "cov", float(np.max(np.abs(want_cov))))
    np.testing.assert_array_equal(pc, pc.T)
    np.testing.assert_allclose(w.A1, A @ cov, rtol=1e-12, atol=1e-12 * np.max(np.abs(A @ cov)))  # Cᵀ of the gain


@pytest.mark.parametrize("n", [1, 3, 5, BLAS_FROM + 2])
@pytest.mark.parametrize("singular", [False, True])
def test_rts_step_is_kalman_rts_step(n, singular):
    rng = np.random.default_rng(n)
    filt_mean, next_mean = rng.standard_normal(n), rng.standard_normal(n)
    filt_cov = _oracle.random_spd(rng, n)
    A = rng.standard_normal((n, n))
    Q = np.zeros((n, n)) if singular else _oracle.random_spd(rng, n)
    if singular:  # no process noise, and a state known exactly that stays known: P⁻ has a zero row
        filt_cov[-1], filt_cov[:, -1] = 0.0, 0.0
        A[-1] = 0.0
    pred_mean, pred_cov = kalman.predict(filt_mean, filt_cov, A, Q)
    next_cov = 0.5 * pred_cov
    angles = np.zeros(n, dtype=bool)
    want_mean, want_cov, want_gain = kalman.rts_step(filt_mean, filt_cov, pred_mean, pred_cov, next_mean, next_cov,
                                                     filt_cov @ A.T)
    w = _step.workspace(n, 1)
    gain = np.empty((n, n))
    ok = _step.smoother_gain(w, pred_cov, A @ filt_cov, gain)
    if singular:
        assert not ok  # the caller takes the least-squares gain (tested through the engines)
        gain = want_gain.copy(order="F")  # the kernel's BLAS calls refuse other layouts, and take the loops
    else:
        close(gain, want_gain, "gain")
    mean, cov = np.empty(n), np.empty((n, n))
    _step.rts_step(w, filt_mean, filt_cov, pred_mean, pred_cov, next_mean, next_cov, gain, angles, mean, cov)
    close(mean, want_mean, "mean")
    close(cov, want_cov, "cov")


def test_not_finite_checks_every_entry_and_the_log_likelihood():
    mean, cov = np.zeros(3), np.eye(3)
    assert not _step.not_finite(mean, cov, 0.0)
    for poison in (np.inf, -np.inf, np.nan):
        c = cov.copy()
        c[0, 2] = poison  # off the diagonal, as kalman.check_finite sees it
        assert _step.not_finite(mean, c, 0.0)
        m = mean.copy()
        m[1] = poison
        assert _step.not_finite(m, cov, 0.0)
        assert _step.not_finite(mean, cov, poison)
    assert not _step.not_finite(np.full(3, 1e308), np.full((3, 3), 1e308), -1e308)  # huge is not overflow


def test_wrap_is_wrap_angle():
    from gaussfuse._linalg import wrap_angle

    a = np.concatenate([np.linspace(-20, 20, 401), [np.pi, -np.pi, 3 * np.pi, 0.0, -0.0, 1e-300]])
    np.testing.assert_array_equal([_step.wrap(x) for x in a], wrap_angle(a))


def test_failures_raise_the_readable_messages():
    fail = _step.failures(3, 2)
    _step.raise_failure(fail)  # nothing failed
    fail.code[1], fail.step[1], fail.size[1] = _step.NOT_POSITIVE_DEFINITE, 4, 1
    with pytest.raises(np.linalg.LinAlgError, match=r"^in series 1, at step 4: the innovation covariance S = "
                                                     r"H P Hᵀ \+ R is not positive definite, so it cannot be "
                                                     r"factorised: \[\[0\.\]\] \(S is singular to round-off where a "
                                                     r"component measured without noise.*give R a variance "
                                                     r"above round-off\.\)$"):
        _step.raise_failure(fail)
    one = _step.failures(1, 2)
    one.code[0], one.step[0] = _step.FILTERED_NOT_FINITE, 2
    with pytest.raises(FloatingPointError, match=r"^at step 2: the filtered mean, covariance or log-likelihood"):
        _step.raise_failure(one)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(1, 6), st.integers(1, 3), st.sampled_from([1e-150, 1e-6, 1.0, 1e6, 1e150]),
       st.booleans(), st.integers(0, 2**32 - 1))
def test_downdate_is_linalg_downdate(n, p, scale, zero_row, seed):
    """The compiled downdate (in place, rows ``:q``) against _linalg.downdate: the same factor to round-off of
    its scale, a component that V does not touch left as it is, and False exactly where the readable one raises."""
    from gaussfuse._linalg import downdate as readable_downdate

    rng = np.random.default_rng(seed)
    L = np.linalg.cholesky(conditioned_cov(rng, n, 1e4)) * scale
    V = 0.3 * L @ rng.standard_normal((n, p)) / np.sqrt(p)  # L Lᵀ - V Vᵀ stays positive definite
    if zero_row:
        V[0] = 0.0
    if rng.random() < 0.25:  # sometimes too much to take away
        V *= 10.0
    try:
        want = readable_downdate(L, V)
    except np.linalg.LinAlgError:
        want = None
    got = L.copy()
    ok = _step.downdate(got, V, n, p, np.empty(n))
    assert ok == (want is not None)
    if want is not None:
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
        if zero_row:
            assert got[0, 0] == L[0, 0]
