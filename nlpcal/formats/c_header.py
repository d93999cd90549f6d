"""A C header for firmware: the matrix and offsets at full double precision, and the function
that applies them.

    B1 = A (B_M - b):  b1[i] = sum_j NLPCAL_A[i][j] * (m[j] - NLPCAL_B[j])

NLPCAL_A is row-major (C order), NLPCAL_B and NLPCAL_FIELD in the unit the one-line comment
names. Every value is written with 17 significant digits, so it reads back to the same double.
`nlpcal_apply(m, b1)` computes B1 as `nlpcal apply` does (Eq. 4 of Zhou et al. 2010, A = O_p
S_p). A temperature calibration adds NLPCAL_T0 [degC], NLPCAL_SCALE_SLOPE [1/degC] and
NLPCAL_OFFSET_SLOPE [unit/degC] and takes the temperature, `nlpcal_apply(m, t, b1)`:

    b1 = A diag(1 / (1 + sigma (t - t0))) (m - b - zeta (t - t0))    (`TemperatureDrift`)

which is Liu et al.'s (2022) Eq. 9 for their common model and the per-axis model of
`nlpcal.models.liu2022`. The function is C99 (static inline) and needs no library. A
calibration's sensor_id is written as `#define NLPCAL_SENSOR_ID 97539` (a device id) or
`"name"`, and read back.
"""

from __future__ import annotations

import json
import re

import numpy as np

from .. import units, validation
from ..errors import InputError
from ..results import distinct
from .affine import MODEL, AffineCorrection, Export, read_unit_source

_UNIT = re.compile(r"b and B1 in (\S+?)[,;]")
#: A constant: "double NAME[...] = {...};" (the function's statements are not declarations).
_ARRAY = re.compile(r"\bdouble\s+(\w+)[^=;(]*=\s*(\{.*?\}\s*\}|\{.*?\}|[^;{]+)", re.DOTALL)
#: The body of a function: from ") {" to the "}" that starts a line.
_BODY = re.compile(r"\)\s*\{.*?^\}", re.DOTALL | re.MULTILINE)
#: The sensor's identity: a device id or a C string literal (JSON's escapes are C's).
_SENSOR_ID = re.compile(r'^\s*#define\s+NLPCAL_SENSOR_ID\s+(\d+|"(?:[^"\\]|\\.)*")', re.MULTILINE)
#: The constants of the correction, by their name in NLPCAL_*.
_USED = ("A", "B", "FIELD")


def _c(value: float) -> str:
    return format(float(value), ".17g")


def write(correction: AffineCorrection) -> Export:
    rows = ",\n    ".join("{" + ", ".join(_c(v) for v in row) + "}" for row in correction.matrix)
    drift = correction.temperature
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
    if correction.sensor_id is not None:
        lines.append(
            f"#define NLPCAL_SENSOR_ID {json.dumps(correction.sensor_id, ensure_ascii=False)} "
            f"/* the sensor this calibration is for */"
        )
    if drift is not None:
        lines += [
            f"static const double NLPCAL_T0 = {_c(drift.base_temperature_degC)}; /* t0 [degC] */",
            f"static const double NLPCAL_SCALE_SLOPE[3] = {_array(drift.scale_slope_per_degC)};"
            f" /* sigma [1/degC] */",
            f"static const double NLPCAL_OFFSET_SLOPE[3] = {_array(drift.offset_slope_per_degC)};"
            f" /* zeta [{correction.unit}/degC] */",
        ]
    lines += [
        "",
        *_function(correction.unit, drift is not None),
        "",
        "#endif /* NLPCAL_CALIBRATION_H */",
    ]
    return Export("\n".join(lines) + "\n")


def _array(values) -> str:
    return "{" + ", ".join(_c(v) for v in values) + "}"


def _function(unit: str, temperature: bool) -> list:
    """nlpcal_apply: B1 = A (m - b), with the temperature drift when the calibration has one."""
    if not temperature:
        head = [
            f"/* B1 = A (m - b), as nlpcal apply computes it; m and b1 in {unit} (C99). */",
            "static inline void nlpcal_apply(const double m[3], double b1[3])",
            "{",
            "    double d[3];",
            "    int i;",
            "    for (i = 0; i < 3; i++) {",
            "        d[i] = m[i] - NLPCAL_B[i];",
            "    }",
        ]
    else:
        head = [
            f"/* B1 = A diag(1 / (1 + sigma dt)) (m - b - zeta dt), dt = t - t0, as nlpcal apply "
            f"computes it; m and b1 in {unit}, t in degC (C99). */",
            "static inline void nlpcal_apply(const double m[3], double t, double b1[3])",
            "{",
            "    const double dt = t - NLPCAL_T0;",
            "    double d[3];",
            "    int i;",
            "    for (i = 0; i < 3; i++) {",
            "        d[i] = (m[i] - NLPCAL_B[i] - NLPCAL_OFFSET_SLOPE[i] * dt)"
            " / (1.0 + NLPCAL_SCALE_SLOPE[i] * dt);",
            "    }",
        ]
    return head + [
        "    for (i = 0; i < 3; i++) {",
        "        b1[i] = NLPCAL_A[i][0] * d[0] + NLPCAL_A[i][1] * d[1] + NLPCAL_A[i][2] * d[2];",
        "    }",
        "}",
    ]


def read(text: str, source: str, unit: str | None = None) -> AffineCorrection:
    """NLPCAL_A, NLPCAL_B (and NLPCAL_FIELD) of a header written by `write`."""
    written = _UNIT.search(text)
    given, unit = unit, unit or (written.group(1) if written else "nT")
    units.field_factor(unit)
    code = re.sub(r"/\*.*?\*/", " ", text, flags=re.DOTALL)
    code = _BODY.sub(") ;", code)  # a function's statements are not constants
    found = [
        (name.removeprefix("NLPCAL_"), _numbers(body, f"{source}: {name}"))
        for name, body in _ARRAY.findall(code)
        if name.startswith("NLPCAL_")
    ]
    values = distinct(found, source, "constant")
    unused = [name for name, _ in _ARRAY.findall(code) if name.removeprefix("NLPCAL_") not in _USED]
    if "A" not in values or "B" not in values:
        raise InputError(f"{source}: no NLPCAL_A[3][3] and NLPCAL_B[3] found")
    if values["A"].size != 9 or values["B"].size != 3:
        raise InputError(f"{source}: NLPCAL_A must hold 9 values and NLPCAL_B 3")
    field = float(values["FIELD"][0]) if "FIELD" in values and values["FIELD"].size else None
    sensor = _SENSOR_ID.search(code)
    return AffineCorrection(
        matrix=values["A"].reshape(3, 3),
        offsets=values["B"],
        unit=unit,
        field=field,
        unused=unused,
        sensor_id=None
        if sensor is None
        else validation.sensor_id(json.loads(sensor.group(1)), f"{source}: NLPCAL_SENSOR_ID"),
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
