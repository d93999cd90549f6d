"""`model="auto"`: the richest form of Eq. 4 in [1] that the attitudes of a log determine.

The forms (`nlpcal.models.zhou2010.MODELS`) are tried from the richest down: the nine parameters,
then offsets and scales, then offsets alone (with a reference, and one common scale). A form is
taken when its calibration solves and the identifiability checks that judge every calibration
(`nlpcal.calibration.diagnostics`, `nlpcal.calibration.coverage`) find that the attitudes
determine it:

* no parameter is left undetermined: no direction along which |B1| does not change, no standard
  error above `diagnostics.UNDETERMINED`, and the samples do not lie (nearly) in one plane;
* and, where the corrected field visits fewer than `coverage.COVERAGE_WARN` of the 26 direction
  bins (a cap of the sphere), no parameter is poorly determined (a standard error above
  `diagnostics.POORLY_DETERMINED`): on a cap a richer form trades its extra parameters against
  each other, and the data cannot tell them apart.

Parameters poorly determined on a log that covers the sphere are the noise's doing, not the
attitudes': a smaller model would not determine them better, only bias them, so the form is kept
(with its warning). When no form is determined, the smallest is returned, with the warnings of
its own calibration (and its quality check).

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from collections.abc import Callable

from ..errors import SolveError
from ..models.zhou2010 import MODELS
from .coverage import COVERAGE_WARN
from .result import CalibrationResult

#: What `calibrate(model=...)` accepts: a form of Eq. 4, or "auto".
MODEL_CHOICES = (*MODELS, "auto")
#: What each form estimates, in words.
ESTIMATES = {
    "full": "all nine parameters",
    "diagonal": "offsets and scales (no angles)",
    "offset": "the offsets (with a reference, one common scale)",
}


def undetermined_by_attitudes(result: CalibrationResult) -> str | None:
    """Why the attitudes of a calibration's log do not determine its form, or None."""
    identifiability = result.identifiability
    weak = identifiability.not_identifiable or []
    if identifiability.planar:
        return f"the samples lie (nearly) in one plane, leaving {', '.join(weak)} undetermined"
    if weak:
        return f"the data leave {', '.join(weak)} undetermined"
    coverage = identifiability.coverage or {}
    poorly = identifiability.poorly_determined or []
    if coverage.get("fraction", 1.0) < COVERAGE_WARN and poorly:
        return (
            f"the field visits {coverage['covered']} of 26 direction bins, and on that cap "
            f"{', '.join(poorly)} are poorly determined"
        )
    return None


def choose_model(trial: Callable[[str], CalibrationResult]) -> tuple[str, dict]:
    """The richest form the attitudes determine, and the record of the choice.

    trial : form -> its calibration (without the quality checks; raises SolveError when the
        solve fails).
    Returns (form, {"requested": "auto", "chosen", "reason", "rejected": [{"model", "reason"}]}).
    """
    rejected = []
    for form in reversed(MODELS):
        try:
            why = undetermined_by_attitudes(trial(form))
        except SolveError as failure:
            status = f" ({failure.status})" if failure.status else ""
            why = f"the solve failed{status}"
        if why is None:
            break
        rejected.append({"model": form, "reason": why})
    reason = f"the attitudes determine {ESTIMATES[form]}"
    if rejected:
        richer = "; ".join(f"{r['model']}: {r['reason']}" for r in rejected if r["model"] != form)
        reason = (
            f"{reason}; richer models are not determined ({richer})"
            if why is None
            else f"no model is determined by the attitudes ({richer}; {form}: {why}); the "
            f"smallest is used"
        )
    return form, {"requested": "auto", "chosen": form, "reason": reason, "rejected": rejected}


def selection_warning(selection: dict) -> str:
    """The warning of a restricted model chosen by "auto": which, why, and what is fixed."""
    return (
        f"model auto chose {selection['chosen']}: {selection['reason']}; the parameters it does "
        f"not estimate are fixed at zero, so the correction assumes them"
    )


#: The level of the test of a restricted form against the full one: the fixed parameters are
#: declared not zero when data of a sensor that obeys the form would give a larger F this rarely.
RESTRICTION_LEVEL_Z = 3.09  # the standard normal quantile of 1 - 0.001
#: ... and when the full form's residual spread is smaller by more than this fraction: a
#: difference too small to matter is not reported, however significant.
RESTRICTION_SPREAD = 0.05


def restriction_warning(restricted: CalibrationResult, full: CalibrationResult, freed: tuple):
    """A warning when a log contradicts the parameters a restricted form fixes, or None.

    The variance of |B1| (the objective of Eq. 8) falls from f_r to f_f when the full form frees
    `freed` = (q_f, q_r) directions more; under the restricted form, F = ((f_r - f_f) / (q_f -
    q_r)) / (f_f / (N - q_f)) is about chi-squared on q_f - q_r degrees of freedom over those
    degrees, whose 1 - 0.001 quantile is taken by the Wilson-Hilferty approximation [2]. The
    fixed parameters then bias the others by what they leave out.

    [2] Wilson, E. B. and Hilferty, M. M. (1931), The distribution of chi-square, PNAS 17(12),
        684-688, doi:10.1073/pnas.17.12.684.
    """
    q_full, q_restricted = freed
    df = q_full - q_restricted
    f_r = restricted.statistics[-1].objective or 0.0  # every solved row has one
    f_f = full.statistics[-1].objective or 0.0
    n = restricted.n_samples
    if df <= 0 or not f_f > 0 or n <= q_full or not f_r > f_f:
        return None
    statistic = (f_r - f_f) / df / (f_f / (n - q_full))
    a = 2.0 / (9.0 * df)
    critical = (1.0 - a + RESTRICTION_LEVEL_Z * a**0.5) ** 3  # chi2 quantile / df, Eq. in [2]
    spread_r, spread_f = restricted.statistics[-1].std or 0.0, full.statistics[-1].std or 0.0
    if statistic <= critical or spread_r <= (1.0 + RESTRICTION_SPREAD) * spread_f:
        return None
    fixed = ", ".join(restricted.fixed_parameters)
    return (
        f"these data contradict the {restricted.model_name} model, which fixes {fixed}: the "
        f"full model's residual spread is {spread_f:.3g} {restricted.unit} against "
        f"{spread_r:.3g} here (F = {statistic:.3g} on {df} parameters), so the estimated "
        f"parameters carry the bias of what it leaves out; use --model full (or auto)"
    )
