"""What a user waits for, on an idle machine and on a busy one.

In one run, with the same interpreter and arrays:

- start-up: `nlpcal --version` and `nlpcal calibrate` of the bundled 2 000-sample log, wall time
  of the whole command (subprocesses);
- small logs: warm calls of nlpcal.calibrate on 2 000 samples (the problems already built),
  joint and staged, without a reference and with the reference field given;
- 1e6 samples in memory: one Gram pass (the 10 x 10 Gram of the quadratic monomials, the floor
  of any full fit; numpy with its BLAS threads, as a user would write it), the joint solve and
  the staged cycle, each as a ratio to that Gram pass;
- the same 1e6 calibrations while `--load` processes spin on the cores (two on a 2-core machine
  leave the calibration a fair share of half the machine), as a ratio to their idle time.

Every figure is the median over the repeats, with the spread (min-max). Run it under each
install to compare them, for example the README's plain install and one with the extras:

    python -m venv /tmp/plain && /tmp/plain/bin/pip install . && \\
        /tmp/plain/bin/python benchmarks/bench_load.py
    python -m venv /tmp/extras && /tmp/extras/bin/pip install '.[fast,bench]' && \\
        /tmp/extras/bin/python benchmarks/bench_load.py
"""

from __future__ import annotations

import argparse
import importlib.util
import multiprocessing
import platform
import statistics
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

import nlpcal
from nlpcal.simulation import ZHOU2010_FIELD_NT, simulate

HERE = Path(__file__).resolve().parent
EXAMPLE = HERE.parent / "data" / "example_zhou2010.csv"


def spin(stop):
    """A busy background process: arithmetic until told to stop."""
    x = 0
    while not stop.is_set():
        for k in range(100_000):
            x += k * k


def timed(function, repeats: int) -> list:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        times.append(time.perf_counter() - started)
    return times


def summary(times) -> str:
    return f"{statistics.median(times):.4f} s ({min(times):.4f}-{max(times):.4f})"


def gram_pass(samples):
    x, y, z = samples.T
    features = np.column_stack([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z, np.ones_like(x)])
    return features.T @ features


def command(*argv) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "nlpcal", *argv], check=True, capture_output=True)
    return time.perf_counter() - started


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--load", type=int, default=2, help="busy background processes")
    parser.add_argument("-n", type=float, default=1e6, help="samples of the large log")
    args = parser.parse_args(argv)

    extras = [name for name in ("pyarrow", "scipy") if importlib.util.find_spec(name)]
    print(
        f"# {platform.machine()}, {multiprocessing.cpu_count()} cores, Python "
        f"{platform.python_version()}, numpy {np.__version__}, nlpcal {nlpcal.__version__}, "
        f"extras installed: {', '.join(extras) or 'none'}"
    )

    version = timed(lambda: command("--version"), args.repeats)
    example = timed(lambda: command("calibrate", str(EXAMPLE), "-o", "/dev/null"), args.repeats)
    print(
        f"start-up: nlpcal --version {summary(version)}; nlpcal calibrate of the bundled log "
        f"{summary(example)}"
    )

    small = simulate(2000, noise=1.0, seed=1).to_numpy()
    for field, given in ((None, ""), (ZHOU2010_FIELD_NT, ", reference field given")):
        for method in ("joint", "staged"):
            call = partial(nlpcal.calibrate, small, method=method, reference_field=field)
            call()  # build the problems
            warm = timed(call, 5 * args.repeats)
            print(
                f"2 000 samples, warm {method}{given}: {statistics.median(warm) * 1e3:.2f} ms "
                f"({min(warm) * 1e3:.2f}-{max(warm) * 1e3:.2f})"
            )

    large = simulate(int(args.n), noise=1.0, seed=2).to_numpy()
    calls = {
        "gram": lambda: gram_pass(large),
        "joint": lambda: nlpcal.calibrate(large, method="joint", reference_field=ZHOU2010_FIELD_NT),
        "staged": lambda: nlpcal.calibrate(
            large, method="staged", reference_field=ZHOU2010_FIELD_NT
        ),
    }
    for call in calls.values():
        call()
    idle = {name: timed(call, args.repeats) for name, call in calls.items()}
    gram = statistics.median(idle["gram"])
    for name in ("joint", "staged"):
        print(
            f"{args.n:.0e} samples idle, {name}: {summary(idle[name])} = "
            f"{statistics.median(idle[name]) / gram:.2f} Gram passes ({summary(idle['gram'])})"
        )

    stop = multiprocessing.Event()
    workers = [multiprocessing.Process(target=spin, args=(stop,)) for _ in range(args.load)]
    for worker in workers:
        worker.start()
    try:
        time.sleep(0.5)
        busy = {name: timed(calls[name], args.repeats) for name in ("joint", "staged")}
    finally:
        stop.set()
        for worker in workers:
            worker.join()
    for name in ("joint", "staged"):
        ratio = statistics.median(busy[name]) / statistics.median(idle[name])
        print(
            f"{args.n:.0e} samples with {args.load} busy processes, {name}: "
            f"{summary(busy[name])} = {ratio:.2f} x idle"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
