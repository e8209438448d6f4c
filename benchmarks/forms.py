"""The cost of the square-root form against the covariance form, compiled, on W1's series.

    python benchmarks/forms.py [--steps 200000] [--repeats 5]

Rows: the covariance form as `filter` runs it (reusing the covariance fixed
point once reached), the covariance form computing every step (the same
matrices given per step, a time-varying model, so no fixed point), and the
square-root form (which reuses its fixed point too); each with
``keep="all"`` and ``keep="last"``. Best of `--repeats` after a warm-up
call; the ratio is the time against the covariance form computing every
step with the same `keep`. Then the smoothers: the covariance and
square-root forms compiled, and the square-root form on the readable path
(on the first 20,000 steps).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import gaussfuse as gf  # noqa: E402
from workloads import long_series  # noqa: E402


def best(call, repeats: int) -> float:
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    T = args.steps
    model, prior, zs = long_series(T)
    every_step = gf.LinearModel(np.repeat(model.F[None], T, 0), model.H, model.Q, model.R)
    print("| form | keep | steps/s | time ÷ covariance form, every step |")
    print("| --- | --- | ---: | ---: |")
    for keep in ("all", "last"):
        runs = {
            "covariance, every step": lambda: gf.filter(every_step, prior, zs, engine="numba", keep=keep),
            "covariance (fixed point reused)": lambda: gf.filter(model, prior, zs, engine="numba", keep=keep),
            "square-root": lambda: gf.filter(model, prior, zs, engine="numba", keep=keep, form="sqrt"),
        }
        times = {name: best(run, args.repeats) for name, run in runs.items()}
        base = times["covariance, every step"]
        for name, t in times.items():
            print(f"| {name} | {keep} | {T / t / 1e6:.2f} M | {t / base:.2f} |")
    # the smoothers: compiled in both forms; the readable square-root one on a prefix
    short = min(T, 20_000)
    print()
    print("| smoother | steps timed | steps/s | time per step ÷ compiled covariance smoother |")
    print("| --- | ---: | ---: | ---: |")
    runs = {
        "covariance, compiled": (T, lambda: gf.smooth(model, prior, zs, engine="numba")),
        "square-root, compiled": (T, lambda: gf.smooth(model, prior, zs, engine="numba", form="sqrt")),
        "square-root, readable": (short, lambda: gf.smooth(model, prior, zs[:short], engine="python", form="sqrt")),
    }
    per_step = {name: best(run, args.repeats) / steps for name, (steps, run) in runs.items()}
    for name, t in per_step.items():
        print(f"| {name} | {runs[name][0]:,} | {1 / t / 1e6:.3f} M | {t / per_step['covariance, compiled']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
