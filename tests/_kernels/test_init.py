"""``gaussfuse._kernels.kernel_states``: each kernel "cold", "cached" or "loaded", decided without importing numba.

Each probe runs in a new interpreter with its own ``NUMBA_CACHE_DIR``, so
the states are those a new user (an empty cache), a new process (a filled
cache) and the same process (kernels loaded) see.
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
        out["held_steps signatures"] = len(linear.held_steps.signatures)  # compiled with forward, when it is
        out["after, smoothing"] = {**states("linear", smoothing=True), **states("sigma_points", smoothing=True)}
    print(json.dumps(out))
""")


def probe(cache_dir, what: str) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    child = subprocess.run([sys.executable, "-c", PROBE, what], env=env, capture_output=True, text=True,
                           timeout=600)
    assert child.returncode == 0, child.stderr
    return json.loads(child.stdout.strip().splitlines()[-1])


def test_cold_then_loaded_then_cached(tmp_path):
    """One cold compilation (a new user), then what a new process and a changed source see."""
    first = probe(tmp_path, "run")
    cold = {"linear.forward": "cold", "sigma_points.advance": "cold", "sigma_points.hold": "cold"}
    assert first["before"] == cold
    assert first["forward"] == {"hits": 0, "misses": 1}  # compiled, and written to the cache
    assert first["held_steps signatures"] == 1  # not a second one for a literal first step (2 s more)
    assert any(tmp_path.rglob("*.nbi"))
    assert not first["numba imported"]  # deciding does not import numba
    # The linear engine's kernels are loaded; the sigma-point engine shares the backward pass only.
    assert first["after, smoothing"] == {"linear.forward": "loaded", "_rts.backward": "loaded",
                                         "sigma_points.advance": "cold", "sigma_points.hold": "cold"}
    second = probe(tmp_path, "run")
    assert second["before"] == {**cold, "linear.forward": "cached"}
    assert not second["numba imported"]
    assert second["forward"] == {"hits": 1, "misses": 0}  # a new process loads it
    assert second["after, smoothing"] == first["after, smoothing"]
    third = probe(tmp_path, "changed")
    assert third["before"] == cold


def test_an_unknown_module_is_refused():
    with pytest.raises(ValueError, match=r"`module` must be one of \['linear', 'sigma_points'\]; got 'kalman'"):
        kernel_states("kalman")


def test_every_entry_point_exists():
    import importlib

    for entries in [*ENTRY_POINTS.values(), (("_rts", "backward"), JITTED_LOOP)]:
        for module, name in entries:
            assert hasattr(importlib.import_module(f"gaussfuse._kernels.{module}"), name)


def test_the_stamp_covers_every_kernel_source():
    assert len(source_stamp()) == 32 and source_stamp() == source_stamp()


def test_the_kernels_a_call_runs():
    assert kernels("linear") == (("linear", "forward"),)
    assert kernels("linear", smoothing=True) == (("linear", "forward"), ("_rts", "backward"))
    assert kernels("sigma_points", smoothing=True) == (("sigma_points", "advance"), ("sigma_points", "hold"),
                                                       ("_rts", "backward"))
    # jitted f and h: the loop compiled around them, instead of the Python mode's kernels
    assert kernels("sigma_points", jitted=True) == (JITTED_LOOP,)
    assert kernels("linear", jitted=True) == kernels("linear")


def test_the_jitted_loop_state_is_the_one_given():
    for loop in ("loaded", "cached", "cold"):
        states = kernel_states("sigma_points", smoothing=True, loop=loop)
        assert list(states) == [JITTED_LOOP, ("_rts", "backward")]
        assert states[JITTED_LOOP] == loop
    assert JITTED_LOOP not in kernel_states("sigma_points")


def test_jitted_tells_numba_functions_from_others():
    numba = pytest.importorskip("numba")
    from gaussfuse._kernels import jitted

    assert jitted(numba.njit(lambda x: x))
    assert not jitted(lambda x: x) and not jitted(None) and not jitted(np.sin)
