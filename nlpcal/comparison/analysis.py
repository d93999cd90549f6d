"""What a comparison reports besides its Table 1 rows: objective trajectories, the coupling of
the stages of Fig. 1 in [1] and the summary of compare.json.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import numpy as np

from ..nlp.blocks import SCALE_INDICES, gauge_basis, objective_function, pack

#: A staged cycle counts as having reached the joint solve when its std is within this fraction.
REACHED_JOINT_RTOL = 0.01
#: Most points kept per trajectory in the JSON (log-spaced in the iteration count).
TRAJECTORY_POINTS = 200


def thin(trajectory: dict, points: int = TRAJECTORY_POINTS) -> dict:
    """Keep the first and last points and about `points` log-spaced in between."""
    its = np.asarray(trajectory["iterations"])
    if its.size <= points:
        return {
            k: [float(v) if k == "objective" else int(v) for v in trajectory[k]]
            for k in ("iterations", "objective")
        }
    keep = np.unique(
        np.concatenate(
            [[0, its.size - 1], np.round(np.geomspace(1, its.size - 1, points)).astype(int)]
        )
    )
    return {
        "iterations": [int(its[i]) for i in keep],
        "objective": [float(trajectory["objective"][i]) for i in keep],
    }


def joint_trajectory(step, iterations: int, f_end: float) -> dict:
    """The objective at every IPOPT iteration of the joint solve `step` (`nlpcal.nlp.steps.Step`).

    IPOPT records the objective of its problem, f / f_ref, at every iteration (`SolveOutcome.
    objectives`). Without that record (no IPOPT call: a start at its optimum), the start and the
    end of the solve are returned.
    """
    f_start = float(getattr(step, "f_start", f_end))
    scaled = step.outcome.objectives
    if len(scaled) != iterations + 1:
        return {"iterations": [0, iterations], "objective": [f_start, f_end]}
    objective = [v * float(step.f_ref) for v in scaled]
    return {"iterations": list(range(len(objective))), "objective": objective}


def staged_trajectory(rows, stages) -> dict:
    """Objective after every stage (`nlpcal.calibration.result.BlockSolve`; or every cycle,
    when the stages do not record it)."""
    path = {"iterations": [0], "objective": [rows[0]["objective"]]}
    if stages and all(s.objective is not None for s in stages):
        for stage in stages:
            path["iterations"].append(path["iterations"][-1] + stage.iterations)
            path["objective"].append(float(stage.objective))
        return path
    for row in rows[1:]:
        path["iterations"].append(path["iterations"][-1] + row["iterations"])
        path["objective"].append(row["objective"])
    return path


def cg_trajectory(histories) -> dict:
    """Concatenated CG objective histories of successive solves, against cumulative iterations."""
    iterations: list[int] = []
    objective: list[float] = []
    total = 0
    for history in histories:
        for k, value in enumerate(history):
            if k == 0 and iterations:
                continue  # the start of a solve is the end of the one before
            iterations.append(total + k)
            objective.append(float(value))
        total += len(history) - 1
    return {"iterations": iterations, "objective": objective}


def block_coupling(moments, theta) -> dict:
    """How strongly the three stages are coupled at `theta`, and what that means for the cycle.

    Near the optimum the objective is the quadratic of its Hessian H, and the cycle of Fig. 1
    (each stage minimising over one block exactly, the others fixed) is block Gauss-Seidel on H
    in the order orthogonal -> scale -> offset. Its error shrinks per cycle by the spectral radius
    rho of the Gauss-Seidel matrix -(D + L)^-1 U (D, L, U the block diagonal, lower and upper
    parts of H), so the objective above its minimum shrinks by about rho^2 per cycle. Without a
    reference field the scale block is taken on the gauge s_x + s_y + s_z = 0.

    Returns rho, rho^2, the cycles that rho^2 needs to cut the excess objective by 1e6, and the
    largest canonical correlation between each pair of blocks (1: a direction of one block can
    be traded for one of the other without changing f; 0: independent blocks). [1]
    """
    hess = np.asarray(
        objective_function(moments.reference)(theta, pack(moments, theta, np.ones(9), 1.0))[2],
        dtype=float,
    )
    gauge = moments.reference == "none"
    scale_basis = gauge_basis(SCALE_INDICES) if gauge else np.eye(3)
    sizes = (3, scale_basis.shape[1], 3)
    basis = np.zeros((9, sum(sizes)))
    basis[6:9, 0:3] = np.eye(3)  # stage order: orthogonal, scale, offset
    basis[3:6, 3 : 3 + sizes[1]] = scale_basis
    basis[0:3, 3 + sizes[1] :] = np.eye(3)
    h = basis.T @ hess @ basis
    h = 0.5 * (h + h.T)
    edges = np.cumsum((0, *sizes))
    parts = [slice(edges[k], edges[k + 1]) for k in range(3)]
    lower = np.zeros_like(h)
    for i in range(3):
        for j in range(i + 1):
            lower[parts[i], parts[j]] = h[parts[i], parts[j]]
    upper = h - lower
    try:
        rho = float(max(abs(np.linalg.eigvals(-np.linalg.solve(lower, upper)))))
        correlations = {}
        names = ("orthogonal", "scale", "offset")
        whiten = []
        for part in parts:
            values, vectors = np.linalg.eigh(h[part, part])
            whiten.append(vectors / np.sqrt(values))
        for i in range(3):
            for j in range(i + 1, 3):
                cross = whiten[i].T @ h[parts[i], parts[j]] @ whiten[j]
                correlations[f"{names[i]}-{names[j]}"] = float(np.linalg.svd(cross)[1][0])
    except (np.linalg.LinAlgError, FloatingPointError):
        return {
            "rho": None,
            "rho_squared": None,
            "cycles_per_1e6": None,
            "canonical_correlations": None,
        }
    rate = rho**2
    cycles = float(np.log(1e-6) / np.log(rate)) if 0 < rate < 1 else None
    return {
        "rho": rho,
        "rho_squared": rate,
        "cycles_per_1e6": cycles,
        "canonical_correlations": correlations,
    }


def run_summary(staged, stop_reason, joint, cg_joint, cg_staged) -> dict:
    """The "summary" of compare.json: cycles, iterations and wall time [s] of each method, and
    the cycle at which each cycle first comes within REACHED_JOINT_RTOL of the joint std."""
    joint_std = joint["std"]
    reached = next(
        (
            k
            for k, row in enumerate(staged[1:], start=1)
            if row["std"] <= joint_std * (1 + REACHED_JOINT_RTOL)
        ),
        None,
    )
    cg_reached = next(
        (
            k
            for k, row in enumerate(cg_staged[1:], start=1)
            if row["std"] <= joint_std * (1 + REACHED_JOINT_RTOL)
        ),
        None,
    )
    return {
        "staged_cycles": len(staged) - 1,
        "staged_stop_reason": stop_reason,
        "staged_iterations": int(sum(r["iterations"] for r in staged)),
        "staged_wall_s": float(sum(r["wall_s"] for r in staged)),
        "staged_cycles_to_joint": reached,
        "staged_final_std_over_joint": staged[-1]["std"] / joint_std if joint_std > 0 else None,
        "reached_joint_rtol": REACHED_JOINT_RTOL,
        "joint_iterations": int(joint["iterations"]),
        "joint_wall_s": float(joint["wall_s"]),
        "cg_joint": {
            row["variant"]: {
                "status": row["status"],
                "iterations": row["iterations"],
                "std": row["std"],
                "wall_s": row["wall_s"],
            }
            for row in cg_joint
        },
        "cg_staged_cycles": len(cg_staged) - 1,
        "cg_staged_iterations": int(sum(r["iterations"] for r in cg_staged)),
        "cg_staged_wall_s": float(sum(r["wall_s"] for r in cg_staged)),
        "cg_staged_cycles_to_joint": cg_reached,
        "cg_staged_all_stages_converged": all(r.get("converged", True) for r in cg_staged[1:]),
    }
