"""The staged cycle of Fig. 1 in [1]: orthogonal -> scale -> offset, repeated.

Steps of Fig. 1: (1) the angles from the raw data, the other blocks at zero; (2)-(3) the scales
from the orthogonality-corrected data; (4)-(5) the offsets from the data corrected for angles and
scales; (6) the full correction; (7) stop if the quality index (range or std of |B1|) meets its
target; (8)-(9) otherwise re-solve the angles with the latest scales and offsets and cycle. Every
correction is applied to the raw data: each stage minimises the objective of the raw samples with
the other six parameters held at their latest values.

Each stage is one of the three block problems of `nlpcal.nlp.blocks`, built once and re-solved.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..nlp.blocks import STAGE_ORDER, block_step


@dataclass(frozen=True)
class StopRule:
    """Stop rules of step 7 of Fig. 1 in [1].

    max_cycles : the most cycles to run.
    target_std : stop when the std of |B1| is at or below this. [field unit]
    target_range : stop when max - min of |B1| is at or below this. [field unit]
    rtol : stop when a cycle lowers the objective by less than this fraction. [1]
    """

    max_cycles: int = 50
    target_std: float | None = None
    target_range: float | None = None
    rtol: float = 1e-9


def run_staged(problem, rule: StopRule):
    """Cycle the three stages until a stop rule holds.

    problem : a `nlpcal.calibration.problem.Problem` (samples, moments, reference).
    Returns (theta, rows, stages, stop_reason): the last parameters, one Table 1 row per cycle
    (after the measured row), the record of every stage solve and why the cycle stopped.
    """
    theta = np.zeros(9)  # Fig. 1: the first pass starts with every other block at zero
    rows = [problem.measured_row()]
    stages = []
    previous = rows[0]["objective"]
    stop_reason = "max_cycles"
    for cycle in range(1, rule.max_cycles + 1):
        started = time.perf_counter()
        iterations = 0
        for stage in STAGE_ORDER:
            step = block_step(problem.moments, stage, theta, problem.ipopt)
            theta = step.theta
            iterations += step.iterations
            stages.append(
                {
                    "cycle": cycle,
                    "stage": stage,
                    "status": step.status,
                    "iterations": step.iterations,
                    "objective": step.f_end,
                }
            )
        row = problem.row(
            f"cycle {cycle}",
            theta,
            step.f_end,
            iterations=iterations,
            wall_s=time.perf_counter() - started,
        )
        rows.append(row)
        if rule.target_std is not None and row["std"] <= rule.target_std:
            stop_reason = "target_std"
            break
        if rule.target_range is not None and row["range"] <= rule.target_range:
            stop_reason = "target_range"
            break
        if previous - row["objective"] <= rule.rtol * previous:
            stop_reason = "rtol"
            break
        previous = row["objective"]
    return theta, rows, stages, stop_reason
