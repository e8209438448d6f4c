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
  chunks of series on a pool of threads. The kernels release the GIL
  (``nogil=True``), so plain Python threads run them on every core: no
  ``parallel=True`` variant is compiled, and numba's threading layers are
  never started.
"""

from __future__ import annotations

import os
import threading
import warnings
from concurrent.futures import ThreadPoolExecutor, wait
from typing import Callable

import numba
from numba.core.caching import CompileResultCacheImpl, FunctionCache

from . import source_stamp

__all__ = ["CacheUnavailableWarning", "jit", "launch", "threads", "entry_point", "cached_signatures"]

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


_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def threads() -> int:
    """How many threads a batch of series runs on: numba's ``NUMBA_NUM_THREADS`` (by default, the cores)."""
    return max(1, int(numba.config.NUMBA_NUM_THREADS))


def _executor() -> ThreadPoolExecutor:
    """The pool the batches of this process share, started on first use."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(threads(), thread_name_prefix="gaussfuse")
        return _pool


def _forget_pool() -> None:
    """In a forked child: the parent's pool threads do not exist there, so start a new pool when needed."""
    global _pool, _pool_lock
    _pool, _pool_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_pool)


def launch(kernel: Callable[..., None], items: int, *args) -> None:
    """``kernel(lo, hi, *args)`` over contiguous chunks ``lo..hi-1`` of the items, in parallel.

    `kernel` runs items ``lo..hi-1`` (series, each independent of the
    others, so the results do not depend on the chunks) and releases the
    GIL. With more than one item and thread, the items are cut into up to
    16 chunks per thread, handed to the threads of a pool shared by every
    call as they finish: a thread slowed down by other work on the machine
    takes fewer of them, and calls from several threads at once share the
    same :func:`threads` threads rather than multiplying them.
    """
    workers = threads()
    chunks = max(1, min(items, _CHUNKS_PER_THREAD * workers))
    if chunks == 1 or workers == 1:
        kernel(0, items, *args)
        return
    pool = _executor()
    done = [pool.submit(kernel, c * items // chunks, (c + 1) * items // chunks, *args) for c in range(chunks)]
    wait(done)  # every chunk has ended before the caller sees its arrays, or an error
    for chunk in done:
        chunk.result()  # raises what the chunk raised


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
