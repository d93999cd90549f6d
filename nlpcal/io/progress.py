"""Progress of a long pass over a log, on a terminal: what is done, its rate and the time left.

A `Progress` is told how far a pass has got (bytes of a file read, rows of a Parquet file) and
rewrites one line of its stream, at most every `INTERVAL` seconds:

    nlpcal: applying big.csv: 41% (154 of 375 MB), 38.2 MB/s, 6 s left

It writes nothing at all when its stream is not a terminal (a log file, a pipe, a test's
captured stderr) or when it is switched off (`enabled=False`: the command line's -q), so that
output meant for files never holds carriage returns. The library's passes take any object with
`update(done)` (or None); the command line makes the one it shows.
"""

from __future__ import annotations

import sys
import time

#: Least time between two rewrites of the line. [s]
INTERVAL = 0.25
#: Passes shorter than this are not shown at all (the line would only flicker). [s]
QUIET_START = 0.5
#: The units a pass may count in: name -> (divisor, label).
UNITS = {"bytes": (1e6, "MB"), "rows": (1.0, "rows")}


def _duration(seconds: float) -> str:
    """A time left, rounded for reading: "7 s", "3 min 05 s", "1 h 02 min"."""
    seconds = max(0, int(round(seconds)))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


class Progress:
    """One progress line for a pass over `total` units (None when unknown: stdin).

    label : what is being done, "applying big.csv".
    unit : "bytes" or "rows" (`UNITS`).
    stream : where the line goes (default sys.stderr).
    enabled : False shows nothing; None (default) shows the line when `stream` is a terminal.
    clock : a function returning seconds (time.monotonic; the tests give their own).
    """

    def __init__(
        self,
        label: str,
        total: float | None = None,
        unit: str = "bytes",
        *,
        stream=None,
        enabled: bool | None = None,
        clock=time.monotonic,
    ):
        self.label, self.total, self.unit = label, total, unit
        self.stream = sys.stderr if stream is None else stream
        if enabled is None:
            isatty = getattr(self.stream, "isatty", None)
            enabled = bool(isatty and isatty())
        self.enabled = enabled
        self.clock = clock
        self.started = clock()
        self.shown_at: float | None = None
        self.done = 0.0

    def update(self, done: float, total: float | None = None) -> None:
        """The pass has got to `done` units (of `total`, when it is known only now)."""
        self.done = float(done)
        if total is not None:
            self.total = float(total)
        if not self.enabled:
            return
        now = self.clock()
        if now - self.started < QUIET_START:
            return
        if self.shown_at is not None and now - self.shown_at < INTERVAL:
            return
        self.shown_at = now
        self.stream.write(f"\r\033[K{self.line(now)}")
        self.stream.flush()

    def line(self, now: float) -> str:
        """The text of the line at time `now`: share done, amount, rate and time left."""
        divisor, label = UNITS[self.unit]
        rate = self.done / max(now - self.started, 1e-9)
        done = f"{self.done / divisor:,.0f}"
        if self.total:
            share = min(self.done / self.total, 1.0)
            amount = f"{share:.0%} ({done} of {self.total / divisor:,.0f} {label})"
        else:
            amount = f"{done} {label}"
        parts = [f"nlpcal: {self.label}: {amount}", f"{rate / divisor:,.1f} {label}/s"]
        if self.total and rate > 0:
            parts.append(f"{_duration(max(self.total - self.done, 0.0) / rate)} left")
        return ", ".join(parts)

    def close(self) -> None:
        """Clear the line, if one was shown (the messages after it start on a clean line)."""
        if self.enabled and self.shown_at is not None:
            self.stream.write("\r\033[K")
            self.stream.flush()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
