"""`nlpcal import`: a calibration from another system back to the nine parameters.

    nlpcal import FILE [--format matlab|matrix|ardupilot|px4|c-header] [--reference-field F]
                  [--unit U] [--instance N] -o params.json

Any affine correction B_out = A (B_M - b) is turned into the nine parameters of Eq. 4 through
the Cholesky route (A^T A)^-1 = (S N)(S N)^T; the rotation that the nine parameters do not carry
is reported (the magnitude |B1| is the same). The result is a parameters file that apply,
stats, report and export use like any other. Without --format, FILE's extension decides (.param/
.parm ardupilot, .params px4, .h c-header, .json matrix, .m matlab). The device id (COMPASS_DEV_ID,
CAL_MAGn_ID) becomes the result's sensor_id and the mounting (COMPASS_ORIENT, CAL_MAGn_ROT) its
orientation; every field of the file the result does not carry is named on stderr.
"""

from __future__ import annotations

from .common import add_command, add_field_argument, emit_json, say, tell
from .export import add_format_arguments


def register(sub):
    parser = add_command(
        sub,
        "import",
        help="read a MATLAB, ArduPilot, PX4, matrix or C-header calibration into params.json",
        description=__doc__.split("\n\n")[2],
        examples=(
            "nlpcal import compass.param -o params.json      # ardupilot, from the extension",
            "nlpcal import magcal.json --format matlab --unit uT --reference-field 48.5",
        ),
    )
    parser.add_argument(
        "file", metavar="FILE", help="the calibration file of the other system (text or JSON)"
    )
    add_field_argument(
        parser,
        "total field the correction should map to [the file's unit], e.g. 48.5: a file with "
        "its own expected field (magcal's expmfs, the matrix 'field') has A rescaled to it; "
        "otherwise it is recorded as the reference field",
        legacy="--field",
    )
    add_format_arguments(
        parser,
        "unit of the offsets and field of a matlab, matrix or c-header file (default: what the "
        "file says, else nT)",
        "FILE",
    )
    parser.add_argument(
        "-o", "--output", metavar="PARAMS.json", help="write here (stdout when absent)"
    )
    parser.set_defaults(func=run)


def run(args) -> int:
    from ..formats import format_for, import_file
    from ..io import check_output_path

    check_output_path(args.output, args.file)
    fmt = args.fmt or format_for(args.file, "FILE")
    result, notes = import_file(
        args.file, fmt, unit=args.unit, reference_field=args.reference_field, instance=args.instance
    )
    tell(notes)
    emit_json(result.to_dict(), args.output)
    if args.output:
        say(f"nlpcal import: wrote {args.output}")
    return 0
