"""The three non-orthogonality angles from rotation logs (section 2 of Wang et al. 2015), and the
repeatability of several inversions of one probe (Table 4).

The inversion minimises the spread of the corrected total field |T^-1 B'_i| around its mean (the
paper's objective), or its distance to a known field, under bounds on the angles. Its objective is
the orthogonal block of Eq. 8 of Zhou et al. (2010) with unit scales and zero offsets, evaluated
from the Gram matrix of `nlpcal.moments`: the problem has the same size for every log
(`nlpcal.nlp.orthogonality.inversion_solver`). The Table 1 statistics before and after are exact
passes over the samples.

References
----------
[1] Wang et al. (2015), see `nlpcal.models.wang2015`.
[2] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import inference, validation
from ..calibration.joint import algebraic_start, joint_start
from ..errors import InputError, QualityError, SolveError
from ..models.wang2015 import ANGLE_NAMES
from ..moments import accumulate
from ..nlp.blocks import moment_parameters
from ..nlp.orthogonality import inversion_objective, inversion_solver
from ..nlp.solver import solve
from ..results import Document, DocumentReader
from ..statistics import field_statistics
from ..verdict import Verdict, judge
from .worst_case import implied_worst_case

#: Default bound of the inversion, as in section 2 of [1]. [deg]
DEFAULT_BOUND_DEG = 0.5
#: Fewest samples the inversion accepts (three angles plus the mean field).
MIN_INVERSION_SAMPLES = 10
#: A solution within this fraction of its bound counts as on the bound. [1]
BOUND_ACTIVE_REL_TOL = 1e-3
#: The three angles do not explain the data when the rms of their residuals exceeds this many
#: times the rms left by the nine parameters of Eq. 4 in [2] on the same samples (the noise, when
#: the nine explain the data). Nested models on the same samples differ by a fraction of the
#: noise when the smaller one holds; offsets and scale errors left in the data raise the ratio to
#: their size over the noise (150 for 100 nT offsets in 1 nT of noise). [1]
UNEXPLAINED_RATIO = 3.0
#: Residuals below this fraction of the field are rounding, not misfit, whatever their ratio. [1]
UNEXPLAINED_FLOOR = 1e-9


@dataclass
class Inversion(Document):
    """Angles inverted from one rotation log (section 2 in [1]).

    Attributes
    ----------
    angles_deg : numpy.ndarray
        (alpha, beta, gamma). [deg]
    angles_std_deg : numpy.ndarray or None
        Standard errors scaled by the residual variance. [deg]
    variant : str
        "reference" (known field) or "spread" (around the mean, the paper's).
    field_nT : float or None
        The reference field of the reference variant. [nT]
    n_samples : int
        Samples inverted.
    objective_nT2 : float
        Mean squared residual at the solution. [nT^2]
    rms_before_nT, rms_after_nT : float
        Rms of |B'| - centre before and after correction. [nT]
    corrected_mean_nT : float
        Mean of |B''| after correction. [nT]
    bound_deg : numpy.ndarray
        The bounds +-bound. [deg]
    bound_active : list of bool
        Per angle: the solution lies on a bound.
    status : str
        IPOPT's return status.
    success : bool
        IPOPT succeeded.
    iterations : int
        IPOPT's iterations.
    warnings : list of str
        What looks wrong, each a sentence.
    source : str or None
        The log the samples came from, if any.
    not_identifiable : list of str
        Angles the attitudes leave free.

    References
    ----------
    [1] Wang et al. (2015), see `nlpcal.models.wang2015`.

    Examples
    --------
    >>> import nlpcal
    >>> probe = nlpcal.synthetic_rotation((0.07, 0.04, 0.1), n=500, noise_nT=0.5, seed=0)
    >>> inversion = nlpcal.invert(probe)
    >>> inversion.variant, inversion.verdict.status
    ('spread', 'ok')
    """

    FORMAT = "nlpcal-orthogonality-inversion"
    LEGACY_FORMATS = (("schema", "nlpcal.orthogonality.inversion/1"),)
    WHAT = "nlpcal inversion file"

    angles_deg: np.ndarray
    angles_std_deg: np.ndarray | None
    variant: str
    field_nT: float | None
    n_samples: int
    objective_nT2: float
    rms_before_nT: float
    rms_after_nT: float
    corrected_mean_nT: float
    bound_deg: np.ndarray
    bound_active: list
    status: str
    success: bool
    iterations: int
    warnings: list = field(default_factory=list)
    source: str | None = None
    not_identifiable: list = field(default_factory=list)

    @property
    def verdict(self) -> Verdict:
        """Failed when IPOPT did not converge or the attitudes leave an angle undetermined (a
        result kept with require_identifiable=False), else ok or warnings."""
        failures = [] if self.success else [f"IPOPT did not converge ({self.status})"]
        if self.not_identifiable:
            failures.append(f"the attitudes do not determine {', '.join(self.not_identifiable)}")
        return judge(failures, [], self.warnings)

    def body(self) -> dict:
        document = {
            "schema": "nlpcal.orthogonality.inversion/1",
            "angles_deg": [float(a) for a in self.angles_deg],
            "angles_std_deg": (
                None if self.angles_std_deg is None else [float(a) for a in self.angles_std_deg]
            ),
            "angle_convention": "zhou2010",
            "variant": self.variant,
            "field_nT": self.field_nT,
            "n_samples": self.n_samples,
            "objective": self.objective_nT2,
            "objective_nT2": self.objective_nT2,
            "rms_before_nT": self.rms_before_nT,
            "rms_after_nT": self.rms_after_nT,
            "corrected_mean_nT": self.corrected_mean_nT,
            "bound_deg": [float(b) for b in self.bound_deg],
            "bound_active": list(self.bound_active),
            "any_bound_active": any(self.bound_active),
            "not_identifiable": list(self.not_identifiable),
            "status": self.status,
            "success": self.success,
            "iterations": self.iterations,
            "warnings": list(self.warnings),
        }
        if self.source is not None:
            document = {"log": self.source, **document}
        return document

    @classmethod
    def from_body(cls, reader: DocumentReader) -> Inversion:
        std = reader.array("angles_std_deg", (3,), None)
        return cls(
            angles_deg=reader.array("angles_deg", (3,)),
            angles_std_deg=std,
            variant=reader.string("variant", options=("spread", "reference")),
            field_nT=reader.number("field_nT", None, positive=True),
            n_samples=reader.integer("n_samples"),
            objective_nT2=reader.number("objective_nT2", minimum=0.0),
            rms_before_nT=reader.number("rms_before_nT", minimum=0.0),
            rms_after_nT=reader.number("rms_after_nT", minimum=0.0),
            corrected_mean_nT=reader.number("corrected_mean_nT"),
            bound_deg=reader.array("bound_deg", (3,)),
            bound_active=reader.items("bound_active"),
            status=reader.string("status"),
            success=bool(reader.raw("success", True)),
            iterations=reader.integer("iterations", 0),
            warnings=reader.strings("warnings", []),
            source=reader.string("log", None),
            not_identifiable=reader.strings("not_identifiable", []),
        )


def invert(
    samples,
    *,
    reference_field: float | None = None,
    field_nT: float | None = None,
    bound_deg=DEFAULT_BOUND_DEG,
    start_deg=(0.0, 0.0, 0.0),
    source: str | None = None,
    verbose: bool = False,
    require_identifiable: bool = True,
    require_explained: bool = True,
) -> Inversion:
    """The three non-orthogonality angles from a rotation log, as a bounded IPOPT problem.

    A solution on a bound gets a warning: the true angle may lie outside the bounds.

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Probe output B' from attitudes spread over the sphere in a constant field; unit
        sensitivities and zero offsets are assumed (remove them first). [nT]
    reference_field : float, optional
        The known field B (`--reference-field`). With it, minimise mean_i (|T^-1 B'_i| - B)^2
        (reference variant); without it, mean_i (|T^-1 B'_i| - mean_j |T^-1 B'_j|)^2 (spread
        variant, the objective of section 2 in [1]). [nT]
    field_nT : float, optional
        The former name of `reference_field`, still accepted. [nT]
    bound_deg : float or array_like of shape (3,)
        |angle| <= bound, one value or three (`--bound-deg`; section 2 of [1] uses 0.5). [deg]
    start_deg : array_like, shape (3,)
        IPOPT's start, (0, 0, 0) as in [1]. [deg]
    source : str, optional
        The log the samples came from, named in messages.
    verbose : bool
        Print IPOPT's log.
    require_identifiable : bool
        Raise QualityError (holding the result) when the attitudes leave an angle undetermined;
        False returns the result with a warning.
    require_explained : bool
        Raise QualityError (holding the result) when the three angles do not explain the data:
        their residual is more than UNEXPLAINED_RATIO times the noise, the rms the nine parameters
        of Eq. 4 in [2] leave on the same samples (offsets or scale errors not removed: calibrate
        first); False returns the result with a warning. Not judged when an angle lies on its
        bound (its warning names that cause first).

    Returns
    -------
    Inversion
        The angles, their standard errors, and the spread of |B'| before and after.

    Raises
    ------
    InputError
        Unusable samples or options.
    SolveError
        IPOPT failed.
    QualityError
        The attitudes leave an angle undetermined, or the angles do not explain the data.

    References
    ----------
    [1] Wang et al. (2015), see `nlpcal.models.wang2015`.
    [2] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> import nlpcal
    >>> probe = nlpcal.synthetic_rotation((0.07, 0.04, 0.1), n=500, noise_nT=0.5, seed=0)
    >>> inversion = nlpcal.invert(probe, reference_field=55_000.0)
    >>> [bool(abs(a - t) < 0.01) for a, t in zip(inversion.angles_deg, (0.07, 0.04, 0.1))]
    [True, True, True]
    """
    samples, bounds, start = _checked_samples(samples, bound_deg, start_deg)
    field_nT = validation.renamed(reference_field, field_nT, "reference_field", "field_nT")
    reference = None if field_nT is None else validation.field(field_nT, what="reference field")
    nominal = _nominal_magnitude(samples)
    n = samples.shape[0]
    validation.reference_scale(reference, nominal, "the reference field")
    moments = accumulate(samples, reference)
    before = field_statistics(samples, None, reference)
    where = f"{source}: " if source else ""
    outcome = _solve_angles(moments, before, start, bounds, bool(verbose), where)
    angles = np.clip(outcome.x, -bounds, bounds)
    theta = np.concatenate([np.zeros(6), np.radians(angles)])
    after = field_statistics(samples, theta, reference)
    active = [
        bool(bounds[i] - abs(angles[i]) <= BOUND_ACTIVE_REL_TOL * bounds[i]) for i in range(3)
    ]
    warnings = [
        f"{where}{name} = {value:+.6g} deg lies on its bound +-{bound:g} deg: the true "
        f"angle may lie outside the bounds; widen the bound and invert again"
        for name, is_active, value, bound in zip(ANGLE_NAMES, active, angles, bounds)
        if is_active
    ]
    uncertainty = _uncertainty(moments, angles, after, spread=reference is None)
    weak = [ANGLE_NAMES[i] for i in uncertainty.weak]
    if weak:
        warnings.append(f"{where}{_undetermined(weak)}")
    unexplained = None  # with an angle on its bound the bound is the first cause, said above
    if not any(active):
        unexplained = _unexplained(samples, moments, reference, math.sqrt(after["objective"]))
    if unexplained:
        warnings.append(f"{where}{unexplained}")
    result = Inversion(
        angles_deg=angles,
        angles_std_deg=uncertainty.standard_errors,
        variant="spread" if reference is None else "reference",
        field_nT=reference,
        n_samples=n,
        objective_nT2=after["objective"],
        rms_before_nT=math.sqrt(before["objective"]),
        rms_after_nT=math.sqrt(after["objective"]),
        corrected_mean_nT=after["mean"],
        bound_deg=bounds,
        bound_active=active,
        status=outcome.status,
        success=outcome.success,
        iterations=outcome.iterations,
        warnings=warnings,
        source=source,
        not_identifiable=weak,
    )
    if weak and require_identifiable:
        raise QualityError(f"{where}{_undetermined(weak)}", "Not_Identifiable", result=result)
    if unexplained and require_explained:
        raise QualityError(
            f"{where}{unexplained}",
            "Model_Unexplained",
            result=result,
            overrides={"require_explained": False},
        )
    return result


def _checked_samples(samples, bound_deg, start_deg) -> tuple:
    """The samples [nT], bounds [deg] and start [deg] of an inversion, checked: enough samples,
    the start within the bounds (InputError otherwise)."""
    samples = validation.samples(
        samples, minimum=MIN_INVERSION_SAMPLES, purpose="attitudes to invert three angles"
    )
    bounds = validation.bounds(bound_deg)
    start = validation.angles(start_deg, what="start angles")
    if (np.abs(start) > bounds).any():
        raise InputError(
            f"the start {validation.fmt_list(start)} deg lies outside the bounds "
            f"+-{validation.fmt_list(bounds)} deg"
        )
    return samples, bounds, start


def _nominal_magnitude(samples) -> float:
    """The mean |B'| of the samples [nT]; InputError when any has zero magnitude."""
    magnitude = np.linalg.norm(samples, axis=1)
    nominal = float(np.mean(magnitude))
    if (magnitude <= 1e-9 * nominal).any():
        bad = int((magnitude <= 1e-9 * nominal).sum())
        raise InputError(f"{bad} sample(s) have zero magnitude; drop those rows")
    return nominal


def _solve_angles(moments, before: dict, start, bounds, verbose: bool, where: str):
    """IPOPT's solution for the three angles [deg] within the bounds, the objective scaled by
    its value before; a failed solve is QualityError when the attitudes are the cause, else
    SolveError."""
    scale = moments.length**2 / max(before["objective"], 1e-16 * moments.length**2)
    p = np.concatenate([moment_parameters(moments), [scale]])
    solver = inversion_solver(moments.reference, verbose)
    outcome = solve(solver, x0=start, p=p, lbx=-bounds, ubx=bounds)
    if not outcome.success:  # say so when the attitudes are the cause
        weak = _uncertainty(moments, start, before, spread=moments.reference == "none").weak
        if weak:
            names = [ANGLE_NAMES[i] for i in weak]
            raise QualityError(f"{where}{_undetermined(names)}", "Not_Identifiable")
        raise SolveError(
            f"{where}IPOPT did not converge on the angles", status=outcome.status, result=outcome
        )
    return outcome


def _undetermined(names: list) -> str:
    """The sentence for angles the attitudes leave undetermined."""
    return (
        f"the attitudes do not determine {', '.join(names)}; rotate the probe through "
        f"directions spread over the whole sphere"
    )


def _unexplained(samples, moments, reference, rms_angles: float) -> str | None:
    """Why three angles alone do not explain the samples, or None when they do.

    The noise is the rms of |B1| about its centre left by the nine parameters of Eq. 4 in [2]
    fitted to the same samples: the algebraic ellipsoid fit of the moments
    (`nlpcal.calibration.joint.algebraic_start`), or the sphere fit where it gives no ellipsoid.
    rms_angles : the rms the inversion leaves. [nT]
    """
    theta = algebraic_start(moments)
    theta = joint_start(moments) if theta is None else theta
    full = field_statistics(samples, theta, reference)
    noise = math.sqrt(full["objective"])
    if not rms_angles > UNEXPLAINED_RATIO * max(noise, UNEXPLAINED_FLOOR * full["mean"]):
        return None
    offsets, scales = theta[0:3], theta[3:6]
    spread = "scale errors" if reference is not None else "differences of the axes' scales"
    if reference is None:  # without a reference only the scales' differences are determined
        scales = scales - scales.mean()
    return (
        f"the three angles do not explain the data: their residual ({rms_angles:.4g} nT rms) is "
        f"{rms_angles / max(noise, 1e-300):.3g} times the noise ({noise:.3g} nT rms, what the "
        f"nine parameters of a calibration leave), which finds offsets up to "
        f"{np.abs(offsets).max():.3g} nT and {spread} up to {np.abs(scales).max():.2%}; the "
        f"inversion assumes offsets and scales already removed: calibrate first (nlpcal "
        f"calibrate, then nlpcal apply) and invert the corrected log"
    )


def _uncertainty(moments, angles_deg, after: dict, spread: bool) -> inference.Uncertainty:
    """Standard errors of the angles [deg] from the Hessian of the moment objective, scaled by
    the residual variance with N - p degrees of freedom (p = 4 for the spread variant, whose
    mean is a fourth, implicit parameter; 3 otherwise) and widened for autocorrelation."""
    n = moments.n
    dof = n - (4 if spread else 3)
    hessian = np.asarray(
        inversion_objective(moments.reference)(angles_deg, moment_parameters(moments))[1],
        dtype=float,
    )
    return inference.estimate(
        inference.information_from_hessian(hessian, n),
        residual_variance=n * after["objective"] / max(dof, 1),
        autocorrelation=after["residual_lag1_autocorrelation"],
        dof=dof,
    )


@dataclass
class Repeatability(Document):
    """Several inversions of the same probe (Table 4 in [1]).

    Attributes
    ----------
    runs : list of Inversion
        The inversion of each log.
    mean_angles_deg : numpy.ndarray
        Mean over the runs. [deg]
    deviations_deg : numpy.ndarray
        Each run minus the mean, (runs, 3). [deg]
    max_deviation_deg : numpy.ndarray
        Largest |deviation| per angle. [deg]
    max_abs_deviation_deg : float
        Largest |deviation| over all angles and runs. [deg]
    field_nT : float
        Field at which the deviation is turned into a total-field error. [nT]
    field_source : str
        "reference" (the given field) or "corrected mean" (of all runs).
    implied_worst_case_nT : float
        `implied_worst_case(max_abs_deviation_deg, field_nT)`. [nT]

    References
    ----------
    [1] Wang et al. (2015), see `nlpcal.models.wang2015`.

    Examples
    --------
    >>> import nlpcal
    >>> runs = [nlpcal.invert(nlpcal.synthetic_rotation((0.07, 0.04, 0.1), seed=k)) for k in (0, 1)]
    >>> nlpcal.repeatability(runs).deviations_deg.shape
    (2, 3)
    """

    FORMAT = "nlpcal-orthogonality-repeatability"
    LEGACY_FORMATS = (("schema", "nlpcal.orthogonality.repeatability/1"),)
    WHAT = "nlpcal repeatability file"

    runs: list
    mean_angles_deg: np.ndarray
    deviations_deg: np.ndarray
    max_deviation_deg: np.ndarray
    max_abs_deviation_deg: float
    field_nT: float
    field_source: str
    implied_worst_case_nT: float

    @property
    def warnings(self) -> list:
        return [w for run in self.runs for w in run.warnings]

    @property
    def verdict(self) -> Verdict:
        """The worst of the runs': their failed checks, each with the run it concerns."""
        failures = [
            f"run {k + 1}: {reason}"
            for k, run in enumerate(self.runs)
            for reason in run.verdict.reasons[: run.verdict.failures]
        ]
        return judge(failures, [], self.warnings)

    def body(self) -> dict:
        return {
            "schema": "nlpcal.orthogonality.repeatability/1",
            "angles_deg": [float(a) for a in self.mean_angles_deg],
            "angle_convention": "zhou2010",
            "n_runs": len(self.runs),
            "runs": [run.to_dict() for run in self.runs],
            "mean_angles_deg": [float(a) for a in self.mean_angles_deg],
            "deviations_deg": [[float(v) for v in row] for row in self.deviations_deg],
            "max_deviation_deg": [float(v) for v in self.max_deviation_deg],
            "max_abs_deviation_deg": self.max_abs_deviation_deg,
            "field_nT": self.field_nT,
            "field_source": self.field_source,
            "implied_worst_case_nT": self.implied_worst_case_nT,
            "any_bound_active": any(any(run.bound_active) for run in self.runs),
            "warnings": self.warnings,
        }

    @classmethod
    def from_body(cls, reader: DocumentReader) -> Repeatability:
        runs = [Inversion.from_dict(run, reader.source) for run in reader.items("runs")]
        count = len(runs)
        return cls(
            runs=runs,
            mean_angles_deg=reader.array("mean_angles_deg", (3,)),
            deviations_deg=reader.array("deviations_deg", (count, 3)),
            max_deviation_deg=reader.array("max_deviation_deg", (3,)),
            max_abs_deviation_deg=reader.number("max_abs_deviation_deg", minimum=0.0),
            field_nT=reader.number("field_nT", positive=True),
            field_source=reader.string("field_source"),
            implied_worst_case_nT=reader.number("implied_worst_case_nT", minimum=0.0),
        )


def repeatability(
    runs, reference_field: float | None = None, *, field_nT: float | None = None
) -> Repeatability:
    """Mean, spread and implied total-field error of several inversions of one probe.

    The implied error is the worst case over all directions when every angle is off by the largest
    deviation from the mean (section 3 of [1]: 0.004 deg -> at most 3.8 nT).

    Parameters
    ----------
    runs : sequence of Inversion
        Inversions of the same probe (at least two).
    reference_field : float, optional
        Field for the implied error (`--reference-field`); default the mean corrected field of
        the runs. [nT]
    field_nT : float, optional
        The former name of `reference_field`, still accepted. [nT]

    Returns
    -------
    Repeatability
        The mean angles, each run's deviation from them and the implied error.

    Raises
    ------
    InputError
        Fewer than two runs, or an unusable field.

    References
    ----------
    [1] Wang et al. (2015), see `nlpcal.models.wang2015`.

    Examples
    --------
    >>> import nlpcal
    >>> runs = [
    ...     nlpcal.invert(nlpcal.synthetic_rotation((0.07, 0.04, 0.1), noise_nT=0.5, seed=k))
    ...     for k in range(3)
    ... ]
    >>> spread = nlpcal.repeatability(runs, 55_000.0)
    >>> spread.max_abs_deviation_deg < 0.01  # [deg]
    True
    """
    runs = list(runs)
    if len(runs) < 2:
        raise InputError(f"repeatability needs at least two inversions, got {len(runs)}")
    angles = np.array([run.angles_deg for run in runs], dtype=float)
    mean = angles.mean(axis=0)
    deviations = angles - mean
    max_deviation = np.abs(deviations).max(axis=0)
    field_nT = validation.renamed(reference_field, field_nT, "reference_field", "field_nT")
    if field_nT is None:
        b, source = float(np.mean([run.corrected_mean_nT for run in runs])), "corrected mean"
    else:
        b, source = validation.field(field_nT), "reference"
    largest = float(max_deviation.max())
    return Repeatability(
        runs=runs,
        mean_angles_deg=mean,
        deviations_deg=deviations,
        max_deviation_deg=max_deviation,
        max_abs_deviation_deg=largest,
        field_nT=b,
        field_source=source,
        implied_worst_case_nT=implied_worst_case(largest, b),
    )
