"""Long-format tables of many series: `gaussfuse filter` and `gaussfuse fit` with --series-column, on Dask.

The oracle is the library on each series alone (filter, smooth) or on the
pooled in-memory array (fit). The commands run on a LocalCluster of 2 worker
processes started here (`--scheduler`), and once on a local cluster of their
own (`--workers`).
"""

import io
import os
import re
import stat
import warnings

import numpy as np
import pytest

import gaussfuse as gf
from gaussfuse import io as gfio, panels
from gaussfuse import cli
from gaussfuse.cli import main

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")
distributed = pytest.importorskip("distributed")

NAMED = '[model]\nkind = "constant_velocity"\ndt = 1.0\nq = 0.5\nr = 1.0\n[prior]\nvar = 10.0\n'
EXPLICIT = ('[model]\nF = [[1.0, 1.0], [0.0, 1.0]]\nH = [[1.0, 0.0]]\nQ = [[0.25, 0.5], [0.5, 1.0]]\nR = [[2.0]]\n'
            '[prior]\nvar = 10.0\n')


@pytest.fixture(scope="module")
def scheduler():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=50)
    with cluster:
        yield cluster.scheduler_address


def dataset(root, kind="parquet", seed=0):
    """Two partitions (hive directories) of 9 series of different lengths at irregular times, rows shuffled."""
    rng = np.random.default_rng(seed)
    series = {}
    for group, ids in (("a", range(0, 5)), ("b", range(5, 9))):
        rows = []
        for i in ids:
            T = 20 + 2 * i
            t = 100.0 + np.cumsum(rng.choice([0.5, 1.0, 2.0], T))
            x = np.cumsum(rng.normal(size=T)) + rng.normal(size=T)
            x[rng.random(T) < 0.1] = np.nan
            series[f"u{i}"] = (t, x)
            rows.append(pd.DataFrame({"unit": f"u{i}", "t": t, "x": x, "note": "-"}))
        frame = pd.concat(rows).sample(frac=1, random_state=1)
        os.makedirs(root / f"group={group}", exist_ok=True)
        if kind == "parquet":
            frame.to_parquet(root / f"group={group}" / "part.parquet", index=False)
        else:
            frame.to_csv(root / f"group={group}" / "part.csv", index=False)
    return series


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("smooth", [False, True])
def test_filter_a_partitioned_parquet_dataset(tmp_path, capsys, scheduler, smooth):
    """One output per partition, each series' rows equal to the library on that series alone."""
    data, out = tmp_path / "data", tmp_path / "out"
    series = dataset(data)
    (tmp_path / "cv.toml").write_text(NAMED)
    code, stdout, err = run(capsys, "filter", data, "-m", tmp_path / "cv.toml", "--series-column", "unit",
                            "--columns", "x", "--out", out, "--scheduler", scheduler, "--engine", "numba",
                            "--check", "off", *(["--smooth"] if smooth else []))
    assert code == 0 and stdout == ""
    assert err.strip().endswith(f"9 series, {sum(len(t) for t, _ in series.values())} rows in 2 partition(s); "
                                f"wrote {out}")
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.parquet")) == \
        ["group=a/part.parquet", "group=b/part.parquet"]
    spec = gfio.read_model(tmp_path / "cv.toml")
    got = pd.concat([pd.read_parquet(p) for p in sorted(out.rglob("*.parquet"))])
    assert list(got.columns) == ["unit", "t", "x", "vx", "std_x", "std_vx"]
    run_one = gf.smooth if smooth else gf.filter
    for name, (t, x) in series.items():
        rows = got[got.unit == name]
        want = run_one(spec.timed, spec.prior, x, times=t, engine="numba", check="off")
        np.testing.assert_array_equal(rows.t.to_numpy(), t)  # time-ordered, the times as read
        np.testing.assert_array_equal(rows[["x", "vx"]].to_numpy(), want.means)
        np.testing.assert_array_equal(rows.std_x.to_numpy(), np.sqrt(want.covs[:, 0, 0]))


def test_filter_csv_partitions_with_explicit_matrices_on_a_cluster_of_its_own(tmp_path, capsys):
    data, out = tmp_path / "data", tmp_path / "out"
    series = dataset(data, kind="csv", seed=1)
    (tmp_path / "m.toml").write_text(EXPLICIT)
    code, _, err = run(capsys, "filter", data, "-m", tmp_path / "m.toml", "--series-column", "unit", "--columns", "x",
                       "--out", out, "--workers", "2", "--engine", "numba", "--check", "off")
    assert code == 0, err
    spec = gfio.read_model(tmp_path / "m.toml")
    got = pd.concat([pd.read_csv(p) for p in sorted(out.rglob("*.csv"))])
    for name, (t, x) in series.items():  # explicit matrices: every row one step; series padded in the batch
        want = gf.filter(spec.model, spec.prior, x, engine="numba", check="off")
        np.testing.assert_array_equal(got[got.unit == name][["x0", "x1"]].to_numpy(), want.means)


def test_progress_on_a_terminal_counts_partitions(tmp_path, capsys, monkeypatch, scheduler):
    """It said "partitions: 1 rows", "partitions: 2 rows" (audit BB3)."""
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    shown = Terminal()
    made = cli._RowProgress
    monkeypatch.setattr(cli, "_RowProgress", lambda stream=None, **kw: made(shown, **kw))
    data = tmp_path / "data"
    dataset(data, kind="csv", seed=1)
    (tmp_path / "m.toml").write_text(EXPLICIT)
    code, _, err = run(capsys, "filter", data, "-m", tmp_path / "m.toml", "--series-column", "unit", "--columns", "x",
                       "--out", tmp_path / "out", "--scheduler", scheduler, "--check", "off")
    assert code == 0, err
    parts = len(list(data.rglob("*.csv")))
    assert parts > 1
    assert shown.getvalue() == "".join(f"\rdone: {k} of {parts} partitions" for k in range(1, parts + 1)) + "\n"


@pytest.mark.parametrize("smooth", [False, True])
def test_filter_series_with_a_diffuse_prior(tmp_path, capsys, scheduler, smooth):
    """A diffuse prior failed with "'NoneType' object is not subscriptable" (no NIS for the divergence check)."""
    rng = np.random.default_rng(4)
    series = {f"s{i}": np.cumsum(rng.normal(size=12 + i)) + rng.normal(size=12 + i) for i in range(3)}
    pd.concat([pd.DataFrame({"id": name, "t": np.arange(len(x), dtype=float), "z": x})
               for name, x in series.items()]).to_csv(tmp_path / "d.csv", index=False)
    (tmp_path / "m.toml").write_text("[model]\nF = [[1.0]]\nH = [[1.0]]\nQ = [[0.5]]\nR = [[1.0]]\n"
                                     "[prior]\ndiffuse = true\n")
    out = tmp_path / "out"
    code, _, err = run(capsys, "filter", tmp_path / "d.csv", "-m", tmp_path / "m.toml", "--series-column", "id",
                       "-o", out, "--scheduler", scheduler, *(["--smooth"] if smooth else []))
    assert code == 0, err
    got = pd.concat([pd.read_csv(p) for p in sorted(out.rglob("*.csv"))])
    spec = gfio.read_model(tmp_path / "m.toml")
    for name, x in series.items():
        want = (gf.smooth if smooth else gf.filter)(spec.model, "diffuse", x)
        np.testing.assert_allclose(got[got.id == name]["x0"].to_numpy(), want.means[:, 0], rtol=1e-12)


def test_series_ids_are_the_text_in_the_file(tmp_path, capsys, scheduler):
    """pandas read the ids as numbers: "007" and "7" (and "1" and "1.0") were one series, written back as 7,
    and the id "NA" was refused as missing. Oracle: gf.filter on each series alone."""
    rows = [("007", 0.0, 1.0), ("7", 1.0, 2.0), ("1", 0.0, 3.0), ("1.0", 0.0, 4.0), ("1e3", 0.0, 5.0),
            ("1000", 1.0, 6.0), ("NA", 0.0, 7.0), ("NA", 2.0, 8.0)]
    (tmp_path / "d.csv").write_text("id,t,z\n" + "".join(f"{i},{t},{z}\n" for i, t, z in rows))
    (tmp_path / "m.toml").write_text("[model]\nF = [[1.0]]\nH = [[1.0]]\nQ = [[0.5]]\nR = [[2.0]]\n"
                                     "[prior]\nvar = 10.0\n")
    out = tmp_path / "out"
    code, _, err = run(capsys, "filter", tmp_path / "d.csv", "-m", tmp_path / "m.toml", "--series-column", "id",
                       "-o", out, "--check", "off", "--scheduler", scheduler)
    assert code == 0, err
    assert "7 series, 8 rows" in err
    got = pd.read_csv(next(out.rglob("*.csv")), dtype={"id": str}, keep_default_na=False)
    assert got["id"].tolist() == [i for i, _, _ in rows]
    spec = gfio.read_model(tmp_path / "m.toml")
    for name in dict.fromkeys(i for i, _, _ in rows):
        zs = np.array([z for i, _, z in rows if i == name])
        want = gf.filter(spec.model, spec.prior, zs, check="off")  # times 1 apart, or the first of its series
        np.testing.assert_allclose(got[got.id == name]["x0"].to_numpy(), want.means[:, 0], rtol=1e-12)


def test_a_partition_is_read_as_one_series_file_is(tmp_path):
    """The panel reader took a byte-order mark into the first column's name ("no column named `id`"), "NA", "null"
    and "None" as missing values, " t" (unstripped) for no time column, rewrote time cells (0.10 as 0.1), and said
    only "UnicodeDecodeError" for a file that is not UTF-8; ISO times became float seconds since 1970."""
    text = ("\ufeffid, t , z\n a ,2026-05-01T12:00:00.000000000Z,1.0\na,2026-05-01T12:00:00.000000100Z,\n"
            "b,2026-05-01T12:00:01Z,NaN\nb,2026-05-01T11:00:00Z,2\n")
    (tmp_path / "d.csv").write_text(text, encoding="utf-8")
    part = panels.read_partition(str(tmp_path / "d.csv"), "id", 1)
    assert part.ids == ["a", "b"] and part.columns == ["id", "t", "z"]
    np.testing.assert_array_equal(part.times[0], [0.0, 1e-7])  # exact to the nanosecond, from the series' first
    np.testing.assert_array_equal(part.times[1], [0.0, 3601.0])  # rows in any order: by time within a series
    np.testing.assert_array_equal(np.concatenate(part.zs)[:, 0], [1.0, np.nan, 2.0, np.nan])
    assert part.frame["t"].tolist()[0] == "2026-05-01T12:00:00.000000000Z"
    (tmp_path / "v.csv").write_text("id,t,z\na,0.10,1\na,1e1,2\na,0020,3\n")
    assert panels.read_partition(str(tmp_path / "v.csv"), "id", 1).frame["t"].tolist() == ["0.10", "1e1", "0020"]
    for cell in ("NA", "null", "None", "1_000"):
        _refused(tmp_path / "n.csv", f"id,t,z\na,0,1\na,1,{cell}\n",
                 rf"n\.csv: line 3: column `z`: '{cell}' is not a number\.")
    _refused(tmp_path / "m.csv", "id,t,z\na,0,1\na,2026-05-01T12:00:01Z,2\n",
             r"the times mix numbers \(seconds\) and ISO-8601 times")
    # named by its line, column and series, as one file's reader names it (it said "a measurement is infinite.")
    _refused(tmp_path / "i.csv", "id,t,z\na,0,1\n\nb,1,-inf\n",
             r"i\.csv: line 4: column `z`: series 'b': a measurement is infinite \(-inf\)\.$")
    _refused(tmp_path / "j.csv", "id,t,z\na,0,1\n,1,-inf\n", r"j\.csv: line 3: column `id`: a row has no series id")
    (tmp_path / "k.csv").write_text("id,t,z\na,0,1\n")  # it said "no column named `id`" (audit X3)
    with pytest.raises(gfio.InputFileError, match=r"k\.csv: the time column `id` is the series-id column; found "
                                                  r"columns \['id', 't', 'z'\]\.$"):
        panels.read_partition(str(tmp_path / "k.csv"), "id", 1, time_column="id")
    _refused(tmp_path / "o.csv", "id\na\n",  # (it was told the file is empty: review R10)
             r"o\.csv: no columns besides the series ids `id`: expected a time column and the measurements")
    _refused(tmp_path / "s.csv", "id;t;z\na;0;1\n",  # (it said "no column named `id`": audit Y3)
             r"s\.csv: one column named 'id;t;z': the file's columns seem to be separated by ';'")
    (tmp_path / "l.csv").write_bytes(b"id,t,z\na,0,1\na,1,\xe9\n")
    with pytest.raises(gfio.InputFileError, match=r"l\.csv: line 3: not UTF-8 text: byte 0xe9 at column 5 cannot be "
                                                  r"decoded\.$"):  # (the codec's "position 17": audit JJ6)
        panels.read_partition(str(tmp_path / "l.csv"), "id", 1)


@pytest.mark.parametrize("parquet", [False, True])
def test_each_series_times_count_from_its_own_first(tmp_path, parquet):
    """Seconds since the partition's first time: a series two centuries after another, stepped by 1 µs, had steps of
    9.5e-7 s (the float's resolution there), where its own file gives 1e-6 (audit X3)."""
    pd = pytest.importorskip("pandas")
    stamps = ["1970-01-01T00:00:00Z", "1970-01-01T00:00:01Z", *(f"2200-01-01T00:00:00.{k:06d}Z" for k in range(10))]
    frame = pd.DataFrame({"id": ["old"] * 2 + ["new"] * 10, "t": stamps, "z": np.arange(12.0)})
    if parquet:
        pytest.importorskip("pyarrow")
        frame["t"] = pd.to_datetime(frame["t"], utc=True, format="ISO8601").astype("datetime64[us, UTC]")
        path = tmp_path / "p.parquet"
        frame.to_parquet(path)
    else:
        path = tmp_path / "p.csv"
        frame.to_csv(path, index=False)
    part = panels.read_partition(str(path), "id", 1)
    (tmp_path / "one.csv").write_text("t,z\n" + "".join(f"{t},{k}\n" for k, t in enumerate(stamps[2:])))
    np.testing.assert_array_equal(part.times[1], gfio.read_measurements(tmp_path / "one.csv").times)
    np.testing.assert_allclose(np.diff(part.times[1]), 1e-6, rtol=1e-15)  # k µs, each rounded once
    np.testing.assert_array_equal(part.times[0], [0.0, 1.0])


def test_matrices_per_row_are_refused_with_series_naming_the_file(tmp_path, capsys):
    """They failed with the library's "time-varying over 3 steps but `zs` has 2 steps", naming no file."""
    (tmp_path / "d.csv").write_text("id,t,z\na,0,1\na,1,2\nb,0,3\n")
    (tmp_path / "m.toml").write_text("[model]\nF = [[1.0]]\nH = [[1.0]]\nQ = [[[0.5]], [[1.0]], [[2.0]]]\n"
                                     "R = [[2.0]]\n[prior]\nvar = 10.0\n")
    out = tmp_path / "out"
    code, _, err = run(capsys, "filter", tmp_path / "d.csv", "-m", tmp_path / "m.toml", "--series-column", "id",
                       "-o", out)
    assert code == 2 and not out.exists()
    assert err.count("\n") == 1 and "m.toml: [model]: matrices given per row (3 of them)" in err


@pytest.mark.parametrize("states, twice, many", [('["t", "id"]', "'id', 't'", True), ('["t", "id"]', "'t'", False),
                                                 ('["x", "std_x"]', "'std_x'", True),
                                                 ('["x", "std_x"]', "'std_x'", False)])
def test_states_named_like_an_output_column_are_refused_before_the_work(tmp_path, capsys, scheduler, states, twice,
                                                                         many):
    """States named t and id replaced the series ids and times of the output with their means; a state std_x
    beside x lost a column to x's standard deviation; one file's header had t or std_x twice. Exit 0, no word."""
    (tmp_path / "d.csv").write_text("id,t,x\na,1,1\na,2,2\n" if many else "t,x\n1,1\n2,2\n")
    (tmp_path / "m.toml").write_text("[model]\nF = [[1.0, 1.0], [0.0, 1.0]]\nH = [[1.0, 0.0]]\n"
                                     f"Q = [[1.0, 0.0], [0.0, 1.0]]\nR = [[1.0]]\nstates = {states}\n")
    out = tmp_path / ("out" if many else "out.csv")
    code, stdout, err = run(capsys, "filter", tmp_path / "d.csv", "-m", tmp_path / "m.toml", "-o", out,
                            *(["--series-column", "id", "--scheduler", scheduler] if many else []))
    assert code == 2 and stdout == "" and not out.exists()
    assert err.count("\n") == 1 and f"the output would have two columns named {twice} " in err
    assert ("d.csv: " if many else "m.toml: ") in err


@pytest.mark.parametrize("text, extra, message", [
    ("id,t,x,y\na,1,1,1\na,2,2,2\n", ["--columns", "t,x"], r"measurement column `t` is the time column"),
    ("id,t,x,y\na,1,1,1\na,2,2,2\n", ["--columns", "x,x"], r"measurement column `x` is named twice"),
    ("id,t,x,y\na,1,1,1\na,2,2,2\n", ["--columns", "id,x"], r"measurement column `id` is the series-id column"),
    ("id,t,x,x\na,1,1,1\na,2,2,2\n", [], r"line 1: the header names column\(s\) \['x'\] more than once"),
    ("t,x,y\na,1,1\na,2,2\n", [], r"the series-id column `t` is named like a time column"),
])
def test_series_columns_are_checked_as_one_files_are(tmp_path, capsys, scheduler, text, extra, message):
    """With --series-column the time column was taken as a measurement, x twice, the id column as one, and
    a repeated header name read as x and x.1 (pandas' renaming), all with exit status 0. The partition's
    reader refuses them (one through the command, the rest on the reader itself: a cluster costs seconds)."""
    (tmp_path / "d.csv").write_text(text)
    series = "t" if text.startswith("t,") else "id"
    columns = extra[1].split(",") if extra else None
    with pytest.raises(gfio.InputFileError, match=message):
        panels.read_partition(str(tmp_path / "d.csv"), series, 2, None, columns)
    if extra == ["--columns", "t,x"]:
        (tmp_path / "m.toml").write_text(EXPLICIT.replace("H = [[1.0, 0.0]]", "H = [[1.0, 0.0], [0.0, 1.0]]")
                                         .replace("R = [[2.0]]", "R = [[2.0, 0.0], [0.0, 2.0]]"))
        out = tmp_path / "out"
        code, _, err = run(capsys, "filter", tmp_path / "d.csv", "-m", tmp_path / "m.toml", "--series-column",
                           series, "--scheduler", scheduler, "-o", out, *extra)
        assert code == 2 and not out.exists()
        assert err.count("\n") == 1 and re.search(message, err), err


def test_pooled_fit_of_a_partitioned_dataset(tmp_path, capsys, scheduler):
    data = tmp_path / "data"
    series = dataset(data, seed=2)
    (tmp_path / "m.toml").write_text(EXPLICIT)
    code, stdout, err = run(capsys, "fit", data, "-m", tmp_path / "m.toml", "--series-column", "unit", "--columns",
                            "x", "--learn", "Q,R", "--method", "em", "--iterations", "10", "--tol", "0", "--scheduler",
                            scheduler, "--engine", "numba")
    assert code == 0, err
    assert "fit: 9 series in 2 partition(s), at most 36 steps each" in err
    fitted = gfio.tomllib.loads(stdout)["model"]
    order = sorted(series, key=lambda k: int(k[1:]))  # the partitions' series, in order
    zs = np.full((9, 36, 1), np.nan)
    for i, name in enumerate(order):
        zs[i, :len(series[name][1]), 0] = series[name][1]
    spec = gfio.read_model(tmp_path / "m.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gf.ConvergenceWarning)
        want = gf.fit(spec.model, spec.prior, zs, learn=("Q", "R"), method="em", iterations=10, tol=0,
                      engine="numba")
    np.testing.assert_allclose(fitted["Q"], want.model.Q, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(fitted["R"], want.model.R, rtol=1e-10)


def test_errors_are_one_line(tmp_path, capsys, scheduler):
    data = tmp_path / "data"
    dataset(data)
    (tmp_path / "cv.toml").write_text(NAMED)
    base = ["filter", data, "-m", tmp_path / "cv.toml", "--series-column", "unit", "--columns", "x",
            "--scheduler", scheduler]
    for extra, match in ((["--out", data], "is the same file as the data file"),
                         ([], "name an output directory with --out"),
                         (["--out", "-"], "name an output directory with --out (standard output, --out -, holds one"),
                         (["--out", tmp_path / "o", "--plot", tmp_path / "f.png"], "--plot draws one series")):
        code, _, err = run(capsys, *base, *extra)
        assert code == 2 and err.startswith("gaussfuse: error: ") and match in err and err.count("\n") == 1, err
    frame = pd.read_parquet(data / "group=a" / "part.parquet")
    frame.loc[frame.index[:2], "t"] = 5.0  # two rows of one series at one time... or two series sharing it
    frame.loc[frame.index[:2], "unit"] = "u0"
    frame.to_parquet(data / "group=a" / "part.parquet", index=False)
    code, _, err = run(capsys, *base, "--out", tmp_path / "o2")
    assert code == 2 and "series 'u0' has two rows at one time" in err and err.count("\n") == 1, err
    assert not (tmp_path / "o2" / "group=a").exists()
    dataset(tmp_path / "split")
    moved = pd.read_parquet(tmp_path / "split" / "group=b" / "part.parquet")
    moved["unit"] = moved["unit"].replace({"u5": "u0"})  # u0 now in both partitions
    moved.to_parquet(tmp_path / "split" / "group=b" / "part.parquet", index=False)
    code, _, err = run(capsys, "fit", tmp_path / "split", "-m", tmp_path / "cv.toml", "--series-column", "unit",
                       "--columns", "x", "--scheduler", scheduler)
    assert code == 2 and "series 'u0' is in two partitions" in err
    # filter only warned, and wrote each part filtered from the prior
    code, _, err = run(capsys, "filter", tmp_path / "split", "-m", tmp_path / "cv.toml", "--series-column", "unit",
                       "--columns", "x", "--scheduler", scheduler, "--out", tmp_path / "o3")
    assert code == 2 and "series 'u0' is in two partitions" in err and err.count("\n") == 1, err
    assert not (tmp_path / "o3").exists() or not any((tmp_path / "o3").rglob("*.parquet"))


@pytest.mark.parametrize("name", ["nosuch.parquet", "nosuch.csv", "nosuchdir"])
def test_missing_data_is_named_with_its_reason(tmp_path, capsys, monkeypatch, name):
    """A missing Parquet file said only "gaussfuse: error: nosuch.parquet", a missing directory "not a .csv or
    .parquet file"; `fit` started a local cluster (a second) before it looked."""
    from gaussfuse import cli

    monkeypatch.setattr(cli, "_cluster", lambda args: pytest.fail("a cluster was started for a missing path"))
    (tmp_path / "cv.toml").write_text(NAMED)
    for command in (["filter", "-o", tmp_path / "o"], ["fit"]):
        code, _, err = run(capsys, command[0], tmp_path / name, "-m", tmp_path / "cv.toml", "--series-column", "unit",
                           *command[1:])
        assert code == 2 and err == f"gaussfuse: error: {tmp_path / name}: No such file or directory\n", err


@pytest.mark.parametrize("smooth", [False, True])
def test_a_series_the_diffuse_prior_cannot_start_is_named(tmp_path, capsys, scheduler, smooth):
    """The error named neither the file nor the series (one observation cannot identify position and velocity)."""
    (tmp_path / "d.csv").write_text("id,t,z\na,0,1\na,1,2\na,2,3\nb,0,1\n")
    (tmp_path / "m.toml").write_text('[model]\nkind = "constant_velocity"\ndt = 1.0\nq = 0.5\nr = 1.0\n'
                                     "[prior]\ndiffuse = true\n")
    code, _, err = run(capsys, "filter", tmp_path / "d.csv", "-m", tmp_path / "m.toml", "--series-column", "id",
                       "-o", tmp_path / "o", "--scheduler", scheduler, *(["--smooth"] if smooth else []))
    assert code == 2 and not (tmp_path / "o").exists()
    assert err.startswith(f"gaussfuse: error: {tmp_path / 'd.csv'}: series 'b': the diffuse initial state is not "
                          "identified") and err.count("\n") == 1, err


def test_a_tables_step_is_its_series_mean_step_and_its_round_off_theirs():
    """step_range kept the smallest and the largest step: a pooled fit stepped by their mean (0.1000000238 for
    0.1000000019 at epoch seconds, 12 times further off than one file's), and a 1.001 ms grid passed for the
    model file's 1 ms, the times' round-off shared by 2 steps instead of all of them (audit Y5)."""
    from gaussfuse.inference.timing import steps

    for step, dt in ((0.1, 0.1), (0.001001, 0.001)):
        times = [1.7e9 + step * np.arange(n) for n in (40, 25)]
        grid = panels.step_range(times)
        alone = steps("times", times[0], 40)  # one series' file, as the single-file reader steps it
        assert grid.count == 63
        assert grid.step == pytest.approx(float(np.mean(np.concatenate([np.diff(t) for t in times]))), rel=1e-15)
        assert grid.near(dt) == alone.near(dt) == (dt == step)
        joined = panels.joined_range([grid, panels.step_range(times[:1])])
        assert joined.count == 63 + 39 and joined.series == 3
        assert joined.step == pytest.approx((grid.total + np.diff(times[0]).sum()) / joined.count, rel=1e-15)
    # many short series on one grid are off alike: 200 of 2 rows are not told a 0.1 s grid steps by 0.0999999 s
    # (review R12: the round-off was shared by all their steps)
    short = panels.step_range([1.7e9 + 0.1 * np.arange(k, k + 2) for k in range(200)])
    assert short.near(0.1) and short.series == 200


def test_panels_step_as_one_series_file_does(tmp_path, capsys, scheduler):
    """A pooled fit used the model file's dt = 0.5 for series 1 s apart, silently (R 10.6% off the single-file fit,
    which warns and fits at 1 s); a panel filter with explicit matrices met irregular times without the warning a
    file gets; an explicit-matrix partition was one batch padded to its longest series (981 MB for a 0.6 MB file),
    and its errors named a series by its place in the batch."""
    rng = np.random.default_rng(8)
    x = (np.cumsum(np.cumsum(rng.normal(size=80)) * 0.1) + rng.normal(size=80)).tolist()
    (tmp_path / "one.csv").write_text("t,x\n" + "".join(f"{k}.0,{v!r}\n" for k, v in enumerate(x)))
    (tmp_path / "many.csv").write_text("id,t,x\n" + "".join(f"s,{k}.0,{v!r}\n" for k, v in enumerate(x)))
    (tmp_path / "cv.toml").write_text(NAMED.replace("dt = 1.0", "dt = 0.5"))
    fits = []
    for data, extra in (("one.csv", []), ("many.csv", ["--series-column", "id", "--scheduler", scheduler])):
        code, stdout, err = run(capsys, "fit", tmp_path / data, "-m", tmp_path / "cv.toml", "--learn", "R",
                                "--method", "mle", *extra)
        assert code == 0 and "the model file's dt = 0.5 s, but the times step by 1 s" in err, err
        fits.append(gfio.tomllib.loads(stdout)["model"])
    assert fits[1]["F"] == [[1.0, 1.0], [0.0, 1.0]]
    np.testing.assert_allclose(fits[1]["R"], fits[0]["R"], rtol=1e-8)
    # and a filter says so as one file's does (a panel said nothing; audit X3)
    for data, extra in (("one.csv", []), ("many.csv", ["--series-column", "id", "--scheduler", scheduler])):
        code, _, err = run(capsys, "filter", tmp_path / data, "-m", tmp_path / "cv.toml", "-o", tmp_path / f"f{data}",
                           "--check", "off", *extra)
        warned = [line for line in err.splitlines() if line.startswith("gaussfuse: warning: ")]
        assert code == 0 and len(warned) == 1 and warned[0].endswith(
            "the model file's dt = 0.5 s, but the times step by 1 s; each step uses the times' own step."), err
    # explicit matrices: batches of similar lengths, each series as it is alone; irregular times named
    lengths = [1, 2, 3, 40, 5, 300, 7]
    rows = [(f"u{i}", t + (0.5 if t % 7 == 3 else 0.0), float(rng.normal())) for i, L in enumerate(lengths)
            for t in range(L)]
    (tmp_path / "p.csv").write_text("id,t,x\n" + "".join(f"{i},{t!r},{v!r}\n" for i, t, v in rows))
    (tmp_path / "m.toml").write_text(EXPLICIT)
    code, _, err = run(capsys, "filter", tmp_path / "p.csv", "-m", tmp_path / "m.toml", "--series-column", "id",
                       "--scheduler", scheduler, "-o", tmp_path / "o", "--check", "off")
    assert code == 0 and "p.csv: the times are irregular (steps from 0.5 s to 1.5 s)" in err, err
    got = pd.read_csv(tmp_path / "o" / "p.csv")
    spec = gfio.read_model(tmp_path / "m.toml")
    for i in range(len(lengths)):
        want = gf.filter(spec.model, spec.prior, np.array([v for j, _, v in rows if j == f"u{i}"]), check="off")
        np.testing.assert_allclose(got[got.id == f"u{i}"]["x0"], want.means[:, 0], rtol=1e-12, atol=1e-12)
    (tmp_path / "d.toml").write_text(EXPLICIT.replace("var = 10.0", "diffuse = true"))
    code, _, err = run(capsys, "filter", tmp_path / "p.csv", "-m", tmp_path / "d.toml", "--series-column", "id",
                       "--scheduler", scheduler, "-o", tmp_path / "o2")
    assert code == 2 and "p.csv: series 'u0': the diffuse initial state is not identified" in err, err


def test_em_in_chunks_does_not_depend_on_how_the_series_are_chunked():
    """A chunk holding only series with nothing observed put all their steps back into EM's sums (a fallback meant
    for data with nothing observed at all, which fit refuses before): chunks (2, 2, 2) differed from the fit in
    memory by 19.4 in log-likelihood after 15 iterations; chunks (3, 3) agreed."""
    da = pytest.importorskip("dask.array")
    rng = np.random.default_rng(5)
    zs = np.cumsum(rng.normal(size=(6, 30, 1)), axis=1) + rng.normal(size=(6, 30, 1))
    zs[2:4] = np.nan  # the middle chunk of (2, 2, 2): nothing observed
    zs[0, 20:] = np.nan
    start = gf.LinearModel(F=1.0, H=1.0, Q=0.3, R=2.0)
    prior = gf.Gaussian(0.0, 5.0)
    options = dict(learn=("Q", "R", "m0", "P0"), iterations=15, tol=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gf.ConvergenceWarning)
        want = gf.fit(start, prior, zs, **options)
        for chunks in ((2, 2, 2), (4, 2), (3, 3)):
            got = gf.fit(start, prior, da.from_array(zs, chunks=(chunks, 30, 1)), **options)
            assert got.loglik == pytest.approx(want.loglik, rel=1e-12), chunks
            np.testing.assert_allclose(got.model.Q, want.model.Q, rtol=1e-10)
            np.testing.assert_allclose(got.prior.cov, want.prior.cov, rtol=1e-10)


def test_a_diffuse_pooled_fit_in_chunks_passes_over_a_series_with_nothing_observed():
    """The in-memory fit left out a series with no observation (it adds nothing); the fit in chunks (dask, and so
    the command line) raised NotIdentified. The oracle is the fit without that series."""
    da = pytest.importorskip("dask.array")
    rng = np.random.default_rng(0)
    zs = rng.normal(size=(4, 20, 1)).cumsum(1)
    zs[1] = zs[2] = np.nan  # one chunk all missing, the other half
    model = gf.LinearModel(F=1.0, H=1.0, Q=0.3, R=0.5)
    want = gf.fit(model, "diffuse", zs[[0, 3]], method="mle")
    got = gf.fit(model, "diffuse", da.from_array(zs, chunks=((1, 2, 1), 20, 1)), method="mle")
    assert got.loglik == pytest.approx(want.loglik, rel=1e-12) and got.nobs == want.nobs
    np.testing.assert_allclose(got.model.Q, want.model.Q, rtol=1e-8)


@pytest.mark.parametrize("kind", ["csv", "parquet"])
def test_a_partition_of_a_header_only_is_one_without_series(tmp_path, capsys, scheduler, kind):
    """A dataset's writer leaves such files (a filter that kept no row of a partition); one of them failed the
    whole command (audit BB3). Its output has the header only; the others' equal a run without it, and the fit
    is the fit without it. A dataset of such files only has no data."""
    data = tmp_path / "data"
    series = dataset(data, kind=kind, seed=2)
    (tmp_path / "cv.toml").write_text(NAMED)
    without = tmp_path / "without"
    assert run(capsys, "filter", data, "-m", tmp_path / "cv.toml", "--series-column", "unit", "--columns", "x",
               "--out", without, "--scheduler", scheduler, "--check", "off")[0] == 0
    os.makedirs(data / "group=c")
    empty = pd.DataFrame({"unit": pd.Series([], dtype=str), "t": pd.Series([], dtype=float),
                          "x": pd.Series([], dtype=float), "note": pd.Series([], dtype=str)})
    if kind == "parquet":
        empty.to_parquet(data / "group=c" / "part.parquet", index=False)
    else:
        (data / "group=c" / "part.csv").write_text("unit,t,x,note\n")
    out = tmp_path / "out"
    code, _, err = run(capsys, "filter", data, "-m", tmp_path / "cv.toml", "--series-column", "unit", "--columns",
                       "x", "--out", out, "--scheduler", scheduler, "--check", "off")
    assert code == 0, err
    read = pd.read_parquet if kind == "parquet" else pd.read_csv
    header_only = read(out / "group=c" / f"part.{kind}")
    assert list(header_only.columns) == ["unit", "t", "x", "vx", "std_x", "std_vx"] and len(header_only) == 0
    for group in "ab":
        pd.testing.assert_frame_equal(read(out / f"group={group}" / f"part.{kind}"),
                                      read(without / f"group={group}" / f"part.{kind}"))
    fits = [run(capsys, "fit", d, "-m", tmp_path / "cv.toml", "--series-column", "unit", "--columns", "x",
                "--learn", "R", "--scheduler", scheduler, "--iterations", "3", "--tol", "0")
            for d in (data, without_c(data, tmp_path))]
    assert fits[0][0] == fits[1][0] == 0  # the same fit, bit for bit (the first line names the data)
    assert fits[0][1].split("\n", 1)[1] == fits[1][1].split("\n", 1)[1]
    assert len(series) == 9
    for group in "ab":
        for f in (data / f"group={group}").iterdir():
            f.unlink()
        (data / f"group={group}" / f"part.{kind}").parent.rmdir()
    for command in (["filter", "--out", tmp_path / "out2"], ["fit"]):
        code, _, err = run(capsys, command[0], data, "-m", tmp_path / "cv.toml", "--series-column", "unit",
                           "--columns", "x", "--scheduler", scheduler, *command[1:])
        assert (code, err) == (2, f"gaussfuse: error: {data}: no data rows: its partition has a header only.\n")
    assert not (tmp_path / "out2").exists()


def without_c(data, tmp_path):
    """A copy of `data` without its partition group=c."""
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(data, copy, ignore=lambda d, names: [n for n in names if n == "group=c"])
    return copy


BAD_TABLES = [
    ("unit,t,x\nu1,1.0,0.5\n,2.0,0.7\n", "line 3: column `unit`: a row has no series id"),
    ("unit,t,x\nu1,1.0,0.5,9\nu1,2.0,0.7\n", "line 2: expected 3 cells (unit, t, x); found 4"),
    ("unit,t,x\nu1,1.0\nu1,2.0,0.7\n", "line 2: expected 3 cells (unit, t, x); found 2"),
    ("unit,t,x\nu1,True,0.5\nu1,False,0.7\n",
     "line 2: column `t`: 'True' is neither a number of seconds nor an ISO-8601"),
    ("unit,t,x\nu1,1.0,True\nu1,2.0,False\n", "line 2: column `x`: 'True' is not a number"),
    ("", "no header: the file is empty or its first line is blank"),
    ("\nunit,t,x\nu1,1.0,0.5\n", "no header: the file is empty or its first line is blank"),  # (review R11)
]


@pytest.mark.parametrize("table, match", BAD_TABLES)
def test_a_malformed_table_is_one_line_and_leaves_no_output(tmp_path, capsys, scheduler, table, match):
    """pandas read a longer row with its first cell as a row name (shifting every cell), padded a shorter one,
    took True/False as 1/0 and an empty id as a series of its own (an IndexError); a second partition's output was
    left behind when the first failed."""
    (tmp_path / "cv.toml").write_text(NAMED)
    data = tmp_path / "data"
    os.makedirs(data)
    good = "unit,t,x\n" + "".join(f"u2,{k}.0,{0.1 * k}\n" for k in range(1, 6))
    (data / "a.csv").write_text(good)
    (data / "b.csv").write_text(table)
    out = tmp_path / "made" / "out"
    code, _, err = run(capsys, "filter", data, "-m", tmp_path / "cv.toml", "--series-column", "unit",
                       "--scheduler", scheduler, "--out", out)
    assert code == 2 and err.startswith("gaussfuse: error: ") and err.count("\n") == 1, err
    assert f"b.csv: {match}" in err, err
    assert not (tmp_path / "made").exists()  # nothing written, and the directories it made are gone again


def test_an_output_inside_the_data_is_refused_and_replaces_nothing(tmp_path, capsys):
    """-o d/sub wrote d/p.csv's estimates over the input partition d/sub/p.csv (exit 0): the data directory's
    files are all inputs, and an output under it would be read as data on the next run."""
    (tmp_path / "m.toml").write_text(EXPLICIT)
    data = tmp_path / "d"
    (data / "sub").mkdir(parents=True)
    (data / "p.csv").write_text("id,t,z\na,0,1\na,1,2\n")
    (data / "sub" / "p.csv").write_text("id,t,z\nb,0,5\nb,1,6\n")
    for out in (data / "sub", data / "out", data):
        code, _, err = run(capsys, "filter", data, "-m", tmp_path / "m.toml", "--series-column", "id", "--workers", "1",
                           "-o", out)
        assert code == 2 and err.count("\n") == 1, err
        assert "is inside the data directory" in err or "is the same file as the data" in err, err
    assert (data / "sub" / "p.csv").read_text() == "id,t,z\nb,0,5\nb,1,6\n"
    assert sorted(p.name for p in data.rglob("*")) == ["p.csv", "p.csv", "sub"]
    single = tmp_path / "one.csv"
    single.write_text("id,t,z\na,0,1\na,1,2\n")
    code, _, err = run(capsys, "filter", single, "-m", tmp_path / "m.toml", "--series-column", "id", "--workers", "1",
                       "-o", tmp_path)
    assert code == 2 and "would write" in err and "over an input" in err, err
    assert single.read_text() == "id,t,z\na,0,1\na,1,2\n"


def test_partitions_of_a_path(tmp_path):
    dataset(tmp_path / "d")
    assert [os.path.relpath(p, tmp_path) for p in panels.partitions(str(tmp_path / "d"))] == \
        ["d/group=a/part.parquet", "d/group=b/part.parquet"]
    (tmp_path / "d" / "extra.csv").write_text("unit,t,x\n")
    with pytest.raises(ValueError, match="both CSV and Parquet"):
        panels.partitions(str(tmp_path / "d"))
    (tmp_path / "e").mkdir()
    with pytest.raises(ValueError, match="without CSV or Parquet files"):
        panels.partitions(str(tmp_path / "e"))


def test_a_diverging_series_is_named(tmp_path, capsys, scheduler):
    data = tmp_path / "data"
    dataset(data)
    frame = pd.read_parquet(data / "group=b" / "part.parquet")
    late = (frame.unit == "u7") & (frame.t > frame[frame.unit == "u7"].t.median())
    frame.loc[late, "x"] += 60.0  # the sensor jumps 60 m away for the second half of one series
    frame.to_parquet(data / "group=b" / "part.parquet", index=False)
    (tmp_path / "cv.toml").write_text(NAMED)
    base = ["filter", data, "-m", tmp_path / "cv.toml", "--series-column", "unit", "--columns", "x",
            "--scheduler", scheduler]
    code, _, err = run(capsys, *base, "--out", tmp_path / "o")
    lines = err.splitlines()
    assert code == 0 and len(lines) == 2, err
    # named in full: every partition of a hive dataset is a part.parquet
    assert lines[0].startswith(f"gaussfuse: warning: {data / 'group=b' / 'part.parquet'}: series 'u7' may be diverging")
    code, _, err = run(capsys, *base, "--out", tmp_path / "o2", "--check", "raise")
    assert code == 2 and "series 'u7' may be diverging" in err and err.count("\n") == 1


@pytest.mark.parametrize("cell, message", [("nan", "a time is missing"), ("NaN ", "a time is missing"),
                                           ("", "a time is missing"), ("inf", "a time is not finite"),
                                           ("-Infinity", "a time is not finite"), ("1e400", "a time is not finite")])
def test_a_time_that_is_not_a_finite_number_is_refused(tmp_path, cell, message):
    """Reading partitions as text let a NaN or infinite time through (its row sorted last, its value kept); the
    single-file reader refuses it, as the partition reader did before."""
    (tmp_path / "d.csv").write_text(f"id,t,z\na,0,1\na,{cell},2\na,2,3\n")
    with pytest.raises(gfio.InputFileError, match=re.escape(f"line 3: column `t`: {message}")):  # (no line before)
        panels.read_partition(str(tmp_path / "d.csv"), "id", 1)


def test_times_of_any_span_are_read_exactly_and_in_order(tmp_path):
    """Times were differences in int64 nanoseconds, which wrap past 292 years: a series of yearly rows from 1700
    to 2020 was filtered from 1993 first, with exit status 0 (audit I); a Parquet timestamp column too."""
    pd = pytest.importorskip("pandas")
    years = range(1700, 2021)
    text = "id,t,z\n" + "".join(f"a,{y}-01-01,{y}\n" for y in years)
    (tmp_path / "y.csv").write_text(text)
    days = np.diff([np.datetime64(f"{y}-01-01", "D").astype(np.int64) for y in years])
    for path in (tmp_path / "y.csv", tmp_path / "y.parquet"):
        if path.suffix == ".parquet":
            pytest.importorskip("pyarrow")
            pd.DataFrame({"id": "a", "t": pd.to_datetime([f"{y}-01-01" for y in years]).astype("datetime64[s]"),
                          "z": np.array(years, dtype=float)}).to_parquet(path)
        part = panels.read_partition(str(path), "id", 1)
        np.testing.assert_array_equal(part.zs[0][:, 0], np.array(years, dtype=float))  # in the order of the years
        np.testing.assert_array_equal(np.diff(part.times[0]), 86400.0 * days)  # each step 365 or 366 days, exactly


def test_a_partition_reads_times_and_names_lines_as_one_series_file_does(tmp_path):
    """The panel reader read ISO times with pandas' rules, not the single-file reader's: it refused week dates and
    decimal commas, cut 12 digits of a second to 9 and took "2026-05" as a time, refused a line of spaces, named
    a cell's line by its row's position (wrong after blank lines and quoted line breaks), and quoted a time cell
    rewritten (audit I)."""
    cases = {"2026-W18-5T12:00:00Z": 0.0, "2026-05-01T12:00:00,5Z": 0.5}
    (tmp_path / "iso.csv").write_text("id,t,z\n   \n" + "".join(f'a,"{c}",1\n' for c in cases) + "\n")
    (tmp_path / "one.csv").write_text("t,z\n" + "".join(f'"{c}",1\n' for c in cases))
    part, one = panels.read_partition(str(tmp_path / "iso.csv"), "id", 1), gfio.read_measurements(tmp_path / "one.csv")
    np.testing.assert_array_equal(part.times[0], list(cases.values()))
    np.testing.assert_array_equal(part.times[0], one.times)
    plain = ["1700-03-01T00:00:00Z", "2026-05-01 12:00:00.123456789+02:00", "2026-05-01T12:00:00.5",
             "2262-01-01T00:00:00Z"]
    (tmp_path / "plain.csv").write_text("id,t,z\n" + "".join(f"a,{c},1\n" for c in plain))  # read by pandas, at once
    (tmp_path / "one.csv").write_text("t,z\n" + "".join(f"{c},1\n" for c in plain))
    np.testing.assert_array_equal(panels.read_partition(str(tmp_path / "plain.csv"), "id", 1).times[0],
                                  gfio.read_measurements(tmp_path / "one.csv").times)
    for cell, message in (("2026-05-01T12:00:00.123456789123Z", "has 12 digits after the second"),
                          ("2026-05", "is neither a number of seconds nor an ISO-8601 time"),
                          ("2026-05-01T12:00:00.000000001z", "'2026-05-01T12:00:00.000000001z' is neither")):
        _refused(tmp_path / "bad.csv", f'id,t,z\n\n"a\nb",2026-05-01T12:00:00Z,1\n\na,{cell},2\n',
                 rf"bad\.csv: line 6: column `t`: .*{re.escape(message)}")
    _refused(tmp_path / "n.csv", 'id,t,x\n\n\na,1,1\n"b\nc",2,2\na,2,oops\n',
             r"n\.csv: line 7: column `x`: 'oops' is not a number\.")
    _refused(tmp_path / "d.csv", "id,t,z\na,1,1\nb,1,1\na,2,2\na,1,3\n",
             r"d\.csv: line 5: column `t`: series 'a' has two rows at one time \(lines 2 and 5\)")
    _refused(tmp_path / "f.csv", "id,t,z\na,1700-01-01T00:00:00Z,1\na,2020-01-01T00:00:00.000000001Z,2\n"
             "a,2020-01-01T00:00:00.000000002Z,3\n", r"f\.csv: line 4: column `t`: series 'a': "
             r"2020-01-01T00:00:00\.000000002Z is 1 ns from 2020-01-01T00:00:00\.000000001Z, finer than seconds")


def _refused(path, text: str, match: str) -> None:
    """A partition of `text` at `path` is refused, with an error matching `match`."""
    path.write_text(text)
    with pytest.raises(gfio.InputFileError, match=match):
        panels.read_partition(str(path), "id", 1)


def test_series_columns_named_by_the_sensor_are_taken_by_name(tmp_path, capsys, scheduler):
    """As in one file (test_cli): a table whose columns are the sensor's y and x was filtered with them swapped
    (audit EE2)."""
    toml = tmp_path / "cv.toml"
    toml.write_text('[model]\nkind = "constant_velocity"\ndim = 2\ndt = 0.5\nq = 0.5\nr = 0.25\n\n'
                    '[prior]\nmean = [0.0, 0.0, 1.0, 0.5]\nvar = 4.0\n')
    rows = [("a", 0.5, 0.254, -0.147), ("a", 1.0, 1.187, 1.057), ("b", 0.5, 2.0, 1.0), ("b", 1.5, 2.6, 1.4)]
    (tmp_path / "xy").mkdir()
    (tmp_path / "yx").mkdir()
    (tmp_path / "xy" / "d.csv").write_text("id,t,x,y\n" + "".join(f"{i},{t},{x},{y}\n" for i, t, x, y in rows))
    (tmp_path / "yx" / "d.csv").write_text("id,t,y,x\n" + "".join(f"{i},{t},{y},{x}\n" for i, t, x, y in rows))
    for name in ("xy", "yx"):
        code, _, err = run(capsys, "filter", tmp_path / name, "--model", toml, "--series-column", "id",
                           "--out", tmp_path / f"out-{name}", "--scheduler", scheduler)
        assert code == 0, err
    assert (tmp_path / "out-xy" / "d.csv").read_text() == (tmp_path / "out-yx" / "d.csv").read_text()


def test_outputs_are_checked_before_the_work_and_written_as_one_file_is(tmp_path, capsys, scheduler):
    """Audit JJ2, JJ4: an output that was a folder failed after the work (naming the temporary file), with the
    earlier outputs already replaced; an output that was a symlink became a file (its target left as it was), and
    one of mode 600 came back 644. Now as --out of one file: refused first, written through, kept."""
    data, out = tmp_path / "data", tmp_path / "out"
    dataset(data, kind="csv")
    (tmp_path / "cv.toml").write_text(NAMED)
    base = ["filter", data, "-m", tmp_path / "cv.toml", "--series-column", "unit", "--columns", "x",
            "--scheduler", scheduler, "--check", "off", "--out", out]
    first, second = out / "group=a" / "part.csv", out / "group=b" / "part.csv"
    first.parent.mkdir(parents=True)
    first.write_text("earlier results\n")
    second.mkdir(parents=True)  # a folder where an output goes
    code, _, err = run(capsys, *base)
    assert code == 2 and err == f"gaussfuse: error: {second}: an output that exists must be a file; it is a directory.\n"
    assert first.read_text() == "earlier results\n"
    second.rmdir()
    target = tmp_path / "kept" / "target.csv"
    target.parent.mkdir()
    target.write_text("old\n")
    first.unlink()
    first.symlink_to(target)
    second.write_text("old\n")
    second.chmod(0o600)
    code, _, err = run(capsys, *base)
    assert code == 0, err
    assert first.is_symlink() and target.read_text().startswith("unit,t,x,vx,std_x,std_vx\n")
    assert stat.S_IMODE(second.stat().st_mode) == 0o600 and second.read_text().startswith("unit,t,x,vx,std_x,std_vx\n")



def test_two_outputs_that_are_one_file_are_refused_before_the_work(tmp_path):
    """Review R43: an output that was a symlink to another shared its temporary file with it: the run failed after
    the work, naming the temporary file, with the other output already replaced."""
    (tmp_path / "b.csv").write_text("earlier\n")
    (tmp_path / "a.csv").symlink_to(tmp_path / "b.csv")
    finals = [str(tmp_path / "a.csv"), str(tmp_path / "b.csv")]
    with pytest.raises(ValueError, match=re.escape(f"{finals[1]} and {finals[0]} are the same file; each output must "
                                                   "be a file of its own.")):
        with cli._written_together(finals):
            raise AssertionError("the work ran")  # pragma: no cover
    assert (tmp_path / "b.csv").read_text() == "earlier\n"
