"""IPOPT settings and the one way nlpcal calls a CasADi `nlpsol`.

Every problem in nlpcal is built once as a symbolic NLP with the data as parameters `p`, and
re-solved with new numbers. IPOPT does not raise on failure: `solve` always reads
`stats()["success"]` and `["return_status"]` and hands them back.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np


@dataclass(frozen=True)
class IpoptOptions:
    """The IPOPT settings nlpcal uses; one place to change them."""

    tol: float = 1e-10
    # Tiny objectives (noise-free data near the optimum) carry rounding noise in their gradient;
    # five iterations in a row within acceptable_tol then count as solved.
    acceptable_tol: float = 1e-6
    acceptable_iter: int = 5
    max_iter: int = 200
    print_level: int = 0
    hessian_approximation: str = "exact"
    extra: tuple = ()  # further (name, value) IPOPT options; a tuple keeps the settings hashable

    def as_casadi(self) -> dict:
        ipopt = {
            "tol": self.tol,
            "acceptable_tol": self.acceptable_tol,
            "acceptable_iter": self.acceptable_iter,
            "max_iter": self.max_iter,
            "print_level": self.print_level,
            "sb": "yes",
            "hessian_approximation": self.hessian_approximation,
        }
        ipopt.update(dict(self.extra))
        return {"ipopt": ipopt, "print_time": False}


#: IPOPT statuses that count as solved.
SUCCESS_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


def build_nlpsol(name: str, x, f, p, g=None, options: IpoptOptions | None = None):
    """Create an IPOPT `nlpsol` for min f(x; p) s.t. lbg <= g(x; p) <= ubg."""
    nlp = {"x": x, "f": f, "p": p}
    if g is not None:
        nlp["g"] = g
    return ca.nlpsol(name, "ipopt", nlp, (options or IpoptOptions()).as_casadi())


@dataclass
class SolveOutcome:
    """What one IPOPT solve returned."""

    x: np.ndarray
    f: float
    status: str
    success: bool
    iterations: int
    lam_x: np.ndarray | None = None


def solve(solver, *, x0, p, lbx=-np.inf, ubx=np.inf, lbg=None, ubg=None) -> SolveOutcome:
    """Solve a built `nlpsol` and read back IPOPT's status and iteration count."""
    args = {"x0": x0, "p": p, "lbx": lbx, "ubx": ubx}
    if lbg is not None:
        args["lbg"] = lbg
        args["ubg"] = ubg
    out = solver(**args)
    stats = solver.stats()
    status = str(stats.get("return_status", "unknown"))
    return SolveOutcome(
        x=np.asarray(out["x"], dtype=float).ravel(),
        f=float(out["f"]),
        status=status,
        success=bool(stats.get("success", False)) or status in SUCCESS_STATUSES,
        iterations=int(stats.get("iter_count", 0)),
        lam_x=np.asarray(out["lam_x"], dtype=float).ravel(),
    )
