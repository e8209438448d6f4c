"""Fuzzing the public API: whatever goes in, a correct result or a clear error comes out.

Random shapes (right, transposed, one off, empty, an extra axis), values
(NaN, ±inf, 1e±300, subnormals, zeros), matrices that are not square,
symmetric or positive semi-definite, and arrays of objects, strings,
complex numbers and booleans go to the model and belief constructors, the
filters and smoothers (both forms and both engines), the online filter and
``fuse``. Every call must return a result whose beliefs are finite and whose
shapes are right, or raise ValueError or TypeError (numpy's LinAlgError and
gaussfuse's ModelFunctionError are ValueErrors), or FloatingPointError for an
overflow (documented, naming the step). Never another exception, and never
NaN presented as a result. Nonlinear models get functions that raise or
return wrong shapes, NaN, inf, lists, strings, complex or boolean values.

The suites run a fixed set of examples in CI (100-150 each, seconds in all).
A longer, random search by hand::

    GAUSSFUSE_FUZZ_EXAMPLES=5000 python -m pytest tests/test_fuzz.py -p no:xdist
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import gaussfuse as gf

_EXAMPLES = int(os.environ.get("GAUSSFUSE_FUZZ_EXAMPLES", "0"))
FUZZ = settings(max_examples=_EXAMPLES or 150, deadline=None, derandomize=not _EXAMPLES,
                suppress_health_check=list(HealthCheck))
CLEAR = (ValueError, TypeError, FloatingPointError)

SPECIAL = [np.nan, np.inf, -np.inf, 1e300, -1e300, 1e-300, 5e-324, 0.0, -0.0]


@st.composite
def arrays(draw, shape: tuple[int, ...], kind: str = "matrix"):
    """An array meant to have `shape`; sometimes another shape, dtype or special values."""
    shape = tuple(shape)
    change = draw(st.sampled_from(["none"] * 6 + ["shape", "dtype", "special", "scale", "empty"]))
    if change == "shape":
        shape = draw(st.sampled_from([shape[::-1], tuple(s + 1 for s in shape), shape[:-1] or (1,), (*shape, 2),
                                      (0, *shape[1:]) if shape else (0,)]))
    if change == "empty":
        shape = tuple(0 for _ in shape) or (0,)
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    a = rng.normal(size=shape)
    if kind == "cov" and len(shape) == 2 and shape[0] == shape[1]:
        a = a @ a.T + 0.1 * np.eye(shape[0])  # usually a valid covariance
    if change == "special" and a.size:
        a.flat[draw(st.integers(0, a.size - 1))] = draw(st.sampled_from(SPECIAL))
    if change == "scale":
        a = a * draw(st.sampled_from([1e-300, 1e-150, 1e150, 1e300]))
    if change == "dtype":
        how = draw(st.sampled_from(["int", "bool", "complex", "object", "str", "list"]))
        if how == "int":
            return a.astype(int)
        if how == "bool":
            return a > 0
        if how == "complex":
            return a + 1j
        if how == "object":
            out = a.astype(object)
            if out.size:
                out.flat[0] = "x"
            return out
        if how == "str":
            return a.astype(str)
        return a.tolist()
    return a


@st.composite
def problems(draw):
    n, m, T = draw(st.integers(1, 3)), draw(st.integers(1, 2)), draw(st.integers(0, 6))
    F = draw(arrays((n, n)))
    H = draw(arrays((m, n)))
    Q = draw(arrays((n, n), "cov"))
    R = draw(arrays((m, m), "cov"))
    mean = draw(arrays((n,)))
    cov = draw(arrays((n, n), "cov"))
    zs = draw(arrays((T, m)))
    if isinstance(zs, np.ndarray) and zs.dtype == float and zs.size and draw(st.booleans()):
        zs[np.random.default_rng(T).random(zs.shape) < 0.3] = np.nan  # missing values: valid
    return n, m, F, H, Q, R, mean, cov, zs


def _finite_result(res, n: int) -> None:
    """A returned result is usable: finite beliefs of the right shapes, symmetric covariances."""
    for name in ("means", "covs", "last_mean", "last_cov"):
        value = getattr(res, name, None)
        if value is None:
            continue
        assert np.all(np.isfinite(value)), f"{name} holds NaN or inf"
        assert value.shape[-1] == n, name
    if getattr(res, "covs", None) is not None:
        np.testing.assert_array_equal(res.covs, np.swapaxes(res.covs, -1, -2))


def _try(call):
    """The call's result, or None when it raised one of the clear errors, with a message."""
    try:
        return call()
    except CLEAR as exc:
        assert str(exc), f"{type(exc).__name__} without a message"
        event(f"raised {type(exc).__name__}")  # --hypothesis-show-statistics tells what the examples reached
        return None


@FUZZ
@given(problems(), st.sampled_from(["filter", "smooth"]), st.sampled_from(["cov", "sqrt"]),
       st.sampled_from(["python", "numba"]))
def test_filter_and_smooth_end_in_a_result_or_a_clear_error(problem, what, form, engine):
    n, m, F, H, Q, R, mean, cov, zs = problem
    model = _try(lambda: gf.LinearModel(F, H, Q, R))
    prior = _try(lambda: gf.Gaussian(mean, cov))
    if model is None or prior is None:
        return
    if form == "sqrt" and engine == "numba":
        engine = "python"
    call = gf.filter if what == "filter" else gf.smooth
    res = _try(lambda: call(model, prior, zs, engine=engine, form=form, check="off"))
    if res is not None:
        event("a result")
        _finite_result(res, n)
        if what == "smooth":
            _finite_result(res.filtered, n)


@FUZZ
@given(problems())
def test_the_online_filter_ends_in_a_belief_or_a_clear_error(problem):
    n, m, F, H, Q, R, mean, cov, zs = problem
    model = _try(lambda: gf.LinearModel(F, H, Q, R))
    prior = _try(lambda: gf.Gaussian(mean, cov))
    if model is None or prior is None:
        return
    kf = gf.KalmanFilter(model, prior, check="off")
    rows = zs if isinstance(zs, np.ndarray) and zs.ndim == 2 else [zs]
    for z in rows:
        if _try(kf.predict) is None or _try(lambda: kf.update(z)) is None:
            return
        assert np.all(np.isfinite(kf.x)) and np.all(np.isfinite(kf.P))


@FUZZ
@given(arrays((2,)), arrays((2, 2), "cov"), arrays((2,)), arrays((2, 2), "cov"))
def test_fuse_ends_in_a_gaussian_or_a_clear_error(m1, c1, m2, c2):
    a, b = _try(lambda: gf.Gaussian(m1, c1)), _try(lambda: gf.Gaussian(m2, c2))
    if a is None or b is None:
        return
    out = _try(lambda: gf.fuse(a, b))
    if out is not None:
        assert np.all(np.isfinite(out.mean)) and np.all(np.isfinite(out.cov))
        np.testing.assert_array_equal(out.cov, out.cov.T)


# ---------------------------------------------------------------------------
# The command line: malformed files and odd paths
# ---------------------------------------------------------------------------

@settings(FUZZ, max_examples=_EXAMPLES or 60)
@given(problems(), st.sampled_from(["em", "mle"]),
       st.sampled_from([("Q", "R"), ("F",), ("H", "R"), ("m0", "P0"), ("Q",), ("R",)]),
       st.sampled_from([None, {"Q": "diagonal"}, {"R": "scalar"}]), st.sampled_from([1, 3]))
def test_fit_ends_in_a_finite_model_or_a_clear_error(problem, method, learn, structure, iterations):
    """`fit` on the same random problems: a model whose matrices and log-likelihood are finite, or a clear error."""
    n, m, F, H, Q, R, mean, cov, zs = problem
    model = _try(lambda: gf.LinearModel(F, H, Q, R))
    prior = _try(lambda: gf.Gaussian(mean, cov))
    if model is None or prior is None:
        return
    if structure is not None and not set(structure) <= set(learn):
        structure = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gf.ConvergenceWarning)  # a few iterations on purpose
        fit = _try(lambda: gf.fit(model, prior, zs, learn=learn, method=method, structure=structure,
                                  iterations=iterations, engine="python"))
    if fit is not None:
        event("a fitted model")
        assert np.isfinite(fit.loglik) and np.all(np.isfinite(fit.history))
        for name in ("F", "H", "Q", "R"):
            value = getattr(fit.model, name)
            assert np.all(np.isfinite(value)), f"fitted {name} holds NaN or inf"
        for name in ("Q", "R"):
            value = getattr(fit.model, name)
            np.testing.assert_array_equal(value, np.swapaxes(value, -1, -2))
            assert np.linalg.eigvalsh(value).min() >= -1e-9 * max(1.0, np.abs(value).max()), name
        assert np.all(np.isfinite(fit.prior.mean)) and np.all(np.isfinite(fit.prior.cov))
        assert all(np.isfinite(v) for v in fit.params.values())


@settings(FUZZ, max_examples=_EXAMPLES or 60)
@given(problems(), st.integers(0, 4), st.integers(0, 2**32 - 1))
def test_forecast_simulate_and_posterior_draws_end_in_finite_arrays_or_a_clear_error(problem, steps, seed):
    n, m, F, H, Q, R, mean, cov, zs = problem
    model = _try(lambda: gf.LinearModel(F, H, Q, R))
    prior = _try(lambda: gf.Gaussian(mean, cov))
    if model is None or prior is None:
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gf.DivergenceWarning)
        fc = _try(lambda: gf.forecast(model, prior, steps))
        sim = _try(lambda: gf.simulate(model, prior, steps, size=2, rng=seed))
        draws = _try(lambda: gf.sample_posterior(model, prior, zs, 3, rng=seed))
    if fc is not None:
        assert all(np.all(np.isfinite(a)) for a in (fc.means, fc.covs, fc.measurement_means, fc.measurement_covs))
    if sim is not None:
        assert sim.states.shape == (2, steps, n) and np.all(np.isfinite(sim.states))
        assert np.all(np.isfinite(sim.measurements))
    if draws is not None:
        event("posterior draws")
        assert draws.shape[0] == 3 and draws.shape[-1] == n and np.all(np.isfinite(draws))


CSV = "t,x,y\n0.0,1.0,2.0\n0.5,1.5,\n1.0,nan,2.5\n1.5,2.5,3.0\n"
TOML = '[model]\nkind = "constant_velocity"\ndim = 2\ndt = 0.5\nq = 0.3\nr = 0.2\n\n[prior]\nvar = 2.0\n'
GARBAGE = ["", ",", ",,", "x", "1e999", "-inf", "nan", "\x00", "é", '"', "[", "]", "=", "\n", "0x10", "1,2,3,4",
           "kind = 3", "[model]", "dt = -1", "q = 'a'", "\ufeff", "   ", "#", "1.0e-400", "true"]


@st.composite
def mangled(draw, text: str) -> str:
    """`text` with a few random cuts, duplications and insertions of awkward tokens."""
    for _ in range(draw(st.integers(0, 4))):
        i = draw(st.integers(0, len(text)))
        j = draw(st.integers(i, min(len(text), i + 8)))
        how = draw(st.sampled_from(["cut", "insert", "double"]))
        if how == "cut":
            text = text[:i] + text[j:]
        elif how == "insert":
            text = text[:i] + draw(st.sampled_from(GARBAGE)) + text[i:]
        else:
            text = text[:j] + text[i:j] + text[j:]
    return text


@settings(FUZZ, max_examples=_EXAMPLES or 100)
@given(mangled(CSV), mangled(TOML), st.sampled_from(["", "--smooth"]), st.sampled_from(["out.csv", "new/out.csv",
                                                                                          ".", "out dir/é.csv"]))
def test_the_cli_ends_in_output_or_one_line_and_exit_code_2(tmp_path_factory, capsys, csv_text, toml_text, smooth,
                                                               out_name):
    """`gaussfuse filter` on mangled input: exit 0 with a complete file, or exit 2, one line and no file."""
    from gaussfuse.cli import main

    where = tmp_path_factory.mktemp("cli")
    data, model, out = where / "data.csv", where / "model.toml", where / out_name
    data.write_text(csv_text, encoding="utf-8")
    model.write_text(toml_text, encoding="utf-8")
    before = set(where.rglob("*"))
    code = main(["filter", str(data), "--model", str(model), "--out", str(out), "--check", "off", *smooth.split()])
    stdout, err = capsys.readouterr()
    event(f"exit status {code}")
    assert code in (0, 2), (code, err)
    if code == 2:
        assert err.startswith("gaussfuse: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
        assert set(where.rglob("*")) == before, "a file was left behind"
    else:
        lines = out.read_text().splitlines()
        assert len(lines) >= 2 and all("," in line for line in lines)


FIT_TOML = ('[model]\nF = [[1.0, 1.0], [0.0, 1.0]]\nH = [[1.0, 0.0], [0.0, 1.0]]\nQ = [[0.25, 0.5], [0.5, 1.0]]\n'
            'R = [[4.0, 0.0], [0.0, 4.0]]\n\n[prior]\nmean = [0.0, 1.0]\nvar = 10.0\n')


@settings(FUZZ, max_examples=_EXAMPLES or 60)
@given(mangled(CSV), mangled(FIT_TOML), st.sampled_from(["Q,R", "R", "F,Q", "q,r", "m0,P0", "", "Q,Q,R"]),
       st.sampled_from(["em", "mle"]), st.sampled_from(["fitted.toml", "new/fitted.toml", ".", "é dir/f.toml"]))
def test_cli_fit_ends_in_a_model_file_or_one_line_and_exit_code_2(tmp_path_factory, capsys, csv_text, toml_text,
                                                                    learn, method, out_name):
    """`gaussfuse fit` on mangled input: exit 0 or 3 with a complete model file, or exit 2, one line and no file."""
    import tomllib

    from gaussfuse.cli import main

    where = tmp_path_factory.mktemp("fit")
    data, model, out = where / "data.csv", where / "model.toml", where / out_name
    data.write_text(csv_text, encoding="utf-8")
    model.write_text(toml_text, encoding="utf-8")
    before = set(where.rglob("*"))
    code = main(["fit", str(data), "--model", str(model), "--out", str(out), "--learn", learn, "--method", method,
                 "--iterations", "3", "--engine", "python"])
    stdout, err = capsys.readouterr()
    event(f"exit status {code}")
    assert code in (0, 2, 3), (code, err)
    if code == 2:
        assert err.startswith("gaussfuse: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
        assert set(where.rglob("*")) == before, "a file was left behind"
    else:
        if code == 3:  # (progress lines come first on stderr)
            assert err.splitlines()[-1].startswith("gaussfuse: warning: ") and "Traceback" not in err, err
        fitted = tomllib.loads(out.read_text(encoding="utf-8"))
        for name in ("F", "H", "Q", "R"):
            assert np.all(np.isfinite(np.array(fitted["model"][name], dtype=float))), name


# ---------------------------------------------------------------------------
# Nonlinear models whose functions misbehave
# ---------------------------------------------------------------------------

BEHAVIOURS = ["fine", "raises", "wrong shape", "nan", "inf", "list", "string", "complex", "bool", "scalar", "huge",
              "none", "sometimes nan"]


def _function(kind: str, size: int, behaviour: str):
    """A transition (kind "f", size n) or measurement (kind "h", size m) that behaves as named."""
    def fn(x, *args):
        x = np.asarray(x, dtype=float)
        good = 0.9 * np.sin(x) if kind == "f" else np.cos(x[:size]) + 0.1 * x[:size]
        if behaviour == "fine":
            return good
        if behaviour == "raises":
            raise RuntimeError("the user's function failed")
        if behaviour == "wrong shape":
            return np.concatenate([good, [1.0]])
        if behaviour == "nan":
            return good * np.nan
        if behaviour == "inf":
            return good + np.inf
        if behaviour == "list":
            return list(good)
        if behaviour == "string":
            return "abc"
        if behaviour == "complex":
            return good + 1j
        if behaviour == "bool":
            return good > 0
        if behaviour == "scalar":
            return float(good[0])
        if behaviour == "huge":
            return good * 1e300
        if behaviour == "none":
            return None
        return good if x.sum() > 0 else good * np.nan  # "sometimes nan"
    return fn


@settings(FUZZ, max_examples=_EXAMPLES or 100)
@given(st.integers(1, 3), st.integers(1, 2), st.sampled_from(BEHAVIOURS), st.sampled_from(BEHAVIOURS),
       st.sampled_from(["ekf", "iekf", "ukf", "ckf", "ghkf", "iplf"]), st.sampled_from(["filter", "smooth"]),
       st.sampled_from(["python", "numba", "sqrt"]), st.integers(0, 2**32 - 1))
def test_nonlinear_filters_end_in_a_result_or_a_clear_error(n, m, f_does, h_does, method, what, engine, seed):
    """Whatever f and h do, a result with finite beliefs, or a clear error (ModelFunctionError is a ValueError)."""
    rng = np.random.default_rng(seed)
    model = gf.NonlinearModel(_function("f", n, f_does), _function("h", m, h_does), 0.1 * np.eye(n),
                              0.2 * np.eye(m))
    prior = gf.Gaussian(rng.normal(size=n), np.eye(n))
    zs = rng.normal(size=(8, m))
    form = "sqrt" if engine == "sqrt" and method in gf.METHODS and "sqrt" in gf.METHODS[method].forms else "cov"
    if method in ("iekf", "iplf", "ekf") or engine != "numba" or method not in ("ukf", "ckf", "ghkf"):
        engine = "python"
    call = gf.filter if what == "filter" else gf.smooth
    options = {"iterations": 5} if method in ("iekf", "iplf") else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gf.ConvergenceWarning)  # 5 iterations: the limit may be reached
        res = _try(lambda: call(model, prior, zs, method=method, engine=engine, form=form, check="off", **options))
    if res is not None:
        event("a result")
        _finite_result(res, n)
