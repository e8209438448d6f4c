"""The interacting multiple model filter, gf.imm_filter."""

from __future__ import annotations

import doctest
import re
import warnings

import numpy as np
import pytest
from scipy.linalg import block_diag

import _oracle
import gaussfuse as gf
import gaussfuse.imm

# ---------------------------------------------------------------------------
# The manoeuvring target: straight, a 90° turn, straight
# ---------------------------------------------------------------------------

DT, R, SPEED = 1.0, 25.0, 15.0
N1, NT, N2 = 30, 15, 30  # steps straight, turning, straight
Q_ACC, Q_TURN = 0.01, 1e-3
SWITCH = np.array([[0.95, 0.05], [0.05, 0.95]])


def _truth() -> tuple[np.ndarray, np.ndarray]:
    """States (T, 5) of a target at constant speed that turns 90° in NT steps; the turn mask (T,)."""
    omega = (np.pi / 2) / (NT * DT)
    exact = gf.CoordinatedTurn(q_acc=0.0, q_turn=0.0)
    x, states = np.array([0.0, 0.0, SPEED, 0.0, 0.0]), []
    turning = np.arange(N1 + NT + N2)
    turning = (N1 <= turning) & (turning < N1 + NT)
    for turn in turning:
        x[4] = omega if turn else 0.0
        x = exact.f(x, DT)
        states.append(x.copy())
    return np.array(states), turning


def _models() -> tuple[gf.LinearModel, gf.NonlinearModel]:
    """Constant velocity on the 5-state [x, y, vx, vy, ω] (ω kept near 0, not moving anything) and CT."""
    F4, Q4 = gf.ConstantVelocity(dim=2, q=Q_ACC).transition(DT)
    cv = gf.LinearModel(F=block_diag(F4, [[0.0]]), H=np.eye(2, 5), Q=block_diag(Q4, [[1e-6]]), R=R * np.eye(2))
    ct = gf.model(gf.CoordinatedTurn(q_acc=Q_ACC, q_turn=Q_TURN), gf.Position(dim=2, r=R), DT)
    return cv, ct


def _prior() -> gf.Gaussian:
    return gf.Gaussian([0.0, 0.0, SPEED, 0.0, 0.0], np.diag([R, R, 4.0, 4.0, 1e-4]))


@pytest.fixture(scope="module")
def monte_carlo():
    """50 seeded runs: position RMSE of IMM, CV and CT, and the IMM's mode probabilities."""
    states, turning = _truth()
    cv, ct = _models()
    rmse = {"imm": [], "cv": [], "ct": []}
    probs = []
    for seed in range(50):
        rng = np.random.default_rng(seed)
        zs = states[:, :2] + rng.normal(scale=np.sqrt(R), size=(states.shape[0], 2))
        results = {
            "imm": gf.imm_filter([cv, ct], _prior(), zs, SWITCH, method="ekf"),
            "cv": gf.filter(cv, _prior(), zs),
            "ct": gf.filter(ct, _prior(), zs, method="ekf"),
        }
        for name, res in results.items():
            err = res.means[:, :2] - states[:, :2]
            rmse[name].append(np.sqrt(np.mean(np.sum(err**2, axis=1))))
        probs.append(results["imm"].mode_probs)
    return {name: float(np.mean(v)) for name, v in rmse.items()}, np.array(probs), turning


def test_imm_beats_the_best_single_model(monte_carlo):
    rmse, _, _ = monte_carlo
    print(f"position RMSE over 50 runs: IMM {rmse['imm']:.3f}, CV {rmse['cv']:.3f}, CT {rmse['ct']:.3f}")
    assert rmse["imm"] < min(rmse["cv"], rmse["ct"])
    # By a clear margin, not by luck.
    assert rmse["imm"] < 0.9 * min(rmse["cv"], rmse["ct"])


def test_mode_probabilities_sum_to_one_and_follow_the_turn(monte_carlo):
    _, probs, turning = monte_carlo
    assert probs.shape == (50, N1 + NT + N2, 2)
    np.testing.assert_allclose(probs.sum(axis=-1), 1.0, rtol=0, atol=1e-12)
    assert np.all(probs >= 0)
    settled_turn = np.zeros_like(turning)
    settled_turn[N1 + 3:N1 + NT] = True  # a few steps to notice the turn
    settled_straight = np.zeros_like(turning)
    settled_straight[5:N1] = settled_straight[N1 + NT + 5:] = True
    p_ct_turn = probs[:, settled_turn, 1].mean()
    p_ct_straight = probs[:, settled_straight, 1].mean()
    print(f"mean P(CT): turning {p_ct_turn:.3f}, straight {p_ct_straight:.3f}")
    assert p_ct_turn > 0.6
    assert p_ct_straight < 0.4
    # In (nearly) every single run, CT is the more likely mode over the turn.
    assert np.mean(probs[:, settled_turn, 1].mean(axis=1) > 0.5) >= 0.95


# ---------------------------------------------------------------------------
# Exactness
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
def test_single_model_imm_is_that_models_filter(seed):
    rng = np.random.default_rng(seed)
    mask = rng.random(size=(12, 2)) < 0.2
    mask[5] = True  # one step with nothing observed
    problem = _oracle.random_problem(rng, 3, 2, 12, p=1, varying={"F", "Q"}, mask=mask)
    model = gf.LinearModel(problem["F"], problem["H"], problem["Q"], problem["R"], problem["B"])
    prior = gf.Gaussian(problem["m0"], problem["P0"])
    ref = gf.filter(model, prior, problem["zs"], problem["us"])
    res = gf.imm_filter([model], prior, problem["zs"], [[1.0]], us=problem["us"])
    np.testing.assert_allclose(res.means, ref.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res.covs, ref.covs, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res.mode_means[:, 0], ref.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(res.mode_probs, np.ones((12, 1)))
    assert res.loglik == pytest.approx(ref.loglik, rel=1e-12)


@pytest.mark.parametrize("method", ["ekf", "ukf", "iekf"])
def test_single_nonlinear_model_imm_is_that_models_filter(method):
    states, _ = _truth()
    zs = states[:, :2] + np.random.default_rng(7).normal(scale=5.0, size=(states.shape[0], 2))
    _, ct = _models()
    ref = gf.filter(ct, _prior(), zs, method=method)
    res = gf.imm_filter([ct], _prior(), zs, [[1.0]], method=method)
    np.testing.assert_allclose(res.means, ref.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res.covs, ref.covs, rtol=1e-12, atol=1e-12)
    assert res.loglik == pytest.approx(ref.loglik, rel=1e-12)


def test_iterated_steps_at_their_limit_are_told_as_the_filter_tells_them():
    """imm_filter ran the iterated update's passes but dropped its count: the filter warned that steps made
    `iterations` passes without meeting `tol`, and the IMM, one model or two copies of it, said nothing (audit YY1)."""
    def f(x):
        return np.array([x[0] + 0.1 * np.sin(x[1]), 0.95 * x[1]])

    def h(x):
        return np.array([np.arctan2(x[1], 1.0 + x[0] ** 2)])

    ct = gf.NonlinearModel(f, h, np.diag([0.1, 0.2]), 0.05)
    start = gf.Gaussian([0.2, 0.4], 0.5 * np.eye(2))
    zs = np.random.default_rng(3).normal(size=20) * 0.3
    with pytest.warns(gf.ConvergenceWarning) as told:
        gf.filter(ct, start, zs, method="iekf", iterations=2, tol=1e-12)
    (expected,) = [str(w.message) for w in told]
    count = re.match(r"method 'iekf': (\d+) of \d+ steps", expected).group(1)
    assert int(count) > 0
    with pytest.warns(gf.ConvergenceWarning) as alone:
        gf.imm_filter([ct], start, zs, [[1.0]], method="iekf", iterations=2, tol=1e-12)
    assert [str(w.message) for w in alone] == [expected]
    with pytest.warns(gf.ConvergenceWarning) as pair:
        gf.imm_filter([ct, ct], start, zs, [[0.9, 0.1], [0.1, 0.9]], method="iekf", iterations=2, tol=1e-12)
    assert [str(w.message) for w in pair] == [expected.replace("'iekf':", f"'iekf' in `models[{j}]`:") for j in (0, 1)]
    assert all(w.filename == __file__ for w in [*alone, *pair])


def _reference_imm(models, m0, P0, zs, Pi, mu):
    """A textbook IMM for linear models (Bar-Shalom, Li & Kirubarajan 2001, §11.6.6), explicit inverses."""
    M, means, covs, out = len(models), [m0] * len(models), [P0] * len(models), []
    loglik = 0.0
    for z in zs:
        c = Pi.T @ mu
        mix = (Pi * mu[:, None]) / c[None, :]
        new_means, new_covs, lik = [], [], np.empty(M)
        for j, (F, H, Q, Rm) in enumerate(models):
            m = sum(mix[i, j] * means[i] for i in range(M))
            P = sum(mix[i, j] * (covs[i] + np.outer(means[i] - m, means[i] - m)) for i in range(M))
            m, P = F @ m, F @ P @ F.T + Q
            S = H @ P @ H.T + Rm
            K = P @ H.T @ np.linalg.inv(S)
            v = z - H @ m
            new_means.append(m + K @ v)
            new_covs.append(P - K @ S @ K.T)
            lik[j] = np.exp(-0.5 * v @ np.linalg.inv(S) @ v) / np.sqrt(np.linalg.det(2 * np.pi * S))
        means, covs = new_means, new_covs
        loglik += np.log(lik @ c)
        mu = lik * c / (lik @ c)
        x = sum(mu[j] * means[j] for j in range(M))
        P = sum(mu[j] * (covs[j] + np.outer(means[j] - x, means[j] - x)) for j in range(M))
        out.append((x, P, mu.copy()))
    return out, loglik


def test_three_linear_models_equal_a_textbook_imm():
    rng = np.random.default_rng(11)
    n, m, T = 3, 2, 15
    H, Rm = rng.normal(size=(m, n)), _oracle.random_spd(rng, m)
    mats = [(_oracle.random_transition(rng, n, 1.0), H, _oracle.random_spd(rng, n, 0.05, s), Rm)
            for s in (0.2, 1.0, 5.0)]
    Pi = np.array([[0.8, 0.15, 0.05], [0.1, 0.7, 0.2], [0.3, 0.3, 0.4]])
    mu0 = np.array([0.5, 0.3, 0.2])
    m0, P0 = rng.normal(size=n), _oracle.random_spd(rng, n)
    zs = rng.normal(size=(T, m)) * 3
    ref, ref_loglik = _reference_imm(mats, m0, P0, zs, Pi, mu0)
    models = [gf.LinearModel(F, H_, Q, R_) for F, H_, Q, R_ in mats]
    res = gf.imm_filter(models, gf.Gaussian(m0, P0), zs, Pi, mode_probs=mu0)
    np.testing.assert_allclose(res.means, [r[0] for r in ref], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(res.covs, [r[1] for r in ref], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(res.mode_probs, [r[2] for r in ref], rtol=1e-10, atol=1e-12)
    assert res.loglik == pytest.approx(ref_loglik, rel=1e-10)
    # The combined belief is the moment-matched mixture of the mode-matched ones.
    for k in range(T):
        w = res.mode_probs[k]
        mean = w @ res.mode_means[k]
        d = res.mode_means[k] - mean
        cov = np.einsum("j,jab->ab", w, res.mode_covs[k]) + (d * w[:, None]).T @ d
        np.testing.assert_allclose(res.means[k], mean, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(res.covs[k], cov, rtol=1e-12, atol=1e-12)


def test_identical_models_and_missing_measurements():
    model = gf.constant_velocity(dt=1.0, q=0.5, r=2.0)
    prior = gf.Gaussian([0.0, 1.0], np.eye(2))
    zs = [1.1, np.nan, 2.8, 4.1]
    ref = gf.filter(model, prior, zs)
    Pi = [[0.9, 0.1], [0.4, 0.6]]
    res = gf.imm_filter([model, model], prior, zs, Pi, mode_probs=[0.25, 0.75])
    # Identical modes: the IMM is the model's filter, and the mode probabilities
    # only follow the Markov chain (equal likelihoods; nothing at all at step 1).
    np.testing.assert_allclose(res.means, ref.means, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(res.covs, ref.covs, rtol=1e-12, atol=1e-12)
    assert res.loglik == pytest.approx(ref.loglik, rel=1e-12)
    mu = np.array([0.25, 0.75])
    for k in range(4):
        mu = mu @ np.array(Pi)
        np.testing.assert_allclose(res.mode_probs[k], mu, rtol=1e-12)


def test_result_is_immutable():
    model = gf.constant_velocity(dt=1.0, q=0.5, r=2.0)
    res = gf.imm_filter([model, model], gf.Gaussian([0.0, 1.0], np.eye(2)), [1.0, 2.0], np.eye(2))
    assert isinstance(res, gf.IMMResult)
    assert res.means.shape == (2, 2) and res.covs.shape == (2, 2, 2) and res.mode_probs.shape == (2, 2)
    assert res.mode_means.shape == (2, 2, 2) and res.mode_covs.shape == (2, 2, 2, 2)
    with pytest.raises(AttributeError):
        res.loglik = 0.0
    with pytest.raises(ValueError):
        res.mode_probs[0, 0] = 0.5


# ---------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------


def _call(**changes):
    model = gf.constant_velocity(dt=1.0, q=0.5, r=2.0)
    args = dict(models=[model, model], prior=gf.Gaussian([0.0, 1.0], np.eye(2)), zs=[1.0, 2.0],
                transition=[[0.9, 0.1], [0.2, 0.8]])
    args.update(changes)
    return gf.imm_filter(**args)


_CV = gf.constant_velocity(dt=1.0, q=0.5, r=2.0)
_CV2 = gf.constant_velocity(dt=1.0, q=0.5, r=2.0, dim=2)
_NL = gf.NonlinearModel(lambda x: x, lambda x: x[:1], np.eye(2), 1.0, state_angles=[1])


@pytest.mark.parametrize("changes, error, message", [
    (dict(models=[]), TypeError,
     "`models` must be a non-empty sequence (list or tuple) of LinearModel or NonlinearModel; got list."),
    (dict(models=_CV), TypeError,
     "`models` must be a non-empty sequence (list or tuple) of LinearModel or NonlinearModel; got LinearModel."),
    (dict(models=[_CV, "ct"]), TypeError, "`models[1]` must be a LinearModel or NonlinearModel; got str."),
    (dict(models=[_CV, _CV2]), ValueError, "`models` must all have the same state dimension n; got n = [2, 4]."),
    (dict(models=[_CV, gf.LinearModel(np.eye(2), np.eye(2), np.eye(2), np.eye(2))]), ValueError,
     "`models` must all have the same measurement dimension m; got m = [1, 2]."),
    (dict(models=[_CV, _NL]), ValueError,
     "`models` must agree on which state components are angles (they are mixed); "
     "got state_angles = [[], [1]]."),
    (dict(prior=gf.Gaussian(0.0, 1.0)), ValueError, "`prior` must have dimension 2 (the model's state); got 1."),
    (dict(zs=[[1.0, 2.0]]), ValueError, "`zs` must have shape (T, 1) or (T,) (one series), with T >= 1; got shape (1, 2)."),
    (dict(zs=np.ones((2, 3, 1))), ValueError, "`zs` must have shape (T, 1) or (T,) (one series), with T >= 1; got shape (2, 3, 1)."),
    (dict(transition=[0.5, 0.5]), ValueError,
     "`transition` must be a probability Markov matrix (one row and column per model) of shape (2, 2); "
     "got shape (2,)."),
    (dict(transition=[[1.1, -0.1], [0.5, 0.5]]), ValueError,
     "`transition` must be non-negative; got -0.1 at index (0, 1)."),
    (dict(transition=[[0.9, 0.2], [0.5, 0.5]]), ValueError,
     "the rows of `transition` must sum to 1; row 0 sums to 1.1."),
    (dict(transition=[[0.9, np.nan], [0.5, 0.5]]), ValueError,
     "`transition` must be finite; got a non-finite (NaN or inf) value at index (0, 1)."),
    (dict(mode_probs=[1.0, 0.0, 0.0]), ValueError,
     "`mode_probs` must be a probability vector (one per model) of shape (2,); got shape (3,)."),
    (dict(mode_probs=[0.5, 0.6]), ValueError, "`mode_probs` must sum to 1; it sums to 1.1."),
    (dict(us=[0.0, 1.0]), ValueError,
     "in `models[0]`: `us` was given but the model has no control input; give the model `B`."),
    (dict(models=[gf.LinearModel(_CV.F, _CV.H, _CV.Q, _CV.R, B=[[0.5], [1.0]]), _CV], us=[[0.0], [1.0]]), ValueError,
     "in `models[1]`: `us` was given but the model has no control input; give the model `B`."),
    (dict(models=[gf.LinearModel(_CV.F, _CV.H, _CV.Q, _CV.R, B=[[0.5], [1.0]])] * 2, us=[[0.0], [np.nan]]),
     ValueError, "`us` must be finite; got a non-finite (NaN or inf) value at index (1, 0)."),
    (dict(models=[gf.LinearModel(_CV.F, _CV.H, _CV.Q, _CV.R, B=[[0.5, 0.0], [1.0, 0.0]]),
                  gf.LinearModel(_CV.F, _CV.H, _CV.Q, _CV.R, B=[[0.5], [1.0]])], us=np.zeros((2, 2))), ValueError,
     "in `models[1]`: `us` must have shape (T, p) = (2, 1)"),
    (dict(zs=[[1.0], [2.0, 3.0]]), TypeError, "`zs` must be a rectangular array of real numbers; got rows of "
                                              "different lengths"),
    (dict(zs=np.ones((0, 1))), ValueError, "`zs` must have shape (T, 1) or (T,) (one series), with T >= 1; "
                                           "got shape (0, 1)."),
    (dict(method="foo"), ValueError, "`method` must be one of"),
    (dict(alpha=0.5), TypeError, "unknown option(s) ['alpha'] for method 'kf'; valid options are none."),
    (dict(models=[_CV, gf.LinearModel(np.stack([np.eye(2)] * 3), [1.0, 0.0], np.eye(2), 1.0)]), ValueError,
     "in `models[1]`: the model is time-varying over 3 steps but `zs` has 2 steps; they must agree."),  # (AA2)
])
def test_validation(changes, error, message):
    with pytest.raises(error, match=re.escape(message)):
        _call(**changes)


def test_mixed_linear_and_nonlinear_models():
    # A LinearModel among NonlinearModels is always filtered exactly; `method` is for the others.
    cv, ct = _models()
    states, _ = _truth()
    zs = states[:20, :2]
    ukf = gf.imm_filter([cv, ct], _prior(), zs, SWITCH, alpha=0.5)
    assert np.all(np.isfinite(ukf.means))
    with pytest.raises(TypeError, match=re.escape("method 'kf' does not apply to a NonlinearModel")):
        gf.imm_filter([cv, ct], _prior(), zs, SWITCH, method="kf")
    bad = gf.NonlinearModel(lambda x: x[:2], lambda x: x[:2], np.eye(5), R * np.eye(2))
    with pytest.raises(ValueError, match=re.escape("at step 0, in `models[1]`: `f` must return shape (5,)")):
        gf.imm_filter([cv, bad], _prior(), zs, SWITCH, method="ekf")


def test_docstring_examples():
    result = doctest.testmod(gaussfuse.imm, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def test_an_overflow_is_the_filters_error_without_numpy_warnings_first():
    """z = 1e200: gf.filter raises FloatingPointError with no warning; the IMM printed three RuntimeWarnings first
    (and, with warnings as errors, raised one of them instead)."""
    m1, m2 = gf.LinearModel(F=1.0, H=1.0, Q=0.01, R=1e-6), gf.LinearModel(F=1.0, H=1.0, Q=0.1, R=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FloatingPointError, match=r"at step 1, in `models\[0\]`: .*overflowed"):
            gf.imm_filter([m1, m2], gf.Gaussian([0.0], [[1.0]]), [0.0, 1e200, 0.0],
                          transition=[[0.9, 0.1], [0.1, 0.9]])



def test_imm_zs_shape_and_method_on_linear_models():
    """The zs message offered (N, T, 1) for N series, which imm_filter then refused; method="ukf" with only
    LinearModels raised, though they are always exact ("kf")."""
    A = gf.constant_velocity(dt=1.0, q=0.01, r=1.0)
    B = gf.constant_velocity(dt=1.0, q=10.0, r=1.0)
    T, prior = [[0.95, 0.05], [0.05, 0.95]], gf.Gaussian([0.0, 1.0], np.eye(2))
    for zs in ([[1.0, 2.0]], np.ones((1, 3, 1))):
        with pytest.raises(ValueError, match=r"^`zs` must have shape \(T, 1\) or \(T,\) \(one series\), with T >= 1; got shape"):
            gf.imm_filter([A, B], prior, zs, T)
    zs = np.sin(np.arange(20.0))
    np.testing.assert_array_equal(gf.imm_filter([A, B], prior, zs, T, method="ukf").means,
                                  gf.imm_filter([A, B], prior, zs, T).means)


def test_a_mode_far_behind_comes_back_without_mixing():
    """Mode probabilities were carried as plain numbers: a mode 748 nats behind became exactly 0 and, with no
    other mode switching into it (identity transition), never came back (mean 7.76 for 27.95, loglik -1.0e9)."""
    still = gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[1e-8]], R=[[1e-6]])
    loose = gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[1.0]], R=[[1.0]])
    prior = gf.Gaussian([0.0], [[1.0]])
    zs = np.r_[np.zeros(120), 30.0, 31.0, 29.0]
    res = gf.imm_filter([still, loose], prior, zs, transition=np.eye(2))
    # With no switching the posterior is exactly the two filters weighted by prior x likelihood, step by step.
    runs = [gf.filter(model, prior, zs) for model in (still, loose)]
    logliks = np.array([r.loglik for r in runs])
    assert res.loglik == pytest.approx(np.logaddexp(*logliks) + np.log(0.5), rel=1e-12)
    cumulative = np.cumsum([_step_logliks(model, prior, zs) for model in (still, loose)], axis=1).T
    expected = np.exp(cumulative - np.logaddexp(cumulative[:, :1], cumulative[:, 1:]))
    np.testing.assert_allclose(res.mode_probs, expected, rtol=1e-9, atol=1e-300)
    assert res.mode_probs[101, 1] < 1e-300 and res.mode_probs[-1, 1] == pytest.approx(1.0, abs=1e-12)
    mean = (expected[-1, 0] * runs[0].means[-1] + expected[-1, 1] * runs[1].means[-1])[0]
    assert res.means[-1, 0] == pytest.approx(mean, rel=1e-12)


def _step_logliks(model, prior, zs):
    """Each step's log p(z_k | z_1..z_{k-1}) of one model's filter."""
    return np.diff([0.0] + [gf.filter(model, prior, zs[:k + 1]).loglik for k in range(len(zs))])


def test_options_are_checked_when_every_model_is_linear():
    """method="ukf" on LinearModels only (exact) took any option silently, even bogus_option=3."""
    A = gf.constant_velocity(dt=1.0, q=0.01, r=1.0)
    prior, zs = gf.Gaussian([0.0, 1.0], np.eye(2)), [1.0, 2.0]
    with pytest.raises(TypeError, match=re.escape("unknown option(s) ['bogus_option'] for method 'ukf'")):
        gf.imm_filter([A, A], prior, zs, np.eye(2), method="ukf", alpha=0.5, bogus_option=3)
    with pytest.raises(ValueError, match=re.escape("`alpha`")):
        gf.imm_filter([A, A], prior, zs, np.eye(2), method="ukf", alpha=-1.0)
    with pytest.raises(ValueError, match=re.escape("`method` must be one of")):
        gf.imm_filter([A, A], prior, zs, np.eye(2), method="ufk")
    np.testing.assert_array_equal(gf.imm_filter([A, A], prior, zs, np.eye(2), method="ukf", alpha=0.5).means,
                                  gf.imm_filter([A, A], prior, zs, np.eye(2)).means)


def test_a_mode_the_measurement_contradicts_drops_out():
    """A mode with Q = R = 0 knows the state exactly after one update; a second measurement that differs made the
    whole filter raise (S singular). Its likelihood is 0: with no switching the answer is the other mode's filter,
    weighted by the prior's 1/2. Where every mode is contradicted, or z lies on a singular S's range, it raises."""
    exact = gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[0.0]], R=[[0.0]])
    loose = gf.LinearModel(F=[[1.0]], H=[[1.0]], Q=[[1.0]], R=[[1.0]])
    prior, zs = gf.Gaussian([0.0], [[1.0]]), [0.5, 0.7, 0.9]
    res = gf.imm_filter([exact, loose], prior, zs, transition=np.eye(2))
    alone = gf.filter(loose, prior, zs)
    np.testing.assert_allclose(res.mode_probs[1:], [[0.0, 1.0], [0.0, 1.0]], atol=1e-300)
    np.testing.assert_allclose(res.means[1:], alone.means[1:], rtol=1e-14)
    np.testing.assert_allclose(res.covs[1:], alone.covs[1:], rtol=1e-14)
    assert res.loglik == pytest.approx(alone.loglik + np.log(0.5), rel=1e-14)
    with pytest.raises(np.linalg.LinAlgError, match=r"at step 1: the measurement is impossible under every model"):
        gf.imm_filter([exact, exact], prior, zs, transition=np.eye(2))
    with pytest.raises(np.linalg.LinAlgError, match=r"at step 1, in `models\[0\]`: the innovation covariance"):
        gf.imm_filter([exact, loose], prior, [0.5, 0.5], transition=np.eye(2))
