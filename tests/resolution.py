"""The resolution at which the library promises its answers, for tests that compare two of them.

Each solve stops within STATIONARY_SE (0.01) standard errors of the optimum of its own samples
(`nlpcal.nlp.steps`), so two solves of the same numbers reached by different paths (another unit,
memory layout, thread count, reader or BLAS kernel, each of which changes the rounding of the
moments) agree within twice that, whatever CPU runs them; their last digits agree on none.
"""

from __future__ import annotations

from nlpcal.nlp.steps import STATIONARY_SE

#: Two solves of the same data agree within this many standard errors.
SAME_OPTIMUM_SE = 2 * STATIONARY_SE


def assert_same_optimum(parameters: dict, expected: dict, standard_errors: dict) -> None:
    """Each parameter within SAME_OPTIMUM_SE standard errors of its expected value."""
    assert set(parameters) == set(expected)
    for name, value in expected.items():
        gap = abs(parameters[name] - value) / standard_errors[name]
        assert gap <= SAME_OPTIMUM_SE, (name, parameters[name], value, gap)
