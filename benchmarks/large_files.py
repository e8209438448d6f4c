"""`gaussfuse filter` on a file larger than memory would like: time and peak memory against pandas' I/O floor.

    python benchmarks/large_files.py [--rows 4800000] [--dir DIR] [--out benchmarks/large_files.md]

Writes a CSV file of `--rows` rows (a 2-D constant-velocity target sampled
exactly at irregular times, 0.1, 0.2 or 0.5 s apart; positions with 1 m
noise, 1 % of the x cells missing), then runs, each in a fresh process:

* the **I/O floor**: pandas reads the file (``read_csv``) and writes a CSV
  file of the output's shape (the time column and 8 columns of full-precision
  floats, ``to_csv``): what any tool that reads and writes these files pays;
* ``gaussfuse filter DATA --model cv2d.toml --out OUT`` (a named model, so
  each step is discretised for its own dt);
* the same with ``--smooth``;
* the floor again, as the machine's speed drifts over minutes (the ratios
  are to the faster floor).

For each: wall time, the ratio to the floor, and the process's peak
resident memory (``ru_maxrss`` of the child, from ``os.wait4``; the data is
written by another child, as a child inherits its parent's size at the
fork as its first peak, so the parent stays small). The issue's
goals: peak under 400 MB whatever the length, and at most 1.5 times the
floor. The outputs are then checked against ``gf.filter`` and ``gf.smooth``
on the whole file in memory (the checker's memory, not the command's): they
must agree to the last bit, the same steps on the same beliefs.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np

MODEL = """[model]
kind = "constant_velocity"
dim = 2
dt = 0.1
q = 0.5
r = 1.0
[prior]
mean = [0.0, 0.0, 0.0, 0.0]
var = 100.0
"""

FLOOR = r"""
import sys, numpy as np, pandas as pd
data, out = sys.argv[1], sys.argv[2]
df = pd.read_csv(data)
est = pd.DataFrame(np.random.default_rng(1).normal(size=(len(df), 8)),
                   columns=["x", "y", "vx", "vy", "std_x", "std_y", "std_vx", "std_vy"])
est.insert(0, "t", df["t"])
est.to_csv(out, index=False)
"""


def write_data(path: str, rows: int, seed: int = 0, q: float = 0.5, r: float = 1.0) -> None:
    """An exactly sampled 2-D constant-velocity track (integrated white noise of density q) at irregular times."""
    rng = np.random.default_rng(seed)
    dts = rng.choice([0.1, 0.2, 0.5], size=rows)
    times = np.round(np.cumsum(dts), 1)
    dts = np.diff(np.concatenate([[0.0], times]))
    pos = np.empty((rows, 2))
    for axis in range(2):  # per axis: [p, v] with Q(dt) = q [[dt³/3, dt²/2], [dt²/2, dt]]
        a, b = rng.normal(size=rows), rng.normal(size=rows)
        var_v = q * dts
        cov_pv = q * dts**2 / 2
        var_p = q * dts**3 / 3
        wv = np.sqrt(var_v) * a
        wp = cov_pv / np.sqrt(var_v) * a + np.sqrt(var_p - cov_pv**2 / var_v) * b
        v = np.cumsum(wv)
        v_before = np.concatenate([[0.0], v[:-1]])
        pos[:, axis] = np.cumsum(dts * v_before + wp)
    zs = np.round(pos + rng.normal(scale=np.sqrt(r), size=(rows, 2)), 4)
    missing = rng.random(rows) < 0.01
    with open(path, "w", encoding="utf-8") as f:
        f.write("t,x,y\n")
        step = 1_000_000
        for lo in range(0, rows, step):
            hi = min(lo + step, rows)
            xs = ["" if missing[k] else repr(float(zs[k, 0])) for k in range(lo, hi)]
            f.write("".join(f"{t!r},{x},{y!r}\n" for t, x, y in zip(times[lo:hi].tolist(), xs, zs[lo:hi, 1].tolist())))


def measure(argv: list[str]) -> tuple[float, float]:
    """Wall seconds and peak resident MB of a child process running `argv`."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    err = proc.stderr.read().decode()
    proc.stderr.close()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{err}")
    return wall, usage.ru_maxrss / 1024  # KiB on Linux


def check(data: str, model_file: str, filtered: str, smoothed: str) -> str:
    """The outputs' largest differences from gf.filter and gf.smooth on the whole file in memory."""
    import pandas as pd

    import gaussfuse as gf
    from gaussfuse import io

    spec = io.read_model(model_file)
    df = pd.read_csv(data)
    zs, times = df[["x", "y"]].to_numpy(), df["t"].to_numpy()
    lines = []
    for name, path, run in (("filter", filtered, gf.filter), ("smoother", smoothed, gf.smooth)):
        result = run(spec.timed, spec.prior, zs, times=times, check="off")
        out = pd.read_csv(path)
        stds = np.sqrt(np.diagonal(result.covs, axis1=1, axis2=2))
        got = out[["x", "y", "vx", "vy", "std_x", "std_y", "std_vx", "std_vy"]].to_numpy()
        same_times = np.array_equal(out["t"].to_numpy(), times)
        lines.append(f"- {name}: largest difference from `gf.{run.__name__}` on the whole file in memory "
                     f"{np.abs(got - np.column_stack([result.means, stds])).max():.3g} (means and standard "
                     f"deviations); times {'identical' if same_times else 'DIFFERENT'}")
        del result, out
    return "\n".join(lines)


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.machine()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", type=int, default=4_800_000)
    parser.add_argument("--dir", help="where to write the files (default: a temporary directory)")
    parser.add_argument("--out", help="also write the report here")
    parser.add_argument("--write-only", metavar="PATH", help=argparse.SUPPRESS)  # the data, in a child process
    args = parser.parse_args()
    if args.write_only:
        write_data(args.write_only, args.rows)
        return
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        data, model = os.path.join(tmp, "track.csv"), os.path.join(tmp, "cv2d.toml")
        with open(model, "w", encoding="utf-8") as f:
            f.write(MODEL)
        print(f"writing {args.rows:,} rows ...", file=sys.stderr)
        # In a child: a child forked from a large parent would report the parent's size as its own peak.
        subprocess.run([sys.executable, __file__, "--rows", str(args.rows), "--write-only", data], check=True)
        size = os.path.getsize(data) / 1e6
        gaussfuse = [sys.executable, "-m", "gaussfuse", "filter", data, "--model", model]
        runs = {}
        floor_argv = [sys.executable, "-c", FLOOR, data, os.path.join(tmp, "floor.csv")]
        for name, argv in [
            ("I/O floor: pandas read_csv + to_csv", floor_argv),
            ("gaussfuse filter", gaussfuse + ["--out", os.path.join(tmp, "filtered.csv")]),
            ("gaussfuse filter --smooth", gaussfuse + ["--smooth", "--out", os.path.join(tmp, "smoothed.csv")]),
            ("I/O floor again (the machine's drift)", floor_argv),
        ]:
            print(f"{name} ...", file=sys.stderr)
            runs[name] = measure(argv)
        print("checking the outputs ...", file=sys.stderr)
        agreement = check(data, model, os.path.join(tmp, "filtered.csv"), os.path.join(tmp, "smoothed.csv"))
    floor = min(runs["I/O floor: pandas read_csv + to_csv"][0], runs["I/O floor again (the machine's drift)"][0])
    import gaussfuse
    import pandas as pd
    lines = [f"# `gaussfuse filter` on a large file ({args.rows:,} rows, {size:.0f} MB)", "",
             f"`python benchmarks/large_files.py --rows {args.rows}` on {_cpu()}, "
             f"{os.cpu_count()} cores, load average {load:.2f} at start and {os.getloadavg()[0]:.2f} at end; Python {platform.python_version()}, "
             f"gaussfuse {gaussfuse.__version__}, pandas {pd.__version__}.", "",
             "The floor is timed before and after the two commands; the ratios are to the faster of the two.", "",
             "| run | wall (s) | ratio to the I/O floor (goal <= 1.5) | peak memory (MB; goal < 400) |",
             "| --- | ---: | ---: | ---: |"]
    for name, (wall, peak) in runs.items():
        lines.append(f"| {name} | {wall:.1f} | {wall / floor:.2f} | {peak:.0f} |")
    lines += ["", agreement, ""]
    report = "\n".join(lines)
    print(report)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            f.write(report)


if __name__ == "__main__":
    main()
