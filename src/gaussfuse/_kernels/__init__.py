"""Compiled kernels: the only place numba is imported.

The compiled mirror of the readable path, in three layers:

* :mod:`._step` -- :mod:`gaussfuse.kalman` compiled: predict, update (Joseph
  form), the RTS gain and step, the overflow check; written once, on the
  products of :mod:`._dense` (loops, or BLAS and LAPACK through
  :mod:`._blas` for large states);
* :mod:`._slr` -- :func:`gaussfuse.linearize.sigma_points.slr` compiled: the
  sigma points and the statistical linear regression;
* the engines, loops over steps and series that call them and never do
  algebra of their own: :mod:`.linear` (method "kf"), :mod:`.sigma_points`
  ("ukf", "ckf", "ghkf"), and :mod:`._rts`, the backward pass of both.

An engine module provides, for the methods that name it in
:data:`gaussfuse.inference.METHODS`:

* ``filter(lin, model, prior, zs, us, keep) -> FilterResult``
* ``smooth(lin, model, prior, zs, us) -> SmoothResult``

with validated measurements ``zs`` of shape (N, T, m), controls ``us`` of
shape (N, T, p) or None, the method's linearisation strategy `lin`, and
results that carry the leading N axis. Kernels are compiled on first use
and cached on disk (:mod:`._jit`); :func:`compiled_state` tells, without
importing numba, whether a call would compile them, load them from the
cache, or find them loaded. Importing this package does not import numba;
importing a module in it does.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import sys
from functools import lru_cache
from pathlib import Path

__all__ = ["compiled_state", "source_stamp", "ENTRY_POINTS", "BATCH_ENTRY_POINTS"]

_HERE = Path(__file__).resolve().parent

ENTRY_POINTS: dict[str, tuple[tuple[str, str], ...]] = {
    "linear": (("linear", "forward"),),
    "sigma_points": (("sigma_points", "advance"),),
}
"""The compiled functions an engine's filter runs on one series, as (module,
function) pairs: what :func:`compiled_state` looks for. A smoother runs
``_rts.backward`` too; a batch of series the parallel forms
(:data:`BATCH_ENTRY_POINTS`). The sigma-point loop compiled around
numba-jitted f and h is compiled separately, when used."""

BATCH_ENTRY_POINTS: dict[str, tuple[tuple[str, str], ...]] = {
    "linear": (("linear", "forward_parallel"),),
    "sigma_points": (),
}
"""What a batch of series runs in addition (the sigma-point engine runs its
series one after the other)."""


@lru_cache(maxsize=None)
def source_stamp() -> bytes:
    """SHA-256 of the source of every kernel module: the stamp of every cached kernel.

    numba stamps a cached function with its own file only, and would load a
    kernel compiled against an older version of a helper in another file
    (say :mod:`._step`); :mod:`._jit` stamps each kernel with this digest
    instead, so that a change to any kernel module invalidates them all.
    :mod:`gaussfuse.kalman` is stamped too: the kernels compile its
    constants in (``SETTLED``, the fixed point's test).
    """
    digest = hashlib.sha256()
    for path in [*sorted(_HERE.glob("*.py")), _HERE.parent / "kalman.py"]:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.digest()


def _cache_dirs() -> list[Path]:
    """Where numba keeps (or would keep) the cache of this directory's functions, as numba picks it.

    numba's locators, in its order: ``NUMBA_CACHE_DIR`` when set (a
    subdirectory named after this directory and the SHA-1 of its path); else
    ``__pycache__`` beside the sources when writable; else the user-wide
    cache (``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``, the same
    subdirectory).
    """
    sub = f"{_HERE.name}_{hashlib.sha1(str(_HERE).encode()).hexdigest()}"
    root = os.environ.get("NUMBA_CACHE_DIR")
    if root:
        return [Path(root) / sub]
    in_tree = _HERE / "__pycache__"
    if os.access(in_tree if in_tree.exists() else _HERE, os.W_OK):
        return [in_tree]
    user = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return [Path(user) / "numba" / sub]


def _cached(module: str, function: str) -> bool:
    """Whether numba's on-disk cache holds `function` of `module`, compiled from the current sources.

    numba names a function's index ``<module>.<function>-<line>.py<XY><abiflags>.nbi``;
    it starts with the pickled numba version, followed by the pickled
    ``(stamp, entries)``. The index counts when it was written by the
    installed numba, lists an entry, and carries :func:`source_stamp` (its
    32 bytes appear verbatim in the pickle, so it is not unpickled: that
    would import numba).
    """
    import importlib.metadata  # here, not at the top: it costs 40 ms of `import gaussfuse`

    try:
        version = importlib.metadata.version("numba")
    except importlib.metadata.PackageNotFoundError:
        return False
    pattern = f"{module}.{function}-*.py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}.nbi"
    stamp = source_stamp()
    for folder in _cache_dirs():
        for index in folder.glob(pattern):
            try:
                with open(index, "rb") as fh:
                    if pickle.load(fh) != version:
                        continue
                    rest = fh.read()
            except (OSError, pickle.UnpicklingError, EOFError, ValueError):
                continue
            if stamp in rest and any(folder.glob(index.name[:-len(".nbi")] + ".*.nbc")):
                return True
    return False


def compiled_state(module: str, batch: bool = False, smoothing: bool = False) -> str:
    """Whether the kernels of an engine are compiled: "loaded", "cached" or "cold".

    Parameters
    ----------
    module : str
        An engine module of this package: "linear" or "sigma_points" (a
        method's ``compiled`` entry in :data:`gaussfuse.inference.METHODS`).

    Returns
    -------
    str
        "loaded" when the engine's kernels (:data:`ENTRY_POINTS`) are
        compiled, or loaded from the cache, in this process: a call pays
        neither; "cached" when numba's on-disk cache holds them for the
        current sources: a new process (or this one) loads them, paying for
        numba's import and start-up but not for compilation; "cold"
        otherwise: the first call compiles them.

    Notes
    -----
    It decides without importing numba. "loaded": the engine's module is
    imported and each of its entry points has a compiled signature. "cached":
    for each entry point, an index file in the cache directory numba would
    use (:func:`_cache_dirs`) written by the installed numba version for the
    current sources (:func:`source_stamp`), with a compiled object beside it.
    The stamp covers every kernel module, so any change to their sources
    makes the state "cold" again.
    """
    if module not in ENTRY_POINTS:
        raise ValueError(f"`module` must be one of {sorted(ENTRY_POINTS)}; got {module!r}.")
    entries = ENTRY_POINTS[module] + (BATCH_ENTRY_POINTS[module] if batch else ())
    if smoothing:
        entries += (("_rts", "backward_parallel" if batch and module == "linear" else "backward"),)
    loaded = []
    for mod, name in entries:
        imported = sys.modules.get(f"{__name__}.{mod}")
        loaded.append(imported is not None and bool(getattr(getattr(imported, name, None), "signatures", ())))
    if all(loaded):
        return "loaded"
    if all(done or _cached(mod, name) for done, (mod, name) in zip(loaded, entries)):
        return "cached"
    return "cold"
