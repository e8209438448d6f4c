"""How fast a compiled UKF step can be at W4's size: bare kernels beside gaussfuse and filterpy, in one run.

    python benchmarks/ukf_floor.py [--steps 5000] [--repeats 20]

W4 (``run.py``) asks gaussfuse's compiled sigma-point engine, with
numba-jitted f and h, for 100 times filterpy's steps per second. This
script measures how far that is from what the arithmetic allows. It times,
on W4's model and data (:func:`workloads.w4_problem`), side by side:

* filterpy's ``UnscentedKalmanFilter.batch_filter`` (W4's peer);
* ``gf.filter(..., method="ukf", engine="numba")`` with W4's numba-jitted
  vectorized f and h (W4's row);
* a **bare kernel**: the classic unscented filter of W4's model written
  out as one numba loop: the predicted covariance from the points'
  weighted outer products, the measurement's affine map and noise from
  the cross-covariance (``A = Cᵀ (P⁻)⁻¹``, ``R + Ω = S - A C``), then the
  Joseph form. That equals the library's statistical linear regression
  and Joseph form in exact arithmetic, not operation for operation: it
  forms no per-point residuals and resolves none of their round-off
  (under a prior 1e12 times the sensor's noise, the last table, that
  costs it a thousand times the error of the library's covariance form).
  It also does none of what the library's kernel
  does besides (no log-likelihood, innovations or predicted beliefs
  kept; no check of f's and h's values, of positive definiteness or of
  overflow; no missing components, angles, controls or time-varying
  matrices). Three versions:

  1. sizes read from the arrays at run time, f and h numba functions
     called as first-class functions (what the library's kernel must do:
     it serves every n and m, and a new f must not recompile its step);
  2. sizes at run time, f and h compiled into the loop (one compilation
     per f and h);
  3. n = 4 and m = 2 fixed when compiling, f and h compiled in (one
     compilation per model);

* **the library's blocks alone** (:func:`library_blocks_kernel`): the
  compiled blocks that ``engine="numba"`` runs, the exact mirror of the
  readable path (the regression with its residuals, then the Joseph
  form), in one loop with sizes at run time and f and h compiled in, and
  nothing else: the most the library's algebra allows, whatever the
  kernel around it.

Each row: steps per second (best of ``--repeats``), the ratio to filterpy,
and the largest difference of the filtered means and covariances from
gaussfuse's readable path (``engine="python"``), which every row must
match to round-off. Then a second table (:func:`exactness`): the error of
each algebra against a 50-digit Kalman filter where the unscented filter
must equal it, under priors up to 1e12 times the sensor's noise.
"""

from __future__ import annotations

import argparse
import os
import sys

import numba
import numpy as np
from numba import types

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import gaussfuse as gf  # noqa: E402
from gaussfuse._kernels import _slr, _step, sigma_points  # noqa: E402
from gaussfuse._kernels._dense import cho_solve, cholesky  # noqa: E402
import workloads  # noqa: E402
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
from _mp_oracle import filter_50_digits  # noqa: E402  the test suite's 50-digit reference
from forms import best  # noqa: E402  (a warm-up call, then the best of `repeats`)

_C2 = types.float64[:, ::1]


def bare_kernel(fixed: tuple[int, int] | None):
    """The bare unscented filter (see the module notes) as a Python function for numba to compile.

    With `fixed`, (n, m) are constants of the compiled code; else they are
    read from the prior and the measurements. The Cholesky factor and solves
    are the library's loops (:mod:`gaussfuse._kernels._dense`). Returns
    ``ukf(f, h, zs, m0, P0, Q, R, xi, wm, wc, means, covs)``: f and h act
    on the (k, n) stack of points; ``xi`` (k, n) are the unit points,
    ``wm``, ``wc`` their weights.
    """
    n_fixed, m_fixed = fixed or (0, 0)

    def moments(Y, wm, wc, d, mean, cov, base):  # mean = Σ wm Y_i, cov = base + Σ wc (Y_i - mean)(Y_i - mean)ᵀ
        for a in range(d):
            t = 0.0
            for i in range(Y.shape[0]):
                t += wm[i] * Y[i, a]
            mean[a] = t
        for a in range(d):
            for b in range(d):
                t = base[a, b]
                for i in range(Y.shape[0]):
                    t += wc[i] * (Y[i, a] - mean[a]) * (Y[i, b] - mean[b])
                cov[a, b] = t

    def draw(mean, L, xi, X, n):  # X_i = mean + L ξ_i
        for i in range(xi.shape[0]):
            for a in range(n):
                t = mean[a]
                for b in range(a + 1):
                    t += L[a, b] * xi[i, b]
                X[i, a] = t

    moments, draw = numba.njit(moments), numba.njit(draw)

    def ukf(f, h, zs, m0, P0, Q, R, xi, wm, wc, means, covs):
        n = n_fixed if n_fixed else m0.shape[0]
        m = m_fixed if m_fixed else zs.shape[1]
        k = xi.shape[0]
        x, P = m0.copy(), P0.copy()
        L, X = np.zeros((n, n)), np.empty((k, n))
        xp, Pp, zp, S = np.empty(n), np.empty((n, n)), np.empty(m), np.empty((m, m))
        C, At, A, Kt = np.empty((n, m)), np.empty((n, m)), np.empty((m, n)), np.empty((m, n))
        LS, IKA, M, KRK, Rp = np.zeros((m, m)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((m, m))
        for t in range(zs.shape[0]):
            cholesky(P, L, n)  # predict: the regression of f at N(x, P), Ω added to Q, as kalman.predict
            draw(x, L, xi, X, n)
            moments(f(X), wm, wc, n, xp, Pp, Q)
            cholesky(Pp, L, n)  # update: the regression of h at N(xp, Pp)
            draw(xp, L, xi, X, n)
            Z = h(X)
            moments(Z, wm, wc, m, zp, S, R)
            for a in range(n):  # C = Σ wc (X_i - xp)(Z_i - zp)ᵀ
                for b in range(m):
                    s = 0.0
                    for i in range(k):
                        s += wc[i] * (X[i, a] - xp[a]) * (Z[i, b] - zp[b])
                    C[a, b] = s
                    At[a, b] = s
            cho_solve(L, At, n, m)  # Aᵀ = Pp⁻¹ C: H = A, and R + Ω = S - A Pp Aᵀ
            for a in range(m):
                for b in range(n):
                    A[a, b] = At[b, a]
                    Kt[a, b] = C[b, a]
            for a in range(m):
                for b in range(m):
                    s = 0.0
                    for i in range(n):
                        s += A[a, i] * C[i, b]  # A Pp Aᵀ = A C
                    Rp[a, b] = S[a, b] - s
            cholesky(S, LS, m)  # Kᵀ = S⁻¹ Cᵀ
            cho_solve(LS, Kt, m, n)
            for a in range(n):
                s = xp[a]
                for b in range(m):
                    s += Kt[b, a] * (zs[t, b] - zp[b])
                x[a] = s
                for b in range(n):  # I - K A
                    s = 1.0 if a == b else 0.0
                    for c in range(m):
                        s -= Kt[c, a] * A[c, b]
                    IKA[a, b] = s
            for a in range(n):  # the Joseph form: (I - K A) Pp (I - K A)ᵀ + K (R + Ω) Kᵀ
                for b in range(n):
                    s = 0.0
                    for c in range(n):
                        s += IKA[a, c] * Pp[c, b]
                    M[a, b] = s
            for a in range(n):
                for b in range(n):
                    s = 0.0
                    for c in range(n):
                        s += M[a, c] * IKA[b, c]
                    r = 0.0
                    for c in range(m):
                        for d in range(m):
                            r += Kt[c, a] * Rp[c, d] * Kt[d, b]
                    KRK[a, b] = s + r
            for a in range(n):
                for b in range(n):
                    P[a, b] = 0.5 * (KRK[a, b] + KRK[b, a])
                means[t, a] = x[a]
                for b in range(n):
                    covs[t, a, b] = P[a, b]
        return 0

    return ukf


def library_blocks_kernel():
    """W4's filter as one numba loop of the library's own compiled blocks, and nothing else.

    The exact mirror of the readable path that ``engine="numba"`` runs
    (:func:`gaussfuse._kernels._slr.draw` and :func:`~gaussfuse._kernels._slr.regress`,
    the statistical linear regression with its residuals; :func:`gaussfuse._kernels._step.predict`
    and :func:`~gaussfuse._kernels._step.update`, the Joseph form), with sizes
    read at run time and f and h compiled in, but without the library's
    kernel's state machine, outputs, checks and fallbacks: the most that
    algebra allows. Returns ``ukf(f, h, zs, m0, P0, Q, R, rule, means, covs)``.
    """
    def ukf(f, h, zs, m0, P0, Q, R, rule, means, covs):
        n, m, k = m0.shape[0], zs.shape[1], rule.points.shape[0]
        gf_, gh_, w = _slr.regression(k, n, n), _slr.regression(k, n, m), _step.workspace(n, m)
        x, P, xp, Pp = m0.copy(), P0.copy(), np.empty(n), np.empty((n, n))
        Qk, Rk, v, S = np.empty((n, n)), np.empty((m, m)), np.empty(m), np.empty((m, m))
        X, Xh = np.empty((k, n)), np.empty((k, n))
        state_angles, measurement_angles = np.zeros(n, dtype=np.bool_), np.zeros(m, dtype=np.bool_)
        for t in range(zs.shape[0]):
            if not _slr.draw(x, P, rule, gf_, X):
                return -1  # (W4 never needs the semi-definite root)
            _slr.regress(f(X), n, rule, x, state_angles, gf_)
            sigma_points._noise(Q, gf_.noise, Qk)  # Q + Ω, as the library's kernel adds it
            _step.predict(w, x, P, gf_.A, Qk, gf_.b, xp, Pp)
            if not _slr.draw(xp, Pp, rule, gh_, Xh):
                return -1
            _slr.regress(h(Xh), m, rule, xp, measurement_angles, gh_)
            sigma_points._noise(R, gh_.noise, Rk)
            ok, _, _ = _step.update(w, xp, Pp, zs[t], gh_.A, Rk, gh_.b, measurement_angles, x, P, v, S)
            if not ok:
                return -1
            for a in range(n):
                means[t, a] = x[a]
                for b in range(n):
                    covs[t, a, b] = P[a, b]
        return 0

    return ukf


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args(argv)
    T = args.steps
    _, Q, R, prior, zs = workloads.w4_problem(T)
    opts = dict(method="ukf", alpha=1.0, beta=0.0, kappa=-1.0)
    reference = gf.filter(gf.NonlinearModel(workloads.f_plain, workloads.h_plain, Q, R), prior, zs,
                          engine="python", **opts)
    rule = gf.linearize.rules.unscented(4, alpha=1.0, beta=0.0, kappa=-1.0)
    xi, wm, wc = (np.ascontiguousarray(a, dtype=float) for a in (rule.points, rule.wm, rule.wc))
    rows = []

    try:
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
    except ImportError:
        filterpy = None
        print("filterpy is not installed (pip install -e '.[bench]'): no ratios.", file=sys.stderr)
    else:
        points = MerweScaledSigmaPoints(n=4, alpha=1.0, beta=0.0, kappa=-1.0)
        filterpy = UnscentedKalmanFilter(dim_x=4, dim_z=2, dt=workloads.UKF_DT, hx=workloads.h_plain,
                                         fx=workloads.fx_filterpy, points=points)
        filterpy.Q, filterpy.R = Q.copy(), R.copy()

        def run_filterpy():
            filterpy.x, filterpy.P = prior.mean.copy(), prior.cov.copy()
            return filterpy.batch_filter(zs)

        rows.append(("filterpy UnscentedKalmanFilter.batch_filter", best(run_filterpy, max(args.repeats // 10, 1)),
                     run_filterpy()))

    model = gf.NonlinearModel(workloads.f_nb_vec, workloads.h_nb_vec, Q, R, vectorized=True)
    library = lambda: gf.filter(model, prior, zs, engine="numba", **opts)  # noqa: E731
    result = library()
    rows.append(('gaussfuse engine="numba", numba.njit vectorized f, h (W4)', best(library, args.repeats),
                 (result.means, result.covs)))

    f, h = workloads.f_nb_vec, workloads.h_nb_vec
    given = (zs, prior.mean, prior.cov, Q, R, xi, wm, wc, np.empty((T, 4)), np.empty((T, 4, 4)))
    first_class = types.FunctionType(_C2(_C2))
    for label, fixed, compiled_in in (("bare kernel 1: run-time sizes, first-class f, h", None, False),
                                      ("bare kernel 2: run-time sizes, f, h compiled in", None, True),
                                      ("bare kernel 3: n, m fixed, f, h compiled in", (4, 2), True)):
        if compiled_in:
            kernel = numba.njit(bare_kernel(fixed))
        else:
            f.compile((_C2,))
            h.compile((_C2,))
            kernel = numba.njit((first_class, first_class) + tuple(numba.typeof(a) for a in given))(bare_kernel(fixed))
        def run(kernel=kernel):  # new outputs at each run, as the library and filterpy allocate theirs
            means, covs = np.empty((T, 4)), np.empty((T, 4, 4))
            kernel(f, h, *given[:-2], means, covs)
            return means, covs

        seconds = best(run, args.repeats)
        rows.append((label, seconds, run()))

    blocks = numba.njit(library_blocks_kernel())
    rule_t = _slr.Rule(xi, wm, wc)

    def run_blocks():
        means, covs = np.empty((T, 4)), np.empty((T, 4, 4))
        if blocks(f, h, zs, prior.mean, prior.cov, Q, R, rule_t, means, covs) != 0:
            raise RuntimeError("the library's blocks needed a fallback on W4")
        return means, covs

    rows.append(("the library's blocks alone: run-time sizes, f, h compiled in", best(run_blocks, args.repeats),
                 run_blocks()))

    peer = rows[0][1] if filterpy is not None else None
    print(f"W4's model and data, {T:,} steps; best of {args.repeats} runs (filterpy: {max(args.repeats // 10, 1)}).\n")
    print("| row | steps/s | ratio to filterpy | max abs diff from the readable path, means | covs |")
    print("| --- | ---: | ---: | ---: | ---: |")
    for label, seconds, (means, covs) in rows:
        ratio = f"{peer / seconds:.1f}x" if peer else "-"
        print(f"| {label} | {T / seconds / 1e3:.1f} k | {ratio} | {np.abs(means - reference.means).max():.1e} | "
              f"{np.abs(covs - reference.covs).max():.1e} |")
    print()
    exactness(workloads.f_nb_vec)
    return 0


def exactness(f) -> None:
    """Print what each algebra gives where the unscented filter must equal the Kalman filter: W4's f with a
    linear position sensor, under a prior ever larger than the sensor's noise.

    The oracle is the test suite's 50-digit Kalman filter
    (``tests/_mp_oracle.py``, mpmath only, nothing of gaussfuse). Per row,
    over 20 steps: the largest relative error of the filtered variances and
    the largest error of the means in the oracle's standard deviations, for
    ``engine="numba"`` (the library's regression) in the covariance and the
    square-root form, and for the bare kernel (the classic form, whose
    ``R + Ω = S - A C`` is the difference that
    :mod:`gaussfuse.linearize.sigma_points` computes from residuals instead).
    """
    @numba.njit
    def positions(X):
        return np.ascontiguousarray(X[:, :2])

    base = gf.constant_velocity(dt=workloads.UKF_DT, q=workloads.UKF_Q, r=1.0, dim=2)
    rule = gf.linearize.rules.unscented(4, alpha=1.0, beta=0.0, kappa=-1.0)
    xi, wm, wc = (np.ascontiguousarray(a, dtype=float) for a in (rule.points, rule.wm, rule.wc))
    classic = numba.njit(bare_kernel(None))
    rng = np.random.default_rng(3)
    T = 20
    print("Where the UKF must equal the Kalman filter (W4's f, a linear position sensor, 20 steps): the largest "
          "relative error of the variances / of the means, in standard deviations.\n")
    print("| prior variance | sensor variance | gaussfuse engine=\"numba\" | the same, form=\"sqrt\" | "
          "bare kernel (classic form) |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    for prior_var, r in ((1.0, 1.0), (1e8, 1e-4), (1e12, 1e-6)):
        R = np.eye(2) * r
        prior = gf.Gaussian(np.array([300.0, 100.0, 5.0, 3.0]), np.eye(4) * prior_var)
        zs = np.array([300.0, 100.0]) + np.arange(1, T + 1)[:, None] * [5.0, 3.0] + rng.standard_normal((T, 2)) * r**0.5
        exact_means, exact_covs = filter_50_digits(base.F, base.H, base.Q, R, prior.mean, prior.cov, zs)
        model = gf.NonlinearModel(f, positions, base.Q, R, vectorized=True)
        ours, ours_sqrt = (gf.filter(model, prior, zs, engine="numba", method="ukf", alpha=1.0, beta=0.0, kappa=-1.0,
                                     check="off", form=form) for form in ("cov", "sqrt"))
        means, covs = np.empty((T, 4)), np.empty((T, 4, 4))
        classic(f, positions, zs, prior.mean, prior.cov, base.Q, R, xi, wm, wc, means, covs)
        variances = np.diagonal(exact_covs, axis1=1, axis2=2)

        def errors(m, c):
            return (f"{np.abs(np.diagonal(c, axis1=1, axis2=2) / variances - 1).max():.1e} / "
                    f"{np.abs((m - exact_means) / np.sqrt(variances)).max():.1e}")

        print(f"| {prior_var:g} | {r:g} | {errors(ours.means, ours.covs)} | "
              f"{errors(ours_sqrt.means, ours_sqrt.covs)} | {errors(means, covs)} |")


if __name__ == "__main__":
    sys.exit(main())
