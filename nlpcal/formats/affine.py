"""The affine form of a calibration, B_out = A (B_M - b): what every external format carries.

The nine parameters of Eq. 4 in [1] give A = O_p S_p (upper triangular) and b = Z_p. Other tools
store other shapes of the same map, and this module holds the two pieces of linear algebra that
translate between them, each written once:

* into the nine parameters: the Cholesky route of `nlpcal.models.zhou2010.from_correction`,
  (A^T A)^-1 = (S N)(S N)^T, which leaves a rotation Q (A = Q O_p S_p) that the nine parameters
  do not carry;
* into a symmetric matrix (ArduPilot, PX4): the polar decomposition A = R P, with P symmetric
  positive definite and R a rotation. An autopilot that applies P gives R^T B1: the same
  magnitude |B1|, in axes turned by R. P's axes are the ones closest to the sensor's own axes;
  those of Eq. 4 keep z on the sensor's z axis and y in its y-z plane. R is small when the axes
  are nearly orthogonal (1.35 deg for the angles of [1]) and is reported with every export.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .. import units, validation
from ..auxiliary.model import converted
from ..calibration.result import CalibrationResult, Reference, read_orientation
from ..errors import InputError
from ..models.zhou2010 import correction_matrix, from_correction, smallest_model
from ..results import Document, DocumentReader, Provenance
from ..version import __version__

#: The model every format states, in the column-vector convention.
MODEL = "B1 = A (B_M - b)"


def polar(matrix) -> tuple[np.ndarray, np.ndarray]:
    """The polar decomposition A = R P: R a rotation, P symmetric positive definite. [1]

    From the singular value decomposition A = W diag(sigma) V^T: R = W V^T, P = V diag(sigma) V^T.
    Raises InputError when A is singular or reverses handedness (R would be a reflection).
    """
    a = validation.matrix(matrix, "the correction matrix A", invertible=True)
    if not np.linalg.det(a) > 0:
        raise InputError("the correction matrix A reverses handedness (det A < 0)")
    w, sigma, vt = np.linalg.svd(a)
    p = vt.T @ np.diag(sigma) @ vt
    return w @ vt, 0.5 * (p + p.T)


def rotation_angle_deg(rotation) -> float:
    """The angle of a rotation matrix, accurate for small angles too. [deg]"""
    r = np.asarray(rotation, dtype=float)
    sine = 0.5 * np.linalg.norm([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return float(np.degrees(np.arctan2(sine, 0.5 * (np.trace(r) - 1.0))))


def expected_field(result: CalibrationResult) -> float | None:
    """The total field a calibration maps to: its reference field (or the mean of a reference
    series), else the mean |B1| of its last Table 1 row, else None. [result unit]"""
    if result.reference.level is not None:
        return float(result.reference.level)
    if result.statistics and isinstance(result.statistics[-1].get("mean"), (int, float)):
        return float(result.statistics[-1]["mean"])
    return None


@dataclass(frozen=True)
class TemperatureDrift:
    """How the correction changes with the temperature t (`nlpcal.models.liu2022`), per axis:

        B_out = A diag(1 / (1 + sigma (t - t0))) (B_M - b - zeta (t - t0))

    Liu et al.'s common model (B_M / k(t) - Z, k = 1 + c (t - t0)) is the case sigma_j = c,
    zeta_j = c z_j; the per-axis model is this form with A = O_p S_p at t0.

    base_temperature_degC : t0. [degC]
    scale_slope_per_degC : sigma. [1/degC]
    offset_slope_per_degC : zeta. [correction unit/degC]
    range_degC : the temperatures of the calibration log (min, max). [degC]
    """

    base_temperature_degC: float
    scale_slope_per_degC: np.ndarray
    offset_slope_per_degC: np.ndarray
    range_degC: tuple

    @classmethod
    def from_result(cls, result, unit: str) -> TemperatureDrift:
        """The drift of a temperature calibration, with zeta in `unit` per degC."""
        model = result.temperature_model
        if result.drifts_in_time or any(model.angle_slope_deg_per_degC):
            raise InputError(
                "the exports carry offsets and scales that drift with temperature, not angles "
                "that drift (--temperature-model full) nor a drift in time (--time-drift); "
                "export a calibration without them"
            )
        if model.kind == "common":
            c = model.k_slope_per_degC
            sigma = np.full(3, c)
            zeta = c * result.model.offsets  # Eq. 9 in Liu et al. (2022): B_b(t) = k B_b0
        else:
            sigma = np.asarray(model.scale_slope_per_degC, dtype=float)
            zeta = np.asarray(model.offset_slope_per_degC, dtype=float)
        return cls(
            model.base_temperature_degC,
            sigma,
            units.from_base(units.to_base(zeta, result.unit), unit),
            tuple(float(v) for v in result.temperature_range),
        )

    @property
    def offsets_only(self) -> bool:
        """Whether only the offsets drift (sigma = 0 exactly): a thermal offset polynomial
        then represents the drift exactly."""
        return not np.any(self.scale_slope_per_degC)

    def in_unit(self, unit: str, new_unit: str) -> TemperatureDrift:
        """The same drift with zeta converted from `unit` to `new_unit` per degC."""
        zeta = units.from_base(units.to_base(self.offset_slope_per_degC, unit), new_unit)
        return dataclasses.replace(self, offset_slope_per_degC=zeta)


@dataclass
class AffineCorrection(Document):
    """B_out = A (B_M - b): an affine correction in one unit, the form every export format carries.

    Attributes
    ----------
    matrix : numpy.ndarray, shape (3, 3)
        A, row-major, in the column-vector convention. [1]
    offsets : numpy.ndarray, shape (3,)
        b. [unit]
    unit : str
        The unit of b, of B_M and of B_out ("raw" for counts).
    field : float or None
        The total field |B_out| the correction maps to. [unit]
    source : dict
        Where it came from (nlpcal version, parameters file, file read, ...).
    sensor_id : int, str or None
        The sensor's device id or name (`nlpcal.validation.sensor_id`).
    orientation : dict or None
        The mounting a file states ({"system", "parameter", "value"[, "name"]}); carried, not
        applied.
    temperature : TemperatureDrift or None
        How the correction drifts with temperature (not in the matrix JSON).
    aux : list of AuxChannel
        Stray fields v_k c_k of auxiliary channels, B_out = A (B_M - b - sum_k v_k c_k)
        (`nlpcal.auxiliary.model`); the autopilots' motor compensation carries one current or
        throttle channel. [unit per channel unit]
    unused : list of str
        Names of the fields of the file read that the correction does not carry.

    Examples
    --------
    >>> import nlpcal
    >>> samples = nlpcal.simulate(300, seed=0)[["bx", "by", "bz"]].to_numpy()
    >>> result = nlpcal.calibrate(samples, method="joint", unit="nT")
    >>> affine = nlpcal.AffineCorrection.from_result(result)
    >>> bool(abs(affine.apply(samples) - result.apply(samples)).max() < 1e-6)  # [nT]
    True
    """

    FORMAT = "nlpcal-affine-correction"
    WHAT = "affine correction (A, b)"
    #: A hand-written file with "A" and "b" but no "format" is read too.
    LEGACY_FORMATS = (("A", None),)

    matrix: np.ndarray
    offsets: np.ndarray
    unit: str = "nT"
    field: float | None = None
    source: dict = dataclasses.field(default_factory=dict)
    sensor_id: int | str | None = None
    orientation: dict | None = None
    temperature: TemperatureDrift | None = None
    unused: list = dataclasses.field(default_factory=list)
    aux: list = dataclasses.field(default_factory=list)

    @classmethod
    def from_result(cls, result, unit: str | None = None) -> AffineCorrection:
        """The correction of a calibration (or of a temperature calibration, with its drift),
        with b and the field in `unit` (default: the unit of the log it was estimated from)."""
        drift = getattr(result, "temperature_model", None)
        calibration = getattr(result, "calibration", result)
        unit = unit or calibration.log_unit
        units.check_compatible(calibration.unit, unit, "the export unit")
        model = calibration.model
        expected = expected_field(calibration)
        return cls(
            matrix=correction_matrix(model),  # A = O_p S_p, Eq. 4
            offsets=units.from_base(units.to_base(model.offsets, calibration.unit), unit),
            unit=unit,
            field=None if expected is None else units.from_base(expected, unit),
            source={"nlpcal_version": __version__, **_provenance(calibration)},
            sensor_id=calibration.sensor_id,
            orientation=calibration.orientation,
            temperature=None if drift is None else TemperatureDrift.from_result(result, unit),
            aux=converted(list(calibration.aux), calibration.unit, unit),
        )

    def checked(self, source: str) -> AffineCorrection:
        """This correction read from `source`, refused (InputError naming the file and the
        value) unless A is a finite invertible 3 x 3 matrix, b three finite numbers and the
        field, when given, a positive finite number; the plausible ranges of the nine
        parameters are those of a parameters file (`CalibrationResult`), applied on import."""
        units.field_factor(self.unit)
        validation.matrix(self.matrix, f"{source}: A", invertible=True)
        offsets = np.asarray(self.offsets, dtype=float)
        if offsets.shape != (3,) or not np.isfinite(offsets).all():
            raise InputError(f"{source}: b must be three finite numbers, got {offsets.tolist()}")
        if self.field is not None:
            validation.number(self.field, f"{source}: the expected field", positive=True)
        return self

    def in_unit(self, unit: str) -> AffineCorrection:
        """The same correction with b and the field in `unit` (A is dimensionless)."""
        units.check_compatible(self.unit, unit, f"unit {unit!r}")

        def convert(value):
            return None if value is None else units.from_base(units.to_base(value, self.unit), unit)

        return dataclasses.replace(
            self,
            offsets=convert(self.offsets),
            unit=unit,
            field=convert(self.field),
            source=dict(self.source),
            temperature=None
            if self.temperature is None
            else self.temperature.in_unit(self.unit, unit),
            aux=converted(self.aux, self.unit, unit),
        )

    def apply(self, samples) -> np.ndarray:
        """B_out = A (B_M - b) for (N, 3) samples in this unit. [unit]"""
        return (np.asarray(samples, dtype=float) - self.offsets) @ self.matrix.T

    def polar(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, P) with A = R P (`polar`)."""
        return polar(self.matrix)

    def rescaled(self, target: float) -> tuple[AffineCorrection, float]:
        """The correction scaled to map onto `target` instead of its own field [unit], and the
        factor applied to A. [1]"""
        target = validation.number(target, "the field", positive=True)
        if self.field is None:
            raise InputError("the correction carries no expected field to rescale")
        factor = target / self.field
        return dataclasses.replace(self, matrix=self.matrix * factor, field=target), factor

    def to_result(
        self, log_unit: str | None = None, unit_source: str = "format", **input_block
    ) -> CalibrationResult:
        """A CalibrationResult holding the nine parameters of this correction (Cholesky route).

        log_unit : the unit of the logs it applies to (default: the base unit, nT or raw).
        unit_source : where the file's unit came from (`read_unit_source`; "format" when the
            format fixes it, as the autopilots' do).
        The rotation Q that the nine parameters do not carry (A = Q O_p S_p) is recorded under
        input.rotation_not_carried; |B1| is the same with or without it. The result's model is
        the smallest form of Eq. 4 that holds the correction exactly (a diagonal A: "diagonal").
        """
        matrix = validation.matrix(self.matrix, "the correction matrix A", invertible=True)
        try:
            params, rotation = from_correction(matrix, units.to_base(self.offsets, self.unit))
        except ValueError as exc:
            raise InputError(str(exc)) from None
        if not all(np.isfinite(list(params.to_dict().values()))):
            raise InputError(
                "the correction matrix A is too far from a calibration (its gains overflow); "
                "check the file's values and --reference-field"
            )
        base = units.base_unit(self.unit)
        angle = rotation_angle_deg(rotation)
        reference = Reference()
        if self.field is not None:
            reference = Reference("constant", field=units.to_base(self.field, self.unit))
        return CalibrationResult(
            sensor_id=self.sensor_id,
            orientation=self.orientation,
            parameters=params.to_dict(),
            statistics=[],
            method="imported",
            reference=reference,
            # the smallest form that holds the correction exactly: a restricted model exported
            # by nlpcal reads back as that model
            model_name=smallest_model(params.to_dict(), reference.scale_known),
            unit=base,
            aux=converted(self.aux, self.unit, base),
            unit_source=unit_source,
            input=Provenance.from_dict(
                {
                    **input_block,
                    "log_unit": log_unit or base,
                    "rotation_not_carried": {"angle_deg": angle, "matrix": rotation.tolist()},
                }
            ),
        )

    # -- the matrix JSON format --------------------------------------------------------------

    def body(self) -> dict:
        r, p = self.polar()
        return {
            "model": MODEL,
            "A": self.matrix.tolist(),
            "b": list(map(float, self.offsets)),
            "unit": self.unit,
            "A_unit": "1",
            "field": self.field,
            "symmetric": {
                "about": "A = R P: P symmetric (what ArduPilot and PX4 apply), R a rotation",
                "P": p.tolist(),
                "R": r.tolist(),
                "rotation_deg": rotation_angle_deg(r),
            },
            "source": dict(self.source),
            "nlpcal_version": __version__,
            **({} if self.sensor_id is None else {"sensor_id": self.sensor_id}),
            **({} if self.orientation is None else {"orientation": dict(self.orientation)}),
        }

    @classmethod
    def from_body(cls, reader: DocumentReader) -> AffineCorrection:
        matrix = reader.array("A", (3, 3))
        validation.matrix(matrix, f"{reader.source}: A", invertible=True)
        unit = reader.string("unit", "nT", options=list(units.FIELD_UNITS_NT))
        return cls(
            matrix=matrix,
            offsets=reader.array("b", (3,)),
            unit=unit,
            field=reader.number("field", None, positive=True),
            source=reader.mapping("source", {}),
            sensor_id=None
            if not reader.has("sensor_id")
            else validation.sensor_id(reader.raw("sensor_id"), f"{reader.source}: sensor_id"),
            orientation=read_orientation(reader),
        )


def _provenance(result: CalibrationResult) -> dict:
    block = {
        "method": result.method,
        "parameters_unit": result.unit,
        "unit_source": result.unit_source,
        "scale_fixed_by": result.scale_fixed_by(),
    }
    if result.input.get("log"):
        block["log"] = result.input["log"]
    return block


def read_unit_source(given, stated) -> str:
    """Where the unit of a file read came from (`nlpcal.units.UNIT_SOURCES`): the unit `given`
    (--unit) is "option", one the file `stated` "format", nlpcal's default nT "assumed"."""
    return "option" if given else "format" if stated else "assumed"


@dataclass
class Export:
    """What an export writes: the text, the notes for the user, the rotation not carried and
    what of the calibration the format has no place for (`dropped`, phrases)."""

    text: str
    notes: list = dataclasses.field(default_factory=list)
    rotation_deg: float | None = None
    dropped: list = dataclasses.field(default_factory=list)


def number_text(value: float) -> str:
    """A float written so that it reads back to the same double (shortest round trip)."""
    return repr(float(value))
