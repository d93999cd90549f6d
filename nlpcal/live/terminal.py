"""The terminal view of a live calibration: redrawn on stderr at every update.

The coverage grid is drawn zone by zone from the +z pole down (`nlpcal.live.grid`), a cell as
`#` when covered, `.` when not and `@` for the one to aim at next; then where to turn, the fit
(the spread of |B1|) and each parameter against its target standard error.
"""

from __future__ import annotations

import numpy as np

from ..models.zhou2010 import PARAMETER_NAMES
from .grid import CELLS, cell_index, direction_name, zones
from .session import Update

#: Clear the screen and go home (ANSI), before each frame.
CLEAR = "\033[H\033[J"


def grid_lines(update: Update) -> list:
    """The coverage grid, one line per zone, centred."""
    counts, _, first = zones()
    covered = update.coverage.covered
    aim = _aim(update)
    width = int(counts.max())
    lines = []
    for zone, (n, start) in enumerate(zip(counts, first)):
        cells = "".join(
            "@" if start + k == aim else ("#" if covered[start + k] else ".") for k in range(n)
        )
        label = "+z" if zone == 0 else ("-z" if zone == len(counts) - 1 else "  ")
        lines.append(f"  {label} {' '.join(cells).center(2 * width - 1)}")
    return lines


def _aim(update: Update) -> int | None:
    nxt = update.coverage.next_direction
    if nxt is None:
        return None
    return int(cell_index(np.asarray([nxt]))[0])


def render(update: Update, stop: str | None = None) -> str:
    """One frame of the view."""
    cov = update.coverage
    verdict = update.to_dict()["verdict"]["status"]
    lines = [
        f"nlpcal live: {update.n_samples} samples, {update.elapsed_s:.1f} s, model "
        f"{update.model}, verdict {verdict}",
        f"coverage: {int(np.count_nonzero(cov.covered))} of {CELLS} cells "
        f"({100 * cov.fraction:.0f} %, target {100 * cov.target:.0f} %)",
        *grid_lines(update),
    ]
    if cov.next_direction is not None:
        lines.append(f"turn next: make the field point along {direction_name(cov.next_direction)}")
    result = update.result
    if result is None:
        lines.append(f"fit: {update.failure}")
    else:
        row = result.statistics[-1]
        lines.append(
            f"fit: std of |B1| {row['std']:.4g} {result.unit} about {row['mean']:.6g} {result.unit}"
        )
        errors = result.standard_errors or {}
        lines.append(f"  {'parameter':<10} {'estimate':>14} {'SE':>11} {'target':>11}")
        for name in PARAMETER_NAMES:
            if name not in update.limits:
                continue
            se = errors.get(name)
            mark = "  <- not yet" if name in update.poorly_determined else ""
            se_text = "-" if se is None else f"{se:.4g}"
            lines.append(
                f"  {name:<10} {result.parameters[name]:>14.6g} {se_text:>11} "
                f"{update.limits[name]:>11.4g}{mark}"
            )
    if update.determined:
        lines.append(f"all parameters determined at sample {update.n_samples}")
    elif stop:
        lines.append(f"stopped ({stop})")
    return "\n".join(lines)
