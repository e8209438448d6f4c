"""W2 scaled up on a Dask cluster: many series filtered chunk by chunk, against the in-process batch path.

    python benchmarks/many_series.py [--series 200000] [--steps 200] [--chunk 10000] [--out benchmarks/many_series.md]

The workload is W2's model (a 1-D constant-velocity target, 2 states, 1
position measurement; ``gf.constant_velocity(0.1, 1.0, 0.25)``), on
`--series` random-walk series of `--steps` steps, filtered with
``keep="last"`` (the last belief and the log-likelihood of each series: what
travels back is small, as when each chunk's estimates are written where it
runs). Rows, each timed once after a warm-up run on a small input (workers
load the compiled kernels from numba's cache, the client imports), best of
`--repeats`:

* **in-process**: ``gf.filter`` on the NumPy array (the compiled batch kernel,
  parallel over the machine's cores);
* **dask, 1 worker** and **dask, 2 workers**: ``gf.filter`` on a dask array of
  the same values, chunked by `--chunk` series, on a ``LocalCluster`` of
  worker processes with one thread each; the measurements are generated on
  the workers (a seeded ``dask.array`` random walk), so that only the
  results travel.

Each row reports steps per second (series x steps), the ratio to the
in-process row, and the peak resident memory of each worker process
(``ru_maxrss``, read on the worker). The results are checked against the
in-process ones (the last means and the log-likelihoods, to the last bit).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
import warnings

import numpy as np


def measurements(series: int, steps: int, chunk: int):
    import dask.array as da

    rng = da.random.default_rng(0)
    return rng.normal(size=(series, steps, 1), chunks=(chunk, steps, 1)).cumsum(axis=1) * 0.3


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--series", type=int, default=200_000)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--chunk", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", help="also write the report here")
    args = parser.parse_args()

    import dask
    import distributed

    import gaussfuse as gf

    model = gf.constant_velocity(0.1, 1.0, 0.25)
    prior = gf.Gaussian([0.0, 0.0], 10.0 * np.eye(2))
    N, T = args.series, args.steps
    lazy = measurements(N, T, args.chunk)
    load = os.getloadavg()[0]
    print(f"{N:,} series x {T} steps, chunks of {args.chunk:,} series", file=sys.stderr)
    with dask.config.set(scheduler="threads"):
        zs = lazy.compute()
    gf.filter(model, prior, zs[:8], engine="numba", keep="last", check="off")  # compile or load the kernels
    best = np.inf
    for _ in range(args.repeats):
        start = time.perf_counter()
        want = gf.filter(model, prior, zs, engine="numba", keep="last", check="off")
        best = min(best, time.perf_counter() - start)
    rows = [("in-process (NumPy array, compiled batch kernel)", best, None)]
    del zs
    for workers in (1, 2):
        print(f"dask, {workers} worker(s) ...", file=sys.stderr)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                               dashboard_address=None, silence_logs=50)
        with distributed.Client(cluster) as client:
            small = gf.filter(model, prior, measurements(8 * workers, 3, 8), engine="numba", keep="last", check="off")
            dask.compute(small.loglik)  # warm-up: imports and kernels on every worker
            best = np.inf
            for _ in range(args.repeats):
                res = gf.filter(model, prior, lazy, engine="numba", keep="last", check="off")
                start = time.perf_counter()
                last, loglik = dask.compute(res.last_mean, res.loglik)
                best = min(best, time.perf_counter() - start)
            peaks = sorted(client.run(peak_mb).values())
            same = np.array_equal(last, want.last_mean) and np.array_equal(loglik, want.loglik)
        cluster.close()
        rows.append((f"dask, {workers} worker process{'es' if workers > 1 else ''}", best, (peaks, same)))
    steps = N * T
    base = rows[0][1]
    import gaussfuse
    lines = [f"# Many series on a Dask cluster: {N:,} series x {T} steps (W2's model)", "",
             f"`python benchmarks/many_series.py --series {N} --steps {T} --chunk {args.chunk}` on "
             f"{platform.machine()}, {os.cpu_count()} cores, load average {load:.2f} at start and "
             f"{os.getloadavg()[0]:.2f} at end; gaussfuse {gaussfuse.__version__}, dask {dask.__version__}, "
             f"distributed {distributed.__version__}. Best of {args.repeats}.", "",
             "| run | seconds | M steps/s | ratio to in-process | peak memory per worker (MB) | equal to in-process |",
             "| --- | ---: | ---: | ---: | --- | --- |"]
    for name, seconds, extra in rows:
        peaks, same = extra if extra else ([], True)
        lines.append(f"| {name} | {seconds:.2f} | {steps / seconds / 1e6:.2f} | {base / seconds:.2f} | "
                     f"{', '.join(f'{p:.0f}' for p in peaks) or '-'} | {'yes' if same else 'NO'} |")
    report = "\n".join(lines) + "\n"
    print(report)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            f.write(report)


if __name__ == "__main__":
    main()
