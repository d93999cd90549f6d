"""Monte Carlo of the lag of a reference series (docs/lag.md): the estimate, its standard error
and its coverage over replicas of the synthetic log of the tests.

    python docs/lag_montecarlo.py              # 100 replicas, about five minutes
    python docs/lag_montecarlo.py --replicas 20

Each replica: 10 Hz for 1 h, uniform attitudes, the field magnitude a sum of sinusoids with
periods of 20-300 s and rms dF/dt 1 nT/s, 0.05 nT of noise on each component and on the
reference, the reference late by 37 ms (`tests/synthetic.py`, written apart from the library's
model). Printed: the mean and spread of tau, the mean standard error, the share of replicas
whose +/-1.96 SE interval covers the truth, the largest error of tau, the same for the estimate
without the correction for the derivative's noise (tau times c / c_observed), and the nine
parameters' errors in their standard errors.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import nlpcal  # noqa: E402
from synthetic import PAPER_TRUTH, lagged_log  # noqa: E402

TAU = 0.037  # [s]
Z = 1.959963984540054


def replica(seed: int) -> tuple:
    """(tau [s], its standard error [s], the attenuated tau [s], max |error| / SE of the nine)."""
    samples, reference, times, _ = lagged_log(seed=seed, tau=TAU)
    result = nlpcal.calibrate(
        samples, reference_field=reference, times=times, lag="auto", method="joint"
    )
    lag = result.lag
    noise_share = lag["reference_noise"] ** 2 * 2 / (2 * lag["sample_interval_s"]) ** 2
    attenuated = (
        lag["seconds"]
        * lag["rms_derivative_per_s"] ** 2
        / (lag["rms_derivative_per_s"] ** 2 + noise_share)
    )
    worst = max(
        abs(result.parameters[n] - PAPER_TRUTH[n]) / result.standard_errors[n] for n in PAPER_TRUTH
    )
    return lag["seconds"], lag["standard_error_s"], attenuated, worst


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicas", type=int, default=100)
    args = parser.parse_args(argv)
    rows = np.array([replica(seed) for seed in range(args.replicas)])
    tau, se, attenuated, worst = rows.T
    covered = np.abs(tau - TAU) <= Z * se
    print(f"replicas {args.replicas}, true tau {TAU * 1e3:.1f} ms")
    print(
        f"tau mean {tau.mean() * 1e3:.3f} ms, std {tau.std(ddof=1) * 1e3:.3f} ms, "
        f"mean SE {se.mean() * 1e3:.3f} ms, largest error {np.abs(tau - TAU).max() * 1e3:.3f} ms"
    )
    print(
        f"coverage of +/-1.96 SE: {covered.mean():.2f} "
        f"(binomial 95 % band for 0.95: {0.95 - Z * np.sqrt(0.0475 / len(tau)):.2f}-"
        f"{min(1.0, 0.95 + Z * np.sqrt(0.0475 / len(tau))):.2f})"
    )
    print(f"without the noise correction: tau mean {attenuated.mean() * 1e3:.3f} ms")
    print(
        f"nine parameters: largest |error| / SE per replica, median {np.median(worst):.2f}, "
        f"max {worst.max():.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
