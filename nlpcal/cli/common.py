"""What every subcommand shares: the parser class, common arguments and output helpers.

Messages go to stderr at three levels, set once per run from -q/--quiet and -v/--verbose (every
subcommand has both): `warn` always prints (warnings and what went wrong), `tell`/`info` print
unless -q (what nlpcal decided on the user's behalf, tables, "wrote ..."), `detail` prints only
with -v (how the log was read, timings); `solver_log` sends IPOPT's own log to stderr with -v.
"""

from __future__ import annotations

import argparse
import contextlib
import sys

#: Field units accepted by --unit (the library's `nlpcal.units.FIELD_UNITS_NT`).
FIELD_UNITS = ("nT", "uT", "mT", "mG", "G", "T", "raw")

#: -1 quiet, 0 normal, 1 verbose; set by `set_verbosity` at the start of a run.
VERBOSITY = 0


class UsageError(Exception):
    """A command line that argparse cannot parse; `prog` is the (sub)command it concerns."""

    def __init__(self, message: str, prog: str = "nlpcal"):
        super().__init__(message)
        self.prog = prog


class Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so that main() keeps the exit status."""

    def error(self, message):
        raise UsageError(f"{self.prog}: error: {message}", self.prog)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples keep their line breaks; argument help is wrapped."""

    def __init__(self, prog):
        super().__init__(prog, max_help_position=30, width=100)


def add_command(sub, name: str, *, help: str, description: str, examples=()):
    """A subcommand parser with the shared formatting, -v/--verbose and -q/--quiet, and its
    examples (command lines, each a string) at the end of its help."""
    epilog = None
    if examples:
        epilog = "examples:\n" + "\n".join(f"  {line}" for line in examples)
    parser = sub.add_parser(
        name,
        help=help,
        description=description,
        epilog=epilog,
        formatter_class=HelpFormatter,
    )
    add_verbosity(parser)
    return parser


def add_verbosity(parser) -> None:
    """-v/--verbose and -q/--quiet (defaults left to the top-level parser)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        default=argparse.SUPPRESS,
        help="also say how the input was read, timings, and show IPOPT's log",
    )
    group.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=argparse.SUPPRESS,
        help="print only warnings and errors on stderr",
    )


def set_verbosity(args) -> None:
    global VERBOSITY
    VERBOSITY = -1 if getattr(args, "quiet", False) else int(bool(getattr(args, "verbose", False)))


def warn(message: str) -> None:
    """A warning on stderr (also with -q)."""
    print(f"nlpcal: warning: {message}", file=sys.stderr)


def info(message: str) -> None:
    """A human message on stderr (not with -q)."""
    if VERBOSITY >= 0:
        print(f"nlpcal: {message}", file=sys.stderr)


def detail(message: str) -> None:
    """A message on stderr with -v only."""
    if VERBOSITY >= 1:
        print(f"nlpcal: {message}", file=sys.stderr)


def tell(notes) -> None:
    """What the library decided on the user's behalf, one line each on stderr (not with -q)."""
    for note in notes:
        info(note)


def show(text: str) -> None:
    """A table or block of text on stderr (not with -q)."""
    if VERBOSITY >= 0:
        print(text, file=sys.stderr)


def report_log(log) -> None:
    """How a log was read (-v), what the reader decided (not -q) and what looks wrong."""
    engine = getattr(log, "engine", "c")
    detail(f"read {log.path}: {log.layout.describe()} (pandas {engine} engine)")
    tell(log.notes)
    for message in log.warnings:
        warn(message)


def solver_log():
    """With -v, IPOPT's log (printed through Python's stdout by CasADi) goes to stderr."""
    return contextlib.redirect_stdout(sys.stderr) if VERBOSITY >= 1 else contextlib.nullcontext()


def add_input_arguments(parser) -> None:
    """--header / --no-header: force or deny a header row (default: detected)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--header",
        dest="header",
        action="store_const",
        const=True,
        default=None,
        help="the first line that is not a # comment names the columns (default: detected)",
    )
    group.add_argument(
        "--no-header",
        dest="header",
        action="store_const",
        const=False,
        help="the file has no header row: columns are 0, 1, 2, ... (default: detected)",
    )


def add_log_arguments(
    parser,
    default_from: str = 'the column names (mx_uT, "X (uT)", _gauss, _counts ...), else nT',
    choices=FIELD_UNITS,
) -> None:
    """--columns, --unit, --header/--no-header and --drop-invalid, shared by every command that
    reads a field log."""
    parser.add_argument(
        "--columns",
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="the three field columns, by name or 0-based position (e.g. --columns mx my mz, "
        "--columns 1 2 3); default: recognised from the names (bx/by/bz, x/y/z, mag_x/..., "
        "mx_uT/...), or, without a header row, the only three columns or the three after a "
        "leading time column",
    )
    parser.add_argument(
        "--unit",
        choices=choices,
        default=None,
        help=f"unit of the field columns, and of a reference whose name carries none "
        f"(default: from {default_from})"
        + ("; 'raw' keeps counts" if "raw" in choices else "")
        + ". Magnitudes far from Earth's 22 000-67 000 nT are warned about, with the units "
        "that would fit; a unit given here is used as given",
    )
    add_input_arguments(parser)
    parser.add_argument(
        "--drop-invalid",
        action="store_true",
        help="drop rows with missing or non-numeric values, and rows repeating the field "
        "vector of the row before (a stuck or oversampling logger), reporting how many, "
        "instead of failing on the first and keeping the second. Rows reading exactly "
        "(0, 0, 0) are always left out",
    )


def add_field_argument(
    parser,
    help: str,
    *,
    legacy: str | None = None,
    legacy_dest: str = "reference_field",
    required: bool = False,
):
    """--reference-field F, the one name of a known field magnitude in every command, in a
    mutually exclusive group (returned) with the hidden old name `legacy` (stored in
    `legacy_dest`: "reference_field" when it meant the same, "reference_field_nt" when it was in
    nT where the new name takes the field columns' unit)."""
    group = parser.add_mutually_exclusive_group(required=required)
    group.add_argument("--reference-field", type=float, metavar="F", help=help)
    if legacy:
        group.add_argument(legacy, dest=legacy_dest, type=float, help=argparse.SUPPRESS)
    return group


def add_reference_arguments(parser) -> None:
    """--reference-field F | --reference-column COL."""
    ref = add_field_argument(
        parser,
        "known total field magnitude, in the unit of the field columns (e.g. 48500 for nT, "
        "or a proton magnetometer reading): fits |B1| to it instead of only flattening it, "
        "which also fixes the absolute scale",
    )
    ref.add_argument(
        "--reference-column",
        metavar="COL",
        help="column of per-sample reference magnitudes (name or 0-based position), in the "
        "unit its name carries (proton_nT) or the field columns' unit",
    )


def log_options(args) -> dict:
    """The keyword arguments of `nlpcal.io.read_log` that the common arguments give."""
    options = {
        "columns": args.columns,
        "unit": args.unit,
        "drop_invalid": args.drop_invalid,
        "header": getattr(args, "header", None),
        "reference_column": getattr(args, "reference_column", None),
        "reference_field": getattr(args, "reference_field", None),
    }
    legacy = getattr(args, "reference_field_nt", None)
    if legacy is not None:
        options.update(reference_field=legacy, reference_field_unit="nT")
    return options


def emit_json(document, output) -> None:
    """JSON to -o (written atomically) or to stdout; strict (no NaN, no Infinity)."""
    from ..io.files import json_text, write_text_atomic

    text = json_text(document)
    if output:
        write_text_atomic(output, text)
    else:
        sys.stdout.write(text)


def emit_csv(frame, output, float_format: str | None = None) -> None:
    """A table to -o (written atomically) or to stdout; exact values unless float_format."""
    from ..io.files import write_csv_atomic

    if output:
        write_csv_atomic(output, frame, float_format)
    else:
        frame.to_csv(sys.stdout, index=False, float_format=float_format)
