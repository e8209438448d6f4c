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
and cached on disk (:mod:`._jit`); :func:`kernel_states` tells, without
importing numba, whether a call would compile each kernel it runs
(:func:`kernels`), load it from the cache, or find it loaded. Importing this
package does not import numba; importing a module in it does.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import sys
from functools import lru_cache
from pathlib import Path

__all__ = ["kernel_states", "kernels", "jitted", "jitted_loop_state", "source_stamp", "ENTRY_POINTS",
           "JITTED_LOOP"]

_HERE = Path(__file__).resolve().parent

ENTRY_POINTS: dict[str, tuple[tuple[str, str], ...]] = {
    "linear": (("linear", "forward"),),
    "sigma_points": (("sigma_points", "advance"), ("sigma_points", "hold")),
}
"""The compiled functions an engine's filter runs, as (module, function)
pairs: what :func:`kernel_states` looks for. A batch of series runs the same
ones: the linear filter and the backward pass over chunks of series on a
pool of threads (:func:`._jit.launch`), the sigma-point engine one series
after the other."""

JITTED_LOOP = ("sigma_points", "run")
"""The sigma-point loop compiled around numba-jitted f and h, once per
signature of f and h (:func:`gaussfuse._kernels.sigma_points.loop_state`
tells its state): what a filter with such a model runs besides
``ENTRY_POINTS["sigma_points"]``, whose step it calls."""


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


def jitted(fn) -> bool:
    """Whether `fn` is a numba-jitted function (:func:`numba.extending.is_jitted`), without importing numba.

    A jitted function exists only once numba is imported, so when it is not,
    nothing is.
    """
    dispatcher = sys.modules.get("numba.core.dispatcher")
    return dispatcher is not None and isinstance(fn, dispatcher.Dispatcher)


def jitted_loop_state(model, prior, us=None, form: str = "cov") -> str | None:
    """The state of :data:`JITTED_LOOP` for the model's numba-jitted f and h: "loaded", "cached" or "cold".

    None when f and h are not both jitted, or do not fit the compiled loop
    (:func:`gaussfuse._kernels.sigma_points.loop_state`, which tells the
    state for their signatures). When the loop is neither compiled in this
    process nor on disk for any f and h, it is "cold" without importing the
    sigma-point engine (0.5-1 s a process): deciding for the readable path
    then costs nothing.
    """
    if not (jitted(getattr(model, "f", None)) and jitted(getattr(model, "h", None))):
        return None
    if f"{__name__}.sigma_points" not in sys.modules and not _cached(*JITTED_LOOP):
        return "cold"
    from . import sigma_points  # numba is imported: f and h are jitted

    return sigma_points.loop_state(model, prior, us, form)


def kernels(module: str, smoothing: bool = False, jitted: bool = False) -> tuple[tuple[str, str], ...]:
    """The compiled functions a call of an engine runs, as (module, function) pairs.

    `smoothing`: the backward pass too (:mod:`._rts`); `jitted`: the
    sigma-point engine with numba-jitted f and h (:data:`JITTED_LOOP`).
    """
    if module not in ENTRY_POINTS:
        raise ValueError(f"`module` must be one of {sorted(ENTRY_POINTS)}; got {module!r}.")
    entries = ENTRY_POINTS[module]
    if jitted and module == "sigma_points":
        entries += (JITTED_LOOP,)
    if smoothing:
        entries += (("_rts", "backward"),)
    return entries


def kernel_states(module: str, smoothing: bool = False, loop: str | None = None) -> dict[tuple[str, str], str]:
    """Whether each kernel a call runs (:func:`kernels`) is "loaded", "cached" or "cold".

    Parameters
    ----------
    module : str
        An engine module of this package: "linear" or "sigma_points" (a
        method's ``compiled`` entry in :data:`gaussfuse.inference.METHODS`).
    smoothing : bool
        As for :func:`kernels`.
    loop : str, optional
        When the call runs the sigma-point loop compiled around its
        numba-jitted f and h (:data:`JITTED_LOOP`), that loop's state
        (:func:`gaussfuse._kernels.sigma_points.loop_state`: numba is
        imported already, since f and h are jitted).

    Returns
    -------
    dict
        For each kernel: "loaded" when it is compiled, or loaded from the
        cache, in this process: a call pays nothing for it; "cached" when
        numba's on-disk cache holds it for the current sources: a new
        process (or this one) loads it, paying for numba's import and
        start-up but not for compilation; "cold" otherwise: the first call
        compiles it.

    Notes
    -----
    It decides without importing numba. "loaded": the kernel's module is
    imported and the kernel has a compiled signature. "cached": an index
    file in the cache directory numba would use (:func:`_cache_dirs`)
    written by the installed numba version for the current sources
    (:func:`source_stamp`), with a compiled object beside it. The stamp
    covers every kernel module, so any change to their sources makes every
    kernel "cold" again.
    """
    out = {}
    for mod, name in kernels(module, smoothing, jitted=loop is not None):
        if (mod, name) == JITTED_LOOP:
            out[mod, name] = loop
            continue
        imported = sys.modules.get(f"{__name__}.{mod}")
        if imported is not None and bool(getattr(getattr(imported, name, None), "signatures", ())):
            out[mod, name] = "loaded"
        else:
            out[mod, name] = "cached" if _cached(mod, name) else "cold"
    return out
