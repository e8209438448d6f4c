"""Motion models: constant velocity and constant acceleration."""

from __future__ import annotations

import warnings

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
        ({"dt": 0.0}, ValueError, r"^`dt` must be a positive number; got 0\.0\.$"),
        ({"dt": -0.1}, ValueError, r"^`dt` must be a positive number; got -0\.1\.$"),
        ({"dt": np.nan}, ValueError, r"^`dt` must be a positive number; got nan\.$"),
        ({"dt": np.inf}, ValueError, r"^`dt` must be a positive number; got inf\.$"),
        ({"dt": "fast"}, TypeError, r"^`dt` must be a positive number; got 'fast'\.$"),
        ({"dt": None}, TypeError, r"^`dt` must be a positive number; got None\.$"),
        ({"q": -1.0}, ValueError, r"^`q` must be a non-negative number; got -1\.0\.$"),
        ({"q": [1.0, 2.0]}, TypeError, r"^`q` must be a non-negative number; got \[1\.0, 2\.0\]\.$"),
        ({"r": -2.0}, ValueError, r"^`r` must be a non-negative number; got -2\.0\.$"),
        ({"dim": 0}, ValueError, r"^`dim` must be 1, 2 or 3; got 0\.$"),
        ({"dim": 4}, ValueError, r"^`dim` must be 1, 2 or 3; got 4\.$"),
        # (not an integer: a TypeError, as `dt`'s "fast" and every integer argument's; audit VV4)
        ({"dim": 2.0}, TypeError, r"^`dim` must be an integer 1, 2 or 3; got 2\.0 \(float\)\.$"),
        ({"dim": "2"}, TypeError, r"^`dim` must be an integer 1, 2 or 3; got '2' \(str\)\.$"),
        ({"dim": True}, TypeError, r"^`dim` must be an integer 1, 2 or 3; got True \(bool\)\.$"),
    ],
)
def test_invalid_arguments(make, kwargs, error, match):
    with pytest.raises(error, match=match):
        make(**({"dt": 0.1, "q": 1.0, "r": 1.0, "dim": 2} | kwargs))


# ---------------------------------------------------------------------------
# Motion classes
# ---------------------------------------------------------------------------

from math import factorial  # noqa: E402

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from gaussfuse.linearize.taylor import complex_step_jacobian, jacobian  # noqa: E402
from gaussfuse.models import motion as motion_module  # noqa: E402
from gaussfuse.models import noise as noise_module  # noqa: E402


def linear_motions():
    """One of each linear motion, with non-trivial settings."""
    return [
        gf.ConstantPosition(dim=2, q=0.3),
        gf.ConstantPosition(dim=1, q=0.3, noise="piecewise"),
        gf.ConstantVelocity(dim=3, q=0.7),
        gf.ConstantVelocity(dim=2, q=0.7, noise="piecewise"),
        gf.ConstantAcceleration(dim=2, q=1.1),
        gf.ConstantAcceleration(dim=1, q=1.1, noise="piecewise"),
        gf.ForceInput(q=0.2, dim=2),
        gf.Singer(dim=2, tau=3.0, sigma=0.8),
        gf.RandomWalk(n=3, q=0.4),
        gf.LocalLevel(q=2.0),
        gf.LocalLinearTrend(q_level=1.5, q_slope=0.25),
        gf.LinearSDE([[0, 1], [-4, -0.4]], [0, 1], 0.1, names=("x", "v")),
    ]


LINEAR_IDS = ["cp", "cp-pw", "cv", "cv-pw", "ca", "ca-pw", "force", "singer", "rw", "level", "trend", "sde"]


def assert_covariance(Q: np.ndarray, n: int) -> None:
    assert Q.shape == (n, n)
    np.testing.assert_array_equal(Q, Q.T)
    scale = max(np.max(np.abs(Q)), 1e-300)
    assert np.min(np.linalg.eigvalsh(Q)) >= -1e-12 * scale


@pytest.mark.parametrize("motion", linear_motions(), ids=LINEAR_IDS)
@pytest.mark.parametrize("dt", [0.05, 1.0, 3.0])
def test_linear_motion_transition_shapes_symmetry_psd(motion, dt):
    assert isinstance(motion, gf.LinearMotion)
    F, Q = motion.transition(dt)
    n = motion.n
    assert F.shape == (n, n)
    assert np.all(np.isfinite(F))
    assert_covariance(Q, n)
    assert np.max(np.abs(Q)) > 0  # every motion above has process noise
    assert len(motion.names) == n and len(set(motion.names)) == n
    assert all(isinstance(s, str) for s in motion.names)
    assert motion.state_angles == ()
    B = motion.control(dt)
    assert B is None or B.shape[0] == n


@pytest.mark.parametrize("motion", linear_motions(), ids=LINEAR_IDS)
@pytest.mark.parametrize(
    ("dt", "error", "match"),
    [
        (0.0, ValueError, r"^`dt` must be a positive number; got 0\.0\.$"),
        (-1.0, ValueError, r"^`dt` must be a positive number; got -1\.0\.$"),
        (np.nan, ValueError, r"^`dt` must be a positive number; got nan\.$"),
        ("1", TypeError, r"^`dt` must be a positive number; got '1'\.$"),
        (None, TypeError, r"^`dt` must be a positive number; got None\.$"),
    ],
)
def test_linear_motion_dt_validation(motion, dt, error, match):
    with pytest.raises(error, match=match):
        motion.transition(dt)
    with pytest.raises(error, match=match):
        motion.control(dt)


@pytest.mark.parametrize("motion", linear_motions() + [gf.CoordinatedTurn()], ids=LINEAR_IDS + ["ct"])
def test_motions_are_immutable(motion):
    name = motion._fields()[0]
    with pytest.raises(AttributeError, match="is immutable"):
        setattr(motion, name, 1.0)
    with pytest.raises(AttributeError, match="is immutable"):
        motion.other = 1.0
    with pytest.raises(AttributeError, match="is immutable"):
        delattr(motion, name)


def test_linear_sde_arrays_are_read_only_and_copied():
    A = np.array([[0.0, 1.0], [-1.0, 0.0]])
    sde = gf.LinearSDE(A, [0, 1], 1.0)
    A[0, 0] = 5.0  # the model keeps its own copy
    assert sde.A[0, 0] == 0.0
    for arr in (sde.A, sde.L, sde.Qc):
        with pytest.raises(ValueError, match="read-only"):
            arr[0, 0] = 1.0


def test_motions_pickle_and_repr():
    import pickle

    for motion in linear_motions() + [gf.CoordinatedTurn(q_acc=2.0, q_turn=0.5)]:
        back = pickle.loads(pickle.dumps(motion))
        assert type(back) is type(motion)
        for f1, f2 in zip(motion.transition(0.5) if isinstance(motion, gf.LinearMotion) else (motion.noise(0.5),),
                          back.transition(0.5) if isinstance(back, gf.LinearMotion) else (back.noise(0.5),)):
            np.testing.assert_array_equal(f1, f2)
    assert repr(gf.ConstantVelocity(dim=2, q=0.5)) == "ConstantVelocity(dim=2, q=0.5, noise='continuous')"
    assert repr(gf.ForceInput(q=0.1)) == "ForceInput(q=0.1, dim=1)"


# -- the integrated white-noise family ---------------------------------------


def kinematic_F(order: int, dt: float) -> np.ndarray:
    return np.array([[dt ** (j - i) / factorial(j - i) if j >= i else 0.0
                      for j in range(order + 1)] for i in range(order + 1)])


def piecewise_axis(order: int, dt: float, var: float) -> np.ndarray:
    g = np.array([dt ** (order + 1 - i) / factorial(order + 1 - i) for i in range(order + 1)])
    return var * np.outer(g, g)


def continuous_axis(order: int, dt: float, q: float) -> np.ndarray:
    return {0: lambda: np.array([[q * dt]]), 1: lambda: cv_axis(dt, q)[1], 2: lambda: ca_axis(dt, q)[1]}[order]()


@pytest.mark.parametrize(("cls", "order"), [(gf.ConstantPosition, 0), (gf.ConstantVelocity, 1),
                                             (gf.ConstantAcceleration, 2)], ids=["cp", "cv", "ca"])
@pytest.mark.parametrize("noise", ["continuous", "piecewise"])
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("dt", [0.1, 2.5])
def test_integrated_white_noise_matrices(cls, order, noise, dim, dt):
    q = 0.7
    motion = cls(dim=dim, q=q, noise=noise)
    assert motion.n == (order + 1) * dim
    assert motion.names == tuple(motion_module.state_names(order, dim))
    F, Q = motion.transition(dt)
    F1 = kinematic_F(order, dt)
    Q1 = continuous_axis(order, dt, q) if noise == "continuous" else piecewise_axis(order, dt, q)
    for a in range(dim):
        for b in range(dim):
            expected_F, expected_Q = (F1, Q1) if a == b else (0.0 * F1, 0.0 * Q1)
            np.testing.assert_allclose(axis_block(F, order, dim, a, b), expected_F, rtol=1e-14, atol=0)
            np.testing.assert_allclose(axis_block(Q, order, dim, a, b), expected_Q, rtol=1e-14, atol=0)
    assert motion.control(dt) is None


def test_names_of_kinematic_states():
    assert gf.ConstantVelocity(dim=2).names == ("x", "y", "vx", "vy")
    assert gf.ConstantAcceleration(dim=3).names == ("x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az")
    assert gf.ConstantPosition(dim=1).names == ("x",)
    assert gf.ForceInput(dim=2).names == ("x", "y", "vx", "vy")
    assert gf.Singer(dim=1).names == ("x", "vx", "ax")
    assert gf.RandomWalk(n=2).names == ("x0", "x1")
    assert gf.LocalLevel().names == ("level",)
    assert gf.LocalLinearTrend().names == ("level", "slope")
    assert gf.LinearSDE(np.zeros((2, 2)), np.eye(2), np.eye(2)).names == ("x0", "x1")
    assert gf.CoordinatedTurn().names == ("x", "y", "vx", "vy", "omega")


@pytest.mark.parametrize(("make", "cls"), [(gf.constant_velocity, gf.ConstantVelocity),
                                           (gf.constant_acceleration, gf.ConstantAcceleration)], ids=CASE_IDS)
@pytest.mark.parametrize("dim", DIMS)
def test_one_call_models_are_the_motion_classes(make, cls, dim):
    dt, q, r = 0.3, 0.9, 0.2
    model = make(dt=dt, q=q, r=r, dim=dim)
    F, Q = cls(dim=dim, q=q).transition(dt)
    np.testing.assert_array_equal(model.F, F)
    np.testing.assert_array_equal(model.Q, Q)


# -- ForceInput ----------------------------------------------------------------


@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("dt", [0.1, 0.5, 2.0])
def test_force_input_matrices(dim, dt):
    q = 0.3
    motion = gf.ForceInput(q=q, dim=dim)
    F, Q = motion.transition(dt)
    B = motion.control(dt)
    assert motion.n == 2 * dim
    assert B.shape == (2 * dim, dim)
    for a in range(dim):
        np.testing.assert_allclose(axis_block(F, 1, dim, a, a), [[1.0, dt], [0.0, 1.0]], rtol=1e-15)
        np.testing.assert_allclose(B[[a, dim + a], a], [dt**2 / 2, dt], rtol=1e-15)
        np.testing.assert_allclose(axis_block(Q, 1, dim, a, a),
                                   q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]]), rtol=1e-14)
    # Each force component acts on its own axis only.
    np.testing.assert_array_equal(np.count_nonzero(B, axis=0), 2)
    # Default: no process noise.
    np.testing.assert_array_equal(gf.ForceInput(dim=dim).transition(dt)[1], 0.0)


def test_force_input_filter_reproduces_exact_kinematics():
    """q = 0, an exactly known start and noise-free positions: the filter follows the physics exactly."""
    dt, T, mass = 0.1, 200, 2.5
    t = dt * np.arange(1, T + 1)
    rng = np.random.default_rng(4)
    # A piecewise-constant force on each axis, changing every 20 steps.
    force = np.repeat(rng.normal(scale=3.0, size=(T // 20, 2)), 20, axis=0)
    acc = force / mass
    x0, v0 = np.array([1.0, -2.0]), np.array([0.5, 0.25])
    # Exact kinematics, integrated per piece in closed form.
    pos, vel = np.empty((T, 2)), np.empty((T, 2))
    p, v = x0.copy(), v0.copy()
    for k in range(T):
        p = p + v * dt + 0.5 * acc[k] * dt**2
        v = v + acc[k] * dt
        pos[k], vel[k] = p, v
    motion = gf.ForceInput(q=0.0, dim=2)
    model = gf.model(motion, gf.Position(dim=2, r=1e-4), dt)
    assert isinstance(model, gf.LinearModel) and model.p == 2
    prior = gf.Gaussian(np.r_[x0, v0], np.zeros((4, 4)))
    res = gf.filter(model, prior, pos, us=acc)
    np.testing.assert_allclose(res.means[:, :2], pos, rtol=0, atol=1e-10)
    np.testing.assert_allclose(res.means[:, 2:], vel, rtol=0, atol=1e-10)
    np.testing.assert_allclose(res.innovations, 0.0, atol=1e-10)
    # Sanity: the same physics at the step ends, t_k = k dt, from the closed form x0 + v0 t + ½ a t².
    first = t[:20]
    np.testing.assert_allclose(res.means[:20, :2], x0 + v0 * first[:, None] + 0.5 * acc[0] * first[:, None] ** 2,
                               rtol=0, atol=1e-10)


def test_force_input_filter_with_noise_recovers_the_track():
    """With an uncertain start the filter locks onto perfect measurements of a forced mass."""
    dt, T = 0.05, 100
    acc = np.tile([[1.0, -0.5]], (T, 1))
    t = dt * np.arange(1, T + 1)[:, None]
    pos = 0.5 * acc * t**2
    model = gf.model(gf.ForceInput(q=0.0, dim=2), gf.Position(dim=2, r=1e-6), dt)
    res = gf.filter(model, gf.Gaussian(np.zeros(4) + 1.0, np.eye(4)), pos, us=acc)
    np.testing.assert_allclose(res.means[-1], np.r_[pos[-1], acc[-1] * t[-1]], atol=1e-3)


# -- Singer -----------------------------------------------------------------


@pytest.mark.parametrize("tau", [0.2, 1.0, 7.0])
@pytest.mark.parametrize("dt", [0.1, 1.0, 3.0])
def test_singer_transition_closed_form(tau, dt):
    motion = gf.Singer(dim=2, tau=tau, sigma=1.5)
    F, Q = motion.transition(dt)
    e = np.exp(-dt / tau)
    F1 = np.array([[1.0, dt, tau**2 * (e - 1 + dt / tau)], [0.0, 1.0, tau * (1 - e)], [0.0, 0.0, e]])
    for a in range(2):
        np.testing.assert_allclose(axis_block(F, 2, 2, a, a), F1, rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(axis_block(Q, 2, 2, a, 1 - a), 0.0)
    assert_covariance(Q, 6)
    # Numerical integration of the SDE's noise, independent of Van Loan.
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0 / tau]])
    Qc = 2 * 1.5**2 / tau

    def integrand(s):
        E = expm(A * s)
        return Qc * np.outer(E[:, 2], E[:, 2])

    ref, _ = quad_vec(integrand, 0.0, dt, epsabs=1e-15, epsrel=1e-13)
    np.testing.assert_allclose(axis_block(Q, 2, 2, 0, 0), ref, rtol=0, atol=1e-10 * np.max(np.abs(ref)))


def test_singer_stationary_acceleration_variance():
    """Over a long step the acceleration forgets its start: Q_aa → sigma² (the stationary variance)."""
    motion = gf.Singer(tau=0.5, sigma=2.0)
    F, Q = motion.transition(50.0)
    np.testing.assert_allclose(Q[2, 2], 4.0, rtol=1e-12)
    assert F[2, 2] < 1e-40


@pytest.mark.parametrize("dt", [0.5, 2.0])
def test_singer_tends_to_constant_acceleration_for_long_tau(dt):
    """tau → ∞ with 2σ²/τ = q fixed: the acceleration becomes a Wiener process (CA with jerk density q)."""
    q = 0.8
    F_ca, Q_ca = gf.ConstantAcceleration(q=q).transition(dt)
    errors = []
    for tau in [1e2, 1e3, 1e4, 1e5, 1e6]:
        F, Q = gf.Singer(tau=tau, sigma=np.sqrt(q * tau / 2)).transition(dt)
        errors.append(max(np.max(np.abs(F - F_ca)), np.max(np.abs(Q - Q_ca) / np.max(np.abs(Q_ca)))))
    assert errors[-1] < 1e-5
    assert all(e2 < 0.2 * e1 for e1, e2 in zip(errors, errors[1:]))  # O(dt / tau)
    assert_covariance(Q, 3)


@pytest.mark.parametrize("dt", [0.5, 2.0])
def test_singer_tends_to_constant_velocity_for_short_tau(dt):
    """tau → 0 with 2σ²τ = q fixed: the acceleration becomes white noise of density q (CV)."""
    q = 0.8
    F_cv, Q_cv = gf.ConstantVelocity(q=q).transition(dt)
    errors = []
    for tau in [1e-2, 1e-3, 1e-4, 1e-5]:
        F, Q = gf.Singer(tau=tau, sigma=np.sqrt(q / (2 * tau))).transition(dt)
        pv = np.ix_([0, 1], [0, 1])
        errors.append(max(np.max(np.abs(F[pv] - F_cv)), np.max(np.abs(Q[pv] - Q_cv)) / np.max(Q_cv)))
    assert errors[-1] < 1e-4
    assert all(e2 < 0.2 * e1 for e1, e2 in zip(errors, errors[1:]))  # O(tau / dt)


# -- random walk, local level / trend, linear SDE ---------------------------------


def test_random_walk_and_structural_models():
    F, Q = gf.RandomWalk(n=3, q=0.5).transition(2.0)
    np.testing.assert_array_equal(F, np.eye(3))
    np.testing.assert_array_equal(Q, np.eye(3))
    F, Q = gf.LocalLevel(q=3.0).transition(1)
    np.testing.assert_array_equal(F, [[1.0]])
    np.testing.assert_array_equal(Q, [[3.0]])
    np.testing.assert_array_equal(gf.LocalLevel(q=3.0).transition(2)[1], [[6.0]])
    F, Q = gf.LocalLinearTrend(q_level=2.0, q_slope=0.5).transition(3.0)
    np.testing.assert_array_equal(F, [[1.0, 3.0], [0.0, 1.0]])
    np.testing.assert_array_equal(Q, [[8.5, 1.5], [1.5, 1.5]])  # three steps (see the test below)


def test_local_level_matches_the_nile_model_by_hand():
    """The local-level model with the Nile's fitted variances gives the textbook filter's first steps."""
    model = gf.model(gf.LocalLevel(q=1469.1), gf.LinearSensor([[1.0]], 15099.0), 1)
    assert isinstance(model, gf.LinearModel)
    res = gf.filter(model, gf.Gaussian([1120.0], [[1e7]]), np.array([1120.0, 1160.0]))
    # One scalar Kalman step by hand.
    P = 1e7 + 1469.1
    K = P / (P + 15099.0)
    a1, P1 = 1120.0, (1 - K) * P
    P2 = P1 + 1469.1
    a2 = a1 + P2 / (P2 + 15099.0) * (1160.0 - a1)
    np.testing.assert_allclose(res.means[:, 0], [a1, a2], rtol=1e-12)


def test_linear_sde_is_van_loan():
    A = [[0.0, 1.0], [-4.0, -0.4]]
    sde = gf.LinearSDE(A, [0, 1], 0.1)
    F, Q = sde.transition(0.7)
    F2, Q2 = gf.van_loan(A, [0, 1], 0.1, 0.7)
    np.testing.assert_array_equal(F, F2)
    np.testing.assert_array_equal(Q, Q2)
    np.testing.assert_allclose(F, expm(np.array(A) * 0.7), rtol=1e-12)
    # The Singer model is a linear SDE.
    singer = gf.Singer(tau=2.0, sigma=0.5)
    as_sde = gf.LinearSDE([[0, 1, 0], [0, 0, 1], [0, 0, -0.5]], [0, 0, 1], 2 * 0.25 / 2.0)
    for M1, M2 in zip(singer.transition(1.3), as_sde.transition(1.3)):
        np.testing.assert_allclose(M1, M2, rtol=1e-15, atol=1e-15)


# -- constructor validation ----------------------------------------------------------


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (lambda: gf.ConstantVelocity(dim=4), ValueError, r"^`dim` must be 1, 2 or 3; got 4\.$"),
        (lambda: gf.ConstantPosition(q=-1), ValueError, r"^`q` must be a non-negative number; got -1\.0\.$"),
        (lambda: gf.ConstantAcceleration(noise="white"), ValueError,
         r"^`noise` must be 'continuous' or 'piecewise'; got 'white'\.$"),
        (lambda: gf.ConstantVelocity(noise=None), ValueError,
         r"^`noise` must be 'continuous' or 'piecewise'; got None\.$"),
        (lambda: gf.ForceInput(q="0"), TypeError, r"^`q` must be a non-negative number; got '0'\.$"),
        (lambda: gf.ForceInput(dim=0), ValueError, r"^`dim` must be 1, 2 or 3; got 0\.$"),
        (lambda: gf.Singer(tau=0.0), ValueError, r"^`tau` must be a positive number; got 0\.0\.$"),
        (lambda: gf.Singer(sigma=-1.0), ValueError, r"^`sigma` must be a non-negative number; got -1\.0\.$"),
        (lambda: gf.Singer(tau=np.inf), ValueError, r"^`tau` must be a positive number; got inf\.$"),
        (lambda: gf.RandomWalk(n=0), ValueError, r"^`n` must be a positive integer; got 0\.$"),
        (lambda: gf.RandomWalk(n=2.0), TypeError, r"^`n` must be a positive integer; got 2\.0\.$"),
        (lambda: gf.RandomWalk(q=np.nan), ValueError, r"^`q` must be a non-negative number; got nan\.$"),
        (lambda: gf.LocalLevel(q=-0.1), ValueError, r"^`q` must be a non-negative number; got -0\.1\.$"),
        (lambda: gf.LocalLinearTrend(q_slope=-1), ValueError, r"^`q_slope` must be a non-negative number; got -1\.0\.$"),
        (lambda: gf.LocalLinearTrend(q_level=[1]), TypeError, r"^`q_level` must be a non-negative number; got \[1\]\.$"),
        (lambda: gf.LinearSDE([[0, 1]], [0, 1], 1.0), ValueError, r"^`A` must be square"),
        (lambda: gf.LinearSDE(np.eye(2), [1, 0, 0], 1.0), ValueError, r"^`L` must have shape \(2, s\)"),
        (lambda: gf.LinearSDE(np.eye(2), np.eye(2), [[1, 0], [0, -1]]), ValueError,
         r"^`Qc` must be positive semi-definite"),
        (lambda: gf.LinearSDE(np.eye(2), [0, 1], 1.0, names=("a",)), ValueError,
         r"^`names` must have 2 entries, one per component; got 1\.$"),
        (lambda: gf.LinearSDE(np.eye(2), [0, 1], 1.0, names="ab"), TypeError,
         r"^`names` must be a sequence of 2 strings; got 'ab'\.$"),
        (lambda: gf.LinearSDE(np.eye(2), [0, 1], 1.0, names=("a", 1)), TypeError,
         r"^`names` must be a sequence of 2 strings; got \('a', 1\)\.$"),
        (lambda: gf.CoordinatedTurn(q_acc=-1.0), ValueError, r"^`q_acc` must be a non-negative number; got -1\.0\.$"),
        (lambda: gf.CoordinatedTurn(q_turn=None), TypeError, r"^`q_turn` must be a non-negative number; got None\.$"),
    ],
)
def test_motion_constructor_validation(make, error, match):
    with pytest.raises(error, match=match):
        make()


# ---------------------------------------------------------------------------
# Coordinated turn
# ---------------------------------------------------------------------------


def turn_ode(t, s):
    x, y, vx, vy, w = s
    return [vx, vy, -w * vy, w * vx, 0.0]


OMEGAS = [0.0, 1e-12, 1e-7, 1e-3, 0.05, 0.0999, 0.1, 0.1001, 0.7, -1.3, 3.0]


@pytest.mark.parametrize("omega", OMEGAS)
@pytest.mark.parametrize("dt", [0.5, 2.0])
def test_coordinated_turn_solves_the_turn_ode(omega, dt):
    ct = gf.CoordinatedTurn()
    x0 = np.array([10.0, -5.0, 3.0, 4.0, omega])
    sol = solve_ivp(turn_ode, (0.0, dt), x0, method="DOP853", rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(ct.f(x0, dt), sol.y[:, -1], rtol=0, atol=1e-9)
    # Speed is conserved and the heading turns by ω dt.
    out = ct.f(x0, dt)
    np.testing.assert_allclose(np.hypot(out[2], out[3]), 5.0, rtol=1e-14)
    turned = np.arctan2(out[3], out[2]) - np.arctan2(4.0, 3.0)
    np.testing.assert_allclose(np.angle(np.exp(1j * (turned - omega * dt))), 0.0, atol=1e-12)


@pytest.mark.parametrize("omega", [0.0, 1e-14, -1e-10, 1e-10])
def test_coordinated_turn_tends_to_constant_velocity(omega):
    ct = gf.CoordinatedTurn()
    dt = 1.5
    x0 = np.array([1.0, 2.0, -3.0, 0.5, omega])
    F_cv, _ = gf.ConstantVelocity(dim=2).transition(dt)
    np.testing.assert_allclose(ct.f(x0, dt)[:4], F_cv @ x0[:4], rtol=0, atol=1e-9)
    np.testing.assert_allclose(ct.jacobian(x0, dt)[:4, :4], F_cv, rtol=0, atol=1e-9)
    if omega == 0.0:
        np.testing.assert_array_equal(ct.f(x0, dt)[:4], F_cv @ x0[:4])


@pytest.mark.parametrize("omega", [1e-9, -1e-7, 1e-5])
def test_coordinated_turn_departs_from_constant_velocity_linearly(omega):
    """f(ω) = F_cv x + ω ∂f/∂ω|₀ + O(ω²), with ∂f/∂ω|₀ = [-vy dt²/2, vx dt²/2, -vy dt, vx dt]."""
    ct = gf.CoordinatedTurn()
    dt, vx, vy = 1.5, -3.0, 0.5
    x0 = np.array([1.0, 2.0, vx, vy, omega])
    F_cv, _ = gf.ConstantVelocity(dim=2).transition(dt)
    slope = np.array([-vy * dt**2 / 2, vx * dt**2 / 2, -vy * dt, vx * dt])
    np.testing.assert_allclose((ct.f(x0, dt)[:4] - F_cv @ x0[:4]) / omega, slope, rtol=1e-4, atol=0)
    np.testing.assert_allclose(ct.jacobian(np.r_[x0[:4], 0.0], dt)[:4, 4], slope, rtol=1e-15)


def test_coordinated_turn_is_smooth_across_the_series_threshold():
    """The series (|ω dt| < 0.1) and closed forms agree where they meet: no jump in f or the Jacobian."""
    ct = gf.CoordinatedTurn()
    dt = 2.0
    edge = 0.1 / dt
    for w in (edge, -edge):
        below = np.array([3.0, 1.0, 2.0, -7.0, w * (1 - 1e-13)])
        above = np.array([3.0, 1.0, 2.0, -7.0, w * (1 + 1e-13)])
        # ω moves by 2e-14 between the two; f by about (∂f/∂ω) 2e-14 < 1e-12.
        np.testing.assert_allclose(ct.f(below, dt), ct.f(above, dt), rtol=0, atol=1e-12)
        np.testing.assert_allclose(ct.jacobian(below, dt), ct.jacobian(above, dt), rtol=0, atol=1e-12)


state_strategy = st.tuples(
    st.floats(-1e3, 1e3), st.floats(-1e3, 1e3),
    st.floats(-50, 50), st.floats(-50, 50),
    st.one_of(st.floats(-3, 3), st.floats(-1e-6, 1e-6), st.sampled_from([0.0, 0.05, -0.05])),
)


@settings(max_examples=60, deadline=None)
@given(x=state_strategy, dt=st.floats(0.01, 5.0))
def test_coordinated_turn_jacobian_matches_complex_step(x, dt):
    ct = gf.CoordinatedTurn()
    x = np.array(x)
    J = ct.jacobian(x, dt)
    J_cs = complex_step_jacobian("f", lambda s: ct.f(s, dt), x, (), 5)
    scale = max(1.0, np.max(np.abs(J_cs)))
    np.testing.assert_allclose(J, J_cs, rtol=0, atol=1e-8 * scale)


@pytest.mark.parametrize("omega", [0.0, 1e-5, 0.049, 0.051, 0.8, -2.0])
def test_coordinated_turn_jacobian_matches_finite_differences(omega):
    """Against the library's automatic Jacobian, and against plain central differences."""
    ct = gf.CoordinatedTurn()
    dt = 2.0
    x = np.array([5.0, -1.0, 12.0, 3.0, omega])
    J = ct.jacobian(x, dt)
    np.testing.assert_allclose(J, jacobian("f", lambda s: ct.f(s, dt), x, (), 5), rtol=0, atol=1e-8)
    h = 1e-5
    J_fd = np.stack([(ct.f(x + h * e, dt) - ct.f(x - h * e, dt)) / (2 * h) for e in np.eye(5)], axis=1)
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-6)


def test_coordinated_turn_evaluates_stacks_of_states():
    ct = gf.CoordinatedTurn()
    rng = np.random.default_rng(0)
    X = rng.normal(size=(7, 5))
    X[0, 4] = 0.0
    X[1, 4] = 1e-9
    np.testing.assert_array_equal(ct.f(X, 0.4), np.stack([ct.f(x, 0.4) for x in X]))
    np.testing.assert_allclose(ct.jacobian(X, 0.4), np.stack([ct.jacobian(x, 0.4) for x in X]), rtol=1e-15)


@pytest.mark.parametrize("dt", [0.1, 1.0, 4.0])
def test_coordinated_turn_noise(dt):
    ct = gf.CoordinatedTurn(q_acc=2.0, q_turn=0.03)
    Q = ct.noise(dt)
    assert_covariance(Q, 5)
    np.testing.assert_allclose(Q[:4, :4], gf.ConstantVelocity(dim=2, q=2.0).transition(dt)[1], rtol=1e-15)
    np.testing.assert_array_equal(Q[4, :4], 0.0)
    np.testing.assert_allclose(Q[4, 4], 0.03 * dt, rtol=1e-15)
    assert np.min(np.linalg.eigvalsh(Q)) > 0


def test_coordinated_turn_attributes_and_zero_step():
    ct = gf.CoordinatedTurn()
    assert isinstance(ct, gf.NonlinearMotion)
    assert (ct.n, ct.dim, ct.state_angles) == (5, 2, ())  # omega is a rate, not an angle
    x = np.array([1.0, 2.0, 3.0, 4.0, 0.5])
    # dt = 0 is the identity (useful for simultaneous events).
    np.testing.assert_array_equal(ct.f(x, 0.0), x)
    np.testing.assert_array_equal(ct.jacobian(x, 0.0), np.eye(5))
    np.testing.assert_array_equal(ct.noise(0.0), np.zeros((5, 5)))
    # The turn rate is not wrapped: a fast spin stays fast.
    np.testing.assert_array_equal(ct.f([0, 0, 1, 0, 10.0], 1.0)[4], 10.0)


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda ct: ct.f(np.zeros(4), 1.0), ValueError, r"^`x` must have shape \(5,\) or \(k, 5\); got shape \(4,\)\.$"),
        (lambda ct: ct.jacobian(np.zeros((2, 2, 5)), 1.0), ValueError,
         r"^`x` must have shape \(5,\) or \(k, 5\); got shape \(2, 2, 5\)\.$"),
        (lambda ct: ct.f(["a"] * 5, 1.0), TypeError, r"^`x` must be an array of numbers"),
        (lambda ct: ct.f(np.zeros(5), -1.0), ValueError, r"^`dt` must be a non-negative number; got -1\.0\.$"),
        (lambda ct: ct.jacobian(np.zeros(5), np.nan), ValueError, r"^`dt` must be a non-negative number; got nan\.$"),
        (lambda ct: ct.noise("1"), TypeError, r"^`dt` must be a non-negative number; got '1'\.$"),
    ],
)
def test_coordinated_turn_argument_validation(call, error, match):
    with pytest.raises(error, match=match):
        call(gf.CoordinatedTurn())


def test_motion_base_classes_are_abstract():
    class Still(gf.NonlinearMotion):
        __slots__ = ()

    with pytest.raises(NotImplementedError):
        Still().f(np.zeros(1), 1.0)
    with pytest.raises(NotImplementedError):
        gf.LinearMotion().transition(1.0)


@pytest.mark.parametrize("kwargs", [{"tau": 1e-310}, {"sigma": 1e200}])
def test_singer_refuses_settings_that_overflow_by_name(kwargs):
    """tau = 1e-310 was accepted and its transition said "`A` must be finite"; sigma = 1e200 raised OverflowError."""
    with pytest.raises(ValueError, match=r"2 sigma² / tau and the rate 1 / tau must be finite"):
        gf.Singer(**kwargs)


def test_booleans_in_a_list_are_not_states():
    """[True, 2, ...] was read as [1.0, 2.0, ...] by the coordinated turn and the sensors."""
    calls = [lambda: gf.CoordinatedTurn().f([True, 2.0, 3.0, 4.0, 5.0], 1.0),
             lambda: gf.CoordinatedTurn().jacobian([[1.0, 2.0, 3.0, 4.0, False]], 1.0),
             lambda: gf.RangeBearing().h([True, 1.0]),
             lambda: gf.RangeBearing().jacobian([[1.0, True]])]
    for call in calls:
        with pytest.raises(TypeError, match="must be an array of numbers; got booleans"):
            call()


@pytest.mark.parametrize("call, owner", [
    (lambda: gf.ConstantVelocity().transition(1e160), "ConstantVelocity: its F or Q"),
    (lambda: gf.ConstantAcceleration(noise="piecewise").transition(1e110), "ConstantAcceleration: its F or Q"),
    (lambda: gf.Singer(tau=1.0, sigma=1.0).transition(1e300), "Singer: its F or Q"),
    (lambda: gf.ForceInput().control(1e200), "ForceInput: its B"),
    (lambda: gf.CoordinatedTurn().noise(1e200), "CoordinatedTurn: its Q"),
    (lambda: noise_module.piecewise_white_noise(1, 1e200, 1.0), r"piecewise_white_noise\(\): its Q"),
    (lambda: noise_module.continuous_white_noise(2, 1e200, 1.0), r"continuous_white_noise\(\): its Q"),
])
def test_a_step_too_long_for_float64_is_named_when_called_directly(call, owner):
    """Through gf.model the step was named; called directly, the powers of a Python float raised OverflowError
    (piecewise_white_noise, ForceInput.control, transition(1e160)) or gave inf without a word."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # and no RuntimeWarning of an overflow on the way
        with pytest.raises(ValueError, match=rf"^a step of dt = 1e\+\d+ s is too long for {owner}"):
            call()


@pytest.mark.parametrize("steps", [2, 3, 7])
def test_a_local_linear_trends_steps_are_that_many_steps(steps):
    """Q over dt steps was diag(q_level, q_slope)·dt: two steps gave [[4, 0], [0, 1]] where two steps of the model
    give [[4.5, 0.5], [0.5, 1]], so a gap filtered otherwise than a missing measurement. Against the steps composed
    by hand, and a gap against the same data with NaN in it (the filter's answer must be the same)."""
    trend = gf.LocalLinearTrend(q_level=2.0, q_slope=0.5)
    F1, Q1 = trend.transition(1)
    F, Q = np.eye(2), np.zeros((2, 2))
    for _ in range(steps):
        F, Q = F1 @ F, F1 @ Q @ F1.T + Q1
    got_F, got_Q = trend.transition(steps)
    np.testing.assert_array_equal(got_F, F)
    np.testing.assert_allclose(got_Q, Q, rtol=1e-15)
    a, b = trend.transition(0.7 + steps)[1], trend.transition(steps)[1]  # any real steps compose
    np.testing.assert_allclose(trend.transition(0.7 + 2 * steps)[1],
                               trend.transition(steps)[0] @ a @ trend.transition(steps)[0].T + b, rtol=1e-14)
    times = np.array([0.0, 1.0, 2.0, 4.0, 5.0])
    zs = np.array([1.0, 2.2, 2.9, 5.1, 6.3])
    prior = gf.Gaussian([0.0, 1.0], np.diag([4.0, 1.0]))
    timed = gf.model(trend, gf.LinearSensor([[1.0, 0.0]], 0.3))
    gap = gf.filter(timed, prior, zs, times=np.concatenate([[-1.0], times]))
    unit = gf.model(trend, gf.LinearSensor([[1.0, 0.0]], 0.3), dt=1.0)
    filled = gf.filter(unit, prior, np.array([1.0, 2.2, 2.9, np.nan, 5.1, 6.3]))
    np.testing.assert_allclose(gap.means[-1], filled.means[-1], rtol=1e-13)
    np.testing.assert_allclose(gap.covs[-1], filled.covs[-1], rtol=1e-13)
    assert gap.loglik == pytest.approx(filled.loglik, rel=1e-13)


def test_a_fraction_of_a_step_without_a_covariance_is_refused():
    """Under one step the composed Q is a covariance only while q_level >= q_slope (1 - dt²) / 12."""
    with pytest.raises(ValueError, match=r"^`dt` = 0\.5 is a fraction of a step, over which LocalLinearTrend"):
        gf.LocalLinearTrend(q_level=0.0, q_slope=1.0).transition(0.5)
    Q = gf.LocalLinearTrend(q_level=1.0 / 16, q_slope=1.0).transition(0.5)[1]  # 1/16 >= 0.75 / 12
    assert np.linalg.eigvalsh(Q).min() >= -1e-17


def test_a_users_motion_with_its_own_name_for_the_step_overflows_as_a_named_step():
    """The step was looked up by the name `dt`: a transition(self, step) that overflowed raised KeyError('dt')."""

    class Growth(gf.LinearMotion):
        __slots__ = ()
        n = 1
        names = ("x",)

        def transition(self, step):
            return np.array([[np.exp(step)]]), np.array([[step]])

    with pytest.raises(ValueError, match=r"^a step of dt = 1000 s is too long for Growth: its F or Q overflows"):
        Growth().transition(1000.0)


@pytest.mark.parametrize("motion", [gf.ConstantPosition(dim=3, q=0.37), gf.ConstantVelocity(dim=2, q=0.37),
                                    gf.ConstantAcceleration(dim=1, q=0.37),
                                    gf.ConstantVelocity(dim=2, q=0.37, noise="piecewise")],
                         ids=["position", "velocity", "acceleration", "piecewise"])
def test_transitions_of_many_steps_are_each_step_s_to_the_bit(motion):
    """TimedModel.at discretised each distinct step in Python (90 us each: 18.5 s for 200,000 rows of a file with
    every step different, against 3.3 s with three step sizes); the closed forms now take the steps together.
    They must give each step's own F and Q, bit for bit, from 1e-8 s to 1e4 s."""
    dts = np.concatenate([np.random.default_rng(0).uniform(1e-6, 50.0, 300),
                          10.0 ** np.random.default_rng(1).uniform(-8.0, 4.0, 300)])
    F, Q = motion.transitions(dts)
    assert np.array_equal(F, np.stack([motion.transition(float(dt))[0] for dt in dts]))
    assert np.array_equal(Q, np.stack([motion.transition(float(dt))[1] for dt in dts]))
    if motion.n > motion.dim:  # (a random walk's Q = q dt does not overflow)
        with pytest.raises(ValueError, match=r"a step of dt = 1e\+200 s is too long"):  # named, as one step's
            motion.transitions(np.array([1.0, 1e200]))


@pytest.mark.parametrize("motion", [gf.ConstantVelocity(q=1.0), gf.ConstantVelocity(q=1.0, noise="piecewise"),
                                    gf.ConstantAcceleration(q=1.0), gf.Singer(), gf.LocalLevel()],
                         ids=["velocity", "piecewise", "acceleration", "singer", "local-level"])
def test_transitions_check_their_steps_as_transition_does(motion):
    """Audit MM2: the closed forms took dt = -1 into a Q with a negative eigenvalue (-1.27) and dt = 0 into Q = 0,
    and a 2-D dts into einsum's error, where transition() refuses both."""
    for bad, match in [([-1.0], r"^`dts` must be positive step sizes; got -1\.0 at index 0\.$"),
                       ([1.0, 0.0], r"^`dts` must be positive step sizes; got 0\.0 at index 1\.$"),
                       ([[1.0, 2.0]], r"^`dts` must have shape \(k,\); got shape \(1, 2\)\.$"),
                       ([1.0, np.nan], r"^`dts` must be finite")]:
        with pytest.raises(ValueError, match=match):
            motion.transitions(np.array(bad))
    with pytest.raises(TypeError, match="`dts` must be an array of numbers"):
        motion.transitions(["1"])
    F, Q = motion.transitions(np.zeros(0))
    assert F.shape == Q.shape == (0, motion.n, motion.n)


def _singer_q_1500_digits(tau: float, sigma: float, dt: float) -> np.ndarray:
    """Singer's closed-form Q per axis, (3, 3), in mpmath at 1500 digits (Singer 1970; Bar-Shalom, Li & Kirubarajan
    2001, §8.2): no cancellation is left at any rate."""
    import mpmath as mp

    with mp.workdps(1500):
        a, T = 1 / mp.mpf(tau), mp.mpf(dt)
        q = 2 * mp.mpf(sigma) ** 2 / mp.mpf(tau)
        e1, e2 = mp.exp(-a * T), mp.exp(-2 * a * T)
        q00 = q / (2 * a**5) * (1 - e2 + 2 * a * T + 2 * a**3 * T**3 / 3 - 2 * a**2 * T**2 - 4 * a * T * e1)
        q01 = q / (2 * a**4) * (e2 + 1 - 2 * e1 + 2 * a * T * e1 - 2 * a * T + a**2 * T**2)
        q02 = q / (2 * a**3) * (1 - e2 - 2 * a * T * e1)
        q11 = q / (2 * a**3) * (4 * e1 - 3 - e2 + 2 * a * T)
        q12 = q / (2 * a**2) * (e2 + 1 - 2 * e1)
        q22 = q / (2 * a) * (1 - e2)
        return np.array([[float(q00), float(q01), float(q02)], [float(q01), float(q11), float(q12)],
                         [float(q02), float(q12), float(q22)]])


@pytest.mark.parametrize("tau, sigma", [(1e-150, 1.0), (1e-140, 1e-10), (1e-150, 1e10), (1e-100, 1e-50)])
def test_singer_at_the_fastest_rates_it_takes_is_its_closed_form(tau, sigma):
    """Audit MM3: at sigma tau = 1e-160 Q's entries were 1e-3 off, below it 0 for 1e-200 (its sub-steps' terms
    underflowed); from 1e-150 up they are exact to round-off, and below it the model is refused. Review R46: the
    same held for the position and velocity block only: at tau = 1e-175 (sigma = 1e30) Q[0, 2] was 43% off, as the
    sub-steps' F[0, 2], about tau², underflowed; tau is refused below 1e-150 too, and all six entries are held."""
    for dt in (1e-6, 1.0, 1e6):
        Q = gf.Singer(tau=tau, sigma=sigma).transition(dt)[1]
        np.testing.assert_allclose(Q, _singer_q_1500_digits(tau, sigma, dt), rtol=1e-13, atol=0)
    with pytest.raises(ValueError, match=r"^sigma \* tau must be at least 1e-150, or sigma 0"):
        gf.Singer(tau=tau, sigma=sigma / 1e11)
    with pytest.raises(ValueError, match=r"^tau must be at least 1e-150, or sigma 0: .* got tau = 1e-175\."):
        gf.Singer(tau=1e-175, sigma=1e30)
    F, Q = gf.Singer(tau=1e-300, sigma=0.0).transition(1.0)  # without noise, F is exact (review R47)
    assert not Q.any()
    np.testing.assert_allclose(F[:3, :3], [[1.0, 1.0, 1e-300], [0.0, 1.0, 1e-300], [0.0, 0.0, 0.0]], rtol=1e-14,
                               atol=0)


@pytest.mark.parametrize("tau, sigma", [(1e10, 1e-155), (1e50, 1e-160), (1.0, 1e-160)])
def test_singer_refuses_a_density_below_the_normal_floats(tau, sigma):
    """Review R44: sigma = 1e-160 with tau = 1e50 made 2 sigma² / tau 0 and Q = 0, where the closed form's position
    variance is 6e-122; sigma = 1e-155 with tau = 1e10 a subnormal density, and Q 1e-5 off. A slow rate with a
    normal density is exact."""
    with pytest.raises(ValueError, match=r"^sigma² and the noise density 2 sigma² / tau must be at least float64's "
                                         r"smallest normal number"):
        gf.Singer(tau=tau, sigma=sigma)
    Q = gf.Singer(tau=1e10, sigma=1e-140).transition(1e6)[1]
    np.testing.assert_allclose(Q, _singer_q_1500_digits(1e10, 1e-140, 1e6), rtol=1e-13, atol=0)


def test_the_coordinated_turn_jacobian_of_a_step_too_long_is_noise_s_error():
    """Past dt = 1.3e154 the Jacobian raised Python's bare OverflowError (a power of a Python float), where noise()
    names the step (audit TT1); and the ∂/∂ω entries over θ² overflowed to 0 where they are finite. An entry
    beyond float64 is now noise's ValueError; one within it is exact (the oracle: the closed form in mpmath at the
    float64 turn angle)."""
    import mpmath as mp

    ct = gf.CoordinatedTurn()
    for w in (0.0, 1e-170):  # dt²/2 and its neighbour overflow float64
        with pytest.raises(ValueError, match=r"^a step of dt = 1e\+160 s is too long for CoordinatedTurn: its "
                                             r"Jacobian overflows float64"):
            ct.jacobian([1.0, 2.0, 3.0, 4.0, w], 1e160)
        with pytest.raises(ValueError, match=r"too long for CoordinatedTurn: its Q overflows"):
            ct.noise(1e160)
    dt, w = 1e160, 0.1
    J = ct.jacobian([1.0, 2.0, 3.0, 4.0, w], dt)
    with mp.workdps(400):
        theta, T = mp.mpf(float(np.float64(w) * dt)), mp.mpf(dt)
        ds = T * T * (mp.cos(theta) / theta - mp.sin(theta) / theta ** 2)
        dc = T * T * (mp.sin(theta) / theta - (1 - mp.cos(theta)) / theta ** 2)
        want = [float(3 * ds - 4 * dc), float(3 * dc + 4 * ds)]
    np.testing.assert_allclose(J[:2, 4], want, rtol=1e-13)


@pytest.mark.parametrize("q_level, q_slope, dt", [(1.0, 1e-300, 1e120), (0.0, 1e-200, 1e104), (1.0, 1e-100, 1e110),
                                                  (0.5, 0.01, 7.0), (2.0, 3.0, 0.75)])
def test_a_local_linear_trend_s_q_overflows_only_where_it_does(q_level, q_slope, dt):
    """d (d - 1) (2d - 1) overflowed before q_slope brought it back into range: steps whose F and Q are finite
    were refused as "too long" (audit VV3). The oracle is the closed form in exact rational arithmetic."""
    from fractions import Fraction

    D, ql, qs = Fraction(dt), Fraction(q_level), Fraction(q_slope)
    want = [[float(D * ql + qs * D * (D - 1) * (2 * D - 1) / 6), float(qs * D * (D - 1) / 2)],
            [float(qs * D * (D - 1) / 2), float(D * qs)]]
    F, Q = gf.LocalLinearTrend(q_level=q_level, q_slope=q_slope).transition(dt)
    np.testing.assert_allclose(Q, want, rtol=4 * np.finfo(float).eps, atol=0.0)
    assert F[0, 1] == dt
    with pytest.raises(ValueError, match=r"too long for LocalLinearTrend: its F or Q overflows float64"):
        gf.LocalLinearTrend(q_level=1.0, q_slope=1.0).transition(1e110)  # 3e329: a real overflow
