"""Regenerate the Monte Carlo table of docs/uncertainty.md: how well nlpcal's standard errors
describe the spread of its estimates, per scenario, against the independent forward model of
the tests (`tests/synthetic.py`).

    python docs/uncertainty.py            # run REPLICAS per case, rewrite the page's table
    python docs/uncertainty.py --check    # CHECK_REPLICAS per case: exit 1 outside the bands
    python docs/uncertainty.py --print    # print the table, touch nothing

A Monte Carlo page cannot be compared digit for digit at a reduced replica count, so `--check`
does not compare the page: it runs every case with CHECK_REPLICAS replicas and verifies the
acceptance bands, widened for that count (`check_case`). The full run (REPLICAS per case: at
200 the ratio of standard deviations still scatters by 5 %, as much as the bands' margins on the
smooth trajectory) takes about 20 minutes on one core; `--check` about a minute.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import nlpcal  # noqa: E402
from generated import replace_block, update_page  # noqa: E402
from synthetic import (  # noqa: E402
    PAPER_TRUTH,
    gauge_truth,
    scenario_log,
    sensor_axes,
    sensor_output,
    slow_field,
    smooth_directions,
    tilt_directions,
    uniform_directions,
)

PAGE = HERE / "uncertainty.md"
NAMES = list(PAPER_TRUTH)
FIELD = 50_000.0
N = 2000
REPLICAS = 500
CHECK_REPLICAS = 40
#: In --check, a case that must cover fails when a parameter's +/-1.96 SE interval covers in
#: fewer than this many of CHECK_REPLICAS replicas: binom.cdf(25, 40, 0.88) = 3e-5, so that over
#: the 72 parameters of the cases, an implementation whose intervals cover at
#: least 88 % fails less than three times in 1 000 runs.
CHECK_COVERED = 26
#: In --check, emp sd / SE must lie within this band (the ratio of standard deviations of 40
#: replicas scatters by about 11 %: the band is the issue's 0.8-1.25 widened by three of those).
CHECK_RATIO = (0.6, 1.6)
#: In --check, emp sd / CRLB on uniform attitudes must stay below this (the issue's 1.1 widened
#: by three times the 11 % scatter of a standard deviation of 40 replicas).
CHECK_CRLB = 1.45


@dataclass(frozen=True)
class Case:
    name: str
    directions: Callable
    magnitude: Callable  # (n, rng) -> field magnitude [nT]
    noise: float
    reference: bool
    loss: str = "l2"
    spikes: bool = False
    uniform: bool = False  # the Cramer-Rao bound is computed (white noise, no spikes)
    method: str = "staged"


def constant(n, rng):
    return FIELD


CASES = [
    Case("uniform, reference", uniform_directions, constant, 5.0, True, uniform=True),
    Case("uniform, no reference", uniform_directions, constant, 5.0, False, uniform=True),
    Case("uniform + 2 % spikes, huber", uniform_directions, constant, 5.0, True, "huber", True),
    Case(
        "smooth trajectory + slow field, no reference",
        smooth_directions,
        slow_field,
        5.0,
        False,
    ),
    Case(
        "independent directions + slow field, no reference",
        uniform_directions,
        slow_field,
        5.0,
        False,
    ),
    Case("smooth trajectory, reference", smooth_directions, constant, 5.0, True),
    Case(
        "short arc (roll, pitch <= 20 deg), reference, 5 nT",
        tilt_directions,
        constant,
        5.0,
        True,
        method="joint",
    ),
    Case(
        "short arc (roll, pitch <= 20 deg), reference, 15 nT",
        tilt_directions,
        constant,
        15.0,
        True,
        method="joint",
    ),
]


def replica(case: Case, seed: int) -> tuple:
    """(estimate - truth, standard errors) of one replica, each (9,) in PARAMETER_NAMES order,
    or None when the calibration gave no standard errors."""
    rng = np.random.default_rng(seed)
    directions = case.directions(N, rng)
    samples = scenario_log(N, case.noise, rng, directions, case.magnitude(N, rng))
    if case.spikes:
        hit = rng.random(N) < 0.02
        samples[hit] += rng.choice([-2000.0, 2000.0], size=(hit.sum(), 3))
    result = nlpcal.calibrate(
        samples,
        reference_field=FIELD if case.reference else None,
        loss=case.loss,
        method=case.method,
        require_identifiable=False,
        allow_unconverged=True,
    )
    if result.standard_errors is None:
        return None
    truth = PAPER_TRUTH if case.reference else gauge_truth()
    error = np.array([result.parameters[k] - truth[k] for k in NAMES])
    return error, np.array([result.standard_errors[k] for k in NAMES])


def cramer_rao(case: Case) -> np.ndarray:
    """The Cramer-Rao bound's standard deviations of the nine parameters for uniform directions
    (the expected information per sample by Monte Carlo over 200 000 directions): the residual
    |B1| - F of the inverse of the forward model, differentiated by central differences, with
    the noise of |B1| sigma (isotropic noise projected on the field). Without a reference the
    mean |B1| is a tenth parameter and the scales are bound under the gauge."""
    rng = np.random.default_rng(1)
    raw = sensor_output(FIELD * uniform_directions(200_000, rng), PAPER_TRUTH)

    def corrected(vector) -> np.ndarray:
        """|B1| of the raw samples for the parameters `vector`: the forward model inverted."""
        params = dict(zip(NAMES, vector))
        axes = sensor_axes(params["alpha_deg"], params["beta_deg"], params["gamma_deg"])
        offsets = np.array([params[f"z_{a}"] for a in "xyz"])
        gains = np.array([1 + params[f"s_{a}"] for a in "xyz"])
        return np.linalg.norm(np.linalg.solve(axes, ((raw - offsets) / gains).T), axis=0)

    base = np.array([PAPER_TRUTH[k] for k in NAMES])
    steps = np.array([1e-2] * 3 + [1e-6] * 3 + [1e-4] * 3)
    columns = []
    for k in range(9):
        up, down = base.copy(), base.copy()
        up[k] += steps[k]
        down[k] -= steps[k]
        columns.append((corrected(up) - corrected(down)) / (2 * steps[k]))
    jacobian = np.column_stack(columns)
    if not case.reference:
        jacobian = np.column_stack([jacobian, np.ones(len(jacobian))])
    information = jacobian.T @ jacobian / len(jacobian) * N / case.noise**2
    if case.reference:
        return np.sqrt(np.diag(np.linalg.inv(information)))
    # the gauge s_x + s_y + s_z = 0: the bound on the subspace it leaves free
    constraint = np.zeros((1, 10))
    constraint[0, 3:6] = 1.0
    _, _, vt = np.linalg.svd(constraint)
    free = vt[1:].T
    covariance = free @ np.linalg.inv(free.T @ information @ free) @ free.T
    return np.sqrt(np.diag(covariance))[:9]


def measure(case: Case, replicas: int) -> dict:
    """Coverage of +/-1.96 SE and emp sd / RMS SE per parameter, emp sd / CRLB when known."""
    runs = [replica(case, 10_000 * (CASES.index(case) + 1) + k) for k in range(replicas)]
    done = [r for r in runs if r is not None]
    errors = np.array([r[0] for r in done])
    ses = np.array([r[1] for r in done])
    spread = errors.std(axis=0, ddof=1)
    out = {
        "replicas": len(done),
        "coverage": (np.abs(errors) < 1.96 * ses).mean(axis=0),
        "ratio": spread / np.sqrt((ses**2).mean(axis=0)),
        "bias_in_se": errors.mean(axis=0) / np.sqrt((ses**2).mean(axis=0)),
        "crlb": spread / cramer_rao(case) if case.uniform else None,
    }
    return out


def _span(values) -> str:
    return f"{np.min(values):.2f}-{np.max(values):.2f}"


def table(results: dict) -> str:
    lines = [
        "| case | replicas | coverage of +/-1.96 SE (lowest: parameter) | emp sd / SE | "
        "emp sd / CRLB | largest mean error [SE] |",
        "|---|---|---|---|---|---|",
    ]
    for case in CASES:
        r = results[case.name]
        low = int(np.argmin(r["coverage"]))
        crlb = _span(r["crlb"]) if r["crlb"] is not None else "-"
        worst = int(np.argmax(np.abs(r["bias_in_se"])))
        lines.append(
            f"| {case.name} | {r['replicas']} | {_span(r['coverage'])} ({NAMES[low]}) | "
            f"{_span(r['ratio'])} | {crlb} | {r['bias_in_se'][worst]:+.2f} ({NAMES[worst]}) |"
        )
    return "\n".join(lines)


def check_case(case: Case, r: dict) -> list:
    """The acceptance bands at CHECK_REPLICAS replicas; the problems found, as sentences."""
    problems = []
    counts = np.round(r["coverage"] * r["replicas"]).astype(int)
    for name, count, ratio in zip(NAMES, counts, r["ratio"]):
        if count < CHECK_COVERED:
            problems.append(f"{case.name}: {name} covered in {count} of {r['replicas']}")
        if not CHECK_RATIO[0] <= ratio <= CHECK_RATIO[1]:
            problems.append(f"{case.name}: {name} emp sd / SE {ratio:.2f}")
    for name, efficiency in zip(NAMES, r["crlb"] if r["crlb"] is not None else []):
        if efficiency > CHECK_CRLB:
            problems.append(f"{case.name}: {name} emp sd / CRLB {efficiency:.2f}")
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="verify the acceptance bands")
    parser.add_argument("--print", action="store_true", help="print the table, touch nothing")
    args = parser.parse_args(argv)
    results = {}
    for case in CASES:
        replicas = CHECK_REPLICAS if args.check else REPLICAS
        results[case.name] = measure(case, replicas)
    if args.check:
        problems = [p for case in CASES for p in check_case(case, results[case.name])]
        for problem in problems:
            print(f"docs/uncertainty.py --check: {problem}", file=sys.stderr)
        return 1 if problems else 0
    body = table(results)
    if args.print:
        print(body)
        return 0
    page = replace_block(PAGE.read_text(), "montecarlo", body, str(PAGE))
    return update_page(PAGE, page, check=False, script="docs/uncertainty.py")


if __name__ == "__main__":
    sys.exit(main())
