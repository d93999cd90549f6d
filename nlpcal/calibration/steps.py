"""The steps of a calibration, in order: prepare, solve, diagnose, assemble, gate.

    data = prepare(samples, settings)               # units, checks, the moments (one pass)
    problem = data.problem(model, settings)
    solution = solve(problem, method, rule, unit)   # the staged cycle or the joint solve
    diagnosis = diagnose(problem, solution, method, rule, unit)   # what the data determine
    result = assemble(problem, solution, diagnosis, method, unit) # parameters, rows, result
    gate(result, problem, diagnosis, quality)       # QualityError unless the result is usable

`nlpcal.calibrate` runs them (`estimate` the last four, once per model tried); each takes the
settings it needs (`nlpcal.calibration.settings`).

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from .. import passes, units, validation
from ..errors import QualityError, SolveError
from ..inference import Z_975
from ..io.lazy import field_samples
from ..io.logs import settle_unit
from ..models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters
from ..moments import Frame, Moments, accumulate, recentred, sphere_frame
from ..nlp.blocks import GAUGE
from ..results import Provenance, TableRow
from ..robust import TUNING
from .coverage import coverage_centre, direction_coverage
from .diagnostics import (
    explain_failure,
    joint_gap,
    notes_for,
    problem_flatness,
    residual_spread,
    scaled_hessian,
    settle,
    uncertainty,
    undetermined_message,
    warnings_for,
)
from .joint import reweighting_limit_warning, run_joint
from .problem import Problem
from .result import BlockSolve, CalibrationResult, Identifiability, SolverReport
from .scores import ScoreSums
from .settings import CalibrationSettings, QualityGate
from .staged import StopRule, run_staged

#: A staged result further than this many standard errors from the joint optimum of the same
#: objective is not reported as an optimum (a bias of 0.2 standard errors adds 4 % to the
#: mean squared error). [1]
STAGED_GAP_LIMIT = 0.2
#: Why a staged cycle stopped without its rtol rule holding.
UNCONVERGED = ("max_cycles", "predicted_unconverged")
#: Least squares warns when the standard deviation of the residuals exceeds their robust one
#: (1.4826 MAD) by this factor: Gaussian residuals give 1. [1]
HEAVY_TAIL_RATIO = 1.5
#: A second-order bias above this many standard errors (of some parameter) is corrected: below
#: it the correction is within the noise of its own estimate; the Table 1 rows end with the
#: corrected estimate's. [1]
BIAS_APPLY = 0.1
#: A second-order bias above this many standard errors is a warning. [1]
BIAS_WARN = 0.5
#: The bias is corrected only while no standard error is widened by more than this for the
#: dependence of neighbouring samples: its formula takes the residuals for white sensor noise,
#: and residuals alike in neighbours are mostly a misfit (a disturbed field, a sensor beyond
#: the model), whose spread it would take for noise. [1]
BIAS_WHITE_WIDENING = 2.0


# --- prepare ---------------------------------------------------------------------------------


@dataclass
class Prepared:
    """The samples of a calibration in their base unit, with their reference and moments.

    samples : (N, 3) raw sensor output B_M. [unit]
    reference : None, a number or (N,) values F_i. [unit]
    moments : `nlpcal.moments.Moments` of the samples and the reference (one pass).
    unit : the base unit of the samples and of the result: "nT" or "raw".
    unit_source : where the unit came from: "option" or "assumed".
    warnings : the warnings about the unit (magnitudes far from Earth's field).
    """

    samples: np.ndarray
    reference: float | np.ndarray | None
    moments: Moments
    unit: str
    unit_source: str
    warnings: list = field(default_factory=list)

    def problem(self, model: str, settings: CalibrationSettings) -> Problem:
        """The calibration problem of the form `model` of Eq. 4 on these data: a new one each
        call (a robust loss reweights its moments)."""
        return Problem(
            samples=self.samples,
            reference=self.reference,
            moments=self.moments,
            loss=settings.loss,
            ipopt=settings.ipopt,
            model=model,
        )


def prepare(samples, settings: CalibrationSettings) -> Prepared:
    """Check the samples and the reference, take them to their base unit and gather their
    moments in one pass.

    A Dask array or DataFrame stays on its cluster (`prepare_lazy`). An assumed unit (none
    given) under which the magnitudes are far from Earth's field is taken as raw counts, with
    the warning (`nlpcal.io.logs.settle_unit`). Raises InputError for unusable samples or a
    reference in a unit that does not mix with theirs.
    """
    samples, reference = passes.lazy(field_samples(samples), settings.reference.field)
    if passes.is_lazy(samples) or passes.is_lazy(reference):
        return prepare_lazy(samples, reference, settings)
    samples = validation.samples(samples)
    reference = validation.reference(reference, samples.shape[0])
    samples, reference = in_base_units(samples, reference, settings)  # a memory map stays mapped
    # one sphere fit for the unit check and the moments' frame
    frame = sphere_frame(samples) if settings.input.unit_source == "assumed" else None
    unit, warnings = settled_unit(samples, reference, settings, frame)
    return Prepared(
        samples=samples,
        reference=reference,
        moments=accumulate(samples, reference, frame=frame),
        unit=units.base_unit(unit),
        unit_source=settings.input.unit_source,
        warnings=warnings,
    )


def in_base_units(samples, reference, settings: CalibrationSettings) -> tuple:
    """The samples and the reference in their base unit (from the unit given, else nT)."""
    unit = settings.input.given_unit
    return units.to_base(samples, unit), units.to_base(reference, settings.reference.unit or unit)


def settled_unit(samples, reference, settings: CalibrationSettings, frame=None) -> tuple:
    """(unit, warnings): an assumed unit checked against the magnitudes of the samples
    (`settle_unit`, with their sphere `frame` when fitted; ruled out, nT becomes raw counts: the
    same numbers, another name), its reference's unit against it, and the reference's scale
    against the samples'."""
    unit, source = settings.input.given_unit, settings.input.unit_source
    warnings = []
    if source == "assumed":  # the unit given is nT: factor 1, the samples stay as they are
        _, unit, warning = settle_unit(samples, unit, source, frame)
        warnings = [warning] if warning else []
        units.check_compatible(unit, settings.reference.unit or unit)
    validation.reference_scale(reference, validation.mean_magnitude(samples))
    return unit, warnings


def prepare_lazy(samples, reference, settings: CalibrationSettings) -> Prepared:
    """`prepare` for samples or a reference series that stay on a Dask cluster, in one pass.

    The pass that gathers the moments gathers the survey too (`nlpcal.passes.reduce`), and a
    reader's pending checks settle in it; so the checks that read the survey (the ranges of the
    values, a series' signs, the unit's plausibility, the reference's scale) come after it, on
    the survey, and refuse the log as they would before it. The assumed unit they may rule out
    is nT, whose numbers are also the raw counts: the moments stay valid under the new name.
    The frame of that pass, needed before it, is fitted to the log's first block
    (`first_frame`) and kept unless it lies far from the frame the samples in memory get
    (`reframed`).
    """
    samples = validation.vectors(
        samples, minimum=validation.MIN_SAMPLES, purpose="for nine parameters"
    )
    if not passes.is_lazy(reference):
        reference = validation.reference(reference, samples.shape[0])
    samples, reference = in_base_units(samples, reference, settings)
    frame, length = first_frame(samples, reference)
    if all(v.surveyed for v in (samples, reference) if isinstance(v, passes.LazySamples)):
        # surveyed already (a log kept in memory, a short series): checked before the pass
        reference = validation.reference(reference, validation.samples(samples).shape[0])
    try:
        moments = accumulate(samples, reference, frame=frame, length=length)
    except ArithmeticError:  # on values the checks of the survey refuse: they say which
        validation.reference(reference, validation.samples(samples).shape[0])
        raise
    samples = validation.samples(samples)  # from the survey the pass gathered
    reference = validation.reference(reference, samples.shape[0])
    frame = sphere_frame(samples)  # on the survey's subsample, as in memory
    unit, warnings = settled_unit(samples, reference, settings, frame)
    return Prepared(
        samples=samples,
        reference=reference,
        moments=reframed(moments, frame, samples, reference),
        unit=units.base_unit(unit),
        unit_source=settings.input.unit_source,
        warnings=warnings,
    )


def first_frame(samples, reference) -> tuple:
    """(frame, length) of the first pass over a Dask log: the sphere fitted to its first block
    (`nlpcal.passes.first_block_sample`: the rows of one block the fit reads, not a pass), and
    the length the moments take (the sphere's radius, the constant reference or the rms of the
    series on the same rows). [field unit]"""
    rows = passes.first_block_rows(samples)
    # NaN refused before the fit (in the other rows, by the reader's checks in the first pass)
    head = validation.finite_vectors(np.asarray(samples[rows], dtype=float))
    with np.errstate(all="ignore"):  # values not yet checked: the survey's checks refuse them
        frame = sphere_frame(head)
        if not (np.isfinite(frame.centre).all() and 0 < frame.radius < np.inf):
            # any frame: the survey's checks refuse the values, or `reframed` runs the pass again
            frame = Frame(centre=np.zeros(3), radius=1.0)
        if reference is None:
            return frame, frame.radius
        if np.ndim(reference) == 0:
            return frame, float(reference)
        first = np.asarray(reference[rows], dtype=float)
        finite = first[np.isfinite(first)]
        length = float(np.sqrt(np.mean(finite**2))) if finite.size else 0.0
    return frame, length if 0 < length < np.inf else frame.radius


#: The first pass's frame is kept while its centre lies within this fraction of the final
#: length from the centre the samples in memory get, and the two radii differ by less than this
#: fraction: a moment of degree <= 8 about it then sums terms at most (1 + 0.05)^8 = 1.5 times
#: its size, as well conditioned as in the final frame. Further away (a first block of a few
#: attitudes, whose sphere is poorly determined), the pass runs again in the final frame. [1]
REFRAME_LIMIT = 0.05


def reframed(moments: Moments, frame, samples, reference) -> Moments:
    """The moments the solves read: those of the first pass, in its own frame, while that frame
    is within REFRAME_LIMIT of `frame` (the sphere the samples in memory get); else gathered
    again in `frame` (a pass more, counted).

    They are not moved to `frame` by the algebra (`nlpcal.moments.recentred`): a change of
    centre combines each small a^k moment from larger ones (M4), and the rounding of the pass's
    summation order, about 1e-15, comes out at 1e-12 to 1e-10 of the small entries, which moved
    a joint fit of 10^7 samples by 8e-3 standard errors between two cluster layouts. Solved in
    the first frame, the fit equals the in-memory one to 1e-8 standard errors. A reference
    series' moments are only re-scaled to the rms of the whole series (M4 with delta = 0, a
    diagonal map: no rounding is mixed in).
    """
    length = moments_length(frame, reference)
    shift = float(np.linalg.norm(frame.centre - moments.frame.centre)) / length
    if max(shift, abs(np.log(frame.radius / moments.frame.radius))) > REFRAME_LIMIT:
        return accumulate(samples, reference, frame=frame, length=length)
    if moments.reference == "series":
        return recentred(moments, moments.frame, length)
    return moments


def moments_length(frame, reference) -> float:
    """L of the moments (`accumulate`): the sphere's radius, the constant reference or the
    rms of the series. [field unit]"""
    if reference is None:
        return frame.radius
    if np.ndim(reference) == 0:
        return float(reference)
    return float(np.sqrt(passes.mean_square(reference)))


# --- solve -----------------------------------------------------------------------------------


@dataclass
class Solution:
    """Where a solve ended: the parameters, the Table 1 rows, the solver report and the Hessian.

    theta : the nine parameters (internal units: offsets [unit], scale errors [1], angles
        [rad]).
    rows : Table 1 rows, the measured |B_M| first.
    report : what finished each block solve, and why the solve stopped.
    hessian : the Hessian of the objective in the scaled variables (`scaled_hessian`).
    scores : the scores at theta, gathered by the pass after the solve with its rows.
    """

    theta: np.ndarray
    rows: list[TableRow]
    report: SolverReport
    hessian: np.ndarray
    scores: ScoreSums | None = None


def solve(
    problem: Problem, method: str, rule: StopRule, unit: str, progress: Callable | None = None
) -> Solution:
    """Solve a calibration problem by the staged cycle of Fig. 1 in [1] (`run_staged`, stopped
    by `rule`, `progress` called after each cycle) or jointly (`run_joint`).

    The Table 1 rows no step of the solve reads are gathered after it, with the scores at the
    solution, in one pass over the data (`settle`).

    Raises SolveError, explained in words of the data (`explain_failure`), when a solve fails.
    """
    try:
        if method == "staged":
            theta, rows, stages, stop_reason = run_staged(problem, rule, progress, defer=True)
            report = SolverReport(
                stages, stop_reason=stop_reason, ipopt_options=problem.ipopt.settings()
            )
            hessian = scaled_hessian(problem.moments, theta)
        else:
            step, rows, report = run_joint(problem, defer=True)
            theta, hessian = step.theta, scaled_hessian(problem.moments, step.theta, step)
    except SolveError as failure:
        problem.deferred = []
        raise explain_failure(problem, failure, method, unit) from None
    return Solution(theta, rows, report, hessian, settle(problem, theta))


# --- diagnose --------------------------------------------------------------------------------


@dataclass
class Diagnosis:
    """What the data determine about a solution, and what is wrong with it.

    errors, covariance : the standard errors and covariance the result states, or None when
        they describe no optimum (a staged result away from it, samples in a plane).
    point_errors : the standard errors at the solution, which the quality gate judges.
    identifiability : the result's identifiability block.
    warnings : what looks wrong, each a sentence.
    robust : the result's robust block (the loss, its scale and the residuals' spread).
    final : the Table 1 row of the solution (the last of the solve).
    stop_reason : why the solve stopped ("above_joint_optimum" for a staged cycle that
        converged by its rtol rule away from the joint optimum).
    unconverged : why a staged result is not at the optimum, when that refuses it.
    """

    errors: dict | None
    covariance: np.ndarray | None
    point_errors: dict | None
    identifiability: Identifiability
    warnings: list
    robust: dict
    final: TableRow
    stop_reason: str
    unconverged: str | None = None


def diagnose(
    problem: Problem, solution: Solution, method: str, rule: StopRule, unit: str
) -> Diagnosis:
    """The standard errors and identifiability of a solution, and its warnings: parameters the
    data leave undetermined, samples in a plane, the attitudes covered, heavy tails or a robust
    reweighting stopped at its limit, and a staged result away from the joint optimum."""
    theta, final = solution.theta, solution.rows[-1]
    objective = final.objective or 0.0  # a solved row has one
    scores = solution.scores if solution.scores is not None else settle(problem, theta)
    residuals = problem.residuals(theta, problem.centre)  # the bias's and the spread's
    errors, identifiability, covariance = uncertainty(
        problem, objective, solution.hessian, theta, final.mean, scores, residuals
    )
    spread = residual_spread(problem, theta, residuals)
    del residuals  # a few buffers of memory (`judge_attitudes` takes its own)
    judge_attitudes(problem, theta, spread, identifiability)
    warnings = warnings_for(
        problem, theta, solution.hessian, errors, identifiability, final, scores, unit
    )
    diagnosis = Diagnosis(
        errors=errors,
        covariance=covariance,
        point_errors=errors,
        identifiability=identifiability,
        warnings=warnings,
        robust=robust_block(problem, spread, final, solution.report, warnings),
        final=final,
        stop_reason=solution.report.stop_reason,
    )
    if method == "staged":
        judge_staged(problem, theta, rule, solution, diagnosis)
    if identifiability.planar:  # along the plane's normal no linearisation
        diagnosis.errors = diagnosis.covariance = None  # describes the data
    return diagnosis


def judge_attitudes(
    problem: Problem, theta, spread: dict, identifiability: Identifiability
) -> None:
    """Add to `identifiability` whether the samples lie in a plane ("flatness", whose blind
    parameters join "not_identifiable") and the directions the field visits ("coverage")."""
    samples = problem.samples
    flat = problem_flatness(problem, theta, spread)
    flat["parameters"] = [n for n in flat["parameters"] if n in problem.estimated]
    identifiability.flatness = flat
    if flat["planar"]:  # the Hessian at a degenerate optimum can look healthy
        blind = set(flat["parameters"]) | set(identifiability.not_identifiable or [])
        identifiability.not_identifiable = [n for n in PARAMETER_NAMES if n in blind]
    if identifiability.not_identifiable:  # theta is not to be trusted: judge the directions
        centred = np.zeros(9)  # about the fitted sphere's centre, or the samples' mean when the
        centred[0:3] = coverage_centre(samples, problem.moments.frame)  # sphere is degenerate
        identifiability.coverage = direction_coverage(samples, centred)
    else:
        identifiability.coverage = direction_coverage(samples, theta)


def robust_block(
    problem: Problem, spread: dict, final: TableRow, report: SolverReport, warnings: list
) -> dict:
    """The result's robust block: the loss, its scale and the residuals' spread; with a robust
    loss where its scale came from and what it down-weighted. Appends to `warnings` a robust
    reweighting stopped at its limit, or least-squares residuals with heavy tails."""
    robust = {**problem.loss.to_dict(), **spread}
    if problem.loss.robust:
        robust.update(
            scale_source="given"
            if problem.scale_given
            else f"1.4826 MAD x {TUNING[problem.loss.kind]:g}",
            reweightings=problem.reweights,
            downweighted=final.downweighted,
            downweighted_fraction=(final.downweighted or 0) / len(problem.samples),
            centre=problem.centre,
        )
        limit = reweighting_limit_warning(report)
        if limit:
            warnings.append(limit)
    elif spread["residual_std"] > HEAVY_TAIL_RATIO * spread["residual_robust_std"]:
        warnings.append(
            f"the residuals are heavy-tailed (std {spread['residual_std']:.3g}, robust std "
            f"{spread['residual_robust_std']:.3g}): spikes or disturbances may pull the least-"
            f"squares estimate; a robust loss (--loss huber) down-weights them"
        )
    return robust


def judge_staged(
    problem: Problem, theta, rule: StopRule, solution: Solution, diagnosis: Diagnosis
) -> None:
    """Check a staged result against the joint optimum of the same objective (`joint_gap`,
    into identifiability "joint_gap"). Further than STAGED_GAP_LIMIT standard errors from it, or
    not checkable, it states no standard errors and is warned about; a cycle that stopped on its
    limit or its prediction, or converged by its rtol rule away from the optimum, is
    unconverged (the gate refuses it unless allowed). Within the limit, a cycle stopped before
    its rtol rule held is only said."""
    stop_reason, rows = diagnosis.stop_reason, solution.rows
    gap = joint_gap(problem, theta, diagnosis.errors)
    diagnosis.identifiability.joint_gap = gap
    distance = gap["max_gap_in_standard_errors"]
    checked = "objective_joint" in gap and distance is not None
    if not checked or distance > STAGED_GAP_LIMIT:
        message = staged_message(stop_reason, rule.max_cycles, gap, solution.report.last)
        diagnosis.warnings.append(message)
        diagnosis.identifiability.standard_errors_at_joint_optimum = diagnosis.errors
        diagnosis.errors = diagnosis.covariance = None  # they describe an optimum, not this point
        # a target stop is the user's request; a cycle that converged by its rtol rule but
        # cannot be checked (no standard errors, no joint optimum) keeps its warning
        if stop_reason in UNCONVERGED or (stop_reason == "rtol" and checked):
            diagnosis.stop_reason = (
                stop_reason if stop_reason in UNCONVERGED else "above_joint_optimum"
            )
            diagnosis.unconverged = message
    elif stop_reason in UNCONVERGED and len(rows) > 2:
        when = (
            f"at the maximum of {rule.max_cycles} cycles"
            if stop_reason == "max_cycles"
            else f"after {len(rows) - 1} cycles, predicting that it could not meet it "
            f"within {rule.max_cycles}"
        )
        diagnosis.warnings.append(
            f"the staged cycle stopped {when} before its rtol rule ({rule.rtol:g}) held; its "
            f"parameters agree with the joint optimum of the same data within "
            f"{STAGED_GAP_LIMIT:g} standard errors"
        )


def staged_message(stop_reason: str, cycles: int, gap: dict, last: BlockSolve | None = None) -> str:
    """Why a staged result is not at the optimum, with both objectives and what to do.

    last : the record of the last stage (its predicted cycles when the cycle stopped early).
    """
    if stop_reason == "predicted_unconverged" and last is not None:
        why = (
            f"the staged cycle stopped after {last.cycle} cycles, predicting from its rate of "
            f"convergence (each cycle's improvement {last.convergence_rate:.4g} times the one "
            f"before) that its rtol rule would need about {last.predicted_cycles} cycles, "
            f"more than its limit of {cycles}"
        )
        advice = "use --method joint, or --allow-unconverged to run to the limit"
    else:
        why = (
            f"the staged cycle stopped at its limit of {cycles} cycles"
            if stop_reason == "max_cycles"
            else f"the staged cycle stopped on its {stop_reason} rule"
        )
        advice = "use --method joint, or more --cycles"
    distance = gap.get("max_gap_in_standard_errors")
    if "objective_joint" not in gap:
        return (
            f"{why}, and the joint optimum of the same data, to check it against, could not "
            f"be found ({gap['status']}); rotate the sensor through more attitudes"
        )
    if distance is None:
        return (
            f"{why}; without standard errors its distance from the joint optimum "
            f"({gap['objective_joint']:.6g} against {gap['objective_staged']:.6g}) cannot be "
            f"judged"
        )
    return (
        f"{why}; its objective {gap['objective_staged']:.6g} lies above the joint optimum "
        f"{gap['objective_joint']:.6g} of the same data; its parameters lie up to "
        f"{distance:.3g} standard errors from that optimum; {advice}"
    )


# --- assemble --------------------------------------------------------------------------------


def assemble(
    problem: Problem, solution: Solution, diagnosis: Diagnosis, method: str, unit: str
) -> CalibrationResult:
    """The result of a solve: its parameters (corrected for their second-order bias where
    `correct_bias` applies it, with a "bias corrected" Table 1 row; or the standard errors
    widened by it), the rows, the solver report, the diagnosis and how the problem was posed."""
    identifiability, warnings = diagnosis.identifiability, diagnosis.warnings
    errors, covariance = diagnosis.errors, diagnosis.covariance
    rows = solution.rows
    parameters = Zhou2010Parameters.from_theta(solution.theta).to_dict()
    bias = identifiability.second_order_bias
    if bias is not None:
        parameters = correct_bias(parameters, bias, identifiability, warnings, errors is not None)
        if bias["applied"]:
            corrected = Zhou2010Parameters.from_dict(parameters).theta
            rows.append(problem.row("bias corrected", corrected, iterations=0, wall_s=0.0))
        elif bias.get("widened") and errors is not None:  # widened only when stated
            errors, covariance = widened_for_bias(errors, covariance, bias["bias"])
    report = replace(
        solution.report,
        stop_reason=diagnosis.stop_reason,
        converged=diagnosis.unconverged is None,
    )
    return CalibrationResult(
        parameters=parameters,
        statistics=rows,
        method=method,
        reference=problem.reference_document(),
        gauge=dict(GAUGE) if problem.moments.reference == "none" else None,
        solver=report,
        unit=unit,
        standard_errors=errors,
        covariance=covariance,
        identifiability=identifiability,
        warnings=warnings,
        notes=notes_for(problem),
        n_samples=int(problem.samples.shape[0]),
        input=Provenance(log_unit=unit),
        robust=diagnosis.robust,
        model_name=problem.model,
    )


def correct_bias(
    parameters: dict,
    block: dict,
    identifiability: Identifiability,
    warnings: list,
    stated: bool = True,
) -> dict:
    """The parameters with their second-order bias (`diagnostics.noise_bias`) removed when it
    exceeds BIAS_APPLY standard errors, the residuals pass for white noise (no standard error
    widened beyond BIAS_WHITE_WIDENING) and the sensor's noise is told apart from a reference
    series' (`noise_separable`); `block` records whether it was applied, the estimate before
    the correction ("parameters_uncorrected") or why not ("not_applied"), and whether the
    standard errors are to be widened by it instead ("widened": the noise cannot be told
    apart). `stated` : False when the result states no standard errors (then nothing is
    corrected). A bias above BIAS_WARN standard errors is a warning either way."""
    in_errors = block["bias_in_standard_errors"]
    widening = (identifiability.score_dependence or {}).get("standard_error_widening", {})
    white = max(widening.values(), default=1.0) <= BIAS_WHITE_WIDENING
    separable = block.get("noise_separable", True)
    large_enough = max(abs(v) for v in in_errors.values()) > BIAS_APPLY
    block["applied"] = stated and white and separable and large_enough
    block["widened"] = stated and white and not separable and large_enough
    if not stated:
        block["not_applied"] = "the result states no standard errors"
        why = "not corrected, for the result states no standard errors at this point"
    elif not white:
        block["not_applied"] = (
            "neighbouring samples are alike: the residuals are not white sensor noise"
        )
        why = (
            "not corrected, for the residuals are not white sensor noise (their neighbours "
            "are alike), which its estimate assumes"
        )
    elif not separable:
        block["not_applied"] = (
            "the reference's own noise cannot be told apart from the sensor's: the standard "
            "errors are widened by the bias instead"
        )
        why = (
            "not corrected, for the reference series' own noise cannot be told apart from the "
            "sensor's, which its estimate assumes; the standard errors are widened by it"
        )
    else:
        why = (
            "the parameters are corrected for it (identifiability.second_order_bias keeps the "
            "uncorrected ones)"
        )
    large = {n: v for n, v in in_errors.items() if abs(v) > BIAS_WARN}
    if large:
        worst = max(large, key=lambda n: abs(large[n]))
        warnings.append(
            f"the estimate's second-order bias from the sensor noise reaches "
            f"{large[worst]:+.2f} standard errors ({worst}) along a direction the attitudes "
            f"barely determine; {why}"
        )
    if not block["applied"]:
        return parameters
    block["parameters_uncorrected"] = dict(parameters)
    bias = block["bias"]
    return {name: value - bias.get(name, 0.0) for name, value in parameters.items()}


def widened_for_bias(errors: dict, covariance, bias: dict) -> tuple:
    """(errors, covariance) with each standard error widened by |bias| / Z_975, so that its
    +/-1.96 SE interval is wider by |bias| on either side; the covariance scaled alike
    (correlations kept)."""
    widened = {name: se + abs(bias.get(name, 0.0)) / Z_975 for name, se in errors.items()}
    factor = np.array([widened[name] / se if se > 0 else 1.0 for name, se in errors.items()])
    return widened, np.asarray(covariance) * np.outer(factor, factor)


# --- gate ------------------------------------------------------------------------------------


def gate(
    result: CalibrationResult, problem: Problem, diagnosis: Diagnosis, quality: QualityGate
) -> CalibrationResult:
    """The result, unless `quality` refuses it: QualityError (holding the result, and the
    settings that would accept it) when the data leave parameters undetermined
    ("Not_Identifiable", unless not required) or a staged cycle did not converge
    ("Staged_Unconverged", unless allowed)."""
    unconverged = None if quality.allow_unconverged else diagnosis.unconverged
    overrides = {"allow_unconverged": True} if unconverged else {}
    identifiability = diagnosis.identifiability
    if quality.require_identifiable and identifiability.not_identifiable:
        also = f" Besides, {unconverged[0].lower()}{unconverged[1:]}." if unconverged else ""
        message = undetermined_message(
            diagnosis.point_errors,
            identifiability,
            diagnosis.final,
            problem.moments.reference,
            result.unit,
            problem.model,
        )
        raise QualityError(
            message + also,
            "Not_Identifiable",
            result=result,
            overrides={"require_identifiable": False, **overrides},
        )
    if unconverged:
        raise QualityError(unconverged, "Staged_Unconverged", result=result, overrides=overrides)
    return result
