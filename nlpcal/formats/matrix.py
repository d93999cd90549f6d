"""The matrix form as JSON: B1 = A (B_M - b) with A (3 x 3, row-major) and b, plus units.

    {"format": "nlpcal-affine-correction", "model": "B1 = A (B_M - b)",
     "A": [[a11, a12, a13], [a21, a22, a23], [a31, a32, a33]], "b": [bx, by, bz],
     "unit": "nT", "A_unit": "1", "field": F, "symmetric": {"P": ..., "R": ...}, ...}

Column-vector convention: B1 = A (B_M - b), B_M and b in `unit`, A dimensionless, `field` the
total field the correction maps to. `symmetric` is the polar decomposition A = R P, for firmware
that takes a symmetric matrix; it is written for the reader and ignored when read back. A file
written by hand needs only "A" and "b" (and "unit" when not nT). "sensor_id" and "orientation"
are written and read back when the calibration has them; an import names any other key.
"""

from __future__ import annotations

from ..errors import InputError
from ..io.files import json_text
from ..results import parse_json
from .affine import AffineCorrection, Export, read_unit_source

#: The keys nlpcal writes: read (A, b, unit, field, sensor_id, orientation, source), or derived
#: from them for the reader (model, A_unit, symmetric) and the envelope.
KNOWN = (
    "format", "format_version", "verdict", "model", "A", "b", "unit", "A_unit", "field",
    "symmetric", "source", "nlpcal_version", "sensor_id", "orientation",
)  # fmt: skip


def write(correction: AffineCorrection) -> Export:
    return Export(json_text(correction.to_dict()))


def read(text: str, source: str, unit: str | None = None) -> AffineCorrection:
    """The correction of a matrix JSON file; `unit` overrides the file's "unit"."""
    try:
        document = parse_json(text, source)
    except RecursionError:
        raise InputError(f"{source}: nested too deeply; not valid JSON") from None
    correction = AffineCorrection.from_dict(document, source)
    stated = isinstance(document, dict) and "unit" in document
    correction.unused = [key for key in document if key not in KNOWN]
    correction.source = {
        "file": source,
        "format": "matrix",
        "written_by": correction.source,
        "unit_source": read_unit_source(unit, stated),
    }
    if unit and unit != correction.unit:
        if isinstance(document, dict) and "unit" in document:
            raise InputError(
                f"{source} says its unit is {correction.unit!r}; --unit {unit} contradicts it"
            )
        correction.unit = unit
    return correction
