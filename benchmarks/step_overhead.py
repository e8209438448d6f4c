"""What one compiled predict and update cost at small sizes, against the same Joseph form written out.

    python benchmarks/step_overhead.py

The compiled mirror (:mod:`gaussfuse._kernels._step`) is written once for
every n and m: loops whose bounds are known only at run time. For a state
of 2 and a scalar measurement, a step's arithmetic is a few dozen
multiply-adds, so the loops' own cost dominates. This script times
``_step.update`` and ``_step.predict`` called in a compiled loop, and, for
n = 2 and m = 1, the same Joseph-form update with every loop unrolled by
hand (the form the kernels had before they were merged into one mirror).
Nanoseconds per call, best of 5 runs of 10⁶ calls.
"""

from __future__ import annotations

import time

import numba
import numpy as np

from gaussfuse._kernels import _step


@numba.njit(error_model="numpy")
def _updates(N, w, x, P, z, H, R, d, angles, pm, pc, v, S):
    total = 0.0
    for _ in range(N):
        total += _step.update(w, x, P, z, H, R, d, angles, pm, pc, v, S)[1]
    return total


@numba.njit(error_model="numpy")
def _predicts(N, w, x, P, F, Q, b, pm, pc):
    for _ in range(N):
        _step.predict(w, x, P, F, Q, b, pm, pc)
    return 0.0


@numba.njit(error_model="numpy")
def _written_out(N, x, P, z, H, R, pm, pc):
    """The Joseph-form update for n = 2, m = 1, unrolled."""
    total = 0.0
    for _ in range(N):
        u0 = H[0, 0] * P[0, 0] + H[0, 1] * P[1, 0]
        u1 = H[0, 0] * P[0, 1] + H[0, 1] * P[1, 1]
        s = u0 * H[0, 0] + u1 * H[0, 1] + R[0, 0]
        k0, k1 = u0 / s, u1 / s
        v = z[0] - (H[0, 0] * x[0] + H[0, 1] * x[1])
        pm[0], pm[1] = x[0] + k0 * v, x[1] + k1 * v
        a00, a01, a10, a11 = 1.0 - k0 * H[0, 0], -k0 * H[0, 1], -k1 * H[0, 0], 1.0 - k1 * H[0, 1]
        b00, b01 = a00 * P[0, 0] + a01 * P[1, 0], a00 * P[0, 1] + a01 * P[1, 1]
        b10, b11 = a10 * P[0, 0] + a11 * P[1, 0], a10 * P[0, 1] + a11 * P[1, 1]
        pc[0, 0] = b00 * a00 + b01 * a01 + k0 * R[0, 0] * k0
        pc[1, 0] = pc[0, 1] = b10 * a00 + b11 * a01 + k1 * R[0, 0] * k0
        pc[1, 1] = b10 * a10 + b11 * a11 + k1 * R[0, 0] * k1
        total += -0.5 * (v * v / s + np.log(s))
    return total


def _best(f, *args, N=1_000_000) -> float:
    f(10, *args)
    best = np.inf
    for _ in range(5):
        t = time.perf_counter()
        f(N, *args)
        best = min(best, time.perf_counter() - t)
    return best / N * 1e9


def main() -> None:
    rng = np.random.default_rng(0)
    print("| n | m | predict (ns) | update (ns) | update written out (ns) |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    for n, m in ((2, 1), (4, 2), (8, 4)):
        A = rng.standard_normal((n, n))
        P = A @ A.T + np.eye(n)
        F, Q, H, R = np.eye(n) + 0.1 * A, np.eye(n), rng.standard_normal((m, n)), np.eye(m)
        x, z = rng.standard_normal(n), rng.standard_normal(m)
        w = _step.workspace(n, m)
        pm, pc, v, S = np.empty(n), np.empty((n, n)), np.empty(m), np.empty((m, m))
        update = _best(_updates, w, x, P, z, H, R, np.zeros(m), np.zeros(m, np.bool_), pm, pc, v, S)
        predict = _best(_predicts, w, x, P, F, Q, np.zeros(n), pm, pc)
        by_hand = f"{_best(_written_out, x, P, z, H, R, pm, pc):.0f}" if (n, m) == (2, 1) else "-"
        print(f"| {n} | {m} | {predict:.0f} | {update:.0f} | {by_hand} |")


if __name__ == "__main__":
    main()
