"""The result of an e-compass calibration: each sensor's correction and how it was found.

References
----------
[1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..models import qiu2017 as model
from ..results import Document, DocumentReader
from ..verdict import Verdict, judge

ESTIMATED_SCALE = "estimated: unknown field, scaled so that det(correction_matrix) = 1"
GRAVITY_SCALE = "1 g by definition (sensitivity relative to the local gravity)"


@dataclass
class SensorCalibration:
    """One sensor's correction v = K (reading - bias), with the model's parameters.

    `correction` K is the inverse of the sensor matrix M = diag(1 + s) E of Eq. 1 in [1];
    `bias` is in `unit`; `magnitude` is the length of v the fit scales to (1 g for the
    accelerometer; the field for the magnetometer, given or estimated).
    """

    sensor: str
    unit: str
    correction: np.ndarray
    bias: np.ndarray
    magnitude: float
    magnitude_source: str
    frame: str
    compensation: dict | None = None  # per turn axis: the two compensation angles [rad]
    compensation_std: dict | None = None  # their standard deviations [rad]
    quality: dict = field(default_factory=dict)

    @property
    def sensor_matrix(self) -> np.ndarray:
        return np.linalg.inv(self.correction)

    @property
    def mounting_angles(self) -> np.ndarray:
        """The six angles of Eq. 3, ANGLE_NAMES order. [rad]"""
        return model.decompose_sensor_matrix(self.sensor_matrix)[0]

    @property
    def sensitivity(self) -> np.ndarray:
        """Sensitivity errors s. [1]"""
        return model.decompose_sensor_matrix(self.sensor_matrix)[1]

    def apply(self, readings) -> np.ndarray:
        """Calibrated vectors (N, 3) from raw readings (N, 3) in `unit`. Eq. 2 in [1]."""
        readings = np.atleast_2d(np.asarray(readings, dtype=float))
        return (readings - self.bias) @ self.correction.T  # Eq. 2

    def to_dict(self) -> dict:
        angles = self.mounting_angles
        out = {
            "unit": self.unit,
            "frame": self.frame,
            "mounting_deg": {n: float(np.degrees(a)) for n, a in zip(model.ANGLE_NAMES, angles)},
            "sensitivity": [float(v) for v in self.sensitivity],
            "bias": [float(v) for v in self.bias],
            "magnitude": float(self.magnitude),
            "magnitude_source": self.magnitude_source,
            "correction_matrix": [[float(v) for v in row] for row in self.correction],
            "sensor_matrix": [[float(v) for v in row] for row in self.sensor_matrix],
        }
        if self.compensation is not None and self.compensation_std is not None:
            out["compensation_deg"] = {
                axis: {
                    f"toward_{other}": float(np.degrees(value)) for other, value in angles_.items()
                }
                for axis, angles_ in self.compensation.items()
            }
            out["compensation_std_deg"] = {
                axis: {
                    f"toward_{other}": float(np.degrees(value)) for other, value in angles_.items()
                }
                for axis, angles_ in self.compensation_std.items()
            }
        out["quality"] = self.quality
        return out

    @classmethod
    def read(cls, sensor: str, reader: DocumentReader) -> SensorCalibration:
        """One sensor's entry of a compass document, every field checked (the correction must be
        invertible: a singular one would give the same heading on every row)."""
        correction = reader.array("correction_matrix", (3, 3))
        if not np.linalg.cond(correction) < 1e12:
            raise InputError(
                f"{reader.source}: {sensor}.correction_matrix is singular; recreate "
                f"it with 'nlpcal compass calibrate'"
            )
        return cls(
            sensor=sensor,
            unit=reader.string("unit"),
            correction=correction,
            bias=reader.array("bias", (3,)),
            magnitude=reader.number("magnitude", float("nan"), positive=True),
            magnitude_source=reader.string("magnitude_source", ""),
            frame=reader.string("frame", ""),
            quality=reader.mapping("quality", {}),
        )


@dataclass
class CompassCalibration(Document):
    """Both sensors' corrections, how they were found, and what could not be identified.

    Attributes
    ----------
    mode : str
        "turns" or "free-rotation".
    magnetometer, accelerometer : SensorCalibration
        Each sensor's correction: mounting angles [deg], bias [nT or g], sensitivity [1].
    identifiability : str
        What the mode identifies and what it does not, a sentence.
    alignment : dict or None
        Free-rotation mode: the magnetometer-to-accelerometer rotation.
    warnings : list of str
        What looks wrong, each a sentence.
    input : dict
        Where the readings came from.

    Examples
    --------
    >>> import nlpcal
    >>> from nlpcal.simulation.qiu2017 import replica
    >>> turns = replica(seed=0, n=10)["turns"]
    >>> mag = turns[["mx_nT", "my_nT", "mz_nT"]].to_numpy()
    >>> acc = turns[["ax_g", "ay_g", "az_g"]].to_numpy()
    >>> calibration = nlpcal.calibrate_turns(mag, acc, turns["turn"].tolist())
    >>> field, force = calibration.apply(mag, acc)  # calibrated [nT] and [g]
    >>> field.shape
    (48, 3)
    """

    FORMAT = "nlpcal-compass"
    WHAT = "nlpcal compass calibration"

    mode: str  # "turns" or "free-rotation"
    magnetometer: SensorCalibration
    accelerometer: SensorCalibration
    identifiability: str
    alignment: dict | None = None  # free-rotation mode: magnetometer-to-accelerometer rotation
    warnings: list = field(default_factory=list)
    input: dict = field(default_factory=dict)

    @property
    def verdict(self) -> Verdict:
        """ok, or warnings (the fits that fail raise instead of returning a result)."""
        return judge(warnings=self.warnings)

    def apply(self, mag, acc) -> tuple:
        """Calibrated (field [nT], specific force [g]) from raw readings in nT and g."""
        return self.magnetometer.apply(mag), self.accelerometer.apply(acc)

    def body(self) -> dict:
        doc = {
            "version": self.FORMAT_VERSION,  # the key of nlpcal 0.1, kept beside format_version
            "mode": self.mode,
            "conventions": {
                "world": "NED (x magnetic north, y east, z down)",
                "body": "housing: x forward, y right, z down",
                "attitude": "C = R_x(roll) R_y(pitch) R_z(heading); v_body = C v_world (Eq. 9)",
                "accelerometer": "specific force: at rest the body components of (0, 0, -1) g",
                "model": "reading = diag(1 + s) E v_body + bias; calibrated v = K (reading - bias)",
                "mounting_angles": "row x of E ~ (1, tan alpha_xy, tan alpha_xz), row y ~ "
                "(tan beta_yx, 1, tan beta_yz), row z ~ (tan gamma_zx, "
                "tan gamma_zy, 1) (Eq. 3)",
            },
            "identifiability": self.identifiability,
            "magnetometer": self.magnetometer.to_dict(),
            "accelerometer": self.accelerometer.to_dict(),
        }
        if self.alignment is not None:
            doc["alignment"] = self.alignment
        doc["warnings"] = list(self.warnings)
        doc["input"] = self.input
        return doc

    @classmethod
    def from_body(cls, reader: DocumentReader) -> CompassCalibration:
        version = reader.integer("version", cls.FORMAT_VERSION)
        if version != cls.FORMAT_VERSION:
            raise InputError(
                f"{reader.source}: compass calibration version {version!r} is not "
                f"supported (expected {cls.FORMAT_VERSION})"
            )
        return cls(
            mode=reader.string("mode", ""),
            magnetometer=SensorCalibration.read("magnetometer", reader.reader("magnetometer")),
            accelerometer=SensorCalibration.read("accelerometer", reader.reader("accelerometer")),
            identifiability=reader.string("identifiability", ""),
            alignment=reader.mapping("alignment", None),
            warnings=reader.strings("warnings", []),
            input=reader.provenance(
                strings=("file", "turn_column"),
                lists=("mag_columns", "acc_columns"),
                units=(
                    ("mag_unit", ("nT", "uT", "mT", "mG", "G", "T")),
                    ("acc_unit", ("g", "mg", "m/s2")),
                ),
            ),
        )
