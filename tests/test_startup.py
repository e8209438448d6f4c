"""Start-up: `import gaussfuse` loads NumPy and nothing else outside the standard library.

What makes an import slow is what it loads (numba and matplotlib take
seconds, SciPy's submodules a large fraction of one), so that is what is
checked; a timing would depend on the machine's load. The import's speed is
measured in ``benchmarks/``.
"""

import subprocess
import sys

CODE = """
import sys
before = set(sys.modules)
import gaussfuse
print(" ".join(sorted({m.split(".")[0] for m in set(sys.modules) - before})))
"""


def test_import_loads_only_numpy_besides_the_standard_library():
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, check=True)
    loaded = set(out.stdout.split())
    third_party = {m for m in loaded - {"gaussfuse"} if m not in sys.stdlib_module_names and not m.startswith("_")}
    assert third_party == {"numpy"}, third_party
