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
parameters' errors against those of a no-lag log of the same draws calibrated without a lag.
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


def parameter_errors(result) -> np.ndarray:
    """The nine parameters' errors in their standard errors. [1]"""
    return np.array(
        [(result.parameters[n] - PAPER_TRUTH[n]) / result.standard_errors[n] for n in PAPER_TRUTH]
    )


def replica(seed: int) -> tuple:
    """(tau [s], its standard error [s], the attenuated tau [s], the rms of the nine errors in
    standard errors with the lag estimated, and the same without a lag in the data or the fit,
    on the same draws)."""
    samples, reference, times, _ = lagged_log(seed=seed, tau=TAU)
    plain, level, _, _ = lagged_log(seed=seed, tau=0.0)
    no_lag = nlpcal.calibrate(plain, reference_field=level, method="joint")
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
    rms = float(np.sqrt(np.mean(parameter_errors(result) ** 2)))
    rms_no_lag = float(np.sqrt(np.mean(parameter_errors(no_lag) ** 2)))
    errors = [abs(result.parameters[n] - PAPER_TRUTH[n]) for n in PAPER_TRUTH]
    errors_no_lag = [abs(no_lag.parameters[n] - PAPER_TRUTH[n]) for n in PAPER_TRUTH]
    return (
        lag["seconds"],
        lag["standard_error_s"],
        attenuated,
        rms,
        rms_no_lag,
        *errors,
        *errors_no_lag,
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replicas", type=int, default=100)
    args = parser.parse_args(argv)
    rows = np.array([replica(seed) for seed in range(args.replicas)])
    tau, se, attenuated, rms, rms_no_lag = rows.T[:5]
    errors, errors_no_lag = rows[:, 5:14], rows[:, 14:23]
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
        f"nine parameters, rms of error / SE over replicas and parameters: lag estimated "
        f"{np.sqrt(np.mean(rms**2)):.3f}, no lag in data or fit "
        f"{np.sqrt(np.mean(rms_no_lag**2)):.3f}"
    )
    ratio = np.sqrt(np.mean(errors**2, axis=0) / np.mean(errors_no_lag**2, axis=0))
    print(
        "rms error with the lag estimated / without a lag, per parameter: "
        + ", ".join(f"{n} {r:.3f}" for n, r in zip(PAPER_TRUTH, ratio))
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
