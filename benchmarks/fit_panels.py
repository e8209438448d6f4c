"""The cost of fitting one model to many short series: EM by `gf.fit` on a panel.

    python benchmarks/fit_panels.py [--series 200,2000] [--steps 100] [--iterations 20] [--repeats 3]

A constant-velocity model (2 states, position measured) learns its full Q
and R from N series of `--steps` steps, three of them missing in every
series, by `--iterations` EM iterations (``tol=0``: exactly that many) plus
the standard errors `fit` always computes, with ``engine="numba"`` after
one untimed warm-up fit. It prints the best of `--repeats` wall times and
the log-likelihood, which a change of speed must leave as it is. Not a peer
comparison: no peer fits one model to a panel of series.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np

import gaussfuse as gf


def panel(series: int, steps: int, seed: int = 0) -> np.ndarray:
    """`series` simulated series (series, steps, 1) with steps 10-12 missing."""
    rng = np.random.default_rng(seed)
    model = gf.constant_velocity(dt=1.0, q=0.5, r=2.0, dim=1)
    prior = gf.Gaussian([0.0, 1.0], 10 * np.eye(2))
    zs = np.stack([gf.simulate(model, prior, steps, rng=rng).measurements for _ in range(series)])
    zs[:, 10:13] = np.nan
    return zs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--series", default="200,2000", help="comma-separated panel sizes")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    start = gf.constant_velocity(dt=1.0, q=2.0, r=5.0, dim=1)
    prior = gf.Gaussian([0.0, 1.0], 10 * np.eye(2))
    print("| series | steps | EM iterations | seconds (best) | log-likelihood |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an EM stopped by its iteration limit warns, by design
        gf.fit(start, prior, panel(50, args.steps), iterations=2, engine="numba")  # compile or load the kernels
        for series in (int(s) for s in args.series.split(",")):
            zs = panel(series, args.steps)
            best, result = np.inf, None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                result = gf.fit(start, prior, zs, iterations=args.iterations, tol=0, engine="numba")
                best = min(best, time.perf_counter() - t0)
            print(f"| {series:,} | {args.steps} | {args.iterations} | {best:.2f} | {result.loglik:.6f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
