"""User code type-checks: `mypy --strict` on code written as the README writes it (tests/data/typed_usage.py).

The package ships its annotations (py.typed); what matters to users is that
their own code using gaussfuse passes a strict type checker, names re-exported
from ``gaussfuse`` and results indexed (``res.means[-1]``) included.
"""

import subprocess
import sys
from pathlib import Path

import pytest

USAGE = Path(__file__).resolve().parent / "data" / "typed_usage.py"


def test_user_code_passes_mypy_strict(tmp_path):
    pytest.importorskip("mypy")
    done = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--cache-dir", str(tmp_path / "cache"),
                           str(USAGE)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr


def test_the_typed_usage_runs():
    namespace: dict = {}
    exec(compile(USAGE.read_text(encoding="utf-8"), str(USAGE), "exec"), namespace)
    assert namespace["textbook"]() > 0
    assert namespace["online"]().shape == (4,)
    assert namespace["fused"]() == pytest.approx(1.8)
    assert type(namespace["timed_and_sensors"]()).__name__ == "Fused"
    loglik, widths = namespace["learn_and_forecast"]()
    assert widths.shape == (5, 1) and (widths > 0).all()
