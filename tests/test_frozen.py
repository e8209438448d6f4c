"""Every public class pickles and copies to an equal value that is as immutable as the original.

One small example of each class in ``gaussfuse.__all__`` goes through a
pickle round trip (every protocol), ``copy.copy`` and ``copy.deepcopy``;
the copy must hold equal values, read-only arrays where the original's are
read-only, and refuse attribute assignment where the original does. A model
and a result also travel to another process, which filters with the model
and gets the same numbers.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import inspect
import pickle
import subprocess
import sys
import textwrap
import types

import numpy as np
import pytest

import gaussfuse as gf

RNG = np.random.default_rng(3)
ZS = RNG.normal(size=(12, 1))


def linear_model() -> gf.LinearModel:
    return gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.1, 0.01]), R=1.0,
                          B=[[0.5], [1.0]])


def prior() -> gf.Gaussian:
    return gf.Gaussian([0.0, 1.0], [[2.0, 0.5], [0.5, 1.0]])


def pendulum_f(x):
    return np.array([x[0] + 0.1 * x[1], x[1] - 0.981 * np.sin(x[0])])


def pendulum_h(x):
    return np.sin(x[:1])


def nonlinear_model() -> gf.NonlinearModel:
    return gf.NonlinearModel(pendulum_f, pendulum_h, 0.01 * np.eye(2), 0.1, state_angles=[0])


def kalman_filter() -> gf.KalmanFilter:
    kf = gf.KalmanFilter(linear_model(), prior())
    kf.predict([1.0])
    kf.update(0.5)
    return kf


def fuse_args() -> tuple:
    sensors = {"gps": gf.Position(dim=2, r=0.5), "radar": gf.RangeBearing(r_range=0.1, r_bearing=1e-3)}
    start = gf.Gaussian([1.0, 0.0, 1.0, 1.0], 4.0 * np.eye(4))
    return gf.ConstantVelocity(dim=2, q=0.1), sensors, start


def fused() -> gf.Fused:
    motion, sensors, start = fuse_args()
    events = [gf.Measurement(1.0, "gps", [2.0, 1.2]), gf.Measurement(1.5, "radar", [2.9, 0.6])]
    return gf.fuse_timeline(motion, sensors, start, 0.0, events, times=[2.0])


def fuser() -> gf.Fuser:
    motion, sensors, start = fuse_args()
    out = gf.Fuser(motion, sensors, start, 0.0)  # nonlinear: "ekf"
    out.update(1.0, "radar", [1.9, 0.5])
    return out


def imm_result() -> gf.IMMResult:
    slow, fast = (gf.LinearModel(F=[[1.0]], H=[1.0], Q=q, R=1.0) for q in (0.01, 1.0))
    return gf.imm_filter([slow, fast], gf.Gaussian(0.0, 1.0), ZS, [[0.95, 0.05], [0.05, 0.95]])


def fit_result() -> gf.FitResult:
    model = gf.LinearModel(F=[[1.0]], H=[1.0], Q=1.0, R=1.0)
    return gf.fit(model, gf.Gaussian(0.0, 10.0), ZS, learn=("Q", "R"), iterations=3, tol=0.0)


EXAMPLES = {
    gf.Gaussian: prior,
    gf.LinearModel: linear_model,
    gf.NonlinearModel: nonlinear_model,
    gf.LinearMotion: gf.LinearMotion,
    gf.NonlinearMotion: gf.NonlinearMotion,
    gf.ConstantPosition: lambda: gf.ConstantPosition(dim=2, q=0.5),
    gf.ConstantVelocity: lambda: gf.ConstantVelocity(dim=2, q=0.5, noise="piecewise"),
    gf.ConstantAcceleration: lambda: gf.ConstantAcceleration(dim=1, q=2.0),
    gf.ForceInput: lambda: gf.ForceInput(q=0.1, dim=2),
    gf.Singer: lambda: gf.Singer(dim=1, tau=2.0, sigma=0.5),
    gf.RandomWalk: lambda: gf.RandomWalk(n=2, q=0.3),
    gf.LocalLevel: lambda: gf.LocalLevel(q=2.0),
    gf.LocalLinearTrend: lambda: gf.LocalLinearTrend(q_level=1.0, q_slope=0.1),
    gf.LinearSDE: lambda: gf.LinearSDE([[0.0, 1.0], [0.0, -0.5]], [[0.0], [1.0]], [[0.2]], names=("p", "v")),
    gf.CoordinatedTurn: lambda: gf.CoordinatedTurn(q_acc=0.5, q_turn=0.02),
    gf.LinearSensor: lambda: gf.LinearSensor([[1.0, 0.0]], [[0.3]], names=("p",)),
    gf.Position: lambda: gf.Position(dim=2, r=0.1, n=4),
    gf.NonlinearSensor: gf.NonlinearSensor,
    gf.RangeBearing: lambda: gf.RangeBearing(r_range=0.2, r_bearing=1e-3, origin=(1.0, -1.0)),
    gf.RangeBearingElevation: lambda: gf.RangeBearingElevation(origin=(0.0, 1.0, 2.0)),
    gf.BearingOnly: lambda: gf.BearingOnly(r_bearing=1e-2),
    gf.FilterResult: lambda: gf.filter(linear_model(), prior(), ZS, np.ones((12, 1))),
    gf.SmoothResult: lambda: gf.smooth(nonlinear_model(), prior(), np.sin(ZS), method="ekf"),
    gf.KalmanFilter: kalman_filter,
    gf.Stationary: lambda: gf.steady_state(linear_model()),
    gf.TimedModel: lambda: gf.model(gf.ConstantVelocity(dim=2, q=0.5), gf.Position(dim=2, r=0.1)),
    gf.Forecast: lambda: gf.forecast(linear_model(), prior(), 3, np.ones((3, 1))),
    gf.Simulation: lambda: gf.simulate(linear_model(), prior(), 4, np.ones((4, 1)), rng=0),
    gf.Measurement: lambda: gf.Measurement(1.5, "gps", np.array([1.0, 2.0])),
    gf.Fused: fused,
    gf.Fuser: fuser,
    gf.IMMResult: imm_result,
    gf.FitResult: fit_result,
    gf.Stacked: lambda: gf.stack_sensors({"gps": gf.Position(dim=2, r=0.5), "radar": gf.RangeBearing()},
                                         gf.ConstantVelocity(dim=2)),
}


def test_every_public_class_has_an_example():
    public = {getattr(gf, name) for name in gf.__all__ if inspect.isclass(getattr(gf, name))
              and not issubclass(getattr(gf, name), BaseException)}  # warnings are not values
    assert public == set(EXAMPLES)


def assert_equal_values(a, b, path="obj"):
    """`a` and `b` hold equal values, with read-only arrays where `a`'s public ones are read-only.

    Private state (a path through a name starting with ``_``) must be equal;
    whether its arrays are writable is the class's business.
    """
    assert type(a) is type(b), path
    if isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=path)
        assert a.dtype == b.dtype, path
        if "._" not in path:
            assert b.flags.writeable == a.flags.writeable, f"{path}: writeable {b.flags.writeable}"
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_equal_values(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            assert_equal_values(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, functools.partial):
        assert a.func is b.func or a.func == b.func, path
        assert_equal_values(a.args, b.args, f"{path}.args")
        assert_equal_values(a.keywords, b.keywords, f"{path}.keywords")
    elif isinstance(a, types.MethodType):
        assert a.__func__ is b.__func__, path
        assert_equal_values(a.__self__, b.__self__, f"{path}.__self__")
    elif isinstance(a, float):
        assert a == b or (np.isnan(a) and np.isnan(b)), path  # (a standard error of NaN copies as NaN)
    elif isinstance(a, (types.FunctionType, type, str, int, bool, slice, type(None))):
        assert a == b, path
    elif dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            assert_equal_values(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    else:  # an object: its slots and instance attributes
        if hasattr(a, "__dict__"):
            assert list(vars(a)) == list(vars(b)), path
        names = [s for cls in type(a).__mro__ for s in getattr(cls, "__slots__", ())]
        for name in names + list(getattr(a, "__dict__", ())):
            assert_equal_values(getattr(a, name), getattr(b, name), f"{path}.{name}")


def is_immutable(obj) -> bool:
    try:
        setattr(obj, "probe", 1)
    except AttributeError:
        return True
    return False


COPIES = {f"pickle-{p}": functools.partial(lambda obj, p: pickle.loads(pickle.dumps(obj, p)), p=p)
          for p in range(2, pickle.HIGHEST_PROTOCOL + 1)}
COPIES.update(copy=copy.copy, deepcopy=copy.deepcopy)


@pytest.mark.parametrize("how", list(COPIES))
@pytest.mark.parametrize("cls", list(EXAMPLES), ids=lambda cls: cls.__name__)
def test_pickles_and_copies_to_an_equal_value_as_immutable_as_the_original(cls, how):
    original = EXAMPLES[cls]()
    assert type(original) is cls
    duplicate = COPIES[how](original)
    assert_equal_values(original, duplicate)
    assert is_immutable(duplicate) == is_immutable(original)


CHILD = textwrap.dedent("""
    import pickle, sys
    import gaussfuse as gf

    with open(sys.argv[1], "rb") as fh:
        jobs = pickle.load(fh)
    results = [gf.smooth(model, prior, zs, us, method) for model, prior, zs, us, method, _ in jobs]
    with open(sys.argv[2], "wb") as fh:
        pickle.dump((results, [expected for *_, expected in jobs]), fh)
""")


def test_a_model_and_a_result_travel_to_another_process_and_back(tmp_path):
    track = gf.model(gf.CoordinatedTurn(q_acc=0.1, q_turn=1e-3), gf.RangeBearing(origin=(-5.0, 0.0)), dt=1.0)
    start = gf.Gaussian([0.0, 0.0, 1.0, 0.5, 0.05], np.diag([1.0, 1.0, 0.1, 0.1, 0.01]))
    x, y = np.arange(1.0, 21.0) + 5.0, 0.5 * np.arange(1.0, 21.0)
    zs = np.column_stack([np.hypot(x, y), np.arctan2(y, x)])
    problems = [(linear_model(), prior(), ZS, np.ones((12, 1)), "kf"), (track, start, zs, None, "ekf")]
    jobs = [(*job, gf.smooth(*job)) for job in problems]
    sent, back = tmp_path / "jobs.pkl", tmp_path / "results.pkl"
    sent.write_bytes(pickle.dumps(jobs))
    child = subprocess.run([sys.executable, "-c", CHILD, str(sent), str(back)], capture_output=True,
                           text=True, timeout=600)
    assert child.returncode == 0, child.stderr
    computed, received = pickle.loads(back.read_bytes())
    for (*_, expected), there, sent_back in zip(jobs, computed, received):
        assert_equal_values(expected, there)  # the model filtered there as here, to the bit
        assert_equal_values(expected, sent_back)


@pytest.mark.parametrize("cls", [c for c in EXAMPLES if dataclasses.is_dataclass(c) and c is not gf.Gaussian],
                         ids=lambda cls: cls.__name__)
def test_results_show_their_shapes_and_numbers_not_their_arrays(cls):
    text = repr(EXAMPLES[cls]())
    assert text.startswith(f"{cls.__name__}(") and "\n" not in text
    assert "array(" not in text and "[[" not in text
