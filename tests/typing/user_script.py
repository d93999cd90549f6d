"""A user's script, as type checkers see it: CI runs mypy on it against the installed package
(`tests/test_typing.py`), which needs the package's py.typed and typed lazy exports."""

from __future__ import annotations

import numpy as np

import nlpcal


def calibrate_example(seed: int = 0) -> tuple[dict, np.ndarray]:
    """Calibrate a simulated log and correct it: the README's first Python example."""
    log = nlpcal.simulate(600, noise=1.0, seed=seed)
    samples = log[["bx", "by", "bz"]].to_numpy()
    result: nlpcal.CalibrationResult = nlpcal.calibrate(
        samples, method="joint", model="full", unit="nT", reference_field=49462.0, cycles=20
    )
    corrected: np.ndarray = result.apply(samples, unit="nT")
    again = nlpcal.CalibrationResult.from_json(result.to_json())
    assert again.parameters == result.parameters
    return result.parameters, corrected


def worst_case_example() -> float:
    """Wang et al. (2015): the worst total-field error of three small axis angles. [nT]"""
    case: nlpcal.WorstCase = nlpcal.worst_case((0.1, 0.1, 0.1), 55_000.0)
    return case.exact_max_nT


if __name__ == "__main__":
    print(calibrate_example()[0])
    print(worst_case_example())
