"""How fast the staged cycle fails on a tilt-limited log, against running it to its limit.

The log: `nlpcal simulate --attitudes tilt --max-tilt-deg 20 --noise 5` in-process (2000
samples, the zhou2010 preset, heading free, roll and pitch uniform within +-20 deg, seed 1): the
staged cycle converges linearly at about 0.97 per cycle and cannot meet its rtol rule within its
500 cycles. In one process and on the same array, warm (every CasADi problem built once before
the timing), it measures:

- predicted: nlpcal.calibrate with the default settings, which stops when the rate of
  convergence predicts the rule cannot hold, and raises QualityError with the advice;
- to_limit: the same call with allow_unconverged=True, which runs the 500 cycles as asked (the
  behaviour before the prediction, and the baseline of this run);
- joint: method="joint", what the advice recommends;

and prints the median and the spread (min .. max) of each over the repeats, the cycles each ran,
and the ratios of the medians to the baseline. Timings are for the machine at hand: compare the
ratios, not the seconds, between machines.

    python benchmarks/bench_fail_fast.py [--repeats 5] [--max-tilt-deg 20]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np

import nlpcal
from nlpcal.errors import QualityError
from nlpcal.simulation import simulate


def predicted(samples):
    try:
        return nlpcal.calibrate(samples, unit="nT")
    except QualityError as failure:
        return failure.result


def to_limit(samples):
    return nlpcal.calibrate(samples, unit="nT", allow_unconverged=True)


def joint(samples):
    return nlpcal.calibrate(samples, unit="nT", method="joint")


def timed(function, samples, repeats: int):
    seconds, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = function(samples)
        seconds.append(time.perf_counter() - started)
    return seconds, result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--max-tilt-deg", type=float, default=20.0)
    args = parser.parse_args(argv)
    samples = simulate(
        2000, noise=5.0, seed=1, attitudes="tilt", max_tilt_deg=args.max_tilt_deg
    ).to_numpy()
    for function in (predicted, joint):  # build every CasADi problem once
        function(samples)
    print(
        f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"nlpcal {nlpcal.__version__}, N = {len(samples)}, repeats {args.repeats}"
    )
    print(f"{'run':<10} {'median s':>9} {'min s':>8} {'max s':>8} {'cycles':>7} {'ratio':>7}  stop")
    runs = {
        name: timed(function, samples, args.repeats)
        for name, function in (("to_limit", to_limit), ("predicted", predicted), ("joint", joint))
    }
    baseline = statistics.median(runs["to_limit"][0])
    for name, (seconds, result) in runs.items():
        median = statistics.median(seconds)
        cycles = len(result.statistics) - 1 if result.method == "staged" else "-"
        print(
            f"{name:<10} {median:9.3f} {min(seconds):8.3f} {max(seconds):8.3f} {cycles!s:>7} "
            f"{median / baseline:7.3f}  {result.solver['stop_reason']}"
        )
    return 0 if np.isfinite(baseline) else 1


if __name__ == "__main__":
    raise SystemExit(main())
