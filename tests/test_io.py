"""Tests of gaussfuse.io: measurement CSV, model TOML, estimates CSV, atomic writes."""

import doctest
import errno
import io as stdio
import os
import re
import socket
import stat
import subprocess
import sys
from contextlib import suppress

import numpy as np
import pytest

import gaussfuse as gf
import gaussfuse.io
from gaussfuse.io import (
    InputFileError,
    iter_measurements,
    open_atomic,
    read_measurements,
    read_model,
    write_estimates,
)


def write(path, text):
    path.write_text(text, encoding="utf-8")
    return path


# ---------------------------------------------------------------------------
# read_measurements
# ---------------------------------------------------------------------------


def test_read_measurements_values_names_and_missing_cells(tmp_path):
    path = write(tmp_path / "data.csv", "t,x,y\n0.5,1.25,-2\n1.0,,NaN\n1.5, nan ,3e-3\n\n")
    times, zs, columns, _ = read_measurements(path)
    assert columns == ["t", "x", "y"]
    np.testing.assert_array_equal(times, [0.5, 1.0, 1.5])
    np.testing.assert_array_equal(zs, [[1.25, -2.0], [np.nan, np.nan], [np.nan, 3e-3]])
    assert zs.shape == (3, 2) and zs.dtype == np.float64


def test_read_measurements_time_column_anywhere_any_case(tmp_path):
    path = write(tmp_path / "data.csv", "\ufeffa, TIME ,b\n1,10,2\n3,20,4\n")  # with a BOM
    times, zs, columns, _ = read_measurements(path, m=2)
    assert columns == ["TIME", "a", "b"]
    np.testing.assert_array_equal(times, [10, 20])
    np.testing.assert_array_equal(zs, [[1, 2], [3, 4]])


@pytest.mark.parametrize(
    "text, match, line",
    [
        ("x,y\n1,2\n", r"data\.csv: no time column: .*`t` or `time`; found columns \['x', 'y'\]", None),
        ("t,time,x\n1,2,3\n", r"data\.csv: more than one time column", None),
        # ("found columns []" and "found columns ['t;x']" said nothing of why: audit Y3)
        ("", r"data\.csv: no header: the file is empty or its first line is blank", None),
        ("\nt,x\n1,2\n", r"data\.csv: no header: the file is empty or its first line is blank", None),
        ("t;x\n1;2\n", r"data\.csv: one column named 't;x': the file's columns seem to be separated by ';'", None),
        ("t\tx\n1\t2\n", r"data\.csv: one column named 't\\tx': .* separated by '\\t'; gaussfuse reads comma", None),
        ("t\n1\n", r"data\.csv: no measurement columns besides `t`", None),
        ("t,x\n", r"data\.csv: no data rows", None),
        ("t,x,y\n1,2,3\n2,abc,4\n", r"data\.csv: line 3: column `x`: 'abc' is not a number\.", 3),
        # float() reads Python's digit separator: "1_000" was 1000
        ("t,x,y\n1,2,3\n2,1_000,4\n", r"data\.csv: line 3: column `x`: '1_000' is not a number\.", 3),
        ("t,x\n1,2\n1_0,3\n", r"data\.csv: line 3: column `t`: '1_0' is neither a number of seconds", 3),
        ("t,x,y\n1,2,3\n2,3\n", r"data\.csv: line 3: expected 3 cells \(t, x, y\); found 2\.", 3),
        ("t,x,y\n1,2,3\n2,3,4,5\n", r"data\.csv: line 3: expected 3 cells", 3),
        ("t,x\n1,2\n2,3\n2,4\n", r"data\.csv: line 4: column `t`: times must be strictly increasing; "
                                 r"2 follows 2\.", 4),
        ("t,x\n1,2\n0.5,4\n", r"line 3: column `t`: times must be strictly increasing", 3),
        ("t,x\n,2\n", r"data\.csv: line 2: column `t`: the time is missing", 2),
        ("t,x\nnan,2\n", r"line 2: column `t`: the time is missing", 2),
        ("t,x\nabc,2\n", r"line 2: column `t`: 'abc' is neither a number of seconds nor an ISO-8601 time", 2),
        ("t,x\n1,-inf\n", r"data\.csv: line 2: column `x`: '-inf' is not finite", 2),
        ("t,x\n1,\"2\n", r"data\.csv: line 2: a quoted cell is not closed \(a '\"' opens it and the file ends\)\.$",
         2),
        ("t,x\n1,2\n\n2,\"3\n3,4\n4,5\n", r"data\.csv: line 4: a quoted cell is not closed", 4),  # said line 6
        ("t,x\n1,\"2\"x\n", r"data\.csv: line 2: .*expected after", 2),
        ("t,x,x\n1,2,3\n", r"data\.csv: line 1: the header names column\(s\) \['x'\] more than once", 1),
        # a trailing comma: a column '' always missing, taken as a measurement (m = 2)
        ("t,x,\n1,2,\n", r"data\.csv: line 1: the header's column 3 has no name", 1),
        # datetime read a fraction of the minute or the hour as one of the second: 12:00.5 as 12:00:00.5
        ("t,x\n2026-05-01T12:00:00,1\n2026-05-01T12:00.5,2\n",
         r"line 3: column `t`: '2026-05-01T12:00\.5' has a fraction of an hour or a minute", 3),
        ('t,x\n"2026-05-01 12,25",1\n', r"line 2: column `t`: '2026-05-01 12,25' has a fraction of an hour", 2),
        ("t,x\n20260501T1200.5,1\n", r"line 2: column `t`: '20260501T1200\.5' has a fraction of an hour", 2),
        ("t,x\n2026-05-01_12.5,1\n", r"line 2: column `t`: '2026-05-01_12\.5' has a fraction of an hour", 2),
    ],
)
def test_read_measurements_errors(tmp_path, text, match, line):
    path = write(tmp_path / "data.csv", text)
    with pytest.raises(InputFileError, match=match) as info:
        read_measurements(path)
    assert info.value.path == str(path) and info.value.line == line
    assert str(info.value).startswith(str(path))


def test_read_measurements_checks_the_number_of_columns(tmp_path):
    path = write(tmp_path / "data.csv", "t,x\n1,2\n")
    with pytest.raises(
        InputFileError,
        match=r"data\.csv: found 1 measurement column\(s\) \['x'\] besides `t`, but the model "
              r"measures m = 2 component\(s\)\.",
    ):
        read_measurements(path, m=2)


@pytest.mark.parametrize("data, line, column", [
    (b"t,x\n1,\xff\n", 2, 3),
    (b"t,x\r1,2\r2,a\xe9b\r", 3, 4),  # lines that end in "\r" alone
    (b"t,x\r\n1,2\r\n3,\xc3\xa9\xff\r\n", 3, 4),  # columns in characters: the \xc3\xa9 before is one
    (b"\xef\xbb\xbft,\xff\n1,2\n", 1, 3),  # a byte-order mark is not a column
    (b"t,x\n" + b"".join(b"%d,%d\n" % (k, k) for k in range(300_000)) + b"300000,\xe9\n", 300_002, 8),
])
def test_read_measurements_not_utf8_names_the_line_and_column(tmp_path, data, line, column):
    """The file is decoded in blocks of 1 MiB: the error gave the decoder's position in its block (823859 for a
    byte on line 300002), not the line."""
    path = tmp_path / "data.csv"
    path.write_bytes(data)
    with pytest.raises(InputFileError, match=rf"data\.csv: line {line}: not UTF-8 text: byte 0x.. at column "
                                             rf"{column} cannot be decoded\.$") as info:
        read_measurements(path)
    assert info.value.line == line


@pytest.mark.parametrize("reader", ["data", "model"])
def test_a_byte_that_is_not_utf8_in_a_pipe_is_named(tmp_path, reader):
    """Audit JJ1: the line of the byte was looked for by reading the file again, which a pipe cannot be (a FIFO,
    /dev/stdin, a shell's <(...)): an AssertionError's traceback reached the terminal. A pipe's error names the
    byte; a model file, read whole, is searched in memory, so its line is named too."""
    import threading

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    data = b"t,x\n1,2\n2,\xff\n" if reader == "data" else b"[model]\nF = 1\nH = 1\nQ = 1\nR = 1\n# \xff\n"
    writer = threading.Thread(target=fifo.write_bytes, args=(data,))
    writer.start()

    def end() -> None:  # a reader that opened the pipe again would wait for a writer forever: give it an end
        with suppress(OSError):  # (ENXIO: no reader waits)
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))

    guard = threading.Timer(5.0, end)
    guard.start()
    expected = r"pipe: not UTF-8 text: byte 0xff cannot be decoded\.$" if reader == "data" else \
        r"pipe: line 6: not UTF-8 text: byte 0xff at column 3 cannot be decoded\.$"
    try:
        with pytest.raises(InputFileError, match=expected):
            read_measurements(fifo) if reader == "data" else read_model(fifo)
    finally:
        guard.cancel()
        writer.join(timeout=10)


def test_a_time_column_without_a_name_is_read_when_chosen(tmp_path):
    """pandas writes an unnamed index as the header's empty first cell: chosen as the time column, it is read."""
    path = write(tmp_path / "data.csv", ",a,b\n1,2,3\n2,4,5\n")
    read = read_measurements(path, time_column="")
    assert read.columns == ["", "a", "b"] and read.times.tolist() == [1.0, 2.0]
    with pytest.raises(InputFileError, match=r"line 1: the header's column 3 has no name"):
        read_measurements(write(tmp_path / "more.csv", "t,a,\n1,2,3\n"))


@pytest.mark.parametrize("kwargs, match", [
    ({"columns": "xy"}, r"`columns` must be a sequence of column names; got the str 'xy' \(for one column: "
                        r"\['xy'\]\)"),  # its letters were the columns x and y
    ({"columns": [1]}, r"`columns` must be a sequence of column names \(str\); got \[1\]"),
    ({"time_column": 0}, r"`time_column` must be a column's name \(a str\); got 0"),
])
def test_read_measurements_checks_the_names_it_is_given(tmp_path, kwargs, match):
    path = write(tmp_path / "data.csv", "t,x,y,xy\n1,2,3,4\n")
    with pytest.raises(TypeError, match=match):
        read_measurements(path, **kwargs)
    assert read_measurements(path, columns=(c for c in ["xy", "x"])).columns == ["t", "xy", "x"]


def test_read_measurements_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_measurements(tmp_path / "nope.csv")


# ---------------------------------------------------------------------------
# read_model
# ---------------------------------------------------------------------------


def test_read_named_model_with_default_prior(tmp_path):
    path = write(tmp_path / "m.toml", '[model]\nkind = "constant_velocity"\ndim = 2\ndt = 0.5\nq = 2\nr = 0.25\n')
    model, prior, names, _ = read_model(path)
    expected = gf.constant_velocity(0.5, 2.0, 0.25, dim=2)
    for a, b in zip(model.at(0), expected.at(0)):
        np.testing.assert_array_equal(a, b)
    assert names == ["x", "y", "vx", "vy"]
    np.testing.assert_array_equal(prior.mean, np.zeros(4))
    np.testing.assert_array_equal(prior.cov, 1e6 * np.eye(4))


def test_a_model_file_with_a_byte_order_mark_reads_as_without(tmp_path):
    """As the measurements' CSV does; it was 'invalid TOML: Invalid statement (at line 1, column 1)'."""
    text = '[model]\nkind = "constant_velocity"\ndt = 0.5\nq = 2\nr = 0.25\n'
    plain, marked = read_model(write(tmp_path / "a.toml", text)), read_model(write(tmp_path / "b.toml", "\ufeff" + text))
    for a, b in zip(plain.model.at(0), marked.model.at(0)):
        np.testing.assert_array_equal(a, b)
    assert plain.state_names == marked.state_names


def test_read_named_constant_acceleration_default_dim_and_var_prior(tmp_path):
    path = write(tmp_path / "m.toml", '[model]\nkind = "constant_acceleration"\ndt = 1\nq = 0.1\nr = 4\n'
                                      "[prior]\nmean = [1, 2, 3]\nvar = 9\n")
    model, prior, names, _ = read_model(path)
    np.testing.assert_array_equal(model.F, gf.constant_acceleration(1.0, 0.1, 4.0).F)
    assert names == ["x", "vx", "ax"]
    np.testing.assert_array_equal(prior.mean, [1, 2, 3])
    np.testing.assert_array_equal(prior.cov, 9 * np.eye(3))


def test_read_named_constant_position_in_two_axes(tmp_path):
    """A random walk per axis seen by a position sensor: the CLI named only velocity and acceleration models
    (audit Y3); the matrices are gf.model's of the same motion and sensor."""
    path = write(tmp_path / "m.toml", '[model]\nkind = "constant_position"\ndim = 2\ndt = 0.5\nq = 3\nr = 4\n')
    model, prior, names, timed = read_model(path)
    want = gf.model(gf.ConstantPosition(dim=2, q=3.0), gf.Position(dim=2, r=4.0), dt=0.5)
    for name in ("F", "H", "Q", "R"):
        np.testing.assert_array_equal(getattr(model, name), getattr(want, name))
    np.testing.assert_array_equal(model.Q, 1.5 * np.eye(2))  # q dt
    assert names == ["x", "y"] and isinstance(timed, gf.TimedModel)


def test_read_explicit_model_with_states_and_cov_prior(tmp_path):
    path = write(tmp_path / "m.toml", "[model]\nF = [[1, 1], [0, 1]]\nH = [1, 0]\nQ = [[1, 0], [0, 3]]\n"
                                      'R = 10\nstates = ["pos", "vel"]\n'
                                      "[prior]\nmean = [0, 1]\ncov = [[500, 0], [0, 500]]\n")
    model, prior, names, _ = read_model(path)
    np.testing.assert_array_equal(model.F, [[1, 1], [0, 1]])
    np.testing.assert_array_equal(model.H, [[1, 0]])
    np.testing.assert_array_equal(model.R, [[10]])
    assert (model.n, model.m, model.p) == (2, 1, 0)
    assert names == ["pos", "vel"]
    np.testing.assert_array_equal(prior.cov, 500 * np.eye(2))


@pytest.mark.parametrize("text", ["[model]\nF = [[1, 1], [0, 1]]\nH = [1, 0]\nQ = [[1, 0], [0, 3]]\nR = 10\n",
                                  '[model]\nkind = "constant_velocity"\ndt = 0.5\nq = 2\nr = 0.25\n'],
                         ids=["explicit", "named"])
def test_a_model_files_states_name_its_model_as_the_cli_names_its_columns(tmp_path, text):
    """Review R13: a named model's file with states = ["pos", "vel"] gave a model named x, vx, so results in
    Python were labelled otherwise than the same file's in the CLI."""
    spec = read_model(write(tmp_path / "m.toml", text + 'states = ["pos", "vel"]\n'))
    assert spec.model.names == ("pos", "vel") and spec.state_names == ["pos", "vel"]
    assert spec.timed is None or spec.timed.names == ("pos", "vel")  # the named model for irregular times too
    frame = gf.filter(spec.model, spec.prior, [1.0, 2.0, 2.5]).to_pandas()
    assert list(frame.columns) == ["pos", "vel", "pos_sd", "vel_sd"]
    unnamed = read_model(write(tmp_path / "u.toml", text))
    assert unnamed.model.names in (None, ("x", "vx"))  # an explicit model's default (x0, x1), or the motion's


def test_read_explicit_model_default_names_and_prior_mean(tmp_path):
    path = write(tmp_path / "m.toml", "[model]\nF = [[1.0]]\nH = [[1.0]]\nQ = [[0.5]]\nR = [[2.0]]\n"
                                      "[prior]\ncov = [[4.0]]\n")
    model, prior, names, _ = read_model(path)
    assert names == ["x0"]
    np.testing.assert_array_equal(prior.mean, [0.0])
    np.testing.assert_array_equal(prior.cov, [[4.0]])


EXPLICIT = "[model]\nF = [[1, 0], [0, 1]]\nH = [[1, 0]]\nQ = [[1, 0], [0, 1]]\nR = 1\n"
NAMED = '[model]\nkind = "constant_velocity"\ndt = 1\nq = 1\nr = 1\n'


@pytest.mark.parametrize(
    "text, match",
    [
        ("[model]\nF = [[1,\n", r"m\.toml: invalid TOML: .*\(at (line \d+, column \d+|end of document)\)"),
        ("[model\n", r"m\.toml: invalid TOML: .*line 1"),
        ("", r"m\.toml: missing the \[model\] table\."),
        ("model = 3\n", r"m\.toml: `model` must be a table"),
        (EXPLICIT + "[extra]\n", r"m\.toml: unknown table\(s\) \['extra'\]; valid tables are \[model\], \[prior\]\."),
        (EXPLICIT + "[prior]\nmean = [0, 0]\nsigma = 1\n",
         r"m\.toml: \[prior\]: unknown key\(s\) \['sigma'\]; valid keys are mean, cov, var"),
        (EXPLICIT + "G = 1\n", r"m\.toml: \[model\]: unknown key\(s\) \['G'\]; valid keys are F, H, Q, R, states "
                               r"\(explicit matrices\), or kind, dim, dt, q, r, states \(a named model\)\."),
        (NAMED + "F = [[1]]\n", r"\[model\]: unknown key\(s\) \['F'\]; valid keys are kind, dim, dt, q, r, states "
                                r"\(a named model\), or F, H, Q, R, states \(explicit matrices, without `kind`\)\.$"),
        # review R46: no key offered as a misspelling of itself, another case first, and explicit matrices with a
        # named model's key are not blamed on a missing `kind`
        (NAMED + "R = 1\n", r"\[model\]: unknown key\(s\) \['R'\]; .*\. \(`R` for `r`\?\)$"),
        (EXPLICIT.replace("R = 1", "r = 1"), r"\[model\]: unknown key\(s\) \['r'\]; valid keys are F, H, Q, R, states "
                                            r"\(explicit matrices\), .*\. \(`r` for `R`\?\)$"),
        (EXPLICIT + "dt = 1\n", r"\[model\]: unknown key\(s\) \['dt'\]; valid keys are F, H, Q, R, states \(explicit "
                                r"matrices\), or kind, dim, dt, q, r, states \(a named model\)\.$"),
        ('[model]\ndt = 1\n', r"\[model\]: `dt` is a key of a named model, which needs `kind`"),
        ('[model]\ndim = 1\ndt = 1\nq = 1\nR = 1\n', r"\[model\]: `dim`, `dt`, `q` are keys of a named model, which "
                                                    r"needs `kind`"),
        # misspelt keys: the one meant is offered, and a misspelt `kind` does not make the named model's keys unknown
        # (audit PP2)
        ('[model]\nknid = "constant_velocity"\ndim = 2\ndt = 0.5\nq = 0.5\nr = 0.25\n',
         r"m\.toml: \[model\]: `dim`, `dt`, `q`, `r` are keys of a named model, which needs `kind` \(one of "
         r"constant_acceleration, constant_position, constant_velocity\) \(`knid` for `kind`\?\); explicit "
         r"matrices are F, H, Q and R\.$"),
        (NAMED.replace("dt = 1", "dts = 1"), r"\[model\]: unknown key\(s\) \['dts'\]; .* \(`dts` for `dt`\?\)$"),
        ("[model]\nF = 1.0\nH = 1.0\nQ = 1.0\nRr = 3.0\n", r"unknown key\(s\) \['Rr'\]; .* \(`Rr` for `R`\?\)$"),
        (EXPLICIT + "B = [[1], [0]]\n",
         r"m\.toml: \[model\] B: a control input is not supported by the command line yet"),
        ("[model]\nF = [[1]]\nH = [[1]]\nQ = [[1]]\n", r"m\.toml: \[model\]: missing key\(s\) \['R'\]; "
                                                        r"explicit models need F, H, Q and R\."),
        ('[model]\nkind = "constant_velocity"\ndt = 1\n', r"\[model\]: missing key\(s\) \['q', 'r'\]"),
        ('[model]\nkind = "singer"\ndt = 1\nq = 1\nr = 1\n', r"m\.toml: \[model\] kind: unknown model kind "
                                                           r"'singer'; valid kinds are constant_acceleration, "
                                                           r"constant_position, constant_velocity\."),
        ("[model]\nkind = 3\n", r"\[model\] kind: unknown model kind 3"),
        (NAMED.replace("dt = 1", "dt = -1"), r"m\.toml: \[model\] dt: `dt` must be a positive number"),
        (NAMED.replace("dt = 1", 'dt = "soon"'), r"m\.toml: \[model\] dt: `dt` must be a positive number"),
        (NAMED.replace("dt = 1", "dt = 1" + "0" * 400), r"m\.toml: \[model\] dt: `dt` must be a positive number; got an "
                                                       r"integer of 401 digits, beyond float64"),  # was a traceback
        (NAMED + "dim = 4\n", r"m\.toml: \[model\] dim: `dim` must be 1, 2 or 3"),
        # (the integer was told in full, 444 characters: audit YY2; the step's overflow is dt's or q's, so the
        # table's: review R54)
        (NAMED + "dim = 1" + "0" * 400 + "\n", r"\[model\] dim: `dim` must be 1, 2 or 3; got an integer of 401 digits\.$"),
        (NAMED.replace("dt = 1", "dt = 1e308"), r"m\.toml: \[model\]: a step of dt = 1e\+308 s is too long"),
        (EXPLICIT.replace("H = [[1, 0]]", "H = [[1, 0, 0]]"), r"m\.toml: \[model\] H: `H` must have shape"),
        (EXPLICIT.replace("F = [[1, 0], [0, 1]]", "F = [[1, 0]]"), r"m\.toml: \[model\] F: `F` must be square"),
        (EXPLICIT.replace("Q = [[1, 0], [0, 1]]", "Q = [[1, 0], [0, -1]]"),
         r"m\.toml: \[model\] Q: `Q` must be positive semi-definite; its smallest eigenvalue is -1"),
        (EXPLICIT.replace("Q = [[1, 0], [0, 1]]", "Q = [[1, 2], [0, 1]]"), r"\[model\] Q: `Q` must be symmetric"),
        (EXPLICIT.replace("R = 1", 'R = "one"'), r"m\.toml: \[model\] R: `R` must be an array of numbers"),
        (EXPLICIT.replace("R = 1", "R = [[1], [2, 3]]"), r"\[model\] R: `R` must be a rectangular array of real numbers; got rows of different lengths \(1, 2\)"),
        (EXPLICIT + 'states = ["a"]\n', r"m\.toml: \[model\] states: `states` must be a list of 2 distinct names"),
        (EXPLICIT + 'states = ["a", "a"]\n', r"\[model\] states: `states` must be a list of 2 distinct names"),
        (EXPLICIT + 'states = ["a", "a_sd"]\n', r"\[model\] states: `states` must not hold a name with '_sd' after"),
        (EXPLICIT + "states = [1, 2]\n", r"\[model\] states: `states` must be a list of 2 distinct names"),
        (EXPLICIT + "states = [[1], [2]]\n", r"\[model\] states: `states` must be a list of 2 distinct names"),
        (EXPLICIT + 'states = "xy"\n', r"\[model\] states: `states` must be a list of 2 distinct names"),
        (EXPLICIT + "[prior]\nmean = [1, 2, 3]\n", r"m\.toml: \[prior\] mean: `mean` must have shape \(2,\)"),
        (EXPLICIT + "[prior]\ncov = [[1]]\n", r"m\.toml: \[prior\] cov: `cov` must have shape \(2, 2\)"),
        (EXPLICIT + "[prior]\ncov = [[1, 0], [0, -1]]\n", r"\[prior\] cov: `cov` must be positive semi-definite"),
        (EXPLICIT + "[prior]\nvar = -2\n", r"m\.toml: \[prior\] var: `var` must be a non-negative number; got -2\.0\."),
        (EXPLICIT + "[prior]\nvar = [1, 2]\n", r"m\.toml: \[prior\] var: `var` must have shape \(\) \(one number\)"),
        (EXPLICIT + "[prior]\nvar = 1\ncov = [[1, 0], [0, 1]]\n",
         r"m\.toml: \[prior\]: give either `cov` or `var` \(var \* I\), not both\."),
        (EXPLICIT + "prior = 1\n", r"\[model\]: unknown key\(s\) \['prior'\]"),
        # a traceback (OverflowError) and silent casts of strings and booleans inside arrays
        (EXPLICIT.replace("R = 1", "R = 1" + "0" * 400), r"\[model\] R: `R` must be finite; got an integer too large"),
        (EXPLICIT + "[prior]\nmean = [1, 1" + "0" * 400 + "]\n", r"\[prior\] mean: `mean` must be finite; got an int"),
        (EXPLICIT.replace("Q = [[1, 0], [0, 1]]", 'Q = [["1", 0], [0, 1]]'), r"\[model\] Q: `Q` must be an array of "
                                                                            r"numbers; got strings\."),
        (EXPLICIT.replace("Q = [[1, 0], [0, 1]]", "Q = [[true, 0], [0, 1]]"), r"\[model\] Q: `Q` must be an array of "
                                                                            r"numbers; got booleans\."),
        (EXPLICIT + '[prior]\nmean = ["1", "2"]\n', r"\[prior\] mean: `mean` must be an array of numbers; got strings"),
        ("prior = 1\n" + EXPLICIT, r"m\.toml: `prior` must be a table"),
    ],
)
def test_read_model_errors(tmp_path, text, match):
    path = write(tmp_path / "m.toml", text)
    with pytest.raises(InputFileError, match=match) as info:
        read_model(path)
    assert str(info.value).startswith(f"{path}: ")
    assert "\n" not in str(info.value)


def test_read_model_keeps_gaussfuse_error_as_cause(tmp_path):
    path = write(tmp_path / "m.toml", EXPLICIT.replace("Q = [[1, 0], [0, 1]]", "Q = [[1, 0], [0, -1]]"))
    with pytest.raises(InputFileError, match=r"\[model\] Q") as info:
        read_model(path)
    assert info.value.field == "[model] Q"
    assert isinstance(info.value.__cause__, ValueError)
    assert str(info.value).endswith(str(info.value.__cause__))


def test_read_model_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_model(tmp_path / "nope.toml")


# ---------------------------------------------------------------------------
# write_estimates
# ---------------------------------------------------------------------------


def random_estimates(T=6, n=3, seed=1):
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.1, 1.0, T))
    means = rng.normal(size=(T, n)) * 10.0 ** rng.integers(-8, 8, size=(T, n))
    A = rng.normal(size=(T, n, n))
    covs = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(n)
    return times, means, covs


def test_write_estimates_round_trips_exactly(tmp_path):
    times, means, covs = random_estimates()
    path = tmp_path / "est.csv"
    write_estimates(path, times, means, covs, ["a", "b", "c"], time_name="time")
    assert path.read_text().splitlines()[0] == "time,a,b,c,std_a,std_b,std_c"
    t, values, columns, _ = read_measurements(path)
    assert columns == ["time", "a", "b", "c", "std_a", "std_b", "std_c"]
    np.testing.assert_array_equal(t, times)
    np.testing.assert_array_equal(values[:, :3], means)
    np.testing.assert_array_equal(values[:, 3:], np.sqrt(np.diagonal(covs, axis1=1, axis2=2)))


def test_write_estimates_to_stdout_and_to_a_stream(tmp_path, capsys):
    times, means, covs = random_estimates(T=2, n=1)
    write_estimates(None, times, means, covs, ["x"])
    stream = stdio.StringIO()
    write_estimates(stream, times, means, covs, ["x"])
    out = capsys.readouterr().out
    assert out == stream.getvalue()
    lines = out.splitlines()
    assert lines[0] == "t,x,std_x" and len(lines) == 3
    assert lines[1] == ",".join(repr(float(v)) for v in (times[0], means[0, 0], np.sqrt(covs[0, 0, 0])))


@pytest.mark.parametrize(
    "args, match",
    [
        ((np.zeros(3), np.zeros((3, 2)), np.zeros((3, 2, 2)), ["a"]), r"`means` must have shape \(3, 1\)"),
        ((np.zeros(3), np.zeros((2, 2)), np.zeros((3, 2, 2)), ["a", "b"]), r"`means` must have shape \(3, 2\)"),
        ((np.zeros(3), np.zeros((3, 2)), np.zeros((3, 2)), ["a", "b"]), r"`covs` must have shape \(3, 2, 2\)"),
        ((np.zeros((3, 1)), np.zeros((3, 2)), np.zeros((3, 2, 2)), ["a", "b"]), r"`times` must have shape"),
    ],
)
def test_write_estimates_rejects_mismatched_shapes(tmp_path, args, match):
    path = tmp_path / "est.csv"
    with pytest.raises(ValueError, match=match):
        write_estimates(path, *args)
    assert not path.exists()


# ---------------------------------------------------------------------------
# open_atomic
# ---------------------------------------------------------------------------


def test_open_atomic_writes_with_usual_permissions(tmp_path):
    path = tmp_path / "out.txt"
    with open_atomic(path, "w") as f:
        f.write("new")
        assert not path.exists()  # nothing appears before the block ends
    assert path.read_text() == "new"
    assert os.listdir(tmp_path) == ["out.txt"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_open_atomic_leaves_nothing_on_error(tmp_path):
    path = tmp_path / "out.bin"
    with pytest.raises(RuntimeError, match="boom"):
        with open_atomic(path, "wb") as f:
            f.write(b"partial")
            raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []


def test_open_atomic_names_the_file_in_a_write_error_that_names_none(tmp_path):
    """A full disk said "[Errno 28] No space left on device", naming no file (audit BB2)."""
    path = tmp_path / "out.csv"
    path.write_text("old")
    with pytest.raises(OSError) as failed:
        with open_atomic(path) as f:
            f.write("new")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert (failed.value.errno, failed.value.filename) == (errno.ENOSPC, str(path))
    other = tmp_path / "input.csv"
    with pytest.raises(FileNotFoundError) as named:  # one that names its own file keeps it
        with open_atomic(path) as f:
            open(other)
    assert named.value.filename == str(other)
    assert path.read_text() == "old"
    assert sorted(os.listdir(tmp_path)) == ["out.csv"]


def test_open_atomic_keeps_the_old_file_on_error(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    with pytest.raises(ValueError, match="bad"):
        with open_atomic(path) as f:
            f.write("new")
            raise ValueError("bad")
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.txt"]


def test_open_atomic_missing_directory_names_the_target(tmp_path):
    path = tmp_path / "nodir" / "out.txt"
    with pytest.raises(FileNotFoundError) as info:
        with open_atomic(path):
            pass
    assert info.value.filename == str(path)


def _open_descriptors() -> set[str]:
    return set(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="needs /proc/self/fd to count descriptors")
@pytest.mark.parametrize("existing", [False, True])
def test_open_atomic_interrupted_while_the_file_object_is_built(tmp_path, monkeypatch, existing):
    # A signal (Ctrl-C, or the CLI's SIGTERM) raised inside open(): the file object built so far is dropped.
    # The interruption must come out as itself, not as an EBADF from closing that descriptor a second time,
    # leaving no temporary file and no open descriptor.
    path = tmp_path / "out.csv"
    if existing:
        path.write_text("old")

    def interrupted_open(fd, *args, **kwargs):
        open(fd, *args, **kwargs)  # built, then dropped (as the signal leaves it)
        raise KeyboardInterrupt

    monkeypatch.setattr(gaussfuse.io, "open", interrupted_open, raising=False)
    before = _open_descriptors()
    with pytest.raises(KeyboardInterrupt):
        with open_atomic(path, "w", newline=""):
            pass
    assert _open_descriptors() == before
    assert os.listdir(tmp_path) == (["out.csv"] if existing else [])
    assert not existing or path.read_text() == "old"


def test_open_atomic_interrupted_as_the_temporary_file_is_created(tmp_path, monkeypatch):
    # A signal that lands after os.open has created the file but before its descriptor is kept: the
    # descriptor is lost to the interruption, but the temporary file is still removed.
    path, opened = tmp_path / "out.csv", []
    real_open = os.open

    def interrupted(*args, **kwargs):
        opened.append(real_open(*args, **kwargs))
        raise KeyboardInterrupt

    monkeypatch.setattr(gaussfuse.io.os, "open", interrupted)
    try:
        with pytest.raises(KeyboardInterrupt):
            with open_atomic(path):
                pass
    finally:
        monkeypatch.undo()
        for fd in opened:
            os.close(fd)
    assert len(opened) == 1 and os.listdir(tmp_path) == []


def test_open_atomic_does_not_remove_a_temporary_name_it_did_not_create(tmp_path, monkeypatch):
    # os.open refusing the temporary name (here: it exists) creates nothing, so nothing is removed.
    path = tmp_path / "out.csv"
    monkeypatch.setattr(gaussfuse.io.secrets, "token_hex", lambda _: "taken")
    other = tmp_path / ".out.csv.taken.tmp"
    other.write_text("someone else's")
    with pytest.raises(FileExistsError) as info:
        with open_atomic(path):
            pass
    assert info.value.filename == str(path)
    assert other.read_text() == "someone else's" and sorted(os.listdir(tmp_path)) == [other.name]


def test_docstring_examples():
    result = doctest.testmod(gaussfuse.io, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


# ---------------------------------------------------------------------------
# Pathological input files: bounded memory, one-line errors
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text",
    [
        "a = " + "[" * 5000 + "]" * 5000 + "\n",                            # arrays, 5000 deep
        "a = " + "{b = " * 5000 + "1" + "}" * 5000 + "\n",                   # inline tables
        "[model]\nF = " + "[" * 490 + "1.0" + "]" * 490 + "\nH = 1\nQ = 1\nR = 1\n",  # parses, then recursed
        "[model]\nF = " + "[" * 17 + "1.0" + "]" * 17 + "\nH = 1\nQ = 1\nR = 1\n",    # just over the limit
        "[prior]\na" + ".b" * 40 + " = 1\n",                                # dotted keys
    ],
    ids=["arrays-5000", "inline-tables-5000", "arrays-490", "arrays-17", "dotted-keys-40"],
)
def test_read_model_rejects_deep_nesting_in_one_line(tmp_path, text):
    path = write(tmp_path / "m.toml", text)
    with pytest.raises(InputFileError, match=r"m\.toml: not a model file: tables and arrays nested more than "
                                             r"16 levels deep") as info:
        read_model(path)
    assert "\n" not in str(info.value)


def test_read_model_accepts_the_nesting_limit(tmp_path):
    # 15 arrays inside [model] make 16 levels: not rejected for its depth (but not a matrix either)
    path = write(tmp_path / "m.toml", "[model]\nF = " + "[" * 15 + "1.0" + "]" * 15 + "\nH = 1\nQ = 1\nR = 1\n")
    with pytest.raises(InputFileError, match=r"\[model\] F: `F` must have shape"):
        read_model(path)


def test_read_model_not_utf8_names_the_file(tmp_path):
    """It named the byte's offset in the file ("position 9"), where the CSV reader names the line and column."""
    path = tmp_path / "m.toml"
    path.write_bytes(b"[model]\nkind = \"\xff\"\n")
    with pytest.raises(InputFileError, match=r"m\.toml: line 2: not UTF-8 text: byte 0xff at column 9 cannot be "
                                             r"decoded\.$"):
        read_model(path)


def test_a_hint_in_a_model_file_is_in_the_files_words(tmp_path):
    """A scalar Q for two states was told "give 1 * np.eye(2)", which a TOML file cannot hold (audit BB2)."""
    path = tmp_path / "m.toml"
    path.write_text("[model]\nF = [[1.0, 0.0], [0.0, 1.0]]\nH = [1.0, 0.0]\nQ = 2.5\nR = 1.0\n")
    with pytest.raises(InputFileError, match=r"\[model\] Q: `Q` must have shape \(2, 2\).* A number is a 1 × 1 matrix "
                                             r"only; for 2\.5 times the identity write the 2 × 2 matrix with 2\.5 on its "
                                             r"diagonal\.$"):
        read_model(path)


@pytest.mark.parametrize("end", ["/", "/.", "/./", "/.."])
def test_open_atomic_refuses_a_folders_name(tmp_path, end):
    """"out.csv/" (audit BB2) and "out.csv/." (review R19) wrote the file out.csv, where the shell's `>` refuses
    a folder's name."""
    with pytest.raises(IsADirectoryError) as refused:
        with open_atomic(str(tmp_path / "out.csv") + end) as f:
            f.write("x")
    assert refused.value.filename == str(tmp_path / "out.csv") + end
    assert os.listdir(tmp_path) == []
    with pytest.raises(FileNotFoundError):  # as the shell's `> ""` (review R20: "Is a directory")
        with open_atomic("") as f:
            f.write("x")


def test_open_atomic_leaves_an_error_of_the_block_that_is_not_a_write_as_it_is(tmp_path):
    """Every OSError of the block that named no file was given the output's name: reading a closed input
    inside it said the output had a bad file descriptor (review R19)."""
    reader, writer = os.pipe()
    os.close(reader)
    with pytest.raises(OSError) as failed:
        with open_atomic(tmp_path / "out.csv") as f:
            f.write("x")
            os.read(reader, 1)
    assert (failed.value.errno, failed.value.filename) == (errno.EBADF, None)
    os.close(writer)


def test_read_model_rejects_a_file_over_the_size_limit(tmp_path):
    limit = gaussfuse.io.MAX_MODEL_BYTES
    path = tmp_path / "m.toml"
    path.write_bytes(NAMED.encode() + b"#" * (limit - len(NAMED)))  # exactly the limit: read
    assert read_model(path).model.n == 2
    with open(path, "ab") as f:
        f.write(b"#")
    with pytest.raises(InputFileError, match=rf"m\.toml: larger than {limit} bytes; not a model file\."):
        read_model(path)


def test_read_measurements_rejects_a_nul_character(tmp_path):
    path = tmp_path / "data.csv"
    path.write_bytes(b"t,x\n1,2\n2,\x003\n")
    with pytest.raises(InputFileError, match=r"data\.csv: line 3: a NUL character: not a text file\.") as info:
        read_measurements(path)
    assert info.value.line == 3


def test_read_measurements_rejects_an_overlong_line(tmp_path):
    limit = gaussfuse.io.MAX_LINE_CHARS
    path = tmp_path / "data.csv"
    path.write_text("t,x\n1,2\n" + "1," * (limit // 2 + 1) + "\n")
    with pytest.raises(InputFileError, match=rf"data\.csv: line 3: longer than {limit} characters\.$") as info:
        read_measurements(path)
    assert info.value.line == 3


def test_read_measurements_line_limit_excludes_the_line_ending(tmp_path, monkeypatch):
    monkeypatch.setattr(gaussfuse.io, "MAX_LINE_CHARS", 8)
    path = tmp_path / "data.csv"
    path.write_text("t,x\r\n1,2.5e-6\r\n2,2.5e-6\n3,2.5e-6", newline="")  # 8 characters each
    np.testing.assert_array_equal(read_measurements(path).zs, [[2.5e-6]] * 3)
    path.write_text("t,x\n1,2.5e-6\n2,2.5e-06\n", newline="")
    with pytest.raises(InputFileError, match=r"data\.csv: line 3: longer than 8 characters\.$"):
        read_measurements(path)


ENDLESS = """\
import resource, sys
import gaussfuse.io
from gaussfuse.cli import main
with open("/proc/self/status") as f:
    vm = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
limit = vm + 512 * 2**20  # what the process has, plus 512 MiB
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
for read in (gaussfuse.io.read_model, gaussfuse.io.read_measurements):
    try:
        read("/dev/zero")
    except gaussfuse.io.InputFileError as exc:
        print(exc)
sys.exit(main(["filter", "/dev/zero", "--model", sys.argv[1]]))
"""


@pytest.mark.skipif(not os.path.exists("/dev/zero") or sys.platform != "linux", reason="needs Linux /dev/zero")
def test_endless_files_fail_fast_in_bounded_memory(tmp_path):
    model = write(tmp_path / "m.toml", NAMED)
    proc = subprocess.run([sys.executable, "-c", ENDLESS, str(model)], capture_output=True, text=True,
                          timeout=120)
    assert proc.stdout.splitlines() == [
        f"/dev/zero: larger than {gaussfuse.io.MAX_MODEL_BYTES} bytes; not a model file.",
        "/dev/zero: line 1: a NUL character: not a text file.",
    ], proc.stderr
    assert (proc.returncode, proc.stderr) == (2, "gaussfuse: error: /dev/zero: line 1: a NUL character: "
                                                 "not a text file.\n")


# ---------------------------------------------------------------------------
# write_model: every file written reads back to the same model
# ---------------------------------------------------------------------------

from hypothesis import HealthCheck, assume, given, settings, strategies as st  # noqa: E402

finite = st.floats(allow_nan=False, allow_infinity=False)  # with -0.0, subnormals and ±1.8e308
nonnegative = st.floats(min_value=0.0, max_value=1e300)  # validation symmetrises: (Q + Qᵀ) / 2 must not overflow
# any text: newlines, quotes, backslashes, control characters, all of Unicode but surrogates
names_of = st.text(min_size=1, max_size=12)


def psd(draw, n):
    """A covariance that LinearModel/Gaussian may accept: diagonal, or B Bᵀ scaled by a power of 2."""
    if draw(st.booleans()):
        return np.diag(draw(st.lists(nonnegative, min_size=n, max_size=n)))
    B = np.array(draw(st.lists(st.floats(-1e3, 1e3), min_size=n * n, max_size=n * n))).reshape(n, n)
    return (B @ B.T) * 2.0 ** draw(st.integers(-1000, 960))


@st.composite
def model_files(draw):
    n, m = draw(st.integers(1, 3)), draw(st.integers(1, 2))

    def matrix(rows, cols):
        return np.array(draw(st.lists(finite, min_size=rows * cols, max_size=rows * cols))).reshape(rows, cols)

    try:
        model = gf.LinearModel(matrix(n, n), matrix(m, n), psd(draw, n), psd(draw, m))
        prior = "diffuse" if draw(st.booleans()) else gf.Gaussian(matrix(n, 1)[:, 0], psd(draw, n))
    except ValueError:  # e.g. B Bᵀ overflowed, or rounding made it slightly indefinite
        assume(False)
    names = draw(st.lists(names_of, min_size=n, max_size=n, unique=True))
    comments = draw(st.lists(st.text(), max_size=3))
    return model, prior, names, comments


def same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(model_files())
def test_write_model_reads_back_bit_for_bit(tmp_path_factory, case):
    model, prior, names, comments = case
    path = tmp_path_factory.mktemp("model") / "m.toml"
    with open(path, "w", encoding="utf-8") as f:
        gaussfuse.io.write_model(f, model, prior, names, comments)
    back = read_model(path)
    assert back.state_names == names
    for name in ("F", "H", "Q", "R"):
        assert same_bits(getattr(back.model, name), getattr(model, name)), name
    if prior == "diffuse":
        assert back.prior == "diffuse"
    else:
        assert same_bits(back.prior.mean, prior.mean) and same_bits(back.prior.cov, prior.cov)
    lines = path.read_text(encoding="utf-8").split("\n")
    assert [line.startswith("# ") for line in lines[:len(comments) + 1]] == [True] * len(comments) + [False]


@pytest.mark.parametrize(
    "names, comments",
    [
        (['a\nb'], []),
        (['"quoted"\\'], []),
        (['\x00\x1f\x7f\r\t\b\f'], []),
        (['ok'], ["gaussfuse fit da\nta.csv", "carriage\rreturn", "nul\x00 and del\x7f"]),
    ],
    ids=["newline", "quote-backslash", "control-characters", "comments"],
)
def test_write_model_escapes_what_toml_cannot_hold_raw(tmp_path, names, comments):
    model = gf.LinearModel(1.0, 1.0, 0.5, 2.0)
    path = tmp_path / "m.toml"
    with open(path, "w", encoding="utf-8", newline="") as f:
        gaussfuse.io.write_model(f, model, gf.Gaussian([-0.0], [[1e-310]]), names, comments)
    back = read_model(path)
    assert back.state_names == names
    assert same_bits(back.prior.mean, [-0.0]) and same_bits(back.prior.cov, [[1e-310]])
    lines = path.read_text(encoding="utf-8").split("\n")
    assert len(lines) == len(comments) + 11  # [model], F, H, Q, R, states, "", [prior], mean, cov, ""
    assert all(line.startswith("# ") for line in lines[:len(comments)])


def test_write_model_refuses_what_would_not_read_back_before_writing():
    """A prior of "gaussian" was written as diffuse, a prior of another dimension and names x, x_sd were written
    for read_model to refuse, and prior=None raised AttributeError after [model] was written (audit BB2)."""
    model = gf.LinearModel(np.eye(2), [[1.0, 0.0]], np.eye(2), 1.0)
    for prior, names, error, match in [
            ("gaussian", ["a", "b"], TypeError, r"^`prior` must be a gaussfuse\.Gaussian\(mean, cov\) or 'diffuse'; "
                                                r"got 'gaussian'\.$"),
            (None, ["a", "b"], TypeError, r"^`prior` must be .*; got NoneType\.$"),
            (gf.Gaussian(np.zeros(3), np.eye(3)), ["a", "b"], ValueError, r"^`prior` must have dimension 2"),
            ("diffuse", ["x", "x_sd"], ValueError, r"^`names` must not hold a name with '_sd' after another")]:
        out = stdio.StringIO()
        with pytest.raises(error, match=match):
            gaussfuse.io.write_model(out, model, prior, names)
        assert out.getvalue() == ""
    with pytest.raises(TypeError, match=r"^`model` must be a gaussfuse\.LinearModel; got str\.$"):
        gaussfuse.io.write_model(stdio.StringIO(), "model", "diffuse", ["a", "b"])


def test_read_measurements_checks_m(tmp_path):
    """m = "1" was reported as the file's fault: "found 1 measurement column(s) ... but the model measures m = 1"
    (audit BB2)."""
    path = tmp_path / "d.csv"
    path.write_text("t,z\n0,1\n1,2\n")
    for m, error in (("1", TypeError), (1.5, TypeError), (True, TypeError), (0, ValueError), (-1, ValueError)):
        with pytest.raises(error, match=rf"^`m` must be a positive integer; got {re.escape(repr(m))}\.$"):
            read_measurements(path, m=m)
    assert read_measurements(path, m=np.int64(1)).zs.shape == (2, 1)


def test_write_estimates_checks_its_arguments_before_writing():
    """Times mixing strings and numbers, complex means and a str of state names gave NumPy's messages or wrote
    the letters as columns (audit BB2)."""
    for args, error, match in [
            ((["a", 1.0], [[1.0], [2.0]], [[[1.0]]] * 2, ["s"]), TypeError, r"^`times` must be an array of numbers"),
            (([0.0], [[1 + 2j]], [[[1.0]]], ["s"]), TypeError, r"^`means` must be real"),
            (([0.0], [[np.inf]], [[[1.0]]], ["s"]), ValueError, r"^`means` must be finite"),
            (([0.0, 1.0], np.ones((2, 2)), np.tile(np.eye(2), (2, 1, 1)), "xy"), TypeError,
             r"^`state_names` must be a sequence of 2 strings; got 'xy'\.$")]:
        out = stdio.StringIO()
        with pytest.raises(error, match=match):
            write_estimates(out, *args)
        assert out.getvalue() == ""
    out = stdio.StringIO()  # a negative variance is the round-off of 0
    write_estimates(out, [0.0], [[1.0]], [[[-1e-18]]], np.array(["s"]))
    assert out.getvalue() == "t,s,std_s\n0.0,1.0,0.0\n"


def test_a_subnormal_noise_intensity_reads(tmp_path):
    """q = 5e-324 was refused ("`Q` must be positive semi-definite", named [model] q): its Q at the 1 s step the
    motion is checked at had a covariance rounded up beside variances rounded down. Each entry is now rounded once
    from its exact value (audit BB1): at dt = 0.5 every one is below half the least subnormal, so Q is 0."""
    path = tmp_path / "m.toml"
    path.write_text('[model]\nkind = "constant_velocity"\ndt = 0.5\nq = 5e-324\nr = 1.0\n')
    assert np.array_equal(read_model(path).model.Q, np.zeros((2, 2)))
    assert np.array_equal(gf.ConstantVelocity(q=5e-324).transition(1.0)[1], [[0.0, 0.0], [0.0, 5e-324]])


@pytest.mark.parametrize(
    "names, match",
    [
        (["a"], r"`names` must be 2 distinct non-empty strings, one per state; got \['a'\]"),
        (["a", "a"], r"`names` must be 2 distinct non-empty strings"),
        (["a", ""], r"`names` must be 2 distinct non-empty strings"),
        (["a", 1], r"`names` must be 2 distinct non-empty strings"),
        (["a", "\udcff"], r"`names` must be Unicode text"),
    ],
)
def test_write_model_rejects_names_that_would_not_read_back(names, match):
    model = gf.LinearModel(np.eye(2), [[1.0, 0.0]], np.eye(2), 1.0)
    out = stdio.StringIO()
    with pytest.raises(ValueError, match=match):
        gaussfuse.io.write_model(out, model, "diffuse", names)
    assert out.getvalue() == ""


# ---------------------------------------------------------------------------
# open_atomic never destroys what is at the path
# ---------------------------------------------------------------------------


def test_open_atomic_writes_through_a_symlink(tmp_path):
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "out.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    with open_atomic(link) as f:
        f.write("new")
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_text() == "new"
    assert sorted(os.listdir(tmp_path)) == ["link.txt", "real"] and os.listdir(tmp_path / "real") == ["out.txt"]


def test_open_atomic_creates_the_target_of_a_dangling_symlink(tmp_path):
    link = tmp_path / "link.txt"
    link.symlink_to("target.txt")
    with open_atomic(link) as f:
        f.write("new")
    assert link.is_symlink() and (tmp_path / "target.txt").read_text() == "new"


def read_all(fd):
    """Everything readable from `fd` (non-blocking) until its writers have closed it."""
    chunks = []
    while chunk := os.read(fd, 65536):
        chunks.append(chunk)
    return b"".join(chunks)


def test_open_atomic_writes_a_fifo_in_place(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader: the writer's open does not block
    try:
        with open_atomic(fifo, "w", encoding="utf-8") as f:
            f.write("through the pipe\n")
        assert read_all(reader) == b"through the pipe\n"
    finally:
        os.close(reader)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert os.listdir(tmp_path) == ["pipe"]


def test_open_atomic_writes_a_fifo_nothing_on_error(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="bad"):  # with no reader, opening the FIFO would block
        with open_atomic(fifo) as f:
            f.write("partial")
            raise ValueError("bad")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and os.listdir(tmp_path) == ["pipe"]


def test_open_atomic_writes_a_character_device_in_place(monkeypatch):
    def no_replace(*args):
        raise AssertionError(f"os.replace{args}")  # before the fix, /dev/null would have been replaced

    monkeypatch.setattr(os, "replace", no_replace)
    before = set(os.listdir("/dev"))
    with open_atomic("/dev/null", "wb") as f:
        f.write(b"gone")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert set(os.listdir("/dev")) <= before  # no temporary file beside it


def test_open_atomic_keeps_the_permissions_of_an_existing_file(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    path.chmod(0o640)
    with open_atomic(path) as f:
        f.write("new")
    assert path.read_text() == "new"
    assert stat.S_IMODE(path.stat().st_mode) == 0o640


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="only root can give a file away")
def test_open_atomic_keeps_the_owner_of_an_existing_file(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")
    os.chown(path, 12345, 23456)
    path.chmod(0o4750)  # setuid survives the chown
    with open_atomic(path) as f:
        f.write("new")
    st_ = path.stat()
    assert (st_.st_uid, st_.st_gid, stat.S_IMODE(st_.st_mode)) == (12345, 23456, 0o4750)


def test_open_atomic_refuses_a_read_only_file(tmp_path, monkeypatch):
    path = tmp_path / "out.txt"
    path.write_text("old")
    path.chmod(0o444)
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False)  # root may write anything: pretend
    with pytest.raises(PermissionError) as info:
        with open_atomic(path) as f:
            f.write("new")
    assert info.value.filename == str(path)
    assert path.read_text() == "old" and os.listdir(tmp_path) == ["out.txt"]


def test_open_atomic_refuses_a_directory_naming_it(tmp_path):
    path = tmp_path / "dir"
    path.mkdir()
    with pytest.raises(IsADirectoryError) as info:
        with open_atomic(path) as f:
            f.write("new")
    assert info.value.filename == str(path)
    assert os.listdir(tmp_path) == ["dir"] and path.is_dir()


def test_open_atomic_refuses_a_socket(tmp_path):
    path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(path))
        with pytest.raises(ValueError, match=r"sock: a socket; gaussfuse writes to a regular file, a new path, "
                                             r"a FIFO or a character device\."):
            with open_atomic(path) as f:
                f.write("new")
        assert stat.S_ISSOCK(os.lstat(path).st_mode) and os.listdir(tmp_path) == ["sock"]


def test_open_atomic_errors_name_the_path_never_the_temporary_file(tmp_path, monkeypatch):
    def cross_device(src, dst):
        raise OSError(errno.EXDEV, os.strerror(errno.EXDEV), src, dst)

    monkeypatch.setattr(os, "replace", cross_device)
    path = tmp_path / "out.txt"
    with pytest.raises(OSError) as info:
        with open_atomic(path) as f:
            f.write("new")
    assert (info.value.errno, info.value.filename, info.value.filename2) == (errno.EXDEV, str(path), None)
    assert os.listdir(tmp_path) == []


# ---------------------------------------------------------------------------
# iter_measurements: the file in pieces
# ---------------------------------------------------------------------------

PIECES = """t,x,y
0.5,1.0,2.0

1.0,,3.5
1.5,nan,4.0
2.0,2.5,
2.5,3.0,1e-300
"""


@pytest.mark.parametrize("rows", [1, 2, 4, 5, 100])
def test_pieces_join_to_the_whole_file(tmp_path, rows):
    path = write(tmp_path / "d.csv", PIECES)
    whole = read_measurements(path)
    pieces = list(iter_measurements(path, rows=rows))
    assert [len(p.times) for p in pieces][:-1] == [rows] * (len(pieces) - 1)
    np.testing.assert_array_equal(np.concatenate([p.times for p in pieces]), whole.times)
    np.testing.assert_array_equal(np.concatenate([p.zs for p in pieces]), whole.zs)
    assert [t for p in pieces for t in p.time_text] == whole.time_text == ["0.5", "1.0", "1.5", "2.0", "2.5"]
    assert all(p.columns == ["t", "x", "y"] for p in pieces)
    np.testing.assert_array_equal(whole.zs, [[1.0, 2.0], [np.nan, 3.5], [np.nan, 4.0], [2.5, np.nan], [3.0, 1e-300]])


@pytest.mark.parametrize("text, line, match", [
    ("t,x\n1,1\n2,2\n3,3\n2.5,4\n", 5, r"strictly increasing; 2\.5 follows 3\."),  # across the boundary
    ("t,x\n1,1\n2,2\n3,3\n4,oops\n", 5, r"column `x`: 'oops' is not a number"),
    ("t,x\n1,1\n2,2\n3,3\n4,inf\n", 5, r"column `x`: 'inf' is not finite"),
    ("t,x\n1,1\n2,2\n3,3\n2026-01-01T00:00:00,4\n", 5, r"mix numbers \(seconds\) and ISO-8601"),
    ("t,x\n1,1\n2,2\n3,3\n4,4,4\n", 5, r"expected 2 cells \(t, x\); found 3"),
    ("t,x\n1,1\n2,2\n3,3\n,4\n", 5, r"the time is missing"),
])
def test_an_error_in_a_later_piece_names_its_line(tmp_path, text, line, match):
    path = write(tmp_path / "d.csv", text)
    pieces = iter_measurements(path, rows=3)
    assert len(next(pieces).times) == 3  # the first piece is good, and read before the error
    with pytest.raises(InputFileError, match=match) as info:
        next(pieces)
    assert info.value.line == line
    with pytest.raises(InputFileError, match=match):
        read_measurements(path)


def test_iso_times_in_pieces(tmp_path):
    path = write(tmp_path / "d.csv", "time,x\n2026-05-01T12:00:00+02:00,1\n2026-05-01T10:00:01Z,2\n"
                                     "2026-05-01T10:00:03.5,3\n")
    pieces = list(iter_measurements(path, rows=2))
    times = np.concatenate([p.times for p in pieces])
    np.testing.assert_array_equal(np.diff(times), [1.0, 2.5])
    assert pieces[1].time_text == ["2026-05-01T10:00:03.5"]


@pytest.mark.parametrize("rows", [0, -1, 1.5, True, "3"])
def test_rows_must_be_a_positive_int(tmp_path, rows):
    path = write(tmp_path / "d.csv", PIECES)
    with pytest.raises(ValueError, match="`rows` must be a positive int"):
        next(iter_measurements(path, rows=rows))


@pytest.mark.parametrize("block", [1, 2, 3, 5, 64])
@pytest.mark.parametrize("ending", ["\n", "\r\n", "\r", "\r\r\n"])
def test_lines_read_in_blocks_are_the_lines_of_the_file(block, ending):
    """Small blocks split lines and "\\r\\n" endings anywhere: the lines (and their numbers) stay the file's."""
    text = ending.join(["t,x", "1,2", "", "3,44444", "5,6"]) + ending + "7,8"
    want = stdio.StringIO(text, newline="").readlines()
    got = list(gaussfuse.io._text_lines("f.csv", stdio.StringIO(text, newline=""), block=block))
    assert got == want
    bad = text.replace("44444", "44\x0044")
    line = 1 + [k for k, text in enumerate(want) if "44444" in text][0]  # 4, or 7 after "\r\r\n"s
    with pytest.raises(InputFileError, match=f"line {line}: a NUL character"):
        list(gaussfuse.io._text_lines("f.csv", stdio.StringIO(bad, newline=""), block=block))


def test_write_estimates_gives_a_variance_of_zero_to_round_off_a_zero_std(tmp_path):
    """A covariance's product can leave a zero variance at -1e-18: its standard deviation is 0, not nan."""
    covs = np.array([[[4.0, 0.0], [0.0, -1e-18]]])
    path = tmp_path / "est.csv"
    write_estimates(path, np.zeros(1), np.zeros((1, 2)), covs, ["a", "b"])
    assert path.read_text().splitlines()[1] == "0.0,0.0,0.0,2.0,0.0"


def test_iso_times_finer_than_their_seconds_resolve_are_named_as_such(tmp_path):
    """Two ISO times 1 ns apart a year after the file's first became one float time: the error said the second
    'follows' the first, as if out of order (audit I). Seconds since the first time resolve about 4 ns there."""
    path = tmp_path / "ns.csv"
    path.write_text("t,z\n2025-01-01T00:00:00Z,1\n2026-01-01T00:00:00.000000003Z,2\n2026-01-01T00:00:00.000000004Z,3\n")
    with pytest.raises(InputFileError, match=r"line 4: column `t`: 2026-01-01T00:00:00\.000000004Z is 1 ns after "
                                                  r"2026-01-01T00:00:00\.000000003Z, finer than seconds since the "
                                                  r"file's first time resolve 3\.1536e\+07 s in"):
        read_measurements(path)
    path.write_text("t,z\n2026-01-01T00:00:00Z,1\n2026-01-01T00:00:00.000000003Z,2\n2026-01-01T00:00:00.000000004Z,3\n")
    np.testing.assert_array_equal(read_measurements(path).times, [0.0, 3e-9, 4e-9])
