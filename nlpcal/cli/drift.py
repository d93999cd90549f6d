"""`nlpcal drift fit`: the temperature drift pipeline of Liu et al. (2022) on a static log.

    nlpcal drift fit LOG.csv --temperature-column COL --reference-column COL
                     [--base-temperature T0] [--columns X Y Z] [--unit nT] [--drop-invalid]
                     [-o drift.json]

Diurnal correction, the line |B_m| = a t + b (Eq. 1) and k(t) of Eq. 9; temperatures in degC.
`nlpcal apply --drift` and `nlpcal stats --drift` use the result (see `nlpcal.cli.calibrate`).
Exit status: 0 success (also with warnings), 1 a solve failed, 2 bad usage or input.
"""

from __future__ import annotations

import sys

from .common import add_log_arguments, emit_json, log_options, tell


def register(sub):
    parser = sub.add_parser(
        "drift",
        help="temperature drift of Liu et al. (2022): fit k(t) against a proton reference",
        description="Temperature drift (Liu et al. 2022): the line |B_m| = a t + b (Eq. 1) of a "
        "static sensor against a proton reference, and the factor k(t) of Eq. 9.",
    )
    inner = parser.add_subparsers(
        dest="drift_command", metavar="SUBCOMMAND", parser_class=type(parser)
    )
    inner.required = True
    fit = inner.add_parser(
        "fit",
        help="fit |B_m| = a t + b (Eq. 1) on a static log with temperature and reference",
        description="The paper's pipeline on a static-sensor log: diurnal correction (base = the "
        "first reference value, -(F_i - F_1) added to the fluxgate modulus), least-"
        "squares line |B_m| = a t + b (Eq. 1) and k(t) = (a t + b)/(a t0 + b) (Eq. 9)."
        " Warns when the temperature span is too small for a meaningful slope.",
    )
    fit.add_argument("log", metavar="LOG.csv")
    fit.add_argument(
        "--temperature-column", required=True, metavar="COL", help="column of temperatures [degC]"
    )
    fit.add_argument(
        "--reference-column",
        required=True,
        metavar="COL",
        help="column of reference magnitudes, e.g. a proton magnetometer [unit]",
    )
    fit.add_argument(
        "--base-temperature",
        type=float,
        metavar="T0",
        help="temperature of the system calibration, where k = 1 [degC] (default: "
        "the log's mean, with a warning)",
    )
    add_log_arguments(fit)
    fit.add_argument(
        "-o", "--output", metavar="DRIFT.json", help="write the fit here (stdout when absent)"
    )
    fit.set_defaults(func=run_fit)


def run_fit(args) -> int:
    from ..drift.fit import fit_drift_log
    from ..io import check_output_path, read_log

    check_output_path(args.output, args.log)
    log = read_log(args.log, **log_options(args), extra_columns=[args.temperature_column])
    tell(log.notes)
    fit = fit_drift_log(log, args.temperature_column, base_temperature=args.base_temperature)
    print(
        f"|B_m| = a t + b (Eq. 1): a = {fit.a:.6g} +/- {fit.a_standard_error:.2g} nT/degC, "
        f"b = {fit.b:.8g} +/- {fit.b_standard_error:.2g} nT, fit RMSE {fit.fit_rmse:.4g} nT, "
        f"n = {fit.n}, t = {fit.temperature_range[0]:g} .. {fit.temperature_range[1]:g} degC; "
        f"k(t) = 1 + {fit.k_slope:.6g} (t - {fit.base_temperature:g}) (Eq. 9)",
        file=sys.stderr,
    )
    tell(f"warning: {message}" for message in fit.warnings)
    emit_json(fit.to_dict(), args.output)
    return 0
