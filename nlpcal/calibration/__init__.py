"""`nlpcal.calibrate`: the nine-parameter calibration of Zhou et al. (2010) on a log.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from collections.abc import Callable

from .. import chunks, units
from ..errors import QualityError, SolveError
from ..io.logs import Log
from ..results import Provenance
from ..robust import Loss
from .channels import Channels, attach, compensated, fit_channels, log_channels, prepare_channels
from .lagged import LAG_ARGUMENTS, calibrate_lagged
from .problem import Problem
from .result import CalibrationResult
from .selection import MODEL_CHOICES, choose_model, restriction_warning, selection_warning
from .settings import (
    METHODS,
    NO_GATE,
    CalibrationSettings,
    InputSettings,
    QualityGate,
    ReferenceSettings,
)
from .staged import CYCLES_DEFAULT, RTOL_DEFAULT, StopRule
from .steps import Prepared, assemble, correct_bias, diagnose, gate, prepare, solve


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
    lag=None,
    times=None,
    lag_tolerance=None,
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
    lag : None, "auto" or float
        The lag of a reference series (`--lag`): "auto" estimates it with the nine parameters,
        a number [s] takes it out of the reference; the result records it under `lag`
        (`nlpcal.lag`). tau > 0 when the reference is late. An undetermined lag raises
        QualityError.
    times : array_like of shape (N,), optional
        The times of the samples, seconds from any origin, for `lag` (`--time-column`). [s]
    lag_tolerance : float, optional
        A lag "auto" is determined when it is 3 standard errors from zero or its standard
        error is within this tolerance (`--lag-tolerance`; default 0.01). [s]

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

    Notes
    -----
    The keywords are checked and packed into settings objects at once
    (`nlpcal.calibration.settings.CalibrationSettings`); the steps `prepare`, `solve`,
    `diagnose`, `assemble` and `gate` (`nlpcal.calibration.steps`) then run on them.

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
    settings = CalibrationSettings.of(
        method=method,
        model=model,
        reference_field=reference_field,
        unit=unit,
        reference_unit=reference_unit,
        cycles=cycles,
        target_std=target_std,
        target_range=target_range,
        rtol=rtol,
        loss=loss,
        loss_scale=loss_scale,
        require_identifiable=require_identifiable,
        allow_unconverged=allow_unconverged,
        verbose=verbose,
        threads=threads,
        ipopt_options=ipopt_options,
        lag=lag,
        times=times,
        lag_tolerance=lag_tolerance,
        aux_columns=aux_columns,
        aux_kind=aux_kind,
    )
    if settings.lag.value is not None:  # the lag of a reference series (nlpcal.lag)
        options = {k: v for k, v in locals().items() if k not in (*LAG_ARGUMENTS, "settings")}
        return calibrate_lagged(calibrate, samples, reference_field, settings.lag, options)
    with chunks.call_threads(settings.input.threads):
        if settings.aux.columns is None:
            return calibrate_prepared(prepare(samples, settings), settings, progress)
        samples, channels = prepare_channels(samples, settings)
        return calibrate_channels(prepare(samples, settings), channels, settings, progress)


def calibrate_channels(
    data: Prepared,
    channels: Channels,
    settings: CalibrationSettings,
    progress: Callable | None = None,
) -> CalibrationResult:
    """`calibrate` with aux channels: their stray fields solved jointly with the nine
    parameters (`fit_channels`), then `calibrate_prepared` on the log without them, whose
    optimum is the joint one; the result (also one a QualityError holds) records them
    (`attach`)."""
    gate = settings.gate
    fit = fit_channels(data, channels, settings.model, settings.ipopt, gate.require_identifiable)
    try:
        result = calibrate_prepared(compensated(data, fit), settings, progress)
    except QualityError as failure:
        if isinstance(failure.result, CalibrationResult):
            attach(failure.result, fit, data.moments)
        raise
    attach(result, fit, data.moments)
    return result


def calibrate_prepared(
    data: Prepared, settings: CalibrationSettings, progress: Callable | None = None
) -> CalibrationResult:
    """`calibrate` on prepared data: the model (chosen by `choose_model` for "auto", each form
    judged on its joint solve, the staged cycle's optimum), its `estimate`, where the unit came
    from and, for a restricted model the user chose, whether the data contradict what it fixes
    (`check_restriction`)."""
    model, selection = settings.model, None
    if model == "auto":
        model, selection = choose_model(
            lambda form: estimate(data.problem(form, settings), "joint", settings.stop, data.unit)
        )
    try:
        result = estimate(
            data.problem(model, settings),
            settings.method,
            settings.stop,
            data.unit,
            progress=progress,
            quality=settings.gate,
        )
    except SolveError as failure:  # a QualityError holds the result: it records the choice
        if isinstance(failure.result, CalibrationResult):
            record_choice(failure.result, data, selection)
        raise
    record_choice(result, data, selection)
    if selection is None and model != "full":  # does the log contradict what the form fixes?
        check_restriction(
            result, data.problem(model, settings), data.problem("full", settings), settings.stop
        )
    return result


def estimate(
    problem: Problem,
    method: str,
    rule: StopRule,
    unit: str,
    *,
    progress: Callable | None = None,
    quality: QualityGate = NO_GATE,
) -> CalibrationResult:
    """One calibration problem, solved by `method` (`rule` stops a staged cycle), diagnosed,
    assembled into its result and gated by `quality` (the default returns every result that
    solved): the steps `solve`, `diagnose`, `assemble` and `gate`.

    unit : the unit of the result (nT or raw). Raises SolveError when the solve fails,
    QualityError (holding the result) when `quality` refuses it.
    """
    solution = solve(problem, method, rule, unit, progress)
    diagnosis = diagnose(problem, solution, method, rule, unit)
    result = assemble(problem, solution, diagnosis, method, unit)
    return gate(result, problem, diagnosis, quality)


def check_restriction(
    result: CalibrationResult, restricted: Problem, full: Problem, rule: StopRule
) -> None:
    """Warn when the log contradicts the parameters a restricted model fixes
    (`selection.restriction_warning`), judged against the full model's joint solve on the same
    moments; a full model the data do not determine says nothing, and no warning is given. The
    test compares variances of |B1|: a robust fit's objective is none, and is not judged."""
    if restricted.loss.robust:
        return
    try:
        reference = estimate(full, "joint", rule, result.unit)
    except SolveError:
        return
    if reference.identifiability.not_identifiable:
        return
    freed = (full.free.basis.shape[1], restricted.free.basis.shape[1])
    warning = restriction_warning(result, reference, freed)
    if warning:
        result.warnings.append(warning)


def record_choice(result: CalibrationResult, data: Prepared, selection: dict | None) -> None:
    """Record where a result's unit came from, with the warnings about it first, and how model
    "auto" chose its model; a restricted choice is its first warning (the correction assumes
    the parameters it fixes)."""
    result.unit_source = data.unit_source
    result.warnings[:0] = data.warnings
    if selection is None:
        return
    result.model_selection = selection
    if selection["chosen"] != "full":
        result.warnings.insert(0, selection_warning(selection))


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
    own; so does the result a QualityError holds. `aux_columns`, a list, names extra columns
    the log was read with.
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
            times=log.times,
            **options,
        )
    except QualityError as failure:
        if isinstance(failure.result, CalibrationResult):
            _record_log(failure.result, log)
        raise
    return _record_log(result, log)


def _record_log(result: CalibrationResult, log: Log) -> CalibrationResult:
    """`result` with the provenance of `log`: its metadata, its unit's source, its warnings."""
    result.input = Provenance.from_dict(log.metadata())
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
    "CalibrationSettings",
    "InputSettings",
    "Loss",
    "Prepared",
    "Problem",
    "QualityGate",
    "ReferenceSettings",
    "StopRule",
    "assemble",
    "calibrate",
    "calibrate_log",
    "correct_bias",
    "diagnose",
    "estimate",
    "gate",
    "prepare",
    "solve",
]
