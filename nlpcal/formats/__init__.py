"""Exports and imports of the calibration formats users come from: MATLAB magcal, a matrix JSON,
ArduPilot, PX4 and a C header.

Every format is one module that documents the target system's formula next to its code, and
writes or reads an `AffineCorrection` B_out = A (B_M - b). `export` turns a calibration into a
format's text; `import_file` reads a file back into a `CalibrationResult` through the Cholesky
route (`nlpcal.models.zhou2010.from_correction`) that `apply` and `stats` use like any other.
"""

from __future__ import annotations

from pathlib import Path

from .. import units, validation
from ..calibration.result import FIELD_LIMIT, CalibrationResult
from ..errors import InputError
from ..io.files import existing_file, sha256_file
from . import ardupilot, c_header, matlab, matrix, px4
from .affine import AffineCorrection, Export, expected_field, polar, rotation_angle_deg

#: Format name -> module; every module has write(correction, ...) and read(text, source, ...).
FORMATS = {
    "matlab": matlab,
    "matrix": matrix,
    "ardupilot": ardupilot,
    "px4": px4,
    "c-header": c_header,
}
#: A rotation the nine parameters do not carry is mentioned above this angle. [deg]
ROTATION_NOTE_DEG = 1e-6
#: Formats whose unit is fixed by the target system.
AUTOPILOTS = ("ardupilot", "px4")
#: The format a file's extension implies: Mission Planner saves ".param", MAVProxy ".parm",
#: QGroundControl ".params"; ".m" is a MATLAB script, ".h" a C header, ".json" the matrix JSON.
EXTENSIONS = {
    ".param": "ardupilot",
    ".parm": "ardupilot",
    ".params": "px4",
    ".h": "c-header",
    ".json": "matrix",
    ".m": "matlab",
}
#: Where each format has a place for the parts of a result beyond A and b ("sensor_id" and
#: "orientation" the autopilots write in their own terms, decided by their modules).
CARRIES = {
    "matlab": ("field",),
    "matrix": ("field", "sensor_id", "orientation"),
    "ardupilot": ("sensor_id", "orientation"),
    "px4": ("sensor_id", "orientation", "temperature"),
    "c-header": ("field", "sensor_id", "temperature"),
}


def format_for(path, option: str) -> str:
    """The format `path`'s extension implies (`EXTENSIONS`), or InputError naming `option`."""
    suffix = "" if path in (None, "-") else Path(str(path)).suffix.lower()
    if suffix in EXTENSIONS:
        return EXTENSIONS[suffix]
    known = ", ".join(f"{k} ({v})" for k, v in EXTENSIONS.items())
    if suffix:
        where = f"the extension {suffix!r} of {path}"
    else:
        where = "stdout" if path in (None, "-") else f"{path}, which has no extension"
    raise InputError(
        f"cannot tell the format from {where}; pass --format, or give {option} one of the "
        f"extensions {known}"
    )


def _check(fmt: str, unit, instance) -> None:
    if fmt not in FORMATS:
        raise InputError(f"unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if fmt in AUTOPILOTS and unit is not None:
        fixed = FORMATS[fmt].UNIT
        raise InputError(f"{fmt} parameters are in {fixed}; --unit applies to the other formats")
    if fmt not in AUTOPILOTS and instance is not None:
        raise InputError(f"--instance applies to ardupilot and px4, not to {fmt}")
    if fmt in AUTOPILOTS and instance is not None:
        FORMATS[fmt].names(instance)  # InputError for an instance the system does not have


def export(
    result,
    format: str | None = None,
    *,
    unit: str | None = None,
    instance: int | None = None,
    max_rotation_deg: float | None = None,
    drop_temperature: bool = False,
    fmt: str | None = None,
) -> Export:
    """A calibration in one of `FORMATS` (matlab, matrix, ardupilot, px4, c-header), as text.

    Parameters
    ----------
    result : CalibrationResult or TemperatureCalibrationResult
        The calibration. A temperature model goes where the format has a place for it (px4's
        TC_M* when they represent it exactly, the C header's function); elsewhere the parameters
        at t0 are written and a note says so.
    format : str
        The format (`--format`).
    unit : str, optional
        The unit of the offsets and field in matlab, matrix and c-header (default: the unit of the
        log the calibration was estimated from); the autopilots' units are fixed.
    instance : int, optional
        The compass instance (ardupilot 1-3, default 1) or slot (px4 0-3, default 0)
        (`--instance`).
    max_rotation_deg : float, optional
        The largest rotation between nlpcal's axes and the symmetric matrix of the autopilot
        formats. [deg]
    drop_temperature : bool
        Write a temperature calibration to px4 without its temperature model when TC_M* cannot
        represent it (`--drop-temperature`; otherwise InputError).
    fmt : str, optional
        The former name of `format`, still accepted.

    Returns
    -------
    Export
        The text, the notes for the user, and the rotation the format could not carry [deg].
        The notes end with one sentence naming what of the result the format has no place for
        (`Export.dropped`): the temperature model, sensor_id, orientation, the expected field,
        the model restriction, the standard errors.

    Raises
    ------
    InputError
        An unknown format, or a calibration the format cannot carry (a unit only assumed, for a
        field unit; a temperature model px4 cannot represent, without `drop_temperature`).

    Examples
    --------
    >>> import nlpcal
    >>> samples = nlpcal.simulate(300, seed=0)[["bx", "by", "bz"]].to_numpy()
    >>> exported = nlpcal.export(nlpcal.calibrate(samples, unit="nT"), "matrix")
    >>> '"model": "B1 = A (B_M - b)"' in exported.text
    True
    """
    fmt = _chosen_format(format, fmt)
    _check(fmt, unit, instance)
    if max_rotation_deg is not None:
        max_rotation_deg = validation.number(
            max_rotation_deg, "--max-rotation-deg", minimum=0.0, maximum=180.0, unit="[deg]"
        )
    calibration = refuse_aux(getattr(result, "calibration", result), fmt)  # a temperature's own
    target = FORMATS[fmt].UNIT if fmt in AUTOPILOTS else unit or calibration.log_unit
    notes = scale_notes(calibration, target)
    correction = AffineCorrection.from_result(result, None if fmt in AUTOPILOTS else unit)
    module = FORMATS[fmt]
    if fmt in AUTOPILOTS:
        chosen = module.INSTANCES[0] if instance is None else instance
        options = {"drop_temperature": drop_temperature} if fmt == "px4" else {}
        written = module.write(
            correction, instance=chosen, max_rotation_deg=max_rotation_deg, **options
        )
    else:
        written = module.write(correction)
        written.rotation_deg = rotation_angle_deg(correction.polar()[0])
    written.dropped += dropped(calibration, correction, fmt)
    written.notes[:0] = notes
    if written.dropped:
        written.notes.append(
            f"not written to {fmt} (it has no place for them): {'; '.join(written.dropped)}"
        )
    return written


def refuse_aux(calibration: CalibrationResult, fmt: str) -> CalibrationResult:
    """InputError for a calibration with aux channels in a format that holds the correction of
    Eq. 4 alone (the autopilots' motor compensation takes one current or throttle channel):
    written without the stray fields it would correct every sample wrongly."""
    channels = getattr(calibration, "aux", None)
    if channels and fmt not in AUTOPILOTS:
        names = ", ".join(f"{c.name} ({c.kind})" for c in channels)
        raise InputError(
            f"the calibration has aux channels {names}, whose stray fields {fmt} has no place "
            f"for; apply it with 'nlpcal apply', which subtracts them, or export to ardupilot "
            f"or px4 (one current or throttle channel)"
        )
    return calibration


def dropped(calibration: CalibrationResult, correction: AffineCorrection, fmt: str) -> list:
    """What of a calibration `fmt` has no place for (`CARRIES`), a phrase each; the parts an
    autopilot writes in its own terms (device id, orientation, px4's temperature model) its
    module decides."""
    carries = CARRIES[fmt]
    phrases = []
    if correction.temperature is not None and "temperature" not in carries:
        phrases.append(
            f"the temperature model (the calibration at "
            f"{correction.temperature.base_temperature_degC:g} degC is written)"
        )
    if fmt not in AUTOPILOTS:
        if correction.sensor_id is not None and "sensor_id" not in carries:
            phrases.append(f"sensor_id {correction.sensor_id!r}")
        if correction.orientation is not None and "orientation" not in carries:
            mounting = correction.orientation
            phrases.append(f"the orientation {mounting['parameter']} = {mounting['value']}")
    if correction.field is not None and "field" not in carries:
        phrases.append(f"the expected field {correction.field:.6g} {correction.unit}")
    if calibration.model_name != "full":
        phrases.append(
            f"the model {calibration.model_name} (its fixed parameters "
            f"{', '.join(calibration.fixed_parameters)} are written as zeros)"
        )
    if calibration.standard_errors:
        phrases.append("the standard errors")
    return phrases


def scale_notes(result: CalibrationResult, target: str) -> list:
    """What the export must say about its physical scale (a list of notes), or InputError when
    `result` cannot be written in the field unit `target`: its unit is raw counts, or was only
    assumed (or not recorded) and no reference field fixed the scale
    (`CalibrationResult.scale_fixed_by`)."""
    if target == "raw":
        return []
    fixed_by = result.scale_fixed_by()
    if fixed_by == "the unit":
        return []
    if fixed_by == "the reference field":
        field = expected_field(result)
        size = "" if field is None else f" ({field:.6g} {result.unit})"
        return [
            f"the unit of the calibrated log was assumed ({result.log_unit}), and its reference "
            f"field{size} fixes the scale: the correction maps the log's numbers to "
            f"{result.unit}, written in {target}"
        ]
    why = {
        "raw": "it is in raw counts",
        "assumed": f"its unit was only assumed ({result.log_unit}: the log's columns name none)",
    }.get(
        "raw" if result.unit == "raw" else result.unit_source or "",
        "its file does not record where its unit came from (written before unit_source)",
    )
    raise InputError(
        f"cannot write this calibration in {target}: {why}, so offsets in a field unit "
        f"could be wrong by any factor; calibrate the log again with --unit (the unit of its "
        f"field columns) or with a reference field (--reference-field, --reference-column or "
        f"--reference-model) that fixes the scale"
    )


def import_file(
    path,
    format: str | None = None,
    *,
    unit: str | None = None,
    reference_field: float | None = None,
    instance: int | None = None,
    fmt: str | None = None,
    field: float | None = None,
) -> tuple[CalibrationResult, list]:
    """A calibration from a file of one of `FORMATS`, and notes for the user.

    Parameters
    ----------
    path : str or os.PathLike
        The file to read.
    format : str
        Its format (`--format`).
    unit : str, optional
        The unit of the file's offsets and field, for matlab, matrix and c-header when the file
        does not say (default nT).
    reference_field : float, optional
        The total field the correction should map to (`--reference-field`). A file that carries
        its expected field (magcal's expmfs, the matrix "field") has A rescaled by
        reference_field / expected; otherwise it is recorded as the reference field. [the
        file's unit]
    instance : int, optional
        The compass instance (ardupilot 1-3, default 1) or slot (px4 0-3, default 0)
        (`--instance`).
    fmt, field : optional
        The former names of `format` and `reference_field`, still accepted.

    Returns
    -------
    tuple of (CalibrationResult, list of str)
        The calibration, and the notes for the user.

    Raises
    ------
    InputError
        An unreadable file, or one that is not a calibration of that format.

    Examples
    --------
    >>> import os, tempfile
    >>> import nlpcal
    >>> samples = nlpcal.simulate(300, seed=0)[["bx", "by", "bz"]].to_numpy()
    >>> result = nlpcal.calibrate(samples, method="joint", unit="nT")
    >>> path = os.path.join(tempfile.mkdtemp(), "matrix.json")
    >>> with open(path, "w") as handle:
    ...     _ = handle.write(nlpcal.export(result, "matrix").text)
    >>> again, notes = nlpcal.import_file(path, "matrix")
    >>> abs(again.parameters["z_x"] - result.parameters["z_x"]) < 1e-9  # [nT]
    True
    """
    fmt = _chosen_format(format, fmt)
    field = validation.renamed(reference_field, field, "reference_field", "field")
    _check(fmt, unit, instance)
    if field is not None:
        field = validation.number(field, "--reference-field", positive=True)
    path = existing_file(path, f"a {fmt} file")
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file; expected a {fmt} file") from None
    module = FORMATS[fmt]
    if fmt in AUTOPILOTS:
        chosen = module.INSTANCES[0] if instance is None else instance
        correction = module.read(text, str(path), instance=chosen)
    else:
        correction = module.read(text, str(path), unit=unit)
    correction.checked(str(path))
    notes = _carried_notes(correction, path)
    scaled = None
    if field is not None:
        correction, scaled = _to_field(correction, field, notes)
    result = correction.to_result(
        log_unit=None if fmt in AUTOPILOTS else correction.unit,
        unit_source="format" if fmt in AUTOPILOTS else correction.source["unit_source"],
        imported_from=str(path),
        format=fmt,
        sha256=sha256_file(path),
        field_scale=scaled,
    )
    # Read back as a parameters file is: the plausible ranges of its values are checked there.
    result = CalibrationResult.from_dict(result.to_dict(), f"{path} (as nine parameters)")
    angle = result.input["rotation_not_carried"]["angle_deg"]
    if angle > ROTATION_NOTE_DEG:
        notes.append(
            f"the nine parameters carry no rotation: the file's correction equals Q B1 with Q a "
            f"rotation of {angle:.4g} deg (same magnitude |B1|)"
        )
    return result, notes


def _chosen_format(format: str | None, former: str | None) -> str:
    """The format given as `format=` or by its former name `fmt=`; InputError without one."""
    chosen = validation.renamed(format, former, "format", "fmt")
    if chosen is None:
        raise InputError(f"no format given; pass format= one of {', '.join(FORMATS)}")
    return chosen


def _carried_notes(correction: AffineCorrection, path) -> list:
    """The notes on what an imported file held beyond A and b: what was not used, and the
    sensor_id and orientation carried into the result."""
    notes = []
    if correction.unused:
        notes.append(f"not used from {path}: {', '.join(correction.unused)}")
    carried = [f"sensor_id {correction.sensor_id!r}"] if correction.sensor_id is not None else []
    if correction.orientation is not None:
        mounting = correction.orientation
        label = f" ({mounting['name']})" if "name" in mounting else ""
        carried.append(
            f"orientation {mounting['parameter']} = {mounting['value']}{label} (recorded, not "
            f"applied: the correction stays in the sensor's axes)"
        )
    if carried:
        notes.append(f"carried into the result: {'; '.join(carried)}")
    return notes


def _to_field(correction: AffineCorrection, field: float, notes: list) -> tuple:
    """The correction mapping to the total `field` [the file's unit]: A rescaled when the file
    carries its own expected field (with a note), else the field recorded as its reference.
    Returns the correction and the factor A was scaled by (None when not)."""
    validation.number(
        units.to_base(field, correction.unit),
        f"--reference-field in {units.base_unit(correction.unit)}",
        maximum=FIELD_LIMIT,
    )
    scaled = None
    if correction.field is not None:
        correction, scaled = correction.rescaled(field)
        notes.append(
            f"A scaled by {scaled:.9g} so that the correction maps to {field:g} "
            f"{correction.unit} instead of the file's expected field"
        )
    else:
        correction.field = field
    return correction, scaled


__all__ = [
    "AUTOPILOTS",
    "EXTENSIONS",
    "FORMATS",
    "AffineCorrection",
    "Export",
    "export",
    "format_for",
    "import_file",
    "polar",
    "rotation_angle_deg",
]
