"""A C header for firmware: the matrix and offsets at full double precision.

    B1 = A (B_M - b):  b1[i] = sum_j NLPCAL_A[i][j] * (m[j] - NLPCAL_B[j])

NLPCAL_A is row-major (C order), NLPCAL_B and NLPCAL_FIELD in the unit the one-line comment
names. Every value is written with 17 significant digits, so it reads back to the same double.
"""

from __future__ import annotations

import re

import numpy as np

from .. import units, validation
from ..errors import InputError
from ..results import distinct
from .affine import MODEL, AffineCorrection, Export, read_unit_source

_UNIT = re.compile(r"b and B1 in (\S+?)[,;]")
_ARRAY = re.compile(r"NLPCAL_(A|B|FIELD)\b[^=]*=\s*(\{.*?\}\s*\}|\{.*?\}|[^;{]+)", re.DOTALL)


def _c(value: float) -> str:
    return format(float(value), ".17g")


def write(correction: AffineCorrection) -> Export:
    rows = ",\n    ".join("{" + ", ".join(_c(v) for v in row) + "}" for row in correction.matrix)
    lines = [
        f"/* nlpcal calibration (Zhou et al. 2010, Eq. 4): {MODEL}, "
        f"b1[i] = sum_j NLPCAL_A[i][j] * (m[j] - NLPCAL_B[j]); b and B1 in {correction.unit}, "
        f"A dimensionless. */",
        "#ifndef NLPCAL_CALIBRATION_H",
        "#define NLPCAL_CALIBRATION_H",
        "",
        f"static const double NLPCAL_A[3][3] = {{\n    {rows}}};",
        f"static const double NLPCAL_B[3] = {{{', '.join(_c(v) for v in correction.offsets)}}};",
    ]
    if correction.field is not None:
        lines.append(
            f"static const double NLPCAL_FIELD = {_c(correction.field)}; "
            f"/* expected |B1| [{correction.unit}] */"
        )
    lines += ["", "#endif /* NLPCAL_CALIBRATION_H */"]
    return Export("\n".join(lines) + "\n")


def read(text: str, source: str, unit: str | None = None) -> AffineCorrection:
    """NLPCAL_A, NLPCAL_B (and NLPCAL_FIELD) of a header written by `write`."""
    written = _UNIT.search(text)
    given, unit = unit, unit or (written.group(1) if written else "nT")
    units.field_factor(unit)
    code = re.sub(r"/\*.*?\*/", " ", text, flags=re.DOTALL)
    found = [
        (name, _numbers(body, f"{source}: NLPCAL_{name}")) for name, body in _ARRAY.findall(code)
    ]
    values = distinct(found, source, "constant")
    if "A" not in values or "B" not in values:
        raise InputError(f"{source}: no NLPCAL_A[3][3] and NLPCAL_B[3] found")
    if values["A"].size != 9 or values["B"].size != 3:
        raise InputError(f"{source}: NLPCAL_A must hold 9 values and NLPCAL_B 3")
    field = float(values["FIELD"][0]) if "FIELD" in values and values["FIELD"].size else None
    return AffineCorrection(
        matrix=values["A"].reshape(3, 3),
        offsets=values["B"],
        unit=unit,
        field=field,
        source={
            "file": source,
            "format": "c-header",
            "unit_source": read_unit_source(given, written),
        },
    )


def _numbers(body: str, what: str) -> np.ndarray:
    """The finite numbers of a C initialiser ({1, 2, 3}, {{...}, ...}) or of a scalar."""
    return np.array(
        [validation.number(v, what) for v in re.split(r"[\s,{}]+", body) if v], dtype=float
    )
