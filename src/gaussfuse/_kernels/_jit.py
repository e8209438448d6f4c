"""How the kernels are compiled and launched: one place for numba's process-wide settings.

* :func:`jit` is :func:`numba.njit` with ``cache=True``: compiled kernels
  are saved to disk and a new process loads them. When numba finds nowhere
  to save them (a read-only install and home, no ``NUMBA_CACHE_DIR``) it
  compiles them in memory instead, with one :class:`CacheUnavailableWarning`
  per process.
* :func:`parallel_launch` lets one thread at a time launch a
  ``parallel=True`` kernel; the others run the serial kernel meanwhile.
"""

from __future__ import annotations

import contextlib
import threading
import warnings
from typing import Callable, Iterator

import numba

__all__ = ["CacheUnavailableWarning", "jit", "parallel_launch"]


class CacheUnavailableWarning(RuntimeWarning):
    """Numba found no writable cache directory: kernels are compiled anew in each process."""


_MESSAGE = (
    "gaussfuse's compiled kernels cannot be cached on disk: numba found no writable cache "
    "directory. They are compiled in memory instead, again in every new process. To cache "
    "them, set the environment variable NUMBA_CACHE_DIR to a writable directory."
)
_cache = True  # False once numba has found no cache directory: the same for every kernel here
_cache_lock = threading.Lock()


def jit(*signature, **options) -> Callable[[Callable], numba.core.registry.CPUDispatcher]:
    """``numba.njit(*signature, cache=True, **options)``, or uncached when nothing can be cached.

    Parameters
    ----------
    *signature
        An optional explicit signature, as for :func:`numba.njit`.
    **options
        Options of :func:`numba.njit`, except `cache`.

    Returns
    -------
    callable
        A decorator that turns a Python function into a numba dispatcher.

    Warns
    -----
    CacheUnavailableWarning
        The first time numba finds no cache directory; every kernel after
        that is compiled without one.
    """
    def decorate(fn: Callable) -> numba.core.registry.CPUDispatcher:
        global _cache
        if _cache:
            try:
                return numba.njit(*signature, cache=True, **options)(fn)
            except RuntimeError as exc:
                if "no locator available" not in str(exc):  # numba's words for "nowhere to cache"
                    raise
                with _cache_lock:
                    warn, _cache = _cache, False
                if warn:
                    warnings.warn(_MESSAGE, CacheUnavailableWarning, stacklevel=2)
        return numba.njit(*signature, **options)(fn)

    return decorate


_parallel = threading.Lock()


@contextlib.contextmanager
def parallel_launch() -> Iterator[bool]:
    """Whether this thread may launch a parallel kernel, for the duration of the block.

    Yields True to one thread at a time and False, at once and without
    waiting, to any other: that thread runs its serial kernel instead, so
    concurrent callers neither block each other nor launch two parallel
    regions at once. Numba's ``workqueue`` threading layer (the one used
    when neither OpenMP nor TBB is installed) is not thread-safe: two
    threads launching parallel regions at once abort the process. On the
    other layers two such launches would only share the same cores.

    Yields
    ------
    bool
        True if this thread holds the right to launch until the block ends.
    """
    mine = _parallel.acquire(blocking=False)
    try:
        yield mine
    finally:
        if mine:
            _parallel.release()
