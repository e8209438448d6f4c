"""Every script in examples/ runs, and says what it promises."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(EXAMPLES.glob("*.py"))


def test_there_are_examples():
    assert SCRIPTS


PLOTS = ("robot_localization", "ekf_slam")
"""The examples that draw a figure when asked (``--plot FILE``): run so, once, their figure is checked too."""


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_example_runs(script, tmp_path):
    plot = ["--plot", "figure.png"] if script.stem in PLOTS else []
    done = subprocess.run([sys.executable, str(script), *plot], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip()
    assert sorted(os.listdir(tmp_path)) == (["figure.png"] if plot else []), "an example wrote files unasked"
    if plot:
        assert "figure: figure.png" in done.stdout
        data = (tmp_path / "figure.png").read_bytes()
        assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 20_000
    if script.stem == "nile":
        found = dict(re.findall(r"^(mle|em): sigma2_eps =\s+([0-9.]+)", done.stdout, re.M))
        assert abs(float(found["mle"]) / 15099 - 1) < 5e-3
        assert abs(float(found["em"]) / 15099 - 1) < 5e-3
    if script.stem == "robot_localization":
        rmse = {name: float(value) for name, value in
                re.findall(r"^(dead reckoning|EKF|UKF)\s+([0-9.]+) m", done.stdout, re.M)}
        assert set(rmse) == {"dead reckoning", "EKF", "UKF"}
        for name in ("EKF", "UKF"):  # both filters beat dead reckoning clearly
            assert rmse[name] < 0.2 * rmse["dead reckoning"]
            assert rmse[name] < 0.15
        nis = re.findall(r"^(EKF|UKF): NIS [0-9.]+, interval \[[0-9., ]+\]: (\w+)", done.stdout, re.M)
        assert nis == [("EKF", "consistent"), ("UKF", "consistent")]
    if script.stem == "gps_gaps":  # reading the time stamps beats the raw fixes; counting rows does not
        rmse = dict(re.findall(r"^(raw fixes|rows as 1 s steps|time-stamped steps)\s+([0-9.]+) m", done.stdout, re.M))
        assert float(rmse["time-stamped steps"]) < 0.6 * float(rmse["raw fixes"])
        assert float(rmse["time-stamped steps"]) < float(rmse["rows as 1 s steps"])
        assert re.search(r"^rows as 1 s steps .* divergence check: flags it$", done.stdout, re.M)
        assert re.search(r"^time-stamped steps .* divergence check: quiet$", done.stdout, re.M)
    if script.stem == "port_from_filterpy":  # the ported loop gives filterpy's numbers, to round-off
        line = re.search(r"^largest difference from filterpy: (.*)$", done.stdout, re.M).group(1)
        found = dict((name, float(value)) for name, value in re.findall(r"(\w+) ([0-9.e+-]+)", line))
        assert set(found) == {"x", "P", "y", "S", "K", "log_likelihood", "mahalanobis"}
        assert max(found.values()) < 1e-10, found
    if script.stem == "ekf_slam":
        dead, slam = map(float, re.search(r"robot position RMSE: dead reckoning ([0-9.]+) m, "
                                          r"EKF-SLAM ([0-9.]+) m", done.stdout).groups())
        assert slam < 0.5 * dead
        rows = re.findall(r"^\s+\d+ +(?:-?[0-9.]+ +){4}([0-9.]+) m +([0-9.]+) +([0-9.]+) m$", done.stdout, re.M)
        assert len(rows) == 5
        worst, rms, std, prior = map(float, re.search(
            r"landmark errors: max ([0-9.]+) m, RMS ([0-9.]+) m; final std at most ([0-9.]+) m "
            r"\(prior ([0-9.]+) m\)", done.stdout).groups())
        assert worst == pytest.approx(max(float(r[0]) for r in rows), abs=1e-3)
        assert std == pytest.approx(max(float(v) for r in rows for v in r[1:]), abs=1e-3)
        # the map is learned: errors and uncertainties far below the prior's 100 m
        assert prior == 100 and worst < 0.5 and std < 1.0
        assert worst < 3 * std
        # the naive EKF's divergence warning is explained in the output, not left on stderr unexplained (audit Y3)
        assert "DivergenceWarning" not in done.stderr
        assert re.search(r"^  the divergence check flagged EKF: innovations too large", done.stdout, re.M)
