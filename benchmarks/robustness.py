"""Accuracy of the covariance and square-root forms against a 50-digit reference.

    python benchmarks/robustness.py [--long-steps 1000000] [--out FILE]

For each problem of the robustness suite (``tests/_robustness.py``: a huge
prior with a precise sensor, in 1-D and 2-D; a rank-deficient Q; states on
scales 1e-6 and 1e6; a nearly unobservable bias) and for a long run (a
constant-velocity model over ``--long-steps`` steps), it filters and
smooths with each form and engine and prints one row per (problem, form,
engine, pass): the largest relative error of a variance, the largest error
of a mean in standard deviations, the steps whose covariance has a negative
eigenvalue (exactly, with 50 digits) and whether every covariance is
exactly symmetric. The same problems also go through the unscented and
cubature filters and smoothers (a NonlinearModel with the linear f and h,
whose regression is exact), in both forms on the readable path; a
covariance form that stops on an indefinite covariance is shown as such.
The reference is ``tests/_mp_oracle.py``'s 50-digit
filter and RTS smoother; for the long run, a 50-digit filter written for
its two states (the smoother is not run there).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import mpmath as mp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import gaussfuse as gf  # noqa: E402
from _mp_oracle import filter_50_digits, smooth_50_digits  # noqa: E402
from _robustness import PROBLEMS, errors  # noqa: E402

RUNS = (("cov", "python"), ("cov", "numba"), ("sqrt", "python"), ("sqrt", "numba"))
SIGMA_POINTS = ("ukf", "ckf")  # run on the same linear problems (their regression of a linear map is exact)


def long_run(T: int):
    """A constant-velocity model over T steps, its measurements, and the 50-digit filter written for two states."""
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q = 1e-3 * np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    H, R = np.array([[1.0, 0.0]]), np.array([[1.0]])
    m0, P0 = np.zeros(2), 1e4 * np.eye(2)
    rng = np.random.default_rng(6)
    x, zs = np.array([0.0, 1.0]), np.empty((T, 1))
    root = np.linalg.cholesky(Q)
    for k in range(T):
        x = F @ x + root @ rng.standard_normal(2)
        zs[k, 0] = x[0] + rng.standard_normal()
    means, variances = np.empty((T, 2)), np.empty((T, 2))
    with mp.workdps(50):
        q00, q01, q11 = (mp.mpf(float(v)) for v in (Q[0, 0], Q[0, 1], Q[1, 1]))
        r = mp.mpf(1.0)
        a, b = mp.mpf(0.0), mp.mpf(0.0)
        p00, p01, p11 = mp.mpf(1e4), mp.mpf(0.0), mp.mpf(1e4)
        for k in range(T):
            a, b = a + b, b                                     # m⁻ = F m
            p00, p01, p11 = p00 + 2 * p01 + p11 + q00, p01 + p11 + q01, p11 + q11
            s = p00 + r
            k0, k1 = p00 / s, p01 / s
            v = mp.mpf(float(zs[k, 0])) - a
            a, b = a + k0 * v, b + k1 * v
            p00, p01, p11 = p00 - k0 * k0 * s, p01 - k0 * k1 * s, p11 - k1 * k1 * s
            means[k] = float(a), float(b)
            variances[k] = float(p00), float(p11)
    return gf.LinearModel(F, H, Q, R), gf.Gaussian(m0, P0), zs, means, variances


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long-steps", type=int, default=1_000_000, help="steps of the long run (default 10^6)")
    parser.add_argument("--out", help="also write the table to this file")
    args = parser.parse_args(argv)
    rows = ["| problem | method | form | engine | pass | max rel. variance error | max mean error (sd) | "
            "negative-eigenvalue steps | symmetric |", "| --- | --- | --- | --- | --- | ---: | ---: | ---: | --- |"]

    def row(name, form, engine, what, e, method="kf"):
        if isinstance(e, Exception):
            rows.append(f"| {name} | {method} | {form} | {engine} | {what} | fails: {str(e)[:70]} | | | |")
        else:
            rows.append(f"| {name} | {method} | {form} | {engine} | {what} | {e.variance:.1e} | {e.mean:.1e} | "
                        f"{e.negative_steps} | {'yes' if e.symmetric else 'no'} |")
        print(rows[-1], file=sys.stderr)

    for make in PROBLEMS:
        p = make()
        ref = {"filter": filter_50_digits(*p[1:]), "smooth": smooth_50_digits(*p[1:])}
        model, prior = gf.LinearModel(p.F, p.H, p.Q, p.R), gf.Gaussian(p.m0, p.P0)
        for form, engine in RUNS:
            for what, call in (("filter", gf.filter), ("smooth", gf.smooth)):
                res = call(model, prior, p.zs, engine=engine, form=form)
                row(p.name, form, engine, what, errors(res.means, res.covs, *ref[what]))
        F, H = p.F, p.H
        curved = gf.NonlinearModel(lambda X: X @ F.T, lambda X: X @ H.T, p.Q, p.R, vectorized=True)
        for method in SIGMA_POINTS:
            for form, engine in (("cov", "python"), ("sqrt", "python"), ("sqrt", "numba")):
                try:
                    res = gf.smooth(curved, prior, p.zs, method=method, form=form, engine=engine, check="off")
                except (ValueError, FloatingPointError) as exc:  # the covariance form can stop on an indefinite P
                    row(p.name, form, engine, "filter + smooth", exc, method)
                    continue
                row(p.name, form, engine, "filter", errors(res.filtered.means, res.filtered.covs, *ref["filter"]),
                    method)
                row(p.name, form, engine, "smooth", errors(res.means, res.covs, *ref["smooth"]), method)
    T = args.long_steps
    start = time.perf_counter()
    model, prior, zs, means, variances = long_run(T)
    print(f"50-digit reference of the long run: {time.perf_counter() - start:.0f} s", file=sys.stderr)
    for form, engine in RUNS:
        res = gf.filter(model, prior, zs, engine=engine, form=form)
        got = np.diagonal(res.covs, axis1=1, axis2=2)
        var = float(np.max(np.abs(got - variances) / variances))
        mean = float(np.max(np.abs(res.means - means) / np.sqrt(variances)))
        # 2x2: a negative eigenvalue is a negative determinant or diagonal (exact enough for a count)
        det = res.covs[:, 0, 0] * res.covs[:, 1, 1] - res.covs[:, 0, 1] * res.covs[:, 1, 0]
        negative = int(np.sum((det < 0) | (got < 0).any(axis=1)))
        symmetric = bool(np.array_equal(res.covs, np.swapaxes(res.covs, 1, 2)))
        rows.append(f"| {T:,} steps, constant velocity | kf | {form} | {engine} | filter | {var:.1e} | {mean:.1e} | "
                    f"{negative} | {'yes' if symmetric else 'no'} |")
        print(rows[-1], file=sys.stderr)
    table = "\n".join(rows)
    print(table)
    if args.out:
        Path(args.out).write_text(f"Command: `python benchmarks/robustness.py --long-steps {T}`\n\n{table}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
