"""`nlpcal batch calibrate` and `nlpcal batch apply`: many logs, one output file per log and a
summary table.

    nlpcal batch calibrate 'fleet/*.csv' --out-dir DIR [--scheduler ...] [--force]
                           [the options of nlpcal calibrate]
    nlpcal batch apply PARAMS 'fleet/*.csv' --out-dir DIR [--scheduler ...] [--force]
                           [--flag-outliers] [--drift DRIFT.json] [--temperature-column COL]

`batch calibrate` takes the options of `nlpcal calibrate` from its own parser (less the ones about
one output: the log, -o, --plot, and the temperature calibration), so the two stay alike.
"""

from __future__ import annotations

import argparse
import time

from . import calibrate as calibrate_cli
from .common import (
    CALIBRATED_LOG_UNIT,
    Parser,
    add_command,
    add_log_arguments,
    add_scheduler_arguments,
    log_options,
    progress,
    warn,
    warning,
)

#: Options of `nlpcal calibrate` that concern one log's output, not taken by `batch calibrate`.
SINGLE_LOG_OPTIONS = (
    "log",
    "output",
    "plot",
    "temperature_column",
    "temperature_model",
    "base_temperature",
)
#: Failed logs named on stderr at the end (the summary has them all).
FAILURES_SHOWN = 10


def register(sub):
    parser = sub.add_parser(
        "batch",
        help="calibrate or correct many logs: one output per log and a summary table",
        description="Calibrate or correct many logs (a glob pattern, a folder or a list of "
        "files), on Dask with --scheduler. One output file per log in --out-dir, and "
        "DIR/summary.csv with one row per log and its status; one bad log never stops the "
        "others, and a log whose output is newer than the log and was written with the same "
        "options is skipped unless --force.",
    )
    actions = parser.add_subparsers(dest="batch_command", metavar="ACTION", parser_class=Parser)
    actions.required = True
    _register_calibrate(actions)
    _register_apply(actions)


class _Collector:
    """Stands in for the subcommands of the top parser, to keep the parser that
    `nlpcal calibrate` registers."""

    parser: argparse.ArgumentParser

    def add_parser(self, name, **options):
        options.pop("help", None)
        self.parser = Parser(prog=f"nlpcal {name}", add_help=False, **options)
        return self.parser


def calibrate_options() -> argparse.ArgumentParser:
    """The parser of `nlpcal calibrate` without SINGLE_LOG_OPTIONS, as a parent parser."""
    collector = _Collector()
    calibrate_cli._register_calibrate(collector)
    parser = collector.parser
    for action in [a for a in parser._actions if a.dest in SINGLE_LOG_OPTIONS]:
        parser._remove_action(action)
        for group in [*parser._action_groups, *parser._mutually_exclusive_groups]:
            if action in group._group_actions:
                group._group_actions.remove(action)
        for option in action.option_strings:
            parser._option_string_actions.pop(option, None)
    return parser


def _add_batch_arguments(parser) -> None:
    parser.add_argument(
        "logs",
        nargs="+",
        metavar="LOGS",
        help="the logs: a quoted glob pattern ('fleet/*.csv', 'fleet/**/*.parquet'), a folder, "
        "or files",
    )
    parser.add_argument(
        "--out-dir",
        required=True,
        metavar="DIR",
        help="folder of the outputs (made if missing) and of summary.csv",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="redo logs whose output is up to date (newer than the log, written with the same "
        "options; skipped by default)",
    )


def _register_calibrate(actions):
    parser = add_command(
        actions,
        "calibrate",
        parents=[calibrate_options()],
        help="calibrate every log: DIR/<log>.params.json and DIR/summary.csv",
        description="""Calibrate every log as 'nlpcal calibrate' does, with its options.
Writes DIR/<log name>.params.json for each log that passes, and DIR/summary.csv with one row per
log: log, status (ok, quality-failed, bad-input, solve-failed, error), verdict (of the result:
ok, warnings or poorly_determined when the status is ok, else failed), exit_status (that of
'nlpcal calibrate' on the log), model (the --model that ran; with auto, the one chosen), the nine
parameters each with its standard error (_se; both empty where the model fixes a parameter),
std_measured and std_corrected of |B|, coverage_fraction, warnings, message, unit, n_samples,
output, action (run, or skipped as up to date), seconds.
Exit status: the largest of the logs'.""",
        examples=(
            "nlpcal batch calibrate 'fleet/*.csv' --out-dir cal",
            "nlpcal batch calibrate fleet/ --out-dir cal --scheduler local --force",
            "nlpcal batch calibrate 'fleet/*.csv' --out-dir cal --scheduler tcp://head:8786",
        ),
    )
    _add_batch_arguments(parser)
    parser.set_defaults(func=run_batch_calibrate)


def _register_apply(actions):
    parser = add_command(
        actions,
        "apply",
        help="correct every log: DIR/<log>.corrected.csv and DIR/summary.csv",
        description="""Correct every log as 'nlpcal apply' does.
PARAMS is one parameters file for every log, or the --out-dir of 'nlpcal batch calibrate'
(DIR/<log name>.params.json for each log). Writes DIR/<log name>.corrected.csv (.parquet for a
Parquet log) and DIR/summary.csv: log, status, exit_status, params, output, n_samples,
std_measured, std_corrected, outliers, warnings, message, unit, action, seconds.""",
        examples=(
            "nlpcal batch apply cal 'fleet/*.csv' --out-dir corrected    # each log's own params",
            "nlpcal batch apply params.json 'fleet/*.csv' --out-dir corrected",
        ),
    )
    parser.add_argument("params", metavar="PARAMS", help="a parameters file, or a folder of them")
    _add_batch_arguments(parser)
    add_log_arguments(parser, CALIBRATED_LOG_UNIT)
    parser.add_argument(
        "--flag-outliers",
        action="store_true",
        help="add a boolean column 'outlier', as 'nlpcal apply --flag-outliers' does",
    )
    parser.add_argument(
        "--drift", metavar="DRIFT.json", help="divide the raw vector by k(t) first (Eq. 9)"
    )
    parser.add_argument("--temperature-column", metavar="COL", help="column of temperatures [degC]")
    add_scheduler_arguments(parser)
    parser.set_defaults(func=run_batch_apply)


def _progress(verb: str):
    """A progress line on stderr (when it is a terminal) as each log finishes."""
    started = time.perf_counter()
    failed = [0]

    def report(done: int, total: int, row: dict) -> None:
        failed[0] += row["status"] != "ok"
        elapsed = time.perf_counter() - started
        left = elapsed / done * (total - done) if done else 0.0
        progress(
            f"{verb} {done}/{total} logs, {failed[0]} failed, {elapsed:.0f} s, ~{left:.0f} s left"
        )

    return report


def _finish(report, verb: str, started: float) -> int:
    """Say what the batch did on stderr; the exit status."""
    progress("")
    for note in report.notes:
        warning(note)
    counts = report.counts()
    done = sum(counts.values())
    skipped = sum(row.get("action") == "skipped" for row in report.rows)
    failures = [row for row in report.rows if row["status"] != "ok"]
    detail = ", ".join(f"{status} {n}" for status, n in sorted(counts.items()))
    warn(
        f"{verb} {done} logs in {time.perf_counter() - started:.1f} s ({detail}; {skipped} "
        f"skipped as up to date); summary: {report.summary}"
    )
    for row in failures[:FAILURES_SHOWN]:
        warn(f"{row['log']}: {row['status']}: {row['message']}")
    if len(failures) > FAILURES_SHOWN:
        warn(f"... and {len(failures) - FAILURES_SHOWN} more failed logs in {report.summary}")
    return report.exit_status


def run_batch_calibrate(args) -> int:
    from ..batch import calibrate_many

    calibrate_cli.warn_ignored(args, joint=args.method == "joint")
    started = time.perf_counter()
    report = calibrate_many(
        _sources(args.logs),
        args.out_dir,
        read_options={**log_options(args), "low_memory": args.low_memory},
        options=calibrate_cli.calibration_options(args),
        force=args.force,
        scheduler=args.scheduler,
        workers=args.workers,
        progress=_progress("calibrated"),
    )
    return _finish(report, "calibrated", started)


def run_batch_apply(args) -> int:
    from ..batch import apply_many

    started = time.perf_counter()
    report = apply_many(
        args.params,
        _sources(args.logs),
        args.out_dir,
        read_options=log_options(args),
        flag_outliers=args.flag_outliers,
        drift=args.drift,
        temperature_column=args.temperature_column,
        force=args.force,
        scheduler=args.scheduler,
        workers=args.workers,
        progress=_progress("corrected"),
    )
    return _finish(report, "corrected", started)


def _sources(logs):
    """One pattern or folder as it is; several arguments (a shell's expansion) as a list of
    files, each pattern or folder among them expanded."""
    from ..io.sources import log_paths

    if len(logs) == 1:
        return logs[0]
    notes: list = []
    paths = [path for log in logs for path in log_paths(log, notes)]
    for note in notes:
        warn(note)
    return paths
