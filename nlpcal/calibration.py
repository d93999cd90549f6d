"""`nlpcal.calibrate`: the nine-parameter calibration of a log, and its result object."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from . import __version__
from .errors import InputError, QualityError, SolveError
from .io import check_reference, check_samples, read_json, write_json_atomic
from .joint import run_joint
from .models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters, correct
from .moments import Moments, accumulate
from .problems import GAUGE, SCALE_INDICES, objective_function, pack, variable_scale
from .staged import StopRule, run_staged
from .statistics import STD_DDOF, field_statistics, format_table, standard_error_inflation

FORMAT_VERSION = 1
METHODS = ("staged", "joint")

#: Above this relative gap between the moment objective and the exact one at the solution, the
#: distance to the exact optimum is estimated (`exact_optimum_shift`).
SERIES_CHECK = 1e-8
#: An estimated distance to the exact optimum above this many standard errors is a warning.
SHIFT_WARN = 0.1


@dataclass
class Problem:
    """The data of one calibration: samples, reference and their moments."""

    samples: np.ndarray
    reference: object  # None, float or (N,) array
    moments: Moments

    def measured_row(self) -> dict:
        """The Table 1 row of the raw |B_M|, gathered with the moments."""
        return {"label": "measured", **self.moments.measured, "iterations": 0, "wall_s": 0.0}

    def row(self, label, theta, series: float | None = None, *, iterations, wall_s) -> dict:
        """A Table 1 row of |B1| for `theta`, with the relative gap between the moment objective
        (`series`, evaluated here when not given) and the exact per-sample one."""
        stats = field_statistics(self.samples, theta, self.reference)
        if series is None:
            p = pack(self.moments, theta, np.ones(9), 1.0)
            series = float(objective_function(self.moments.reference)(theta, p)[0])
        exact = stats["objective"]
        stats["series_rel_error"] = abs(series - exact) / exact if exact > 0 else 0.0
        stats["parameters"] = parameters_from_theta(theta).as_dict()
        return {"label": label, **stats, "iterations": int(iterations), "wall_s": float(wall_s)}


def theta_from_parameters(params: Zhou2010Parameters) -> np.ndarray:
    """Internal vector: z [field], s [1], angles [rad]."""
    return np.concatenate([params.offsets, params.scales, params.angles_rad])


def parameters_from_theta(theta) -> Zhou2010Parameters:
    theta = np.asarray(theta, dtype=float)
    return Zhou2010Parameters.from_vector(np.concatenate([theta[:6], np.degrees(theta[6:9])]))


@dataclass
class CalibrationResult:
    """A calibration: the nine parameters of Eq. 4, Table 1 rows and how they were obtained.

    parameters : z_x, z_y, z_z [unit], s_x, s_y, s_z [1], alpha_deg, beta_deg, gamma_deg [deg].
    statistics : Table 1 rows (label, max, min, mean, std, range [unit], objective [unit^2],
        iterations, wall_s [s]); the first is the measured |B_M|.
    """

    parameters: dict
    statistics: list
    method: str = "staged"
    reference: dict = field(default_factory=lambda: {"mode": "none"})
    gauge: dict | None = None
    solver: dict = field(default_factory=dict)
    unit: str = "nT"
    standard_errors: dict | None = None
    identifiability: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    n_samples: int = 0
    version: str = __version__

    @property
    def model(self) -> Zhou2010Parameters:
        return Zhou2010Parameters.from_dict(self.parameters)

    def apply(self, samples) -> np.ndarray:
        """Corrected field B1 = O_p S_p (B_M - Z_p) (Eq. 4), in the unit of the calibration."""
        samples = np.asarray(samples, dtype=float)
        if samples.ndim != 2 or samples.shape[1] != 3:
            raise InputError(f"samples must have shape (N, 3), got {samples.shape}")
        return correct(samples, self.model)

    def table(self) -> str:
        return format_table(self.statistics, self.unit, extra=("iterations",))

    def to_dict(self) -> dict:
        return {
            "format_version": FORMAT_VERSION,
            "parameters": dict(self.parameters),
            "statistics": list(self.statistics),
            "std_ddof": STD_DDOF,
            "method": self.method,
            "reference": dict(self.reference),
            "gauge": self.gauge,
            "solver": dict(self.solver),
            "unit": self.unit,
            "standard_errors": self.standard_errors,
            "identifiability": dict(self.identifiability),
            "warnings": list(self.warnings),
            "n_samples": self.n_samples,
            "nlpcal_version": self.version,
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_dict(cls, document: dict) -> "CalibrationResult":
        if not isinstance(document, dict) or "parameters" not in document:
            raise InputError("not an nlpcal parameters file: no \"parameters\" object")
        version = document.get("format_version")
        if version != FORMAT_VERSION:
            raise InputError(f"parameters file has format_version {version!r}; this nlpcal "
                             f"reads format_version {FORMAT_VERSION}")
        try:
            params = Zhou2010Parameters.from_dict(document["parameters"]).as_dict()
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"parameters file: {exc}") from None
        return cls(
            parameters=params,
            statistics=list(document.get("statistics", [])),
            method=document.get("method", "staged"),
            reference=dict(document.get("reference") or {"mode": "none"}),
            gauge=document.get("gauge"),
            solver=dict(document.get("solver") or {}),
            unit=document.get("unit", "nT"),
            standard_errors=document.get("standard_errors"),
            identifiability=dict(document.get("identifiability") or {}),
            warnings=list(document.get("warnings", [])),
            n_samples=int(document.get("n_samples", 0)),
            version=document.get("nlpcal_version", "unknown"),
        )

    @classmethod
    def from_json(cls, text: str) -> "CalibrationResult":
        try:
            return cls.from_dict(json.loads(text))
        except json.JSONDecodeError as exc:
            raise InputError(f"not valid JSON ({exc})") from None

    def save(self, path) -> None:
        write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path) -> "CalibrationResult":
        return cls.from_dict(read_json(path, "nlpcal parameters file"))


def scaled_hessian(moments: Moments, theta, step=None) -> np.ndarray:
    """D H D: the Hessian of the objective [field^2] in the scaled variables theta = D x.

    From the joint problem's own Hessian when `step` is its solve, else from the full objective.
    """
    scale = variable_scale(moments.frame.radius)
    if step is not None and step.problem.block == "joint":
        return step.f_ref * step.problem.hessian(step.x, step.p)
    p = pack(moments, theta, scale, 1.0)
    hess = np.asarray(objective_function(moments.reference)(theta, p)[2], dtype=float)
    return scale[:, None] * hess * scale[None, :]


def gauge_basis(moments: Moments) -> np.ndarray:
    """Orthonormal basis of the scaled variables the gauge leaves free (all nine with a reference;
    eight without one, s_x + s_y + s_z = 0)."""
    if moments.reference != "none":
        return np.eye(9)
    normal = np.zeros(9)
    normal[list(SCALE_INDICES)] = variable_scale(moments.frame.radius)[list(SCALE_INDICES)]
    return np.linalg.svd(normal[None, :])[2][1:].T  # 9 x 8, orthogonal to the gauge's normal


def _uncertainty(problem: Problem, theta, objective: float, hs: np.ndarray,
                 autocorrelation: float = 0.0):
    """Standard errors from the Hessian of the objective, and which parameters are identifiable.

    For f = (1/N) sum r_i^2, the Gauss-Newton covariance is cov = 2 f / (N - 9) H^-1 with H the
    Hessian of f; without a reference, H is reduced to the gauge's null space. A log is a time
    series: when neighbouring residuals are alike (lag-1 autocorrelation rho > 0), the samples
    carry less information than their number says, and the standard errors are multiplied by
    sqrt((1 + rho) / (1 - rho)), the AR(1) variance inflation.
    """
    moments = problem.moments
    scale = variable_scale(moments.frame.radius)
    basis = gauge_basis(moments)
    reduced = basis.T @ hs @ basis
    reduced = 0.5 * (reduced + reduced.T)
    values, vectors = np.linalg.eigh(reduced)
    top = max(abs(values[-1]), 1e-300)
    weak = values < 1e-9 * top

    def involved(k):
        direction = basis @ vectors[:, k]
        return {PARAMETER_NAMES[i] for i in np.flatnonzero(np.abs(direction) > 0.3)}

    not_identifiable = set().union(*(involved(k) for k in np.flatnonzero(weak)))
    n = problem.samples.shape[0]
    inflation = standard_error_inflation(autocorrelation)
    errors = None
    if not weak.any() and n > 9:
        cov_scaled = basis @ np.linalg.inv(reduced) @ basis.T * (2.0 * objective / (n - 9))
        sd = np.sqrt(np.clip(np.diag(cov_scaled), 0, None)) * scale * inflation
        sd[6:9] = np.degrees(sd[6:9])
        errors = {name: float(v) for name, v in zip(PARAMETER_NAMES, sd)}
    limits = np.concatenate([POORLY_DETERMINED[:3] * moments.frame.radius,
                             POORLY_DETERMINED[3:]])
    poorly = [name for name, limit in zip(PARAMETER_NAMES, limits)
              if errors is not None and errors[name] > limit]
    return errors, {
        "not_identifiable": sorted(not_identifiable, key=PARAMETER_NAMES.index),
        "poorly_determined": poorly,
        "weakest_combination": sorted(involved(0), key=PARAMETER_NAMES.index),
        "hessian_eigenvalues_scaled": [float(v) for v in values],
        "residual_lag1_autocorrelation": float(autocorrelation),
        "standard_error_inflation": inflation,
        "poorly_determined_limits": {n_: float(v) for n_, v in zip(PARAMETER_NAMES, limits)},
    }


#: Standard errors above these are "poorly determined": offsets 1 % of the field, scale errors
#: 0.01, angles 1 deg.
POORLY_DETERMINED = np.array([1e-2] * 3 + [1e-2] * 3 + [1.0] * 3)

#: The 26 directions of a cube's faces, edges and corners: the bins of `direction_coverage`.
_BIN_DIRECTIONS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                            if (i, j, k) != (0, 0, 0)], dtype=float)
_BIN_DIRECTIONS /= np.linalg.norm(_BIN_DIRECTIONS, axis=1, keepdims=True)
#: Fewer bins than this fraction are reported as poor attitude coverage.
COVERAGE_WARN = 0.5


def direction_coverage(samples, theta, max_points: int = 20000) -> dict:
    """How many of 26 direction bins the corrected field B1 visits (a strided subsample)."""
    sub = samples[:: max(1, samples.shape[0] // max_points)]
    b1 = correct(sub, parameters_from_theta(theta))
    nearest = np.argmax(b1 @ _BIN_DIRECTIONS.T, axis=1)
    covered = int(np.unique(nearest).size)
    return {"direction_bins": 26, "covered": covered, "fraction": covered / 26}


def exact_optimum_shift(problem: Problem, theta, hs: np.ndarray, errors) -> float | None:
    """How far the exact optimum lies from `theta`, in standard errors (largest over parameters).

    One Newton step on the exact per-sample objective: its gradient by central differences
    (18 passes over the data), the Hessian of the moment objective. Without a reference the step
    stays in the gauge's null space.
    """
    if errors is None:
        return None
    scale = variable_scale(problem.moments.frame.radius)
    h = 1e-3  # in scaled variables: 1e-6 of the field for offsets, 1e-6 for scales, 1e-5 rad

    def exact(x):
        return field_statistics(problem.samples, theta + scale * x, problem.reference)["objective"]

    grad = np.array([(exact(h * e) - exact(-h * e)) / (2 * h) for e in np.eye(9)])
    basis = gauge_basis(problem.moments)
    reduced = basis.T @ hs @ basis
    step = -basis @ np.linalg.solve(0.5 * (reduced + reduced.T), basis.T @ grad)
    shift = step * scale
    shift[6:9] = np.degrees(shift[6:9])
    sd = np.array([errors[name] for name in PARAMETER_NAMES])
    return float(np.max(np.abs(shift) / np.where(sd > 0, sd, np.inf)))


def _explain_failure(problem: Problem, failure: SolveError) -> SolveError:
    """Say which parameters the data determine least, when IPOPT fails.

    The Hessian is taken where the failing solve started (failure.result).
    """
    theta = failure.result
    if theta is None or not np.all(np.isfinite(theta)):
        return failure
    hs = scaled_hessian(problem.moments, theta)
    objective = field_statistics(problem.samples, theta, problem.reference)["objective"]
    _, identifiability = _uncertainty(problem, theta, objective, hs)
    weak = identifiability["not_identifiable"]
    if weak:
        reason = f"the data do not determine {', '.join(weak)}"
    else:
        reason = (f"the least determined combination involves "
                  f"{', '.join(identifiability['weakest_combination'])}")
    return SolveError(f"{failure}: {reason}; rotate the sensor through more attitudes",
                      failure.status, result=theta)


def _warnings(problem: Problem, theta, hs, errors, identifiability: dict, final: dict) -> list:
    """What the data cannot tell, in words (and the exact-optimum check, into identifiability)."""
    warnings = []
    if problem.moments.reference == "none":
        warnings.append("absolute scale not identifiable without a reference field: the scales "
                        "are fixed by the gauge s_x + s_y + s_z = 0; the scale ratios, offsets "
                        "and angles are determined. Give a reference field for absolute scales.")
    if identifiability["not_identifiable"]:
        warnings.append("not identifiable from this attitude coverage: "
                        + ", ".join(identifiability["not_identifiable"])
                        + "; rotate the sensor through more attitudes")
    coverage = identifiability["coverage"]
    if coverage["fraction"] < COVERAGE_WARN:
        warnings.append(f"poor attitude coverage: the corrected field visits "
                        f"{coverage['covered']} of 26 direction bins; the result leans on a "
                        f"small part of the sphere")
    if identifiability["poorly_determined"]:
        warnings.append("poorly determined (standard error above the limits in "
                        "identifiability.poorly_determined_limits): "
                        + ", ".join(identifiability["poorly_determined"]))
    if final.get("series_rel_error", 0.0) > SERIES_CHECK:
        shift = exact_optimum_shift(problem, theta, hs, errors)
        identifiability["exact_optimum_shift_in_standard_errors"] = shift
        if shift is None or shift > SHIFT_WARN:
            where = ("could not be located (no standard errors)" if shift is None
                     else f"is estimated to lie {shift:.2g} standard errors away")
            warnings.append(f"the moment expansion of the objective is inexact here "
                            f"({final['series_rel_error']:.1e} relative; |B1|^2 varies by up to "
                            f"{final['max_abs_u']:.1%}); the exact optimum {where}; check the "
                            f"reference field and the data for disturbances")
    return warnings


def calibrate(samples, *, method: str = "staged", reference_field=None, cycles: int = 50,
              target_std: float | None = None, target_range: float | None = None,
              rtol: float = 1e-9, unit: str = "nT",
              require_identifiable: bool = True) -> CalibrationResult:
    """Estimate the nine parameters of Eq. 4 in [1] from a log of many attitudes.

    samples : (N, 3) array-like of raw sensor output B_M. [nT, or `unit`]
    method : "staged", the cycle of Fig. 1 in [1] (orthogonal -> scale -> offset), or "joint",
        all nine in one IPOPT problem.
    reference_field : None (Eq. 8, absolute scale not identifiable), a float F, or an array of N
        values F_i (for example a proton magnetometer sampled with the log). [nT, or `unit`]
    cycles : the most staged cycles. target_std, target_range : stop the cycle when |B1| meets
        them [nT]. rtol : stop when a cycle lowers the objective by less than this fraction.
    require_identifiable : raise QualityError (holding the result) when the attitude coverage
        leaves parameters undetermined; False returns the result with its warnings.

    Returns a CalibrationResult. Raises InputError for unusable input, SolveError when IPOPT
    fails and QualityError as above.

    References
    ----------
    [1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
    """
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if int(cycles) < 1:
        raise InputError(f"cycles must be at least 1, got {cycles}")
    for name, value in (("target_std", target_std), ("target_range", target_range)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number, got {value}")
    if not (np.isfinite(rtol) and rtol >= 0):
        raise InputError(f"rtol must be a non-negative number, got {rtol}")
    samples = check_samples(samples)
    reference = check_reference(reference_field, samples.shape[0])
    problem = Problem(samples=samples, reference=reference, moments=accumulate(samples, reference))
    try:
        if method == "staged":
            rule = StopRule(max_cycles=int(cycles), target_std=target_std,
                            target_range=target_range, rtol=rtol)
            theta, rows, stages, stop_reason = run_staged(problem, rule)
            hs = scaled_hessian(problem.moments, theta)
        else:
            step, rows, stages = run_joint(problem)
            theta, stop_reason = step.theta, "solved"
            hs = scaled_hessian(problem.moments, theta, step)
    except SolveError as failure:
        raise _explain_failure(problem, failure) from None
    final = rows[-1]
    errors, identifiability = _uncertainty(problem, theta, final["objective"], hs,
                                           final["residual_lag1_autocorrelation"])
    identifiability["coverage"] = direction_coverage(samples, theta)

    mode = problem.moments.reference
    warnings = _warnings(problem, theta, hs, errors, identifiability, final)
    if method == "staged" and stop_reason == "max_cycles" and len(rows) > 2:
        warnings.append(f"the staged cycle stopped at the maximum of {cycles} cycles before "
                        f"converging (rtol {rtol:g}); results may improve with more cycles")

    reference_doc = {"mode": mode}
    if mode == "constant":
        reference_doc["field"] = float(reference)
    elif mode == "series":
        reference_doc["field_mean"] = float(np.mean(reference))
    iterations = sum(s["iterations"] for s in stages)
    result = CalibrationResult(
        parameters=parameters_from_theta(theta).as_dict(),
        statistics=rows,
        method=method,
        reference=reference_doc,
        gauge=dict(GAUGE) if mode == "none" else None,
        solver={"name": "ipopt", "status": stages[-1]["status"], "success": True,
                "iterations": iterations, "stop_reason": stop_reason, "stages": stages},
        unit=unit,
        standard_errors=errors,
        identifiability=identifiability,
        warnings=warnings,
        n_samples=int(samples.shape[0]),
    )
    if require_identifiable and identifiability["not_identifiable"]:
        raise QualityError(f"the data do not determine "
                           f"{', '.join(identifiability['not_identifiable'])}; rotate the sensor "
                           f"through more attitudes (require_identifiable=False returns the "
                           f"result anyway)", "Not_Identifiable", result=result)
    return result
