"""The `nlpcal` command line: parse the arguments, call one library verb, print.

Exit status: 0 success, 1 a solve or quality check failed, 2 bad usage or input.
Data go to stdout or -o; human messages go to stderr.

Each subcommand module registers its arguments with plain argparse and imports the library only
when it runs, so `nlpcal --help` and `nlpcal --version` do not pay for numpy, pandas and CasADi.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import InputError, QualityError, SolveError
from ..version import __version__
from . import (
    calibrate,
    common,
    compare,
    compass,
    drift,
    export,
    imports,
    orthogonality,
    report,
    simulate,
)
from .common import Parser, UsageError, add_quiet_argument

#: The subcommand modules, in the order of the help.
COMMANDS = (simulate, calibrate, compare, orthogonality, drift, compass, export, imports, report)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="nlpcal", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"nlpcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    sub.required = True
    for module in COMMANDS:
        module.register(sub)
    add_quiet_argument(parser)
    return parser


def main(argv=None) -> int:
    """Run the command line; returns the exit status instead of exiting."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except UsageError as exc:
        print(f"{exc}\n(see 'nlpcal --help')", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help and --version
        return int(exc.code or 0)
    common.QUIET = bool(getattr(args, "quiet", False))
    try:
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"nlpcal {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except QualityError as exc:
        print(f"nlpcal {args.command}: quality check failed: {exc}", file=sys.stderr)
        return 1
    except SolveError as exc:
        status = f" (IPOPT status: {exc.status})" if exc.status else ""
        print(f"nlpcal {args.command}: solve failed: {exc}{status}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"nlpcal {args.command}: interrupted", file=sys.stderr)
        return 130
