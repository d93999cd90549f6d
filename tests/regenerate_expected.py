"""Regenerate the stored Table 1 expectations of tests/test_compare.py. Run it by hand only:

    python tests/regenerate_expected.py            # rewrite tests/expected/table1_*.json
    python tests/regenerate_expected.py --check    # compare without writing (exit 1 on drift)

The tests never write these files: a change of the numbers has to be made, looked at and
committed on purpose (say in the commit why the rows moved).

Each case simulates a log of the `zhou2010` preset (the final parameters and field of Zhou et al.
2010) with a fixed seed and attitude set, runs `nlpcal.comparison.compare` and stores the Table 1
statistics (max, min, mean, std, range [nT]) of every row: the staged cycle (measured row, then one
per cycle), the joint IPOPT solve, the joint CG in paper units and scaled, and the CG-staged cycle.
Iteration counts and wall times are not stored: they are not results.

Tolerance (TOLERANCE_NT + TOLERANCE_REL * |expected|): 1e-3 nT + 1e-7 relative, that is at most
about 6e-3 nT at 49 500 nT. Solving the same log with its rows permuted (another summation order)
moves the rows by at most about 1e-5 nT, so the tolerance leaves a factor of about 100 for
platform and BLAS differences, and it is still below the 0.01 nT to which Table 1 of the paper is
printed. A change of the mathematics (objective, model, stage order, stop rules) moves the rows by
far more and must show up as a failure. The number of cycles a run takes may differ by up to
CYCLE_SLACK: it varies by a few with the floating-point kernel (its stop rule compares
quantities whose last digits the kernel decides); then the common cycles and the last rows are
compared.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from nlpcal.comparison import CompareSettings, compare  # noqa: E402
from nlpcal.comparison.conjugate_gradient import CGOptions  # noqa: E402
from nlpcal.simulation import PRESETS, simulate  # noqa: E402

EXPECTED = HERE / "expected"
STAT_KEYS = ("max", "min", "mean", "std", "range")
TOLERANCE_NT = 1e-3
TOLERANCE_REL = 1e-7
#: Runs whose cycle counts differ by at most this many are compared (as in docs/generated.py).
CYCLE_SLACK = 3

#: (attitude set, seed, samples). Small logs and few cycles keep tests/test_compare.py fast.
CASES = (
    ("uniform", 3, 500),
    ("turntable", 3, 500),
    ("tilt_band", 3, 500),
    ("clustered", 3, 500),
)
SETTINGS = CompareSettings(cycles=8, rtol=1e-9, cg=CGOptions(max_iter=1000))
NOISE = 1.0


def case_path(attitudes: str, seed: int) -> Path:
    return EXPECTED / f"table1_{attitudes}_seed{seed}.json"


def run_case(attitudes: str, seed: int, n: int):
    preset = PRESETS["zhou2010"]
    samples = simulate(
        n,
        parameters=preset.parameters,
        field=preset.field,
        noise=NOISE,
        seed=seed,
        attitudes=attitudes,
    ).to_numpy()
    return compare(samples, settings=SETTINGS)


def table_rows(result) -> dict:
    """The stored part of a Comparison: labels and Table 1 statistics of every row."""

    def strip(rows):
        return [{"label": r["label"], **{k: r[k] for k in STAT_KEYS}} for r in rows]

    return {
        "staged": strip(result.staged),
        "joint": strip([result.joint])[0],
        "cg_joint": strip(result.cg_joint),
        "cg_staged": strip(result.cg_staged),
    }


def document(attitudes: str, seed: int, n: int, result) -> dict:
    return {
        "what": "Table 1 statistics of nlpcal compare; regenerate with "
        "tests/regenerate_expected.py only",
        "case": {
            "preset": "zhou2010",
            "attitudes": attitudes,
            "seed": seed,
            "n": n,
            "noise_nT": NOISE,
            "cycles": SETTINGS.cycles,
            "rtol": SETTINGS.rtol,
            "cg_max_iter": SETTINGS.cg.max_iter,
        },
        "tolerance": {"abs_nT": TOLERANCE_NT, "rel": TOLERANCE_REL},
        **table_rows(result),
    }


def _paired(want: list, have: list) -> list | None:
    """The rows of two runs paired by label; when they stopped within CYCLE_SLACK cycles of each
    other, the common cycles and the last rows. None when they cannot be paired."""
    labels = [r["label"] for r in want], [r["label"] for r in have]
    if labels[0] == labels[1]:
        return list(zip(want, have))
    common = min(len(want), len(have)) - 1
    if (
        labels[0][:common] == labels[1][:common]
        and abs(len(want) - len(have)) <= CYCLE_SLACK
        and all(names[-1].startswith("cycle ") for names in labels)
    ):
        return list(zip(want[:common], have[:common])) + [(want[-1], have[-1])]
    return None


def differences(expected: dict, got: dict) -> list:
    """Human-readable list of the rows and statistics outside the tolerance."""
    problems = []
    for key in ("staged", "joint", "cg_joint", "cg_staged"):
        want, have = expected[key], got[key]
        if isinstance(want, dict):
            want, have = [want], [have]
        pairs = _paired(want, have)
        if pairs is None:
            problems.append(
                f"{key}: rows {[r['label'] for r in have]}, expected {[r['label'] for r in want]}"
            )
            continue
        for w, h in pairs:
            for stat in STAT_KEYS:
                limit = TOLERANCE_NT + TOLERANCE_REL * abs(w[stat])
                if abs(h[stat] - w[stat]) > limit:
                    problems.append(
                        f"{key} / {w['label']} / {stat}: {h[stat]:.6f}, expected "
                        f"{w[stat]:.6f} (tolerance {limit:.1e})"
                    )
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare only, write nothing")
    args = parser.parse_args(argv)
    EXPECTED.mkdir(exist_ok=True)
    drift = 0
    for attitudes, seed, n in CASES:
        result = run_case(attitudes, seed, n)
        doc = document(attitudes, seed, n, result)
        path = case_path(attitudes, seed)
        if args.check:
            if not path.exists():
                print(f"{path}: missing", file=sys.stderr)
                drift += 1
                continue
            problems = differences(json.loads(path.read_text()), doc)
            drift += bool(problems)
            for line in problems:
                print(f"{path.name}: {line}", file=sys.stderr)
        else:
            path.write_text(json.dumps(doc, indent=1) + "\n")
            print(f"wrote {path}", file=sys.stderr)
    return 1 if drift else 0


if __name__ == "__main__":
    raise SystemExit(main())
