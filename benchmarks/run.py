"""Side-by-side benchmarks of gaussfuse against filterpy, pykalman, simdkalman and statsmodels.

    python benchmarks/run.py [--quick] [--only W1,W5] [--skip pykalman] [--out benchmarks/results.md]

Every library runs on identical inputs; its results are checked against
gaussfuse (relative difference <= 1e-8, see README.md) and the script exits
with status 1 if any check fails or any entry raises. Timings are the best of
a few repeats (time.perf_counter, garbage collector off while timing), after
one untimed warm-up call on a small input, which for numba entries is where
compilation (or loading from numba's cache) happens.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import shlex
import sys
import time
import traceback
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import gaussfuse as gf  # noqa: E402
import workloads  # noqa: E402

RTOL = 1e-8  # max |ours - theirs| / max |ours|, for means and covariances separately


# ---------------------------------------------------------------------------
# Machine and versions
# ---------------------------------------------------------------------------


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def load() -> str:
    try:
        return "{:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    except OSError:
        return "unknown"


def machine_lines() -> list[str]:
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    lines = [
        f"- CPU: {cpu_model()}; nproc {usable} (os.cpu_count() {os.cpu_count()})",
        f"- OS: {platform.platform()}",
        f"- Python {platform.python_version()}; numpy {np.__version__}; scipy {version('scipy')}; "
        f"numba {version('numba')}; gaussfuse {gf.__version__}",
        "- peers: " + "; ".join(f"{p} {version(p)}" for p in workloads.PEERS),
    ]
    try:
        from gaussfuse._kernels._jit import threads

        lines.append(f"- threads a batch of series runs on: {threads()} (NUMBA_NUM_THREADS)")
    except ImportError:
        pass
    return lines


# ---------------------------------------------------------------------------
# Timing and checking
# ---------------------------------------------------------------------------


@dataclass
class Row:
    workload: str
    entry: workloads.Entry
    seconds: float | None = None
    runs: int = 0
    warmup: float | None = None
    diffs: dict | None = None       # key -> (max abs diff, relative)
    is_reference: bool = False
    error: str | None = None
    ratio: float | None = None
    goal_text: str = ""
    problem: str | None = None      # timed, but not what the row claims (fails the run)

    @property
    def speed(self) -> float | None:
        return None if self.seconds is None else self.entry.steps / self.seconds

    @property
    def ok(self) -> bool:
        return self.error is None and self.problem is None and all(rel <= RTOL for _, rel in (self.diffs or {}).values())


def timed(fn, n):
    gc.collect()
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        t0 = time.perf_counter()
        out = fn(n)
        return time.perf_counter() - t0, out
    finally:
        if was_enabled:
            gc.enable()


def compare(out: dict, ref: dict) -> dict:
    diffs = {}
    for key in ("means", "covs"):
        if out.get(key) is None:
            continue
        a, b = np.asarray(out[key], dtype=float), ref[key]
        if a.shape != b.shape:
            raise ValueError(f"`{key}` has shape {a.shape}; gaussfuse's has {b.shape}")
        d = float(np.max(np.abs(a - b)))
        scale = float(np.max(np.abs(b)))
        diffs[key] = (d, d / scale if scale > 0 else d)
    return diffs


def check_mode(entry) -> str | None:
    """For sigma-point numba entries: does the engine run in the mode the row is about?

    The compiled engine falls back from its fully compiled loop to a Python
    loop when f and h do not fit it; a silent fallback would time the wrong
    thing, so it fails the run.
    """
    mode = entry.run.actual_mode()
    if mode == entry.mode:
        return None
    return f"engine runs in its {mode!r} mode, not {entry.mode!r}"


def _failure(row: Row, exc: Exception) -> None:
    row.error = " ".join(f"{type(exc).__name__}: {exc}".split())[:300].replace("|", "\\|")
    traceback.print_exc(file=sys.stderr)


def run_workload(wl: workloads.Workload, sizes: workloads.Sizes) -> list[Row]:
    """Warm every entry up, then time them in rounds, one run of each per round.

    Interleaving the repeats makes every entry see the same machine: a burst
    of load from elsewhere then slows one run of each rather than all runs of
    one, and the best-of-N ratios stay fair. The first timed run's output is
    checked (against the reference row's output when it is the reference).
    """
    rows = [Row(wl.key, e, is_reference=e.label == wl.reference_label) for e in wl.entries]
    # What exists now (modules, the workload's data) lives to the end: moved out of the collector's view, so that
    # the collection before each timed run scans only what the runs made (a full one took 0.2 s, 16 of 23 s of W5's
    # quick run on a slow machine).
    gc.collect()
    gc.freeze()
    order = sorted(rows, key=lambda r: not r.is_reference)  # the reference first: it seeds the cache
    times: dict[int, list[float]] = {id(r): [] for r in rows}
    for row in order:
        try:
            row.warmup, _ = timed(row.entry.run, min(sizes.warmup, row.entry.n))
        except Exception as exc:  # report and carry on: the exit status says it failed
            _failure(row, exc)
    for _ in range(sizes.repeats):
        for row in order:
            done = times[id(row)]
            if row.error or (done and sum(done) >= sizes.budget):
                continue
            try:
                t, out = timed(row.entry.run, row.entry.n)
                done.append(t)
                if len(done) == 1:
                    if row.entry.mode is not None:
                        row.problem = check_mode(row.entry)
                    if row.is_reference:
                        wl.reference.cache[row.entry.n] = out
                    row.diffs = compare(out, wl.reference(row.entry.n))
                del out
            except Exception as exc:
                _failure(row, exc)
    for row in rows:
        done = times[id(row)]
        if done and not row.error:
            row.seconds, row.runs = min(done), len(done)
    return rows


def assess(wl: workloads.Workload, rows: list[Row], primary_engine_ok: bool, quick: bool) -> None:
    """Fill in ratios and goals."""
    by_label = {r.entry.label: r for r in rows}
    if wl.peer is None:  # W1-W3: the primary gaussfuse row against every other row
        primary = by_label.get(wl.primary)
        for r in rows:
            if r is not primary and r.speed and primary is not None and primary.speed:
                r.ratio = primary.speed / r.speed
    else:  # W4: every gaussfuse row against the peer
        peer = by_label.get(wl.peer)
        for r in rows:
            if r.entry.library == "gaussfuse" and r.speed and peer is not None and peer.speed:
                r.ratio = r.speed / peer.speed
    groups: dict[str, list[Row]] = {}
    for r in rows:
        if r.entry.goal is not None:
            groups.setdefault(r.entry.goal_group or r.entry.label, []).append(r)
    for members in groups.values():
        timed_ = [r for r in members if r.speed]
        counted = max(timed_, key=lambda r: r.speed) if timed_ else members[0]
        for r in members:
            if r is not counted:
                r.goal_text = "(slower variant; the faster one counts)"
                continue
            goal = r.entry.goal
            if r.ratio is None:
                r.goal_text = f">= {goal:g}x: not measured"
            elif not primary_engine_ok:
                r.goal_text = f">= {goal:g}x: n/a (numba engine unavailable)"
            else:
                r.goal_text = f">= {goal:g}x: {'met' if r.ratio >= goal else 'NOT MET'}"
                if quick:
                    r.goal_text += " (quick sizes: not a measurement)"


# ---------------------------------------------------------------------------
# Output
# ---------------------------------------------------------------------------


def fmt_speed(s: float | None) -> str:
    if s is None:
        return "-"
    if s >= 1e6:
        return f"{s / 1e6:.2f} M"
    if s >= 1e3:
        return f"{s / 1e3:.1f} k"
    return f"{s:.0f}"


def fmt_diff(r: Row, key: str) -> str:
    if r.is_reference:
        return "reference"
    if not r.diffs or key not in r.diffs:
        return "-"
    d, rel = r.diffs[key]
    flag = "" if rel <= RTOL else " **MISMATCH**"
    return f"{d:.1e} (rel {rel:.0e}){flag}"


def table(rows: list[Row]) -> list[str]:
    out = ["| workload | library / engine | steps timed | steps/s | ratio | max abs diff, means "
           "| max abs diff, covs | goal |",
           "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in rows:
        e = r.entry
        if r.error:
            out.append(f"| {r.workload} | {e.label} | {e.steps:,} | ERROR | - | {r.error} | - | "
                       f"{r.goal_text} |")
            continue
        timedn = f"{e.steps:,}" + (f" ({e.note})" if e.note else "")
        label = e.label + (f" **({r.problem})**" if r.problem else "")
        ratio = "-" if r.ratio is None else f"{r.ratio:.1f}x"
        out.append(f"| {r.workload} | {label} | {timedn} | {fmt_speed(r.speed)} | {ratio} "
                   f"| {fmt_diff(r, 'means')} | {fmt_diff(r, 'covs')} | {r.goal_text} |")
    return out


def warmup_lines(rows: list[Row]) -> list[str]:
    return [f"- {r.workload} {r.entry.label}: {r.warmup:.2f} s"
            for r in rows if r.entry.compiled and r.warmup is not None]


# ---------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------


def probe_numba() -> tuple[bool, bool, list[str]]:
    """Whether engine="numba" works for "kf" and for "ukf"; messages for the report."""
    notes = []
    ok = {}
    model = gf.constant_velocity(dt=1.0, q=1.0, r=1.0)
    prior = gf.Gaussian([0.0, 0.0], np.eye(2))
    nl = gf.NonlinearModel(lambda x: model.F @ x, lambda x: x[:1], model.Q, model.R)
    for name, call in (("kf", lambda: gf.filter(model, prior, np.ones(3), engine="numba")),
                       ("ukf", lambda: gf.filter(nl, prior, np.ones(3), engine="numba"))):
        try:
            t0 = time.perf_counter()
            call()
            ok[name] = True
            notes.append(f"- engine=\"numba\" for {name!r}: available "
                         f"(first call, compile or cache load: {time.perf_counter() - t0:.2f} s)")
        except Exception as exc:
            ok[name] = False
            message = " ".join(str(exc).split())[:300]
            notes.append(f"- engine=\"numba\" for {name!r}: UNAVAILABLE ({type(exc).__name__}: {message}); "
                         "its rows fall back to engine=\"python\" and this run fails")
    return ok["kf"], ok["ukf"], notes


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, seconds)")
    ap.add_argument("--only", default="", help="comma-separated workloads, e.g. W1,W4")
    ap.add_argument("--skip", default="", help="comma-separated peer libraries to leave out")
    ap.add_argument("--out", type=Path, default=None, help="also write the markdown report here")
    given = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(given)

    sizes = workloads.QUICK if args.quick else workloads.FULL
    keys = [k.strip().upper() for k in args.only.split(",") if k.strip()] or list(workloads.BUILDERS)
    unknown = [k for k in keys if k not in workloads.BUILDERS]
    if unknown:
        ap.error(f"unknown workload(s) {unknown}; choose from {list(workloads.BUILDERS)}")
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    bad = skip - set(workloads.PEERS)
    if bad:
        ap.error(f"--skip takes peer libraries {list(workloads.PEERS)}; got {sorted(bad)}")

    started = time.perf_counter()
    load_before = load()
    report = ["# gaussfuse benchmarks", "",
              f"Command: `{shlex.join(['python', 'benchmarks/run.py', *given])}`"
              f" ({'quick sizes: a smoke test, not a measurement' if args.quick else 'full sizes'}), "
              f"{time.strftime('%Y-%m-%d %H:%M %Z')}", "", "## Machine", "", *machine_lines(),
              f"- load average (1, 5, 15 min) at start: {load_before}", ""]
    print("\n".join(report), flush=True)

    avail, peer_notes = {}, []
    for p in workloads.PEERS:
        avail[p], why = workloads.peer_available(p, skip)
        peer_notes.append(f"- {p}: {'used' if avail[p] else 'NOT USED, ' + why + '; its rows are omitted'}")
    kf_ok, ukf_ok, engine_notes = probe_numba()
    setup = ["## Setup", "", *peer_notes, *engine_notes, ""]
    print("\n".join(setup), flush=True)
    report += setup

    all_rows, descriptions, failed = [], [], not (kf_ok and ukf_ok)
    for key in keys:
        engine = "numba" if (ukf_ok if key == "W4" else kf_ok) else "python"
        built = workloads.BUILDERS[key](sizes, avail, engine)
        for wl in built if isinstance(built, list) else [built]:  # W5: one workload per state dimension
            descriptions.append(f"- **{wl.key}** ({wl.title}): {wl.description}.")
            rows = run_workload(wl, sizes)
            for row in rows:
                entry = row.entry
                status = row.error or (f"{fmt_speed(row.speed)} steps/s (best of {row.runs}); "
                                       f"diff means {fmt_diff(row, 'means')}, covs {fmt_diff(row, 'covs')}"
                                       + (f"; PROBLEM: {row.problem}" if row.problem else ""))
                print(f"  {wl.key} {entry.label}: {status}", file=sys.stderr, flush=True)
            assess(wl, rows, engine == "numba", args.quick)
            failed |= not all(r.ok for r in rows)
            all_rows += rows

    body = ["## Results", "",
            "steps/s: measurement steps per second (W2: series x steps), best of up to "
            f"{sizes.repeats} timed runs (fewer when the runs took over {sizes.budget:g} s), "
            "after one untimed warm-up call on a small input; the runs of a workload's entries "
            "are interleaved (one of each per round). Ratio: W1-W3 and W5, gaussfuse's "
            "engine=\"numba\" row ÷ this row; W4, this row ÷ filterpy. Differences are against "
            f"gaussfuse on the same input (relative = max abs diff ÷ max abs value; must be <= {RTOL:g}).",
            "", *table(all_rows), "", "Workloads:", "", *descriptions, "",
            "Warm-up calls of the numba entries (compilation, or loading from numba's on-disk "
            "cache; excluded from the timings):", "", *(warmup_lines(all_rows) or ["- none"]), "",
            f"Load average at end (this run included): {load()}; wall time {time.perf_counter() - started:.0f} s.", "",
            f"Result: {'FAILED (a check failed, an entry raised, an engine is unavailable or ran in the wrong mode)' if failed else 'all checks passed'}.",
            ""]
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(report + body), encoding="utf-8")
    print("\n".join(body), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
