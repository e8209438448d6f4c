"""Start-up: `import gaussfuse` is quick and loads neither numba nor matplotlib."""

import subprocess
import sys

CODE = """
import time, sys
t = time.perf_counter()
import gaussfuse
elapsed = time.perf_counter() - t
print(elapsed, "numba" in sys.modules, "matplotlib" in sys.modules)
"""


def test_import_is_fast_and_lazy():
    runs = []
    for _ in range(3):
        out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, check=True)
        elapsed, numba_loaded, mpl_loaded = out.stdout.split()
        runs.append(float(elapsed))
        assert numba_loaded == "False"
        assert mpl_loaded == "False"
    assert min(runs) < 0.5, runs
