"""Shared fixtures for the core test suite.

The test folder is put on ``sys.path`` (whatever pytest's import mode), so
test modules import the dense reference as ``import _oracle``.

Hypothesis draws the same examples on every run ("ci", the default profile:
derandomised, no example database), so that a run of the suite does not
depend on which examples it happened to draw; run
``python -m pytest --hypothesis-profile=explore`` to search with new random
examples, and pin what that finds as an example test.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile("ci")

TESTS_DIR = Path(__file__).resolve().parent
DATA_DIR = TESTS_DIR / "data"

if str(TESTS_DIR) not in sys.path:
    sys.path.insert(0, str(TESTS_DIR))


def pytest_configure(config):
    """Before xdist starts its workers, compile the kernels into numba's cache, a share per core.

    Otherwise every worker compiles each kernel it meets, at about the same time as the others: on two cores,
    each kernel twice (a cold run's compiling took 576 s of processor time here, against 320 s for compiling
    each kernel once). With a warm cache this only loads them (a few seconds). Runs without workers skip it.
    """
    workers = getattr(config.option, "numprocesses", None)
    if hasattr(config, "workerinput") or not isinstance(workers, int) or workers < 2:
        return
    workers = min(workers, os.cpu_count() or 1)
    script = str(TESTS_DIR / "_warm_kernels.py")
    print(f"compiling (or loading) the kernels in numba's cache, {workers} processes ...", file=sys.stderr,
          flush=True)  # minutes when the cache is empty: say what the pause is
    children = [subprocess.Popen([sys.executable, script, str(i), str(workers)]) for i in range(workers)]
    for child in children:
        child.wait()  # a failure here shows again, with its test, when the suite meets it


@pytest.fixture(autouse=True)
def _no_readable_history():
    """Each test starts with no readable calls behind "auto" (``drivers._SPENT``): what it chooses must not
    depend on which tests ran before in the same process."""
    from gaussfuse.inference import drivers

    drivers._SPENT.clear()
    yield
    drivers._SPENT.clear()


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The folder of test data files, found relative to this file."""
    return DATA_DIR


@pytest.fixture(scope="session")
def car_track() -> dict[str, np.ndarray]:
    """Särkkä & Svensson's car-tracking data: X (4, 100) truth, Y (2, 100) measurements."""
    with open(DATA_DIR / "car_track.json", encoding="utf-8") as fh:
        raw = json.load(fh)
    return {"X": np.asarray(raw["X"], dtype=float), "Y": np.asarray(raw["Y"], dtype=float)}


@pytest.fixture(scope="session")
def robot() -> dict[str, np.ndarray]:
    """Abbeel's robot data as pykalman ships it, with the MATLAB filter's, smoother's and EM's published results.

    Read from the installed pykalman (a bench extra): its licence's terms for some distribution channels are not
    ones this repository can take on, so the file is not copied here.

    The model is x_k = A x_{k-1} + b_{k-1} + w_k, y_k = C x_k + d + v_k for k = 1..500, from x_0 ~ N(x0, P_0)
    one step before the first measurement (gaussfuse's convention). ``xfilt``/``Vfilt`` and ``xsmooth``/``Vsmooth``
    have 501 entries, the first being x_0's; ``ll`` is the log-likelihood before each of 50 EM iterations that
    learn Q and R from 10 I, ending at ``Q`` and ``R`` (which the filter and smoother used).
    """
    from importlib.resources import files

    from scipy.io import loadmat

    pytest.importorskip("pykalman")
    with files("pykalman").joinpath("datasets", "data", "robot.mat").open("rb") as fh:
        raw = loadmat(fh)
    out = {name: np.asarray(raw[name], dtype=float) for name in ("A", "C", "Q", "R", "P_0")}
    out["x0"], out["d"], out["ll"] = raw["x0"][:, 0], raw["d"][:, 0], raw["ll"][0]
    out["y"], out["b"], out["xfilt"], out["xsmooth"] = raw["y"].T, raw["b"].T, raw["xfilt"].T, raw["xsmooth"].T
    for name in ("Vfilt", "Vsmooth"):  # MATLAB cell arrays: an object array of 5 x 5 matrices
        out[name] = np.stack([np.asarray(v, dtype=float) for v in raw[name][0]])
    return out
