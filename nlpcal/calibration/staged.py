"""The staged cycle of Fig. 1 in [1]: orthogonal -> scale -> offset, repeated.

Steps of Fig. 1: (1) the angles from the raw data, the other blocks at zero; (2)-(3) the scales
from the orthogonality-corrected data; (4)-(5) the offsets from the data corrected for angles and
scales; (6) the full correction; (7) stop if the quality index (range or std of |B1|) meets its
target; (8)-(9) otherwise re-solve the angles with the latest scales and offsets and cycle. Every
correction is applied to the raw data: each stage minimises the objective of the raw samples with
the other six parameters held at their latest values.

Each stage is one of the three block problems of `nlpcal.nlp.blocks`, built once and re-solved.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..defaults import CYCLES_DEFAULT, RTOL_DEFAULT
from ..nlp.blocks import STAGE_ORDER, variables
from ..nlp.steps import block_step
from ..results import TableRow
from .result import BlockSolve

#: The prediction of the rtol rule (`cycles_to_converge`) reads the rate of convergence from the
#: last RATE_WINDOW ratios of successive decreases of the objective, and trusts it only when they
#: agree within RATE_STEADY and do not fall (a rate still speeding up is a transient, and the
#: cycle may yet converge fast). A steady linear rate that is only slowing down, as block
#: coordinate descent on coupled blocks does, makes the prediction a lower bound on the cycles
#: needed; the cycle stops when even that exceeds the limit by PREDICTION_MARGIN. On the bundled
#: log, the real logs and the simulated attitude sets (2000 samples, 1 and 5 nT of noise, seeds
#: 1-3) no prediction ever exceeded the cycles the rule then took. [1]
RATE_WINDOW = 6
RATE_STEADY = 1e-4
#: Ratios that differ by less than this fraction are equal: the rounding of the objectives. [1]
RATE_ROUNDING = 1e-9
PREDICTION_MARGIN = 1.1


@dataclass(frozen=True)
class StopRule:
    """Stop rules of step 7 of Fig. 1 in [1], for the staged cycle of `calibrate`.

    Attributes
    ----------
    max_cycles : int
        The most cycles to run (`--cycles`).
    target_std : float, optional
        Stop when the std of |B1| is at or below this. [field unit]
    target_range : float, optional
        Stop when max - min of |B1| is at or below this. [field unit]
    rtol : float
        Stop when a cycle lowers the objective by less than this fraction. [1]
    predict : bool
        Stop early, with stop reason "predicted_unconverged", when the rate of convergence shows
        that the rtol rule cannot hold within max_cycles; False runs to the limit. Never with a
        target, a robust loss or rtol = 0.
    every_row_exact : bool
        A pass over the data for the Table 1 row of every cycle; False takes the rows between the
        first and the last cycle from the moments (mean and std of |B1| without max, min and
        range) where they hold, which makes a cycle cost a few small solves whatever N. A target
        is always judged on exact rows.

    References
    ----------
    [1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> import nlpcal
    >>> rule = nlpcal.StopRule(max_cycles=50, rtol=1e-9)
    >>> rule.max_cycles, rule.target_std is None
    (50, True)
    """

    max_cycles: int = CYCLES_DEFAULT
    target_std: float | None = None
    target_range: float | None = None
    rtol: float = RTOL_DEFAULT
    predict: bool = True
    every_row_exact: bool = True


def cycles_to_converge(objectives, rtol: float) -> tuple | None:
    """(rate, cycles) the rtol rule still needs, predicted from the objectives so far, or None.

    objectives : the objective before the first cycle and after every cycle since, f_0 .. f_k.
    The decreases d_j = f_(j-1) - f_j of a linearly converging cycle shrink by a steady rate
    q = d_j / d_(j-1) < 1, so d_(k+m) = d_k q^m, and the rule d <= rtol f holds after
    m = log(rtol f_k / d_k) / log q more cycles (with f_k for the later, smaller f: fewer cycles,
    never more). None until RATE_WINDOW steady, non-falling ratios are seen (see RATE_STEADY).
    """
    f = np.asarray(objectives[-(RATE_WINDOW + 2) :], dtype=float)
    if rtol <= 0 or f.size < RATE_WINDOW + 2:
        return None
    d = -np.diff(f)
    if not (d > 0).all():
        return None
    q = d[1:] / d[:-1]
    falling = (np.diff(q) < -RATE_ROUNDING * q[1:]).any()
    if not (q < 1).all() or falling or q.max() > q.min() * (1 + RATE_STEADY):
        return None
    rate = float(q[-1])
    needed = np.log(rtol * f[-1] / d[-1]) / np.log(rate)
    return rate, max(int(np.ceil(needed)), 1)


def run_staged(problem, rule: StopRule, progress=None, defer: bool = False):
    """Cycle the three stages until a stop rule holds.

    problem : a `nlpcal.calibration.problem.Problem` (samples, moments, reference, loss).
    With a robust loss the cycle first runs least squares until its rtol rule holds (for half of
    the cycles at most), then starts every cycle by reweighting the samples at the latest
    parameters (iteratively reweighted least squares, one reweighting per cycle) until the rule
    holds on the mean loss with the loss scale settled. Reweighting from the second cycle on
    instead takes the weights far from the optimum, and on a log whose offsets the data determine
    weakly (the RM3100 logs of docs/real-data.md) the cycle then crawls along the valley until
    its cycle limit.
    progress : None, or called with (cycle, its Table 1 row) after every cycle (a row left to
        the pass after the solve is shown from the moments where they hold it, else gathered
        now).
    defer : the exact rows no stop rule reads are left to the pass after the solve
        (`Problem.deferred_row`): a least-squares cycle then reads the data in no pass.
    Returns (theta, rows, stages, stop_reason): the last parameters, one Table 1 row per cycle
    (after the measured row), the `BlockSolve` of every stage solve and why the cycle stopped.
    """
    theta = np.zeros(9)  # Fig. 1: the first pass starts with every other block at zero
    # a restricted model has no stage for the blocks it does not estimate (the diagonal model no
    # orthogonal stage; the offset model a scale stage only for its common scale)
    order = [s for s in STAGE_ORDER if variables(s, problem.moments.reference, problem.model).size]
    rows = [problem.measured_row()]
    stages: list = []
    previous = rows[0].objective
    stop_reason = "max_cycles"
    predicting = (
        rule.predict
        and not problem.loss.robust
        and rule.target_std is None
        and rule.target_range is None
    )
    objectives = [previous]
    robust_phase, changed = False, False  # least squares first, then reweighting every cycle
    for cycle in range(1, rule.max_cycles + 1):
        started = time.perf_counter()
        changed = robust_phase and problem.reweight(theta)
        step, iterations = run_cycle(problem, order, theta, cycle, stages)
        theta = step.theta
        wall_s = time.perf_counter() - started
        row = cycle_row(problem, rule, cycle, step, iterations, wall_s, defer)
        rows.append(row)
        if progress is not None:
            progress(cycle, shown_row(problem, row, step, iterations, wall_s))
        target = target_met(rule, row)
        if target:
            stop_reason = target
            break
        if robust_phase:  # the mean loss, from an exact row
            current = row.robust_objective
        else:  # the exact objective of the row, or the moments' when rows come from them
            current = row.objective if rule.every_row_exact else step.f_end
        settled = previous is not None and previous - current <= rule.rtol * previous
        if settled and not changed and (robust_phase or not problem.loss.robust):
            stop_reason = "rtol"
            break
        if problem.loss.robust and not robust_phase and (settled or 2 * cycle >= rule.max_cycles):
            robust_phase, current = True, None  # least squares has converged (or half the
            # cycles are spent, which leaves the other half to the loss): reweight
        previous = current
        objectives.append(current)
        predicted = cycles_to_converge(objectives, rule.rtol) if predicting else None
        if predicted and cycle + predicted[1] / PREDICTION_MARGIN > rule.max_cycles:
            stop_reason = "predicted_unconverged"
            stages[-1].convergence_rate = predicted[0]
            stages[-1].predicted_cycles = cycle + predicted[1]
            break
    last = rows[-1]
    if last.from_moments:  # the last cycle's row is always exact
        rows[-1] = (problem.deferred_row if defer else problem.row)(
            last.label, theta, step.f_end, iterations=last.iterations, wall_s=last.wall_s
        )
    return theta, rows, stages, stop_reason


def run_cycle(problem, order: list, theta, cycle: int, stages: list):
    """One cycle of Fig. 1 in [1]: each stage of `order` solved in turn from the latest
    parameters, its `BlockSolve` appended to `stages`. Returns (the last stage's
    `nlpcal.nlp.steps.Step`, IPOPT's iterations over the cycle)."""
    iterations = 0
    for stage in order:
        step = block_step(problem.moments, stage, theta, problem.ipopt, model=problem.model)
        theta = step.theta
        iterations += step.iterations
        stages.append(BlockSolve.of(step, cycle, stage))
    return step, iterations


def cycle_row(
    problem, rule: StopRule, cycle: int, step, iterations: int, wall_s: float, defer=False
) -> TableRow:
    """The Table 1 row of a cycle: from the moments where `rule` and the problem let it
    (`StopRule.every_row_exact`, `Problem.rows_from_moments`; never the first cycle, nor with a
    target), else exact: from a pass over the data now where a stop rule reads it (every row
    exact, a target, a robust loss's objective), else with `defer` from the pass after the
    solve."""
    targets = rule.target_range is not None or rule.target_std is not None
    exact = rule.every_row_exact or cycle == 1 or targets or not problem.rows_from_moments
    label = f"cycle {cycle}"
    row = (
        None
        if exact
        else problem.moment_row(label, step.theta, iterations=iterations, wall_s=wall_s)
    )
    if row is None:
        later = defer and not (rule.every_row_exact or targets or problem.loss.robust)
        make = problem.deferred_row if later else problem.row
        row = make(label, step.theta, step.f_end, iterations=iterations, wall_s=wall_s)
    return row


def shown_row(problem, row: TableRow, step, iterations: int, wall_s: float) -> TableRow:
    """What the progress of a cycle shows of its row: the row; one left to the pass after the
    solve (no statistics yet) from the moments where they hold it, else gathered now (a pass)
    and no longer left to that pass."""
    if row.std is not None:
        return row
    shown = problem.moment_row(row.label, step.theta, iterations=iterations, wall_s=wall_s)
    if shown is not None:
        return shown
    problem.deferred = [entry for entry in problem.deferred if entry[0] is not row]
    problem.fill_row(row, step.theta, step.f_end, problem.statistics(step.theta))
    return row


def target_met(rule: StopRule, row: TableRow) -> str | None:
    """The stop reason of a target of step 7 of Fig. 1 in [1] that a cycle's row meets, or
    None."""
    if rule.target_std is not None and row.std is not None and row.std <= rule.target_std:
        return "target_std"
    if rule.target_range is not None and row.range is not None and row.range <= rule.target_range:
        return "target_range"
    return None
