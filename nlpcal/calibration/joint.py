"""The joint solve: all nine parameters of Eq. 4 in [1] in one IPOPT problem.

The paper argues that a joint solve converges badly because offsets (hundreds of nT), scale
errors (~1e-3) and angles (~1e-2 rad) differ by orders of magnitude. `nlpcal.nlp.blocks` scales
every variable to order one, and IPOPT uses the exact Hessian of the moment objective.

Start: offsets at the centre of a sphere fitted to the raw samples, angles zero, and scales zero
(Eq. 8) or the common scale that maps the sphere radius onto the reference field.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import time

import numpy as np

from ..nlp.blocks import block_step, variable_scale


def joint_start(moments) -> np.ndarray:
    """Starting parameters (internal units: z [field], s [1], angles [rad])."""
    theta = np.zeros(9)
    theta[0:3] = moments.frame.centre
    if moments.reference != "none":
        theta[3:6] = moments.frame.radius / moments.length - 1.0
    return theta


#: Reweighting stops when no parameter moves by more than this many of its typical sizes
#: (`nlpcal.nlp.blocks.variable_scale`: 1e-9 of the field for offsets) and the scale is settled.
IRLS_XTOL = 1e-6
#: The most reweightings of a joint solve with a robust loss.
MAX_REWEIGHTS = 100


def run_joint(problem):
    """Solve all nine at once; with a robust loss, reweight and re-solve from the least-squares
    solution until the weights no longer move the parameters (iteratively reweighted least
    squares, each solve warm-started).

    Returns (step, rows, stages): the `nlpcal.nlp.blocks.Step` of the last solve, the measured
    and the joint Table 1 rows, and the record of every solve.
    """
    rows = [problem.measured_row()]
    started = time.perf_counter()
    step = block_step(problem.moments, "joint", joint_start(problem.moments))
    records = [(step, "joint")]
    scale = variable_scale(problem.moments.frame.radius)
    for _ in range(MAX_REWEIGHTS if problem.loss.robust else 0):
        changed = problem.reweight(step.theta)
        new = block_step(problem.moments, "joint", step.theta)
        move = float(np.max(np.abs(new.theta - step.theta) / scale))
        step = new
        records.append((step, "joint (reweighted)"))
        if move < IRLS_XTOL and not changed:
            break
    rows.append(
        problem.row(
            "joint",
            step.theta,
            step.f_end,
            iterations=sum(s.iterations for s, _ in records),
            wall_s=time.perf_counter() - started,
        )
    )
    stages = [
        {
            "cycle": k,
            "stage": stage,
            "status": s.status,
            "iterations": s.iterations,
            "objective": s.f_end,
        }
        for k, (s, stage) in enumerate(records, start=1)
    ]
    return step, rows, stages
