"""`CalibrationResult`: the nine parameters of Eq. 4, how they were found and what they are worth.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import inference, units, validation
from ..errors import InputError
from ..models.zhou2010 import PARAMETER_NAMES, PARAMETER_UNITS, Zhou2010Parameters, correct
from ..results import Document, DocumentReader
from ..statistics import STD_DDOF, format_table
from ..version import __version__

#: Plausible ranges of the parameters read from a document: scale errors keep every gain within
#: (0.1, 10); angles within +-89 deg; offsets within 1e9 of the field unit (1 T in nT). [1], [deg]
SCALE_RANGE = (-0.9, 9.0)
OFFSET_LIMIT = 1e9


def read_parameters(reader: DocumentReader, key: str = "parameters") -> Zhou2010Parameters:
    """The nine parameters of a document, each a finite number within its plausible range."""
    values = reader.reader(key)
    limits = {
        **{name: (-OFFSET_LIMIT, OFFSET_LIMIT) for name in PARAMETER_NAMES[:3]},
        **{name: SCALE_RANGE for name in PARAMETER_NAMES[3:6]},
        **{
            name: (-validation.MAX_ANGLE_DEG, validation.MAX_ANGLE_DEG)
            for name in PARAMETER_NAMES[6:]
        },
    }
    return Zhou2010Parameters(
        **{
            name: values.number(name, minimum=low, maximum=high)
            for name, (low, high) in limits.items()
        }
    )


def read_robust(reader: DocumentReader) -> dict:
    """The "robust" block: the loss, its scale and the residuals' spread, checked."""
    block = reader.reader("robust", None)
    if block is None:
        return {}
    block.string("loss", "l2", options=("l2", "huber", "cauchy"))
    for name in ("scale", "residual_std", "residual_robust_std"):
        block.number(name, None, minimum=0.0)
    return dict(block.document)


def read_covariance(reader: DocumentReader) -> np.ndarray | None:
    """The optional "covariance" block: 9 x 9, symmetric, finite, non-negative diagonal."""
    if not reader.has("covariance"):
        return None
    block = reader.reader("covariance")
    if block.strings("parameters") != list(PARAMETER_NAMES):
        raise InputError(
            f"{reader.source}: covariance.parameters must be {', '.join(PARAMETER_NAMES)}"
        )
    matrix = block.array("matrix", (9, 9))
    if not np.allclose(matrix, matrix.T, rtol=1e-9, atol=0.0) or (np.diag(matrix) < 0).any():
        raise InputError(
            f"{reader.source}: covariance.matrix must be symmetric with a non-negative diagonal"
        )
    return matrix


@dataclass
class CalibrationResult(Document):
    """A calibration: the nine parameters of Eq. 4 in [1], Table 1 rows and how they were found.

    parameters : z_x, z_y, z_z [unit], s_x, s_y, s_z [1], alpha_deg, beta_deg, gamma_deg [deg].
    statistics : Table 1 rows (label, max, min, mean, std, range [unit], objective [unit^2],
        iterations, wall_s [s]); the first is the measured |B_M|.
    unit : the unit of offsets and rows: "nT", or "raw" for counts.
    unit_source : where the unit of the log came from (`nlpcal.units.UNIT_SOURCES`: "option",
        "names", "format" or "assumed"); None in a document written before results recorded it,
        which is treated as "assumed" (`scale_fixed_by`).
    standard_errors : per parameter, in its unit; None when the data leave a direction free.
    covariance : (9, 9) covariance of the parameters in PARAMETER_NAMES order, in their units
        (offsets [unit], scale errors [1], angles [deg]); None without standard errors.
    identifiability : what the attitude coverage determines (`nlpcal.calibration.diagnostics`).
    input : where the samples came from (file, columns, the unit of the file).
    robust : the loss and its scale, the samples it down-weighted, and the spread of the
        residuals (their standard deviation and robust standard deviation). [unit]
    """

    FORMAT = "nlpcal-calibration"
    LEGACY_FORMATS = (("parameters", None),)
    WHAT = "nlpcal parameters file"
    #: A temperature calibration holds the nine parameters at its base temperature too; read as a
    #: CalibrationResult, it gives the system correction at t0.
    ALSO_READS = ("nlpcal-temperature-calibration",)

    @classmethod
    def accepts(cls, document: dict) -> bool:
        return document.get("format") in cls.ALSO_READS or super().accepts(document)

    parameters: dict
    statistics: list
    method: str = "staged"
    reference: dict = field(default_factory=lambda: {"mode": "none"})
    gauge: dict | None = None
    solver: dict = field(default_factory=dict)
    unit: str = "nT"
    unit_source: str | None = None
    standard_errors: dict | None = None
    covariance: np.ndarray | None = None
    identifiability: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    n_samples: int = 0
    version: str = __version__
    input: dict = field(default_factory=dict)
    robust: dict = field(default_factory=dict)

    @property
    def model(self) -> Zhou2010Parameters:
        return Zhou2010Parameters.from_dict(self.parameters)

    @property
    def log_unit(self) -> str:
        """The unit of the log the parameters were estimated from (the result's unit if unknown)."""
        recorded = self.input.get("log_unit")
        return recorded if recorded in units.FIELD_UNITS_NT else self.unit

    def scale_fixed_by(self) -> str | None:
        """What fixes the physical scale of the result, or None when nothing does.

        "the unit" when the unit of the log was given, fixed by its format or carried by its
        column names; "the reference field" when the unit was only assumed but a reference
        field fitted |B1| to a magnitude in it. A result in raw counts, or whose unit was only
        assumed (or not recorded: a document older than `unit_source`) without a reference, has
        no physical scale: its offsets may be off by any power of ten.
        """
        if self.unit == "raw":
            return None
        if self.unit_source in units.FIXING_SOURCES:
            return "the unit"
        if (self.reference or {}).get("mode", "none") != "none":
            return "the reference field"
        return None

    def apply(self, samples, unit: str | None = None) -> np.ndarray:
        """Corrected field B1 = O_p S_p (B_M - Z_p), Eq. 4 in [1].

        samples : (N, 3) raw output, in `unit` (default: the unit of the calibration).
        Returns (N, 3) corrected field in the same unit as `samples`.
        """
        samples = validation.vectors(samples)
        unit = unit or self.unit
        units.check_compatible(self.unit, unit, "the samples")
        corrected = correct(units.to_base(samples, unit), self.model)
        return units.from_base(corrected, unit)

    def correlation(self) -> np.ndarray | None:
        """(9, 9) correlation matrix of the parameters, or None without a covariance. [1]"""
        return inference.correlation(self.covariance)

    def table(self) -> str:
        return format_table(self.statistics, self.unit, extra=("iterations",))

    def body(self) -> dict:
        document = {
            "parameters": dict(self.parameters),
            "statistics": list(self.statistics),
            "std_ddof": STD_DDOF,
            "method": self.method,
            "reference": dict(self.reference),
            "gauge": self.gauge,
            "solver": dict(self.solver),
            "unit": self.unit,
            "unit_source": self.unit_source,
            "standard_errors": self.standard_errors,
            "identifiability": dict(self.identifiability),
            "warnings": list(self.warnings),
            "n_samples": self.n_samples,
            "nlpcal_version": self.version,
        }
        if self.covariance is not None:
            document["covariance"] = {
                "parameters": list(PARAMETER_NAMES),
                "units": [self.unit if u == "field" else u for u in PARAMETER_UNITS],
                "matrix": np.asarray(self.covariance).tolist(),
            }
        if self.input:
            document["input"] = dict(self.input)
        if self.robust:
            document["robust"] = dict(self.robust)
        return document

    @classmethod
    def fields_from(cls, reader: DocumentReader) -> dict:
        """The constructor arguments stored in a document (shared with the temperature kind)."""
        errors = reader.reader("standard_errors") if reader.has("standard_errors") else None
        return {
            "parameters": read_parameters(reader).to_dict(),
            "statistics": reader.items("statistics", []),
            "method": reader.string("method", "staged"),
            "reference": reader.mapping("reference", {"mode": "none"}),
            "gauge": reader.mapping("gauge", None),
            "solver": reader.mapping("solver", {}),
            "unit": reader.string("unit", "nT", options=list(units.FIELD_UNITS_NT)),
            "unit_source": reader.string("unit_source", None, options=units.UNIT_SOURCES),
            "standard_errors": None
            if errors is None
            else {
                name: errors.number(name, positive=False, minimum=0.0)
                for name in PARAMETER_NAMES
                if errors.has(name)
            },
            "covariance": read_covariance(reader),
            "identifiability": reader.mapping("identifiability", {}),
            "warnings": reader.strings("warnings", []),
            "n_samples": reader.integer("n_samples", 0),
            "version": reader.string("nlpcal_version", "unknown"),
            "input": reader.provenance(
                strings=("log", "temperature_column"),
                lists=("columns",),
                units=(("log_unit", units.FIELD_UNITS_NT), ("unit_source", units.UNIT_SOURCES)),
            ),
            "robust": read_robust(reader),
        }

    @classmethod
    def from_body(cls, reader: DocumentReader) -> CalibrationResult:
        return cls(**cls.fields_from(reader))
