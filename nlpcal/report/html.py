"""A calibration report as one self-contained HTML file: figures embedded as base64 PNG, styles
inline, no script and nothing fetched from the network, so it opens from disk in any browser.

What matters comes first: the verdict (`nlpcal.verdict`) as a banner, the warnings and notes, the
nine parameters rounded by their standard errors with the poorly determined ones marked; then the
figure of the log before and after, the Table 1 rows of the log, the correlations, the Table 1
rows of the calibration (folded after TABLE_ROWS rows), the reference field, identifiability and
provenance (nlpcal version, input files and their SHA-256, options), all as tables.
"""

from __future__ import annotations

import base64
import datetime
import html

import numpy as np

from ..calibration.result import CalibrationResult
from ..inference import rounded
from ..models.zhou2010 import PARAMETER_NAMES, PARAMETER_UNITS
from ..statistics import STAT_KEYS
from ..version import __version__
from .view import CalibrationView

SYMBOLS = {
    "z_x": "z<sub>x</sub>",
    "z_y": "z<sub>y</sub>",
    "z_z": "z<sub>z</sub>",
    "s_x": "s<sub>x</sub>",
    "s_y": "s<sub>y</sub>",
    "s_z": "s<sub>z</sub>",
    "alpha_deg": "&alpha;",
    "beta_deg": "&beta;",
    "gamma_deg": "&gamma;",
}
MEANINGS = {
    "z": "zero offset Z<sub>p</sub>",
    "s": "scale error, gain 1 + s",
    "alpha_deg": "x axis out of the plane x<sub>1</sub>o y<sub>1</sub>",
    "beta_deg": "y axis from oy<sub>1</sub>",
    "gamma_deg": "x projection from ox<sub>1</sub>",
}
STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 1em auto;
       max-width: 1200px; color: #1a1a1a; line-height: 1.35; padding: 0 1em; }
h1 { font-size: 1.5em; margin: 0.2em 0; } h2 { font-size: 1.2em; margin: 1em 0 0.4em;
  border-bottom: 1px solid #ccc; padding-bottom: 0.15em; }
table { border-collapse: collapse; margin: 0.4em 0; font-size: 0.9em; }
th, td { border: 1px solid #d0d0d0; padding: 0.15em 0.6em; text-align: right; }
th { background: #f2f2f2; } td.text, th.text { text-align: left; }
.num { font-variant-numeric: tabular-nums; font-family: ui-monospace, Menlo, Consolas, monospace; }
.warn { background: #fff4e0; border-left: 4px solid #e69500; padding: 0.3em 0.8em;
        margin: 0.3em 0; font-size: 0.92em; }
.ok { color: #1d7a2e; } .bad { color: #b00020; font-weight: bold; }
img { max-width: 100%; height: auto; border: 1px solid #ddd; }
code, pre { font-family: ui-monospace, Menlo, Consolas, monospace; font-size: 0.9em; }
pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto; }
.small { color: #555; font-size: 0.85em; }
.verdict { padding: 0.5em 1em; margin: 0.5em 0 0.8em; border-radius: 4px; font-size: 1.05em; }
.verdict strong { font-size: 1.2em; }
.verdict ul { margin: 0.3em 0 0; }
.verdict-ok { background: #e6f4ea; border-left: 6px solid #1d7a2e; }
.verdict-warnings { background: #fff4e0; border-left: 6px solid #e69500; }
.verdict-poorly_determined { background: #fde8e8; border-left: 6px solid #c0392b; }
.verdict-failed { background: #b00020; color: white; border-left: 6px solid #600010; }
tr.poor td { background: #fde8e8; } tr.undetermined td { background: #f8c8c8; }
details summary { cursor: pointer; color: #0b57d0; margin: 0.3em 0; }
"""
#: Table 1 rows of the calibration shown before the rest are folded away.
TABLE_ROWS = 10


def _e(value) -> str:
    return html.escape(str(value))


def _number(value, digits: int = 8) -> str:
    if value is None:
        return "&ndash;"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    return f"{float(value):.{digits}g}"


def _table(header, rows, text_columns=(0,), classes=None) -> str:
    """An HTML table; `classes` gives each row's CSS class ("" for none)."""
    head = "".join(
        f'<th class="{"text" if k in text_columns else ""}">{h}</th>' for k, h in enumerate(header)
    )
    classes = classes or [""] * len(rows)
    body = "".join(
        (f'<tr class="{css}">' if css else "<tr>")
        + "".join(
            f'<td class="{"text" if k in text_columns else "num"}">{cell}</td>'
            for k, cell in enumerate(row)
        )
        + "</tr>"
        for css, row in zip(classes, rows)
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _verdict(result: CalibrationResult) -> str:
    """The banner: the status and the failed checks and poorly determined parameters in full."""
    verdict = result.verdict
    serious = verdict.reasons[: verdict.failures + verdict.poorly_determined]
    items = "".join(f"<li>{_e(reason)}</li>" for reason in serious)
    count = verdict.warnings
    more = f"<li>{count} warning{'s' if count > 1 else ''}, below</li>" if count else ""
    listed = f"<ul>{items}{more}</ul>" if items or more else ""
    return (
        f'<div class="verdict verdict-{verdict.status}" id="verdict"><strong>Verdict: '
        f"{_e(verdict.label)}</strong>{listed}</div>"
    )


def _warnings(result: CalibrationResult) -> str:
    warnings = "".join(f'<p class="warn">{_e(w)}</p>' for w in result.warnings) or (
        '<p class="ok">No warnings.</p>'
    )
    notes = "".join(f'<p class="small">Note: {_e(n)}</p>' for n in result.notes)
    return warnings + notes


def _parameters(result: CalibrationResult) -> str:
    """The nine parameters rounded by their standard errors (`nlpcal.inference.rounded`), the
    poorly determined and undetermined ones marked."""
    errors = result.standard_errors or {}
    block = result.identifiability
    marks = {
        **{name: ("poor", "poorly determined") for name in block.get("poorly_determined", [])},
        **{name: ("undetermined", "not determined") for name in block.get("not_identifiable", [])},
    }
    rows = []
    for name, unit in zip(PARAMETER_NAMES, PARAMETER_UNITS):
        meaning = MEANINGS.get(name, MEANINGS.get(name[0], ""))
        value, error = rounded(result.parameters[name], errors.get(name))
        css, mark = marks.get(name, ("", ""))
        rows.append(
            (
                css,
                [
                    f"{SYMBOLS[name]} <code>{name}</code>",
                    value,
                    error.replace("-", "&ndash;")
                    if name not in result.fixed_parameters
                    else f"fixed ({_e(result.model_name)} model)",
                    _e(result.unit if unit == "field" else unit),
                    f'<span class="bad">&#9888; {mark}</span>' if mark else "",
                    meaning,
                ],
            )
        )
    note = ""
    if not errors:
        note = '<p class="warn">No standard errors: the data leave a direction undetermined.</p>'
    header = ["parameter", "value", "standard error", "unit", "determined", "meaning"]
    return _table(header, [r for _, r in rows], (0, 3, 4, 5), [c for c, _ in rows]) + note


def _correlations(result: CalibrationResult) -> str:
    matrix = result.correlation()
    if matrix is None:
        return "<p>No covariance in this result (no standard errors, or an older file).</p>"

    def cell(value: float) -> tuple[str, str]:
        shade = int(255 - 155 * min(abs(value), 1.0))
        colour = f"rgb(255,{shade},{shade})" if value > 0 else f"rgb({shade},{shade},255)"
        weight = "font-weight:bold;" if abs(value) > 0.9 else ""
        return f'<span style="{weight}">{value:+.3f}</span>', colour

    gauge = (
        " The gauge s<sub>x</sub> + s<sub>y</sub> + s<sub>z</sub> = 0 (no reference field) ties "
        "the three scale errors together."
        if result.gauge
        else ""
    )
    names = result.estimated_parameters  # the covariance's (the model may fix some)
    head = "".join(f"<th>{SYMBOLS[n]}</th>" for n in names)
    body = ""
    for i, name in enumerate(names):
        cells = ""
        for j in range(len(names)):
            text, colour = cell(float(matrix[i, j]))
            cells += f'<td class="num" style="background:{colour}">{text}</td>'
        body += f"<tr><th>{SYMBOLS[name]}</th>{cells}</tr>"
    return (
        f"<table><thead><tr><th></th>{head}</tr></thead><tbody>{body}</tbody></table>"
        '<p class="small">Correlation of the estimates (red positive, blue negative; bold where '
        f"|r| &gt; 0.9).{gauge}</p>"
    )


def _rows(rows, unit: str) -> str:
    extra = [k for k in ("rmse", "objective", "iterations") if any(k in r for r in rows)]
    header = ["row", *[f"{k} [{unit}]" for k in STAT_KEYS]]
    header += [
        {"objective": f"objective [{unit}&sup2;]", "rmse": f"rmse [{unit}]"}.get(k, k)
        for k in extra
    ]
    table = [
        [_e(r.get("label", "")), *[_number(r.get(k), 9) for k in (*STAT_KEYS, *extra)]]
        for r in rows
    ]
    return _table(header, table)


def _folded(rows, unit: str, shown: int = TABLE_ROWS) -> str:
    """Table 1 rows: the first `shown`, the rest behind a <details> that unfolds them."""
    if len(rows) <= shown:
        return _rows(rows, unit)
    return (
        _rows(rows[:shown], unit)
        + f"<details><summary>the other {len(rows) - shown} rows</summary>"
        + _rows(rows[shown:], unit)
        + "</details>"
    )


def _cell(value) -> str:
    """A value of a provenance or reference block as readable text (nested blocks as tables)."""
    if isinstance(value, dict):
        return _pairs(value)
    if isinstance(value, (list, tuple)):
        return _e(", ".join(str(v) for v in value)) if value else "&ndash;"
    if isinstance(value, bool) or value is None:
        return {True: "yes", False: "no", None: "&ndash;"}[value]
    if isinstance(value, (int, float, np.number)):
        return _number(value)
    return _e(value)


def _pairs(block: dict) -> str:
    """A block of key -> value as a two-column table (keys with underscores as words)."""
    if not block:
        return "&ndash;"
    return _table(
        ["", ""], [[_e(str(k).replace("_", " ")), _cell(v)] for k, v in block.items()], (0, 1)
    )


def _reference(result: CalibrationResult, view: CalibrationView) -> str:
    """The reference the calibration was fitted to, and the one this report judges against."""
    stored = result.reference.to_dict()
    judged = {
        "none": "none: the field's own mean is the only level, so the histograms show the spread "
        "of |B| about its mean",
        "given": f"{view.target_label}, given to this report",
        "stored": f"{view.target_label}, the reference stored in the parameters file",
    }[view.reference_source]
    rows = [
        ["fitted to", _pairs(stored) if stored.get("mode") != "none" else "no reference field"],
        ["this report judges against", _e(judged)],
    ]
    if result.gauge:
        rows.append(["gauge", _pairs(result.gauge)])
    return _table(["", ""], rows, (0, 1))


def _identifiability(result: CalibrationResult) -> str:
    block = result.identifiability
    if not block:
        return "<p>Not recorded (an imported calibration has no data behind it).</p>"
    missing = block.get("not_identifiable") or []
    poor = block.get("poorly_determined") or []
    coverage = block.get("coverage") or {}
    dependence = block.get("score_dependence") or {}
    widening = dependence.get("standard_error_widening") or {}
    items = [
        (
            "not determined by the data",
            f'<span class="bad">{_e(", ".join(missing))}</span>'
            if missing
            else '<span class="ok">none</span>',
        ),
        (
            "poorly determined",
            f'<span class="bad">{_e(", ".join(poor))}</span>'
            if poor
            else '<span class="ok">none</span>',
        ),
        ("least determined combination", _e(", ".join(block.get("weakest_combination", [])))),
        (
            "attitude coverage",
            f"{coverage.get('covered', '?')} of {coverage.get('direction_bins', 26)} direction bins"
            if coverage
            else "&ndash;",
        ),
        (
            "standard-error widening for alike neighbouring samples (largest)",
            _number(max(widening.values(), default=None), 4),
        ),
        ("groups of the block jackknife", _number(dependence.get("groups"), 6)),
    ]
    return _table(["", ""], [[k, v] for k, v in items], (0, 1))


def render_report(
    result: CalibrationResult,
    view: CalibrationView,
    provenance: dict,
    png: bytes | None = None,
    missing_figure: str = "",
) -> str:
    """The report as HTML text.

    result : the calibration; view : the log before and after it; provenance : input files with
    their SHA-256 and the options of the run; png : the figure (`nlpcal.plots.calibration_png`),
    or None with `missing_figure` saying why.
    """
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    if png is not None:
        encoded = base64.b64encode(png).decode("ascii")
        figure = (
            f'<img src="data:image/png;base64,{encoded}" alt="total field before and after the '
            f'correction, residual histograms, direction coverage map and cycle convergence">'
        )
    else:
        figure = f'<p class="warn">No figure: {_e(missing_figure)}</p>'
    calibration_rows = (
        _folded(result.statistics, result.unit)
        if result.statistics
        else "<p>The calibration carries no Table 1 rows (imported).</p>"
    )
    title = _e(view.title or "calibration report")
    sections = [
        f"<h1>nlpcal calibration report</h1><p class='small'>{title} &middot; generated {now} "
        f"by nlpcal {_e(__version__)}</p>",
        _verdict(result),
        f"<h2>Warnings</h2>{_warnings(result)}",
        "<h2>Parameters (Zhou et al. 2010, Eq. 4: B1 = O<sub>p</sub> S<sub>p</sub> "
        f"(B<sub>M</sub> &minus; Z<sub>p</sub>))</h2>{_parameters(result)}"
        f"<p class='small'>Values rounded to two significant digits of their standard errors. "
        f"Method: {_e(result.method)}; finished by "
        f"{_e(result.solver.last.finished_by if result.solver.last else 'none')} "
        f"({_e(result.solver.status or 'no status')}), {result.solver.iterations} IPOPT "
        f"iterations.</p>",
        f"<h2>Before and after</h2>{figure}",
        f"<h2>Table 1 rows of this log</h2>{_rows(view.rows(), view.unit)}"
        f"<p class='small'>std with ddof = 0; RMSE against the reference field when there is "
        f"one.</p>",
        f"<h2>Correlations</h2>{_correlations(result)}",
        f"<h2>Table 1 rows of the calibration</h2>{calibration_rows}",
        f"<h2>Reference field</h2>{_reference(result, view)}",
        f"<h2>Identifiability</h2>{_identifiability(result)}",
        f"<h2>Provenance</h2>{_pairs(provenance)}",
    ]
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>nlpcal report: {title}</title><style>{STYLE}</style></head>"
        f"<body>{''.join(sections)}</body></html>\n"
    )
