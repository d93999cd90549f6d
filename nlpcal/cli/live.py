"""`nlpcal live`: calibrate while the data arrive, and stop when they determine the parameters.

nlpcal live [-|--serial PORT --baud B|--udp HOST:PORT] [--columns X Y Z] [--unit U]
            [--regex PATTERN] [--model M] [--reference-field F] [--target-se KIND=VALUE]
            [--coverage FRACTION] [--forgetting LAMBDA] [--max-seconds S] [--record FILE]
            [--web] [--web-port PORT] [--export-format FMT --export FILE] -o params.json
"""

from __future__ import annotations

from .common import FIELD_UNITS, add_command, say, tell_written, warn, warning

FORMATS = ("matlab", "matrix", "ardupilot", "px4", "c-header")  # nlpcal.formats.FORMATS
#: --target-se kinds and their defaults: offsets as a percentage of the field, scale errors,
#: angles in degrees (`nlpcal.live.session.Targets`).
TARGET_KINDS = {"offset": "0.1%", "scale": "0.001", "angle": "0.05"}


def register(sub):
    parser = add_command(
        sub,
        "live",
        help="calibrate from a live stream (stdin, serial, UDP); stop when determined",
        description="""\
Read magnetometer samples as they arrive (stdin with '-', a serial port, or UDP datagrams),
re-solve the calibration about every 0.5 s and print one JSON line per update on stdout:
"n_samples", "parameters", "standard_errors", "coverage" (80 equal-area cells of field
directions), "verdict", the Table 1 row ("table1"), "poorly_determined" (the parameters above
their target), and "determined": true on the line that stops it. It stops when every parameter
of --model has a standard error below its --target-se and --coverage of the cells are covered
(or on Ctrl-C, the end of the input, or --max-seconds), then writes -o params.json (and
--export) atomically: the result 'nlpcal calibrate' gives for the same samples. Lines are
MotionCal 'Raw:' lines, delimited text (detected as 'nlpcal calibrate' detects a log), or
whatever --regex captures. On a terminal, stderr shows the coverage grid, where to turn next
and the fit.""",
        examples=(
            "nlpcal live --serial /dev/ttyACM0 --baud 115200 -o params.json   # MotionCal sketch",
            "nlpcal live --udp 0.0.0.0:5005 --unit uT --web -o params.json",
            "logger | nlpcal live - --record session.csv -o params.json",
            "nlpcal live - --target-se offset=0.5% scale=0.005 angle=0.5 -o params.json",
        ),
    )
    parser.add_argument(
        "source", nargs="?", metavar="-", choices=["-"], help="read stdin (the default)"
    )
    parser.add_argument("--serial", metavar="PORT", help="read a serial port (needs pyserial)")
    parser.add_argument(
        "--baud", type=int, default=115200, metavar="B", help="the port's bit/s (115200)"
    )
    parser.add_argument("--udp", metavar="HOST:PORT", help="listen for UDP datagrams of lines")
    parser.add_argument(
        "--columns", nargs=3, metavar=("X", "Y", "Z"), help="field columns (names or positions)"
    )
    parser.add_argument("--unit", choices=FIELD_UNITS, help="unit of the field values")
    parser.add_argument(
        "--regex",
        metavar="PATTERN",
        help="take x, y, z from each line by this pattern: named groups x, y, z or the first "
        "three groups",
    )
    parser.add_argument(
        "--model",
        choices=("full", "diagonal", "offset"),
        default="full",
        help="the form of Eq. 4 to determine, as in calibrate (default full)",
    )
    parser.add_argument(
        "--reference-field", type=float, metavar="F", help="known |B|, in the unit of the values"
    )
    parser.add_argument(
        "--target-se",
        nargs="+",
        metavar="KIND=VALUE",
        help="standard errors that count as determined: offset=0.1%% (of the field), "
        "scale=0.001, angle=0.05 (deg); the defaults",
    )
    parser.add_argument(
        "--coverage",
        type=float,
        default=0.9,
        metavar="FRACTION",
        help="fraction of the 80 equal-area cells the field must visit (default 0.9)",
    )
    parser.add_argument(
        "--forgetting",
        type=float,
        default=1.0,
        metavar="LAMBDA",
        help="weight of each sample relative to the next (e.g. 0.999 for a drifting sensor; "
        "default 1: all samples alike)",
    )
    parser.add_argument("--max-seconds", type=float, metavar="S", help="stop after S seconds [s]")
    parser.add_argument(
        "--record", metavar="FILE", help="save the stream's lines here (for nlpcal calibrate)"
    )
    parser.add_argument(
        "--web", action="store_true", help="serve a live view on http://127.0.0.1:PORT/"
    )
    parser.add_argument(
        "--web-port", type=int, default=8765, metavar="PORT", help="port of --web (8765; 0: any)"
    )
    parser.add_argument("--export-format", choices=FORMATS, metavar="FMT", help="also export")
    parser.add_argument("--export", metavar="FILE", help="write the --export-format file here")
    parser.add_argument(
        "-o",
        "--output",
        metavar="PARAMS.json",
        help="write the parameters here (default: one more line on stdout, after the updates)",
    )
    parser.set_defaults(func=run)


def run(args) -> int:
    import time

    from ..errors import InputError
    from ..io import Outputs, check_output_path
    from ..live import LiveSession, open_source, open_stream, read_head, run, targets_from
    from ..live.parsers import detect_parser
    from ..live.run import json_line
    from ..results import Provenance

    sources = [s for s in (args.source, args.serial, args.udp) if s]
    if len(sources) > 1:
        raise InputError("give one source: '-' (stdin), --serial PORT or --udp HOST:PORT")
    if bool(args.export_format) != bool(args.export):
        raise InputError("--export-format FMT and --export FILE go together")
    check_output_path(args.output)
    check_output_path(args.export)
    targets = targets_from(args.target_se or [])
    source = open_source(args.serial, args.baud, args.udp)
    started = time.monotonic()
    deadline = None if args.max_seconds is None else started + args.max_seconds
    web = None
    if args.udp or args.serial:
        warn(f"reading {source.name}")
    try:
        if args.web:
            from ..live.web import WebView

            web = WebView(args.web_port)
            warn(f"live view on {web.url}")
        head = read_head(source, deadline)
        parser = detect_parser(head, columns=args.columns, regex=args.regex, unit=args.unit)
        stream = open_stream(parser, head)
        for note in parser.notes:
            warn(f"{source.name}: {note}")
        for message in stream.warnings:
            warning(message)
        reference = args.reference_field
        session = LiveSession(
            stream.unit,
            reference=None if reference is None else reference * stream.factor,
            model=args.model,
            targets=targets,
            forgetting=args.forgetting,
            coverage_target=args.coverage,
        )
        recorder = _recorder(args.record, parser)
        try:
            stop = run(
                session,
                source,
                stream,
                emit=_emitter(session, web),
                head=head,
                recorder=recorder,
                deadline=deadline,
            )
        except BaseException:
            if recorder is not None:
                recorder.discard()
            raise
    except BaseException:
        if web is not None:
            web.close()
        raise
    finally:
        source.close()
    _said_stop(session, stop)
    try:
        result = session.final()
    except BaseException:
        if recorder is not None:
            recorder.discard()
        raise
    finally:
        if web is not None:
            web.close()
    result.input = Provenance(
        log_unit=result.unit, extra={"source": source.name, "format": parser.kind}
    )
    with Outputs() as outputs:
        if args.output:
            outputs.json(args.output, result.to_dict())
        else:  # after the update lines, the parameters document as one line of its own
            outputs.text(None, json_line(result.to_dict()) + "\n")
        if args.export:
            from ..formats import export

            outputs.text(args.export, export(result, args.export_format).text)
    if recorder is not None:
        recorder.commit()
    tell_written(args.output, args.export, args.record)
    return 0


def _recorder(path, parser):
    from ..live import Recorder

    if path is None:
        return None
    recorder = Recorder(path)
    if parser.header:
        recorder.write([parser.header])
    return recorder


def _emitter(session, web):
    """The callback of every update: its JSON line on stdout, the terminal view, the web."""
    import sys

    from ..live import render, update_line
    from . import common

    view = sys.stderr.isatty() and common.VERBOSITY >= 0

    def emit(update):
        sys.stdout.write(update_line(update) + "\n")
        sys.stdout.flush()
        if view:
            sys.stderr.write("\033[H\033[J" + render(update) + "\n")
            sys.stderr.flush()
        if web is not None:
            web.publish(update, session.cloud())

    return emit


def _said_stop(session, stop: str) -> None:
    if stop == "determined":
        warn(f"all parameters determined at sample {session.determined_at}")
        return
    why = {
        "end": "the input ended",
        "time": "--max-seconds passed",
        "interrupted": "interrupted",
    }[stop]
    latest = session.latest
    missing = []
    if latest is not None:
        missing = list(latest.poorly_determined)
        if not latest.coverage.complete:
            missing.append(f"coverage {100 * latest.coverage.fraction:.0f} %")
    say(
        f"nlpcal: {why} after {session.n} samples before every parameter was determined"
        + (f" ({', '.join(missing)} short of the targets)" if missing else "")
        + "; the parameters are calibrate's of the samples so far"
    )
