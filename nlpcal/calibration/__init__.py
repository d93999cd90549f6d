"""`nlpcal.calibrate`: the nine-parameter calibration of Zhou et al. (2010) on a log.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import numpy as np

from .. import units, validation
from ..errors import QualityError, SolveError
from ..io.logs import Log
from ..models.zhou2010 import Zhou2010Parameters
from ..moments import accumulate
from ..nlp.blocks import GAUGE
from ..nlp.solver import IpoptOptions
from .diagnostics import (
    direction_coverage,
    explain_failure,
    scaled_hessian,
    uncertainty,
    undetermined_message,
    warnings_for,
)
from .joint import run_joint
from .problem import Problem
from .result import CalibrationResult
from .staged import StopRule, run_staged

METHODS = ("staged", "joint")
#: Default most cycles of the staged method.
CYCLES_DEFAULT = 50
#: Default relative improvement below which the staged cycle stops. [1]
RTOL_DEFAULT = 1e-9


def calibrate(
    samples,
    *,
    method: str = "staged",
    reference_field=None,
    unit: str = "nT",
    reference_unit: str | None = None,
    cycles: int = CYCLES_DEFAULT,
    target_std: float | None = None,
    target_range: float | None = None,
    rtol: float = RTOL_DEFAULT,
    require_identifiable: bool = True,
    verbose: bool = False,
) -> CalibrationResult:
    """Estimate the nine parameters of Eq. 4 in [1] from a log of many attitudes.

    samples : (N, 3) array-like of raw sensor output B_M. [unit]
    method : "staged", the cycle of Fig. 1 in [1] (orthogonal -> scale -> offset), or "joint",
        all nine in one IPOPT problem.
    reference_field : None (Eq. 8, absolute scale not identifiable), a number F, or an array of
        N values F_i (for example a proton magnetometer sampled with the log). [reference_unit]
    unit : the unit of the samples: nT, uT, mT, mG, G, T, or raw for counts. The result is in nT
        (or raw), whatever the unit of the samples.
    reference_unit : the unit of the reference (default: `unit`).
    cycles : the most staged cycles. target_std, target_range : stop the cycle when |B1| meets
        them [unit]. rtol : stop when a cycle lowers the objective by less than this fraction.
    require_identifiable : raise QualityError (holding the result) when the data leave parameters
        undetermined (a direction along which |B1| does not change, or a standard error above
        `diagnostics.UNDETERMINED`: 10 % of the field, 0.1, 10 deg); False returns the result
        with its warnings.
    verbose : print IPOPT's log of every solve (on stdout, as CasADi does).

    Returns a CalibrationResult. Raises InputError for unusable input, SolveError when IPOPT
    fails and QualityError as above.
    """
    validation.choice(method, "method", METHODS)
    cycles = validation.count(cycles, "cycles")
    target_std = validation.optional_number(target_std, "target_std", positive=True)
    target_range = validation.optional_number(target_range, "target_range", positive=True)
    rtol = validation.number(rtol, "rtol", minimum=0.0)
    units.check_compatible(unit, reference_unit or unit)
    samples = validation.samples(samples)
    reference = validation.reference(reference_field, samples.shape[0])
    samples = units.to_base(samples, unit)  # in base units a memory map stays mapped
    reference = units.to_base(reference, reference_unit or unit)
    target_std, target_range = units.to_base(target_std, unit), units.to_base(target_range, unit)
    problem = Problem(
        samples=samples,
        reference=reference,
        moments=accumulate(samples, reference),
        ipopt=IpoptOptions(print_level=5) if verbose else IpoptOptions(),
    )
    try:
        if method == "staged":
            rule = StopRule(
                max_cycles=cycles, target_std=target_std, target_range=target_range, rtol=rtol
            )
            theta, rows, stages, stop_reason = run_staged(problem, rule)
            hs = scaled_hessian(problem.moments, theta)
        else:
            step, rows, stages = run_joint(problem)
            theta, stop_reason = step.theta, "solved"
            hs = scaled_hessian(problem.moments, theta, step)
    except SolveError as failure:
        raise explain_failure(problem, failure) from None
    final = rows[-1]
    errors, identifiability = uncertainty(
        problem, final["objective"], hs, final["residual_lag1_autocorrelation"]
    )
    if identifiability["not_identifiable"]:  # theta is not to be trusted: the sphere's centre is
        centred = np.zeros(9)
        centred[0:3] = problem.moments.frame.centre
        identifiability["coverage"] = direction_coverage(samples, centred)
    else:
        identifiability["coverage"] = direction_coverage(samples, theta)
    base = units.base_unit(unit)
    warnings = warnings_for(problem, theta, hs, errors, identifiability, final, base)
    if method == "staged" and stop_reason == "max_cycles" and len(rows) > 2:
        warnings.append(
            f"the staged cycle stopped at the maximum of {cycles} cycles before "
            f"converging (rtol {rtol:g}); results may improve with more cycles, or with the "
            f"joint solve of all nine (method='joint', --method joint)"
        )
    mode = problem.moments.reference
    result = CalibrationResult(
        parameters=Zhou2010Parameters.from_theta(theta).to_dict(),
        statistics=rows,
        method=method,
        reference=problem.reference_document(),
        gauge=dict(GAUGE) if mode == "none" else None,
        solver={
            "name": "ipopt",
            "status": stages[-1]["status"],
            "success": True,
            "iterations": sum(s["iterations"] for s in stages),
            "stop_reason": stop_reason,
            "stages": stages,
        },
        unit=units.base_unit(unit),
        standard_errors=errors,
        identifiability=identifiability,
        warnings=warnings,
        n_samples=int(samples.shape[0]),
        input={"log_unit": unit},
    )
    if require_identifiable and identifiability["not_identifiable"]:
        unconverged = method == "staged" and stop_reason == "max_cycles" and len(rows) > 2
        raise QualityError(
            undetermined_message(errors, identifiability, final, problem.moments.reference, base)
            + (
                f" The staged cycle also stopped at its maximum of {cycles} cycles before "
                f"converging, so this may be the cycle's slowness rather than the data: try the "
                f"joint solve (--method joint, method='joint')."
                if unconverged
                else ""
            ),
            "Not_Identifiable",
            result=result,
        )
    return result


def calibrate_log(
    log: Log, *, target_std: float | None = None, target_range: float | None = None, **options
) -> CalibrationResult:
    """`calibrate` on a log read by `nlpcal.io.read_log` (its reference included).

    target_std, target_range : in the unit of the log's field columns.
    The result records the log (file, columns, unit) under `input`.
    """
    result = calibrate(
        log.samples,
        unit=log.base_unit,
        reference_field=log.reference,
        target_std=units.to_base(target_std, log.unit),
        target_range=units.to_base(target_range, log.unit),
        **options,
    )
    result.input = log.metadata()
    if log.reference_column:
        result.reference["column"] = log.reference_column
    return result


__all__ = [
    "CYCLES_DEFAULT",
    "METHODS",
    "RTOL_DEFAULT",
    "CalibrationResult",
    "Problem",
    "StopRule",
    "calibrate",
    "calibrate_log",
]
