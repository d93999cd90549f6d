"""Regenerate the tables of docs/robustness.md: spikes and robust losses, the staged cycle on
restricted attitudes, and logs turned about one axis.

    python docs/robustness.py            # rewrite the generated blocks of docs/robustness.md
    python docs/robustness.py --check    # exit 1 if the page's tables are out of date
    python docs/robustness.py --print    # print the tables, touch nothing

The logs are synthetic, made by the forward model of the tests (`tests/synthetic.py`, written
apart from the correction), with fixed seeds. Takes about a minute.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import nlpcal  # noqa: E402
from generated import replace_block, update_page  # noqa: E402
from nlpcal.simulation.attitudes import tilt_band_attitudes, world_field  # noqa: E402
from synthetic import (  # noqa: E402
    PAPER_FIELD,
    PAPER_TRUTH,
    band_directions,
    circle_directions,
    make_log,
    sensor_output,
)

PAGE = HERE / "robustness.md"
SPIKE_SHARE, SPIKE_NT = 0.02, 2000.0


def spiked(samples: np.ndarray, seed: int = 7) -> np.ndarray:
    """Single-axis spikes of +/-SPIKE_NT on SPIKE_SHARE of the rows (a logger fault)."""
    rng = np.random.default_rng(seed)
    out = samples.copy()
    rows = rng.choice(len(out), size=int(SPIKE_SHARE * len(out)), replace=False)
    out[rows, rng.integers(0, 3, len(rows))] += rng.choice([-SPIKE_NT, SPIKE_NT], len(rows))
    return out


def scores(result, test: np.ndarray) -> tuple:
    """(std of the corrected |B| on clean test attitudes [nT], largest offset error [nT])."""
    std = float(np.linalg.norm(result.apply(test), axis=1).std())
    error = max(abs(result.parameters[f"z_{a}"] - PAPER_TRUTH[f"z_{a}"]) for a in "xyz")
    return std, error


def spikes_table() -> str:
    train, _ = make_log(n=5000, noise=1.0, seed=21)
    test, _ = make_log(n=5000, noise=1.0, seed=22)
    bad = spiked(train)
    lines = [
        "| method, reference | clean fit: std, offset error | least squares on spikes: std "
        "(warns?) | huber: std (x clean), offset error (x clean) | cauchy: std |",
        "|---|---|---|---|---|",
    ]
    for method in ("joint", "staged"):
        for reference in (None, PAPER_FIELD):
            options = {"method": method, "reference_field": reference}
            clean = scores(nlpcal.calibrate(train, **options), test)
            plain_result = nlpcal.calibrate(bad, allow_unconverged=True, **options)
            plain = scores(plain_result, test)
            warns = any("heavy-tailed" in w for w in plain_result.warnings)
            huber = scores(nlpcal.calibrate(bad, loss="huber", **options), test)
            cauchy = scores(nlpcal.calibrate(bad, loss="cauchy", **options), test)
            lines.append(
                f"| {method}, {'F given' if reference else 'none'} | {clean[0]:.4f}, "
                f"{clean[1]:.3f} nT | {plain[0]:.3f} ({'yes' if warns else 'no'}) | "
                f"{huber[0]:.4f} ({huber[0] / clean[0]:.3f}x), {huber[1]:.3f} nT "
                f"({huber[1] / clean[1]:.2f}x) | {cauchy[0]:.4f} |"
            )
    return "\n".join(lines)


def tilt_table() -> str:
    rng = np.random.default_rng(1)
    rotations = tilt_band_attitudes(5000, rng, max_tilt_deg=20.0)  # sensor-from-world
    field = rotations @ world_field(PAPER_FIELD)  # the field in the sensor frame, 60 deg dip
    samples = sensor_output(field, PAPER_TRUTH) + rng.normal(size=field.shape)
    lines = ["| --cycles | outcome |", "|---|---|"]
    for cycles in (50, 500, 5000):
        try:
            result = nlpcal.calibrate(samples, method="staged", cycles=cycles)
        except nlpcal.QualityError as failure:
            gap = failure.result.identifiability["joint_gap"]["max_gap_in_standard_errors"]
            ran, why = len(failure.result.statistics) - 1, failure.result.solver.stop_reason
            outcome = (
                f"exit 1 after {ran} cycles ({why}), quality check: {gap:.3g} standard errors "
                f"from the joint optimum"
            )
        else:
            # where a rule stops a long cycle varies with the kernel like the cycle count, and
            # the distance left with it: one figure is what the page can state
            gap = result.identifiability["joint_gap"]["max_gap_in_standard_errors"]
            outcome = (
                f"exit 0, stopped by {result.solver.stop_reason} after "
                f"{len(result.statistics) - 1} cycles, {gap:.1g} standard errors from the joint "
                f"optimum"
            )
        lines.append(f"| {cycles} | {outcome} |")
    return "\n".join(lines)


def plane_table() -> str:
    lines = [
        "| attitudes | thickness / extent of the samples | joint, no reference |",
        "|---|---|---|",
    ]
    cases = [("one circle about z", None), ("one circle about (1, 2, 2), 60 deg", "oblique")]
    cases += [(f"turns about z, tilts within +/-{t:g} deg", t) for t in (1, 2, 3, 5, 20)]
    for label, tilt in cases:
        rng = np.random.default_rng(8)
        if tilt is None:
            directions = circle_directions(3000, rng, (0, 0, 1), 90)
        elif tilt == "oblique":
            directions = circle_directions(3000, rng, (1, 2, 2), 60)
        else:
            directions = band_directions(3000, rng, tilt)
        samples, _ = make_log(n=3000, noise=2.5, seed=9, directions=directions)
        try:
            result = nlpcal.calibrate(samples, method="joint")
        except nlpcal.SolveError as failure:
            # refused after the solve (the quality check) or by a solve that wandered along the
            # free directions: which comes first, the floating-point kernel's rounding decides
            found = failure.identifiability or {}
            flat = found.get("flatness", {})
            if flat.get("planar"):
                how = "in one plane" if flat["within_noise"] else "nearly in one plane"
                blind = ", ".join(flat["parameters"])
                outcome = f"exit 1, the samples lie {how}: not determined: {blind}"
            else:
                outcome = f"exit 1: not determined: {', '.join(found['not_identifiable'])}"
        else:
            angles = ("alpha_deg", "beta_deg")  # free of the gauge on the scales
            worst = max(
                abs(result.parameters[n] - PAPER_TRUTH[n]) / result.standard_errors[n]
                for n in angles
            )
            outcome = f"exit 0; alpha and beta within {worst:.2g} standard errors of the truth"
        spread = np.linalg.eigvalsh(np.cov(samples.T))  # the cloud's principal variances
        ratio = np.sqrt(spread[0] / spread[-1])
        lines.append(f"| {label} | {ratio:.3g} | {outcome} |")
    return "\n".join(lines)


BLOCKS = {"spikes": spikes_table, "tilt": tilt_table, "plane": plane_table}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--check", action="store_true", help="exit 1 if docs/robustness.md is out of date"
    )
    parser.add_argument("--print", action="store_true", help="print the tables, touch nothing")
    args = parser.parse_args(argv)
    tables = {name: make() for name, make in BLOCKS.items()}
    if args.print:
        for name, table in tables.items():
            print(f"## {name}\n{table}\n")
        return 0
    page = PAGE.read_text()
    for name, table in tables.items():
        page = replace_block(page, name, table, str(PAGE))
    return update_page(PAGE, page, check=args.check, script="docs/robustness.py")


if __name__ == "__main__":
    sys.exit(main())
