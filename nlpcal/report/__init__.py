"""Looking at a calibration: the figure of a log before and after its correction, and a
self-contained HTML report (`nlpcal report`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..calibration.result import CalibrationResult
from ..errors import InputError
from ..io.files import sha256_file
from ..io.layout import STDIN
from ..io.logs import Log
from ..io.observatory import terms_of_use
from ..models.zhou2010 import correct
from ..plots import calibration_png, require_matplotlib
from ..version import __version__
from .html import render_report
from .view import CalibrationView


def _calibration(parameters) -> CalibrationResult | None:
    """The nine-parameter calibration of a parameters document (of a temperature one too)."""
    if isinstance(parameters, CalibrationResult):
        return parameters
    return getattr(parameters, "calibration", None)


def _same_log(calibration: CalibrationResult | None, log: Log) -> bool:
    """Whether the calibration was estimated from this log (so that its cycles describe it)."""
    recorded = calibration.input.log if calibration is not None else None
    return bool(recorded) and Path(str(recorded)).resolve() == Path(log.path).resolve()


def figure_png(log: Log, parameters, corrected=None, *, title: str = "", dpi: int = 150) -> bytes:
    """The calibration figure (`nlpcal.plots.calibration_png`) of a log and its correction.

    parameters : a CalibrationResult (or a temperature calibration); corrected : the corrected
    samples [base unit] (default: Eq. 4 with the parameters, after the stray field of their aux
    channels, read from the log under their names).
    """
    calibration = _calibration(parameters)
    if corrected is None:
        raw = log.samples
        channels = getattr(calibration, "aux", None)
        if channels:
            raw = raw - calibration.stray_field({c.name: log.values(c.name) for c in channels})  # type: ignore[union-attr]
        corrected = correct(raw, calibration.model)  # type: ignore[union-attr]
    view = CalibrationView.build(log, corrected, calibration, title)
    if not _same_log(calibration, log):
        view.cycles = []  # the cycles of another log's calibration do not describe this one
    return calibration_png(view, dpi=dpi)


@dataclass
class Report:
    """An HTML report and what the user should know about it."""

    html: str
    notes: list = field(default_factory=list)


def report(
    parameters,
    log: Log,
    corrected,
    *,
    parameters_path=None,
    options: dict | None = None,
    dpi: int = 150,
) -> Report:
    """The HTML report of a calibration on a log: figure, parameters with standard errors and
    correlations, Table 1 rows, identifiability, warnings and provenance (input files with their
    SHA-256, options).

    corrected : the log's corrected samples [base unit]. Without matplotlib the report is written
    without its figure, and a note says so.
    """
    calibration = _calibration(parameters)
    if calibration is None:
        raise InputError("the report needs a parameters file of the nine-parameter calibration")
    title = f"{log.path} corrected with {parameters_path or 'the calibration'}"
    view = CalibrationView.build(log, corrected, calibration, title)
    notes, png, missing = [], None, ""
    try:
        require_matplotlib()
        png = calibration_png(view, dpi=dpi)
    except InputError as exc:
        missing = str(exc)
        notes.append(f"the report has no figure: {missing}")
    terms = terms_of_use(log.observatory) or terms_of_use(calibration)
    provenance = {
        **({"acknowledgement": terms} if terms else {}),
        "nlpcal_version": __version__,
        "parameters": {
            "file": None if parameters_path is None else str(parameters_path),
            "sha256": None if parameters_path is None else sha256_file(parameters_path),
            "written_by_nlpcal": calibration.version,
            "calibration_input": calibration.input,
        },
        "log": {"file": log.path, **_digest(log.path), **log.metadata(rows=log.n)},
        "options": options or {},
    }
    return Report(render_report(calibration, view, provenance, png, missing), notes)


def _digest(path) -> dict:
    """{"sha256": the digest of the log's file}; nothing for a log read from stdin, whose bytes
    are gone."""
    return {} if str(path) == STDIN else {"sha256": sha256_file(path)}


__all__ = ["CalibrationView", "Report", "figure_png", "render_report", "report"]
