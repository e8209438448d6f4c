"""The benchmark script runs: `benchmarks/run.py --quick` exits 0 with every workload's rows.

Not a timing test: the quick sizes are tiny and the speeds they print mean
nothing. What it guards is that the script, its adapters to the peer
libraries and its agreement checks (a mismatch exits non-zero) do not rot.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "run.py"
PEERS = ("filterpy", "pykalman", "simdkalman", "statsmodels")

# Rows every quick run prints: (workload, the start of the library / engine label).
EXPECTED_ROWS = [
    ("W1", 'gaussfuse engine="numba"'),
    ("W1", 'gaussfuse engine="python"'),
    ("W1", "filterpy KalmanFilter.batch_filter"),
    ("W1", "filterpy predict()/update() functions"),
    ("W1", "pykalman KalmanFilter.filter"),
    ("W1", "simdkalman compute(filtered)"),
    ("W1", "statsmodels KalmanSmoother.filter"),
    ("W2", 'gaussfuse engine="numba"'),
    ("W2", "simdkalman compute(filtered)"),
    ("W2", "filterpy batch_filter, loop over series"),
    ("W2", "statsmodels KalmanSmoother.filter, loop over series"),
    ("W3", 'gaussfuse engine="numba"'),
    ("W3", "filterpy batch_filter + rts_smoother"),
    ("W3", "pykalman KalmanFilter.smooth"),
    ("W3", "simdkalman compute(smoothed)"),
    ("W3", "statsmodels KalmanSmoother.smooth"),
    ("W4", "filterpy UnscentedKalmanFilter.batch_filter"),
    ("W4", 'gaussfuse engine="numba", plain Python f, h'),
    ("W4", 'gaussfuse engine="numba", vectorized f, h'),
    ("W4", 'gaussfuse engine="numba", numba.njit f, h'),
    ("W4", 'gaussfuse engine="numba", numba.njit vectorized f, h'),
    ("W4", 'gaussfuse engine="numba", form="sqrt", plain Python f, h'),
    ("W4", 'gaussfuse engine="numba", form="sqrt", numba.njit f, h'),
    ("W4", 'gaussfuse engine="python", plain Python f, h'),
    *((f"W5 n={n}", label) for n in (2, 8, 32, 64, 128)
      for label in ('gaussfuse engine="numba"', 'gaussfuse engine="auto"', 'gaussfuse engine="python"',
                    "statsmodels KalmanSmoother.filter")),
]


@pytest.mark.skipif(not all(importlib.util.find_spec(p) for p in PEERS),
                    reason="the peer libraries are not installed (pip install -e '.[bench]')")
@pytest.mark.parametrize("only", ["W1,W2,W3", "W4", "W5"])  # three runs, so that test workers share them
def test_quick_benchmark_runs_and_agrees(tmp_path, only):
    out = tmp_path / "results.md"
    proc = subprocess.run(
        [sys.executable, str(SCRIPT), "--quick", "--only", only, "--out", str(out)],
        capture_output=True, text=True, timeout=600, cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    rows = [line for line in proc.stdout.splitlines() if line.startswith("| W")]
    expected = [(w, label) for w, label in EXPECTED_ROWS if w.split()[0] in only.split(",")]
    assert expected
    for workload, label in expected:
        matching = [r for r in rows if r.startswith(f"| {workload} | {label}")]
        assert matching, f"no row for {workload} {label!r} in:\n" + "\n".join(rows)
        assert "ERROR" not in matching[0] and "MISMATCH" not in matching[0], matching[0]
    for peer in PEERS:
        assert f"- {peer}: used" in proc.stdout
    assert "all checks passed" in proc.stdout
    assert out.read_text(encoding="utf-8").count("| W") == len(rows)
