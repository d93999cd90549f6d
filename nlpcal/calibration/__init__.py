"""`nlpcal.calibrate`: the nine-parameter calibration of Zhou et al. (2010) on a log.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .. import chunks, passes, units, validation
from ..errors import QualityError, SolveError
from ..inference import Z_975
from ..io.lazy import field_samples
from ..io.logs import Log, settle_unit
from ..models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters
from ..moments import accumulate
from ..nlp.blocks import GAUGE, OPTIONS
from ..robust import TUNING, Loss
from .channels import (
    attach,
    check_aux_options,
    fit_channels,
    log_channels,
    prepare_channels,
)
from .coverage import coverage_centre, direction_coverage
from .diagnostics import (
    explain_failure,
    joint_gap,
    notes_for,
    problem_flatness,
    residual_spread,
    scaled_hessian,
    uncertainty,
    undetermined_message,
    warnings_for,
)
from .joint import reweighting_limit_warning, run_joint
from .problem import Problem
from .result import BlockSolve, CalibrationResult, SolverReport
from .selection import MODEL_CHOICES, choose_model, restriction_warning, selection_warning
from .staged import CYCLES_DEFAULT, RTOL_DEFAULT, StopRule, run_staged

METHODS = ("staged", "joint")
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


def calibrate(
    samples,
    *,
    method: str = "staged",
    model: str = "full",
    reference_field=None,
    unit: str | None = None,
    reference_unit: str | None = None,
    cycles: int = CYCLES_DEFAULT,
    target_std: float | None = None,
    target_range: float | None = None,
    rtol: float = RTOL_DEFAULT,
    loss: str = "l2",
    loss_scale: float | None = None,
    require_identifiable: bool = True,
    allow_unconverged: bool = False,
    progress=None,
    verbose: bool = False,
    threads: int | None = None,
    ipopt_options: dict | None = None,
    aux_columns=None,
    aux_kind=None,
) -> CalibrationResult:
    """Estimate the nine parameters of Eq. 4 in [1] from a log of many attitudes.

    The parameters minimise the spread of the corrected total field |B1| (Eq. 8), or its distance to
    a reference field, as CasADi/IPOPT problems whose size does not depend on N.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw sensor output B_M: a numpy or Dask array, or a pandas or Dask DataFrame whose field
        columns are detected. [unit]
    method : {"staged", "joint"}
        "staged", the cycle of Fig. 1 in [1] (orthogonal -> scale -> offset), or "joint", all nine
        in one IPOPT problem (`--method`).
    model : {"full", "diagonal", "offset", "auto"}
        The form of Eq. 4 estimated (`--model`): "full" (the nine, the paper's), "diagonal"
        (offsets and scales, no angles), "offset" (offsets; with a reference also one common scale),
        or "auto": the richest of them the attitudes determine, with the reason under
        `model_selection`. The parameters a form does not estimate are fixed at zero and listed
        under `fixed_parameters`.
    reference_field : None, float or array_like of shape (N,)
        None (Eq. 8, absolute scale not identifiable: the gauge s_x + s_y + s_z = 0 fixes it), a
        number F, or N values F_i, for example a proton magnetometer sampled with the log
        (`--reference-field`). [reference_unit]
    unit : str, optional
        The unit of the samples (`--unit`): nT, uT, mT, mG, G, T, or raw for counts. The result is
        in nT (or raw), whatever the unit of the samples, and records the unit as given
        (`unit_source` "option"). None assumes nT ("assumed"): when the magnitudes are far from
        Earth's field in nT, the samples are taken as raw counts and the result is in raw, with
        the warning.
    reference_unit : str, optional
        The unit of the reference (default: `unit`).
    cycles : int
        The most staged cycles (`--cycles`).
    target_std, target_range : float, optional
        Stop the staged cycle when the std (or the range) of |B1| meets them. [unit]
    rtol : float
        Stop the staged cycle when a cycle lowers the objective by less than this fraction. [1]
    loss : {"l2", "huber", "cauchy"}
        "l2" (least squares, the paper's), or a loss robust to spikes and other outliers, by
        iteratively reweighted moments (`--loss`).
    loss_scale : float, optional
        The residual beyond which a sample is down-weighted (`--loss-scale`); default 1.345 (Huber)
        or 2.385 (Cauchy) times 1.4826 MAD of the residuals. [unit]
    require_identifiable : bool
        Raise QualityError (holding the result) when the data leave parameters undetermined (a
        direction along which |B1| does not change, or a standard error above 10 % of the field,
        0.1 or 10 deg); False returns the result with its warnings (`--allow-unidentifiable`).
    allow_unconverged : bool
        Return a staged result that stopped at its cycle limit, or away from the joint optimum of
        the same objective, with a warning and without standard errors, instead of raising
        QualityError (`--allow-unconverged`).
    progress : callable, optional
        Called with (cycle, Table 1 row) after every staged cycle.
    verbose : bool
        Print IPOPT's log of every solve (on stdout, as CasADi does).
    threads : int, optional
        Threads of the passes over the data (`--threads`; default: the cores available to the
        process, its CPU affinity within its cgroup's quota); BLAS is held to one thread meanwhile.
    ipopt_options : dict, optional
        Further IPOPT options (`--ipopt-option KEY=VALUE`): name -> int, float or str, as IPOPT
        types them ({"max_iter": 50, "mu_strategy": "adaptive"}), over nlpcal's own
        (`nlpcal.nlp.blocks.OPTIONS`). IPOPT checks them first (InputError for an option it does
        not know or a value it refuses); the result records every option IPOPT was given under
        `solver.ipopt_options`.
    aux_columns : list of str or mapping, optional
        Auxiliary channels c_k (`--aux-columns`): columns of a DataFrame `samples`, or a mapping
        of names to (N,) values. Their stray fields v_k c_k are estimated jointly with the nine
        parameters, B1 = O_p S_p (B_M - Z_p - sum_k v_k c_k) (`nlpcal.calibration.channels`),
        and recorded under the result's `aux`. Least squares with the model "full", "diagonal"
        or "offset". [channel unit]
    aux_kind : str or list of str, optional
        What each channel is (`--aux-kind`): "current" [A], "throttle" [fraction] or "other"
        (the default), one for all or one per channel.

    Returns
    -------
    CalibrationResult
        The parameters (offsets [nT or raw], scale errors [1], angles [deg]), their standard errors,
        Table 1 rows, the verdict and how the problem was posed.

    Raises
    ------
    InputError
        Unusable samples or options (too few rows, NaN, an unknown unit or method).
    SolveError
        IPOPT failed.
    QualityError
        The data leave parameters undetermined, or a staged cycle did not converge, as above.

    References
    ----------
    [1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> import nlpcal
    >>> log = nlpcal.simulate(2000, seed=1)  # the truth of Zhou et al.'s Table 1, 1 nT of noise
    >>> samples = log[["bx", "by", "bz"]].to_numpy()
    >>> result = nlpcal.calibrate(samples, reference_field=49462.0, method="joint")
    >>> result.verdict.status
    'ok'
    >>> abs(result.parameters["z_x"] - (-71.55)) < 5 * result.standard_errors["z_x"]
    True
    >>> corrected = result.apply(samples)  # Eq. 4, in the unit of the samples [nT]
    >>> corrected.shape
    (2000, 3)
    """
    with chunks.call_threads(validation.optional_whole(threads, "threads")):
        validation.choice(method, "method", METHODS)
        validation.choice(model, "model", MODEL_CHOICES)
        ipopt = (replace(OPTIONS, print_level=5) if verbose else OPTIONS).with_options(
            ipopt_options
        )
        unit_source = "assumed" if unit is None else "option"
        unit = "nT" if unit is None else unit
        units.field_factor(unit)
        cycles = validation.count(cycles, "cycles")
        target_std = validation.optional_number(target_std, "target_std", positive=True)
        target_range = validation.optional_number(target_range, "target_range", positive=True)
        rtol = validation.number(rtol, "rtol", minimum=0.0)
        units.check_compatible(unit, reference_unit or unit)
        chosen_loss = Loss(
            loss,
            units.to_base(
                validation.optional_number(loss_scale, "the loss scale", positive=True), unit
            ),
        )
        channels = None
        if aux_columns is not None:
            check_aux_options(loss, model)
            samples, channels = prepare_channels(samples, aux_columns, aux_kind)
        # A Dask array or DataFrame stays on its cluster: one survey pass checks it (passes).
        samples, reference_field = passes.surveyed(field_samples(samples), reference_field)
        samples = validation.samples(samples)
        reference = validation.reference(reference_field, samples.shape[0])
        samples = units.to_base(samples, unit)  # in base units a memory map stays mapped
        unit_warnings = []
        if unit_source == "assumed":
            samples, unit, unit_warning = settle_unit(samples, unit, unit_source)
            unit_warnings = [unit_warning] if unit_warning else []
            units.check_compatible(unit, reference_unit or unit)
        reference = units.to_base(reference, reference_unit or unit)
        target_std, target_range = (
            units.to_base(target_std, unit),
            units.to_base(target_range, unit),
        )
        validation.reference_scale(reference, validation.mean_magnitude(samples))
        moments = raw_moments = accumulate(samples, reference)
        fit = None
        if channels is not None:  # the joint solve; the nine's estimate on the compensated log
            fit = fit_channels(
                samples, channels, reference, moments, model, ipopt, require_identifiable
            )
            samples = fit.compensated(samples)
            moments = accumulate(samples, reference)

        def problem_for(form: str) -> Problem:
            return Problem(
                samples=samples,
                reference=reference,
                moments=moments,
                loss=chosen_loss,
                ipopt=ipopt,
                model=form,
            )

        rule = StopRule(
            max_cycles=cycles,
            target_std=target_std,
            target_range=target_range,
            rtol=rtol,
            predict=not allow_unconverged,  # the user asked to run to the limit
            every_row_exact=False,
        )
        base = units.base_unit(unit)
        selection = None
        if model == "auto":  # each form judged on its joint solve, the staged cycle's optimum
            model, selection = choose_model(
                lambda form: estimate(problem_for(form), "joint", rule, base, quality=False)
            )
        try:
            result = estimate(
                problem_for(model),
                method,
                rule,
                base,
                progress=progress,
                require_identifiable=require_identifiable,
                allow_unconverged=allow_unconverged,
            )
        except SolveError as failure:  # a QualityError holds the result: it records the choice
            if isinstance(failure.result, CalibrationResult):
                record_unit(failure.result, unit_source, unit_warnings)
                if selection is not None:
                    record_selection(failure.result, selection)
            raise
        record_unit(result, unit_source, unit_warnings)
        if fit is not None:
            attach(result, fit, raw_moments)
        if selection is not None:
            record_selection(result, selection)
        elif model != "full":  # a form the user chose: do the data contradict what it fixes?
            check_restriction(result, problem_for(model), problem_for("full"), rule, base)
        return result


def check_restriction(
    result: CalibrationResult, restricted: Problem, full: Problem, rule: StopRule, base: str
) -> None:
    """Warn when the log contradicts the parameters a restricted model fixes
    (`selection.restriction_warning`), judged against the full model's joint solve on the same
    moments; a full model the data do not determine says nothing, and no warning is given. The
    test compares variances of |B1|: a robust fit's objective is none, and is not judged."""
    if restricted.loss.robust:
        return
    try:
        reference = estimate(full, "joint", rule, base, quality=False)
    except SolveError:
        return
    if reference.identifiability.get("not_identifiable"):
        return
    freed = (full.free.basis.shape[1], restricted.free.basis.shape[1])
    warning = restriction_warning(result, reference, freed)
    if warning:
        result.warnings.append(warning)


def record_unit(result: CalibrationResult, source: str, warnings: list) -> None:
    """Record where a result's unit came from, and the warnings about it first."""
    result.unit_source = source
    result.warnings[:0] = warnings


def record_selection(result: CalibrationResult, selection: dict) -> None:
    """Record how model "auto" chose a result's model; a restricted choice is its first warning
    (the correction assumes the parameters it fixes)."""
    result.model_selection = selection
    if selection["chosen"] != "full":
        result.warnings.insert(0, selection_warning(selection))


def estimate(
    problem: Problem,
    method: str,
    rule: StopRule,
    base: str,
    *,
    progress=None,
    quality: bool = True,
    require_identifiable: bool = True,
    allow_unconverged: bool = False,
) -> CalibrationResult:
    """Solve one calibration problem by `method`, judge what the data determine and build its
    result (`calibrate`): the model's parameters, Table 1 rows, standard errors, identifiability
    and warnings.

    base : the unit of the result (nT or raw). quality : raise QualityError as `calibrate` does
    (False returns every result that solved, as with require_identifiable=False and
    allow_unconverged=True). Raises SolveError when the solve fails.
    """
    try:
        if method == "staged":
            theta, rows, stages, stop_reason = run_staged(problem, rule, progress)
            report = SolverReport(stages, ipopt_options=problem.ipopt.settings())
            hs = scaled_hessian(problem.moments, theta)
        else:
            step, rows, report = run_joint(problem)
            theta, stop_reason, stages = step.theta, report.stop_reason, report.stages
            hs = scaled_hessian(problem.moments, theta, step)
    except SolveError as failure:
        raise explain_failure(problem, failure, method, base) from None
    samples = problem.samples
    final = rows[-1]
    errors, identifiability, covariance = uncertainty(
        problem, final["objective"], hs, theta, final["mean"]
    )
    spread = residual_spread(problem, theta)
    flat = problem_flatness(problem, theta, spread)
    flat["parameters"] = [n for n in flat["parameters"] if n in problem.estimated]
    identifiability["flatness"] = flat
    if flat["planar"]:  # the Hessian at a degenerate optimum can look healthy
        blind = set(flat["parameters"]) | set(identifiability["not_identifiable"])
        identifiability["not_identifiable"] = [n for n in PARAMETER_NAMES if n in blind]
    if identifiability["not_identifiable"]:  # theta is not to be trusted: judge the directions
        centred = np.zeros(9)  # about the fitted sphere's centre, or the samples' mean when the
        centred[0:3] = coverage_centre(samples, problem.moments.frame)  # sphere is degenerate
        identifiability["coverage"] = direction_coverage(samples, centred)
    else:
        identifiability["coverage"] = direction_coverage(samples, theta)
    warnings = warnings_for(problem, theta, hs, errors, identifiability, final, base)
    point_errors = errors  # the standard errors at theta, which the quality check judges
    robust = {**problem.loss.to_dict(), **spread}
    if problem.loss.robust:
        robust.update(
            scale_source="given"
            if problem.scale_given
            else f"1.4826 MAD x {TUNING[problem.loss.kind]:g}",
            reweightings=problem.reweights,
            downweighted=final["downweighted"],
            downweighted_fraction=final["downweighted"] / len(samples),
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
    unconverged = None
    if method == "staged":
        gap = joint_gap(problem, theta, errors)
        identifiability["joint_gap"] = gap
        distance = gap["max_gap_in_standard_errors"]
        checked = "objective_joint" in gap and distance is not None
        if not checked or distance > STAGED_GAP_LIMIT:
            message = staged_message(stop_reason, rule.max_cycles, gap, stages[-1])
            warnings.append(message)
            identifiability["standard_errors_at_joint_optimum"] = errors
            errors = covariance = None  # they describe an optimum, not this point
            # a target stop is the user's request; a cycle that converged by its rtol rule but
            # cannot be checked (no standard errors, no joint optimum) keeps its warning
            if stop_reason in UNCONVERGED or (stop_reason == "rtol" and checked):
                stop_reason = stop_reason if stop_reason in UNCONVERGED else "above_joint_optimum"
                unconverged = message
        elif stop_reason in UNCONVERGED and len(rows) > 2:
            when = (
                f"at the maximum of {rule.max_cycles} cycles"
                if stop_reason == "max_cycles"
                else f"after {len(rows) - 1} cycles, predicting that it could not meet it "
                f"within {rule.max_cycles}"
            )
            warnings.append(
                f"the staged cycle stopped {when} before its rtol rule ({rule.rtol:g}) held; its "
                f"parameters agree with the joint optimum of the same data within "
                f"{STAGED_GAP_LIMIT:g} standard errors"
            )
    if flat["planar"]:  # along the plane's normal no linearisation describes the data
        errors = covariance = None
    mode = problem.moments.reference
    parameters = Zhou2010Parameters.from_theta(theta).to_dict()
    bias = identifiability.get("second_order_bias")
    if bias is not None:
        parameters = correct_bias(parameters, bias, identifiability, warnings, errors is not None)
        if bias["applied"]:
            corrected = Zhou2010Parameters.from_dict(parameters).theta
            rows.append(problem.row("bias corrected", corrected, iterations=0, wall_s=0.0))
        elif bias.get("widened"):
            errors, covariance = widened_for_bias(errors, covariance, bias["bias"])
    result = CalibrationResult(
        parameters=parameters,
        statistics=rows,
        method=method,
        reference=problem.reference_document(),
        gauge=dict(GAUGE) if mode == "none" else None,
        solver=replace(report, stop_reason=stop_reason, converged=unconverged is None),
        unit=base,
        standard_errors=errors,
        covariance=covariance,
        identifiability=identifiability,
        warnings=warnings,
        notes=notes_for(problem),
        n_samples=int(samples.shape[0]),
        input={"log_unit": base},
        robust=robust,
        model_name=problem.model,
    )
    if not quality:
        return result
    unconverged = None if allow_unconverged else unconverged
    overrides = {"allow_unconverged": True} if unconverged else {}
    if require_identifiable and identifiability["not_identifiable"]:
        also = f" Besides, {unconverged[0].lower()}{unconverged[1:]}." if unconverged else ""
        raise QualityError(
            undetermined_message(point_errors, identifiability, final, mode, base, problem.model)
            + also,
            "Not_Identifiable",
            result=result,
            overrides={"require_identifiable": False, **overrides},
        )
    if unconverged:
        raise QualityError(unconverged, "Staged_Unconverged", result=result, overrides=overrides)
    return result


def correct_bias(
    parameters: dict, block: dict, identifiability: dict, warnings: list, stated: bool = True
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
    widening = identifiability.get("score_dependence", {}).get("standard_error_widening", {})
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


def calibrate_log(
    log: Log,
    *,
    target_std: float | None = None,
    target_range: float | None = None,
    loss_scale: float | None = None,
    **options,
) -> CalibrationResult:
    """`calibrate` on a log read by `nlpcal.io.read_log` (its reference included).

    target_std, target_range, loss_scale : in the unit of the log's field columns.
    The result records the log (file, columns, unit and where the unit came from) under
    `input`, and the reader's warnings (a unit that does not fit the magnitudes) first among its
    own; so does the result a QualityError holds.
    """
    if isinstance(options.get("aux_columns"), (list, tuple)):  # their values come with the log
        options["aux_columns"] = log_channels(log, options["aux_columns"])
    try:
        result = calibrate(
            log.samples,
            unit=log.base_unit,
            reference_field=log.reference,
            target_std=units.to_base(target_std, log.unit),
            target_range=units.to_base(target_range, log.unit),
            loss_scale=units.to_base(loss_scale, log.unit),
            **options,
        )
    except QualityError as failure:
        if isinstance(failure.result, CalibrationResult):
            _record_log(failure.result, log)
        raise
    return _record_log(result, log)


def _record_log(result: CalibrationResult, log: Log) -> CalibrationResult:
    """`result` with the provenance of `log`: its metadata, its unit's source, its warnings."""
    result.input = log.metadata()
    result.unit_source = log.unit_source
    result.warnings = [*log.warnings, *(w for w in result.warnings if w not in log.warnings)]
    if log.reference_column:
        result.reference.column = log.reference_column
    if log.reference_source:
        result.reference.model = dict(log.reference_source)
    return result


__all__ = [
    "CYCLES_DEFAULT",
    "METHODS",
    "MODEL_CHOICES",
    "RTOL_DEFAULT",
    "CalibrationResult",
    "Problem",
    "StopRule",
    "calibrate",
    "calibrate_log",
]
