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
from ..models.zhou2010 import (
    MODELS,
    PARAMETER_NAMES,
    PARAMETER_UNITS,
    Zhou2010Parameters,
    correct,
    estimated_parameters,
    is_of_model,
    tied_parameters,
)
from ..results import Document, DocumentReader
from ..statistics import STD_DDOF, format_table
from ..verdict import Verdict, judge
from ..version import __version__

#: Plausible ranges of the parameters read from a document: scale errors keep every gain within
#: (0.1, 10); angles within +-89 deg; offsets within 1e9 of the field unit (1 T in nT). [1], [deg]
SCALE_RANGE = (-0.9, 9.0)
OFFSET_LIMIT = 1e9
#: Largest total field a document may name: that of the offsets (1 T in nT). [field unit]
FIELD_LIMIT = OFFSET_LIMIT
#: The kinds of reference a calibration has: none (Eq. 8), a constant field or a series.
REFERENCE_MODES = ("none", "constant", "series")
#: The systems whose orientation parameters a result can carry (`read_orientation`).
ORIENTATION_SYSTEMS = ("ardupilot", "px4")


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


def read_reference(reader: DocumentReader) -> dict:
    """The "reference" block: its mode, and the field (or the mean of a series) as a positive
    number within the plausible range of a field (FIELD_LIMIT). [result unit]"""
    block = reader.reader("reference", None)
    if block is None:
        return {"mode": "none"}
    block.string("mode", "none", options=REFERENCE_MODES)
    for name in ("field", "field_mean"):
        block.number(name, None, positive=True, maximum=FIELD_LIMIT)
    return dict(block.document)


def read_robust(reader: DocumentReader) -> dict:
    """The "robust" block: the loss, its scale and the residuals' spread, checked."""
    block = reader.reader("robust", None)
    if block is None:
        return {}
    block.string("loss", "l2", options=("l2", "huber", "cauchy"))
    for name in ("scale", "residual_std", "residual_robust_std"):
        block.number(name, None, minimum=0.0)
    return dict(block.document)


def read_covariance(reader: DocumentReader, estimated: list) -> np.ndarray | None:
    """The optional "covariance" block of the `estimated` parameters: symmetric, finite,
    non-negative diagonal."""
    if not reader.has("covariance"):
        return None
    block = reader.reader("covariance")
    if block.strings("parameters") != list(estimated):
        raise InputError(
            f"{reader.source}: covariance.parameters must be {', '.join(estimated)} (the "
            f"parameters its model estimates)"
        )
    size = len(estimated)
    matrix = block.array("matrix", (size, size))
    if not np.allclose(matrix, matrix.T, rtol=1e-9, atol=0.0) or (np.diag(matrix) < 0).any():
        raise InputError(
            f"{reader.source}: covariance.matrix must be symmetric with a non-negative diagonal"
        )
    return matrix


def read_orientation(reader: DocumentReader) -> dict | None:
    """The optional "orientation" block: the system and parameter that state the mounting, its
    value (an integer of the system's rotation list; PX4's -1 is "the board's") and its name."""
    block = reader.reader("orientation", None)
    if block is None:
        return None
    block.string("system", options=ORIENTATION_SYSTEMS)
    block.string("parameter")
    block.integer("value", minimum=-1)
    block.string("name", None)
    return dict(block.document)


def check_model(parameters: dict, model_name: str, scale_known: bool, source: str) -> None:
    """InputError unless the parameters are of the form `model_name`: the ones it does not
    estimate at zero, the ones it ties equal."""
    if is_of_model(parameters, model_name, scale_known):
        return
    estimated = estimated_parameters(model_name, scale_known)
    moved = [n for n in PARAMETER_NAMES if n not in estimated and parameters[n] != 0.0]
    given = ", ".join(f"{n} = {parameters[n]:g}" for n in moved)
    raise InputError(
        f"{source}: model {model_name} fixes {', '.join(moved)} at 0, but the parameters give "
        f"{given}"
        if moved
        else f"{source}: model {model_name} estimates one common value for "
        f"{', '.join(tied_parameters(model_name, scale_known)[0])}, but the parameters differ"
    )


@dataclass
class CalibrationResult(Document):
    """A calibration: the nine parameters of Eq. 4 in [1], Table 1 rows and how they were found.

    Returned by `calibrate`; `apply` corrects new samples, `to_json`, `save`, `from_json` and
    `load` write and read the versioned JSON document (`params.json`).

    Attributes
    ----------
    parameters : dict
        z_x, z_y, z_z [unit], s_x, s_y, s_z [1], alpha_deg, beta_deg, gamma_deg [deg].
    statistics : list of dict
        Table 1 rows (label, max, min, mean, std, range [unit], objective [unit^2], iterations,
        wall_s [s]); the first is the measured |B_M|.
    method : str
        "staged" or "joint".
    reference : dict
        The reference field used: mode "none", "constant" or "series", and its values.
    gauge : dict or None
        Without a reference field, the constraint that fixes the overall scale.
    solver : dict
        The solver's status, iterations and stop reason.
    unit : str
        The unit of offsets and rows: "nT", or "raw" for counts.
    unit_source : str or None
        Where the unit of the log came from ("option", "names", "format" or "assumed"); None in a
        document written before results recorded it, which is treated as "assumed".
    standard_errors : dict or None
        Per estimated parameter, in its unit; None when the data leave a direction free.
        Parameters the model does not estimate have none (they are fixed, not estimated).
    covariance : numpy.ndarray or None
        (k, k) covariance of the k estimated parameters in the order of `parameters`, in their
        units (offsets [unit^2], scale errors [1], angles [deg^2]); None without standard errors.
    identifiability : dict
        What the attitude coverage determines, and the residuals' autocorrelation.
    warnings : list of str
        What looks wrong with the data or the result, each a sentence.
    notes : list of str
        How the problem was posed (the gauge without a reference field), each a sentence.
    n_samples : int
        Samples the calibration used.
    version : str
        The nlpcal version that made it ("nlpcal_version" in the document).
    input : dict
        Where the samples came from (file, columns, the unit of the file).
    robust : dict
        The loss and its scale, the samples it down-weighted, and the spread of the residuals.
        [unit]
    model_name : str
        The form of Eq. 4 estimated ("model" in the document): the parameters it does not estimate
        are fixed at zero (`fixed_parameters`).
    model_selection : dict or None
        How model "auto" chose it (the reason, the richer forms rejected), or None.
    sensor_id : int, str or None
        The sensor calibrated: an autopilot device id or a name (`--sensor-id`), or None
        ("sensor_id" in the document, written when given).
    orientation : dict or None
        How the sensor is mounted, as the file a calibration was imported from states it
        ({"system", "parameter", "value"[, "name"]}, e.g. ArduPilot's COMPASS_ORIENT); carried,
        not applied ("orientation" in the document, written when given).

    References
    ----------
    [1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> import nlpcal
    >>> samples = nlpcal.simulate(500, seed=3)[["bx", "by", "bz"]].to_numpy()
    >>> result = nlpcal.calibrate(samples, method="joint")
    >>> sorted(result.parameters)[:3]
    ['alpha_deg', 'beta_deg', 'gamma_deg']
    >>> again = nlpcal.CalibrationResult.from_json(result.to_json())
    >>> again.parameters == result.parameters
    True
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
    notes: list = field(default_factory=list)
    n_samples: int = 0
    version: str = __version__
    input: dict = field(default_factory=dict)
    robust: dict = field(default_factory=dict)
    model_name: str = "full"
    model_selection: dict | None = None
    sensor_id: int | str | None = None
    orientation: dict | None = None

    @property
    def estimated_parameters(self) -> list:
        """The parameters the model estimates, in PARAMETER_NAMES order."""
        return estimated_parameters(self.model_name, self.reference.get("mode", "none") != "none")

    @property
    def fixed_parameters(self) -> list:
        """The parameters the model does not estimate: held at zero, without standard errors."""
        return [name for name in PARAMETER_NAMES if name not in self.estimated_parameters]

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

    def table(self, most: int | None = None) -> str:
        """Table 1 rows as text; with `most`, the first, a few and the last of them."""
        return format_table(self.statistics, self.unit, extra=("iterations",), most=most)

    @property
    def verdict(self) -> Verdict:
        """The result's verdict (`nlpcal.verdict`): failed when the solve did not converge or
        the data do not determine some parameters (a result written with an allow flag),
        poorly determined when some standard errors exceed their limits, else ok or warnings."""
        block = self.identifiability or {}
        failures = []
        if self.solver.get("success") is False:
            failures.append(f"the solver failed ({self.solver.get('status')})")
        elif self.solver.get("converged") is False:
            failures.append(
                f"not converged: the {self.method} solve stopped on "
                f"{self.solver.get('stop_reason')}, away from the optimum"
            )
        if block.get("not_identifiable"):
            failures.append(f"the data do not determine {', '.join(block['not_identifiable'])}")
        poor = block.get("poorly_determined") or []
        return judge(
            failures,
            [f"{', '.join(poor)}: standard errors above their limits"] if poor else [],
            self.warnings,
        )

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
            "model": self.model_name,
            "fixed_parameters": self.fixed_parameters,
            "standard_errors": self.standard_errors,
            "identifiability": dict(self.identifiability),
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "n_samples": self.n_samples,
            "nlpcal_version": self.version,
        }
        tied = tied_parameters(self.model_name, self.reference.get("mode", "none") != "none")
        if tied:
            document["tied_parameters"] = tied
        if self.model_selection:
            document["model_selection"] = dict(self.model_selection)
        if self.covariance is not None:
            unit_of = dict(zip(PARAMETER_NAMES, PARAMETER_UNITS))
            document["covariance"] = {
                "parameters": self.estimated_parameters,
                "units": [
                    self.unit if unit_of[n] == "field" else unit_of[n]
                    for n in self.estimated_parameters
                ],
                "matrix": np.asarray(self.covariance).tolist(),
            }
        if self.input:
            document["input"] = dict(self.input)
        if self.robust:
            document["robust"] = dict(self.robust)
        if self.sensor_id is not None:
            document["sensor_id"] = self.sensor_id
        if self.orientation is not None:
            document["orientation"] = dict(self.orientation)
        return document

    @classmethod
    def fields_from(cls, reader: DocumentReader) -> dict:
        """The constructor arguments stored in a document (shared with the temperature kind)."""
        errors = reader.reader("standard_errors") if reader.has("standard_errors") else None
        model_name = reader.string("model", "full", options=list(MODELS))
        reference = read_reference(reader)
        scale_known = reference.get("mode", "none") != "none"
        estimated = estimated_parameters(model_name, scale_known)
        parameters = read_parameters(reader).to_dict()
        check_model(parameters, model_name, scale_known, reader.source)
        return {
            "parameters": parameters,
            "statistics": reader.items("statistics", []),
            "method": reader.string("method", "staged"),
            "reference": reference,
            "gauge": reader.mapping("gauge", None),
            "solver": reader.mapping("solver", {}),
            "unit": reader.string("unit", "nT", options=list(units.FIELD_UNITS_NT)),
            "unit_source": reader.string("unit_source", None, options=units.UNIT_SOURCES),
            "standard_errors": None
            if errors is None
            else {
                name: errors.number(name, positive=False, minimum=0.0)
                for name in estimated
                if errors.has(name)
            },
            "covariance": read_covariance(reader, estimated),
            "identifiability": reader.mapping("identifiability", {}),
            "warnings": reader.strings("warnings", []),
            "notes": reader.strings("notes", []),
            "n_samples": reader.integer("n_samples", 0),
            "version": reader.string("nlpcal_version", "unknown"),
            "input": reader.provenance(
                strings=("log", "temperature_column"),
                lists=("columns",),
                units=(("log_unit", units.FIELD_UNITS_NT), ("unit_source", units.UNIT_SOURCES)),
            ),
            "robust": read_robust(reader),
            "model_name": model_name,
            "model_selection": reader.mapping("model_selection", None),
            "sensor_id": None
            if not reader.has("sensor_id")
            else validation.sensor_id(reader.raw("sensor_id"), f"{reader.source}: sensor_id"),
            "orientation": read_orientation(reader),
        }

    @classmethod
    def from_body(cls, reader: DocumentReader) -> CalibrationResult:
        return cls(**cls.fields_from(reader))
