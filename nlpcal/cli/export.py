"""`nlpcal export`: a calibration in the format of the system that will use it.

    nlpcal export PARAMS.json --format matlab|matrix|ardupilot|px4|c-header [-o FILE]
                  [--unit U] [--instance N] [--max-rotation-deg D]

matlab: MATLAB magcal's C = (D - b) * A (A the transpose of nlpcal's), b, expmfs; matrix: JSON
with A (3 x 3, row-major) and b of B1 = A (B_M - b), plus units; ardupilot: a .param file
(COMPASS_OFS*, DIA*, ODI*, SCALE*, milligauss); px4: CAL_MAGn_* (gauss) in QGroundControl's
parameter file; c-header: NLPCAL_A, NLPCAL_B at full double precision. The autopilots take a
symmetric matrix: the symmetric factor of the polar decomposition A = R P, with the rotation R
stated in the file and on stderr. Exit 2 when the calibration cannot be expressed in the format.
"""

from __future__ import annotations

from .common import FIELD_UNITS, add_command, add_params_argument, say, tell

FORMATS = ("matlab", "matrix", "ardupilot", "px4", "c-header")  # nlpcal.formats.FORMATS


def register(sub):
    parser = add_command(
        sub,
        "export",
        help="write a calibration for MATLAB, ArduPilot, PX4, firmware (C) or as a matrix",
        description=__doc__.split("\n\n")[2],
        examples=(
            "nlpcal export params.json --format ardupilot -o compass.param",
            "nlpcal export params.json --format c-header -o calibration.h",
            "nlpcal export params.json --format matlab --unit uT",
        ),
    )
    add_params_argument(parser)
    add_format_arguments(
        parser,
        "unit of the offsets and field in matlab, matrix and c-header (default: the unit of the "
        "calibrated log); ardupilot is in mG and px4 in G",
    )
    parser.add_argument("-o", "--output", metavar="FILE", help="write here (stdout when absent)")
    parser.add_argument(
        "--max-rotation-deg",
        type=float,
        metavar="D",
        help="largest rotation between nlpcal's axes and the autopilot's symmetric matrix "
        "(default 5 deg)",
    )
    parser.set_defaults(func=run)


def add_format_arguments(parser, unit_help: str) -> None:
    """--format, --unit and --instance, shared by export and import."""
    parser.add_argument(
        "--format",
        required=True,
        choices=FORMATS,
        dest="fmt",
        metavar="FMT",
        help=f"one of {', '.join(FORMATS)}",
    )
    parser.add_argument("--unit", choices=FIELD_UNITS, help=unit_help)
    parser.add_argument(
        "--instance",
        type=int,
        metavar="N",
        help="compass instance: ardupilot 1, 2 or 3 (default 1; 2 is COMPASS_OFS2_* ...), px4 "
        "calibration slot 0-3 (default 0)",
    )


def run(args) -> int:
    from ..correction import load_parameters
    from ..formats import export
    from ..io import check_output_path, write_text_atomic

    check_output_path(args.output, args.params)
    written = export(
        load_parameters(args.params),
        args.fmt,
        unit=args.unit,
        instance=args.instance,
        max_rotation_deg=args.max_rotation_deg,
    )
    tell(written.notes)
    if args.fmt in ("ardupilot", "px4"):
        say(
            f"nlpcal export: the symmetric matrix turns nlpcal's axes by "
            f"{written.rotation_deg:.4f} deg (R is in the file's comments); |B1| is unchanged"
        )
    write_text_atomic(args.output, written.text)
    if args.output:
        say(f"nlpcal export: wrote {args.fmt} to {args.output}")
    return 0
