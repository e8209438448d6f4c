"""Reading measurements (CSV) and models (TOML), writing estimates (CSV).

Measurement file (CSV)
----------------------
A header row, then one row per time step::

    t,x,y
    0.0,1.02,-0.31
    0.5,,0.12
    1.0,nan,NaN

* One column is the time, named ``t`` or ``time`` (any case); its values are
  numbers of seconds or ISO-8601 times, strictly increasing (how the command
  line steps by them: ``gaussfuse filter --help``).
* Every other column, in order, is one component of the measurement (or, with
  a named model's measurement names, columns named as those are taken by name).
* An empty cell, ``nan`` or ``NaN`` is a missing component.

Model file (TOML)
-----------------
Either explicit matrices (nested arrays; a scalar is a 1 x 1 matrix, a flat
array is one row of ``H``)::

    [model]
    F = [[1.0, 1.0], [0.0, 1.0]]
    H = [[1.0, 0.0]]
    Q = [[0.25, 0.5], [0.5, 1.0]]
    R = [[4.0]]
    states = ["x", "v"]          # optional; default x0, x1, ...

or a named motion model (:class:`gaussfuse.ConstantPosition`,
:class:`~gaussfuse.ConstantVelocity` or :class:`~gaussfuse.ConstantAcceleration`
seen by :class:`~gaussfuse.Position`, as :func:`gaussfuse.constant_velocity`
builds)::

    [model]
    kind = "constant_velocity"   # or "constant_position", "constant_acceleration"
    dim = 2                      # 1, 2 or 3 axes; default 1
    dt = 0.5
    q = 1.0
    r = 0.25

and optionally the belief one step before the first measurement::

    [prior]
    mean = [0.0, 0.0, 1.0, 0.0]  # default: zeros
    var = 100.0                  # var * I; or cov = [[...]]; default 1e6 * I

or ``diffuse = true`` alone: a flat prior, handled exactly (see
:mod:`gaussfuse.inference.diffuse`).

A control input ``B`` is not supported in model files yet.

Estimates file (CSV)
--------------------
The time column, the state means (one column per state name), then
``std_<name>`` for each state; floats are written with ``repr`` so they read
back exactly.

Limits
------
So that a file that is not what it should be (``/dev/zero``, a binary file,
a generated file gone wrong) fails at once in bounded memory:

* a measurement file must be text: a NUL character is an error, and so is a
  line longer than :data:`MAX_LINE_CHARS` (1 Mi characters, enough for some
  40 000 columns);
* a model file may be at most :data:`MAX_MODEL_BYTES` (8 MiB, enough for
  explicit matrices of a few hundred states), and its tables and arrays may
  be nested at most :data:`MAX_NESTING` (16) levels deep; a model needs 4.

Every error about a file's content is an :class:`InputFileError` whose message
starts with the file, then the line or field, e.g.
``model.toml: [model] Q: `Q` must be positive semi-definite; ...``.
"""

from __future__ import annotations

import csv
import datetime
import errno
import io as stdio
import math
import os
import re
import secrets
import stat
import sys
import tomllib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import IO, NamedTuple

import numpy as np

from ._linalg import marginal_std
from ._validation import as_array, as_vector, integer, real, shape_error
from .gaussian import Gaussian
from .inference.frames import ColumnNames, column_names, in_model_order
from .inference.validation import check_prior
from .models._base import check_names
from .models.linear import LinearModel
from .models.compose import TimedModel
from .models.compose import model as compose_model
from .models.motion import ConstantAcceleration, ConstantPosition, ConstantVelocity, state_names
from .models.sensors import Position

__all__ = [
    "InputFileError",
    "Measurements",
    "ModelFile",
    "read_measurements",
    "iter_measurements",
    "read_model",
    "write_estimates",
    "estimate_columns",
    "write_model",
    "open_atomic",
    "names_a_folder",
    "DEFAULT_PRIOR_VAR",
    "MAX_LINE_CHARS",
    "MAX_MODEL_BYTES",
    "MAX_NESTING",
]

DEFAULT_PRIOR_VAR = 1e6
"""Variance of each state in the default prior ``N(0, 1e6 I)``."""

CHUNK_ROWS = 2**16
"""Rows per piece of :func:`iter_measurements` (and of the command line's streaming filter)."""

MAX_LINE_CHARS = 2**20
"""Longest line of a measurement file, in characters (the line ending not counted)."""

MAX_MODEL_BYTES = 8 * 2**20
"""Largest model file, in bytes."""

MAX_NESTING = 16
"""Deepest nesting of tables and arrays in a model file (``[model]`` and ``F = [[1.0]]`` make 3)."""

TIME_COLUMNS = ("t", "time")
_QUOTED = re.compile(r'[,"\r\n]')  # what the csv module quotes

StrPath = str | os.PathLike[str]

# kind -> (motion, order of the integrated white-noise model), seen by a Position sensor
_KINDS = {"constant_position": (ConstantPosition, 0), "constant_velocity": (ConstantVelocity, 1),
          "constant_acceleration": (ConstantAcceleration, 2)}
_EXPLICIT_KEYS = ("F", "H", "Q", "R", "states")
_NAMED_KEYS = ("kind", "dim", "dt", "q", "r", "states")
_PRIOR_KEYS = ("mean", "cov", "var", "diffuse")
_TABLES = ("model", "prior")


class InputFileError(ValueError):
    """Bad content in an input file.

    The message is ``"<path>: line <line>: <field>: <message>"``, leaving out
    the parts that are not known.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    message : str
        What is wrong.
    line : int, optional
        1-based line number (the header of a CSV file is line 1).
    field : str, optional
        Where in the file, e.g. ``"column `x`"`` or ``"[model] Q"``.
    """

    def __init__(
        self, path: StrPath, message: str, *, line: int | None = None, field: str | None = None
    ) -> None:
        self.path = os.fspath(path)
        self.line = line
        self.field = field
        where = [self.path] + ([f"line {line}"] if line is not None else []) + ([field] if field else [])
        super().__init__(": ".join(where + [message]))


# ---------------------------------------------------------------------------
# Measurements (CSV)
# ---------------------------------------------------------------------------


class Measurements(NamedTuple):
    """What :func:`read_measurements` returns.

    Parameters
    ----------
    times : ndarray of shape (T,)
        Strictly increasing times.
    zs : ndarray of shape (T, m)
        Measurements; NaN where a component is missing.
    columns : list of str
        The time column's name, then the m measurement columns' names.
    time_text : list of str, optional
        The time cells as written, for output that keeps them verbatim.
    """

    times: np.ndarray
    zs: np.ndarray
    columns: list[str]
    time_text: list[str] | None = None


def read_measurements(path: StrPath, m: int | None = None, time_column: str | None = None,
                      columns: Sequence[str] | None = None, names: Sequence[str] | None = None) -> Measurements:
    """Read a measurement CSV file (see the module docstring for the format).

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.
    m : int, optional
        The number of measurement components the model expects; when given,
        the file must have exactly that many measurement columns.
    time_column : str, optional
        The time column's name, matched exactly or else in any case
        (default: the one named ``t`` or ``time``, in any case). Its cells
        are seconds, or ISO-8601 times (``2026-05-01T12:00:00.5+02:00``; one
        without a zone is UTC; a fraction only after the seconds), all of one
        kind; ISO times (to the nanosecond) become seconds since the file's
        first time, each rounded once from the exact difference.
    columns : sequence of str, optional
        The measurement columns, in this order (default: every other one,
        each of which must have a name); the others are not read.
    names : sequence of str, a sequence of such sequences, or ColumnNames, optional
        The model's measurement names (a named model's: the names of the
        states its sensor reads), for the
        default `columns`: a file whose measurement columns are these names
        in another order, in any case, is read in the model's order (as
        :func:`gaussfuse.filter` takes a DataFrame whose columns are the
        names as written); one that names some of them and not others is
        refused (it would be read by position). Several lists are
        alternatives, the first that all the columns name taken. A
        :class:`~gaussfuse.inference.frames.ColumnNames`
        (:meth:`ModelFile.sensed`) also names the states the model does not
        measure: columns taken in order that have one of those names are
        refused.

    Returns
    -------
    Measurements
        ``(times, zs, columns, time_text)``: times of shape (T,) in seconds,
        zs of shape (T, m), the column names (time column first) and the
        time cells as written.

    Raises
    ------
    InputFileError
        For a missing or repeated time column, a measurement column without a
        name, a wrong number of columns or cells, a cell that is not a
        number, an infinite value, a missing or non-increasing time, or no
        data rows; for a file that is not text (a NUL character, bytes that
        are not UTF-8, a line longer than :data:`MAX_LINE_CHARS`); the
        message names the file and the line and column.
    TypeError
        When `m` is not an integer, `time_column` not a str, or `columns` a
        str or a sequence holding something else.
    ValueError
        When `m` is below 1.
    OSError
        When the file cannot be read.

    See Also
    --------
    iter_measurements : the same file in pieces, in memory independent of its length.
    """
    pieces = list(iter_measurements(path, m, time_column, columns, names=names))
    return Measurements(np.concatenate([p.times for p in pieces]), np.concatenate([p.zs for p in pieces]),
                        pieces[0].columns, [text for p in pieces for text in p.time_text])


def iter_measurements(path: StrPath, m: int | None = None, time_column: str | None = None,
                      columns: Sequence[str] | None = None, rows: int = CHUNK_ROWS,
                      names: Sequence[str] | None = None) -> Iterator[Measurements]:
    """Read a measurement CSV file in pieces of at most `rows` rows, each as it is needed.

    Takes the arguments of :func:`read_measurements` and checks the file as
    it does (times increase across pieces too); a file of any length is
    read in memory proportional to `rows`. An error in a later piece is
    raised when that piece is reached.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.
    m : int, optional
        The number of measurement components, as for :func:`read_measurements`.
    time_column : str, optional
        The time column's name, as for :func:`read_measurements`.
    columns : sequence of str, optional
        The measurement columns, as for :func:`read_measurements`.
    rows : int, default CHUNK_ROWS
        The most rows per piece (positive).
    names : sequence of str, optional
        The model's measurement names, as for :func:`read_measurements`.

    Yields
    ------
    Measurements
        The rows of one piece, in file order; the first piece is yielded
        only once the header has been checked, and there is at least one.
    """
    if not isinstance(rows, int) or isinstance(rows, bool) or rows < 1:
        raise ValueError(f"`rows` must be a positive int; got {rows!r}.")
    if m is not None:  # (m = "1" was blamed on the file: "found 1 measurement column(s) ... m = 1": audit BB2)
        m = integer("m", m)
    if time_column is not None and not isinstance(time_column, str):
        raise TypeError(f"`time_column` must be a column's name (a str); got {time_column!r}.")
    if columns is not None:
        if isinstance(columns, str):  # its letters were taken as the names
            raise TypeError(f"`columns` must be a sequence of column names; got the str {columns!r} (for one "
                            f"column: [{columns!r}]).")
        columns = list(columns)
        if not all(isinstance(name, str) for name in columns):
            raise TypeError(f"`columns` must be a sequence of column names (str); got {columns!r}.")
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(_text_lines(path, f), strict=True)
        done = 0  # the lines read before the row being read
        try:
            header = [name.strip() for name in next(reader, [])]
            _check_header(path, header)
            time_col = _time_column(path, header, time_column)
            wanted = _measurement_columns(path, header, time_col, columns, names)
            labels = [header[time_col]] + [header[i] for i in wanted]
            if m is not None and len(labels) - 1 != m:
                raise InputFileError(
                    path,
                    f"found {len(labels) - 1} measurement column(s) {labels[1:]} besides `{labels[0]}`, "
                    f"but the model measures m = {m} component(s).",
                )
            parser = _Rows(path, header, time_col, wanted, labels)
            cells: list[list[str]] = []
            lines: list[int] = []
            done = reader.line_num
            for row in reader:
                done = reader.line_num
                if len(row) != len(header):
                    if len(row) <= 1 and not "".join(row).strip():
                        continue  # a blank line
                    _parse_row(path, reader.line_num, header, time_col, wanted, row)  # raises
                cells.append(row)
                lines.append(reader.line_num)
                if len(cells) == rows:
                    yield parser.parse(cells, lines)
                    cells, lines = [], []
        except csv.Error as exc:
            text, line = str(exc), reader.line_num
            if text == "unexpected end of data":  # the file ends within quotes: name the line the row starts on
                text, line = "a quoted cell is not closed (a '\"' opens it and the file ends).", done + 1
            raise InputFileError(path, text, line=line) from None
        except UnicodeDecodeError as exc:  # decoded in blocks: the line is found again in the bytes
            raise _undecodable(path, exc) from None
        if cells:
            yield parser.parse(cells, lines)
        elif parser.last is None:
            raise InputFileError(path, "no data rows after the header.")


class _Rows:
    """Turns the rows of a measurement file into :class:`Measurements`, a piece at a time.

    The cells of a whole piece are converted at once (NumPy parses numbers
    as ``float`` does); a piece that does not convert is parsed row by row by
    :func:`_parse_row`, which raises the error naming the line and column.
    The times are checked to increase across pieces, and to be all numbers
    or all ISO-8601 times.
    """

    def __init__(self, path, header: list[str], time_col: int, wanted: list[int], names: list[str]) -> None:
        self.path, self.header, self.time_col, self.wanted, self.names = path, header, time_col, wanted, names
        self.last: tuple[float, int, str] | None = None  # the last time read, its line and its cell
        self.stamps: bool | None = None  # whether the times are ISO-8601 times (set by the first row)
        self.origin: int | None = None  # the first ISO time, in nanoseconds since 1970: the times' zero

    def parse(self, rows: list[list[str]], lines: list[int]) -> Measurements:
        texts = [row[self.time_col].strip() for row in rows]
        cells = [row[i] for row in rows for i in self.wanted]
        try:
            times = np.array(texts, dtype=np.float64)
            stamps = np.zeros(len(rows), dtype=bool)
            values = np.array([c if c.strip() else "nan" for c in cells], dtype=np.float64)
            # float() reads "1_000" as 1000, as Python source would, and "٣" as 3: neither is a CSV number
            joined = "".join(texts) + "".join(cells)
            good = np.isfinite(times).all() and not np.isinf(values).any() and "_" not in joined and joined.isascii()
        except ValueError:  # ISO-8601 times, or a cell that is not a number
            good = False
        if not good:
            parsed = [_parse_row(self.path, line, self.header, self.time_col, self.wanted, row)
                      for row, line in zip(rows, lines)]
            stamps = np.array([isinstance(p[0], _Stamp) for p in parsed])
            if self.origin is None and stamps.any():
                self.origin = parsed[int(np.argmax(stamps))][0]
            times = np.array([(p[0] - self.origin) / 10**9 if s else p[0] for p, s in zip(parsed, stamps)],
                             dtype=np.float64)  # an int difference, then one rounding
            values = np.array([p[1:] for p in parsed], dtype=np.float64)
            if stamps.all():
                self._check_resolution([p[0] for p in parsed], times, lines, texts)
        self._check_times(times, stamps, lines, texts)
        return Measurements(times, values.reshape(len(rows), len(self.wanted)), self.names, texts)

    def _check_resolution(self, exact: list[int], times: np.ndarray, lines: list[int], texts: list[str]) -> None:
        """ISO times that increase (`exact`, nanoseconds) but not as seconds since the first (`times`): named as
        such, not as times out of order."""
        for k in range(1, len(exact)):
            if exact[k] > exact[k - 1] and not times[k] > times[k - 1]:
                raise InputFileError(
                    self.path, f"{texts[k]} is {exact[k] - exact[k - 1]} ns after {texts[k - 1]}, finer than seconds "
                    f"since the file's first time resolve {times[k]:g} s in (float64); start the file later or give "
                    "the times as seconds from a nearer origin.", line=lines[k], field=f"column `{self.names[0]}`")

    def _check_times(self, times: np.ndarray, stamps: np.ndarray, lines: list[int], texts: list[str]) -> None:
        where = {"field": f"column `{self.names[0]}`"}
        if self.stamps is None:
            self.stamps = bool(stamps[0])
        mixed = np.flatnonzero(stamps != self.stamps)
        if mixed.size:
            raise InputFileError(self.path, "the times mix numbers (seconds) and ISO-8601 times; use one kind.",
                                 line=lines[mixed[0]], **where)
        if self.last is not None:
            times = np.concatenate([[self.last[0]], times])
            lines, texts = [self.last[1], *lines], [self.last[2], *texts]
        with np.errstate(over="ignore"):  # an infinite step is increasing; the filter says it is too long
            back = np.flatnonzero(np.diff(times) <= 0)
        if back.size:
            k = back[0] + 1
            raise InputFileError(self.path, f"times must be strictly increasing; {texts[k]} follows {texts[k - 1]}.",
                                 line=lines[k], **where)
        self.last = (float(times[-1]), lines[-1], texts[-1])


def _not_utf8(lines: IO[bytes]) -> tuple[int, int, int] | None:
    """The line, the column (from 1, in characters) and the value of the first byte of `lines` that is not UTF-8,
    or None where there is none.

    Lines end as the reader ends them: at ``\\n``, ``\\r\\n`` or a ``\\r`` alone.
    """
    number = 0
    for raw in lines:  # split at b"\n", which no UTF-8 character holds
        try:
            raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            head = raw[:exc.start]
            number += 1 + head.count(b"\r") - head.count(b"\r\n")
            line = head[head.rfind(b"\r") + 1:].decode("utf-8")
            if number == 1:
                line = line.removeprefix("\ufeff")  # a byte-order mark is not a column
            return number, len(line) + 1, raw[exc.start]
        number += 1 + raw.count(b"\r") - raw.count(b"\r\n")
    return None


def _undecodable(path, exc: UnicodeDecodeError, data: bytes | None = None) -> InputFileError:
    """The error for the byte of `path` that the decoder refused (`exc`), naming its line and column.

    They are found in `data` (the file's bytes, where it was read whole), or
    by reading a regular file again; a pipe cannot be read again (a FIFO
    would wait for a writer), and its error names the byte alone (an
    AssertionError's traceback before: audit JJ1).
    """
    if data is not None:
        found = _not_utf8(stdio.BytesIO(data))
    elif stat.S_ISREG(os.stat(path).st_mode):
        with open(path, "rb") as again:
            found = _not_utf8(again)
    else:
        found = None
    if found is None:
        return InputFileError(path, f"not UTF-8 text: byte {exc.object[exc.start]:#04x} cannot be decoded.")
    line, column, byte = found
    return InputFileError(path, f"not UTF-8 text: byte {byte:#04x} at column {column} cannot be decoded.", line=line)


def _text_lines(path, f: IO[str], block: int = 2**20) -> Iterator[str]:
    """The lines of `f`, read in blocks of about `block` characters and checked to be text.

    A block is completed to the end of its last line by a read of at most
    ``MAX_LINE_CHARS + 2`` characters, so memory stays bounded by a line far
    too long (which is an error).
    """
    number = 0
    while text := f.read(block):
        while text.endswith("\r") and (more := f.read(1)):
            text += more  # a "\r\n" split between blocks stays one line ending (after any "\r" before it)
        if not text.endswith(("\n", "\r")):
            text += f.readline(MAX_LINE_CHARS + 2)
        lines = stdio.StringIO(text, newline="").readlines()
        if "\0" in text or max(map(len, lines)) > MAX_LINE_CHARS:
            for k, line in enumerate(lines, start=number + 1):
                if "\0" in line:
                    raise InputFileError(path, "a NUL character: not a text file.", line=k)
                if len(line.rstrip("\r\n")) > MAX_LINE_CHARS:
                    raise InputFileError(path, f"longer than {MAX_LINE_CHARS} characters.", line=k)
        number += len(lines)
        yield from lines


def _check_header(path, header: list[str] | None) -> None:
    """A file without a header (empty, or a blank first line) is refused as such ("found columns []" said nothing
    of why: audit Y3; the panel reader's "line 2: expected 0 cells": review R11)."""
    if not header or header == [""]:
        raise InputFileError(path, "no header: the file is empty or its first line is blank; expected a header row "
                                   "naming the columns (the time, the measurements), then one row per time.")


def _check_separator(path, header: list[str]) -> None:
    """A header of one column whose name holds a ';', a tab or a '|' is refused as a file of other separators."""
    if len(header) == 1 and (separator := next((c for c in ";\t|" if c in header[0]), None)):
        raise InputFileError(path, f"one column named {header[0]!r}: the file's columns seem to be separated by "
                                   f"{separator!r}; gaussfuse reads comma-separated values.")


def _time_column(path, header: list[str], name: str | None = None) -> int:
    """Index of the time column in `header`: the one named `name`, or the one named t or time."""
    _check_separator(path, header)
    if name is not None:
        found = [i for i, h in enumerate(header) if h == name] or [i for i, h in enumerate(header)
                                                                  if h.lower() == name.lower()]
        if len(found) != 1:
            raise InputFileError(path, f"{'no' if not found else 'more than one'} column named `{name}` "
                                       f"(the time column); found columns {header}.")
    else:
        found = [i for i, h in enumerate(header) if h.lower() in TIME_COLUMNS]
        if len(found) != 1:
            what = "no time column" if not found else "more than one time column"
            raise InputFileError(
                path, f"{what}: expected exactly one column named `t` or `time`; found columns {header} "
                      "(name another with --time-column)."
            )
    if len(header) < 2:
        raise InputFileError(path, f"no measurement columns besides `{header[found[0]]}`.")
    return found[0]


def _measurement_columns(path, header: list[str], time_col: int, columns, named=None) -> list[int]:
    """Indices of the measurement columns: those named in `columns`, in order, or every one but the time's (in the
    order of the model's measurement names `named`, where they are those names: see :func:`read_measurements`)."""
    if columns is None:
        if len(header) < 2:
            raise InputFileError(path, f"no measurement columns besides `{header[time_col]}`.")
        twice = sorted({h for h in header if header.count(h) > 1})
        if twice:  # which column is which would be a guess (the output names them)
            raise InputFileError(path, f"the header names column(s) {twice} more than once; found columns {header}.",
                                 line=1)
        unnamed = [i + 1 for i, h in enumerate(header) if not h and i != time_col]
        if unnamed:  # a trailing comma made a column that is always missing, taken as a measurement
            raise InputFileError(path, f"the header's column {unnamed[0]} has no name; found columns {header} (choose "
                                 "the measurement columns with --columns).", line=1)
        others = [i for i in range(len(header)) if i != time_col]
        try:  # as gaussfuse.filter takes a DataFrame's (audit EE2)
            if not isinstance(named, ColumnNames):  # a list of names, or of alternative lists
                named = ColumnNames([named] if named and isinstance(named[0], str) else list(named or []), ())
            choices, unmeasured = named
            order = in_model_order([header[i] for i in others], choices,
                                   f"the measurement columns {[header[i] for i in others]} name some of",
                                   "choose the columns with --columns", unmeasured)
        except ValueError as exc:
            raise InputFileError(path, str(exc), line=1) from None
        return others if order is None else [others[i] for i in order]
    out = []
    for name in columns:
        found = [i for i, h in enumerate(header) if h == name]
        if len(found) != 1 or found[0] == time_col or found[0] in out:
            why = ("is the time column" if found and found[0] == time_col else "is named twice" if found
                   and found[0] in out else "is not a column" if not found else "is not unique")
            raise InputFileError(path, f"measurement column `{name}` {why}; found columns {header}.")
        out.append(found[0])
    if not out:
        raise InputFileError(path, "no measurement columns chosen.")
    return out


def _float(text: str) -> float:
    """A number cell as ``float`` reads it, except "1_000" (Python source's digit separator) and digits of other
    scripts ("٣", which ``float`` reads as 3): neither is a CSV number."""
    if "_" in text or not text.isascii():
        raise ValueError(text)
    return float(text)


_FRACTION = re.compile(r"((?::|[Tt ]\d\d\d\d)\d\d)[.,](\d+)")  # the seconds' fraction (12:00:00.5 or 120000.5)
# a fraction of the hour or the minute (T12.5, T12:00.5, T1200.5), after a calendar, week or ordinal date and any
# one separator, as datetime reads them
_COARSE_FRACTION = re.compile(r"^(?:\d{4}-\d\d-\d\d|\d{8}|\d{4}-?W\d\d(?:-?\d)?|\d{4}-?\d{3}).\d\d(?::?\d\d)?[.,]\d")
_EPOCH = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)


def _parse_time(path, text: str, where: dict):
    """A time cell: seconds (a float), or an ISO-8601 time as a `_Stamp` of nanoseconds since 1970 UTC."""
    if not text:
        raise InputFileError(path, "the time is missing; every row needs a time.", **where)
    try:
        value = _float(text)
    except ValueError:
        if _COARSE_FRACTION.search(text):  # datetime reads "12:00.5" as 12:00:00.5, not 12:00:30
            raise InputFileError(path, f"{text!r} has a fraction of an hour or a minute; write the time to the "
                                 "second, with any fraction after the seconds (12:00:30 or 12:00:30.25).",
                                 **where) from None
        found = _FRACTION.search(text)  # datetime reads at most 6 digits (Python 3.11 drops the rest silently)
        digits = found.group(2) if found else ""
        if len(digits) > 9:
            raise InputFileError(path, f"{text!r} has {len(digits)} digits after the second; times are read to "
                                 "the nanosecond (9 digits).", **where) from None
        # (read with the fraction to 6 digits; the cell as written is what a message quotes)
        read = f"{text[:found.start()]}{found.group(1)}.{digits[:6]:0<6}{text[found.end():]}" if found else text
        try:
            when = datetime.datetime.fromisoformat(read)
        except ValueError:
            raise InputFileError(path, f"{text!r} is neither a number of seconds nor an ISO-8601 time.",
                                 **where) from None
        if when.tzinfo is None:
            when = when.replace(tzinfo=datetime.timezone.utc)
        micro = (when - _EPOCH) // datetime.timedelta(microseconds=1)  # exact, in integers
        return _Stamp(1000 * micro + int(f"{digits[6:]:0<3}"))
    if math.isnan(value):
        raise InputFileError(path, "the time is missing; every row needs a time.", **where)
    if not math.isfinite(value):
        raise InputFileError(path, f"{text!r} is not finite.", **where)
    return value


class _Stamp(int):
    """Nanoseconds since 1970 UTC read from an ISO-8601 time (an int that remembers it was one)."""


def _wrong_cells(path, header: list[str], row: list[str], line: int) -> InputFileError:
    """The error for a data row with another number of cells than the header (both CSV readers)."""
    return InputFileError(path, f"expected {len(header)} cells ({', '.join(header)}); found {len(row)}.", line=line)


def _parse_row(path, line: int, header: list[str], time_col: int, wanted: list[int], row: list[str]) -> list:
    """One data row as ``[time, z_1, ..., z_m]``; empty and NaN cells are NaN."""
    if len(row) != len(header):
        raise _wrong_cells(path, header, row, line)
    values = [_parse_time(path, row[time_col].strip(), {"line": line, "field": f"column `{header[time_col]}`"})]
    for i in wanted:
        where = {"line": line, "field": f"column `{header[i]}`"}
        text = row[i].strip()
        try:
            value = _float(text) if text else math.nan
        except ValueError:
            raise InputFileError(path, f"{row[i]!r} is not a number.", **where) from None
        if math.isinf(value):
            raise InputFileError(path, f"{row[i]!r} is not finite.", **where)
        values.append(value)
    return values


# ---------------------------------------------------------------------------
# Models (TOML)
# ---------------------------------------------------------------------------


class ModelFile(NamedTuple):
    """What :func:`read_model` returns.

    Parameters
    ----------
    model : LinearModel
        The model, with state dimension n.
    prior : Gaussian
        The belief one step before the first measurement; ``N(0, 1e6 I)``
        when the file has no ``[prior]``.
    state_names : list of str
        n names, one per state.
    timed : TimedModel or None, optional
        For a named model (``kind = ...``), its motion and sensor without
        the time step: discretised for each step of the data's times.
        None for explicit matrices.
    """

    model: LinearModel
    prior: Gaussian
    state_names: list[str]
    timed: TimedModel | None = None

    def sensed(self) -> ColumnNames | None:
        """The names by which a data file's measurement columns are matched (see :func:`read_measurements`).

        Returns
        -------
        ColumnNames or None
            For a named model, its ``choices``: the names of the states its
            sensor reads as its `states` give them, then as the sensor's own
            (x, y), where they differ and name none of the states:
            alternatives, the first that a file's columns all name taken
            (audit SS1: a model with `states` read a file's x, y by
            position); and its ``unmeasured`` states' names, which no
            measurement column taken in order may have (audit YY1: columns
            vy, vx were read as positions). As for a DataFrame
            (:func:`gaussfuse.inference.frames.column_names`). None for
            explicit matrices.
        """
        if self.timed is None:
            return None
        choices, unmeasured = column_names(self.timed)
        return ColumnNames([list(names) for names in choices], unmeasured)


def read_model(path: StrPath) -> ModelFile:
    """Read a model TOML file (see the module docstring for the format).

    Parameters
    ----------
    path : str or os.PathLike
        The TOML file.

    Returns
    -------
    ModelFile
        ``(model, prior, state_names, timed)``.

    Raises
    ------
    InputFileError
        For a TOML syntax error, an unknown table or key, a missing key, a
        control input ``B``, or a value that gaussfuse rejects; for a file
        that is not UTF-8, larger than :data:`MAX_MODEL_BYTES` or nested
        deeper than :data:`MAX_NESTING`; the message names the file and the
        field, followed by gaussfuse's own message.
    OSError
        When the file cannot be read.
    """
    with open(path, "rb") as f:
        data = f.read(MAX_MODEL_BYTES + 1)
    if len(data) > MAX_MODEL_BYTES:
        raise InputFileError(path, f"larger than {MAX_MODEL_BYTES} bytes; not a model file.")
    too_deep = f"not a model file: tables and arrays nested more than {MAX_NESTING} levels deep."  # (valid TOML)
    try:
        doc = tomllib.loads(data.decode("utf-8-sig"))  # a byte-order mark, as some editors write, is not content
    except UnicodeDecodeError as exc:  # (it said "position 5", a byte's: audit BB2)
        raise _undecodable(path, exc, data) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputFileError(path, f"invalid TOML: {exc}") from None
    except RecursionError:  # tomllib recurses once per level: no other way to stop it
        raise InputFileError(path, too_deep) from None
    if _depth(doc) > MAX_NESTING:
        raise InputFileError(path, too_deep)
    _check_keys(path, None, doc, _TABLES)
    table = _table(path, doc, "model")
    if table is None:
        raise InputFileError(path, "missing the [model] table.")
    if "kind" in table:
        model, names, timed = _named_model(path, table)
    else:
        model, names = _explicit_model(path, table)
        timed = None
    names = _state_names(path, table.get("states"), names)
    if "states" in table:  # the models' own names too, which results' to_pandas use
        model = model._replace(names=names)
        timed = None if timed is None else TimedModel(timed.motion, timed.sensor, names)
    prior = _prior(path, _table(path, doc, "prior") or {}, model.n)
    return ModelFile(model, prior, names, timed)


def _depth(doc: dict) -> int:
    """How deep tables and arrays are nested in `doc` (the document itself is level 0)."""
    deepest, todo = 0, [(doc, 0)]
    while todo:
        value, level = todo.pop()
        deepest = max(deepest, level)
        children = value.values() if isinstance(value, dict) else value
        todo.extend((child, level + 1) for child in children if isinstance(child, (dict, list)))
    return deepest


def _table(path, doc: dict, name: str) -> dict | None:
    table = doc.get(name)
    if table is not None and not isinstance(table, dict):
        raise InputFileError(path, f"`{name}` must be a table, [{name}]; got {table!r:.40}.")
    return table


def _meant(key, *choices: Sequence[str]) -> str | None:
    """The key that `key` may be a misspelling of: the closest in the first of `choices` that has one (audit PP2)."""
    import difflib

    if not isinstance(key, str):
        return None
    for keys in choices:  # the same letters in another case first (`r` for `R`), never the key itself (review R46)
        close = [k for k in keys if k.lower() == key.lower()] + difflib.get_close_matches(key, keys, n=2)
        close = [k for k in close if k != key]
        if close:
            return close[0]
    return None


def _check_keys(path, table_name: str | None, table: dict, valid: Sequence[str], hint: str = "",
                also: Sequence[str] = ()) -> None:
    """Reject keys of `table` not in `valid`, listing the valid ones and the one each may be a misspelling of
    (among `valid`, then `also`, the other kind of model's)."""
    unknown = [key for key in table if key not in valid]
    if unknown:
        if table_name is None:
            what = f"unknown table(s) {unknown}; valid tables are " + ", ".join(f"[{t}]" for t in valid)
        else:
            what = f"unknown key(s) {unknown}; valid keys are {', '.join(valid)}"
        typos = [f"`{key}` for `{meant}`?" for key in unknown if (meant := _meant(key, valid, also))]
        raise InputFileError(path, what + hint + "." + (f" ({'; '.join(typos)})" if typos else ""),
                             field=None if table_name is None else f"[{table_name}]")


def _require(path, table: dict, keys: Sequence[str], what: str) -> None:
    missing = [key for key in keys if key not in table]
    if missing:
        raise InputFileError(path, f"missing key(s) {missing}; {what}.", field="[model]")


@contextmanager
def _field(path, table_name: str, fields: dict[str, str]) -> Iterator[None]:
    """Turn a gaussfuse ValueError/TypeError into an InputFileError naming the field.

    gaussfuse names the offending argument first, in backticks; `fields`
    maps those argument names to the file's keys.
    """
    try:
        yield
    except (ValueError, TypeError) as exc:
        named = re.search(r"`(\w+)`", str(exc))
        key = fields.get(named.group(1)) if named else None
        field = f"[{table_name}] {key}" if key else f"[{table_name}]"
        # a hint in Python's words ("give 2 * np.eye(3)") in the file's (audit BB2)
        text = re.sub(r"give (\S+) \* np\.eye\((\d+)\)\.", r"write the \2 × \2 matrix with \1 on its diagonal.", str(exc))
        raise InputFileError(path, text, field=field) from exc


def _explicit_model(path, table: dict) -> tuple[LinearModel, list[str]]:
    if "B" in table:
        raise InputFileError(
            path, "a control input is not supported by the command line yet (no controls are read); remove `B`.",
            field="[model] B",
        )
    named = [key for key in table if key in _NAMED_KEYS and key != "states"]
    if named and len(named) >= sum(key in table for key in "FHQR"):
        # a named model's keys without `kind` (misspelt, say): blame the kind, not them (audit PP2); beside as many
        # explicit matrices or more they are unknown keys, below (review R46: `r` for `R` was blamed on a missing
        # `kind`; review R47: dim, dt, q beside R are a named model's)
        typos = [f" (`{key}` for `kind`?)" for key in table if key not in _NAMED_KEYS + _EXPLICIT_KEYS
                 and _meant(key, ["kind"])]
        are = "are keys" if len(named) > 1 else "is a key"
        raise InputFileError(path, f"{', '.join(f'`{key}`' for key in named)} {are} of a named model, which needs "
                             f"`kind` (one of {', '.join(sorted(_KINDS))}){''.join(typos[:1])}; explicit matrices "
                             "are F, H, Q and R.", field="[model]")
    _check_keys(path, "model", table, _EXPLICIT_KEYS,
                f" (explicit matrices), or {', '.join(_NAMED_KEYS)} (a named model)", also=_NAMED_KEYS)
    _require(path, table, ("F", "H", "Q", "R"), "explicit models need F, H, Q and R")
    with _field(path, "model", {k: k for k in "FHQR"}):
        model = LinearModel(table["F"], table["H"], table["Q"], table["R"])
    return model, [f"x{i}" for i in range(model.n)]


def _named_model(path, table: dict) -> tuple[LinearModel, list[str], TimedModel]:
    """A named model at its dt, its state names, and the model for any dt (checked at dt = 1)."""
    _check_keys(path, "model", table, _NAMED_KEYS,
                f" (a named model), or {', '.join(_EXPLICIT_KEYS)} (explicit matrices, without `kind`)",
                also=_EXPLICIT_KEYS)
    kind = table["kind"]
    if not isinstance(kind, str) or kind not in _KINDS:
        raise InputFileError(
            path, f"unknown model kind {kind!r}; valid kinds are {', '.join(sorted(_KINDS))}.",
            field="[model] kind",
        )
    _require(path, table, ("dt", "q", "r"), f"a {kind} model needs dt, q and r (and optionally dim)")
    order = _KINDS[kind][1]
    dim = table.get("dim", 1)
    with _field(path, "model", {"dim": "dim", "dt": "dt", "q": "q", "r": "r", "Q": "q", "R": "r"}):
        timed = _timed(table)
        model = compose_model(timed.motion, timed.sensor, real("dt", table["dt"], positive=True))
    return model, state_names(order, dim), timed


def _timed(table: dict) -> TimedModel:
    """A named model's motion and sensor, without its dt."""
    motion = _KINDS[table["kind"]][0](dim=table.get("dim", 1), q=table["q"])
    return compose_model(motion, Position(dim=table.get("dim", 1), r=table["r"]))


def _state_names(path, given, default: list[str]) -> list[str]:
    if given is None:
        return default
    n = len(default)
    if (not isinstance(given, list) or not all(isinstance(s, str) and s for s in given)
            or len(given) != n or len(set(given)) != n):
        raise InputFileError(
            path, f"`states` must be a list of {n} distinct names, one per state; got {given!r:.80}.",
            field="[model] states",
        )
    try:
        check_names(given, n, None)  # as a model's names (which it becomes)
    except ValueError as exc:
        raise InputFileError(path, str(exc).replace("`names`", "`states`"), field="[model] states") from None
    return given


def _prior(path, table: dict, n: int) -> Gaussian | str:
    _check_keys(path, "prior", table, _PRIOR_KEYS, " (give `cov` or `var`, not both)")
    if "diffuse" in table:
        if table["diffuse"] is not True:
            raise InputFileError(path, f"`diffuse` can only be true (a diffuse prior; for a Gaussian one give `mean` "
                                       f"and `cov` or `var` instead); got {table['diffuse']!r:.40}.", field="[prior]")
        if len(table) > 1:
            raise InputFileError(path, "`diffuse = true` stands alone: no `mean`, `cov` or `var` with it.",
                                 field="[prior]")
        return "diffuse"
    if "cov" in table and "var" in table:
        raise InputFileError(path, "give either `cov` or `var` (var * I), not both.", field="[prior]")
    with _field(path, "prior", {"mean": "mean", "cov": "var" if "var" in table else "cov", "var": "var"}):
        mean = as_vector("mean", table.get("mean", np.zeros(n)), n)
        if "cov" in table:
            cov = table["cov"]
        else:
            var = as_array("var", table.get("var", DEFAULT_PRIOR_VAR))
            if var.ndim != 0:
                raise shape_error("var", "() (one number)", var.shape)
            if var < 0:
                raise ValueError(f"`var` must be a non-negative number; got {float(var)!r}.")
            cov = var * np.eye(n)
        return Gaussian(mean, cov)


# ---------------------------------------------------------------------------
# Estimates (CSV)
# ---------------------------------------------------------------------------


def estimate_columns(time_name: str, state_names, series_name: str | None = None) -> list[str]:
    """The columns of written estimates: the series id (if any), the time, the means, ``std_<name>``.

    Parameters
    ----------
    time_name : str
        The time column's name.
    state_names : sequence of str
        The states' names (their means' columns).
    series_name : str, optional
        The series-id column's name, first when given.

    Returns
    -------
    list of str

    Raises
    ------
    ValueError
        When two of them have one name (a state named like the time column,
        or ``std_x`` beside a state x): a reader would take the wrong column,
        and a table by name would keep only one of them.
    """
    columns = [*([series_name] if series_name is not None else []), time_name, *state_names,
               *(f"std_{name}" for name in state_names)]
    twice = sorted({c for c in columns if columns.count(c) > 1})
    if twice:
        raise ValueError(f"the output would have two columns named {', '.join(map(repr, twice))} (columns "
                         f"{', '.join(columns)}): rename the model's states (`states = [...]` in its [model]).")
    return columns


def write_estimates(
    dest: StrPath | IO[str] | None,
    times,
    means,
    covs,
    state_names: Sequence[str],
    time_name: str = "t",
    header: bool = True,
) -> None:
    """Write state estimates as CSV: time, means, then standard deviations.

    Parameters
    ----------
    dest : str, os.PathLike, text file or None
        A path (written atomically: nothing is left behind on error), an
        open text file, or None for standard output.
    times : array_like of shape (T,), or sequence of str
        Times, one per row; strings (the input's time cells) are written as
        they are.
    means : array_like of shape (T, n)
        State means.
    covs : array_like of shape (T, n, n)
        State covariances; the square roots of their diagonals are written.
    state_names : sequence of str, of length n
        Column names of the means; the standard deviations are ``std_<name>``.
    time_name : str, default "t"
        Name of the time column.
    header : bool, default True
        Whether to write the header row first (False for the rows that
        continue a file).

    Raises
    ------
    TypeError, ValueError
        When an argument is not of the type or shape above, a time is
        neither a finite number nor text (NaN, or a datetime64: give such
        times as their text), or a mean or covariance is infinite or
        complex; nothing is written then.

    Notes
    -----
    Floats are written with ``repr``, the shortest text that reads back to
    the same float64. A variance below 0 is written as a standard deviation
    of 0, as a round-off of 0: a smoothed covariance is a difference of
    covariances, whose round-off is relative to those, not to the result.

    Examples
    --------
    >>> import io, numpy as np
    >>> from gaussfuse.io import write_estimates
    >>> out = io.StringIO()
    >>> write_estimates(out, [0.5], [[1.0, -2.0]], [np.diag([4.0, 0.01])], ["x", "v"])
    >>> print(out.getvalue(), end="")
    t,x,v,std_x,std_v
    0.5,1.0,-2.0,2.0,0.1
    """
    verbatim = len(times) > 0 and all(isinstance(t, str) for t in times)
    stamps = list(times) if verbatim else None
    times = np.zeros(len(times)) if verbatim else as_array("times", times, copy=False)
    means, covs = as_array("means", means, allow_nan=True, copy=False), as_array("covs", covs, allow_nan=True, copy=False)
    try:
        n = len(state_names) if hasattr(state_names, "__len__") else means.shape[-1] if means.ndim else 1
        state_names = check_names(state_names, n, ())
    except (TypeError, ValueError) as exc:  # (a str was taken for its letters: audit BB2)
        raise type(exc)(str(exc).replace("`names`", "`state_names`")) from None
    T, n = times.shape[0], len(state_names)
    for name, arr, shape in (("times", times, (T,)), ("means", means, (T, n)), ("covs", covs, (T, n, n))):
        if arr.shape != shape:
            raise shape_error(name, str(shape), arr.shape)
    stds = marginal_std(covs)
    columns = estimate_columns(time_name, state_names)
    values = np.column_stack([means, stds]).tolist()  # Python floats: str() is repr
    stamps = stamps if verbatim else [repr(t) for t in times.tolist()]

    def write(f: IO[str]) -> None:
        if header:
            csv.writer(f, lineterminator="\n").writerow(columns)
        if _QUOTED.search("".join(stamps)):  # a time cell that needs quotes: the csv module's rows
            csv.writer(f, lineterminator="\n").writerows([stamp, *row] for stamp, row in zip(stamps, values))
        else:  # numbers need no quotes: joined directly, a third faster
            f.write("".join([stamp + "," + ",".join(map(repr, row)) + "\n" for stamp, row in zip(stamps, values)]))

    if dest is None:
        write(sys.stdout)
    elif hasattr(dest, "write"):
        write(dest)
    else:
        with open_atomic(dest, "w", newline="", encoding="utf-8") as f:
            write(f)


def write_model(out: IO[str], model: LinearModel, prior: Gaussian | str, names: Sequence[str],
                comments: Sequence[str] = ()) -> None:
    """Write a model file (explicit matrices) that :func:`read_model` reads back exactly.

    F, H, Q, R, the prior and the state names read back bit for bit; a
    model's ``dt`` (a label of the step its matrices are for) is not
    written, and reads back as None.

    Parameters
    ----------
    out : text stream
        Where to write.
    model : LinearModel
        A time-invariant model without control input.
    prior : Gaussian or "diffuse"
    names : sequence of str
        State names: ``model.n`` distinct, non-empty strings. Any Unicode
        text is written escaped as TOML needs it (quotes, backslashes, line
        breaks and other control characters).
    comments : sequence of str
        Lines written first, as TOML comments; a control character in one
        (a line break, say) is written as its escape, ``\\n``, so that each
        stays one comment line.

    Raises
    ------
    TypeError
        If `model` is not a LinearModel, `prior` neither a Gaussian nor
        "diffuse", or `names` not a sequence of strings.
    ValueError
        If the model is time-varying or has a control input, the prior's
        dimension is not the model's, or `names` would not read back (wrong
        number, repeated or empty names, a name with ``_sd`` after another,
        or surrogate code points, which are not Unicode text). Nothing is
        written then.

    Notes
    -----
    Floats are written with ``repr``, which reads back to the same float64,
    including ``-0.0`` and subnormal numbers.
    """
    if not isinstance(model, LinearModel):
        raise TypeError(f"`model` must be a gaussfuse.LinearModel; got {type(model).__name__}.")
    if model.steps is not None or model.B is not None:
        raise ValueError("only a time-invariant model without control input can be written as a model file.")
    prior = check_prior(prior, model.n, diffuse_ok=True)  # ("gaussian" was written as diffuse: audit BB2)
    names = list(names)
    if (len(names) != model.n or not all(isinstance(name, str) and name for name in names)
            or len(set(names)) != model.n):
        raise ValueError(f"`names` must be {model.n} distinct non-empty strings, one per state; "
                         f"got {names!r:.80}.")
    check_names(names, model.n, ())  # as read_model reads them back ("x" beside "x_sd" did not)
    if any(_SURROGATE.search(name) for name in names):
        raise ValueError(f"`names` must be Unicode text, without surrogate code points; got {names!r:.80}.")
    for line in comments:
        out.write(f"# {_COMMENT_ESCAPES.sub(_escape, line)}\n")
    out.write("[model]\n")
    for name in ("F", "H", "Q", "R"):
        out.write(f"{name} = {_toml_array(getattr(model, name))}\n")
    out.write(f"states = [{', '.join(_toml_string(n) for n in names)}]\n\n[prior]\n")
    if isinstance(prior, str):
        out.write("diffuse = true\n")
    else:
        out.write(f"mean = {_toml_array(prior.mean)}\ncov = {_toml_array(prior.cov)}\n")


def _toml_array(a: np.ndarray) -> str:
    if a.ndim == 0:
        return repr(float(a))
    return "[" + ", ".join(_toml_array(x) for x in a) + "]"


# What a TOML basic string cannot hold as it is: control characters, the quote and the backslash.
_STRING_ESCAPES = re.compile(r'[\x00-\x1f\x7f"\\]')
# What a TOML comment cannot hold (every control character but tab), and what UTF-8 cannot encode.
_COMMENT_ESCAPES = re.compile(r"[\x00-\x08\x0a-\x1f\x7f\ud800-\udfff]")
_SURROGATE = re.compile(r"[\ud800-\udfff]")
_SHORT_ESCAPES = {"\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r", '"': '\\"',
                  "\\": "\\\\"}


def _escape(match: re.Match) -> str:
    char = match.group()
    return _SHORT_ESCAPES.get(char) or f"\\u{ord(char):04X}"


def _toml_string(text: str) -> str:
    return '"' + _STRING_ESCAPES.sub(_escape, text) + '"'


@contextmanager
def open_atomic(path: StrPath, mode: str = "w", **kwargs) -> Iterator[IO]:
    """Open a file for writing, never destroying what is at `path`.

    What is written appears only if the block ends without an exception; how
    depends on what `path` is:

    * A regular file or a new path: the data go to a hidden temporary file in
      the same directory, which then replaces the file (``os.replace``); on an
      exception the temporary file is removed and the file is left as it was.
      An existing file keeps its permission bits (and, where allowed, its
      owner and group); one the user may not write is refused, as the shell
      would refuse it. A new file gets ``0o666`` less the umask.
    * A symbolic link: the same for the file it points to (created if the
      link dangles); the link stays a link.
    * A FIFO or a character device (a named pipe, a terminal, ``/dev/null``):
      the data are kept in memory, then written to it, opened in place (the
      open waits for a FIFO's reader, as the shell's ``>`` does).
    * Anything else (a directory, a socket, a block device) is refused
      before the block runs.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write.
    mode : {"w", "wb"}
        Text or binary.
    **kwargs
        Passed to :func:`open` (e.g. ``newline=""``, ``encoding``).

    Raises
    ------
    OSError
        When `path` cannot be written (its directory is missing, it is a
        directory, the user may not write it, the disk is full); the error
        names `path`, never the temporary file. A full disk or a file too
        large (ENOSPC, EDQUOT, EFBIG) in the block, which names no file, is
        given `path`'s name; other errors of the block are left as they are.
    IsADirectoryError
        When `path` ends as a folder's name does (a separator, ``.`` or
        ``..``), as the shell's ``>`` refuses it.
    ValueError
        When `path` is a socket or a block device, or for an unknown `mode`.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"`mode` must be 'w' or 'wb'; got {mode!r}.")
    path = os.fspath(path)
    if not path:  # (as the shell's `> ""`: review R20)
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), path)
    if names_a_folder(path):  # "out.csv/" and "out.csv/." wrote out.csv (audit BB2, review R19); `>` refuses them
        raise IsADirectoryError(errno.EISDIR, f"{os.strerror(errno.EISDIR)} (a folder's name)", path)
    try:
        info = os.stat(path)  # of the file a symlink points to
    except FileNotFoundError:
        info = None
    except OSError as exc:
        raise _naming(exc, path) from None
    if info is None or stat.S_ISREG(info.st_mode):
        writer = _write_replacing(path, info, mode, kwargs)
    elif stat.S_ISFIFO(info.st_mode) or stat.S_ISCHR(info.st_mode):
        writer = _write_in_place(path, mode, kwargs)
    elif stat.S_ISDIR(info.st_mode):
        raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), path)
    else:
        kind = "a socket" if stat.S_ISSOCK(info.st_mode) else "a block device" if stat.S_ISBLK(
            info.st_mode) else "not a regular file"
        raise ValueError(f"{path}: {kind}; gaussfuse writes to a regular file, a new path, a FIFO or a "
                         "character device.")
    with writer as f:
        yield f


def _replaced_file(path: str, info: os.stat_result | None) -> str:
    """The file that writing `path` replaces: through symlinks (the link stays, its file is replaced); one that
    exists (`info`, its status) and that the user may not write is refused, as the shell would refuse it."""
    target = os.path.realpath(path)
    if info is not None and not os.access(target, os.W_OK):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), path)
    return target


def _keep_status(file: int | str, info: os.stat_result) -> None:
    """Give the new `file` (a descriptor or a path) the permission bits, and where allowed the owner and group,
    of the file it replaces (`info`): chown first, as it clears set-user-ID bits."""
    with suppress(OSError):  # only root may give a file away
        os.chown(file, info.st_uid, info.st_gid)
    os.chmod(file, stat.S_IMODE(info.st_mode))


@contextmanager
def _write_replacing(path: str, info: os.stat_result | None, mode: str, kwargs: dict) -> Iterator[IO]:
    """Write a temporary file beside the file `path` names, then put it in that file's place."""
    target = _replaced_file(path, info)
    directory, name = os.path.split(target)
    tmp = os.path.join(directory, f".{name}.{secrets.token_hex(6)}.tmp")
    # The descriptor stays ours (the file object does not close it), so that the clean-up knows whether it is
    # open whatever instant an interruption (Ctrl-C, SIGTERM) picks: a file object that open() had begun to
    # build closes its descriptor as it goes, and closing that again raised EBADF in place of the interruption.
    fd, f, made = -1, None, True
    try:
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        except OSError as exc:
            made = False  # nothing was created, or the name is another's: nothing to remove
            raise _naming(exc, path) from None
        if info is not None:
            _keep_status(fd, info)
        f = open(fd, mode, closefd=False, **kwargs)
        try:
            yield f
        except OSError as exc:  # a write of the block's (a full disk: audit BB2 found it named no file)
            if exc.filename is not None or exc.errno not in _WRITE_ERRORS:
                raise
            raise _naming(exc, path) from None
        try:
            f.close()
            closing, fd = fd, -1  # forgotten before it is closed: a descriptor is never closed twice
            os.close(closing)
            os.replace(tmp, target)
        except OSError as exc:
            raise _naming(exc, path) from None
    except BaseException:  # includes KeyboardInterrupt and SIGTERM turned into an exception
        if f is not None:
            with suppress(OSError):
                f.close()
        if fd >= 0:
            with suppress(OSError):  # the interruption is what the caller must see
                os.close(fd)
        if made:
            with suppress(FileNotFoundError):
                os.unlink(tmp)
        raise


@contextmanager
def _write_in_place(path: str, mode: str, kwargs: dict) -> Iterator[IO]:
    """Collect the data in memory, then write them to the FIFO or device `path`, opened in place."""
    buffer = stdio.BytesIO()
    f = buffer if mode == "wb" else stdio.TextIOWrapper(buffer, **kwargs)
    yield f
    f.flush()
    try:
        fd = os.open(path, os.O_WRONLY | getattr(os, "O_BINARY", 0))  # never O_CREAT: if it went, create nothing
        with open(fd, "wb") as out:
            out.write(buffer.getvalue())
    except OSError as exc:
        raise _naming(exc, path) from None


_WRITE_ERRORS = {errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", errno.ENOSPC)}
"""What a write to a file fails with for want of room: the file's, when the error names none."""


def names_a_folder(path: str) -> bool:
    """Whether `path` ends as a folder's name does: with a separator, ``.`` or ``..``.

    Parameters
    ----------
    path : str
        A path to write.

    Returns
    -------
    bool
        True for ``out.csv/`` and ``out.csv/.``, which the shell's ``>``
        refuses (writing them wrote ``out.csv``).
    """
    return os.path.basename(path) in ("", ".", "..")


def _naming(exc: OSError, path: str) -> OSError:
    """`exc` about `path`, as the user named it (not the temporary file, not the link's target)."""
    return type(exc)(exc.errno, exc.strerror, path) if exc.errno is not None else exc
