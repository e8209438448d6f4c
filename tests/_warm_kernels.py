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


# Each job with its form and its cold cost in seconds on a 2-core Zen 4, in one process (2026-12-06). The
# sigma-point jobs of one form run that form's step kernel (advance or advance_sqrt, compiled with the form's
# first job; the loops around jitted f and h call it, compiling in under a second each), so a process takes
# the jobs of one form.
JOBS = [
    ("sqrt", 27, lambda: _toy("jitted", False, "sqrt")),
    ("sqrt", 13, lambda: _linear("sqrt", True)),
    ("sqrt", 1, lambda: _toy("plain", False, "sqrt")),
    ("sqrt", 1, lambda: _toy("jitted", True, "sqrt")),
    ("cov", 24, lambda: _toy("jitted-vectorized", True, "cov")),
    ("cov", 14, lambda: _linear("cov", True)),
    ("cov", 1, lambda: _toy("plain", False, "cov")),
    ("cov", 1, lambda: _toy("jitted-vectorized", False, "cov")),
    ("cov", 1, lambda: _toy("jitted", False, "cov")),
    ("cov", 1, lambda: _toy("jitted", True, "cov")),
    ("cov", 1, _scalar_h),
]
FORMS = ("sqrt", "cov")


def share(index: int, count: int) -> list:
    """The jobs of process `index` of `count`: the processes take the forms in turn, and each form's jobs are
    dealt to its processes longest first, each to the one with the least so far (one process takes them all)."""
    if count == 1:
        return [job for _, _, job in JOBS]
    form = FORMS[index % len(FORMS)]
    mine = [i for i in range(count) if FORMS[i % len(FORMS)] == form]
    loads, jobs = dict.fromkeys(mine, 0.0), []
    for job_form, cost, job in sorted((j for j in JOBS if j[0] == form), key=lambda j: -j[1]):
        least = min(loads, key=loads.get)
        loads[least] += cost
        if least == index:
            jobs.append(job)
    return jobs


if __name__ == "__main__":
    index, count = int(sys.argv[1]), int(sys.argv[2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for job in share(index, count):
            job()
