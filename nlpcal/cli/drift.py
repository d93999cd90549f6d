"""`nlpcal drift fit`: the temperature drift pipeline of Liu et al. (2022) on a static log.

    nlpcal drift fit LOG --temperature-column COL --reference-column COL --base-temperature T0
                     [--diurnal fitted|paper] [--columns X Y Z] [--unit nT] [--drop-invalid]
                     [-o drift.json]

Diurnal correction, the line |B_m| = a t + b (Eq. 1) and k(t) of Eq. 9; temperatures in degC.
--diurnal paper is the paper's correction -(F_i - F_1) exactly; the default fits how strongly
the modulus follows the reference with the line (`nlpcal.drift.fit.DIURNAL_METHODS`).
`nlpcal apply --drift` and `nlpcal stats --drift` use the result (see `nlpcal.cli.calibrate`).
Exit status: 0 success (also with warnings), 1 a solve failed, 2 bad usage or input.

--base-temperature is required: k(t) = 1 must sit at the temperature of the system calibration
the drift will be applied with, which the static log cannot know. On the liu2022 replica, the
drift log's mean (6.0 degC) instead of the calibration's 7.3 degC leaves 9.3 nT of RMSE at
12.8 degC instead of 0.5 nT.
"""

from __future__ import annotations

from .common import (
    add_command,
    add_log_arguments,
    emit_json,
    log_options,
    report_log,
    warn,
    warning,
)

#: `nlpcal.drift.fit.DIURNAL_METHODS`, spelled out so that the command line starts without numpy.
DIURNAL_METHODS = ("fitted", "paper")


def register(sub):
    parser = add_command(
        sub,
        "drift",
        help="temperature drift (Liu et al. 2022): fit k(t) on a static log against a reference",
        description="""\
Temperature drift of a fluxgate (Liu et al. 2022): on a log of a sensor that stays still while
its temperature changes, fit the line |B_m| = a t + b (Eq. 1) against a reference magnetometer,
and from it the factor k(t) = (a t + b) / (a t0 + b) (Eq. 9) by which scale and offsets grow
with temperature. 'nlpcal apply --drift' and 'nlpcal stats --drift' divide the raw field by k(t)
before the calibration of 'nlpcal calibrate'.""",
        examples=(
            "nlpcal drift fit drift.csv --temperature-column temp_c "
            "--reference-column proton_nT --base-temperature 7.3 -o drift.json",
        ),
    )
    inner = parser.add_subparsers(
        dest="drift_command", metavar="SUBCOMMAND", parser_class=type(parser), title="subcommands"
    )
    inner.required = True
    fit = add_command(
        inner,
        "fit",
        help="fit |B_m| = a t + b (Eq. 1) on a static log with temperature and reference",
        description="""\
The paper's pipeline on a static-sensor log: diurnal correction (base = the first reference
value F_1), the least-squares line |B_m| = a t + b (Eq. 1), and k(t) = (a t + b) / (a t0 + b)
(Eq. 9), which is 1 at the base temperature t0. By default the line is fitted together with the
gain g of |B_m| on the reference, |B_m| = a t + b + g (F_i - F_1); --diurnal paper adds
-(F_i - F_1) to the modulus as the paper does (g = 1), which biases a wherever the field drifts
with the temperature (a raw modulus 2 % too large follows the field 2 % too strongly).
Warns when the temperature span is too small for a meaningful slope, or when the sensor moved.""",
        examples=(
            "nlpcal drift fit drift.csv --temperature-column temp_c "
            "--reference-column proton_nT --base-temperature 7.3 -o drift.json",
        ),
    )
    fit.add_argument("log", metavar="LOG", help="the static log: delimited text, or - for stdin")
    fit.add_argument(
        "--temperature-column",
        required=True,
        metavar="COL",
        help="column of temperatures [degC] (name or 0-based position), e.g. temp_c",
    )
    fit.add_argument(
        "--reference-column",
        required=True,
        metavar="COL",
        help="column of reference magnitudes, e.g. a proton magnetometer (proton_nT); in the "
        "unit its name carries, else the field columns'",
    )
    fit.add_argument(
        "--base-temperature",
        type=float,
        metavar="T0",
        help="temperature of the system calibration the drift will be applied with, where "
        "k = 1 [degC], e.g. 7.3 (required: the static log cannot know it, and the wrong t0 "
        "leaves an error of c (t0' - t0) |B| at every temperature)",
    )
    fit.add_argument(
        "--diurnal",
        choices=DIURNAL_METHODS,
        default="fitted",
        help="how the diurnal variation F_i - F_1 leaves the modulus: 'fitted' (default) "
        "estimates its gain with the line; 'paper' subtracts it one for one, exactly as the "
        "paper (reproduces its numbers; biased where the field drifts with the temperature)",
    )
    add_log_arguments(fit)
    fit.add_argument(
        "-o", "--output", metavar="DRIFT.json", help="write the fit here (stdout when absent)"
    )
    fit.set_defaults(func=run_fit)


def run_fit(args) -> int:
    from ..drift.fit import fit_drift_log
    from ..errors import InputError
    from ..io import check_output_path, read_log

    check_output_path(args.output, args.log)
    log = read_log(
        args.log,
        **log_options(args),
        extra_columns={"--temperature-column": args.temperature_column},
    )
    report_log(log)
    fit = fit_drift_log(
        log, args.temperature_column, base_temperature=args.base_temperature, diurnal=args.diurnal
    )
    if args.base_temperature is None:  # the data are fine; only t0 is missing
        low, high = fit.temperature_range
        raise InputError(
            f"pass --base-temperature T0, the temperature [degC] of the system calibration the "
            f"drift will be applied with (k = 1 there); the static log cannot know it, and its "
            f"own mean ({fit.base_temperature:.3g} degC; it spans {low:.3g} .. {high:.3g}) "
            f"would leave an error of about {abs(fit.a):.2g} nT per degC between "
            f"it and the true t0 (on the liu2022 replica 9.3 nT instead of 0.5 nT)"
        )
    warn(
        f"|B_m| = a t + b (Eq. 1): a = {fit.a:.6g} +/- {fit.a_standard_error:.2g} nT/degC, "
        f"b = {fit.b:.8g} +/- {fit.b_standard_error:.2g} nT, fit RMSE {fit.fit_rmse:.4g} nT, "
        f"n = {fit.n}, t = {fit.temperature_range[0]:g} .. {fit.temperature_range[1]:g} degC; "
        f"k(t) = 1 + {fit.k_slope:.6g} (t - {fit.base_temperature:g}) (Eq. 9)"
        + (
            f"; diurnal gain g = {fit.diurnal_gain:.5g} +/- {fit.diurnal_gain_standard_error:.2g}"
            if fit.diurnal == "fitted" and fit.diurnal_gain_standard_error is not None
            else ""
        )
    )
    for message in fit.warnings:
        warning(message)
    emit_json(fit.to_dict(), args.output)
    if args.output:
        warn(f"wrote {args.output}")
    return 0
