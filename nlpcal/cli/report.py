"""`nlpcal report`: a calibration and a log as one self-contained HTML file.

    nlpcal report PARAMS.json LOG.csv -o report.html [--columns X Y Z] [--unit U]
                  [--reference-field F | --reference-column COL | --reference-model igrf|wmm ...]

The report embeds the figure (base64 PNG; needs matplotlib, else it says so), the parameters with
standard errors, units and correlations, the Table 1 rows of the calibration and of the log,
identifiability, warnings and provenance (nlpcal version, input files and their SHA-256, options).
It opens from disk in any browser: no script, nothing fetched. Without a reference option the
reference of the calibration is used: its constant field, or the log's column it was fitted with.
"""

from __future__ import annotations

import sys

from .apply import add_correction_arguments, correction_for
from .common import (
    add_command,
    add_reference_arguments,
    log_options,
    report_log,
    say,
    table_options,
    tell,
)


def register(sub):
    parser = add_command(
        sub,
        "report",
        help="a self-contained HTML report of a calibration on a log",
        description=__doc__.split("\n\n")[2],
        examples=(
            "nlpcal report params.json log.csv -o report.html",
            "nlpcal report params.json log.csv --reference-model igrf --lat 48.1 --lon 11.6 "
            "--date 2026-05-01 -o report.html",
        ),
    )
    add_correction_arguments(parser)
    add_reference_arguments(parser)
    parser.add_argument(
        "-o", "--output", required=True, metavar="REPORT.html", help="write the report here"
    )
    parser.set_defaults(func=run)


def stored_reference_column(parameters, options: dict, columns) -> str | None:
    """The reference column the calibration was fitted with, when no reference option is given
    and the log has that column (a constant reference is taken from the parameters by
    `nlpcal.report`)."""
    if any(
        options.get(k) is not None for k in ("reference_field", "reference_model", "reference_log")
    ):
        return None
    if options.get("reference_column") is not None:
        return None
    reference = getattr(parameters, "reference", None)  # a CalibrationResult's, or none
    column = reference.column if reference is not None else None
    return column if column is not None and column in list(columns) else None


def run(args) -> int:
    from ..correction import read_log_for
    from ..io import check_output_path, read_table, write_text_atomic
    from ..report import report

    check_output_path(args.output, args.params, args.log, args.drift)
    table = read_table(args.log, **table_options(args))
    correction = correction_for(args, table.columns, require_temperature=True)
    options = log_options(args)
    stored = stored_reference_column(correction.parameters, options, table.columns)
    if stored:
        options["reference_column"] = stored
        correction.notes.append(
            f"reference column {stored!r} of the log, as in the parameters file (a reference "
            f"option overrides it)"
        )
    log = read_log_for(table, correction, **options)
    report_log(log)
    corrected = correction.apply(log)
    tell(correction.notes)
    options = {
        key: value
        for key, value in sorted(vars(args).items())
        if key not in ("func", "params", "log", "output") and value not in (None, False)
    }
    options["command_line"] = " ".join(["nlpcal", *sys.argv[1:]]) if sys.argv else "nlpcal"
    written = report(
        correction.parameters, log, corrected, parameters_path=args.params, options=options
    )
    tell(written.notes)
    write_text_atomic(args.output, written.html)
    say(f"nlpcal report: wrote {args.output}")
    return 0
