"""`nlpcal orthogonality`: worst-case total-field error, error map and angle inversion (Wang et
al. 2015).

    nlpcal orthogonality worst-case --angles-deg A B G --reference-field F [-o out.json] [-v]
    nlpcal orthogonality map --angles-deg A B G --reference-field F [-o map.png] [--csv map.csv|-]
                             [--step-deg 1]
    nlpcal orthogonality invert LOG [LOG2 ...] [--reference-field F] [--bound-deg B [B B]]
                             [--columns X Y Z] [--unit nT] [--drop-invalid] [-o out.json] [-v]

Angles are alpha, beta, gamma of Zhou et al. (2010) in degrees; the field of worst-case and map
in nT, the reference field of invert in the unit of the logs' field columns. `invert` with two or
more logs of the same probe also reports their repeatability (Table 4 of Wang et al. 2015).
JSON goes to -o or, without it, to stdout; messages and warnings go to stderr. Exit status: 0
success (also when a bound is active: that is a warning), 1 IPOPT failed, 2 bad usage or input.
The old name --field is still accepted everywhere (in nT).
"""

from __future__ import annotations

from .common import (
    add_command,
    add_field_argument,
    add_log_arguments,
    emit_json,
    log_options,
    report_log,
    solver_log,
    warn,
    warning,
)

DEFAULT_BOUND_DEG = 0.5  # the library's nlpcal.orthogonality.DEFAULT_BOUND_DEG [deg]
ANGLES_HELP = (
    "how far the three sensor axes are from perpendicular [deg], in the convention of Zhou et al. "
    "(2010): alpha and gamma tilt the x axis, beta the y axis; e.g. 0.1 0.1 0.1"
)


def register(sub):
    parser = add_command(
        sub,
        "orthogonality",
        help="axes not quite perpendicular: worst-case |B| error, error map, angle inversion",
        description="""\
Non-orthogonal axes (Wang et al. 2015): when the three sensor axes are not exactly
perpendicular, the measured |B| depends on the field's direction. worst-case finds the largest
error over all directions for given angles, map draws it over all directions, invert finds the
angles from logs of a probe rotated in a steady field.""",
        examples=(
            "nlpcal orthogonality worst-case --angles-deg 0.1 0.1 0.1 --reference-field 55000",
            "nlpcal orthogonality map --angles-deg 0.1 0.1 0.1 --reference-field 55000 -o map.png",
            "nlpcal orthogonality invert run1.csv run2.csv -o angles.json",
        ),
    )
    inner = parser.add_subparsers(
        dest="orthogonality_command",
        metavar="SUBCOMMAND",
        parser_class=type(parser),
        title="subcommands",
    )
    inner.required = True

    worst = add_command(
        inner,
        "worst-case",
        help="largest total-field error over all field directions",
        description="""\
Largest positive and most negative total-field error |TB| - |B| over all field directions
(theta, phi) for given angles, solved with IPOPT from several starts and certified by the
singular values of T. Wang et al. (2015) report about 95 nT for 0.1 deg each at 55 000 nT.""",
        examples=(
            "nlpcal orthogonality worst-case --angles-deg 0.1 0.1 0.1 --reference-field 55000",
        ),
    )
    _add_angles_and_field(worst)
    worst.add_argument(
        "-o", "--output", metavar="OUT.json", help="write the JSON here (default: stdout)"
    )

    mapping = add_command(
        inner,
        "map",
        help="theta-phi map and sphere picture of the total-field error",
        description="""\
The total-field error over a (theta, phi) grid of field directions: a PNG with the sphere
(Fig. 3 of Wang et al. 2015) and the theta-phi map (Fig. 4), and/or a CSV with columns
theta_deg, phi_deg, delta_B_nT.""",
        examples=(
            "nlpcal orthogonality map --angles-deg 0.1 0.1 0.1 --reference-field 55000 -o map.png",
            "nlpcal orthogonality map --angles-deg 0.1 0 0 --reference-field 50000 --csv - ",
        ),
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

    invert = add_command(
        inner,
        "invert",
        help="the three angles from rotation logs (bounded IPOPT problem)",
        description="""\
Invert alpha, beta, gamma from logs of a probe rotated in a steady field (unit sensitivities and
zero offsets assumed: use it on a probe whose offsets and scales are already corrected). With
--reference-field, the corrected total field is fitted to that field; without it, its spread
around the mean is minimised (the paper's objective). With two or more logs of the same probe,
also reports the mean, the largest deviation from it and the worst-case total-field error that
deviation implies. Give the logs before --bound-deg/--columns (or end those with --).""",
        examples=(
            "nlpcal orthogonality invert rotation.csv -o angles.json",
            "nlpcal orthogonality invert run1.csv run2.csv run3.csv --reference-field 55000",
        ),
    )
    invert.add_argument(
        "logs",
        nargs="+",
        metavar="LOG",
        help="rotation log(s): delimited text, or - for stdin",
    )
    add_field_argument(
        invert,
        "known total field magnitude, in the unit of the field columns (e.g. 55000 for nT)",
        legacy="--field",
        legacy_dest="reference_field_nt",
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
    add_log_arguments(invert, choices=("nT", "uT", "mT", "mG", "G", "T"))
    invert.add_argument(
        "-o", "--output", metavar="OUT.json", help="write the JSON here (default: stdout)"
    )

    parser.set_defaults(func=run)


def _add_angles_and_field(parser):
    parser.add_argument(
        "--angles-deg",
        type=float,
        nargs=3,
        required=True,
        metavar=("ALPHA", "BETA", "GAMMA"),
        help=ANGLES_HELP,
    )
    add_field_argument(
        parser, "total field magnitude [nT], e.g. 55000", legacy="--field", required=True
    )


def run(args) -> int:
    handlers = {"worst-case": _run_worst_case, "map": _run_map, "invert": _run_invert}
    return handlers[args.orthogonality_command](args)


def _run_worst_case(args) -> int:
    from ..io import check_output_path
    from ..orthogonality import worst_case

    check_output_path(args.output)
    with solver_log():
        result = worst_case(args.angles_deg, args.reference_field, verbose=args.verbose)
    emit_json(result.to_dict(), args.output)
    if args.output:
        warn(
            f"max |dB| = {result.max_abs_error_nT:.4f} nT at theta = "
            f"{result.worst.theta_deg:.2f} deg, phi = {result.worst.phi_deg:.2f} deg; "
            f"wrote {args.output}"
        )
    return 0


def _run_map(args) -> int:
    from ..errors import InputError
    from ..io import Outputs, check_output_path
    from ..io.output import Precision, check_table_output, write_frames
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
        check_table_output(args.csv)
    theta, phi, error = error_map(args.angles_deg, args.reference_field, args.step_deg)
    png = None
    if args.output:
        png = orthogonality_map_png(
            args.angles_deg,
            args.reference_field,
            theta,
            phi,
            error,
            worst_case(args.angles_deg, args.reference_field),
        )
    table = error_table(theta, phi, error) if args.csv else None
    with Outputs() as outputs:  # everything is computed: only now touch the outputs
        if png is not None:
            outputs.bytes(args.output, png)
        if table is not None:
            write_frames(outputs, args.csv, [table], precision=Precision(10))
    if png is not None:
        warn(f"wrote {args.output} (grid max |dB| = {abs(error).max():.4f} nT)")
    if table is not None and args.csv != "-":
        warn(f"wrote {args.csv} ({len(table)} grid points)")
    return 0


def _run_invert(args) -> int:
    from ..io import check_output_path, read_log
    from ..orthogonality import invert_logs

    check_output_path(args.output, *args.logs)
    options = log_options(args)
    logs = [read_log(path, **options) for path in args.logs]
    for log in logs:
        report_log(log)
    with solver_log():
        result = invert_logs(
            logs, reference_field=logs[0].reference, bound_deg=args.bound_deg, verbose=args.verbose
        )
    for message in result.warnings:
        warning(message)
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
        warn(f"{angles} deg{extra}; wrote {args.output}")
    return 0
