"""The cost of the first call in a fresh process: import, compilation or cache loading, warm-up.

    python benchmarks/first_call.py [--cache cold,warm] [--steps 5000] [--repeats 3] [--engine auto]
    python benchmarks/first_call.py --floor [--repeats 5]

For each call (filter, smooth, fit by maximum likelihood, an unscented
filter, each on one series of `--steps` steps) a fresh Python process
imports gaussfuse, makes the call, and makes it again. The **first-call
overhead** is the time of the first call, ``import gaussfuse`` included,
minus the time of the repeated call: what a new user, or a new process of a
pipeline, pays once. `--cache cold` gives each process an empty
``NUMBA_CACHE_DIR``; `--cache warm` one that a previous process, making
the same call with ``engine="numba"``, has filled with the compiled kernels. The report is the median over `--repeats` processes.
The package's bytecode is compiled first and the children read it, as an
installed package's are (see :func:`_environment`).

`--floor` times, instead, what a warm first call pays before gaussfuse
does anything: fresh processes importing NumPy, SciPy's optimizers (which
`fit` runs), numba, and numba's first load of a cached function (its
registries of typing and lowering, set up once per process). A warm first
`fit` pays all of them, so no change to gaussfuse's own code brings its
overhead below their sum.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

RANGE_BEARING = r"""
dt = 0.1
F = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1.0]])
PRIOR = gf.Gaussian([10.0, 5.0, 1.0, 0.5], np.eye(4))


def f(x):
    return F @ x


def h(x):
    return np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])


def bearings(T):  # T range-bearing measurements of a target moving away from the prior mean (draws from rng)
    truth = PRIOR.mean + np.arange(1, T + 1)[:, None] * np.array([dt, dt * 0.5, 0, 0])
    return np.array([h(x) for x in truth]) + rng.normal(size=(T, 2)) * [0.5, 0.005]
"""
"""The UKF's model and data in a child (needs ``np``, ``gf`` and ``rng``): a constant-velocity target,
a range-bearing sensor; shared with ``auto_choice.py``."""

CHILD = r"""
import sys, time, json
t0 = time.perf_counter()
import gaussfuse as gf
t_import = time.perf_counter() - t0
import numpy as np
call, steps, engine = sys.argv[1], int(sys.argv[2]), sys.argv[3]
rng = np.random.default_rng(0)
""" + RANGE_BEARING + r"""
if call in ("filter", "smooth", "fit"):
    model = gf.constant_velocity(0.1, 1.0, 0.25, dim=2)
    prior = gf.Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))
    zs = np.cumsum(rng.normal(size=(steps, 2)), axis=0) * 0.1 + rng.normal(size=(steps, 2)) * 0.5
    if call == "fit":
        local = gf.LinearModel(F=1.0, H=1.0, Q=1.0, R=1.0)
        y = np.cumsum(rng.normal(size=steps)) + rng.normal(size=steps)
        run = lambda: gf.fit(local, gf.Gaussian(0.0, 10.0), y, method="mle", engine=engine)
    else:
        fn = getattr(gf, call)
        run = lambda: fn(model, prior, zs, engine=engine)
else:
    model = gf.NonlinearModel(f, h, 0.01 * np.eye(4), np.diag([0.25, 2.5e-5]))
    prior, zs = PRIOR, bearings(steps)
    run = lambda: gf.filter(model, prior, zs, method="ukf", alpha=1.0, beta=0.0, kappa=-1.0, engine=engine)
t1 = time.perf_counter()
run()
first = time.perf_counter() - t1
t2 = time.perf_counter()
run()
again = time.perf_counter() - t2
print(json.dumps({"import": t_import, "first": first, "again": again,
                  "overhead": t_import + first - again, "numba": "numba" in sys.modules}))
"""

CALLS = ("filter", "smooth", "fit", "ukf")

FLOOR_CHILD = r"""
import sys, time
t0 = time.perf_counter()
exec(sys.argv[1])
print(time.perf_counter() - t0)
"""
FLOOR_KERNEL = "import numba\n\n@numba.njit(cache=True)\ndef one(x):\n    return x + 1.0\n"
FLOORS = (("import numpy", "import numpy"),
          ("import numpy, scipy.optimize", "import numpy, scipy.optimize"),
          ("import numpy, numba", "import numpy, numba"),
          ("import numpy, numba, scipy.optimize", "import numpy, numba, scipy.optimize"),
          ("the same, and a cached numba function's first call",
           "import numpy, numba, scipy.optimize, floor_kernel; floor_kernel.one(1.0)"),
          ("import gaussfuse", "import gaussfuse"))


def floor(repeats: int) -> None:
    """Print the median time of each of :data:`FLOORS` in fresh processes (see the module notes)."""
    print("| fresh process | median (s) |")
    print("| --- | --- |")
    with tempfile.TemporaryDirectory() as where:
        with open(os.path.join(where, "floor_kernel.py"), "w") as f:
            f.write(FLOOR_KERNEL)
        env = _environment(NUMBA_CACHE_DIR=os.path.join(where, "cache"), PYTHONPATH=where)
        subprocess.run([sys.executable, "-c", "import floor_kernel; floor_kernel.one(1.0)"], env=env, check=True)
        for label, code in FLOORS:
            times = [float(subprocess.run([sys.executable, "-c", FLOOR_CHILD, code], env=env, check=True,
                                          capture_output=True, text=True).stdout) for _ in range(repeats)]
            print(f"| {label} | {statistics.median(times):.3f} |", flush=True)


def _environment(**extra: str) -> dict:
    """The children's environment: Python's default of reading and writing bytecode (.pyc) files.

    A user's installed gaussfuse has them (pip compiles them at install), so
    PYTHONDONTWRITEBYTECODE, if this shell sets it, would time compiling
    the package's sources at every import instead (about 80 ms here).
    """
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(extra)
    return env


def compile_package() -> None:
    """Write gaussfuse's .pyc files, as ``pip install`` does (an editable install writes them on first import)."""
    where = subprocess.run([sys.executable, "-c", "import gaussfuse, os; print(os.path.dirname(gaussfuse.__file__))"],
                           capture_output=True, text=True, check=True, env=_environment()).stdout.strip()
    subprocess.run([sys.executable, "-m", "compileall", "-q", where], check=True, env=_environment())


def run_child(call: str, steps: int, engine: str, cache_dir: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, call, str(steps), engine],
                         env=_environment(NUMBA_CACHE_DIR=cache_dir), capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure(call: str, cache: str, steps: int, engine: str, repeats: int) -> list[dict]:
    runs = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as cache_dir:
            if cache == "warm":
                run_child(call, steps, "numba", cache_dir)  # fills the cache with the compiled kernels
            runs.append(run_child(call, steps, engine, cache_dir))
            print(f"  {call} {cache}: {runs[-1]}", file=sys.stderr)
    return runs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", default="cold,warm", help="cold, warm or both (default)")
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--engine", default="auto")
    parser.add_argument("--only", default=",".join(CALLS), help=f"some of {','.join(CALLS)}")
    parser.add_argument("--floor", action="store_true",
                        help="time the imports and numba's set-up that a warm first fit pays, instead")
    args = parser.parse_args(argv)
    compile_package()
    if args.floor:
        floor(args.repeats)
        return 0
    print(f"| call | cache | import (s) | first call (s) | repeated call (s) | overhead (s) | numba loaded |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for call in args.only.split(","):
        for cache in args.cache.split(","):
            runs = measure(call, cache, args.steps, args.engine, args.repeats)
            med = {k: statistics.median(r[k] for r in runs) for k in ("import", "first", "again", "overhead")}
            print(f"| {call} | {cache} | {med['import']:.3f} | {med['first']:.3f} | {med['again']:.3f} | "
                  f"{med['overhead']:.3f} | {runs[0]['numba']} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
