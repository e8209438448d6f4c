"""How the kernels are compiled and launched.

Compiled: cached on disk when numba can, in memory when it cannot. Numba raises ``RuntimeError: cannot cache function ...: no locator available``
when a function with ``cache=True`` is created and no cache directory is
writable. The tests take that condition into a subprocess by emptying
numba's list of cache locators before gaussfuse imports its kernels: as
root, file permissions would not stop the writes.

Launched: threads may call the batched kernels at once; their chunks share
one pool of threads.
"""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

# Run first in every child: no cache locator can be found, as with a
# read-only site-packages and home and no NUMBA_CACHE_DIR.
NO_CACHE = textwrap.dedent("""
    import numba.core.caching as caching
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    impl._locator_classes = []
""")

WARNING = NO_CACHE + textwrap.dedent("""
    import json, warnings
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # record every warning, not one per location
        from gaussfuse._kernels import _rts, linear, sigma_points  # each defines kernels: numba looks for a cache
    print(json.dumps([f"{w.category.__name__}: {w.message}" for w in caught]))
""")

# The command line first (compiling the linear filter in memory), then the library in the same process.
RUNS = NO_CACHE + textwrap.dedent("""
    import contextlib, io, json, sys, warnings
    import numpy as np
    import gaussfuse as gf
    from gaussfuse import cli

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        out = {"cli": cli.main(sys.argv[1:]), "cli stderr": err.getvalue()}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.1, 0.01]), R=1.0)
        prior = gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
        zs = np.sin(np.arange(1500) / 40.0)
        got, want = gf.filter(model, prior, zs, engine="numba"), gf.filter(model, prior, zs, engine="python")
        out["filter"] = float(np.max(np.abs(got.means - want.means)))  # the kernel the command line compiled
        from gaussfuse._kernels import linear

        out["held_steps signatures"] = len(linear.held_steps.signatures)  # compiled with the filter

        # A kernel made after the warning, with an explicit signature, as the sigma-point loop for jitted f and h
        # is made on first use (compiling that loop itself would take 15 s here, for the same path).
        from gaussfuse._kernels._jit import jit

        twice = jit("float64(float64)")(lambda x: 2.0 * x)
        out["late kernel"] = twice(1.5)
    out["warnings"] = [f"{w.category.__name__}: {w.message}" for w in caught]
    print(json.dumps(out))
""")


def run_child(code: str, *args: str) -> subprocess.CompletedProcess:
    """Run `code` in a new interpreter, without a NUMBA_CACHE_DIR that would provide a cache."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CACHE_DIR", "NUMBA_CACHE_LOCATOR_CLASSES")}
    return subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True,
                          text=True, timeout=900)


def test_without_a_cache_location_kernels_warn_once_naming_the_setting():
    child = run_child(WARNING)
    assert child.returncode == 0, child.stderr
    warnings = json.loads(child.stdout.strip().splitlines()[-1])
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith("CacheUnavailableWarning: ") and "NUMBA_CACHE_DIR" in warnings[0]


def test_without_a_cache_location_the_cli_and_the_library_compile_in_memory(tmp_path):
    """One process: the command line filters a long file, with the warning as one line of its own; then the
    library's compiled filter equals the readable path, a kernel made later compiles, and nothing warns again."""
    t = np.arange(1200)
    data, result = tmp_path / "data.csv", tmp_path / "out.csv"
    np.savetxt(data, np.column_stack([t, np.sin(t / 30.0)]), delimiter=",", header="t,z", comments="")
    model = tmp_path / "model.toml"
    model.write_text('[model]\nkind = "constant_velocity"\ndt = 1.0\nq = 0.01\nr = 0.5\n')
    child = run_child(RUNS, "filter", str(data), "--model", str(model), "--engine", "numba", "--out", str(result))
    assert child.returncode == 0, child.stderr
    out = json.loads(child.stdout.strip().splitlines()[-1])
    assert out["cli"] == 0, out["cli stderr"]
    assert "Traceback" not in out["cli stderr"]
    lines = out["cli stderr"].splitlines()
    assert len(lines) == 1 and lines[0].startswith("gaussfuse: warning: gaussfuse's compiled kernels cannot be "
                                                   "cached") and "NUMBA_CACHE_DIR" in lines[0], lines
    assert len(result.read_text().splitlines()) == 1201  # the header and one row a step
    assert out["filter"] < 1e-10
    assert out["held_steps signatures"] == 1  # not a second one for a literal first step (2 s more)
    assert out["late kernel"] == 3.0
    assert out["warnings"] == []  # once a process


# ---------------------------------------------------------------------------
# Launching: concurrent calls from threads share one pool and get the one-thread results
# ---------------------------------------------------------------------------


def test_threads_calling_batched_filters_at_once_get_the_single_thread_results():
    import threading

    import gaussfuse as gf
    from gaussfuse._kernels import _jit

    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.1, 0.01]), R=1.0)
    prior = gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    zs = np.random.default_rng(0).normal(size=(64, 200, 1))  # many series: chunks on the pool

    def f(x):
        return np.array([x[0] + 0.01 * x[1], x[1] - 0.0981 * np.sin(x[0])])

    def h(x):
        return np.sin(x[:1])

    pendulum = gf.NonlinearModel(f, h, 1e-4 * np.eye(2), 0.1)
    start = gf.Gaussian([0.0, 0.0], 0.1 * np.eye(2))
    calls = {
        "filter": lambda: gf.filter(model, prior, zs, engine="numba"),
        "smooth": lambda: gf.smooth(model, prior, zs, engine="numba"),
        "ukf": lambda: gf.smooth(pendulum, start, zs[:4, :50], engine="numba"),
    }
    reference = {name: call() for name, call in calls.items()}  # one call at a time

    def same(a, b):
        if hasattr(a, "filtered"):
            return same(a.filtered, b.filtered) and all(
                np.array_equal(getattr(a, k), getattr(b, k)) for k in ("means", "covs", "gains"))
        return all(np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True)
                   for k in ("means", "covs", "predicted_means", "predicted_covs", "innovations",
                             "innovation_covs", "loglik", "last_mean", "last_cov"))

    start_together = threading.Barrier(4)
    differ, errors = [], []

    def work():
        try:
            start_together.wait()
            for _ in range(8):
                for name, call in calls.items():
                    if not same(call(), reference[name]):
                        differ.append(name)
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)

    callers = [threading.Thread(target=work) for _ in range(4)]
    for t in callers:
        t.start()
    for t in callers:
        t.join()
    assert errors == []
    assert sorted(set(differ)) == []
    pool = [t.name for t in threading.enumerate() if t.name.startswith("gaussfuse_")]
    assert 0 < len(pool) <= _jit.threads()  # four callers, one pool of the machine's threads
