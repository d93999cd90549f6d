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


#: Set by -q/--quiet: human messages are silenced (errors are not).
QUIET = False


def warn(message: str) -> None:
    """A human message on stderr (silent with -q)."""
    if not QUIET:
        print(f"nlpcal: {message}", file=sys.stderr)


def say(text: str) -> None:
    """Human text (a table, say) on stderr, silent with -q."""
    if not QUIET:
        print(text, file=sys.stderr)


def progress(message: str, done: bool = False) -> None:
    """A progress line on stderr, rewritten in place: only when stderr is a terminal and not -q."""
    if QUIET or not sys.stderr.isatty():
        return
    sys.stderr.write(f"\r\033[K{message}" + ("\n" if done else ""))
    sys.stderr.flush()


def add_quiet_argument(parser) -> None:
    """-q/--quiet on a parser and, recursively, on its subcommands (the value set anywhere on the
    command line wins)."""
    default = argparse.SUPPRESS if parser.prog != "nlpcal" else False
    parser.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        default=default,
        help="no messages on stderr but errors",
    )
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                add_quiet_argument(child)


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
    """--reference-field F | --reference-column COL, or --reference-model with a place."""
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
    add_reference_model_arguments(parser)


MODELS = ("igrf", "wmm")  # the library's nlpcal.geomagnetic.MODELS


def add_place_arguments(parser, columns: bool = True) -> None:
    """--lat, --lon, --alt-m, --date, and with `columns` their per-sample column forms."""
    parser.add_argument("--lat", type=float, metavar="DEG", help="geodetic latitude [deg], north +")
    parser.add_argument("--lon", type=float, metavar="DEG", help="longitude [deg], east +")
    parser.add_argument(
        "--alt-m",
        type=float,
        metavar="M",
        help="height above the WGS 84 ellipsoid [m] (default 0)",
    )
    parser.add_argument("--date", metavar="YYYY-MM-DD", help="date (UTC) of the measurement")
    if columns:
        parser.add_argument("--lat-column", metavar="COL", help="column of latitudes [deg]")
        parser.add_argument("--lon-column", metavar="COL", help="column of longitudes [deg]")
        parser.add_argument("--alt-column", metavar="COL", help="column of heights [m]")
        parser.add_argument(
            "--time-column",
            metavar="COL",
            help="column of UTC times: ISO 8601 text, or Unix seconds",
        )


def add_reference_model_arguments(parser) -> None:
    """--reference-model igrf|wmm with the place and date, constant or per sample."""
    group = parser.add_argument_group(
        "reference field from a geomagnetic model (pip install 'nlpcal[geomag]')"
    )
    group.add_argument(
        "--reference-model",
        choices=MODELS,
        help="the model's total field at the place and date becomes the reference: igrf "
        "(IGRF-14, 1900-2030) or wmm (WMM2025, 2025-2030); per sample with the column options",
    )
    add_place_arguments(group)


def reference_model(args):
    """The `nlpcal.geomagnetic.ReferenceModel` the arguments ask for, or None."""
    from ..errors import InputError
    from ..geomagnetic import ReferenceModel

    names = ("lat", "lon", "alt_m", "date", "lat_column", "lon_column", "alt_column", "time_column")
    given = {name: getattr(args, name, None) for name in names}
    model = getattr(args, "reference_model", None)
    if model is None:
        used = [f"--{name.replace('_', '-')}" for name, value in given.items() if value is not None]
        if used:
            raise InputError(f"{', '.join(used)} need --reference-model igrf|wmm")
        return None
    spec = ReferenceModel(
        model=model,
        lat_deg=given["lat"],
        lon_deg=given["lon"],
        alt_m=given["alt_m"],
        date=given["date"],
        lat_column=given["lat_column"],
        lon_column=given["lon_column"],
        alt_column=given["alt_column"],
        time_column=given["time_column"],
    )
    spec.check()
    return spec


def add_threads_argument(parser) -> None:
    """--threads N."""
    parser.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="threads of the passes over the data (default: the cores available to the "
        "process, within its CPU affinity and cgroup quota)",
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
        "reference_model": reference_model(args),
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
