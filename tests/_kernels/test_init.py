"""``gaussfuse._kernels.kernel_states``: each kernel "cold", "cached" or "loaded", decided without importing numba.

Each probe runs in a new interpreter, on an empty cache (``NUMBA_CACHE_DIR``
a new folder) or on this run's, so the states are those a new user (an
empty cache), a new process (a filled cache) and the same process (kernels
loaded) see. This run's cache holds what a process of the run compiled
(the test itself, or the session's warm-up): a probe compiling the linear
filter into a cache of its own cost 15 s of the suite.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from gaussfuse._kernels import ENTRY_POINTS, JITTED_LOOP, kernel_states, kernels, source_stamp

PROBE = textwrap.dedent("""
    import json, sys
    import gaussfuse._kernels as kernels
    if sys.argv[1] == "changed":  # as if a kernel's source had changed since the cache was written
        kernels.source_stamp = lambda: b"x" * 32

    def states(module, smoothing=False):
        return {f"{m}.{n}": state for (m, n), state in kernels.kernel_states(module, smoothing).items()}

    out = {"before": {**states("linear"), **states("sigma_points")}, "numba imported": "numba" in sys.modules}
    if sys.argv[1] == "run":
        import numpy as np
        import gaussfuse as gf
        model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.eye(2), R=1.0)
        gf.smooth(model, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.0, 3.0], engine="numba")
        from gaussfuse._kernels import linear
        stats = linear.forward.stats  # compiled and written to the cache, or loaded from it
        out["forward"] = {"hits": sum(stats.cache_hits.values()), "misses": sum(stats.cache_misses.values())}
        out["after, smoothing"] = {**states("linear", smoothing=True), **states("sigma_points", smoothing=True)}
    print(json.dumps(out))
""")


def probe(cache_dir, what: str) -> dict:
    """What the probe prints, run with `cache_dir` as numba's cache (None: this run's own)."""
    env = {**os.environ, **({} if cache_dir is None else {"NUMBA_CACHE_DIR": str(cache_dir)})}
    child = subprocess.run([sys.executable, "-c", PROBE, what], env=env, capture_output=True, text=True,
                           timeout=600)
    assert child.returncode == 0, child.stderr
    return json.loads(child.stdout.strip().splitlines()[-1])


def test_cold_then_cached_then_loaded(tmp_path):
    """A new user's empty cache, then a new process on a cache holding the linear kernels, then a changed source."""
    import gaussfuse as gf

    model = gf.LinearModel(F=[[1.0, 1.0], [0.0, 1.0]], H=[1.0, 0.0], Q=np.eye(2), R=1.0)
    gf.smooth(model, gf.Gaussian([0.0, 0.0], np.eye(2)), [1.0, 2.0, 3.0], engine="numba")  # now in this run's cache
    cold = {"linear.forward": "cold", "sigma_points.advance": "cold", "sigma_points.hold": "cold"}
    first = probe(tmp_path, "look")
    assert first["before"] == cold
    assert not first["numba imported"]  # deciding does not import numba
    second = probe(None, "run")
    assert second["before"]["linear.forward"] == "cached"
    assert not second["numba imported"]
    assert second["forward"] == {"hits": 1, "misses": 0}  # a new process loads it
    # The linear engine's kernels are loaded; the sigma-point engine shares the backward pass only.
    after = second["after, smoothing"]
    assert after["linear.forward"] == after["_rts.backward"] == "loaded"
    for entry in ("sigma_points.advance", "sigma_points.hold"):
        assert after[entry] == second["before"][entry] in ("cold", "cached")
    third = probe(None, "changed")
    assert third["before"] == cold


def test_an_unknown_module_is_refused():
    with pytest.raises(ValueError, match=r"`module` must be one of \['linear', 'sigma_points'\]; got 'kalman'"):
        kernel_states("kalman")


def test_every_entry_point_exists():
    import importlib

    for entries in [*ENTRY_POINTS.values(), (("_rts", "backward"), JITTED_LOOP)]:
        for module, name in entries:
            assert hasattr(importlib.import_module(f"gaussfuse._kernels.{module}"), name)


def test_the_stamp_covers_every_kernel_source(tmp_path, monkeypatch):
    """The stamp is the SHA-256 of every kernel module and of kalman.py, so that an edit to any of them leaves no
    stale kernel in numba's cache. Checked on a copy of the sources: against hashlib over the same files, and
    changed by an edit to each (audit QQ1: the test compared the stamp with itself, and passed with a stamp that
    read no file)."""
    import hashlib
    import shutil

    import gaussfuse._kernels as package

    kernels = tmp_path / "gaussfuse" / "_kernels"
    shutil.copytree(package._HERE, kernels, ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    shutil.copy(package._HERE.parent / "kalman.py", kernels.parent / "kalman.py")
    monkeypatch.setattr(package, "_HERE", kernels)

    def stamp():
        source_stamp.cache_clear()
        return source_stamp()

    files = [*sorted(kernels.glob("*.py")), kernels.parent / "kalman.py"]
    want = hashlib.sha256()
    for path in files:
        want.update(path.name.encode())
        want.update(path.read_bytes())
    first = stamp()
    assert first == want.digest() and len(files) >= 5
    seen = {first}
    for path in files:
        text = path.read_bytes()
        path.write_bytes(text + b"\n# edited\n")
        seen.add(stamp())
        path.write_bytes(text)
    assert len(seen) == len(files) + 1 and stamp() == first
    source_stamp.cache_clear()


def test_the_kernels_a_call_runs():
    assert kernels("linear") == (("linear", "forward"),)
    assert kernels("linear", smoothing=True) == (("linear", "forward"), ("_rts", "backward"))
    assert kernels("sigma_points", smoothing=True) == (("sigma_points", "advance"), ("sigma_points", "hold"),
                                                       ("_rts", "backward"))
    # jitted f and h: the loop compiled around them, which calls the Python mode's step kernel
    assert kernels("sigma_points", jitted=True) == (("sigma_points", "advance"), ("sigma_points", "hold"),
                                                    JITTED_LOOP)
    assert kernels("linear", jitted=True) == kernels("linear")


def test_the_jitted_loop_state_is_the_one_given():
    for loop in ("loaded", "cached", "cold"):
        states = kernel_states("sigma_points", smoothing=True, loop=loop)
        assert list(states) == [("sigma_points", "advance"), ("sigma_points", "hold"), JITTED_LOOP,
                                ("_rts", "backward")]
        assert states[JITTED_LOOP] == loop
    assert JITTED_LOOP not in kernel_states("sigma_points")


def test_jitted_tells_numba_functions_from_others():
    numba = pytest.importorskip("numba")
    from gaussfuse._kernels import jitted

    assert jitted(numba.njit(lambda x: x))
    assert not jitted(lambda x: x) and not jitted(None) and not jitted(np.sin)
