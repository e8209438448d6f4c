"""What ``engine="auto"`` picks on a first call, against what each engine would have cost.

    python benchmarks/auto_choice.py [--repeats 1] [--only ukf-jitted,kf-batch,ukf-warm,kf-cold]

The rule (:func:`gaussfuse.inference.drivers.compiled_engine`): the compiled
path only when starting the kernels the call runs (compiling the cold ones,
loading the cached ones) is expected to cost less than what the readable
path would spend. For each scenario, fresh Python processes make the same
first call with ``engine="auto"``, ``"numba"`` and ``"python"``, each from
its own copy of the same numba cache (empty, or filled beforehand as the
scenario says); the report gives the median time of each first call
(``import gaussfuse`` excluded, numba's import included) and the path
"auto" took. "auto" did right when its time is the smaller of the other two
(to the noise of the machine).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from first_call import RANGE_BEARING, _environment, compile_package  # noqa: E402  (a sibling script)

CHILD = r"""
import json, math, sys, time
import numpy as np
import gaussfuse as gf
scenario, engine = sys.argv[1], sys.argv[2]
rng = np.random.default_rng(0)
""" + RANGE_BEARING + r"""
ukf = dict(method="ukf", alpha=1.0, beta=0.0, kappa=-1.0)
prior4 = PRIOR
if scenario.startswith("kf"):
    N, T = (600, 1000) if scenario == "kf-batch" else (1, 5000)
    model = gf.constant_velocity(1.0, 0.1, 1.0, dim=1)
    zs = rng.normal(size=(N, T, 1)).cumsum(axis=1)
    call = lambda e: gf.filter(model, gf.Gaussian([0.0, 0.0], np.eye(2)), zs, engine=e)
elif scenario == "prime-python-mode":  # fills the cache with the sigma-point engine's Python-mode kernels
    call = lambda e: gf.filter(gf.NonlinearModel(f, h, 0.01 * np.eye(4), np.diag([0.25, 2.5e-5])), prior4,
                               bearings(50), engine=e, **ukf)
elif scenario == "ukf-jitted":
    import numba

    @numba.njit
    def fj(x):
        out = np.empty(4)
        out[0], out[1], out[2], out[3] = x[0] + dt * x[2], x[1] + dt * x[3], x[2], x[3]
        return out

    @numba.njit
    def hj(x):
        out = np.empty(2)
        out[0], out[1] = math.hypot(x[0], x[1]), math.atan2(x[1], x[0])
        return out

    zs = bearings(10_000)
    fj(prior4.mean), hj(prior4.mean)  # the user's functions compiled before the call
    model = gf.NonlinearModel(fj, hj, 0.01 * np.eye(4), np.diag([0.25, 2.5e-5]))
    call = lambda e: gf.filter(model, prior4, zs, engine=e, **ukf)
else:  # "ukf-warm"
    zs = bearings(5_000)
    model = gf.NonlinearModel(f, h, 0.01 * np.eye(4), np.diag([0.25, 2.5e-5]))
    call = lambda e: gf.filter(model, prior4, zs, engine=e, **ukf)
t = time.perf_counter()
call(engine)
first = time.perf_counter() - t
linear, sigma = (sys.modules.get(f"gaussfuse._kernels.{m}") for m in ("linear", "sigma_points"))
compiled = bool((linear and linear.forward.signatures)
                or (sigma and (sigma._LOOPS or sigma.advance.signatures)))
print(json.dumps({"first": first, "compiled": compiled}))
"""

SCENARIOS = {
    # name: (description, how the cache is filled beforehand: a scenario run with engine="numba", or None)
    "ukf-jitted": ("UKF, numba-jitted f and h, 10,000 steps; the cache holds the Python mode's kernels only",
                   "prime-python-mode"),
    "kf-batch": ("linear filter, 600 series x 1,000 steps; empty cache", None),
    "ukf-warm": ("UKF, plain Python f and h, 5,000 steps; the cache holds its kernels", "ukf-warm"),
    "kf-cold": ("linear filter, 5,000 steps; empty cache", None),
}


def run_child(scenario: str, engine: str, cache_dir: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, scenario, engine], env=_environment(NUMBA_CACHE_DIR=cache_dir),
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure(scenario: str, repeats: int) -> dict:
    """Median first-call time per engine, and the path "auto" took, from identical caches."""
    times: dict[str, list[float]] = {"auto": [], "numba": [], "python": []}
    took = set()
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as root:
            primed = Path(root, "primed")
            primed.mkdir()
            prime = SCENARIOS[scenario][1]
            if prime is not None:
                run_child(prime, "numba", str(primed))
            for engine in times:
                cache = Path(root, engine)
                shutil.copytree(primed, cache)
                got = run_child(scenario, engine, str(cache))
                times[engine].append(got["first"])
                if engine == "auto":
                    took.add("compiled" if got["compiled"] else "readable")
                print(f"  {scenario} {engine}: {got}", file=sys.stderr)
    return {**{e: statistics.median(t) for e, t in times.items()}, "took": "/".join(sorted(took))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--only", default=",".join(SCENARIOS), help=f"some of {','.join(SCENARIOS)}")
    args = parser.parse_args(argv)
    compile_package()
    print("| scenario | auto took | auto (s) | numba (s) | python (s) | the cheaper engine's path |")
    print("| --- | --- | ---: | ---: | ---: | --- |")
    for scenario in args.only.split(","):
        if scenario not in SCENARIOS:
            parser.error(f"--only: unknown scenario {scenario!r}; choose from {', '.join(SCENARIOS)}")
        got = measure(scenario, args.repeats)
        cheaper = "compiled" if got["numba"] < got["python"] else "readable"
        print(f"| {SCENARIOS[scenario][0]} | {got['took']} | {got['auto']:.2f} | {got['numba']:.2f} | "
              f"{got['python']:.2f} | {'yes' if got['took'] == cheaper else 'NO'} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
