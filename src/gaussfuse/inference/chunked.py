"""Many series in chunks: a dask array of measurements, filtered and smoothed chunk by chunk.

A dask array ``zs`` of shape (N, T, m), chunked over its series axis, is
filtered (or smoothed) one chunk of series at a time, each chunk by the same
batch path as an in-memory array (the compiled batch kernel for the linear
engine), as a task of Dask's graph: nothing is computed until asked, and a
chunk runs where Dask schedules it (a thread, a process, a worker of a
``dask.distributed`` cluster). The result's arrays are dask arrays with the
input's chunks over series; they equal, series for series, the in-memory
batch path on the same input, because each series is filtered on its own.

Dask is imported only here, and only when a dask array is given
(``pip install -e ".[dask]"``).

The divergence check (``check``) runs in each chunk's task, naming series
by their number in the whole array; a warning is issued where the task runs
(in a worker's log on a cluster), and ``check="raise"`` raises from
``compute``. Each field of a result is built from the same task per chunk, so
``dask.compute(res.means, res.covs)`` (or ``dask.compute(res)``) runs each
chunk's filter once; computing the fields one after another runs it once per
field.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import fields, is_dataclass

import numpy as np

from .. import kalman
from .._validation import as_array, shape_error
from ..models.compose import TimedModel
from . import drivers, timing

__all__ = ["is_dask", "chunked_like", "series_blocks", "paired_blocks", "map_series", "observed", "renumber"]


def is_dask(a) -> bool:
    """Whether `a` is a dask collection (without importing dask)."""
    return type(a).__module__.split(".")[0] == "dask" and hasattr(a, "__dask_graph__")


def observed(zs) -> int:
    """The number of observed (not NaN) entries of a dask array (N, T, m), computed.

    Raises
    ------
    ValueError
        Where an entry is infinite, naming its index in the whole array, as
        :func:`gaussfuse.fit` does in memory (in the same pass over the data;
        audit NN1: the pooled fit met it as an overflow of a chunk's series).
    """
    import dask
    import dask.array as da

    count, infinite = dask.compute((~da.isnan(zs)).sum(), da.isinf(zs).any(axis=(1, 2)))
    bad = np.flatnonzero(infinite)
    if bad.size:
        s = int(bad[0])
        try:
            as_array("zs", np.asarray(zs[s:s + 1].compute(), dtype=np.float64), allow_nan=True, copy=False)
        except ValueError as err:
            renumber(err, s, 1)
            raise
    return int(count)


def observed_series(zs) -> np.ndarray:
    """Which series (N,) of a dask array (N, T, m) have an observed (not NaN) entry, computed."""
    import dask.array as da

    return np.asarray((~da.isnan(zs)).any(axis=(1, 2)).compute())


def series_blocks(a):
    """A dask array (N, T, k), checked by :func:`check_lazy`: its blocks, one per chunk of series, and their sizes.

    A chunked time or component axis is rejoined: each chunk of series needs its whole series.
    """
    if any(len(c) > 1 for c in a.chunks[1:]):
        a = a.rechunk({1: -1, 2: -1})
    return a.astype(np.float64).to_delayed().reshape(-1).tolist(), a.chunks[0]


def chunked_like(us, zs):
    """`us` as a dask array: as it is if it is one, else (an array in memory, of the shape :func:`check_lazy`
    checked) chunked over series as `zs` is."""
    if us is None or is_dask(us):
        return us
    import dask.array as da

    return da.from_array(np.asarray(us), chunks=(zs.chunks[0], -1, -1))


def paired_blocks(zs, us) -> tuple[list, list, tuple]:
    """The blocks of `zs` and of `us` (None for each when `us` is None), chunk for chunk, and the chunks' sizes.

    Raises
    ------
    ValueError
        When `us` is not chunked over series as `zs` is.
    """
    blocks, sizes = series_blocks(zs)
    if us is None:
        return blocks, [None] * len(blocks), sizes
    controls, control_sizes = series_blocks(chunked_like(us, zs))
    if control_sizes != sizes:
        raise ValueError(f"`us` must be chunked over series as `zs` is; got chunks {control_sizes} and {sizes}.")
    return blocks, controls, sizes


def map_series(run: Callable, zs, us, kwargs: dict):
    """``run(zs=chunk, us=chunk, **kwargs)`` on each chunk of series, as a result whose arrays are dask arrays.

    Parameters
    ----------
    run : callable
        The in-memory front function (``filter`` or ``smooth``): called on a
        chunk's (N_c, T, m) block, it returns a result with the series axis.
    zs, us : dask arrays (N, T, m) and (N, T, p) or None
    kwargs : dict
        The other arguments of `run`. The result's structure is read from
        `run` on one series of zeros (readable path, no check), longer than
        n, m and p by more than one step, so that its time axes are told
        apart from the model's; where the model's functions fail on zeros,
        on the first series' own first steps (its first chunk computed),
        or the whole of it when it is shorter.

    Raises
    ------
    TypeError, ValueError
        Before any chunk runs, when `zs` or `us` is not an array of numbers
        of the shape the model needs (:func:`check_lazy`). An error of a
        chunk's run, raised by ``compute``, names the series by its number
        in the whole array.

    Returns
    -------
    The result type of `run`, its arrays dask arrays chunked like `zs` over
    series; a ``loglik`` is an (N,) array.
    """
    import dask
    import dask.array as da

    check_lazy(zs, us, kwargs.get("model"))
    us = chunked_like(us, zs)  # (a list or an array in memory)
    blocks, controls, sizes = paired_blocks(zs, us)
    T = zs.shape[1]

    # The probe steps as the real times do (their step, or their steps cycled), from their first time (in float
    # seconds, their round-off is theirs): its model is resolved as theirs.
    times = kwargs.get("times")
    grid = None if times is None else timing.steps("times", times, T, kwargs.get("model"))
    if times is not None and not isinstance(kwargs.get("model"), TimedModel):  # every step's, before any chunk runs
        timing.resolve(kwargs.get("model"), times, T)  # (the probe's were its first few only: audit NN3)
    start = None if times is None else float(timing.as_seconds("times", times)[0])

    def meta(steps: int, own: bool = False):
        stepped = None if grid is None else start + np.concatenate([[0.0], np.cumsum(
            np.full(steps, grid.step) if grid.regular else np.resize(grid.dts, steps))])
        probes = [None if a is None else np.zeros((1, steps, a.shape[2])) if not own else
                  np.asarray(a[:1, :steps].compute(), dtype=np.float64) for a in (zs, us)]  # (its first steps)
        return run(zs=probes[0], us=probes[1], **{**kwargs, "engine": "python", "check": "off", "times": stepped})

    # A result's other axes are the model's n, m and p: an axis of the probe's length, or one less or more, is a
    # time axis. The probe is longer than the state dimension, so that a diffuse prior is identified (2 steps did
    # not identify 3 states measured by one component: NotIdentified before any chunk ran).
    probe = max(zs.shape[2], getattr(kwargs.get("model"), "n", 0), 0 if us is None else us.shape[2]) + 3
    if getattr(kwargs.get("model"), "steps", None) is not None:  # matrices per step: T steps, whose axes are T's
        probe = T
    try:
        template = meta(probe)
    except (ValueError, FloatingPointError):  # (a ModelFunctionError, a LinAlgError)
        template = None  # the model's f or h fail where zeros lead it (a square root of a level: audit BB3)
    if template is None:  # the data's own first steps lead it where the chunks will (not within `except`: its
        # error is then the data's alone); a series shorter than the probe is taken whole, whose axes are then
        # the result's (made longer, by steps missing or by its steps again, the model met a state or a seam that
        # no series has: reviews R19-R21)
        probe = min(probe, T)
        try:
            template = meta(probe, own=True)
        except (ValueError, FloatingPointError) as err:  # at a step of the first series: name it, as a chunk does
            step = re.match(r"at step (\d+)", str(err))
            if step is not None and int(step.group(1)) < T:
                renumber(err, 0, 1)
            raise
    firsts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).tolist()
    tasks = [dask.delayed(_chunk, pure=True)(run, first, block, control, kwargs, size / zs.shape[0])
             for first, block, control, size in zip(firsts, blocks, controls, sizes)]

    def build(template, path):
        if not is_dataclass(template):
            return template
        values = {}
        for f in fields(template):
            value = getattr(template, f.name)
            if is_dataclass(value):
                values[f.name] = build(value, path + (f.name,))
            elif isinstance(value, np.ndarray) and value.ndim >= 1:
                # a time axis of the probe's length (or one less or more) is T's (or T - 1's or T + 1's)
                shape = tuple(T + d - probe if abs(d - probe) <= 1 else d for d in value.shape[1:])
                values[f.name] = da.concatenate([
                    da.from_delayed(dask.delayed(_field, pure=True)(task, path + (f.name,)),
                                    shape=(size, *shape), dtype=value.dtype)
                    for task, size in zip(tasks, sizes)])
            else:
                values[f.name] = value
        return type(template)(**values)

    return build(template, ())


def check_lazy(zs, us, model) -> None:
    """Check the dtype and shape of a dask `zs` (N, T, m) and `us` (N, T, p), without computing a dask array.

    A dask array's values are checked where each chunk runs; a `us` in
    memory (an array or nested lists) is checked whole here, as
    :func:`gaussfuse.filter` checks it.

    Raises
    ------
    TypeError
        When either is not an array of numbers (a `us` in memory: not a
        rectangular array of real numbers).
    ValueError
        When `zs` is not (N, T, m) with the model's m, N >= 1 and T >= 1, or
        `us` is not (N, T, p) with the N and T of `zs` (and the model's p,
        when it has one); when a `us` in memory is NaN or infinite.
    """
    for name, a in (("zs", zs), ("us", us)):
        if a is not None and is_dask(a) and not hasattr(a, "chunks"):  # a dask DataFrame or Series (audit NN5)
            raise TypeError(f"`{name}` must be a dask array of N series, (N, T, k); got a dask "
                            f"{type(a).__name__}: make one with .to_dask_array(lengths=True) and reshape it, or give "
                            "the command line a long table with --series-column.")
        if a is not None and is_dask(a) and any(np.isnan(c).any() for c in map(np.asarray, a.chunks)):
            raise ValueError(f"`{name}` has chunks of unknown size (shape {a.shape}), as a dask array indexed by a "
                             f"mask has: call `{name}.compute_chunk_sizes()` first.")
        dtype = None if a is None else a.dtype if is_dask(a) else as_array(name, a).dtype  # (`us` may be a list)
        if dtype is not None and dtype.kind not in "iuf":
            raise TypeError(f"`{name}` must be an array of real numbers; got {'a dask array' if is_dask(a) else 'an array'}"
                            f" of {dtype}.")
    m = getattr(model, "m", None)
    if zs.ndim != 3 or 0 in zs.shape[:2] or (isinstance(m, int) and zs.shape[2] != m):
        raise shape_error("zs", f"(N, T, {m if isinstance(m, int) else 'm'}) with N >= 1 and T >= 1 (a dask "
                          "array of N series)", zs.shape)
    p = getattr(model, "p", None)
    if us is not None and (np.ndim(us) != 3 or np.shape(us)[:2] != zs.shape[:2]
                           or (isinstance(p, int) and p > 0 and np.shape(us)[2] != p)):
        raise shape_error("us", f"(N, T, {p if isinstance(p, int) and p > 0 else 'p'}) = ({zs.shape[0]}, "
                          f"{zs.shape[1]}, {p if isinstance(p, int) and p > 0 else 'p'}), the series and steps of "
                          "`zs`", np.shape(us))


def _chunk(run: Callable, first: int, zs: np.ndarray, us: np.ndarray | None, kwargs: dict, share: float = 1.0):
    """`run` on one chunk of series; its errors and divergence check name the series by their numbers in the
    whole array.

    The chunk's test spends its `share` of the series of the false-alarm rate, so that the call's is the one
    an in-memory call has (each chunk spending all of it made 1,000 one-series chunks warn in 2.6% of calls
    on consistent data, for 4.5e-6 in memory)."""
    check = kwargs.get("check", "warn")
    try:
        result = run(zs=zs, us=us, **{**kwargs, "check": "off"})
    except (ValueError, TypeError, FloatingPointError) as err:  # (LinAlgError and ModelFunctionError are ValueErrors)
        renumber(err, first, zs.shape[0])
        raise
    gate = kalman.Gate.of(kwargs.get("gate"), kwargs.get("gate_by", "measurement"))  # the gate's lost-track test too
    drivers.check_divergence(getattr(result, "filtered", result), check, first_series=first, gate=gate, share=share)
    return result


def renumber(err: Exception, first: int, size: int) -> None:
    """Name the series in `err`'s message by their numbers in the whole array, whose chunk of `size` starts at
    `first`: the drivers' leading "in series s" and the check of `zs` or `us` ("... at index (s, ...") move by
    `first` (not a number in the user's own text: review R19); a message naming none gets the chunk's series."""
    if not err.args or not isinstance(err.args[0], str):
        return
    message = err.args[0]
    ours = re.match(r"(in series |`(?:zs|us)` must [^:]*? at index \()(\d+)", message)
    if ours:
        renumbered = f"{ours.group(1)}{int(ours.group(2)) + first}{message[ours.end():]}"
    else:
        renumbered = f"in series {first}{'' if size == 1 else f' to {first + size - 1}'}, {message}"
    err.args = (renumbered, *err.args[1:])


def _field(result, path: tuple):
    for name in path:
        result = getattr(result, name)
    return result
