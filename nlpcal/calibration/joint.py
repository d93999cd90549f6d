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

from ..nlp.blocks import block_step


def joint_start(moments) -> np.ndarray:
    """Starting parameters (internal units: z [field], s [1], angles [rad])."""
    theta = np.zeros(9)
    theta[0:3] = moments.frame.centre
    if moments.reference != "none":
        theta[3:6] = moments.frame.radius / moments.length - 1.0
    return theta


def run_joint(problem):
    """Solve all nine at once.

    Returns (step, rows, stages): the `nlpcal.nlp.blocks.Step` of the solve, the measured and the
    joint Table 1 rows, and the record of the solve.
    """
    rows = [problem.measured_row()]
    started = time.perf_counter()
    step = block_step(problem.moments, "joint", joint_start(problem.moments), problem.ipopt)
    rows.append(
        problem.row(
            "joint",
            step.theta,
            step.f_end,
            iterations=step.iterations,
            wall_s=time.perf_counter() - started,
        )
    )
    stages = [
        {
            "cycle": 1,
            "stage": "joint",
            "status": step.status,
            "iterations": step.iterations,
            "objective": step.f_end,
        }
    ]
    return step, rows, stages
