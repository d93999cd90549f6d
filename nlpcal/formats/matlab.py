"""MATLAB `magcal`: the row-vector convention C = (D - b) * A.

MATLAB's `[A, b, expmfs] = magcal(D)` returns a 3 x 3 matrix A, a 1 x 3 offset b and the
expected magnetic field strength expmfs; the data D are N x 3 (one sample per row) and the
corrected data are

    C = (D - b) * A                                   (MATLAB Sensor Fusion Toolbox, magcal)

so that, written for column vectors, c = A^T (d - b^T). The A of this file is therefore the
transpose of nlpcal's A (B1 = A (B_M - b)); b and expmfs are in the unit of D. The file is a
MATLAB script that defines A, b and expmfs; the unit is written as a comment ("% unit: nT").
"""

from __future__ import annotations

import re

import numpy as np

from .. import units
from ..errors import InputError
from ..results import distinct
from .affine import MODEL, AffineCorrection, Export, number_text, read_unit_source

_UNIT = re.compile(r"^\s*%\s*unit:\s*(\S+)", re.MULTILINE)
_ASSIGNMENT = re.compile(r"\b(A|b|expmfs)\s*=\s*(\[[^\]]*\]|[^;\n]+)", re.DOTALL)


def write(correction: AffineCorrection) -> Export:
    """The script: A (the transpose of nlpcal's), b and expmfs at full double precision."""
    a = correction.matrix.T  # magcal's row-vector convention: C = (D - b) * A
    rows = ";\n".join("    " + " ".join(number_text(v) for v in row) for row in a)
    source = ", ".join(f"{k}: {v}" for k, v in correction.source.items())
    lines = [
        f"% nlpcal calibration for MATLAB magcal's convention C = (D - b) * A (nlpcal: {MODEL},"
        f" A here is its transpose)",
        f"% unit: {correction.unit}",
        f"% D and C: N x 3, one sample per row, in {correction.unit}; A dimensionless",
    ]
    if source:
        lines.append(f"% source: {source}")
    lines += [f"A = [\n{rows}];", f"b = [{' '.join(number_text(v) for v in correction.offsets)}];"]
    if correction.field is not None:
        lines.append(f"expmfs = {number_text(correction.field)};")
    return Export("\n".join(lines) + "\n")


def read(text: str, source: str, unit: str | None = None) -> AffineCorrection:
    """A, b and expmfs of a MATLAB script (comments, commas and `...` continuations allowed).

    unit : the unit of b and expmfs (default: the "% unit:" comment, else nT).
    """
    written = _UNIT.search(text)
    file_unit = unit or (written.group(1) if written else "nT")
    units.field_factor(file_unit)
    code = "\n".join(line.split("%", 1)[0] for line in text.splitlines()).replace("...", " ")
    assigned = re.findall(r"^\s*([A-Za-z]\w*)\s*=(?!=)", code, re.MULTILINE)
    values = distinct(
        [(name, _numbers(body, f"{source}: {name}")) for name, body in _ASSIGNMENT.findall(code)],
        source,
        "variable",
    )
    for name in ("A", "b"):
        if name not in values:
            raise InputError(
                f"{source}: no assignment '{name} = [...]' found; expected magcal's "
                f"A (3 x 3), b (1 x 3) and optionally expmfs"
            )
    a, b = values["A"], values["b"]
    if a.shape != (3, 3):
        raise InputError(f"{source}: A must be 3 x 3, got {a.shape[0]} x {a.shape[1]}")
    if b.size != 3:
        raise InputError(f"{source}: b must have 3 values, got {b.size}")
    field = None
    if "expmfs" in values:
        if values["expmfs"].size != 1 or not values["expmfs"].ravel()[0] > 0:
            raise InputError(f"{source}: expmfs must be one positive number")
        field = float(values["expmfs"].ravel()[0])
    return AffineCorrection(
        unused=sorted({name for name in assigned if name not in ("A", "b", "expmfs")}),
        matrix=a.T,  # back to the column-vector convention
        offsets=b.ravel(),
        unit=file_unit,
        field=field,
        source={"file": source, "format": "matlab", "unit_source": read_unit_source(unit, written)},
    )


def _numbers(body: str, what: str) -> np.ndarray:
    """A MATLAB numeric literal ([1 2; 3 4], [1, 2, 3], 5) as a 2-d array."""
    body = body.strip().strip("[]")
    rows = [row for row in re.split(r"[;\n]", body) if row.strip()]
    try:
        parsed = [[float(v) for v in re.split(r"[\s,]+", row.strip()) if v] for row in rows]
    except ValueError:
        raise InputError(f"{what} must hold numbers only") from None
    if not parsed or len({len(row) for row in parsed}) != 1:
        raise InputError(f"{what}: rows of different lengths")
    array = np.array(parsed, dtype=float)
    if not np.isfinite(array).all():
        raise InputError(f"{what} contains non-finite values")
    return array
