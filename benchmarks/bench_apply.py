"""A large log through `nlpcal calibrate` and `nlpcal apply`: peak memory, time, output size.

    python benchmarks/bench_apply.py --rows 10000000           # the figures of docs/performance.md
    python benchmarks/bench_apply.py --rows 200000 --repeats 3  # a quick look

The log is written as `nlpcal simulate` writes one (10 significant digits, about 37 bytes a row)
into a temporary folder. Every measurement runs in a fresh process, its peak resident memory
and CPU time taken from the kernel when it ends (wait4: a child started by vfork inherits the
peak of this process, which therefore never reads a big file), its stderr on a pseudo-terminal
as a user's would be (so the progress lines are drawn, and counted):

- reading the log in memory (`read_log`) and chunked into a memory map (`low_memory=True`,
  calibrate's default reading): seconds and peak memory, and their ratios;
- `nlpcal calibrate LOG`: seconds, peak memory;
- `nlpcal apply PARAMS LOG -o out.csv` and `-o out.parquet`: seconds, peak memory, the output's
  size as a multiple of the input's, whether the file is Parquet, whether progress was drawn.

Each figure is the median over --repeats runs, with the spread (min-max). The machine's other
load changes the seconds, not the memory: compare ratios of runs made together.
"""

from __future__ import annotations

import argparse
import os
import pty
import select
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

READ = (
    "import sys; from nlpcal.io import read_log; "
    "log = read_log(sys.argv[1], low_memory=sys.argv[2] == 'lean'); print(log.n)"
)


def measured(argv: list) -> dict:
    """Run `argv` with stderr on a pseudo-terminal: its seconds, peak memory [MB], exit status
    and what its terminal showed."""
    master, slave = pty.openpty()
    started = time.perf_counter()
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    shown = b""
    while True:
        ready, _, _ = select.select([master], [], [], 0.5)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                chunk = b""
            if not chunk:
                break
            shown += chunk
        elif process.poll() is not None:
            break
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - started
    os.close(master)
    text = shown.decode(errors="replace")
    return {
        "seconds": seconds,
        "cpu_seconds": usage.ru_utime + usage.ru_stime,
        "peak_MB": usage.ru_maxrss / 1024,  # KiB on Linux
        "status": os.waitstatus_to_exitcode(status),
        "progress": "left" in text and "MB/s" in text,
        "terminal": text,
    }


def summary(runs: list, key: str) -> str:
    values = [run[key] for run in runs]
    middle = statistics.median(values)
    return f"{middle:8.2f} ({min(values):.2f}-{max(values):.2f})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=10_000_000)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--keep", metavar="DIR", help="work in DIR and keep its files")
    args = parser.parse_args()
    nlpcal = [sys.executable, "-m", "nlpcal"]
    with tempfile.TemporaryDirectory(dir=args.keep) as folder:
        work = Path(folder)
        log, params = work / "big.csv", work / "params.json"
        text_out, parquet_out = work / "out.csv", work / "out.parquet"
        made = subprocess.run(
            [*nlpcal, "simulate", "-n", str(args.rows), "-o", str(log), "-q"], check=False
        )
        if made.returncode:
            return made.returncode
        size = log.stat().st_size
        print(f"log: {args.rows:,} rows, {size / 1e6:.1f} MB ({size / args.rows:.1f} bytes a row)")
        runs: dict = {name: [] for name in ("in memory", "lean", "calibrate", "csv", "parquet")}
        for _ in range(args.repeats):
            for kind, name in (("whole", "in memory"), ("lean", "lean")):
                runs[name].append(measured([sys.executable, "-c", READ, str(log), kind]))
            runs["calibrate"].append(measured([*nlpcal, "calibrate", str(log), "-o", str(params)]))
            for out, name in ((text_out, "csv"), (parquet_out, "parquet")):
                run = measured([*nlpcal, "apply", str(params), str(log), "-o", str(out)])
                run["ratio"] = out.stat().st_size / size
                with open(out, "rb") as handle:  # 4 bytes: a big read here would count
                    run["parquet"] = handle.read(4) == b"PAR1"  # in the next child's peak
                runs[name].append(run)
        failed = [name for name, done in runs.items() if any(run["status"] for run in done)]
        if failed:
            print(f"failed: {', '.join(failed)}")
            return 1
        print(
            f"{'':28s}{'seconds':>8s} (spread)   {'CPU s':>8s} (spread)   {'peak MB':>8s} (spread)"
        )
        labels = {
            "in memory": "read_log, in memory",
            "lean": "read_log, chunked (lean)",
            "calibrate": "nlpcal calibrate",
            "csv": "nlpcal apply -o out.csv",
            "parquet": "nlpcal apply -o out.parquet",
        }
        for name, label in labels.items():
            done = runs[name]
            print(
                f"{label:28s}{summary(done, 'seconds')}   {summary(done, 'cpu_seconds')}   "
                f"{summary(done, 'peak_MB')}"
            )
        lean, whole = runs["lean"], runs["in memory"]
        ratio_s = statistics.median(a["seconds"] / b["seconds"] for a, b in zip(lean, whole))
        ratio_m = statistics.median(a["peak_MB"] / b["peak_MB"] for a, b in zip(lean, whole))
        print(f"chunked / in memory: {ratio_s:.2f} x the time, {ratio_m:.2f} x the memory")
        for name in ("csv", "parquet"):
            done = runs[name]
            print(
                f"apply -o out.{name}: output {summary(done, 'ratio').strip()} x the input; "
                f"Parquet: {all(run['parquet'] for run in done)}; "
                f"progress drawn: {all(run['progress'] for run in done)}"
            )
        print(f"calibrate progress drawn: {all(run['progress'] for run in runs['calibrate'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
