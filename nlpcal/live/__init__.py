"""Live calibration: samples from a stream, updates as they arrive, a stop when determined.

`nlpcal live` reads lines from stdin, a serial port or UDP (`sources`), parses them
(`parsers`), adds their samples to moments that grow with the stream (`accumulator`), re-solves
them as `calibrate` does about every half second (`solve`, `session`) and judges each solve by
the standard errors and the coverage of an equal-area grid of field directions (`grid`). Views:
a terminal frame (`terminal`) and a local web page (`web`).
"""

from __future__ import annotations

from ..errors import InputError
from .accumulator import StreamMoments
from .grid import Coverage, coverage
from .run import Recorder, Stream, open_stream, read_head, run, update_line
from .session import LiveSession, Targets, Update
from .sources import LineSource, SerialSource, StdinSource, UdpSource
from .terminal import render


def open_source(serial: str | None, baud: int, udp: str | None) -> LineSource:
    """The source named by the options: a serial port, a UDP address, else stdin."""
    if serial:
        return SerialSource(serial, baud)
    if udp:
        return UdpSource(udp)
    return StdinSource()


def targets_from(items) -> Targets:
    """`Targets` from KIND=VALUE items (offset=0.1%, scale=0.001, angle=0.05 [deg])."""
    values: dict = {}
    for item in items:
        kind, sep, text = str(item).partition("=")
        if not sep or kind not in ("offset", "scale", "angle"):
            raise InputError(f"--target-se takes offset=P%, scale=S and angle=DEG; got {item!r}")
        percent = kind == "offset"
        if percent and not text.endswith("%"):
            raise InputError(
                f"--target-se offset is a percentage of the field, e.g. offset=0.1%; got {item!r}"
            )
        try:
            value = float(text.rstrip("%")) / (100.0 if percent else 1.0)
        except ValueError:
            raise InputError(f"--target-se {kind}: expected a number, got {text!r}") from None
        if not value > 0 or value == float("inf"):
            raise InputError(f"--target-se {kind} must be positive and finite; got {text!r}")
        values[{"offset": "offset_fraction", "scale": "scale", "angle": "angle_deg"}[kind]] = value
    return Targets(**values)


__all__ = [
    "Coverage",
    "LiveSession",
    "Recorder",
    "Stream",
    "StreamMoments",
    "Targets",
    "Update",
    "coverage",
    "open_source",
    "open_stream",
    "read_head",
    "render",
    "run",
    "targets_from",
    "update_line",
]
