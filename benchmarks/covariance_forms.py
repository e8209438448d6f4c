"""Accuracy of four covariance updates against a 50-digit filter: why the Joseph form's cost is kept.

    python benchmarks/covariance_forms.py

The forms, with U = P⁻ Hᵀ, S = H U + R and K = U S⁻¹ (all symmetrised):

* joseph: (I - K H) P⁻ (I - K H)ᵀ + K R Kᵀ, what gaussfuse computes
  (about 4n³ + 4n²m + 2nm² multiply-adds);
* J3: M = P⁻ - K Uᵀ, then M - (M Hᵀ - K R) Kᵀ: the same Joseph form,
  factored to 6n²m + 2nm²;
* expanded: P⁻ + G Kᵀ + K Gᵀ with G = K S/2 - U, the Joseph form expanded
  (one symmetric rank-2m update, 2n²m + 2nm²);
* conventional: P⁻ - K Uᵀ (2n²m), statsmodels' form.

Each is run in float64 on the problems below and compared with the same
filter in 50 digits (mpmath, in the test extra). The table is the largest
relative error of a variance, the largest error of a mean in standard
deviations, and the steps whose covariance has a negative eigenvalue; then
the same over 60 random ill-conditioned problems.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _mp_oracle import filter_50_digits  # noqa: E402  the test suite's 50-digit reference

FORMS = ("joseph", "J3", "expanded", "conventional")


def float64_filter(F, H, Q, R, m0, P0, zs, form):
    """The filter in float64 with the covariance update `form` (see the module notes)."""
    m, P, out = m0.copy(), P0.copy(), []
    for z in zs:
        m, P = F @ m, F @ P @ F.T + Q
        P = (P + P.T) / 2
        U = P @ H.T
        S = H @ U + R
        L = np.linalg.cholesky((S + S.T) / 2)
        K = np.linalg.solve(L.T, np.linalg.solve(L, U.T)).T
        m = m + K @ (z - H @ m)
        if form == "joseph":
            I_KH = np.eye(len(m)) - K @ H
            P = I_KH @ P @ I_KH.T + K @ R @ K.T
        elif form == "J3":
            M = P - K @ U.T
            P = M - (M @ H.T - K @ R) @ K.T
        elif form == "expanded":
            P = P + (K @ S / 2 - U) @ K.T + K @ (K @ S / 2 - U).T
        else:
            P = P - K @ U.T
        out.append((m, (P + P.T) / 2))
    return out


def errors(ref, got):
    """Largest relative variance error, largest mean error in standard deviations, steps with a negative eigenvalue."""
    var = mean = 0.0
    negative = 0
    for (m_ref, P_ref), (m, P) in zip(ref, got):
        d = np.diag(P_ref)
        var = max(var, np.max(np.abs(np.diag(P) - d) / d))
        mean = max(mean, np.max(np.abs(m - m_ref) / np.sqrt(d)))
        negative += np.linalg.eigvalsh(P).min() < 0
    return var, mean, negative


def problems(rng):
    """Named problems (F, H, Q, R, m0, P0, T)."""
    F, H = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1.0, 0.0]])
    yield "constant velocity, P0 = 1e12 I, R = 1e-6, Q = 0", (F, H, np.zeros((2, 2)), np.array([[1e-6]]),
                                                              np.zeros(2), 1e12 * np.eye(2), 40)
    yield "constant velocity, P0 = 1e6 I, R = 1e-2, Q = 1e-3 I", (F, H, 1e-3 * np.eye(2), np.array([[1e-2]]),
                                                                  np.zeros(2), 1e6 * np.eye(2), 60)
    A, B, Hr = rng.standard_normal((4, 4)), rng.standard_normal((4, 4)), rng.standard_normal((2, 4))
    Fr, Qr = 0.95 * A / np.max(np.abs(np.linalg.eigvals(A))), B @ B.T / 4 + 0.1 * np.eye(4)
    yield "random, 4 states", (Fr, Hr, Qr, 0.5 * np.eye(2), np.zeros(4), np.eye(4), 60)
    D = np.diag([1e-6, 1e-6, 1e6, 1e6])
    yield "the same on scales 1e-6 and 1e6", (D @ Fr @ np.linalg.inv(D), Hr @ np.linalg.inv(D), D @ Qr @ D,
                                              0.5 * np.eye(2), np.zeros(4), D @ D, 60)
    Fq = np.eye(3) + 1e-9 * np.eye(3)[::-1]
    Fq[0, 1] = 1.0
    yield "nearly unobservable, rank-1 Q, P0 = 1e8 I", (Fq, np.array([[1.0, 0, 0], [0, 0, 1.0]]),
                                                        1e-4 * np.diag([0.0, 1.0, 0.0]), 1e-4 * np.eye(2),
                                                        np.zeros(3), 1e8 * np.eye(3), 80)


def random_problem(rng):
    """A small model with scales spread over up to 6 decades, a prior of up to 1e10 and R down to 1e-6."""
    n, T = int(rng.integers(2, 5)), 30
    m = int(rng.integers(1, n + 1))
    A = rng.standard_normal((n, n))
    F = A / np.max(np.abs(np.linalg.eigvals(A))) * rng.uniform(0.5, 1.05)
    D = np.diag(10.0 ** rng.uniform(-3, 3, n))
    B = rng.standard_normal((n, n)) * 10.0 ** rng.uniform(-4, 0)
    return (F, rng.standard_normal((m, n)), D @ B @ B.T @ D, np.diag(10.0 ** rng.uniform(-6, 0, m)),
            np.zeros(n), np.diag(10.0 ** rng.uniform(0, 10, n)), T)


def run(F, H, Q, R, m0, P0, T, rng):
    zs = rng.standard_normal((T, H.shape[0]))
    ref = list(zip(*filter_50_digits(F, H, Q, R, m0, P0, zs)))
    out = {}
    for form in FORMS:
        try:
            out[form] = errors(ref, float64_filter(F, H, Q, R, m0, P0, zs, form))
        except np.linalg.LinAlgError:
            out[form] = None  # S not positive definite
    return out


def main() -> None:
    rng = np.random.default_rng(1)
    print("| problem | form | max relative error, variances | max error, means (sd) | steps with a negative eigenvalue |")
    print("| --- | --- | ---: | ---: | ---: |")
    for name, (F, H, Q, R, m0, P0, T) in problems(rng):
        for form, e in run(F, H, Q, R, m0, P0, T, rng).items():
            print(f"| {name} | {form} | " + ("S not positive definite | | |" if e is None else
                                             f"{e[0]:.1e} | {e[1]:.1e} | {e[2]}/{T} |"))
    trials = [run(*random_problem(rng), rng) for _ in range(60)]
    print()
    print("60 random ill-conditioned problems (variances, max relative error):")
    joseph = np.array([t["joseph"][0] for t in trials])
    for form in FORMS:
        v = np.array([np.inf if t[form] is None else t[form][0] for t in trials])
        print(f"- {form}: median {np.median(v):.1e}, 90th percentile {np.quantile(v, 0.9):.1e}, max {v.max():.1e}; "
              f"more than 10 times the Joseph form's error in {np.sum(v > 10 * joseph + 1e-15)} of 60")


if __name__ == "__main__":
    main()
