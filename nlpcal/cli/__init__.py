"""The `nlpcal` command line: thin wrappers over the library's verbs.

Exit status: 0 success, 1 a solve or quality check failed, 2 bad usage or input.
Data go to stdout or -o; human messages go to stderr.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys

from .. import __version__
from ..errors import InputError, QualityError, SolveError
from ..io import write_csv_atomic, write_json_atomic

#: Modules of nlpcal.cli that each add one subcommand through `register(subparsers)`.
COMMAND_MODULES = (
    "simulate",
    "core",
    "orthogonality",
    "compass",
    "drift",
    "compare",
)


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so that main() keeps the exit status."""

    def error(self, message):
        raise _UsageError(f"{self.prog}: {message}")


class _UsageError(Exception):
    pass


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="nlpcal", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"nlpcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv=None) -> int:
    """Run the command line; returns the exit status instead of exiting."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:
        print(f"{exc}\n(see 'nlpcal --help')", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help and --version
        return int(exc.code or 0)
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


def warn(message: str) -> None:
    """A human message on stderr."""
    print(f"nlpcal: {message}", file=sys.stderr)


def emit_csv(frame, output, float_format: str | None = None) -> None:
    """A table to -o (written atomically) or to stdout; exact values unless float_format."""
    if output:
        write_csv_atomic(output, frame, float_format)
    else:
        frame.to_csv(sys.stdout, index=False, float_format=float_format)


def emit_json(document, output) -> None:
    """JSON to -o (written atomically) or to stdout."""
    if output:
        write_json_atomic(output, document)
    else:
        sys.stdout.write(json.dumps(document, indent=2) + "\n")
