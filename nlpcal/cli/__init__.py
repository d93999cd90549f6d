"""The `nlpcal` command line: parse the arguments, call one library verb, print.

Exit status: 0 success, 1 a solve or quality check failed, 2 bad usage or input.
Data go to stdout or -o; human messages go to stderr.

Each subcommand module registers its arguments with plain argparse and imports the library only
when it runs, so `nlpcal --help` and `nlpcal --version` do not pay for numpy, pandas and CasADi.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading

from ..errors import InputError, QualityError, SolveError, WriteError
from ..version import __version__
from . import (
    apply,
    batch,
    calibrate,
    compare,
    compass,
    drift,
    export,
    imports,
    live,
    orthogonality,
    report,
    reproduce,
    simulate,
)
from . import platform as platform_command  # nlpcal platform fit|apply (Tolles-Lawson)
from .common import HelpFormatter, Parser, UsageError, add_verbosity, set_verbosity

#: Live calibration from a stream (`nlpcal.live`), listed after the commands on logs.
COMMANDS_LIVE = (live,)

#: The subcommand modules, in the order of the help (calibrate, apply and stats first).
COMMANDS: tuple = (
    calibrate,
    apply,
    batch,
    compare,
    orthogonality,
    drift,
    compass,
    export,
    imports,
    report,
    simulate,
    reproduce,
)
#: nlpcal platform fit|apply: Tolles-Lawson compensation of a scalar magnetometer for its platform.
COMMANDS += (platform_command,)

DESCRIPTION = """\
nlpcal calibrates three-axis magnetometers (fluxgates, MEMS compasses). From a log of readings
taken while the sensor is turned through many orientations in a steady field, it estimates the
offsets (hard iron), the scale error of each axis and the angles between the axes, so that the
corrected field has the same magnitude in every orientation. Logs are delimited text (comma,
semicolon, tab or whitespace, with or without a header row; '-' reads stdin), Parquet files,
or a quoted pattern or a folder of them.

start here:
  nlpcal calibrate LOG.csv -o params.json             estimate the calibration from a log
  nlpcal apply params.json LOG.csv -o corrected.csv   correct a log (any log of that sensor)
  nlpcal stats LOG.csv --params params.json           |B| before and after, as a table

  e.g. nlpcal calibrate mag.txt --unit raw   (counts, no header: the three columns are found)
       nlpcal calibrate log.csv --columns 4 5 6 --unit uT

Each command explains itself: nlpcal COMMAND --help.
"""

EPILOG = """\
exit status: 0 success; 1 the solve failed or the data cannot determine the calibration;
2 bad usage or input (one sentence on stderr). Data go to stdout or -o, messages to stderr.
"""


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="nlpcal", description=DESCRIPTION, epilog=EPILOG, formatter_class=HelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"nlpcal {__version__}")
    sub = parser.add_subparsers(
        dest="command", metavar="COMMAND", parser_class=Parser, title="commands"
    )
    sub.required = True
    for module in COMMANDS + COMMANDS_LIVE:
        module.register(sub)
    add_verbosity(parser)
    return parser


def _command_parser(parser: argparse.ArgumentParser, argv) -> argparse.ArgumentParser:
    """The parser of the innermost subcommand named in argv."""
    for token in sys.argv[1:] if argv is None else argv:
        choices = [a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if choices and str(token) in choices[0]:
            parser = choices[0][str(token)]
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that a write under way cleans up after itself."""


#: Set by SIGTERM: an interruption CasADi caught during a solve may reach main as a plain
#: KeyboardInterrupt (`nlpcal.nlp.solver`), and it is then this termination.
_TERMINATION = threading.Event()


def _terminate(signum, frame):
    _TERMINATION.set()
    raise Terminated


def _check_environment() -> None:
    """The environment variables nlpcal reads, checked before a command reads anything: a bad
    one is exit 2 for every command, not for the first pass over a log."""
    from ..compiled import choice

    choice()  # NLPCAL_KERNEL


def main(argv=None) -> int:
    """Run the command line; returns the exit status instead of exiting."""
    try:
        parser = build_parser()
        args, unknown = parser.parse_known_args(argv)
        if unknown:  # said by the (sub)command they were given to, which points to its help
            _command_parser(parser, argv).error(f"unrecognized arguments: {' '.join(unknown)}")
    except UsageError as exc:
        print(f"{exc}\n(see '{exc.prog} --help')", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help and --version
        return int(exc.code or 0)
    except BrokenPipeError:
        return _reader_gone()
    except KeyboardInterrupt:  # as the command line is read: no command has started
        print("nlpcal: interrupted", file=sys.stderr)
        return 130
    set_verbosity(args)
    _TERMINATION.clear()
    previous = signal.getsignal(signal.SIGTERM)
    in_main_thread = _set_signal(signal.SIGTERM, _terminate)
    try:
        _check_environment()
        return int(args.func(args) or 0)
    except InputError as exc:
        print(f"nlpcal {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except QualityError as exc:  # its reason: the Python keywords that override it do not apply
        print(f"nlpcal {args.command}: quality check failed: {exc.reason}", file=sys.stderr)
        return 1
    except SolveError as exc:
        status = f" (solver status: {exc.status})" if exc.status else ""
        print(f"nlpcal {args.command}: solve failed: {exc}{status}", file=sys.stderr)
        return 1
    except WriteError as exc:
        print(f"nlpcal {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `nlpcal simulate | head`: the reader has what it wanted
        return _reader_gone()
    except OSError as exc:  # a file that cannot be read, named by the system's reason
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"nlpcal {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        return _interrupted(args.command, exc)
    except (MemoryError, RecursionError) as exc:
        print(
            f"nlpcal {args.command}: error: the input is too large or too deeply nested to "
            f"process ({type(exc).__name__})",
            file=sys.stderr,
        )
        return 2
    except Exception as exc:  # a defect of nlpcal: one line, the traceback on request
        interruption = _interruption_within(exc)
        if interruption is not None:
            return _interrupted(args.command, interruption)
        if os.environ.get("NLPCAL_DEBUG"):
            raise
        print(
            f"nlpcal {args.command}: internal error: {type(exc).__name__}: {exc} (a defect of "
            f"nlpcal; please report it with the command; NLPCAL_DEBUG=1 shows the traceback)",
            file=sys.stderr,
        )
        return 1
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous)


#: The exit status a shell reports for a process killed by SIGPIPE: 128 + 13.
BROKEN_PIPE_STATUS = 141


def _reader_gone() -> int:
    """End quietly, as tools killed by SIGPIPE do, when the reader of stdout (or of a FIFO
    output) went away. Python ignores SIGPIPE, so the write raised instead; stdout is pointed
    at the null device so that the interpreter's last flush of it finds no broken pipe."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        with contextlib.suppress(OSError, ValueError):
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, sys.stdout.fileno())
            os.close(null)
    return BROKEN_PIPE_STATUS


def _interrupted(command: str, interruption: KeyboardInterrupt) -> int:
    """Say that a Ctrl-C ("interrupted", 130) or SIGTERM ("terminated", 143) ended `command`."""
    terminated = isinstance(interruption, Terminated) or _TERMINATION.is_set()
    print(f"nlpcal {command}: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
    return 143 if terminated else 130


def _interruption_within(error: BaseException | None) -> KeyboardInterrupt | None:
    """The interruption behind `error`, if one is: CasADi's Python code run from its C++
    (numpy reading a result, `DM.__array__`) hands a Ctrl-C raised there back wrapped, as a
    SystemError whose cause it is."""
    seen: set = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def _set_signal(number, handler) -> bool:
    """Install a handler where Python allows it (the main thread); False elsewhere."""
    try:
        signal.signal(number, handler)
    except ValueError:
        return False
    return True
