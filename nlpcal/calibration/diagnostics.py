"""What a nine-parameter calibration is worth: standard errors, identifiability, coverage, and
what the data cannot tell, in words.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import numpy as np

from .. import inference, units
from ..errors import SolveError
from ..models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters
from ..moments import Moments
from ..nlp.blocks import evaluate, objective_function, variable_scale
from ..nlp.steps import block_step
from ..results import TableRow
from ..robust import robust_std
from ..statistics import (
    exact_objectives,
    field_statistics,
    objectives_block,
    statistics_block,
    statistics_result,
)
from .coverage import COVERAGE_WARN, direction_coverage, flatness, planar_message
from .problem import Problem
from .result import Identifiability
from .scores import ScoreSums, after_solve, finished, score_terms

#: Standard errors above these are "poorly determined": offsets 1 % of the field, scale errors
#: 0.01, angles 1 deg (a calibration that changes |B| by about 1 % either way).
POORLY_DETERMINED = np.array([1e-2] * 3 + [1e-2] * 3 + [1.0] * 3)
#: Standard errors above these mean the data do not determine the parameter at all (offsets 10 %
#: of the field, scale errors 0.1, angles 10 deg): the linearisation behind a standard error no
#: longer holds, and the solvers wander along the valley (data on a cap of the sphere).
UNDETERMINED = 10.0 * POORLY_DETERMINED
#: Above this relative spread of |B1| after calibration, the field or the sensor is disturbed
#: beyond what the nine parameters describe (a clean fluxgate reaches 1e-4). [1]
DISTURBED_SPREAD = 5e-3
#: Above this widening of a standard error for the dependence of neighbouring samples' scores,
#: more independent samples are advice worth giving. [1]
CORRELATED_INFLATION = 2.0
#: Above this widening of a standard error for the dependence of neighbouring samples' scores,
#: a warning says why and what would help (`dependence_warning`). [1]
DEPENDENCE_WARN = 3.0
#: Above this relative gap between the moment objective and the exact one at the solution, the
#: distance to the exact optimum is estimated (`exact_optimum_shift`).
SERIES_CHECK = 1e-8
#: An estimated distance to the exact optimum above this many standard errors is a warning.
SHIFT_WARN = 0.1
#: The sensor's noise is told apart from a reference series' only while the reference's white
#: variance is at most this share of the residuals': beyond, their difference rests on too
#: little and the bias is not corrected (`correct_bias`). [1]
REFERENCE_NOISE_SHARE = 0.5


def scaled_hessian(moments: Moments, theta, step=None) -> np.ndarray:
    """D H D: the Hessian of the objective [field^2] in the scaled variables theta = D x.

    From the joint problem's own Hessian when `step` is its solve of all nine, else from the
    full objective.
    """
    scale = variable_scale(moments.frame.radius)
    if step is not None and step.block == "joint" and step.free.model == "full":
        return step.f_ref * step.hess
    hess = evaluate(objective_function, moments, theta)[2]
    return scale[:, None] * hess * scale[None, :]


def _names(indices) -> list:
    return [PARAMETER_NAMES[i] for i in sorted(indices)]


def uncertainty(
    problem: Problem,
    objective: float,
    hs: np.ndarray,
    theta=None,
    centre: float | None = None,
    sums: ScoreSums | None = None,
    residuals: np.ndarray | None = None,
):
    """Standard errors [parameter units], the identifiability block of a result and the
    covariance of the nine parameters in their units (angles in deg), or None.

    For f = (1/N) sum r_i^2 the Gauss-Newton information is A = N H / 2 (`nlpcal.inference`),
    here in the scaled variables of the problems, on the directions the model estimates (without
    a reference, within the gauge's null space: `nlpcal.nlp.blocks.Variables.basis`); with a
    robust loss A = sum psi'(r) J J^T (`ScoreSums.information`). With `theta` the covariance is
    the sandwich A^-1 Omega A^-1 with Omega = A V A, V the moving-block jackknife of the scores
    psi(r_i) J_i (`sandwich`): it follows the dependence of the scores of neighbouring samples
    (a smooth trajectory in a slowly changing field); scores without clear dependence
    (`inference.scores_dependent`) keep s^2 A^-1 (A^-1 B A^-1, B = sum psi^2 J J^T, for a robust
    loss), widened by Student's t on N - p. Without `theta` (identifiability alone) it is
    s^2 A^-1. `centre` : without a reference, the mean |B1| the least-squares residuals are
    taken from [field unit]; `sums` : the scores at theta when the pass after the solve
    (`settle`) has gathered them, else a pass of their own; `residuals` : those at theta
    (`Problem.residuals` with the problem's centre), when at hand.
    """
    n = problem.samples.shape[0]
    robust = problem.loss.robust and theta is not None
    if theta is not None and sums is None:
        sums = settle(problem, theta, centre)
    if robust and sums is not None:
        information = sums.information()
    else:
        information = inference.information_from_hessian(hs, n)
    result, alone, dependence, noise = sandwich(problem, information, objective, theta, sums)
    estimated = problem.estimated
    to_units = scaled_to_units(problem.moments.frame.radius)
    errors, covariance = in_units(result, to_units, estimated)
    # what the attitudes determine: the standard errors of independent samples (the same
    # without `theta`), by which a parameter is undetermined; the dependence of neighbouring
    # samples widens a standard error (poorly determined) but leaves no valley in the objective
    independent = errors
    if dependence is not None and errors is not None and alone.standard_errors is not None:
        alone_errors = alone.standard_errors * to_units
        independent = {n: float(alone_errors[PARAMETER_NAMES.index(n)]) for n in estimated}
        dependence["standard_errors_independent"] = independent
        dependence["standard_error_widening"] = {
            name: errors[name] / independent[name] if independent[name] > 0 else 1.0
            for name in estimated
        }
    block = determination(problem, result, errors, independent)
    block.covariance_form = "sandwich" if theta is not None else "gauss-newton"
    block.poorly_determined_limits, block.undetermined_limits = stated_limits(problem)
    block.score_dependence = dependence
    if dependence is not None and errors is not None and not result.weak:
        block.second_order_bias = second_order_bias(
            problem, theta, robust, (information, noise), to_units, errors, residuals
        )
    return errors, block, covariance


def sandwich(problem: Problem, information, objective: float, theta, sums) -> tuple:
    """(estimate, estimate of independent samples, score dependence, noise terms) of
    `uncertainty`: s^2 A^-1 without `theta`; with it the sandwich A^-1 Omega A^-1 of the scores
    (`score_meat`, `inference.dependence_meat`): the moving-block jackknife's meat where they
    are dependent, never narrower than that of independent samples, else the latter widened by
    Student's t. The second and the last two are None without `theta`. `sums` : the
    `ScoreSums` at theta (None without it)."""
    n = problem.samples.shape[0]
    basis = problem.free.basis
    # the parameters fitted: the model's free directions, and without a reference the mean |B1|
    fitted = basis.shape[1] + (1 if problem.moments.reference == "none" else 0)
    options: dict = {"basis": basis, "dof": n - fitted}
    variance = n * objective / max(n - fitted, 1)
    if theta is None:
        return inference.estimate(information, residual_variance=variance, **options), *(None,) * 3
    series, shares, independent, dependence, noise = score_meat(sums, basis, n, n - fitted)
    if independent is None:  # s^2 A: the meat of independent samples of least squares
        independent = variance * np.asarray(information)
    meat, described, freedom = inference.dependence_meat(
        series, shares, independent, n - fitted, basis
    )
    dependence.update(described)
    if dependence["method"] != "independent":
        dependence["degrees_of_freedom"] = {
            name: float(freedom[PARAMETER_NAMES.index(name)]) for name in problem.estimated
        }
    result, alone = inference.estimates(information, [meat, independent], **options)
    return result, alone, dependence, noise


def scaled_to_units(radius: float) -> np.ndarray:
    """The factors from the scaled variables to the parameters' units (angles in deg). (9,)"""
    to_units = variable_scale(radius).copy()
    to_units[6:9] = np.degrees(to_units[6:9])
    return to_units


def in_units(estimate, to_units: np.ndarray, estimated: list) -> tuple:
    """(standard errors, covariance) of the `estimated` parameters of an `inference.estimate`
    in their units, or (None, None) when its covariance is not finite."""
    if estimate.covariance is None or not np.all(np.isfinite(estimate.covariance)):
        return None, None
    index = [PARAMETER_NAMES.index(name) for name in estimated]
    full = to_units[:, None] * estimate.covariance * to_units[None, :]
    errors = {name: float(np.sqrt(full[i, i])) for name, i in zip(estimated, index)}
    return errors, full[np.ix_(index, index)]


def determination_limits(radius: float) -> tuple:
    """(poorly determined, undetermined) standard errors of the nine parameters: the fractions
    POORLY_DETERMINED and UNDETERMINED of the field for offsets. [parameter units]"""
    limits = np.concatenate([POORLY_DETERMINED[:3] * radius, POORLY_DETERMINED[3:]])
    far = np.concatenate([UNDETERMINED[:3] * radius, UNDETERMINED[3:]])
    return limits, far


def determination(problem: Problem, estimate, errors, independent) -> Identifiability:
    """The first entries of the identifiability block: the parameters not identifiable (along
    a direction the objective does not change, or undetermined: a standard error of
    independent samples above its UNDETERMINED limit), poorly determined (above
    POORLY_DETERMINED), the weakest combination and the scaled Hessian's eigenvalues."""
    estimated = problem.estimated
    n = problem.samples.shape[0]
    limits, far = determination_limits(problem.moments.frame.radius)
    undetermined = [
        n for n in estimated if independent and independent[n] > far[PARAMETER_NAMES.index(n)]
    ]
    poorly = [
        n
        for n in estimated
        if errors and errors[n] > limits[PARAMETER_NAMES.index(n)] and n not in undetermined
    ]
    weak = _names(estimate.weak)
    return Identifiability(
        not_identifiable=[n for n in PARAMETER_NAMES if n in weak or n in undetermined],
        undetermined=undetermined,
        poorly_determined=poorly,
        weakest_combination=_names(estimate.weakest),
        hessian_eigenvalues_scaled=[float(v) for v in estimate.eigenvalues * 2.0 / n],
    )


def stated_limits(problem: Problem) -> tuple:
    """The (poorly determined, undetermined) limits of `determination` of the estimated
    parameters, by name. [parameter units]"""
    limits, far = determination_limits(problem.moments.frame.radius)
    index = [PARAMETER_NAMES.index(name) for name in problem.estimated]
    return (
        {n: float(limits[i]) for n, i in zip(problem.estimated, index)},
        {n: float(far[i]) for n, i in zip(problem.estimated, index)},
    )


def second_order_bias(
    problem: Problem,
    theta,
    robust: bool,
    terms: tuple,
    to_units: np.ndarray,
    errors: dict,
    residuals: np.ndarray | None = None,
) -> dict:
    """The "second_order_bias" block: the bias of the estimate in the sensor's white noise
    (`noise_bias` of `terms`, the information and the noise terms of `score_meat`), with the
    sensor's noise the white part of the residuals' variance (`residuals` at theta, computed
    when None) less a reference series'. [parameter units]"""
    if residuals is None:
        residuals = problem.residuals(theta, problem.centre)
    white = white_variance(residuals, robust)
    series = problem.reference_series()
    reference = 0.0 if series is None else white_variance(series, robust)
    variance = max(white - reference, 0.0)  # the sensor's share of the white residuals
    estimated = problem.estimated
    index = [PARAMETER_NAMES.index(name) for name in estimated]
    information, noise = terms
    shift = noise_bias(information, problem.free.basis, noise, variance) * to_units
    return {
        "form": "errors in variables, second order in the sensor noise",
        "noise_std": float(np.sqrt(variance / noise["mean_square_g"])),
        "reference_noise_std": float(np.sqrt(reference)),
        "noise_separable": bool(reference <= REFERENCE_NOISE_SHARE * white),
        "bias": {name: float(shift[i]) for name, i in zip(estimated, index)},
        "bias_in_standard_errors": {
            name: _in_errors(float(shift[i]), errors[name]) for name, i in zip(estimated, index)
        },
    }


def _in_errors(shift: float, error: float) -> float:
    """A shift in standard errors; none (0) on residuals of zero, whose standard error is 0
    (a shift with a standard error of 0 is infinitely many: no result states it)."""
    if error == 0.0:
        return 0.0 if shift == 0.0 else float(np.copysign(np.inf, shift))
    return shift / error


def white_variance(series, robust: bool) -> float:
    """The variance of the white part of a time series: half the mean square of its successive
    differences (1.4826 MAD of them, squared, for a robust loss), which a slowly changing part
    (a field that drifts, the misfit along a smooth trajectory) hardly enters. [unit^2]"""
    steps = np.diff(np.asarray(series, dtype=float))
    if steps.size == 0:
        return 0.0
    return 0.5 * (robust_std(steps) ** 2 if robust else float(np.mean(steps**2)))


def noise_bias(information, basis, noise: dict, variance: float) -> np.ndarray:
    """The bias of the estimate to second order in white sensor noise of sigma on each axis, in
    the scaled variables (9,).

    The residual r_i = |M (b_i + n_i - Z_p)| - F_i depends on the noise n_i of the raw sample,
    and so does its sensitivity J_i: E[r_i J_i] = sigma^2 (dJ_i/db g_i + tr(d2 r_i/db2) J_i / 2)
    with g_i = dr_i/db = M^T u_i, which does not vanish. The estimating equation sum r_i J_i = 0
    is then off by sigma^2 times their sum (`scores.ScoreSums.bias`), and the estimate by
    bias = -sigma^2 A^-1 sum(...) (on the directions the model estimates). It grows as sigma^2
    and as A^-1: along a direction the attitudes barely determine (a short arc) it reaches
    standard errors. The formula assumes the noise is the sensor's: sigma^2 = s^2 / mean |g|^2
    (the noise of |B1| is sigma |g|), s^2 the white part of the residuals' variance
    (`white_variance`: a slowly changing field is no sensor noise) less the white part of a
    reference series' (its own noise, which enters the residuals but not the raw samples). A
    robust loss's equation sum psi(r_i) J_i = 0 is off by the same terms
    weighted by psi'(r_i) (Stein's lemma, E[psi(x) x] = sigma_x^2 E[psi'(x)] for Gaussian x),
    A = sum psi' J J^T, and s the inliers' spread (1.4826 MAD): spikes (psi' = 0) take no part.
    """
    reduced = basis.T @ np.asarray(information, dtype=float) @ basis
    sigma2 = variance / noise["mean_square_g"]
    return -sigma2 * basis @ np.linalg.solve(reduced, basis.T @ noise["gradient"])


def score_meat(sums: ScoreSums, basis, n: int, dof: int) -> tuple:
    """(scores, informations, G_0, description, noise): the block sums of the scores and (when
    asked: `ScoreSums.informations`) of the information, for `inference.dependence_meat`;
    sum psi(r_i)^2 J_i J_i^T times N / dof on the estimated directions (`basis`), the meat of
    independent samples of an M-estimate (None when not gathered: least squares takes s^2 A);
    what the result says of the blocks (`score_dependence`); and the noise terms of the bias
    (`noise_bias`)."""
    independent = None
    if sums.meat is not None:
        independent = basis @ (basis.T @ sums.meat @ basis) @ basis.T * n / max(dof, 1)
    description = {"block_samples": sums.block_rows}
    return sums.series, sums.informations, independent, description, sums.bias


def settle(problem: Problem, theta, centre: float | None = None) -> ScoreSums:
    """The one pass over the data after the solve: the statistics of the Table 1 rows the solve
    deferred (`Problem.deferred`, each at its own parameters) and the scores at theta
    (`nlpcal.calibration.scores`), sharing |B1| at theta. Without a reference a least-squares
    fit takes its residuals from the mean |B1| of the same pass: the scores are gathered about
    the mean of the first samples' and moved to it after (exact: psi = r is linear in the
    centre). A robust fit's exact-optimum check, which every robust fit runs, takes its 18
    objectives from the same pass (`optimum_points`). `centre` : a given centre instead (the
    mean of an earlier pass). [field unit]"""
    samples, reference, loss = problem.samples, problem.reference, problem.loss
    n = samples.shape[0]
    deferred, problem.deferred = problem.deferred, []
    theta = np.asarray(theta, dtype=float)
    rows = [entry[3] for entry in deferred]
    shared = [np.array_equal(entry[1], theta) for entry in deferred]
    if not any(shared):  # the statistics at theta: the mean |B1| of least squares
        rows.append(statistics_block(samples, theta))
        shared.append(True)
    at_theta = shared.index(True)
    robust = loss.robust
    if robust:
        centre = problem.centre
    elif reference is None and centre is None:
        centre = rows[at_theta].shift  # the mean |B1| of the first samples
    radius = problem.moments.frame.radius
    terms = score_terms(theta, radius, n, loss, centre, robust)
    check = objectives_block(samples, **optimum_points(problem, theta)) if robust else None
    stats, part, totals = after_solve(samples, reference, rows, terms, shared, check)
    for entry, sums in zip(deferred, stats):
        problem.fill_deferred(entry, *sums)
    shift = 0.0
    if reference is None and not robust:
        mean = statistics_result(*stats[at_theta])["mean"]
        shift = mean - float(centre)  # type: ignore[arg-type]
    sums = finished(part, terms, n, reference is None, shift)
    if check is not None:  # a robust fit's exact-optimum check, always run
        sums.exact_objectives = check.values(totals, reference is not None)
    return sums


def joint_gap(problem: Problem, theta, errors) -> dict:
    """How far the joint optimum of the same objective (the same moments, the same weights) lies
    from a staged estimate: the joint problem solved from `theta`.

    Returns the two objectives [field^2], the largest distance of a parameter from its joint
    value in standard errors (None without standard errors), the joint parameters and IPOPT's
    status of the joint solve.
    """
    try:
        step = block_step(problem.moments, "joint", theta, model=problem.model)
    except SolveError as failure:
        return {"status": failure.status, "max_gap_in_standard_errors": None}
    staged = Zhou2010Parameters.from_theta(theta).as_vector()
    joint = Zhou2010Parameters.from_theta(step.theta).as_vector()
    gap = None
    if step.newton_decrease is not None:  # not re-solved: the Newton step's length bounds it
        gap = float(np.sqrt(problem.moments.n * step.newton_decrease / step.f_start))
    elif errors is not None:
        gap = float(np.max(np.abs(staged - joint) / _standard_errors(errors)))
    return {
        "objective_staged": step.f_start,
        "objective_joint": step.f_end,
        "max_gap_in_standard_errors": gap,
        "joint_parameters": Zhou2010Parameters.from_theta(step.theta).to_dict(),
        "status": step.status,
    }


def residual_spread(problem: Problem, theta, residuals: np.ndarray | None = None) -> dict:
    """The standard deviation of the residuals at theta (`residuals`, computed when None) and
    their robust one (1.4826 MAD). [field unit]"""
    if residuals is None:
        residuals = problem.residuals(theta, problem.centre)
    return {"residual_std": float(np.std(residuals)), "residual_robust_std": robust_std(residuals)}


def problem_flatness(problem: Problem, theta, spread: dict | None = None) -> dict:
    """`coverage.flatness` of a problem's samples, judged against the robust spread of its
    residuals at theta (`spread`, from `residual_spread`, when already at hand)."""
    spread = spread or residual_spread(problem, theta)
    return flatness(problem.samples, spread["residual_robust_std"], problem.reference is not None)


def exact_optimum_shift(
    problem: Problem, theta, hs: np.ndarray, errors, scores: ScoreSums
) -> float | None:
    """How far the exact optimum lies from `theta`, in standard errors (largest over parameters).

    One Newton step on the exact per-sample objective: its gradient by central differences (the
    18 objectives in one pass over the data), the Hessian of the moment objective. The step
    stays in the directions the model estimates (without a reference, in the gauge's null
    space). With a robust loss the objective is the one the fit minimises, (2/N) sum rho(r_i)
    (`statistics.exact_objectives`), and its Hessian (2/N) sum psi'(r_i) J_i J_i^T (the bread of
    the sandwich, `ScoreSums.information` of the `scores` at theta): the distance to the optimum
    of the loss, not of the unweighted squares. A robust fit's objectives come with the
    `scores` from the pass after the solve (`settle`); an inexact expansion takes a pass.
    """
    if errors is None:
        return None
    scale = variable_scale(problem.moments.frame.radius)
    robust = problem.loss.robust and problem.loss.scale is not None
    values = scores.exact_objectives
    if values is None:
        values = exact_objectives(
            problem.samples, reference=problem.reference, **optimum_points(problem, theta)
        )
    grad = (values[0::2] - values[1::2]) / (2 * SHIFT_STEP)
    if robust:
        hs = 2.0 * scores.information() / problem.samples.shape[0]
    basis = problem.free.basis
    reduced = basis.T @ hs @ basis
    step = -basis @ np.linalg.solve(0.5 * (reduced + reduced.T), basis.T @ grad)
    shift = step * scale
    shift[6:9] = np.degrees(shift[6:9])
    return float(np.max(np.abs(shift) / _standard_errors(errors)))


#: The central differences of `exact_optimum_shift`, in the scaled variables: 1e-6 of the field
#: for offsets, 1e-6 for scales, 1e-5 rad.
SHIFT_STEP = 1e-3


def optimum_points(problem: Problem, theta) -> dict:
    """The keywords of `statistics.exact_objectives` for the 18 exact objectives of
    `exact_optimum_shift`: theta moved by +/- SHIFT_STEP along each scaled variable, the loss
    the fit minimises when robust."""
    scale = variable_scale(problem.moments.frame.radius)
    steps = [sign * SHIFT_STEP * e for e in np.eye(9) for sign in (1.0, -1.0)]
    robust = problem.loss.robust and problem.loss.scale is not None
    return {
        "thetas": [theta + scale * x for x in steps],
        "loss": problem.loss if robust else None,
        "centre": problem.centre,
    }


def _standard_errors(errors: dict) -> np.ndarray:
    """The nine standard errors in PARAMETER_NAMES order, inf where a parameter has none (fixed
    by the model) or none above zero: what a distance in standard errors divides by."""
    sd = np.array([errors.get(name, np.inf) for name in PARAMETER_NAMES])
    return np.where(sd > 0, sd, np.inf)


def explain_failure(
    problem: Problem, failure: SolveError, method: str | None, unit: str = "nT"
) -> SolveError:
    """Say which parameters the data do not determine, when IPOPT fails; blame the attitude
    coverage only when it is to blame.

    The Hessian is taken where the failing solve started (failure.result). `method` is the one
    that failed, whose alternative is suggested (None: no suggestion). The error returned carries
    what was found as its `identifiability` (the parameters not determined, the flatness).
    """
    theta = failure.result
    if theta is None or not np.all(np.isfinite(theta)):
        return failure
    limit = dict(problem.ipopt.extra).get("max_iter")  # an iteration limit the user set
    if failure.status == "Maximum_Iterations_Exceeded" and limit is not None:
        return SolveError(
            f"{failure}: IPOPT stopped at the iteration limit given (max_iter {limit}); raise "
            f"it or leave it at its default",
            failure.status,
            result=theta,
        )
    flat = problem_flatness(problem, theta)
    if flat["planar"]:
        return SolveError(
            f"{failure}: {planar_message(flat, _unit_word(unit))}",
            failure.status,
            result=theta,
            identifiability=Identifiability(not_identifiable=flat["parameters"], flatness=flat),
        )
    hs = scaled_hessian(problem.moments, theta)
    objective = field_statistics(problem.samples, theta, problem.reference)["objective"]
    _, identifiability, _ = uncertainty(problem, objective, hs)
    weak = identifiability.not_identifiable or []
    identifiability.flatness = flat
    coverage = identifiability.coverage = direction_coverage(problem.samples, theta)
    if not weak and coverage["fraction"] < COVERAGE_WARN:
        final = row_at(problem, theta)
        help_ = what_would_help(identifiability, final, problem.moments.reference, problem.model)
        covered = coverage["covered"]
        return SolveError(
            f"{failure}: the field directions cover {covered} of 26 direction bins, a cap of the "
            f"sphere on which a larger, far-away sphere fits nearly as well, so the solver "
            f"wanders. {help_[:1].upper()}{help_[1:]}",
            failure.status,
            result=theta,
            identifiability=identifiability,
        )
    if not weak:
        return SolveError(
            f"{failure}: where the solve started, the attitudes determine every parameter, so "
            f"the coverage is not the likely cause"
            + (f"; try --method {'staged' if method == 'joint' else 'joint'}" if method else ""),
            failure.status,
            result=theta,
            identifiability=identifiability,
        )
    final = row_at(problem, theta)
    help_ = what_would_help(identifiability, final, problem.moments.reference, problem.model)
    help_ = help_ or "rotate the sensor through more attitudes"
    return SolveError(
        f"{failure}: the data do not determine {', '.join(weak)}. {help_[:1].upper()}{help_[1:]}",
        failure.status,
        result=theta,
        identifiability=identifiability,
    )


def _unit_word(unit: str) -> str:
    return "counts" if unit == "raw" else unit


#: The three kinds of parameter, their names and how their limits are stated.
_KINDS = (
    ("offsets", PARAMETER_NAMES[:3]),
    ("scale errors", PARAMETER_NAMES[3:6]),
    ("angles", PARAMETER_NAMES[6:]),
)


def _judged(errors: dict, limits: dict, names, unit: str, share: float) -> str:
    """ "offsets z_x ± 10, z_y ± 9.6 counts (limit 6.28 counts = 1 % of the field); angles ..."
    : standard errors by kind, each kind's limit stated once. Two significant digits: a
    standard error this large is taken where the solve stopped on a flat objective, whose
    place (and so the error's third digit) the rounding of the moments decides."""
    parts = []
    for kind, members in _KINDS:
        chosen = [n for n in members if n in names]
        if not chosen:
            continue
        word = {"offsets": f" {_unit_word(unit)}", "scale errors": "", "angles": " deg"}[kind]
        if kind == "offsets":
            limit = f"limit {units.readable(limits[chosen[0]])}{word} = {share:g} % of the field"
        else:
            limit = f"limit {limits[chosen[0]]:g}{word}"
        values = ", ".join(f"{n} ± {units.readable(errors[n], 2)}" for n in chosen)
        parts.append(f"{kind} {values}{word} ({limit})")
    return "; ".join(parts)


def row_at(problem: Problem, theta) -> TableRow:
    """The Table 1 statistics of |B1| at theta, as a row labelled "stopped" (one pass)."""
    return TableRow("stopped", **field_statistics(problem.samples, theta, problem.reference))


def what_would_help(
    identifiability: Identifiability, final: TableRow, reference: str, model: str = "full"
) -> str:
    """What would determine the parameters better, from what limits them here (`model`: the form
    of Eq. 4 fitted; a smaller one is suggested where the attitudes cover a cap of the sphere)."""
    advice = []
    coverage = identifiability.coverage or {}
    missing = coverage.get("missing", [])
    if missing:
        more = f" and {len(missing) - 6} other directions" if len(missing) > 6 else ""
        advice.append(
            f"rotate the sensor through more attitudes: the field never pointed along "
            f"{', '.join(missing[:6])}{more} (sensor axes; {coverage['covered']} of 26 direction "
            f"bins visited)"
        )
    mean = final.mean or 0.0
    spread = (final.std or 0.0) / mean if mean > 0 else 0.0
    if spread > DISTURBED_SPREAD:
        advice.append(
            f"a steadier field: |B1| still varies by {spread:.1%} (a clean field gives 0.1 %): "
            f"iron, electronics or motion nearby, or sensor errors beyond the nine parameters"
        )
    widening = (identifiability.score_dependence or {}).get("standard_error_widening", {})
    inflation = max(widening.values(), default=1.0)
    if CORRELATED_INFLATION < inflation <= DEPENDENCE_WARN:  # above: `dependence_warning`
        advice.append(
            f"more independent samples: the scores of neighbouring samples are alike (standard "
            f"errors up to x{inflation:.1f} for it)"
        )
    if reference == "none":
        advice.append("a known field magnitude (--reference-field F) to fix the overall scale")
    if model != "offset" and (
        coverage.get("fraction", 1.0) < COVERAGE_WARN or identifiability.not_identifiable
    ):
        advice.append(
            "or a smaller model: --model auto fits the richest the attitudes determine "
            "(diagonal: offsets and scales; offset: the offsets alone)"
        )
    return "what would help: " + "; ".join(advice) if advice else ""


def undetermined_message(
    errors,
    identifiability: Identifiability,
    final: TableRow,
    reference: str,
    unit,
    model: str = "full",
):
    """Why the data do not determine some parameters, and what would: a few sentences."""
    undetermined = identifiability.undetermined or []
    flat = identifiability.flatness or {}
    blind = flat.get("parameters", [])
    weak = [n for n in identifiability.not_identifiable or [] if n not in undetermined + blind]
    parts = [planar_message(flat, _unit_word(unit))] if flat.get("planar") else []
    if undetermined:  # judged on what the attitudes determine (`uncertainty`)
        dependence = identifiability.score_dependence or {}
        judged = _judged(
            dependence.get("standard_errors_independent", errors),
            identifiability.undetermined_limits or {},
            undetermined,
            unit,
            100 * UNDETERMINED[0],
        )
        parts.append(f"the data do not determine the {judged}")
    if weak:
        parts.append(
            f"the data do not determine {', '.join(weak)} (|B1| does not change along a "
            f"combination of them)"
        )
    help_ = what_would_help(identifiability, final, reference, model)
    return "; ".join(parts) + (f". {help_[0].upper()}{help_[1:]}." if help_ else ".")


#: The note on the method of a calibration without a reference field (a result's `notes`, not
#: its warnings: it says how the problem is posed, not what is wrong with the data).
def gauge_note(estimated) -> str:
    """The note of the gauge s_x + s_y + s_z = 0, naming what a model with the `estimated`
    parameters still determines without a reference field."""
    determined = ["scale ratios", "offsets"] + (["angles"] if "alpha_deg" in estimated else [])
    return (
        "no reference field: the overall scale is fixed by s_x + s_y + s_z = 0 ("
        f"{', '.join(determined[:-1])} and {determined[-1]} are determined); a reference field "
        "fixes it"
    )


def notes_for(problem: Problem) -> list:
    """What the user should know about how the problem was posed (not about the data): the
    gauge, when there is no reference and the model estimates scales."""
    estimated = problem.estimated
    if problem.moments.reference != "none" or "s_x" not in estimated:
        return []
    return [gauge_note(estimated)]


def warnings_for(
    problem: Problem,
    theta,
    hs,
    errors,
    identifiability: Identifiability,
    final: TableRow,
    scores: ScoreSums,
    unit: str = "nT",
) -> list:
    """What the data cannot tell, in words (and the exact-optimum check, into identifiability);
    `scores` : those at theta (`settle`)."""
    warnings = []
    reference = problem.moments.reference
    if identifiability.not_identifiable:
        warnings.append(
            "not identifiable: "
            + undetermined_message(
                errors, identifiability, final, reference, unit, problem.model
            ).rstrip(".")
        )
    coverage = identifiability.coverage or {}
    if coverage["fraction"] < COVERAGE_WARN and not identifiability.not_identifiable:
        warnings.append(
            f"poor attitude coverage: the corrected field visits "
            f"{coverage['covered']} of 26 direction bins; the result leans on a "
            f"small part of the sphere"
        )
    if identifiability.poorly_determined:
        judged = _judged(
            errors,
            identifiability.poorly_determined_limits or {},
            identifiability.poorly_determined,
            unit,
            100 * POORLY_DETERMINED[0],
        )
        help_ = what_would_help(identifiability, final, reference, problem.model)
        warnings.append(
            f"poorly determined (standard errors above the limits): {judged}"
            + (f". {help_[0].upper()}{help_[1:]}" if help_ else "")
        )
    inexact = (final.series_rel_error or 0.0) > SERIES_CHECK
    robust = problem.loss.robust  # reweighting may stop before the weights settle
    if inexact or robust:
        shift = exact_optimum_shift(problem, theta, hs, errors, scores)
        identifiability.exact_optimum_shift_in_standard_errors = shift
        if shift is None or shift > SHIFT_WARN:
            where = (
                "could not be located (no standard errors)"
                if shift is None
                else f"is estimated to lie {shift:.2g} standard errors away"
            )
            why = (
                f"the moment expansion of the objective is inexact here "
                f"({final.series_rel_error:.1e} relative; |B1|^2 varies by up to "
                f"{final.max_abs_u:.1%}); "
                if inexact
                else ""
            )
            optimum = (
                f"the exact optimum of the {problem.loss.kind} loss"
                if robust
                else ("the exact optimum")
            )
            advice = (
                "the reweighting may have stopped before the weights settled (--method joint "
                "reweights until they do), or the data are disturbed"
                if robust
                else "check the reference field and the data for disturbances"
            )
            warnings.append(f"{why}{optimum} {where}; {advice}")
    dependence = dependence_warning(identifiability.get("score_dependence", {}))
    return warnings + ([dependence] if dependence else [])


def dependence_warning(dependence: dict) -> str | None:
    """The warning of standard errors widened more than DEPENDENCE_WARN times for the dependence
    of neighbouring samples' scores (`score_dependence`), naming the cause and what would help;
    None below."""
    widening = dependence.get("standard_error_widening") or {}
    if not widening or max(widening.values()) <= DEPENDENCE_WARN:
        return None
    name = max(widening, key=lambda key: widening[key])
    span = dependence["bandwidth_blocks"] * dependence["block_samples"]
    return (
        f"standard errors widened up to x{widening[name]:.3g} ({name}) over those of independent "
        f"samples for autocorrelated scores: the attitude changes slowly relative to the "
        f"sampling, so neighbouring samples repeat nearly the same information (their scores "
        f"stay alike over about {span:.0f} samples). What would help: turn the sensor through "
        f"its attitudes more times in the log (faster, or a longer log), not a higher sample "
        f"rate; where the field drifts, its magnitude logged alongside (--reference-column)"
    )
