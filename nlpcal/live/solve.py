"""The solve of a live calibration: `calibrate`'s, on the moments of the stream.

`nlpcal.calibration.estimate` solves one calibration problem (`Problem`: samples, reference,
moments, loss, model) by the staged cycle of Fig. 1 in [1] and judges what the data determine.
`calibrate` builds the moments of a log in one pass; here they come from the stream
(`nlpcal.live.accumulator`), and the problem and its stopping rule are the ones `calibrate`
poses with its defaults: the final parameters are `nlpcal calibrate`'s of the recorded stream.
CasADi's `nlpsol` of each block is built once and cached (`nlpcal.nlp.blocks`), so every update
re-solves the same fixed-size problem with new numbers.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from ..calibration import Problem, StopRule
from ..calibration import estimate as estimate_problem
from ..calibration.result import CalibrationResult
from ..calibration.settings import NO_GATE, QualityGate
from ..moments import Moments
from ..nlp.blocks import OPTIONS

#: The forms of Eq. 4 a live calibration estimates (`nlpcal.models.zhou2010.MODELS`): it stops
#: when the one chosen is determined, so the choice is the user's.
LIVE_MODELS = ("full", "diagonal", "offset")
#: The stopping rule of `calibrate` with its defaults (`nlpcal calibrate` without targets).
DEFAULT_RULE = StopRule(every_row_exact=False)


def solve(
    samples, moments: Moments, reference: float | None, model: str, unit: str, final: bool
) -> CalibrationResult:
    """`calibrate`'s solve of the samples' moments.

    samples : (N, 3) the samples the moments hold (for the Table 1 rows, the residuals and the
        coverage `estimate` judges on them). [unit]
    reference : None or the constant field F. [unit]
    unit : the base unit of the samples, nT or raw.
    final : the final solve, `nlpcal calibrate`'s: the staged cycle (its default method), with
        its quality checks (QualityError when the data leave parameters undetermined). False:
        an update, the joint solve of the same objective (the same optimum, reached in a few
        Newton steps from the algebraic start even while the attitudes are still few), every
        result that solved returned.
    Raises SolveError when IPOPT fails.
    """
    problem = Problem(
        samples=samples, reference=reference, moments=moments, ipopt=OPTIONS, model=model
    )
    method, gate = ("staged", QualityGate()) if final else ("joint", NO_GATE)
    return estimate_problem(problem, method, DEFAULT_RULE, unit, quality=gate)
