"""`nlpcal export`: a calibration in the format of the system that will use it.

    nlpcal export PARAMS.json [--format matlab|matrix|ardupilot|px4|c-header] [-o FILE]
                  [--unit U] [--instance N] [--max-rotation-deg D] [--drop-temperature]

matlab: MATLAB magcal's C = (D - b) * A (A the transpose of nlpcal's), b, expmfs; matrix: JSON
with A (3 x 3, row-major) and b of B1 = A (B_M - b), plus units; ardupilot: a .param file
(COMPASS_OFS*, DIA*, ODI*, SCALE*, milligauss); px4: CAL_MAGn_* (gauss) in QGroundControl's
parameter file; c-header: NLPCAL_A, NLPCAL_B at full double precision and nlpcal_apply(), the
function that applies them. The autopilots take a symmetric matrix: the symmetric factor of the
polar decomposition A = R P, with the rotation R stated in the file and on stderr. Without
--format, the extension of -o decides (.param/.parm ardupilot, .params px4, .h c-header, .json
matrix, .m matlab). The device id (sensor_id) goes into COMPASS_DEV_ID or CAL_MAGn_ID; what the
format has no place for is named on stderr. Exit 2 when the calibration cannot be expressed in
the format (a temperature model PX4 cannot represent, without --drop-temperature).
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
            "nlpcal export params.json -o compass.param      # ardupilot, from the extension",
            "nlpcal export params.json -o calibration.h      # C header with nlpcal_apply()",
            "nlpcal export temperature.json -o vehicle.params --drop-temperature",
            "nlpcal export params.json --format matlab --unit uT",
        ),
    )
    add_params_argument(parser)
    add_format_arguments(
        parser,
        "unit of the offsets and field in matlab, matrix and c-header (default: the unit of the "
        "calibrated log); ardupilot is in mG and px4 in G",
        "-o",
    )
    parser.add_argument(
        "-o",
        "--output",
        metavar="FILE",
        help="write here (stdout when absent); its extension gives the format when --format "
        "is absent",
    )
    parser.add_argument(
        "--drop-temperature",
        action="store_true",
        help="write a temperature calibration to px4 without its temperature model when PX4's "
        "thermal compensation (TC_M*) cannot represent it (default: exit 2)",
    )
    parser.add_argument(
        "--max-rotation-deg",
        type=float,
        metavar="D",
        help="largest rotation between nlpcal's axes and the autopilot's symmetric matrix "
        "(default 5 deg)",
    )
    parser.set_defaults(func=run)


def add_format_arguments(parser, unit_help: str, file: str) -> None:
    """--format, --unit and --instance, shared by export and import (`file`: the argument
    whose extension gives the format when --format is absent)."""
    parser.add_argument(
        "--format",
        choices=FORMATS,
        dest="fmt",
        metavar="FMT",
        help=f"one of {', '.join(FORMATS)} (default: from the extension of {file})",
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
    from ..formats import export, format_for
    from ..io import check_output_path, write_text_atomic

    check_output_path(args.output, args.params)
    fmt = args.fmt or format_for(args.output, "-o")
    written = export(
        load_parameters(args.params),
        fmt,
        unit=args.unit,
        instance=args.instance,
        max_rotation_deg=args.max_rotation_deg,
        drop_temperature=args.drop_temperature,
    )
    tell(written.notes)
    if fmt in ("ardupilot", "px4"):
        say(
            f"nlpcal export: the symmetric matrix turns nlpcal's axes by "
            f"{written.rotation_deg:.4f} deg (R is in the file's comments); |B1| is unchanged"
        )
    write_text_atomic(args.output, written.text)
    if args.output:
        say(f"nlpcal export: wrote {fmt} to {args.output}")
    return 0
