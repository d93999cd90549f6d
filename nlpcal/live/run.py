"""The loop of a live calibration: read lines, add their samples, update, stop.

    head = read_head(source)                       # the first lines choose the parser
    parser = detect_parser(head, ...)
    stream = Stream(parser, unit check on the head)  # lines -> samples in the base unit
    stop = run(session, source, stream, emit=..., head=head)

`run` returns why it stopped: "determined" (every parameter of the model below its target and
the coverage complete), "end" (the input ended), "time" (`max_seconds`) or "interrupted"
(Ctrl-C). The recording (`Recorder`) holds every line a sample came from, so that `nlpcal
calibrate` reads it as this loop did.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from .. import units
from ..io.files import plain
from ..io.logs import settle_unit
from .parsers import HEAD_LINES, Parser
from .session import LiveSession, Update

#: Longest wait for lines before the loop looks at the clock again. [s]
POLL_S = 0.05
STOPS = ("determined", "end", "time", "interrupted")


class Recorder:
    """The raw lines of a stream, written to a temporary file beside `path` and put in place
    by `commit` (an interrupted or failed run leaves `path` as it was and no temporary file)."""

    def __init__(self, path):
        self.path = Path(path)
        directory = self.path.parent
        fd, name = tempfile.mkstemp(dir=directory, prefix=f".{self.path.name}.", suffix=".part")
        self._temporary = Path(name)
        self._file = os.fdopen(fd, "w", encoding="utf-8", newline="\n")

    def write(self, lines) -> None:
        for line in lines:
            self._file.write(line + "\n")

    def commit(self) -> None:
        self._file.close()
        os.chmod(self._temporary, 0o666 & ~_umask())
        os.replace(self._temporary, self.path)

    def discard(self) -> None:
        with contextlib.suppress(OSError):
            self._file.close()
        with contextlib.suppress(OSError):
            self._temporary.unlink()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@dataclass
class Stream:
    """Lines to samples in the base unit. factor : the size of one value in the base unit."""

    parser: Parser
    unit: str  # the base unit, nT or raw
    factor: float
    warnings: list = field(default_factory=list)
    skipped: int = 0

    def samples(self, lines) -> tuple:
        """((k, 3) samples [base unit], the lines to record)."""
        rows, kept, skipped = self.parser.parse(lines)
        self.skipped += skipped
        return rows * self.factor, kept


def open_stream(parser: Parser, head: list) -> Stream:
    """The stream of a parser, its unit checked on the head's samples as `calibrate` checks a
    log's (`nlpcal.io.logs.settle_unit`: an assumed nT that does not fit is taken as raw)."""
    rows, _, _ = parser.parse(head)
    unit, warnings = parser.unit, []
    factor = units.field_factor(unit)
    if len(rows):
        _, unit, warning = settle_unit(rows * factor, unit, parser.unit_source)
        warnings = [warning] if warning else []
        factor = units.field_factor(unit)
    return Stream(parser, units.base_unit(unit), factor, warnings)


def read_head(source, deadline: float | None = None) -> list:
    """The first HEAD_LINES lines that are not empty (fewer when the stream ends or the
    deadline, a `time.monotonic` value, passes)."""
    head: list = []
    while len([line for line in head if line.strip()]) < HEAD_LINES:
        if deadline is not None and time.monotonic() >= deadline:
            break
        lines = source.read(POLL_S)
        if lines is None:
            break
        head.extend(lines)
    return head


def run(
    session: LiveSession,
    source,
    stream: Stream,
    *,
    emit: Callable[[Update], None],
    head: list = (),  # type: ignore[assignment]
    recorder: Recorder | None = None,
    deadline: float | None = None,
) -> str:
    """Feed the stream to the session until it stops; `emit` gets every update. Returns the
    reason it stopped (STOPS): Ctrl-C (a plain KeyboardInterrupt) is the user's stop; a
    subclass of it (the command line's SIGTERM) propagates. deadline : a `time.monotonic`
    value (--max-seconds)."""
    pending = list(head)
    try:
        while True:
            rows, kept = stream.samples(pending)
            if recorder is not None:
                recorder.write(kept)
            if len(rows):
                session.add(rows)
            if session.due():
                update = session.update()
                emit(update)
                if update.determined:
                    return "determined"
            if deadline is not None and time.monotonic() >= deadline:
                return "time"
            pending = source.read(POLL_S)
            if pending is None:
                return _last(session, emit)
    except KeyboardInterrupt as interruption:
        if type(interruption) is not KeyboardInterrupt:  # SIGTERM as the command line raises it:
            raise  # the run was killed, not stopped, and writes nothing
        return "interrupted"


def _last(session: LiveSession, emit) -> str:
    """At the end of the input: an update of the samples the last one missed."""
    if session.stream.frame is not None and (
        session.latest is None or session.latest.n_samples < session.n
    ):
        update = session.update()
        emit(update)
        if update.determined:
            return "determined"
    return "end"


def json_line(document) -> str:
    """A document as one line of strict JSON (no NaN, no Infinity), without the newline."""
    return json.dumps(plain(document), allow_nan=False)


def update_line(update: Update) -> str:
    """The JSON line of an update."""
    return json_line(update.to_dict())


__all__ = ["Recorder", "Stream", "json_line", "open_stream", "read_head", "run", "update_line"]
