"""`CalibrationResult`: the nine parameters of Eq. 4, how they were found and what they are worth.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .. import inference, units, validation
from ..auxiliary.model import read_aux, stray_field
from ..errors import InputError
from ..lag import read_lag
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
from ..nlp.solver import FINISHERS, NLPCAL_STATUSES
from ..results import Document, DocumentReader, Provenance, Record, TableRow
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


@dataclass
class Reference:
    """The reference field a calibration was fitted to: none (Eq. 8 in [1], the scale fixed by
    the gauge), a constant field, or a series of one value per sample.

    mode : "none", "constant" or "series" (REFERENCE_MODES).
    field : the constant field. [unit]  field_mean : the mean of a series. [unit]
    column : the log's column the series came from. model : the geomagnetic model that gave it.
    """

    mode: str = "none"
    field: float | None = None
    field_mean: float | None = None
    column: str | None = None
    model: dict | None = None

    @property
    def scale_known(self) -> bool:
        """Whether the reference fixes the physical scale (any mode but "none")."""
        return self.mode != "none"

    @property
    def level(self) -> float | None:
        """The field the calibration maps to: the constant field or the mean of the series."""
        return self.field if self.field is not None else self.field_mean

    def to_dict(self) -> dict:
        return _present(**asdict(self))

    @classmethod
    def read(cls, reader: DocumentReader) -> Reference:
        """The "reference" block of a document: its mode, and the field (or the mean of a
        series) as a positive number within the plausible range of a field (FIELD_LIMIT)."""
        block = reader.reader("reference", None)
        if block is None:
            return cls()
        return cls(
            mode=block.string("mode", "none", options=REFERENCE_MODES),
            field=block.number("field", None, positive=True, maximum=FIELD_LIMIT),
            field_mean=block.number("field_mean", None, positive=True, maximum=FIELD_LIMIT),
            column=block.string("column", None),
            model=block.mapping("model", None),
        )


@dataclass(eq=False, repr=False)
class Identifiability(Record):
    """What the data determine of a calibration (the "identifiability" block of its document):
    the parameters left undetermined or poorly determined, why, and the checks behind it. A
    field that is None is absent from the document.

    Attributes
    ----------
    not_identifiable : list of str
        The parameters the data do not determine: along a direction |B1| does not change, a
        standard error above its undetermined limit, or blind to a plane the samples lie in.
    undetermined : list of str
        Those with a standard error (of independent samples) above `undetermined_limits`.
    poorly_determined : list of str
        Those with a standard error above `poorly_determined_limits`.
    weakest_combination : list of str
        The parameters of the weakest direction of the information.
    hessian_eigenvalues_scaled : list of float
        The eigenvalues of the objective's Hessian in the scaled variables, over N / 2. [unit^2]
    covariance_form : str
        "sandwich" or "gauss-newton".
    poorly_determined_limits, undetermined_limits : dict
        Per estimated parameter, the standard errors beyond which it is poorly determined or
        undetermined. [parameter units]
    score_dependence : dict
        How the standard errors follow the dependence of the samples' scores.
    second_order_bias : dict
        The estimate's bias in the sensor noise, and whether it was corrected.
    flatness : dict
        Whether the samples lie (nearly) in one plane, and the parameters it blinds.
    coverage : dict
        The direction bins the field visits (of 26).
    exact_optimum_shift_in_standard_errors : float
        The estimated distance to the exact optimum (an inexact expansion, a robust loss).
    joint_gap : dict
        A staged result against the joint optimum of the same objective.
    standard_errors_at_joint_optimum : dict
        A staged result away from that optimum: the standard errors there.
    extra : dict
        Keys of other kinds (a temperature calibration's Gauss-Newton eigenvalues).

    Examples
    --------
    >>> from nlpcal.calibration.result import Identifiability
    >>> block = Identifiability(not_identifiable=["z_z"], poorly_determined=[])
    >>> block.to_dict()
    {'not_identifiable': ['z_z'], 'poorly_determined': []}
    """

    not_identifiable: list[str] | None = None
    undetermined: list[str] | None = None
    poorly_determined: list[str] | None = None
    weakest_combination: list[str] | None = None
    hessian_eigenvalues_scaled: list[float] | None = None
    covariance_form: str | None = None
    poorly_determined_limits: dict[str, float] | None = None
    undetermined_limits: dict[str, float] | None = None
    score_dependence: dict | None = None
    second_order_bias: dict | None = None
    flatness: dict | None = None
    coverage: dict | None = None
    exact_optimum_shift_in_standard_errors: float | None = None
    joint_gap: dict | None = None
    standard_errors_at_joint_optimum: dict[str, float] | None = None
    extra: dict = field(default_factory=dict)

    @property
    def planar(self) -> bool:
        """Whether the samples lie (nearly) in one plane."""
        return bool((self.flatness or {}).get("planar"))

    @classmethod
    def read(cls, reader: DocumentReader) -> Identifiability:
        """The "identifiability" block of a document, its lists of parameters checked."""
        block = reader.reader("identifiability", None)
        if block is None:
            return cls()
        for name in ("not_identifiable", "undetermined", "poorly_determined"):
            block.strings(name, None)
        return cls.from_dict(block.document)


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


@dataclass
class BlockSolve:
    """One block solve of a calibration (a stage of a staged cycle, or the joint solve): what
    finished it and how.

    finished_by : "ipopt", "newton" (a Newton step verified to land within the resolution of
        the data) or "start" (`nlpcal.nlp.solver.FINISHERS`).
    iterations : IPOPT's iterations (0 when IPOPT did not run).
    ipopt_status : IPOPT's return status, or None when IPOPT did not run.
    nlpcal_status : nlpcal's own status when its checks decided the solve
        (`nlpcal.nlp.solver.NLPCAL_STATUSES`), else None.
    objective : the objective where the solve ended. [unit^2]
    convergence_rate, predicted_cycles : on the last stage of a staged cycle stopped on its
        prediction (`nlpcal.calibration.staged.cycles_to_converge`).
    """

    cycle: int
    stage: str
    finished_by: str
    iterations: int
    objective: float | None = None
    ipopt_status: str | None = None
    nlpcal_status: str | None = None
    convergence_rate: float | None = None
    predicted_cycles: int | None = None

    @classmethod
    def of(cls, step, cycle: int, stage: str) -> BlockSolve:
        """The record of a `nlpcal.nlp.steps.Step`."""
        outcome = step.outcome
        return cls(
            cycle=cycle,
            stage=stage,
            finished_by=outcome.finished_by,
            iterations=int(outcome.iterations),
            objective=float(step.f_end),
            ipopt_status=outcome.status or None,
            nlpcal_status=outcome.nlpcal_status,
        )

    @property
    def status(self) -> str:
        """nlpcal's status when its checks decided the solve, else IPOPT's."""
        return self.nlpcal_status or self.ipopt_status or ""

    def to_dict(self) -> dict:
        return _present(**asdict(self))

    @classmethod
    def from_dict(cls, record: dict, source: str = "solver.stages") -> BlockSolve:
        """A stage record, also as nlpcal 0.1.0 wrote it: one "status" shared by IPOPT's and
        nlpcal's statuses (told apart by name), no "finished_by"."""
        reader = DocumentReader(record, source)
        status = reader.string("status", None)
        own = status if status in NLPCAL_STATUSES else None
        ipopt = reader.string("ipopt_status", None if own else status)
        nlpcal = reader.string("nlpcal_status", own, options=NLPCAL_STATUSES)
        finished = {"At_Stationary_Point": "newton", "At_Precision_Floor": "start"}
        return cls(
            cycle=reader.integer("cycle", 1),
            stage=reader.string("stage", ""),
            finished_by=reader.string(
                "finished_by", finished.get(str(own), "ipopt"), options=FINISHERS
            ),
            iterations=reader.integer("iterations", 0),
            objective=reader.number("objective", None),
            ipopt_status=ipopt,
            nlpcal_status=nlpcal,
            convergence_rate=reader.number("convergence_rate", None),
            predicted_cycles=reader.integer("predicted_cycles", None),
        )


@dataclass
class SolverReport:
    """How a calibration was solved: every block solve, why it stopped, IPOPT's options.

    stages : the BlockSolve of every block solve, in order.
    stop_reason : why the solve stopped ("solved" for a joint solve; a staged cycle's rule).
    converged : False for a staged cycle stopped away from the optimum.
    ipopt_options : the options IPOPT was given (`nlpcal.nlp.solver.IpoptOptions.settings`),
        whether or not it ran; empty in a document that did not record them.
    start : where a joint solve started: "algebraic" (the ellipsoid fit), "sphere" or "given";
        None for a staged cycle (Fig. 1 in [1] starts at zero).
    success : False only in a document written for a failed solve.
    gauss_newton_steps : the Levenberg-Marquardt steps of a temperature calibration.
    """

    stages: list = field(default_factory=list)
    stop_reason: str = "solved"
    converged: bool = True
    ipopt_options: dict = field(default_factory=dict)
    start: str | None = None
    success: bool = True
    gauss_newton_steps: int | None = None

    @property
    def iterations(self) -> int:
        """IPOPT's iterations over every block solve."""
        return sum(s.iterations for s in self.stages)

    @property
    def last(self) -> BlockSolve | None:
        return self.stages[-1] if self.stages else None

    @property
    def status(self) -> str:
        """The status of the last block solve (nlpcal's when its checks decided it)."""
        return self.last.status if self.last is not None else ""

    def summary(self) -> dict:
        """How the solve ended, the same for every command that reports it (`calibrate`'s
        "solver" block, `compare`'s joint row): where it started, what finished its last block
        solve with IPOPT's and nlpcal's statuses, IPOPT's iterations and solves over all."""
        last = self.last
        return _present(
            start=self.start,
            finished_by=None if last is None else last.finished_by,
            ipopt_status=None if last is None else last.ipopt_status,
            nlpcal_status=None if last is None else last.nlpcal_status,
            iterations=self.iterations,
            ipopt_solves=sum(s.ipopt_status is not None for s in self.stages),
        )

    def to_dict(self) -> dict:
        """The "solver" block: success, convergence and stop reason, the `summary`, the
        options, and every stage."""
        return _present(
            success=self.success,
            converged=self.converged,
            stop_reason=self.stop_reason,
            **self.summary(),
            gauss_newton_steps=self.gauss_newton_steps,
            ipopt_options=dict(self.ipopt_options),
            stages=[s.to_dict() for s in self.stages],
        )

    @classmethod
    def from_dict(cls, block: dict, source: str = "document") -> SolverReport:
        reader = DocumentReader(block, source, "solver.")
        stages = reader.items("stages", [])
        return cls(
            stages=[
                BlockSolve.from_dict(s, f"{source}: solver.stages[{i}]")
                for i, s in enumerate(stages)
            ],
            stop_reason=reader.string("stop_reason", "solved"),
            converged=reader.raw("converged", True) is not False,
            ipopt_options=reader.mapping("ipopt_options", {}),
            start=reader.string("start", None),
            success=reader.raw("success", True) is not False,
            gauss_newton_steps=reader.integer("gauss_newton_steps", None),
        )


def _present(**values) -> dict:
    """The values that are not None (a document holds no null)."""
    return {name: value for name, value in values.items() if value is not None}


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
    statistics : list of TableRow
        Table 1 rows (`nlpcal.results.TableRow`: label, max, min, mean, std, range [unit],
        objective [unit^2], iterations, wall_s [s], ...); the first is the measured |B_M|.
    method : str
        "staged" or "joint".
    reference : Reference
        The reference field used: mode "none", "constant" or "series", and its values.
    gauge : dict or None
        Without a reference field, the constraint that fixes the overall scale.
    solver : SolverReport
        What finished each block solve (IPOPT with its status and iterations, a verified Newton
        step, or the start), nlpcal's own statuses apart, the IPOPT options and the stop reason.
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
    identifiability : Identifiability
        What the attitude coverage determines, how the standard errors follow the dependence of
        the scores (`score_dependence`) and the second-order bias (`second_order_bias`).
    warnings : list of str
        What looks wrong with the data or the result, each a sentence.
    notes : list of str
        How the problem was posed (the gauge without a reference field), each a sentence.
    n_samples : int
        Samples the calibration used.
    version : str
        The nlpcal version that made it ("nlpcal_version" in the document).
    input : Provenance
        Where the samples came from (file, columns, the unit of the file; `Provenance`).
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
    aux : list of AuxChannel
        The stray fields v_k c_k of auxiliary channels (`nlpcal.auxiliary.model`), estimated
        with the nine parameters ("aux" in the document, written when any). [unit per channel
        unit]
    lag : dict or None
        The lag of a reference series (`nlpcal.lag`): {"status": "estimated", "given" or
        "undetermined", "seconds" [s], "standard_error_s" [s], ...}; None without one.

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

    parameters: dict[str, float]
    statistics: list[TableRow]
    method: str = "staged"
    reference: Reference = field(default_factory=Reference)
    gauge: dict | None = None
    solver: SolverReport = field(default_factory=SolverReport)
    unit: str = "nT"
    unit_source: str | None = None
    standard_errors: dict[str, float] | None = None
    covariance: np.ndarray | None = None
    identifiability: Identifiability = field(default_factory=Identifiability)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    n_samples: int = 0
    version: str = __version__
    input: Provenance = field(default_factory=Provenance)
    robust: dict = field(default_factory=dict)
    model_name: str = "full"
    model_selection: dict | None = None
    sensor_id: int | str | None = None
    orientation: dict | None = None
    aux: list = field(default_factory=list)
    lag: dict | None = None

    def __setattr__(self, name: str, value) -> None:
        """A record given as the JSON object it writes (a dict) is read into its type: the
        rows, the identifiability block and the provenance, in the constructor and after."""
        read = RECORD_FIELDS.get(name)
        super().__setattr__(name, value if read is None else read(value))

    @property
    def estimated_parameters(self) -> list:
        """The parameters the model estimates, in PARAMETER_NAMES order."""
        return estimated_parameters(self.model_name, self.reference.scale_known)

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
        recorded = self.input.log_unit
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
        if self.reference.scale_known:
            return "the reference field"
        return None

    def apply(self, samples, unit: str | None = None, aux=None) -> np.ndarray:
        """Corrected field B1 = O_p S_p (B_M - Z_p), Eq. 4 in [1]; with aux channels
        B1 = O_p S_p (B_M - Z_p - sum_k v_k c_k) (`nlpcal.auxiliary.model`).

        samples : (N, 3) raw output, in `unit` (default: the unit of the calibration).
        aux : channel name -> (N,) values (a DataFrame's columns do), for a result with aux
            channels. [channel unit]
        Returns (N, 3) corrected field in the same unit as `samples`.
        """
        samples = validation.vectors(samples)
        unit = unit or self.unit
        units.check_compatible(self.unit, unit, "the samples")
        base = units.to_base(samples, unit)
        if self.aux:
            base = base - self.stray_field(aux if aux is not None else {}, len(base))
        return units.from_base(correct(base, self.model), unit)

    def stray_field(self, aux, rows: int | None = None) -> np.ndarray:
        """sum_k v_k c_k of the aux channels for `aux`, channel name -> (N,) values; InputError
        naming a channel it lacks or whose values are not N finite numbers. [unit]"""
        values = []
        for channel in self.aux:
            if channel.name not in aux:
                raise InputError(
                    f"the calibration needs the aux channel {channel.name!r}; pass its values"
                )
            values.append(
                validation.channel(aux[channel.name], rows, f"aux channel {channel.name!r}")
            )
        return stray_field(self.aux, np.column_stack(values))

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
        block = self.identifiability
        failures = []
        if not self.solver.success:
            failures.append(f"the solver failed ({self.solver.status})")
        elif not self.solver.converged:
            failures.append(
                f"not converged: the {self.method} solve stopped on "
                f"{self.solver.stop_reason}, away from the optimum"
            )
        if block.not_identifiable:
            failures.append(f"the data do not determine {', '.join(block.not_identifiable)}")
        blind = (block.get("aux") or {}).get("not_identifiable")
        if blind:
            failures.append(f"aux channels {', '.join(blind)} vary only with the attitude")
        poor = block.poorly_determined or []
        return judge(
            failures,
            [f"{', '.join(poor)}: standard errors above their limits"] if poor else [],
            self.warnings,
        )

    def body(self) -> dict:
        document = {
            "parameters": dict(self.parameters),
            "statistics": [row.to_dict() for row in self.statistics],
            "std_ddof": STD_DDOF,
            "method": self.method,
            "reference": self.reference.to_dict(),
            "gauge": self.gauge,
            "solver": self.solver.to_dict(),
            "unit": self.unit,
            "unit_source": self.unit_source,
            "model": self.model_name,
            "fixed_parameters": self.fixed_parameters,
            "standard_errors": self.standard_errors,
            "identifiability": self.identifiability.to_dict(),
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "n_samples": self.n_samples,
            "nlpcal_version": self.version,
        }
        tied = tied_parameters(self.model_name, self.reference.scale_known)
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
            document["input"] = self.input.to_dict()
        if self.robust:
            document["robust"] = dict(self.robust)
        if self.sensor_id is not None:
            document["sensor_id"] = self.sensor_id
        if self.orientation is not None:
            document["orientation"] = dict(self.orientation)
        if self.aux:
            document["aux"] = {c.name: c.to_dict(self.unit) for c in self.aux}
        if self.lag is not None:
            document["lag"] = dict(self.lag)
        return document

    @classmethod
    def fields_from(cls, reader: DocumentReader) -> dict:
        """The constructor arguments stored in a document (shared with the temperature kind)."""
        errors = reader.reader("standard_errors") if reader.has("standard_errors") else None
        model_name = reader.string("model", "full", options=list(MODELS))
        reference = Reference.read(reader)
        scale_known = reference.scale_known
        unit = reader.string("unit", "nT", options=list(units.FIELD_UNITS_NT))
        estimated = estimated_parameters(model_name, scale_known)
        parameters = read_parameters(reader).to_dict()
        check_model(parameters, model_name, scale_known, reader.source)
        return {
            "parameters": parameters,
            "statistics": [
                TableRow.read(row, f"{reader.source}: statistics[{i}]")
                for i, row in enumerate(reader.items("statistics", []))
            ],
            "method": reader.string("method", "staged"),
            "reference": reference,
            "gauge": reader.mapping("gauge", None),
            "solver": SolverReport.from_dict(reader.mapping("solver", {}), reader.source),
            "unit": unit,
            "unit_source": reader.string("unit_source", None, options=units.UNIT_SOURCES),
            "standard_errors": None
            if errors is None
            else {
                name: errors.number(name, positive=False, minimum=0.0)
                for name in estimated
                if errors.has(name)
            },
            "covariance": read_covariance(reader, estimated),
            "identifiability": Identifiability.read(reader),
            "warnings": reader.strings("warnings", []),
            "notes": reader.strings("notes", []),
            "n_samples": reader.integer("n_samples", 0),
            "version": reader.string("nlpcal_version", "unknown"),
            "input": Provenance.from_dict(
                reader.provenance(
                    strings=("log", "temperature_column"),
                    lists=("columns",),
                    units=(("log_unit", units.FIELD_UNITS_NT), ("unit_source", units.UNIT_SOURCES)),
                )
            ),
            "robust": read_robust(reader),
            "model_name": model_name,
            "model_selection": reader.mapping("model_selection", None),
            "sensor_id": None
            if not reader.has("sensor_id")
            else validation.sensor_id(reader.raw("sensor_id"), f"{reader.source}: sensor_id"),
            "orientation": read_orientation(reader),
            "aux": read_aux(reader, unit),
            "lag": read_lag(reader),
        }

    @classmethod
    def from_body(cls, reader: DocumentReader) -> CalibrationResult:
        return cls(**cls.fields_from(reader))


#: The fields of a CalibrationResult that hold typed records, and how each is read from the
#: JSON object it writes.
RECORD_FIELDS = {
    "statistics": lambda rows: [TableRow.of(row) for row in rows],
    "identifiability": Identifiability.of,
    "input": Provenance.of,
}
