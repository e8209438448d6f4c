"""The ``gaussfuse`` command: ``gaussfuse demo``, ``gaussfuse filter`` and ``gaussfuse fit``.

The work is done by :mod:`gaussfuse.io`, the filters and
:mod:`gaussfuse.plotting`; this module parses arguments, prints, and turns a
bad-input error into one line ``gaussfuse: error: <message>`` on stderr and
exit status 2. Outputs are written with :func:`gaussfuse.io.open_atomic`, so
that no user's file is ever destroyed; an output that is the same file as an
input, or as another output, is refused before any work. SIGTERM stops the
program as Ctrl-C does (exit status 143 instead of 130), and a standard
output closed early (``| head``) ends it quietly with status 141.
"""

from __future__ import annotations

import argparse
import csv
import errno
import itertools
import os
import re
import signal
import stat
import sys
import tempfile
import threading
import warnings
from contextlib import contextmanager, nullcontext, suppress
from io import StringIO
from typing import NamedTuple

import numpy as np

from . import __version__, inference, learning, panels, plotting
from . import io as gfio
from .errors import STEP_ERRORS, ConvergenceWarning, DivergenceWarning, fixed_text, spooled
from .gaussian import Gaussian
from .inference import FilterResult, SmoothResult
from .inference import streaming, timing
from .inference.drivers import ENGINES
from .models import LinearModel, constant_velocity

__all__ = ["main", "build_parser", "textbook_example", "tracking_demo", "TrackingDemo"]

DEMO_FIGURE = "gaussfuse-demo.png"
NOT_CONVERGED = 3
"""Exit status of ``gaussfuse fit`` when the fit stopped before converging."""

_FORMATS = """\
DATA.csv: a header row; one time column, named `t` or `time` (any case) or
by --time-column, strictly increasing: seconds, or ISO-8601 times such as
2026-05-01T12:00:00.5+02:00 (UTC without a zone; read to the nanosecond,
each becomes seconds since the file's first time, rounded once: a step is
exact to about 1e-16 of that time, 4 ns a year in); every other column (or
those named by --columns), in order, is one measurement component (as many
as the model's m); for a named model, columns named as the states it
measures (x, y, or its `states` names for them, in any case) are taken
by name, in any order, and columns named as states it does not measure (vx)
are refused. An empty cell or NaN is a missing component.

MODEL.toml: explicit matrices
    [model]
    F = [[1.0, 1.0], [0.0, 1.0]]
    H = [[1.0, 0.0]]
    Q = [[0.25, 0.5], [0.5, 1.0]]
    R = [[4.0]]
    states = ["x", "v"]            # optional; default x0, x1, ...
(with `filter`, any of F, H, Q and R may instead be an array of matrices,
one per row of DATA.csv: Q = [[[0.25]], [[0.5]], ...]), or a named model
    [model]
    kind = "constant_velocity"     # or "constant_position", "constant_acceleration"
    dim = 2                        # 1, 2 or 3 axes (default 1)
    dt = 0.5
    q = 1.0
    r = 0.25
and optionally the belief one step before the first measurement
    [prior]
    mean = [0.0, 0.0, 1.0, 0.0]    # default: zeros
    var = 100.0                    # var * I, or cov = [[...]]
Without [prior] the prior is N(0, 1e6 I); `diffuse = true` alone in [prior]
is a flat prior, handled exactly (the rows before the data determine the
whole state are written as nan; with --series-column, as empty cells,
pandas' missing value). A control input (B) is not supported
yet."""

_FILTER_STEPS = """\
A named model steps by the data's own times: each step is discretised
exactly for its dt (the file's dt is used only for a single row, and a
warning says when the times step otherwise). Explicit matrices make every
row one step (of the same matrices, or of that row's): with irregular times
a warning says so.

Output CSV: the time column as written in DATA.csv, the state means, then
std_<state> for each state, written with full float precision.

Files of any length: DATA.csv is read in pieces and the estimates are
spooled to a temporary file (in TMPDIR, about the output's size; the
smoother also keeps the pieces there), then copied to the output, so memory
does not grow with the file (except for --plot, and for the smoother with a
diffuse prior, which reads the file whole)."""

_FIT_STEPS = """\
A named model is fitted at the data's step: times on a regular grid are
steps of the model discretised for that grid's dt (a warning says when the
file's dt differs). A fitted model has one set of matrices, so with
irregular times every row is fitted as one step of the file's dt, and a
warning says so; explicit matrices are always for one step per row. The
fitted model is written as explicit matrices.

DATA.csv is read whole; with --series-column, each partition where a
worker runs, and every series is fitted with one step per row."""

_LIMITS = """\
Limits, so that a wrong file fails at once: DATA.csv must be text (no NUL
character) with lines of at most 1 Mi characters; MODEL.toml at most 8 MiB,
its tables and arrays nested at most 16 levels deep."""

_OUTPUTS = """\
Output files are written whole or not at all: an existing file is replaced
only once the output is complete, keeping its permissions; a symlink is
written through to its file and stays a link; a FIFO or a character device
(/dev/null, a terminal) is written in place. An output that is the same file
as an input, or as another output, is refused (exit status 2)."""

_EXIT_STATUSES = """\
exit status:
  0    success
  2    bad arguments or bad input; one line `gaussfuse: error: ...` on stderr
  3    `fit` did not converge: the best model found is written all the same,
       and one line `gaussfuse: warning: ...` on stderr says so
  130  interrupted by Ctrl-C (`fit` first writes the best model so far)
  141  standard output closed early, e.g. by `| head`
  143  terminated by SIGTERM, as by Ctrl-C"""


# ---------------------------------------------------------------------------
# The demo
# ---------------------------------------------------------------------------


def textbook_example() -> tuple[np.ndarray, FilterResult]:
    """The textbook 1-D position/velocity example, filtered.

    ``x0 = [0, 1]``, ``P0 = 500 I``, ``F = [[1, 1], [0, 1]]``, ``H = [1, 0]``,
    ``Q = diag(1, 3)``, ``R = 10`` and measurements 1, 2, 3, 2, 1.

    Returns
    -------
    zs : ndarray of shape (5,)
        The measurements.
    result : FilterResult
        The filtered beliefs.
    """
    model = LinearModel(F=[[1, 1], [0, 1]], H=[1, 0], Q=np.diag([1.0, 3.0]), R=10)
    zs = np.array([1.0, 2.0, 3.0, 2.0, 1.0])
    return zs, inference.filter(model, Gaussian([0, 1], 500 * np.eye(2)), zs)


class TrackingDemo(NamedTuple):
    """A simulated 2-D constant-velocity track, filtered and smoothed.

    Attributes
    ----------
    times : ndarray of shape (T,)
    truth : ndarray of shape (T, 4)
        True states ``[x, y, vx, vy]``.
    zs : ndarray of shape (T, 2)
        Noisy position measurements.
    smoothed : SmoothResult
        The smoother; ``smoothed.filtered`` is the filter.
    rmse : dict of str to float
        Position RMSE of ``"measurements"``, ``"filter"`` and ``"smoother"``.
    """

    times: np.ndarray
    truth: np.ndarray
    zs: np.ndarray
    smoothed: SmoothResult
    rmse: dict[str, float]


def tracking_demo(seed: int = 0, steps: int = 150, dt: float = 0.1, q: float = 1.0,
                  r: float = 0.25) -> TrackingDemo:
    """Simulate a 2-D constant-velocity target, then filter and smooth it.

    Parameters
    ----------
    seed : int, default 0
        Seed of :func:`numpy.random.default_rng`.
    steps : int, default 150
        Number of measurements T.
    dt, q, r : float
        Time step, acceleration noise density and position-measurement
        variance of :func:`gaussfuse.constant_velocity`.

    Returns
    -------
    TrackingDemo
    """
    rng = np.random.default_rng(seed)
    model = constant_velocity(dt, q, r, dim=2)
    prior = Gaussian([0.0, 0.0, 1.0, 0.5], np.eye(4))
    x = prior.sample(rng=rng)
    truth = np.empty((steps, 4))
    for k in range(steps):
        x = model.F @ x + rng.multivariate_normal(np.zeros(4), model.Q)
        truth[k] = x
    zs = truth @ model.H.T + rng.multivariate_normal(np.zeros(2), model.R, size=steps)
    smoothed = inference.smooth(model, prior, zs)

    def rmse(positions: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((positions - truth[:, :2]) ** 2, axis=1))))

    errors = {"measurements": rmse(zs), "filter": rmse(smoothed.filtered.means[:, :2]),
              "smoother": rmse(smoothed.means[:, :2])}
    return TrackingDemo(dt * np.arange(1, steps + 1), truth, zs, smoothed, errors)


def _run_demo(args: argparse.Namespace) -> int:
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer; got {args.seed}.")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out {args.out} is a file; it must be a directory (created if missing).")
    # the folder its figures go in, or the one it is made in: before printing. Not normalised (abspath takes
    # "link/.." as the working folder, where the OS takes the link's target's parent, or fails on a dangling one)
    existing = os.path.join(os.getcwd(), args.out)
    while not os.path.lexists(existing):  # (a read-only one printed the tables, then failed: audit EE2; a
        # dangling link is a name the folder cannot be made under: review R36)
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise NotADirectoryError(errno.ENOTDIR, f"{os.strerror(errno.ENOTDIR)} (on the way to `--out`)", existing)
    resolved = os.path.realpath(args.out)  # where the OS puts it: "new/../.." leaves the folder made (review R38)
    while not os.path.exists(resolved):
        resolved = os.path.dirname(resolved)
    _takes_a_file(resolved, "`--out`", args.out)
    path = os.path.join(args.out, DEMO_FIGURE)
    if os.path.isdir(path):  # (it printed the tables, then failed: audit YY1)
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), path)
    if os.path.islink(path) and not os.path.isdir(os.path.dirname(os.path.realpath(path))):  # (review R54)
        raise FileNotFoundError(errno.ENOENT, f"{os.strerror(errno.ENOENT)} (the folder its link points into)", path)
    zs, res = textbook_example()
    print("1-D textbook example: x0 = [0, 1], P0 = 500 I, F = [[1, 1], [0, 1]], H = [1, 0],")
    print("Q = diag(1, 3), R = 10")
    print(f"{'step':>4} {'z':>6} {'position':>10} {'velocity':>10} {'std(pos)':>10}")
    for k, (z, m, P) in enumerate(zip(zs, res.means, res.covs), start=1):
        print(f"{k:>4} {z:>6.1f} {m[0]:>10.4f} {m[1]:>10.4f} {np.sqrt(P[0, 0]):>10.4f}")

    demo = tracking_demo(args.seed)
    print()
    print(f"2-D constant-velocity target, {len(demo.times)} steps, seed {args.seed}")
    print(f"{'estimate':<12} {'position RMSE':>14}")
    for name, value in demo.rmse.items():
        print(f"{name:<12} {value:>14.4f}")

    os.makedirs(args.out, exist_ok=True)
    sm = demo.smoothed
    estimates = {"filtered": (sm.filtered.means, sm.filtered.covs), "smoothed": (sm.means, sm.covs)}
    plotting.save_figure(plotting.plot_demo(demo.times, demo.zs, demo.truth, estimates), path)
    print()
    print(f"figure: {path}")
    return 0


# ---------------------------------------------------------------------------
# gaussfuse filter
# ---------------------------------------------------------------------------


def _run_filter(args: argparse.Namespace) -> int:
    """`gaussfuse filter`: the file in pieces (:func:`gaussfuse.io.iter_measurements`), so memory is bounded.

    The estimates go to a temporary spool, piece by piece (the smoother's
    last piece first), and are copied to the output in order once all are
    computed: an error leaves no output, and no partial standard output.
    """
    _check_paths(args, {"--out": args.out, "--plot": args.plot})
    _check_many(args)
    spec = gfio.read_model(args.model)
    columns = _columns(args)
    if args.series_column is not None:
        return _run_many(args, spec, columns)
    read = {"m": spec.model.m, "time_column": args.time_column, "columns": columns, "names": spec.sensed()}
    if (args.smooth and isinstance(spec.prior, str)) or spec.model.steps is not None:
        # A diffuse prior is smoothed whole; matrices given per step are for the whole file, which they already
        # hold in memory step by step.
        pieces = iter([gfio.read_measurements(args.data, **read)])
    else:
        pieces = gfio.iter_measurements(args.data, rows=_piece_rows(spec.model.n, spec.model.m), **read)
    head = next(pieces)
    try:  # refused before the work, if ambiguous
        columns_out = gfio.estimate_columns(head.columns[0], spec.state_names)
    except ValueError as exc:
        raise ValueError(f"{args.model}: {exc}") from None
    if spec.model.steps is not None and spec.model.steps != head.zs.shape[0]:
        raise ValueError(f"{args.model}: [model]: the matrices are given for {spec.model.steps} "
                         f"step{'s' * (spec.model.steps != 1)}, but "
                         f"{args.data} has {head.zs.shape[0]} rows; give one per row.")
    steps = _Steps(spec, head)
    pieces = steps.watch(itertools.chain([head], pieces))
    model = spec.timed if steps.timed else spec.model
    run = streaming.smooth_pieces if args.smooth else streaming.filter_pieces
    drawn = _Drawn() if args.plot else None
    progress = _RowProgress()
    pieces = progress.count("filtered", pieces)
    with tempfile.TemporaryFile() as spool:
        starts = []  # where each piece's rows start in the spool, in the order written
        try:
            for piece, result in run(model, spec.prior, pieces, timed=steps.timed, engine=args.engine,
                                     check=args.check):
                text = StringIO()
                gfio.write_estimates(text, piece.time_text, result.means, result.covs, spec.state_names,
                                     header=False)
                starts.append(spool.tell())
                spooled(spool.write, text.getvalue().encode("utf-8"))
                if args.smooth:
                    progress.add("smoothed", piece.zs.shape[0])
                if drawn is not None:
                    drawn.add(piece, result)
        except (ValueError, FloatingPointError, DivergenceWarning) as exc:  # (--check raise's too: audit JJ5)
            if isinstance(exc, gfio.InputFileError):
                raise  # a reading error, which names the file and line already
            raise type(exc)(f"{args.data}: {exc}") from exc  # the data's series: name the file
        finally:
            progress.close()
        spooled(spool.flush)  # (a full folder may show only here)
        steps.warn()
        spans = list(zip(starts, starts[1:] + [spool.tell()]))
        # Into a file, the CSV is written (to its temporary name) before the figure is saved, and appears
        # after it: on an error, neither does. To standard output, which cannot be taken back, the figure
        # comes first.
        def draw() -> None:
            if drawn is not None:
                plotting.save_figure(drawn.figure(spec, args.data, head.columns, args.smooth, steps.stamps), args.plot)

        with gfio.open_atomic(args.out, "wb") if args.out else nullcontext(_StandardOutput()) as out:
            if not args.out:
                draw()
            out.write(_header(columns_out))
            for start, stop in (reversed(spans) if args.smooth else spans):  # the smoother wrote the last first
                spool.seek(start)
                while start < stop:
                    block = spooled(spool.read, min(stop - start, 2**24))
                    out.write(block)
                    start += len(block)
            if args.out:
                out.flush()  # a full disk shows here, before the figure is drawn
                draw()
    return 0


def _run_many(args: argparse.Namespace, spec: gfio.ModelFile, columns) -> int:
    """`gaussfuse filter --series-column`: each partition filtered where a worker runs, to its own output file."""
    if not args.out:
        raise ValueError("--series-column writes one output file per partition: name an output directory with --out "
                         "(standard output, --out -, holds one file).")
    if args.plot:
        raise ValueError("--plot draws one series; leave it out with --series-column.")
    if spec.model.steps is not None:
        raise ValueError(f"{args.model}: [model]: matrices given per row ({spec.model.steps} of them) are for one "
                         "series, the rows of one file; with --series-column give one set of matrices for every "
                         "series.")
    parts = panels.partitions(args.data)
    out = os.path.realpath(args.out)
    if os.path.isdir(args.data):  # every file under the data directory is a partition, now or on the next run
        source = os.path.realpath(args.data)
        if out == source or out.startswith(source.rstrip(os.sep) + os.sep):
            raise ValueError(f"`--out` {args.out} is inside the data directory {args.data}; choose one outside it, "
                             "so that no input is replaced and no output is read as data.")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"`--out` {args.out} is a file; with --series-column it is a directory (created if missing).")
    finals = [panels.output_path(args.data, part, args.out) for part in parts]
    inputs = {os.path.realpath(part) for part in parts}
    for final in finals:
        if os.path.realpath(final) in inputs:
            raise ValueError(f"`--out` {args.out} would write {final} over an input; choose another directory.")
    with _written_together(finals) as temps, _cluster(args) as client:
        import distributed

        futures = [client.submit(panels.filter_partition, part, temp, spec, args.series_column,
                                 smooth=args.smooth, time_column=args.time_column, columns=columns,
                                 engine=args.engine, check=args.check, pure=False)
                   for part, temp in zip(parts, temps)]
        progress = _RowProgress(unit=f"of {len(parts):,} partitions")  # (it said "partitions: 2 rows": audit BB3)
        try:
            for future in distributed.as_completed(futures):
                future.result()  # a partition's error stops the command here
                progress.add("done", 1)
        except Exception:
            distributed.wait(futures)  # the partitions still running finish first: none writes after the cleanup
            raise
        finally:
            progress.close()
        done = client.gather(futures)
        seen: dict = {}
        for part, (ids, _, _) in zip(parts, done):  # checked before the outputs are kept
            for i in ids:
                if i in seen:
                    raise ValueError(f"series {i!r} is in two partitions ({seen[i]} and {part}); each series must "
                                     "lie in one partition (a part alone would start again from the prior).")
                seen[i] = part
        if not seen:  # (a partition of a header only is one without series, but not all of them)
            raise ValueError(_no_rows(args.data, parts))
    for _, _, messages in done:
        for message in messages:
            print(f"gaussfuse: warning: {message}", file=sys.stderr)
    rows = sum(r for _, r, _ in done)
    print(f"{'smooth' if args.smooth else 'filter'}: {len(seen):,} series, {rows:,} rows in {len(parts)} "
          f"partition(s); wrote {args.out}", file=sys.stderr)
    return 0


@contextmanager
def _written_together(finals: list[str]):
    """Temporary names beside the output files `finals`, renamed to them once the block succeeds.

    As :func:`gaussfuse.io.open_atomic` writes one file: an existing output
    is replaced keeping its permissions, a symbolic link is written through
    to its file, and one that is not a regular file (a folder) or that the
    user may not write is refused before the block runs (audit JJ2, JJ4: a
    folder failed after the work, with earlier outputs already replaced).
    On an error, the temporary files and the directories made for them are
    removed: a failed run leaves no output, and replaces no earlier one.
    """
    targets, kept = [], []
    for final in finals:
        try:
            info = os.stat(final)  # of the file a symlink points to
        except FileNotFoundError:
            info = None
        if info is not None and not stat.S_ISREG(info.st_mode):
            raise ValueError(f"{final}: an output that exists must be a file; it is "
                             f"{'a directory' if stat.S_ISDIR(info.st_mode) else 'not a regular file'}.")
        target = gfio._replaced_file(final, info)
        if target in targets:  # (through a symlink: one temporary file for both, and a failure after the work)
            raise ValueError(f"{final} and {finals[targets.index(target)]} are the same file; each output must be "
                             "a file of its own.")
        targets.append(target)
        kept.append(info)
    temps = [os.path.join(os.path.dirname(t), f".partial-{os.getpid()}-{os.path.basename(t)}") for t in targets]
    made = set()
    for target in targets:
        directory = os.path.dirname(target)
        while not os.path.exists(directory):
            made.add(directory)
            directory = os.path.dirname(directory)
    try:
        yield temps
        for temp, info in zip(temps, kept):
            if info is not None:  # what the user had
                gfio._keep_status(temp, info)
        for temp, target in zip(temps, targets):
            os.replace(temp, target)
    except BaseException:
        for temp in temps:
            with suppress(FileNotFoundError):
                os.remove(temp)
        for directory in sorted(made, key=len, reverse=True):  # deepest first; only if left empty
            with suppress(OSError):
                os.rmdir(directory)
        raise


@contextmanager
def _cluster(args: argparse.Namespace):
    """A Dask client: of the cluster at `--scheduler`, or of a local cluster of `--workers` processes."""
    try:
        import distributed
    except ImportError:
        raise ValueError("--series-column runs on Dask: install it with pip install -e \".[dask]\".") from None
    import logging

    if args.scheduler:
        with distributed.Client(args.scheduler, timeout="30s") as client:
            yield client
        return
    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the local cluster's notes about ports and dashboards
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.CRITICAL)
    with cluster, distributed.Client(cluster) as client:  # a task's error reaches the client, not the logs
        yield client


def _piece_rows(n: int, m: int) -> int:
    """Rows per piece of a file: a piece's arrays (about 6 n² + m² floats per row for the smoother) in ~32 MiB."""
    return int(np.clip(2**25 // (8 * (6 * n * n + 3 * n + m * m + m)), 1024, gfio.CHUNK_ROWS))


class _StandardOutput:
    """Standard output for the results, taking UTF-8 bytes (after what was written as text), whatever the
    locale's encoding; a failed write names standard output (``> /dev/full`` said "[Errno 28] No space left on
    device", naming nothing)."""

    def __init__(self) -> None:
        with _failing_output():
            sys.stdout.flush()  # what was written as text goes first
        buffer = getattr(sys.stdout, "buffer", None)
        self._write = sys.stdout.write if buffer is None else buffer.write
        self._decode = buffer is None  # a text stream taking bytes, such as a test's StringIO

    def write(self, data) -> None:
        with _failing_output():
            if self._decode:
                self._write(data.decode("utf-8"))
                return
            view = memoryview(data)
            while view:  # a pipe closed in the middle takes part and returns its count; the next write raises
                written = self._write(view)
                if not written:  # (a stream that took nothing and said nothing: never loop on it)
                    raise OSError(errno.EIO, "standard output took none of the results")
                view = view[written:]


class _OutputFailed(Exception):
    """A write of the results to standard output failed, with the OSError as its cause."""


@contextmanager
def _failing_output():
    """An OSError of standard output as :class:`_OutputFailed`; a closed pipe stays one (exit status 141)."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise _OutputFailed from exc


def _header(names: list[str]) -> bytes:
    """The CSV header row of `names`, quoted as the csv module quotes."""
    text = StringIO()
    csv.writer(text, lineterminator="\n").writerow(names)
    return text.getvalue().encode("utf-8")


class _Steps:
    """How a file's rows step in time: whether a named model steps by them, and the warnings to give.

    A named model steps by the data's times (each step discretised for its
    own dt); explicit matrices are for one fixed step. :meth:`watch` follows
    the times as the pieces are read; :meth:`warn` says, in one line, when
    explicit matrices met irregular times, or a named model's dt is not the
    times' regular step.
    """

    def __init__(self, spec: gfio.ModelFile, head: gfio.Measurements) -> None:
        self.spec = spec
        self.timed = spec.timed is not None and head.times.shape[0] >= 2  # one row: the file's dt
        self.stamps = not _is_number(head.time_text[0])  # ISO-8601 times
        self.low, self.high, self.last, self.largest = np.inf, -np.inf, None, 0.0
        self.total, self.count = 0.0, 0  # the steps' sum and number: their mean, as one array's (review R12)

    def watch(self, pieces):
        for piece in pieces:
            times = piece.times if self.last is None else np.concatenate([[self.last], piece.times])
            if times.shape[0] >= 2:
                with np.errstate(over="ignore"):  # times ±1e308 apart: the filter names that step
                    steps = np.diff(times)
                self.low, self.high = min(self.low, float(steps.min())), max(self.high, float(steps.max()))
                self.total, self.count = self.total + float(np.sum(steps)), self.count + steps.size
                self.largest = max(self.largest, float(np.abs(times).max()))
            self.last = piece.times[-1]
            yield piece

    def warn(self) -> None:
        if self.high < 0:
            return
        said = panels.step_warning(self.spec, timing.Steps(np.array([self.low, self.high]),
                                                           timing.round_off(self.largest), self.total, self.count))
        if said is not None:
            print(f"gaussfuse: warning: {said}", file=sys.stderr)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class _RowProgress:
    """Rows (or other `unit`s) done, on one line of stderr, when stderr is a terminal: ``filtered: 1,234,567 rows``."""

    def __init__(self, stream=None, unit: str = "rows") -> None:
        self.done: dict[str, int] = {}
        self.unit = unit
        self.stream = stream if stream is not None else sys.stderr
        self.live = self.stream is not None and self.stream.isatty()

    def count(self, what: str, pieces):
        """The pieces, counted under `what` as they go by."""
        for piece in pieces:
            yield piece
            self.add(what, piece.zs.shape[0])

    def add(self, what: str, rows: int) -> None:
        self.done[what] = self.done.get(what, 0) + rows
        if self.live:
            self.stream.write("\r" + ", ".join(f"{name}: {n:,} {self.unit}" for name, n in self.done.items()))
            self.stream.flush()

    def close(self) -> None:
        if self.live and self.done:
            self.stream.write("\n")


class _Drawn:
    """What `--plot` draws, kept in memory as the pieces go by (the only part of the command that grows with the file)."""

    def __init__(self) -> None:
        self.parts: list[tuple] = []

    def add(self, piece: gfio.Measurements, result) -> None:
        self.parts.append((piece.times, piece.zs, result.means, result.covs, piece.time_text[0]))

    def figure(self, spec: gfio.ModelFile, data: str, columns: list[str], smoothed: bool, stamps: bool):
        """Measurements against the estimates, titled; with an x–y panel for two measurement columns.

        ISO-8601 times are drawn as seconds since the first. Plain numbers are
        seconds to a named model, which steps by them, and have no unit to
        explicit matrices, which only label the rows with them (a year).
        """
        parts = sorted(self.parts, key=lambda p: p[0][0])  # the smoother's come last first
        times, zs, means, covs = (np.concatenate(a) for a in list(zip(*parts))[:4])
        what = "smoothed" if smoothed else "filtered"
        columns = [_literal(c) for c in columns]
        xlabel = columns[0]
        if stamps:
            xlabel = f"{columns[0]} since {parts[0][4]}"
            times = times - times[0]
        return plotting.plot_measurements(
            times, zs, means, covs, spec.model.H, names=columns[1:], label=what, xlabel=xlabel,
            time_unit="s" if stamps or spec.timed is not None else None,
            title=f"{_literal(os.path.basename(data))}: {what} estimates, ±2σ", track=len(columns) == 3)


def _literal(text: str) -> str:
    """A file's or a column's name as matplotlib draws it as written: ``$`` escaped (it starts mathtext), and a
    byte that is not UTF-8 (in a file's name) as U+FFFD. A column "$\\foo$" and a file "f_\\xff.csv" failed the
    figure after the work was done (audit JJ3)."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace").replace("$", r"\$")


def _check_many(args: argparse.Namespace) -> None:
    """--scheduler and --workers are for --series-column; --workers is a positive count."""
    if args.series_column is None:
        given = [name for name, value in (("--scheduler", args.scheduler), ("--workers", args.workers))
                 if value is not None]
        if given:
            raise ValueError(f"{' and '.join(given)} {'is' if len(given) == 1 else 'are'} for --series-column (its series "
                             "run on Dask); give --series-column or leave "
                             f"{'it' if len(given) == 1 else 'them'} out.")
    cores = os.cpu_count() or 1
    if args.workers is not None and not 1 <= args.workers <= cores:
        raise ValueError(f"--workers must be a positive integer, at most this machine's {cores} cores (a local "
                         f"cluster of one process a worker); got {args.workers}.")


def _check_paths(args: argparse.Namespace, outputs: dict[str, str | None]) -> None:
    """Refuse, before any work, outputs that would destroy an input or each other.

    Also refuses to write to a closed standard output, to a directory (but
    the output directory of --series-column), into a directory that does not
    exist (a link's target's; an output directory of --series-column is made)
    or cannot take a new file (read-only, say), or a figure in a format
    matplotlib does not write: each would lose the results of the work.
    """
    if not outputs["--out"] and sys.stdout is None:
        raise ValueError("standard output is closed; name an output file with `--out`.")
    earlier = [("the data file", args.data), ("the model file", args.model)]
    for option, path in outputs.items():
        if path is None:
            continue
        made = option == "--out" and args.command == "filter" and args.series_column is not None  # a directory
        if (os.path.isdir(path) or gfio.names_a_folder(str(path))) and not made:
            raise IsADirectoryError(errno.EISDIR, f"{os.strerror(errno.EISDIR)} (`{option}` names a file)", path)
        folder = os.path.dirname(os.path.realpath(path))  # a link's target's folder: where the file is written
        if not made and not os.path.isdir(folder):
            raise FileNotFoundError(errno.ENOENT, f"{os.strerror(errno.ENOENT)} (the folder of `{option}`)", path)
        special = os.path.exists(path) and not os.path.isfile(path)  # /dev/null, a FIFO: written in place
        if os.path.isdir(folder) and not special:  # a file is written beside its name, then renamed
            _takes_a_file(folder, f"the folder of `{option}`", path)
        for what, other in earlier:
            if _same_file(path, other):
                raise ValueError(f"`{option}` {path} is the same file as {what} {other}; choose another path.")
        earlier.append((f"`{option}`", path))
        if option == "--plot":
            plotting.image_format(path)  # a format matplotlib cannot write: said now, not after the work


def _takes_a_file(folder: str, what: str, path) -> None:
    """Raise, naming `what` and `path`, the OSError of making a new file in `folder` (read-only, say)."""
    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as exc:
        raise type(exc)(exc.errno, f"cannot write in {what} ({exc.strerror})", path) from None


def _same_file(a: str, b: str) -> bool:
    """Whether paths `a` and `b` name one file that writing one would clobber.

    A character device such as /dev/null may be named twice.
    """
    try:
        return os.path.samefile(a, b) and not stat.S_ISCHR(os.stat(a).st_mode)
    except OSError:  # one does not exist (yet): the same file only if the same path
        return os.path.realpath(a) == os.path.realpath(b)


# ---------------------------------------------------------------------------
# gaussfuse fit
# ---------------------------------------------------------------------------


def _names(text: str, what: str, valid) -> list[str]:
    items = [item.strip() for item in text.split(",") if item.strip()]
    bad = [item for item in items if item not in valid]
    if bad or not items or len(set(items)) < len(items):
        raise ValueError(f"{what} must be a comma-separated list of distinct names from {', '.join(valid)}; "
                         f"got {text!r}.")
    return items


def _structure(text: str | None) -> dict:
    """--structure as :func:`gaussfuse.fit`'s `structure` (which checks it)."""
    out: dict = {}
    for item in text.split(",") if text else ():
        name, sep, kind = (part.strip() for part in item.partition("="))
        if not sep or not name or not kind or name in out:
            why = "names " + name + " twice" if sep and name and kind else "takes NAME=KIND pairs"
            raise ValueError(f"--structure {why} (pairs such as Q=diagonal,R=scalar); got {text!r}.")
        out[name] = kind
    return out


class _Progress:
    """A one-line progress bar on stderr (only when stderr is a terminal)."""

    def __init__(self, method: str, total: int, stream=None) -> None:
        self.method, self.total = method, total
        self.stream = stream if stream is not None else sys.stderr
        self.live = self.stream.isatty()

    def __call__(self, iteration: int, loglik: float) -> None:
        if not self.live:
            return
        width = 30
        done = min(width, round(width * iteration / max(self.total, 1)))
        self.stream.write(f"\r{self.method} [{'#' * done}{'.' * (width - done)}] "
                          f"{iteration}/{self.total}  loglik {fixed_text(loglik, 6)}")
        self.stream.flush()

    def close(self) -> None:
        if self.live:
            self.stream.write("\n")


def _run_fit(args: argparse.Namespace) -> int:
    _check_paths(args, {"--out": args.out})
    _check_many(args)
    if args.iterations is not None and args.iterations < 1:
        raise ValueError(f"--iterations must be a positive integer; got {args.iterations}.")
    if args.tol is not None and not 0.0 <= args.tol < np.inf:  # NaN too
        raise ValueError(f"--tol must be a non-negative finite number; got {args.tol}.")
    spec = gfio.read_model(args.model)
    if spec.model.steps is not None:
        raise ValueError(f"{args.model}: [model]: matrices given per row cannot be written back as a model file; "
                         "`fit` takes one set of matrices.")
    columns = _columns(args)
    learn = _names(args.learn, "--learn", [name for name in learning.LEARNABLE if name != "B"])  # no B in a file
    structure = _structure(args.structure)
    learning.check_learn(spec.model, spec.prior, learn, structure)  # before any data are read (audit Y5)
    if args.series_column is None:
        data = gfio.read_measurements(args.data, m=spec.model.m, time_column=args.time_column, columns=columns,
                                      names=spec.sensed())
        T = data.times.shape[0]
        grid = timing.steps("times", data.times, T - 1) if T > 1 else None  # the T - 1 steps between the rows
        return _fit_and_write(args, _stepped(spec, grid), learn, structure, data.zs)
    parts = panels.partitions(args.data)  # a missing or empty path is named before a cluster starts
    with _cluster(args) as client:
        zs, grid = _pooled(args, spec, columns, parts, client)
        return _fit_and_write(args, _stepped(spec, grid), learn, structure, zs)


def _stepped(spec: gfio.ModelFile, grid: timing.Steps | None) -> gfio.ModelFile:
    """The model to fit on data whose steps are `grid`: a named model discretised for a regular grid's step.

    Irregular steps (or explicit matrices) keep one set of matrices, each
    row one step, with a warning; so does a named model on one row.
    """
    if grid is not None and not grid.regular:
        of = f"the file's dt = {spec.model.dt:g} s" if spec.timed is not None else "it"
        print(f"gaussfuse: warning: the times are irregular (steps from {grid.dts.min():g} s to {grid.dts.max():g} s), "
              f"but a fitted model has one set of matrices: every row is fitted as one step of {of}.", file=sys.stderr)
    elif grid is not None and spec.timed is not None:  # a named model on a regular grid: discretised for its dt
        stepped = spec.timed.at(np.full(1, grid.step))[0]
        if not grid.near(spec.model.dt):
            print(f"gaussfuse: warning: the model file's dt = {spec.model.dt:g} s, but the times step by "
                  f"{grid.step:g} s; the model is fitted for the times' step.", file=sys.stderr)
        spec = spec._replace(model=stepped)
    return spec


def _no_rows(data: str, parts: list[str]) -> str:
    """The error for a dataset whose every partition has a header only (one such partition among others is none)."""
    which = "its partition" if len(parts) == 1 else f"each of its {len(parts)} partitions"
    return f"{data}: no data rows: {which} has a header only."


def _pooled(args: argparse.Namespace, spec: gfio.ModelFile, columns, parts: list[str], client):
    """Every series of the partitions `parts` as one dask array (N, T, m), each read on a worker; and the
    range of the series' steps (:func:`gaussfuse.panels.step_range`).

    Series shorter than the longest are padded at the end with missing steps
    (which leave the likelihood as it is). A series in two partitions is an
    error, found before the fit.
    """
    import dask
    import dask.array as da

    read = dict(series_column=args.series_column, m=spec.model.m, time_column=args.time_column, columns=columns,
                names=spec.sensed())
    shapes = client.gather([client.submit(panels.partition_shape, part, **read, pure=False) for part in parts])
    seen: dict = {}
    for part, (ids, _, _) in zip(parts, shapes):
        for i in ids:
            if i in seen:
                raise ValueError(f"series {i!r} is in two partitions ({seen[i]} and {part}); each series must lie "
                                 "in one partition.")
            seen[i] = part
    if not seen:
        raise ValueError(_no_rows(args.data, parts))
    T = max(steps for _, steps, _ in shapes)
    blocks = [da.from_delayed(dask.delayed(panels.partition_arrays)(part, **read, steps=T),
                              shape=(len(ids), T, spec.model.m), dtype=np.float64)
              for part, (ids, _, _) in zip(parts, shapes)]
    print(f"fit: {len(seen):,} series in {len(parts)} partition(s), at most {T} steps each", file=sys.stderr)
    return client.persist(da.concatenate(blocks)), panels.joined_range([grid for _, _, grid in shapes])


def _fit_and_write(args: argparse.Namespace, spec: gfio.ModelFile, learn: list[str], structure: dict, zs) -> int:
    """`gaussfuse fit`'s fit of `zs` (an array, or a dask array of many series) and its output."""
    iterations = args.iterations if args.iterations is not None else (500 if args.method == "em" else 1000)
    progress = _Progress(args.method, iterations)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ConvergenceWarning)
            try:
                res = learning.fit(spec.model, spec.prior, zs, learn=learn, method=args.method,
                                   structure=structure, iterations=iterations, tol=args.tol,
                                   callback=progress, engine=args.engine)
            except (ValueError, FloatingPointError) as exc:  # of the data, or of the model on them: name the file
                text = str(exc)
                if isinstance(exc, gfio.InputFileError) or not ("`zs`" in text or isinstance(exc, STEP_ERRORS)
                                                                 or text.startswith(("at step", "EM iteration"))):
                    raise  # a reading error names the file already; an option's error is the option's
                raise type(exc)(f"{args.data}: {text.replace('`zs`', 'the data')}") from exc
    finally:
        progress.close()
    unconverged = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
    for w in caught:
        if w not in unconverged:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    comments = [f"fitted by gaussfuse {__version__}: gaussfuse fit {os.path.basename(args.data)} "
                f"--learn {','.join(learn)} --method {args.method}",
                f"log-likelihood {res.loglik!r} after {len(res.history) - 1} iterations; {_options(res.message)}",
                *map(_options, res.summary().splitlines())]
    if args.out:
        with gfio.open_atomic(args.out, "w", encoding="utf-8") as out:
            gfio.write_model(out, res.model, res.prior, spec.state_names, comments)
    else:  # whole, and in UTF-8 whatever the locale's encoding (read_model reads UTF-8)
        text = StringIO()
        gfio.write_model(text, res.model, res.prior, spec.state_names, comments)
        _StandardOutput().write(text.getvalue().encode("utf-8"))
    print(f"{args.method}: {_options(res.message).rstrip('.')}; log-likelihood {fixed_text(res.loglik, 6)} after "
          f"{len(res.history) - 1} iterations" + (f"; wrote {args.out}" if args.out else ""), file=sys.stderr)
    if res.message.startswith("interrupted"):
        return 130
    if unconverged:
        print(f"gaussfuse: warning: {_options(str(unconverged[0].message))}", file=sys.stderr)
        return NOT_CONVERGED
    return 0


# ---------------------------------------------------------------------------
# The parser and main
# ---------------------------------------------------------------------------


def _given(text: str) -> str:
    """An option's text, refused when empty: ``--out "$OUT"`` with OUT unset wrote to standard output."""
    if not text:
        raise argparse.ArgumentTypeError("it is empty (an unset shell variable?)")
    return text


def _output(text: str) -> str | None:
    """An output file's option: None (standard output) for ``-``, which wrote a file named "-" (audit EE2)."""
    return None if _given(text) == "-" else text


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose usage errors are one line like the command's other errors (exit status 2)."""

    def error(self, message: str):
        self.exit(2, f"gaussfuse: error: {message} (`{self.prog} --help` lists the options)\n")

    def _print_message(self, message: str, file=None) -> None:
        """As argparse prints, but a failed write of the help or version to standard output raises (argparse
        ignores it: `--help > /dev/full` exited 0); one to standard error (a usage error) is still ignored."""
        file = file if file is not None else sys.stderr
        if not message or file is None:
            return
        if file is sys.stdout:
            file.write(message)
            return
        try:
            file.write(message)
        except OSError:  # (and at exit, Python's flush of it would fail again: exit status 120)
            _silence(file)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``gaussfuse`` command."""
    raw = argparse.RawDescriptionHelpFormatter
    parser = _Parser(
        prog="gaussfuse",
        description="Kalman filtering and smoothing of measurement files.",
        epilog="examples:\n  gaussfuse demo --out figures\n"
               "  gaussfuse filter track.csv --model cv2d.toml --smooth --out track-smoothed.csv\n\n"
               f"{_EXIT_STATUSES}\n\n"
               "Run `gaussfuse COMMAND --help` for the details of a command.",
        formatter_class=raw,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(title="commands", dest="command", metavar="COMMAND", required=True)

    demo = commands.add_parser(
        "demo", help="run the built-in examples and draw a figure",
        description="Filter the textbook 1-D example and print its estimates; simulate a 2-D\n"
                    "constant-velocity target, filter and smooth it and print the position RMSE\n"
                    f"of each; write the figure {DEMO_FIGURE} and print its path.",
        epilog="example:\n  gaussfuse demo --out figures --seed 1", formatter_class=raw,
    )
    demo.add_argument("--out", metavar="DIR", type=_given, default=".",
                      help="directory for the figure, created if missing (default: current directory)")
    demo.add_argument("--seed", metavar="N", type=int, default=0,
                      help="seed of the simulation (default: 0)")
    demo.set_defaults(run=_run_demo, parser=demo)

    filt = commands.add_parser(
        "filter", help="filter (or smooth) a CSV file of measurements with a TOML model",
        description="Filter (or, with --smooth, smooth) the measurements in DATA.csv with the\n"
                    "model in MODEL.toml and write the state estimates as CSV.\n\n" + _FORMATS
                    + "\n\n" + _FILTER_STEPS + "\n\n" + _LIMITS + "\n\n" + _OUTPUTS,
        epilog="example:\n  gaussfuse filter track.csv --model cv2d.toml --smooth "
               "--out track-smoothed.csv --plot track.png",
        formatter_class=raw,
    )
    filt.add_argument("data", metavar="DATA.csv", type=_given, help="the measurements")
    filt.add_argument("-m", "--model", metavar="MODEL.toml", type=_given, required=True, help="the model and prior")
    filt.add_argument("--smooth", action="store_true",
                      help="write smoothed estimates (RTS smoother) instead of filtered ones")
    filt.add_argument("-o", "--out", metavar="OUT.csv", type=_output,
                      help="write the estimates to this file (default, or -: standard output); "
                           "not DATA.csv, MODEL.toml or FIG.png")
    filt.add_argument("--plot", metavar="FIG.png", type=_given,
                      help="also draw measurements against the estimates with ±2σ bands, and for two "
                           "measurement columns the x-y track (needs matplotlib; what it draws is held in "
                           "memory, so a very large file needs memory for it)")
    _column_options(filt)
    _many_options(filt, "filter each series of a long-format table (CSV or Parquet file, or a directory of "
                        "them: a partitioned dataset), one output file per partition under --out DIR")
    filt.add_argument("--check", choices=("warn", "raise", "off"), default="warn",
                      help="the divergence test (default warn: one line on stderr naming the steps whose "
                           "innovations are too large for the filter's covariances; raise: an error, exit "
                           "status 2; off)")
    _engine_option(filt)
    filt.set_defaults(run=_run_filter, parser=filt)

    fit = commands.add_parser(
        "fit", help="learn a model's matrices from a CSV file of measurements",
        description="Learn the matrices named by --learn (of F, H, Q, R and the prior's m0, P0)\n"
                    "from the measurements in DATA.csv, starting from MODEL.toml, by EM or by\n"
                    "maximum likelihood, and write the fitted model as a TOML model file.\n"
                    "A prior `diffuse = true` in MODEL.toml is handled exactly. Ctrl-C stops the\n"
                    "fit and writes the best model so far (exit status 130; 143 for SIGTERM).\n\n"
                    + _FORMATS + "\n\n" + _FIT_STEPS + "\n\n" + _LIMITS + "\n\n" + _OUTPUTS,
        epilog="example:\n  gaussfuse fit examples/data/nile.csv --model examples/models/local_level.toml "
               "--learn Q,R --method mle --out nile-fitted.toml",
        formatter_class=raw,
    )
    fit.add_argument("data", metavar="DATA.csv", type=_given, help="the measurements")
    fit.add_argument("-m", "--model", metavar="MODEL.toml", type=_given, required=True,
                     help="the starting model and prior")
    fit.add_argument("--learn", metavar="NAMES", default="Q,R",
                     help="comma-separated matrices to learn, of F,H,Q,R,m0,P0 (default: Q,R); a variance "
                          "that is 0 in MODEL.toml stays 0 (start it above 0 to learn it), under "
                          "--structure NAME=scalar only where all of NAME's start at 0")
    fit.add_argument("--method", choices=("em", "mle"), default="em",
                     help="expectation-maximisation or maximum likelihood (default: em)")
    fit.add_argument("--structure", metavar="NAME=KIND,...",
                     help="constrain learned covariances: Q, R or P0 = full, diagonal or scalar "
                          "(default: full)")
    fit.add_argument("--iterations", type=int, metavar="N",
                     help="maximum iterations (default: 500 for em, 1000 for mle)")
    fit.add_argument("--tol", type=float, metavar="TOL",
                     help="when to stop: em when the log-likelihood changes by at most TOL per observed value "
                          "(default 1e-10; 0 runs every --iterations), mle when the gradient per observation is "
                          "below TOL (default 1e-8)")
    _column_options(fit)
    _many_options(fit, "fit one model to every series of a long-format table (CSV or Parquet file, or a "
                       "directory of them), pooled")
    fit.add_argument("-o", "--out", metavar="FITTED.toml", type=_output,
                     help="write the fitted model to this file (default, or -: standard output); "
                          "not DATA.csv or MODEL.toml")
    _engine_option(fit)
    fit.set_defaults(run=_run_fit, parser=fit)
    return parser


def _column_options(command: argparse.ArgumentParser) -> None:
    command.add_argument("--time-column", metavar="NAME", type=_given, help="the time column (default: the one named t or time)")
    command.add_argument("--columns", metavar="A,B,...", type=_given,
                         help="the measurement columns, in order (default: every other column)")


def _columns(args: argparse.Namespace) -> list[str] | None:
    """The measurement columns named by --columns, or None for every other one."""
    return None if args.columns is None else [c.strip() for c in args.columns.split(",")]


def _many_options(command: argparse.ArgumentParser, what: str) -> None:
    many = command.add_argument_group("many series (on Dask; pip install -e \".[dask]\")")
    many.add_argument("--series-column", metavar="NAME", type=_given,
                      help=f"the series-id column: {what}. Its rows may come in any order: each series is "
                           "ordered by its times, which must differ (one file alone must be in time order)")
    many.add_argument("--scheduler", metavar="ADDRESS", type=_given,
                      help="with --series-column: the Dask scheduler of an existing cluster (tcp://host:8786)")
    many.add_argument("--workers", metavar="N", type=int,
                      help="with --series-column and no --scheduler: a local cluster of N worker processes "
                           "(default, and at most: one per core)")


def _engine_option(command: argparse.ArgumentParser) -> None:
    command.add_argument("--engine", choices=ENGINES, default="auto",
                         help="numba: the compiled kernels (compiled on first use, then cached on disk); "
                              "python: the readable path; auto (default): compiled when that is expected "
                              "to take less time, compilation or loading included")


class _Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that it stops as it does on Ctrl-C."""


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one line on stderr: ``gaussfuse: warning: <message>`` (a DivergenceWarning, say)."""
    print(f"gaussfuse: warning: {_options(str(message))}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run the ``gaussfuse`` command.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name; ``sys.argv[1:]`` by default.

    Returns
    -------
    int
        Exit status: 0 on success, 2 for bad arguments or bad input (after
        printing one line ``gaussfuse: error: <message>`` to stderr), 3 when
        ``fit`` did not converge (the best model is written), 130 on
        Ctrl-C, 141 when standard output was closed early (a broken pipe),
        143 on SIGTERM.

    Notes
    -----
    While it runs (in the main thread), SIGTERM raises a
    :class:`KeyboardInterrupt`, so that it stops the work as Ctrl-C does:
    temporary files are removed and ``fit`` writes the best model so far.
    """
    if sys.stderr is None:  # closed (2>&-): messages go nowhere, not into standard output, where print puts them
        with open(os.devnull, "w", encoding="utf-8") as sink:
            sys.stderr = sink
            try:
                return main(argv)
            finally:
                sys.stderr = None
    try:
        args, extra = build_parser().parse_known_args(argv)
        if extra:  # named by the command's parser, whose --help lists its options
            args.parser.error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as exc:  # --help, --version and usage errors
        code = exc.code if isinstance(exc.code, int) else 2
        return _flushed(code, "the help or version") if code == 0 else code
    except OSError as exc:  # the help or version could not be written
        return _write_failed(exc, "the help or version")
    terminated = []

    def on_sigterm(signum, frame):
        terminated.append(signum)
        raise _Terminated

    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, on_sigterm) if in_main_thread else None
    try:
        with warnings.catch_warnings(), _logged_as_warnings("matplotlib"):
            warnings.showwarning = _show_warning  # one line each, like the errors
            code = args.run(args)
        code = _flushed(code, "the results")  # a closed pipe or a full disk shows here, not at interpreter exit
        return 143 if code == 130 and terminated else code
    except KeyboardInterrupt:
        return _stopped(terminated)
    except Exception as exc:
        if _interrupted(exc):  # (an interrupted C extension's import raises ImportError from it)
            return _stopped(terminated)
        if isinstance(exc, _OutputFailed):
            return _write_failed(exc.__cause__, "the results")
        if isinstance(exc, BrokenPipeError) and exc.filename is None:  # standard output, not a FIFO given as one
            _silence()
            return 141
        if not isinstance(exc, (ValueError, TypeError, OSError, FloatingPointError, DivergenceWarning)):
            raise
        # ValueError includes InputFileError and LinAlgError; FloatingPointError is an overflow at a step;
        # a DivergenceWarning is raised with --check raise
        print(f"gaussfuse: error: {_message(exc)}", file=sys.stderr)
        return 2
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous)


def _interrupted(exc: BaseException) -> bool:
    """Whether `exc` was caused by Ctrl-C or SIGTERM: a C extension whose import is interrupted reports the
    interrupt as the cause of an ``ImportError: initialization failed``."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _stopped(terminated: list) -> int:
    """Exit status 143 after SIGTERM, 130 after Ctrl-C, said in one line."""
    print(f"gaussfuse: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
    return 143 if terminated else 130


def _flushed(code: int, what: str) -> int:
    """`code`, once standard output (holding `what`) is flushed; else as :func:`_write_failed`."""
    try:
        if sys.stdout is not None:
            sys.stdout.flush()
    except OSError as exc:
        return _write_failed(exc, what)
    return code


def _write_failed(exc: OSError, what: str) -> int:
    """The exit status of a failed write of `what` to standard output: 141 for a closed pipe, else 2, named
    (``--help > /dev/full`` exited 0 with the help lost)."""
    _silence()
    if isinstance(exc, BrokenPipeError):
        return 141
    with suppress(OSError):  # standard error may be the stream that failed
        print(f"gaussfuse: error: writing {what} to standard output: {exc.strerror or exc}", file=sys.stderr)
    return 2


def _silence(stream=None) -> None:
    """Point standard output (or `stream`) at the null device, so that Python's final flush cannot fail again."""
    with suppress(AttributeError, ValueError, OSError):  # e.g. a test's capture, which has no descriptor
        fd = (sys.stdout if stream is None else stream).fileno()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)


def _message(exc: Exception) -> str:
    """The error as one line; an OSError as ``<file>: <reason>``; the library's argument names as the options."""
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return _options(" ".join(text.splitlines()))


# The library's words for what the command spells as options (its errors and warnings reach the command's user).
_OPTION_WORDS = [(re.compile(pattern), replacement) for pattern, replacement in (
    (r"`(learn|structure|iterations|tol|check|engine)`", r"--\1"),
    (r"\b(method|check|engine)='(\w+)'", r"--\1 \2"),
    (r"\btol=0\b", r"--tol 0"),
    (r"`?structure=\{'(\w+)': '(\w+)'\}`?", r"--structure \1=\2"),
)]


@contextmanager
def _logged_as_warnings(name: str):
    """The warnings logger `name` logs (matplotlib's: "The PostScript backend does not support transparency"), as
    one-line warnings while the command runs."""
    import logging

    class OneLine(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            print(f"gaussfuse: warning: {' '.join(record.getMessage().split())}", file=sys.stderr)

    logger, handler = logging.getLogger(name), OneLine(logging.WARNING)
    propagate, logger.propagate = logger.propagate, False
    logger.addHandler(handler)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.propagate = propagate


def _options(text: str) -> str:
    """`text` with the library's argument names as the command's options (`learn` as --learn, method='em' as --method em)."""
    for pattern, replacement in _OPTION_WORDS:
        text = pattern.sub(replacement, text)
    return text


if __name__ == "__main__":  # `python -m gaussfuse.cli` ran nothing and exited 0 (audit Y3)
    sys.exit(main())
