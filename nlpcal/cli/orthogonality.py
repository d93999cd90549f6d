"""`nlpcal orthogonality`: worst-case total-field error, error map and angle inversion (seed 003).

    nlpcal orthogonality worst-case --angles-deg A B G --field F [-o out.json] [-v]
    nlpcal orthogonality map --angles-deg A B G --field F [-o map.png] [--csv map.csv|-]
                             [--step-deg 1]
    nlpcal orthogonality invert LOG.csv [LOG2.csv ...] [--field F] [--bound-deg B [B B]]
                             [--columns X Y Z] [--unit nT] [--drop-invalid] [-o out.json] [-v]

Angles are alpha, beta, gamma of Zhou et al. (2010) in degrees; fields in nT. `invert` with two or
more logs of the same probe also reports their repeatability (Table 4 of Wang et al. 2015).
JSON goes to -o or, without it, to stdout; messages and warnings go to stderr. Exit status: 0
success (also when a bound is active: that is a warning), 1 IPOPT failed, 2 bad usage or input.
"""

from __future__ import annotations

import contextlib
import sys

from .common import emit_csv, emit_json, tell

DEFAULT_BOUND_DEG = 0.5  # the library's nlpcal.orthogonality.DEFAULT_BOUND_DEG [deg]


def register(sub):
    parser = sub.add_parser(
        "orthogonality",
        help="non-orthogonality: worst-case error, error map, angle inversion",
        description=__doc__.splitlines()[0].split(": ", 1)[1],
    )
    inner = parser.add_subparsers(dest="orthogonality_command", metavar="SUBCOMMAND")
    inner.required = True

    worst = inner.add_parser(
        "worst-case",
        help="largest total-field error over all field directions",
        description="Largest positive and most negative total-field error |TB| - |B| over all "
        "directions (theta, phi), solved with IPOPT from several starts and "
        "certified by the singular values of T.",
    )
    _add_angles_and_field(worst)
    worst.add_argument(
        "-o", "--output", metavar="OUT.json", help="write the JSON here (default: stdout)"
    )
    worst.add_argument("-v", "--verbose", action="store_true", help="show IPOPT's log (on stderr)")

    mapping = inner.add_parser(
        "map",
        help="theta-phi map and sphere picture of the total-field error",
        description="The total-field error over a (theta, phi) grid: a PNG with the sphere "
        "(Fig. 3 of Wang et al. 2015) and the theta-phi map (Fig. 4), and/or a CSV "
        "with columns theta_deg, phi_deg, delta_B_nT.",
    )
    _add_angles_and_field(mapping)
    mapping.add_argument(
        "-o",
        "--output",
        metavar="MAP.png",
        help="write the figure here (needs matplotlib: pip install 'nlpcal[plot]')",
    )
    mapping.add_argument("--csv", metavar="MAP.csv", help="write the grid here ('-': stdout)")
    mapping.add_argument(
        "--step-deg",
        type=float,
        default=1.0,
        metavar="DEG",
        help="grid step in theta and phi, in (0, 10] [deg] (default 1)",
    )

    invert = inner.add_parser(
        "invert",
        help="the three angles from rotation logs (bounded IPOPT problem)",
        description="Invert alpha, beta, gamma from logs of a probe rotated in a constant field "
        "(unit sensitivities and zero offsets assumed). With --field, the corrected "
        "total field is fitted to that field; without it, its spread around the mean "
        "is minimised (the paper's objective). With two or more logs of the same "
        "probe, also reports the mean, the largest deviation from it and the "
        "worst-case total-field error that deviation implies. Give the logs "
        "before --bound-deg/--columns (or end those with --).",
    )
    invert.add_argument("logs", nargs="+", metavar="LOG.csv", help="rotation log(s), CSV")
    invert.add_argument(
        "--field", type=float, metavar="NT", help="known total field for the reference variant [nT]"
    )
    invert.add_argument(
        "--bound-deg",
        type=float,
        nargs="+",
        default=[DEFAULT_BOUND_DEG],
        metavar="DEG",
        help="bound |angle| <= DEG, one value or three (alpha beta gamma) [deg] "
        f"(default {DEFAULT_BOUND_DEG:g})",
    )
    invert.add_argument(
        "--columns",
        nargs="+",
        metavar="COL",
        help="the three field columns (default: recognised bx/by/bz, x/y/z, ...)",
    )
    invert.add_argument(
        "--unit",
        default=None,
        choices=["nT", "uT", "mT", "mG", "G", "T"],
        help="unit of the field columns (default: from the column names, "
        'mx_uT, "X (uT)" ..., else nT)',
    )
    invert.add_argument(
        "--drop-invalid",
        action="store_true",
        help="drop rows with missing or non-numeric values instead of failing",
    )
    invert.add_argument(
        "-o", "--output", metavar="OUT.json", help="write the JSON here (default: stdout)"
    )
    invert.add_argument("-v", "--verbose", action="store_true", help="show IPOPT's log (on stderr)")

    parser.set_defaults(func=run)


def _add_angles_and_field(parser):
    parser.add_argument(
        "--angles-deg",
        type=float,
        nargs=3,
        required=True,
        metavar=("ALPHA", "BETA", "GAMMA"),
        help="non-orthogonality angles, Zhou 2010 convention [deg]",
    )
    parser.add_argument(
        "--field", type=float, required=True, metavar="NT", help="total field magnitude [nT]"
    )


def run(args) -> int:
    handlers = {"worst-case": _run_worst_case, "map": _run_map, "invert": _run_invert}
    return handlers[args.orthogonality_command](args)


def _run_worst_case(args) -> int:
    from ..io import check_output_path
    from ..orthogonality import worst_case

    check_output_path(args.output)
    with _solver_log(args.verbose):
        result = worst_case(args.angles_deg, args.field, verbose=args.verbose)
    emit_json(result.to_dict(), args.output)
    if args.output:
        _info(
            f"max |dB| = {result.max_abs_error_nT:.4f} nT at theta = "
            f"{result.worst.theta_deg:.2f} deg, phi = {result.worst.phi_deg:.2f} deg; "
            f"wrote {args.output}"
        )
    return 0


def _run_map(args) -> int:
    from ..errors import InputError
    from ..io import check_output_path, write_bytes_atomic
    from ..orthogonality import error_map, error_table, worst_case
    from ..plots import orthogonality_map_png, require_matplotlib

    if not args.output and not args.csv:
        raise InputError(
            "nothing to write; pass -o MAP.png and/or --csv MAP.csv (or --csv - for stdout)"
        )
    if args.output:
        require_matplotlib(three_d=True)
        check_output_path(args.output)
    if args.csv and args.csv != "-":
        check_output_path(args.csv)
    theta, phi, error = error_map(args.angles_deg, args.field, args.step_deg)
    png = None
    if args.output:
        png = orthogonality_map_png(
            args.angles_deg, args.field, theta, phi, error, worst_case(args.angles_deg, args.field)
        )
    # everything is computed: only now touch the outputs
    if png is not None:
        write_bytes_atomic(args.output, png)
        _info(f"wrote {args.output} (grid max |dB| = {abs(error).max():.4f} nT)")
    if args.csv:
        table = error_table(theta, phi, error)
        emit_csv(table, None if args.csv == "-" else args.csv, "%.10g")
        if args.csv != "-":
            _info(f"wrote {args.csv} ({len(table)} grid points)")
    return 0


def _run_invert(args) -> int:
    from ..errors import InputError
    from ..io import check_output_path, read_log
    from ..orthogonality import invert_logs

    check_output_path(args.output, *args.logs)
    if args.columns is not None and len(args.columns) != 3:
        raise InputError(f"got {len(args.columns)} field columns, expected 3; pass --columns X Y Z")
    logs = [
        read_log(path, args.columns, unit=args.unit, drop_invalid=args.drop_invalid)
        for path in args.logs
    ]
    for log in logs:
        tell(log.notes)
    with _solver_log(args.verbose):
        result = invert_logs(
            logs, field_nT=args.field, bound_deg=args.bound_deg, verbose=args.verbose
        )
    for message in result.warnings:
        _info(f"warning: {message}")
    document = result.to_dict()
    emit_json(document, args.output)
    if args.output:
        angles = ", ".join(
            f"{name} = {value:+.5f}"
            for name, value in zip(("alpha", "beta", "gamma"), document["angles_deg"])
        )
        extra = ""
        if len(logs) > 1:
            extra = (
                f"; {len(logs)} runs, largest deviation from the mean "
                f"{result.max_abs_deviation_deg:.5f} deg -> at most "
                f"{result.implied_worst_case_nT:.2f} nT"
            )
        _info(f"{angles} deg{extra}; wrote {args.output}")
    return 0


def _solver_log(verbose: bool):
    """With -v, IPOPT's log (printed through Python's stdout by CasADi) goes to stderr."""
    return contextlib.redirect_stdout(sys.stderr) if verbose else contextlib.nullcontext()


def _info(message: str) -> None:
    print(f"nlpcal orthogonality: {message}", file=sys.stderr)
