"""How the kernels are compiled and launched: one place for numba's process-wide settings.

* :func:`jit` is :func:`numba.njit` with a disk cache: compiled kernels
  are saved to disk and a new process loads them. The cache is numba's,
  except that its entries are stamped with the sources of *every* kernel
  module (:func:`gaussfuse._kernels.source_stamp`) rather than the
  function's own file alone: a kernel calls helpers in other files, and a
  change there must not leave a stale kernel in the cache. When numba finds
  nowhere to save them (a read-only install and home, no
  ``NUMBA_CACHE_DIR``) it compiles them in memory instead, with one
  :class:`CacheUnavailableWarning` per process.
* :func:`launch` runs a kernel over a batch of series, in parallel over
  chunks of series when there are several, and :func:`parallel_launch`
  lets one thread at a time launch a ``parallel=True`` kernel; the others
  run the serial kernel meanwhile.
"""

from __future__ import annotations

import contextlib
import threading
import warnings
from typing import Callable, Iterator

import numba
from numba.core.caching import CompileResultCacheImpl, FunctionCache

from . import source_stamp

__all__ = ["CacheUnavailableWarning", "jit", "launch", "parallel_launch", "entry_point", "cached_signatures"]

_CHUNKS_PER_THREAD = 16  # chunks of series per thread, handed out dynamically, for balance


class CacheUnavailableWarning(RuntimeWarning):
    """Numba found no writable cache directory: kernels are compiled anew in each process."""


_MESSAGE = (
    "gaussfuse's compiled kernels cannot be cached on disk: numba found no writable cache "
    "directory. They are compiled in memory instead, again in every new process. To cache "
    "them, set the environment variable NUMBA_CACHE_DIR to a writable directory."
)
_cache = True  # False once numba has found no cache directory: the same for every kernel here
_cache_lock = threading.Lock()


class _Stamped:
    """numba's cache locator for a function, stamping it with every kernel source (see the module notes)."""

    def __init__(self, locator) -> None:
        self._locator = locator

    def __getattr__(self, name):
        return getattr(self._locator, name)

    def get_source_stamp(self) -> bytes:
        return source_stamp()


class _KernelCacheImpl(CompileResultCacheImpl):
    @property
    def locator(self) -> _Stamped:
        return _Stamped(super().locator)


class _KernelCache(FunctionCache):
    """numba's per-function disk cache (:class:`numba.core.caching.FunctionCache`), with the kernels' stamp."""

    _impl_class = _KernelCacheImpl


def jit(*signature, **options) -> Callable[[Callable], numba.core.registry.CPUDispatcher]:
    """``numba.njit(*signature, cache=True, **options)`` with the kernels' cache, or uncached when nothing can be.

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
        dispatcher = numba.njit(**options)(fn)  # lazily: the cache is attached before anything compiles
        if _cache:
            try:
                dispatcher._cache = _KernelCache(fn)  # numba's own enable_caching(), with our cache class
            except RuntimeError as exc:
                if "no locator available" not in str(exc):  # numba's words for "nowhere to cache"
                    raise
                with _cache_lock:
                    warn, _cache = _cache, False
                if warn:
                    warnings.warn(_MESSAGE, CacheUnavailableWarning, stacklevel=2)
        if signature:  # as numba.njit(signature): compiled (or loaded) now, and only for it
            for sig in (signature[0] if isinstance(signature[0], list) else signature):
                dispatcher.compile(sig)
            dispatcher.disable_compile()
        return dispatcher

    return decorate


def cached_signatures(fn: Callable) -> list:
    """The signatures numba's disk cache holds compiled for the kernel function `fn`, from the current sources.

    Read from the cache's index (:class:`_KernelCache`, the one :func:`jit`
    gives `fn`), without compiling or loading anything; empty when nothing
    is cached, or nothing can be.
    """
    if not _cache:
        return []
    try:
        index = _KernelCache(fn)._cache_file._load_index()
    except Exception:  # no locator, an unreadable or foreign index: as good as none
        return []
    return [key[0] for key in index]


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


def launch(serial, parallel, items: int, *args) -> None:
    """``serial(0, items, *args)``, or ``parallel(chunks, *args)`` over chunks of the items.

    `serial` runs items ``lo..hi-1``; `parallel` is its ``parallel=True``
    form over `chunks` contiguous groups (compiled only when a batch needs
    it). Chunks are handed to the threads one at a time as they finish
    (numba's parallel chunk size 1), so a thread slowed down by other work
    on the machine takes fewer of them. One call at a time runs in parallel
    (:func:`parallel_launch`): a call made while another thread's runs takes
    the serial kernel, which gives the same numbers.
    """
    chunks = max(1, min(items, _CHUNKS_PER_THREAD * numba.get_num_threads()))
    if chunks > 1:
        with parallel_launch() as mine:
            if mine:
                previous = numba.set_parallel_chunksize(1)
                try:
                    parallel(chunks, *args)
                finally:
                    numba.set_parallel_chunksize(previous)
                return
    serial(0, items, *args)


def entry_point(dispatcher, *args):
    """The compiled function `dispatcher` runs for arguments like `args`, to call many times with such arguments.

    Compiles it (or loads it from the cache) if needed. Calling the result
    skips numba's dispatch (typing every argument, a few microseconds for a
    tuple of arrays) on each call: for kernels called once a step from a
    Python loop, with arguments of the same types every time.
    """
    sig = tuple(dispatcher.typeof_pyval(a) for a in args)
    dispatcher.compile(sig)
    return dispatcher.overloads[sig].entry_point
