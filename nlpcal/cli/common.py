"""What every subcommand shares: the parser class, common arguments and output helpers."""

from __future__ import annotations

import argparse
import sys

#: Field units accepted by --unit (the library's `nlpcal.units.FIELD_UNITS_NT`).
FIELD_UNITS = ("nT", "uT", "mT", "mG", "G", "T", "raw")


class UsageError(Exception):
    """A command line that argparse cannot parse."""


class Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so that main() keeps the exit status."""

    def error(self, message):
        raise UsageError(f"{self.prog}: {message}")


def warn(message: str) -> None:
    """A human message on stderr."""
    print(f"nlpcal: {message}", file=sys.stderr)


def add_log_arguments(
    parser, default_from: str = 'the column names (mx_uT, "X (uT)", _gauss, _counts ...), else nT'
):
    """--columns, --unit and --drop-invalid, shared by every command that reads a field log."""
    parser.add_argument(
        "--columns",
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="the three field columns (default: detected, bx/by/bz, x/y/z, ...)",
    )
    parser.add_argument(
        "--unit",
        choices=FIELD_UNITS,
        default=None,
        help=f"unit of the field columns and references (default: from "
        f"{default_from}); 'raw' keeps counts or other non-field units",
    )
    parser.add_argument(
        "--drop-invalid",
        action="store_true",
        help="drop rows with missing or non-numeric values (reporting how many) instead of failing",
    )


def add_reference_arguments(parser) -> None:
    """--reference-field F | --reference-column COL."""
    ref = parser.add_mutually_exclusive_group()
    ref.add_argument(
        "--reference-field",
        type=float,
        metavar="F",
        help="known field magnitude [unit], e.g. a proton reading",
    )
    ref.add_argument(
        "--reference-column", metavar="COL", help="column of per-sample reference magnitudes [unit]"
    )


def add_loss_arguments(parser) -> None:
    """--loss l2|huber|cauchy and --loss-scale F."""
    parser.add_argument(
        "--loss",
        choices=("l2", "huber", "cauchy"),
        default="l2",
        help="l2: least squares (default, the paper's); huber or cauchy: robust to spikes and "
        "other outliers, which they down-weight",
    )
    parser.add_argument(
        "--loss-scale",
        type=float,
        metavar="F",
        help="residual of |B1| beyond which a sample is down-weighted [unit] (default: 1.345 "
        "(huber) or 2.385 (cauchy) times the robust standard deviation, 1.4826 MAD, of the "
        "residuals)",
    )


def log_options(args) -> dict:
    """The keyword arguments of `nlpcal.io.read_log` that the common arguments give."""
    return {
        "columns": args.columns,
        "unit": args.unit,
        "drop_invalid": args.drop_invalid,
        "reference_column": getattr(args, "reference_column", None),
        "reference_field": getattr(args, "reference_field", None),
    }


def tell(notes) -> None:
    """What the library decided on the user's behalf, one line each on stderr."""
    for note in notes:
        warn(note)


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
