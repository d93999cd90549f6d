"""Beyond one process: one large Parquet log on a Dask cluster, and a fleet of small logs.

    python -m pip install '.[dask,bench]'
    python benchmarks/bench_scale.py big   [--samples 1e8] [--workers 2] [--repeats 3]
    python benchmarks/bench_scale.py fleet [--logs 1000] [--samples 1e4] [--workers 2]
    python benchmarks/bench_scale.py kept  [--samples 2e6] [--workers 2] [--repeats 3]

big: a log of N samples (1 nT noise, uniform attitudes, no reference) in Parquet files of 10^7
rows each (row groups of 2^20 rows, pyarrow's default). In one run it measures

- read (floor): the time to only read the files, in this process (pyarrow, every column
  read into numpy) and on the cluster (one task per row group that reads it and sums it);
- cluster: `nlpcal calibrate 'DIR/*.parquet' --scheduler local` as library calls on a
  LocalCluster of `--workers` single-threaded worker processes started beforehand: reading
  (the footers: no pass) and calibrating, every pass a Dask reduction over the row groups,
  which are read once and kept in the workers' memory (where they fit, as here);
- cluster-files: the same with `--low-memory`: the log left in its files, every pass reading
  every row group again;
- low-memory: `nlpcal calibrate 'DIR/*.parquet' --low-memory` as library calls in this
  process: the files streamed into a memory-mapped file, then the passes over it in threads;
- memory (up to IN_MEMORY_MOST samples): `read_log` and `calibrate_log` in this process, the
  log in memory;

for each method, and prints medians over the repeats with their range (min-max), the ratios to
the floors, the passes over the files, the largest gap of each path's parameters to the
in-memory path's in standard errors (to --low-memory's above IN_MEMORY_MOST samples, the same
code on a memory map), where the cluster's time goes and the peak memory of a worker.

kept: one log of N samples as one CSV file and as Parquet (row groups of 2^18 rows), each
calibrated jointly with least squares and with Huber's loss on Dask's threads and on a
LocalCluster of `--workers` workers, read once and kept in memory (`read_lazy_log(keep=True)`,
the default where the log fits) and left in its files (keep=False, `--low-memory`): medians
over the repeats with their range, the passes over the data and the ratio of the two.

fleet: `--logs` CSV logs of `--samples` samples, two of them broken on purpose (a non-numeric
cell, no field columns). In one run it measures

- cli loop: `nlpcal calibrate LOG -o LOG.params.json`, one command after another (the shell
  loop a user writes without `batch`): each log pays the start of Python, the imports and the
  building of the CasADi problems;
- python loop: `calibrate_log(read_log(LOG))` and `save`, one log after another in one process;
- batch: `nlpcal batch calibrate DIR --out-dir OUT --scheduler local` as the library call, the
  LocalCluster started within the timing (as the command does), with `--force`;
- batch here: the same batch in this process (no --scheduler);
- python loops side by side: `--workers` python loops at once, each in a process of its own
  over its share of the logs: the best any scheduler of that many processes could do;

and the per-log costs: the median time of one log inside a task, the overhead per log beyond
it, and what a cold process pays first (the imports, the first calibration, which builds the
problems, against the same calibration warm).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import nlpcal
from nlpcal import cluster
from nlpcal.batch import calibrate_many
from nlpcal.calibration import calibrate_log
from nlpcal.io import read_log
from nlpcal.io.lazy import read_lazy_log
from nlpcal.models.zhou2010 import PARAMETER_NAMES
from nlpcal.simulation import simulate

FILE_ROWS = 10_000_000
SIMULATE_ROWS = 1_000_000


def machine() -> str:
    import casadi
    import dask
    import pyarrow

    return (
        f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"numpy {np.__version__}, casadi {casadi.__version__}, dask {dask.__version__}, "
        f"pyarrow {pyarrow.__version__}, nlpcal {nlpcal.__version__}"
    )


def spread(times) -> str:
    """median [min-max] of a list of seconds."""
    return f"{statistics.median(times):.2f} s [{min(times):.2f}-{max(times):.2f}]"


def load() -> str:
    return "load average " + " ".join(f"{v:.2f}" for v in os.getloadavg())


# --- one big log -----------------------------------------------------------------------------


def make_big(folder: Path, n: int) -> list:
    """Parquet files of FILE_ROWS rows with the log's N samples (made once, then reused)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    marker = folder / f"complete-{n}"
    if marker.exists():
        return sorted(folder.glob("*.parquet"))
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    written, k = 0, 0
    while written < n:
        rows = min(FILE_ROWS, n - written)
        with pq.ParquetWriter(
            folder / f"log_{k:04d}.parquet",
            pa.schema([("bx", pa.float64()), ("by", pa.float64()), ("bz", pa.float64())]),
        ) as writer:
            for start in range(0, rows, SIMULATE_ROWS):
                size = min(SIMULATE_ROWS, rows - start)
                part = simulate(size, noise=1.0, seed=written + start)
                writer.write_table(pa.Table.from_pandas(part, preserve_index=False))
        written += rows
        k += 1
    marker.write_text("")
    return sorted(folder.glob("*.parquet"))


def read_here(paths) -> float:
    """Read every column of every file into numpy in this process. [s]"""
    import pyarrow.parquet as pq

    started = time.perf_counter()
    total = 0.0
    for path in paths:
        table = pq.read_table(path)
        total += sum(float(table.column(k).to_numpy().sum()) for k in range(table.num_columns))
    assert np.isfinite(total)
    return time.perf_counter() - started


def _read_row_group(path, index) -> float:
    import pyarrow.parquet as pq

    table = pq.ParquetFile(path).read_row_group(index)
    return sum(float(table.column(k).to_numpy().sum()) for k in range(table.num_columns))


def read_on_cluster(paths) -> float:
    """One task per row group that reads it into numpy and sums it, on the current cluster. [s]"""
    import dask
    import pyarrow.parquet as pq

    started = time.perf_counter()
    tasks = [
        dask.delayed(_read_row_group)(str(path), i)
        for path in paths
        for i in range(pq.ParquetFile(path).metadata.num_row_groups)
    ]
    assert np.isfinite(sum(dask.compute(*tasks)))
    return time.perf_counter() - started


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


#: Above this many samples the in-memory path is left out (a 10^8 log takes 2.4 GB as one
#: array and several times that while pandas reads it): the cluster is compared with
#: --low-memory, which runs the same in-process code on a memory map.
IN_MEMORY_MOST = 30_000_000


def run_path(path: str, pattern: str, method: str) -> tuple:
    """(seconds, of which reading, result, passes over the data or None, timings) of one
    calibration: "cluster" (read_lazy_log on the current cluster, the row groups kept in its
    memory), "cluster-files" (left in the files), "low-memory" or "memory"."""
    started = time.perf_counter()
    lazy = path.startswith("cluster")
    if lazy:
        log = read_lazy_log(pattern, keep=path == "cluster")
    else:
        log = read_log(pattern, low_memory=path == "low-memory")
    read_s = time.perf_counter() - started
    result = calibrate_log(log, method=method)
    total = time.perf_counter() - started
    passes = log.samples.passes if lazy else None
    timings = list(log.samples.timings) if lazy else []
    del log
    return total, read_s, result, passes, timings


def largest_gap(result, peer) -> float:
    """The largest difference of two results' parameters, in the peer's standard errors (at
    the joint optimum for a staged result that states none). [SE]"""
    errors = peer.standard_errors or peer.identifiability.get("standard_errors_at_joint_optimum")
    return max(abs(result.parameters[k] - peer.parameters[k]) / errors[k] for k in PARAMETER_NAMES)


def bench_big(args) -> None:
    n = int(args.samples)
    folder = Path(args.data_dir) / f"big-{n:.0e}"
    started = time.perf_counter()
    paths = make_big(folder, n)
    pattern = str(folder / "*.parquet")
    size = sum(p.stat().st_size for p in paths) / 2**30
    print(f"# {n:.0e} samples in {len(paths)} Parquet files, {size:.2f} GiB ({load()})")
    print(f"# data ready in {time.perf_counter() - started:.0f} s", flush=True)
    from nlpcal import compiled

    kernel = "compiled (numba)" if compiled.use(n) else "numpy"
    print(f"# moment pass kernel: {kernel} (the first repeat pays each worker's load)")
    baseline = "memory" if n <= IN_MEMORY_MOST else "low-memory"
    routes = [
        "cluster",
        "cluster-files",
        "low-memory",
        *(["memory"] if baseline == "memory" else []),
    ]
    started = time.perf_counter()
    times: dict = {}
    results: dict = {}
    splits: dict = {}
    with cluster.scheduler("local", workers=args.workers) as client:  # as --scheduler local
        print(
            f"# LocalCluster of {args.workers} workers up in {time.perf_counter() - started:.1f} s",
            flush=True,
        )
        for repeat in range(args.repeats):
            times.setdefault("read here", []).append(read_here(paths))
            times.setdefault("read cluster", []).append(read_on_cluster(paths))
            for method in args.methods:
                for path in routes:
                    total, read_s, result, passes, timings = run_path(path, pattern, method)
                    key = f"{path} {method}"
                    times.setdefault(key, []).append(total)
                    times.setdefault(f"{key} read", []).append(read_s)
                    results[key] = (result, passes)
                    if path.startswith("cluster"):
                        splits.setdefault(key, []).append((total, timings))
            print(f"# repeat {repeat + 1} done ({load()})", flush=True)
        worker_peak = client.run(_peak_rss_mib)
    print_big(args, n, times, results, baseline, routes)
    print_splits(splits)
    print(
        f"\npeak memory of the workers: "
        f"{', '.join(f'{v:.0f} MiB' for v in worker_peak.values())}; data {size:.2f} GiB"
    )
    print(f"staged cycles: {len(results[f'cluster {args.methods[-1]}'][0].statistics) - 1}")


def print_big(args, n: int, times: dict, results: dict, baseline: str, routes: list) -> None:
    """The table of `bench_big`: per path and method the time, its ratios to the reads, the
    passes over the files and the largest gap to the `baseline` path's parameters."""
    floor_here = statistics.median(times["read here"])
    floor_cluster = statistics.median(times["read cluster"])
    print(f"\n## {n:.0e} samples, medians over {args.repeats} repeats [min-max]\n")
    print(f"| what | time | / read here | / read on cluster | passes | largest gap to {baseline} |")
    print("|---|---|---|---|---|---|")
    for name in ("read here", "read cluster"):
        median = statistics.median(times[name])
        print(
            f"| {name} | {spread(times[name])} | {median / floor_here:.2f} | "
            f"{median / floor_cluster:.2f} | 1 | |"
        )
    for method in args.methods:
        for path in routes:
            key = f"{path} {method}"
            result, passes = results[key]
            peer = results[f"{baseline} {method}"][0]
            gap = "" if path == baseline else f"{largest_gap(result, peer):.1e} SE"
            median = statistics.median(times[key])
            print(
                f"| {key} (read {spread(times[key + ' read'])}) | {spread(times[key])} | "
                f"{median / floor_here:.2f} | {median / floor_cluster:.2f} | "
                f"{passes if passes is not None else ''} | {gap} |"
            )


def print_splits(splits: dict) -> None:
    """Where the time of the median cluster run of each path and method goes: its passes (and
    reads of the first block, the reading kept), and the rest (the solves, the diagnostics,
    the scheduling)."""
    for key, runs in splits.items():
        total, timings = sorted(runs, key=lambda run: run[0])[len(runs) // 2]
        parts: dict = {}
        for what, seconds in timings:
            count, spent = parts.get(what, (0, 0.0))
            parts[what] = (count + 1, spent + seconds)
        rest = total - sum(spent for _, spent in parts.values())
        shares = ", ".join(
            f"{what} x{count} {spent:.2f} s" for what, (count, spent) in parts.items()
        )
        print(f"\n{key}, where the time goes: {shares}, solves and the rest {rest:.2f} s")


# --- a log kept in memory ---------------------------------------------------------------------

#: Rows per Parquet row group of the `kept` case: 2^18, so that a log of 2 x 10^6 samples has
#: eight blocks, as the CSV log has in blocks of 16 MiB.
KEPT_ROW_GROUP = 2**18
#: Bytes per block of the `kept` case's CSV log. [byte]
KEPT_BLOCK_BYTES = 16 * 2**20


def make_kept(folder: Path, n: int) -> tuple:
    """(CSV path, Parquet path) of one log of n samples, 1 nT noise (made once)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    text, table = folder / "log.csv", folder / "log.parquet"
    marker = folder / f"complete-{n}"
    if not marker.exists():
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        frame = simulate(n, noise=1.0, seed=11)
        frame.to_csv(text, index=False)
        pq.write_table(
            pa.Table.from_pandas(frame, preserve_index=False), table, row_group_size=KEPT_ROW_GROUP
        )
        marker.write_text("")
    return text, table


def run_kept(path: Path, loss: str, keep: bool) -> tuple:
    """(seconds, passes over the data) of reading and calibrating one log jointly on the
    current scheduler."""
    started = time.perf_counter()
    log = read_lazy_log(str(path), keep=keep, block_bytes=KEPT_BLOCK_BYTES)
    calibrate_log(log, method="joint", loss=loss)
    seconds = time.perf_counter() - started
    return seconds, log.samples.passes


def bench_kept(args) -> None:
    n = int(args.samples)
    paths = make_kept(Path(args.data_dir) / f"kept-{n:.0e}", n)
    print(
        f"# {n:.0e} samples, CSV {paths[0].stat().st_size / 2**20:.0f} MiB, Parquet "
        f"{paths[1].stat().st_size / 2**20:.0f} MiB ({load()})"
    )
    print(
        f"\n## read once and kept, or read in every pass: medians over {args.repeats} "
        "repeats [min-max]\n"
    )
    print("| log | scheduler | loss | passes kept / files | kept | in its files | files / kept |")
    print("|---|---|---|---|---|---|---|")
    for scheduler in ("threads", "local"):
        with cluster.scheduler(scheduler, workers=args.workers):
            for path in paths:
                for loss in ("l2", "huber"):
                    run_kept(path, loss, False)  # the first run pays the loads
                    times: dict = {True: [], False: []}
                    passes: dict = {}
                    for _ in range(args.repeats):
                        for keep in (True, False):
                            seconds, passes[keep] = run_kept(path, loss, keep)
                            times[keep].append(seconds)
                    ratio = statistics.median(times[False]) / statistics.median(times[True])
                    print(
                        f"| {path.suffix[1:]} | {scheduler} | {loss} | "
                        f"{passes[True]} / {passes[False]} | "
                        f"{spread(times[True])} | {spread(times[False])} | {ratio:.2f} |",
                        flush=True,
                    )


# --- a fleet ----------------------------------------------------------------------------------


def make_fleet(folder: Path, logs: int, n: int) -> list:
    """`logs` CSV logs of n samples, the first and the middle one broken (made once)."""
    marker = folder / f"complete-{logs}-{n}"
    if not marker.exists():
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        for k in range(logs):
            simulate(n, noise=1.0, seed=k).to_csv(folder / f"sensor_{k:05d}.csv", index=False)
        (folder / "sensor_00000.csv").write_text("bx,by,bz\n1,2,3\n4,five,6\n")
        (folder / f"sensor_{logs // 2:05d}.csv").write_text("time,temperature\n0,21.5\n")
        marker.write_text("")
    return sorted(folder.glob("*.csv"))


def python_loop(paths, out: Path) -> tuple:
    """calibrate_log per log in this process; (total s, per-log seconds)."""
    each = []
    started = time.perf_counter()
    for path in paths:
        begun = time.perf_counter()
        with contextlib.suppress(nlpcal.errors.NlpcalError):
            calibrate_log(read_log(path)).save(out / f"{path.stem}.params.json")
        each.append(time.perf_counter() - begun)
    return time.perf_counter() - started, each


def cli_loop(paths, out: Path) -> tuple:
    """`nlpcal calibrate LOG -o ...` per log, one process each; (total s, per-log seconds)."""
    each = []
    started = time.perf_counter()
    for path in paths:
        begun = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "nlpcal",
                "calibrate",
                str(path),
                "-q",
                "-o",
                str(out / f"{path.stem}.params.json"),
            ],
            check=False,
        )
        each.append(time.perf_counter() - begun)
    return time.perf_counter() - started, each


def cold_costs(path) -> dict:
    """What a fresh process pays before its first log: the imports, then the first calibration
    of a fleet log (which builds the CasADi problems), against the same calibration warm. [s]"""
    code = (
        "import sys, time; t=time.perf_counter(); import nlpcal.calibration, nlpcal.io; "
        "t1=time.perf_counter(); log=nlpcal.io.read_log(sys.argv[1]); t2=time.perf_counter(); "
        "nlpcal.calibration.calibrate_log(log); t3=time.perf_counter(); "
        "nlpcal.calibration.calibrate_log(log); t4=time.perf_counter(); "
        "print(t1-t, t3-t2, t4-t3)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True
    )
    imports, first, warm = (float(v) for v in out.stdout.split())
    return {"imports": imports, "first calibration": first, "warm calibration": warm}


def _half_loop(paths, out: str) -> None:
    python_loop([Path(p) for p in paths], Path(out))


def side_by_side(paths, out: Path, workers: int) -> float:
    """`workers` python loops side by side, each over its share of the logs, in processes of
    their own: what any scheduler of `workers` processes could do at best. [s]"""
    from concurrent.futures import ProcessPoolExecutor

    shares = [[str(p) for p in paths[k::workers]] for k in range(workers)]
    started = time.perf_counter()
    with ProcessPoolExecutor(workers) as pool:
        list(pool.map(_half_loop, shares, [str(out)] * workers))
    return time.perf_counter() - started


def bench_fleet(args) -> None:
    logs, n = int(args.logs), int(args.samples)
    folder = Path(args.data_dir) / f"fleet-{logs}x{n:.0e}"
    paths = make_fleet(folder, logs, n)
    print(f"# {logs} CSV logs of {n:.0e} samples, 2 broken ({load()})", flush=True)
    scratch = Path(tempfile.mkdtemp(prefix="nlpcal-fleet-"))
    times: dict = {}
    per_log: dict = {}
    try:
        for repeat in range(args.repeats):
            for name in ("batch", "batch here", "python loop", "python loops side by side"):
                out = scratch / f"{name.replace(' ', '-')}-{repeat}"
                out.mkdir()
                started = time.perf_counter()
                if name == "python loop":
                    _, each = python_loop(paths, out)
                elif name == "python loops side by side":
                    side_by_side(paths, out, args.workers)
                    each = []
                else:
                    report = calibrate_many(
                        folder,
                        out,
                        force=True,
                        scheduler="local" if name == "batch" else None,
                        workers=args.workers,
                    )
                    each = [row["seconds"] for row in report.rows]
                    assert report.counts().get("bad-input") == 2 and len(report.rows) == logs
                    assert len(list(out.glob("*.params.json"))) == logs - 2
                times.setdefault(name, []).append(time.perf_counter() - started)
                per_log.setdefault(name, []).extend(each)
                print(
                    f"# {name} repeat {repeat + 1}: {times[name][-1]:.1f} s ({load()})", flush=True
                )
        chosen = paths[: args.cli_loop] if args.cli_loop else paths
        out = scratch / "cli"
        out.mkdir()
        total, each = cli_loop(chosen, out)
        per_log["cli loop"] = each
        times["cli loop"] = [total * len(paths) / len(chosen)]
        print(f"# cli loop over {len(chosen)} logs: {total:.1f} s ({load()})", flush=True)
        costs = cold_costs(paths[1])
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    cli = times["cli loop"][0]
    loop = statistics.median(times["python loop"])
    scaled = "" if len(chosen) == len(paths) else f" (scaled from {len(chosen)} logs)"
    print(
        f"\n## {logs} logs of {n:.0e} samples, {args.workers} workers, medians over "
        f"{args.repeats} repeats [min-max]\n"
    )
    print("| what | total | / cli loop | / python loop | per log, median [p10-p90] |")
    print("|---|---|---|---|---|")
    for name in ("cli loop", "python loop", "batch here", "python loops side by side", "batch"):
        median = statistics.median(times[name])
        each = np.array(per_log[name])
        cell = spread(times[name]) if len(times[name]) > 1 else f"{median:.1f} s"
        cell += scaled if name == "cli loop" else ""
        within = (
            f"{np.median(each) * 1e3:.0f} ms [{np.percentile(each, 10) * 1e3:.0f}-"
            f"{np.percentile(each, 90) * 1e3:.0f}]"
            if len(each)
            else ""
        )
        print(f"| {name} | {cell} | {median / cli:.3f} | {median / loop:.2f} | {within} |")
    batch = statistics.median(times["batch"])
    in_task = statistics.median(per_log["batch"])
    command = statistics.median(per_log["cli loop"]) - in_task
    print(
        f"\nper-log overhead: the command loop {command:.3f} s per log beyond the calibration; "
        f"the batch "
        f"{batch * args.workers / logs - in_task:.4f} s per log (its wall time times the workers "
        f"per log, less the median time of a log inside its task)"
    )
    print(
        f"\ncold process: imports {costs['imports']:.2f} s, first calibration (builds the "
        f"problems) {costs['first calibration']:.2f} s, the same calibration warm "
        f"{costs['warm calibration'] * 1e3:.0f} ms"
    )


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", choices=("big", "fleet", "kept"))
    parser.add_argument(
        "--samples", type=float, help="samples of the log (big: 1e8, fleet: 1e4, kept: 2e6)"
    )
    parser.add_argument("--logs", type=float, default=1000, help="fleet: logs")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--methods", nargs="+", default=["joint", "staged"])
    parser.add_argument(
        "--cli-loop",
        type=int,
        default=0,
        help="fleet: run the command loop on this many logs "
        "only and scale its total (default: all)",
    )
    parser.add_argument(
        "--data-dir",
        default=str(Path(tempfile.gettempdir()) / "nlpcal-bench-scale"),
        help="where the generated logs are kept between runs",
    )
    args = parser.parse_args(argv)
    if args.samples is None:
        args.samples = {"big": 1e8, "fleet": 1e4, "kept": 2e6}[args.case]
    print(f"# machine: {machine()}")
    print(f"# {cluster.describe('local')} of {args.workers} workers")
    {"big": bench_big, "fleet": bench_fleet, "kept": bench_kept}[args.case](args)


if __name__ == "__main__":
    main()
