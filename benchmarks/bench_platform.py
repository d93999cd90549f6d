"""The Tolles-Lawson fit of `nlpcal platform fit` on a long record: seconds, against a baseline.

    python benchmarks/bench_platform.py                          # 10^6 rows, 5 repeats
    python benchmarks/bench_platform.py --rows 200000 --repeats 3

A record of manoeuvres at 10 Hz (a vector magnetometer in a 50 000 nT field turned through
smooth random attitudes, a scalar with 18 Tolles-Lawson terms and 0.01 nT of noise) is made in
memory, then `nlpcal.fit_tolles_lawson` (18 terms, 0.1-0.9 Hz) runs --repeats times on
--threads threads (default: the cores available). The baseline, run in the same process between
the fits, is one numpy pass over a matrix the size of the band-passed design (rows x 19): its
Gram matrix X'X. The machine's other load moves the seconds; their ratio moves much less.

Reported: the median seconds of each, with the spread (min-max), their ratio, and whether the
fit's median is under --target seconds (1 s for 10^6 rows on 2 cores).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
import scipy

import nlpcal
from nlpcal import chunks


def record(n: int, seed: int = 0) -> tuple:
    """(vector (n, 3), scalar (n,)) [nT]: smooth random attitudes at 10 Hz, 18 TL terms."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 10.0
    angles = []
    for _ in range(3):  # a few slow sinusoids per angle, 0.02 to 0.5 Hz
        f = rng.uniform(0.02, 0.5, 4)
        phase = rng.uniform(0, 2 * np.pi, 4)
        angles.append((0.3 * np.sin(2 * np.pi * f[:, None] * t + phase[:, None])).sum(axis=0))
    roll, pitch, heading = angles
    heading = heading + 2 * np.pi * t / 600.0  # a slow turn through every heading
    cosines = np.column_stack(
        [np.cos(pitch) * np.cos(heading), np.cos(pitch) * np.sin(heading), np.sin(pitch + roll)]
    )
    cosines /= np.linalg.norm(cosines, axis=1, keepdims=True)
    vector = 5e4 * cosines
    rates = np.gradient(cosines, 0.1, axis=0)
    induced = [cosines[:, i] * cosines[:, j] for i in range(3) for j in range(i, 3)]
    eddy = [cosines[:, i] * rates[:, j] for i in range(3) for j in range(3)]
    terms = np.column_stack([cosines, 5e4 * np.column_stack(induced + eddy)])
    truth = np.concatenate(
        [[10, -20, 15], rng.uniform(-2e-4, 2e-4, 6), rng.uniform(-3e-3, 3e-3, 9)]
    )
    scalar = 5e4 + terms @ truth + 0.01 * rng.standard_normal(n)
    return vector, scalar


def spread(times) -> str:
    """median [min-max] of a list of seconds."""
    return f"{statistics.median(times):.3f} s [{min(times):.3f}-{max(times):.3f}]"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--target", type=float, default=1.0, help="seconds the fit must beat")
    args = parser.parse_args()

    vector, scalar = record(args.rows)
    design = np.random.default_rng(1).standard_normal((args.rows, 19))
    threads = args.threads or chunks.available_cores()
    print(
        f"{platform.machine()}, {os.cpu_count()} cores ({threads} threads), Python "
        f"{platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"nlpcal {nlpcal.__version__}; {args.rows} rows, {args.repeats} repeats; load average "
        + " ".join(f"{v:.2f}" for v in os.getloadavg())
    )
    fits, baselines = [], []
    with chunks.call_threads(threads):
        nlpcal.fit_tolles_lawson(vector[:50_000], scalar[:50_000], rate_hz=10.0)  # warm up
        for _ in range(args.repeats):
            started = time.perf_counter()
            fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=10.0)
            fits.append(time.perf_counter() - started)
            started = time.perf_counter()
            gram = design.T @ design
            baselines.append(time.perf_counter() - started)
    assert np.isfinite(gram).all() and fit.improvement_ratio > 10
    ratio = statistics.median(fits) / statistics.median(baselines)
    print(f"fit_tolles_lawson (18 terms)       {spread(fits)}")
    print(f"baseline: numpy X'X (rows x 19)    {spread(baselines)}")
    print(f"ratio fit / baseline               {ratio:.1f}")
    print(
        f"improvement ratio {fit.improvement_ratio:.0f}, compensated std "
        f"{fit.compensated_std:.4f} nT"
    )
    verdict = "under" if statistics.median(fits) < args.target else "OVER"
    print(f"median fit {verdict} the target of {args.target:g} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
