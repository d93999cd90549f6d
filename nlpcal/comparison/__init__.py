"""Staged cycle vs joint IPOPT vs the paper's conjugate gradient, on one log.

Section 4 of [1] argues that solving the nine parameters of Eq. 4 at once converges badly (mixed
units and magnitudes make the stopping rule of its conjugate gradient hard to set) and that
cycling through the three stages of Fig. 1 fixes it. `compare` runs, on the same data and the same
objective (Eq. 8, or its reference variant):

    staged     the cycle of Fig. 1, every stage an IPOPT problem
               (`nlpcal.calibration.staged.run_staged`)
    joint      the nine parameters in one IPOPT problem (`nlpcal.calibration.joint.run_joint`)
    cg_joint   the conjugate gradient of section 5 on all nine at once, in the paper's units,
               then the same on variables scaled to order one
               (`nlpcal.comparison.conjugate_gradient`)
    cg_staged  the cycle of Fig. 1 with every stage solved by that conjugate gradient

and reports Table 1 rows for each (max, min, mean, std, range of |B1| [field unit], objective
[field^2], iterations and wall time [s]) together with the objective against the cumulative
solver iterations of every method, for the figures of Fig. 2.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .. import chunks, units, validation
from ..calibration.coverage import planar_message
from ..calibration.diagnostics import (
    explain_failure,
    problem_flatness,
    scaled_hessian,
    uncertainty,
)
from ..calibration.joint import joint_start, run_joint
from ..calibration.problem import Problem
from ..calibration.staged import StopRule, run_staged
from ..defaults import CYCLES_DEFAULT, RTOL_DEFAULT
from ..errors import QualityError, SolveError
from ..io.logs import Log
from ..models.zhou2010 import Zhou2010Parameters, correct
from ..moments import accumulate
from ..nlp.blocks import OPTIONS
from ..results import Document, DocumentReader
from ..robust import Loss
from ..statistics import STD_DDOF, format_table
from ..version import __version__
from .analysis import (
    block_coupling,
    cg_trajectory,
    joint_trajectory,
    run_summary,
    staged_trajectory,
    thin,
)
from .conjugate_gradient import CGOptions, run_cg_joint, run_cg_staged

#: Keys of compare.json that hold Table 1 rows (a contract: keep exactly).
ROW_KEYS = ("staged", "joint", "cg_joint", "cg_staged")
#: The statistics every row carries.
ROW_FIELDS = ("max", "min", "mean", "std", "range", "objective", "iterations", "wall_s")


@dataclass(frozen=True)
class CompareSettings:
    """How `compare` runs the four methods.

    Attributes
    ----------
    cycles : int
        The most cycles of the staged and the CG-staged runs (the default of `calibrate`).
    rtol : float
        Both cycles stop when a cycle lowers the objective by less than this fraction; the staged
        cycle runs on to its limit when it cannot (no early stop on a predicted failure: the
        comparison shows the whole path). [1]
    cg : CGOptions
        Settings of the conjugate gradient (step constant, eps, iteration cap).

    Raises
    ------
    InputError
        A cycle count below one or a negative rtol.

    Examples
    --------
    >>> import nlpcal
    >>> nlpcal.CompareSettings(cycles=20).cycles
    20
    """

    cycles: int = CYCLES_DEFAULT
    rtol: float = RTOL_DEFAULT
    cg: CGOptions = field(default_factory=lambda: CGOptions(max_iter=5000))

    def __post_init__(self):
        validation.count(self.cycles, "cycles (--cycles)")
        validation.number(self.rtol, "rtol (--rtol)", minimum=0.0)


@dataclass
class Comparison(Document):
    """The four methods on one log: Table 1 rows, trajectories and a summary.

    Attributes
    ----------
    samples : numpy.ndarray or None
        The log (in memory only: the figures need it; None for a comparison read back). [unit]
    staged : list of dict
        Table 1 rows of the staged cycle: the measured row, then one row per cycle.
    joint : dict
        The Table 1 row of the joint solve, from the CG's start (the sphere fit), with how its
        solve ended as `calibrate` reports it (`SolverReport.summary`: start, finished_by,
        IPOPT's and nlpcal's statuses, IPOPT's iterations).
    cg_joint : list of dict
        The CG on all nine, unscaled (the paper's setting) then scaled.
    cg_staged : list of dict
        The staged cycle with the CG: the measured row, then one row per cycle.
    trajectories : dict
        Method -> {"iterations": cumulative solver iterations, "objective": [unit^2]}.
    summary : dict
        Cycles, iterations and wall times of each method, and whether the cycles reached the
        joint optimum.
    reference : dict
        The reference field used.
    settings : CompareSettings
        How the methods ran.
    unit : str
        The unit of the rows ("nT" or "raw").
    warnings : list of str
        What looks wrong with the data, each a sentence.
    n_samples : int
        Samples compared.
    input : dict
        Where the samples came from.
    ipopt_options : dict
        The options IPOPT was given (`nlpcal.nlp.solver.IpoptOptions.settings`), as `calibrate`
        records them under `solver.ipopt_options`; written under `settings.ipopt_options`.

    Examples
    --------
    >>> import nlpcal
    >>> samples = nlpcal.simulate(500, seed=1)[["bx", "by", "bz"]].to_numpy()
    >>> comparison = nlpcal.compare(samples, settings=nlpcal.CompareSettings(cycles=3))
    >>> sorted(comparison.trajectories)
    ['cg_joint', 'cg_joint_scaled', 'cg_staged', 'joint', 'staged']
    """

    FORMAT = "nlpcal-comparison"
    WHAT = "nlpcal comparison"

    samples: np.ndarray | None
    staged: list
    joint: dict
    cg_joint: list
    cg_staged: list
    trajectories: dict
    summary: dict
    reference: dict
    settings: CompareSettings
    unit: str = "nT"
    warnings: list = field(default_factory=list)
    n_samples: int = 0
    input: dict = field(default_factory=dict)
    ipopt_options: dict = field(default_factory=dict)

    def body(self) -> dict:
        document = {
            "unit": self.unit,
            "std_ddof": STD_DDOF,
            "n_samples": self.n_samples,
            "reference": dict(self.reference),
            "staged": list(self.staged),
            "joint": dict(self.joint),
            "cg_joint": list(self.cg_joint),
            "cg_staged": list(self.cg_staged),
            "summary": dict(self.summary),
            "settings": {
                "cycles": int(self.settings.cycles),
                "rtol": self.settings.rtol,
                "cg": asdict(self.settings.cg),
                "ipopt_options": dict(self.ipopt_options),
            },
            "trajectories": {name: thin(t) for name, t in self.trajectories.items()},
            "warnings": list(self.warnings),
            "nlpcal_version": __version__,
        }
        if self.input:
            document["input"] = dict(self.input)
        return document

    @classmethod
    def from_body(cls, reader: DocumentReader) -> Comparison:
        settings = reader.reader("settings")
        cg = settings.mapping("cg", {})
        return cls(
            samples=None,
            staged=reader.items("staged"),
            joint=reader.mapping("joint"),
            cg_joint=reader.items("cg_joint"),
            cg_staged=reader.items("cg_staged"),
            trajectories=reader.mapping("trajectories", {}),
            summary=reader.mapping("summary", {}),
            reference=reader.mapping("reference"),
            settings=CompareSettings(
                cycles=settings.integer("cycles", minimum=1),
                rtol=settings.number("rtol", minimum=0.0),
                cg=CGOptions(**cg),
            ),
            unit=reader.string("unit", "nT"),
            warnings=reader.strings("warnings", []),
            n_samples=reader.integer("n_samples", 0),
            input=reader.mapping("input", {}),
            ipopt_options=settings.mapping("ipopt_options", {}),
        )

    def table(self) -> str:
        """All rows in the layout of Table 1 of [1], one block per method."""
        extra = ("objective", "iterations", "wall_s")
        blocks = [
            ("staged cycle, IPOPT stages", self.staged),
            ("joint, IPOPT", [self.joint]),
            ("conjugate gradient of section 5, joint", self.cg_joint),
            ("conjugate gradient of section 5, staged cycle", self.cg_staged[1:]),
        ]
        parts = []
        for title, rows in blocks:
            parts.append(f"== {title}")
            parts.append(format_table(rows, self.unit, extra=extra))
        return "\n".join(parts)

    def magnitudes(self, row) -> np.ndarray:
        """|B1| of every sample for a row's parameters (the measured |B_M| for the measured row)."""
        if self.samples is None:
            raise ValueError("a comparison read back from a document has no samples")
        if "parameters" not in row:
            return np.linalg.norm(self.samples, axis=1)
        params = Zhou2010Parameters.from_dict(row["parameters"])
        return np.linalg.norm(correct(self.samples, params), axis=1)


def compare(
    samples,
    *,
    reference_field=None,
    settings: CompareSettings = CompareSettings(),
    unit: str = "nT",
    reference_unit: str | None = None,
    loss: str = "l2",
    loss_scale: float | None = None,
    require_identifiable: bool = True,
    threads: int | None = None,
    ipopt_options: dict | None = None,
) -> Comparison:
    """Run the staged cycle, the joint solve and the paper's CG (joint and staged) on one log.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw sensor output B_M. [unit]
    reference_field : None, float or array_like of shape (N,)
        None (Eq. 8), a number F or N values F_i (`--reference-field`). [reference_unit]
    settings : CompareSettings
        Cycles, rtol and the CG settings (`--cycles`, `--rtol`, `--cg-*`).
    unit : str
        The unit of the samples; the comparison is in nT (or raw for counts).
    reference_unit : str, optional
        The unit of the reference (default: `unit`).
    loss : {"l2", "huber", "cauchy"}
        A robust loss, as in `calibrate`; its weights are fixed at the reweighted joint solution,
        and every method then minimises that weighted objective.
    loss_scale : float, optional
        The residual beyond which a sample is down-weighted. [unit]
    require_identifiable : bool
        Raise QualityError when the attitudes leave parameters undetermined.
    threads : int, optional
        Threads of the passes over the data (default: the cores available).
    ipopt_options : dict, optional
        Further IPOPT options for the staged and joint solves, as in `calibrate`
        (`--ipopt-option KEY=VALUE`): name -> int, float or str over nlpcal's own
        (`nlpcal.nlp.blocks.OPTIONS`), checked by IPOPT first (InputError for an option it does
        not know or a value it refuses). The comparison records every option IPOPT was given
        (`Comparison.ipopt_options`).

    Returns
    -------
    Comparison
        Table 1 rows of the four methods, the objective against the cumulative solver iterations
        of each, and a summary.

    Raises
    ------
    InputError
        Unusable input.
    SolveError
        IPOPT failed.
    QualityError
        The attitudes leave parameters undetermined.

    Examples
    --------
    >>> import nlpcal
    >>> samples = nlpcal.simulate(500, seed=1)[["bx", "by", "bz"]].to_numpy()
    >>> comparison = nlpcal.compare(samples, settings=nlpcal.CompareSettings(cycles=5))
    >>> len(comparison.staged)  # the measured row and one row per cycle
    6
    """
    with chunks.call_threads(validation.optional_whole(threads, "threads")):
        ipopt = OPTIONS.with_options(ipopt_options)
        problem = _problem(samples, reference_field, unit, reference_unit, loss, loss_scale, ipopt)
        samples, moments = problem.samples, problem.moments

        rule = StopRule(max_cycles=int(settings.cycles), rtol=settings.rtol, predict=False)
        try:
            _, staged, stages, stop_reason = run_staged(problem, rule)
            start = joint_start(moments)
            joint_step, joint_rows, joint_report = run_joint(problem, start, "sphere")
        except SolveError as failure:
            raise explain_failure(problem, failure, None) from None
        joint_theta = joint_step.theta
        joint = {**joint_rows[-1], **joint_report.summary()}  # as `calibrate` reports it
        joint_path = joint_trajectory(joint_step, joint["iterations"], joint["objective"])
        if require_identifiable:
            _require_optimum(problem, joint_step, joint["objective"], unit)

        cg_joint, cg_joint_paths = _run_cg_joint(problem, start, settings.cg)
        _, cg_staged, cg_stages = run_cg_staged(
            problem, settings.cycles, settings.cg, settings.rtol
        )

        trajectories = {
            "staged": staged_trajectory(staged, stages),
            "joint": joint_path,
            "cg_joint": cg_joint_paths["cg joint"],
            "cg_joint_scaled": cg_joint_paths["cg joint scaled"],
            "cg_staged": cg_trajectory([s["history"] for s in cg_stages]),
        }

        summary = run_summary(staged, stop_reason, joint, cg_joint, cg_staged)
        summary["block_coupling"] = block_coupling(moments, joint_theta)
        summary["loss"] = problem.loss.to_dict()
        return Comparison(
            samples=samples,
            staged=staged,
            joint=joint,
            cg_joint=cg_joint,
            cg_staged=cg_staged,
            trajectories=trajectories,
            summary=summary,
            reference=problem.reference_document().to_dict(),
            settings=settings,
            unit=units.base_unit(unit),
            warnings=_warnings(settings, stop_reason, staged, joint, cg_joint, cg_staged),
            n_samples=int(samples.shape[0]),
            ipopt_options=ipopt.settings(),
        )


def _problem(samples, reference_field, unit, reference_unit, loss, loss_scale, ipopt) -> Problem:
    """The problem every method solves: the samples and reference in the base unit, their
    moments, and a robust loss's weights fixed at the reweighted joint solution."""
    units.check_compatible(unit, reference_unit or unit)
    samples = validation.samples(samples)
    reference = validation.reference(reference_field, samples.shape[0])
    samples = units.to_base(samples, unit)
    reference = units.to_base(reference, reference_unit or unit)
    chosen = Loss(loss, units.to_base(loss_scale, unit))
    validation.reference_scale(reference, validation.mean_magnitude(samples))
    moments = accumulate(samples, reference)
    problem = Problem(
        samples=samples, reference=reference, moments=moments, loss=chosen, ipopt=ipopt
    )
    if chosen.robust:  # the weights of the robust optimum, then the same objective for all
        run_joint(problem)
        problem.frozen = True
    return problem


def _require_optimum(problem: Problem, joint_step, objective: float, unit: str) -> None:
    """QualityError when the attitudes leave parameters undetermined at the joint solution
    (planar data, or parameters the Hessian does not determine): no method has an optimum."""
    hs = scaled_hessian(problem.moments, joint_step.theta, joint_step)
    weak = uncertainty(problem, objective, hs)[1]["not_identifiable"]
    flat = problem_flatness(problem, joint_step.theta)
    if flat["planar"]:
        raise QualityError(
            f"{planar_message(flat, units.base_unit(unit))}; no method has an optimum to reach",
            "Not_Identifiable",
            overrides={"require_identifiable": False},
        )
    if weak:
        raise QualityError(
            f"the data do not determine {', '.join(weak)}, so no method has an optimum to "
            f"reach; rotate the sensor through more attitudes",
            "Not_Identifiable",
            overrides={"require_identifiable": False},
        )


def _run_cg_joint(problem: Problem, start, cg: CGOptions) -> tuple:
    """The conjugate gradient on all nine parameters from `start`, unscaled (the paper's
    setting) then scaled: the two Table 1 rows and label -> objective trajectory."""
    rows, paths = [], {}
    for scaled in (False, True):
        options = CGOptions(**{**asdict(cg), "scaled": scaled})
        label = "cg joint scaled" if scaled else "cg joint"
        _, row, outcome = run_cg_joint(problem, start, options, label=label)
        rows.append(row)
        paths[label] = cg_trajectory([outcome.history])
    return rows, paths


def _warnings(settings, stop_reason, staged, joint, cg_joint, cg_staged) -> list:
    """What the comparison should say: a staged cycle still improving at its limit, and
    conjugate gradients that did not converge."""
    warnings = []
    if stop_reason == "max_cycles":
        warnings.append(
            f"the staged cycle was still improving after {settings.cycles} cycles "
            f"(std {staged[-1]['std']:.4g} vs joint {joint['std']:.4g}); pass a "
            f"larger --cycles to see where it ends"
        )
    for row in cg_joint:
        if row["status"] != "converged":
            warnings.append(
                f"{row['label']}: the conjugate gradient did not converge "
                f"({row['status']} after {row['iterations']} iterations; std "
                f"{row['std']:.4g} vs joint {joint['std']:.4g})"
            )
    bad = [r["label"] for r in cg_staged[1:] if not r.get("converged", True)]
    if bad:
        warnings.append(f"conjugate gradient stages that did not converge in: {', '.join(bad)}")
    return warnings


def compare_log(
    log: Log,
    *,
    settings: CompareSettings = CompareSettings(),
    loss: str = "l2",
    loss_scale: float | None = None,
    threads: int | None = None,
    ipopt_options: dict | None = None,
) -> Comparison:
    """`compare` on a log read by `nlpcal.io.read_log` (its reference included); the comparison
    records the log under `input`. loss_scale : in the unit of the log's field columns."""
    result = compare(
        log.samples,
        reference_field=log.reference,
        settings=settings,
        unit=log.base_unit,
        loss=loss,
        loss_scale=units.to_base(loss_scale, log.unit),
        threads=threads,
        ipopt_options=ipopt_options,
    )
    result.input = log.metadata(unit_factor_nT=units.field_factor(log.unit))
    if log.reference_column:
        result.reference["column"] = log.reference_column
    return result
