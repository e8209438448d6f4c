"""Compile the kernels the suite runs into numba's disk cache, a share of them per process.

Run as ``python tests/_warm_kernels.py I N``: process I of N compiles (or
loads) its share of :data:`JOBS`. The test session starts N
of them side by side before its workers (see ``conftest.py``), so that each
kernel is compiled once, on one core, instead of by every worker that meets
it at about the same time. Each job is an ordinary call of the package on a
small input: what it compiles is what such calls compile.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import gaussfuse as gf  # noqa: E402


def _linear(form: str, smooth: bool) -> None:
    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.diag([0.1, 0.01]), R=1.0)
    run = gf.smooth if smooth else gf.filter
    run(model, gf.Gaussian([0.0, 0.0], np.eye(2)), np.sin(np.arange(20.0)), engine="numba", form=form)


def _toy(mode: str, controls: bool, form: str) -> None:
    from _kernels.test_sigma_points import toy_problem

    model, prior, zs, us = toy_problem(0, mode, controls=controls)
    gf.smooth(model, prior, zs, us, method="ukf", engine="numba", form=form)


def _scalar_h() -> None:
    from _kernels.test_sigma_points import pendulum_model

    gf.smooth(pendulum_model("jitted-scalar-h"), gf.Gaussian([0.0, 0.0], np.eye(2)), np.zeros(5), method="ukf",
              engine="numba")


# Each job with its cold cost in seconds, measured on a slow 2-core machine (two processes side by side), to share
# the jobs out evenly: longest first, each to the process with the least so far.
JOBS = [
    (60, lambda: _toy("jitted", False, "sqrt")),
    (44, lambda: _toy("jitted-vectorized", True, "cov")),
    (41, lambda: _toy("jitted", False, "cov")),
    (33, lambda: _linear("sqrt", True)),
    (31, lambda: _toy("plain", False, "sqrt")),
    (30, lambda: _linear("cov", True)),
    (20, lambda: _toy("jitted-vectorized", False, "cov")),
    (19, lambda: _toy("plain", False, "cov")),
    (16, lambda: _toy("jitted", True, "sqrt")),
    (13, lambda: _toy("jitted", True, "cov")),
    (12, _scalar_h),
]


def share(index: int, count: int) -> list:
    """The jobs of process `index` of `count`."""
    loads, mine = [0.0] * count, []
    for cost, job in JOBS:
        least = loads.index(min(loads))
        loads[least] += cost
        if least == index:
            mine.append(job)
    return mine


if __name__ == "__main__":
    index, count = int(sys.argv[1]), int(sys.argv[2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for job in share(index, count):
            job()
