"""Where a warm calibration of a small log spends its time, and how close it is to its floor.

On N samples (default 2 000: uniform attitudes, 1 nT noise, the reference field given), with the
problems built by one untimed call first, it measures in one process:

- the warm calls nlpcal.calibrate(method="joint") and (method="staged", default stop rules):
  median and spread (min-max) over the repeats;
- the steps of those calls (`nlpcal.calibration`: prepare, solve, diagnose, assemble), each
  timed on its own as `calibrate` runs them;
- the staged cycle's IPOPT solves, re-run stage by stage as the cycle runs them (the same
  starts, the same problems): per solve its iterations, the wall time of the solver's call,
  the part CasADi's timers put in the evaluations of the problem's functions, and IPOPT's own
  time, the rest (with CasADi's wrapper around it; `nlpcal.nlp.solver.SolveOutcome`);
- the floor of each method: the moment pass (`nlpcal.moments.accumulate`), one Table 1 pass
  (`Problem.row`) and, for the staged cycle, its IPOPT solves (joint: the Newton check that
  finishes the algebraic start, IPOPT not running on such a log).

    python benchmarks/bench_small.py [-n 2000] [--repeats 31]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from bench_load import timed  # the benchmarks' folder is the script's

import nlpcal
from nlpcal.calibration import assemble, diagnose, gate, prepare, solve
from nlpcal.calibration.joint import algebraic_start
from nlpcal.calibration.settings import CalibrationSettings
from nlpcal.moments import accumulate
from nlpcal.nlp.blocks import STAGE_ORDER
from nlpcal.nlp.steps import block_step
from nlpcal.simulation import ZHOU2010_FIELD_NT, simulate

FIELD = ZHOU2010_FIELD_NT


def ms(times) -> str:
    """The median and the spread of `times` in milliseconds."""
    return (
        f"{statistics.median(times) * 1e3:.3f} ms ({min(times) * 1e3:.3f}-{max(times) * 1e3:.3f})"
    )


def step_times(samples, method: str, repeats: int) -> dict:
    """The median wall time [s] of each step of a warm `calibrate`, in the order it runs them."""
    settings = CalibrationSettings.of(method=method, reference_field=FIELD)
    times: dict = {name: [] for name in ("prepare", "solve", "diagnose", "assemble + gate")}
    for _ in range(repeats + 1):  # the first builds what is built once
        started = time.perf_counter()
        data = prepare(samples, settings)
        problem = data.problem(settings.model, settings)
        prepared = time.perf_counter()
        solution = solve(problem, method, settings.stop, data.unit)
        solved = time.perf_counter()
        diagnosis = diagnose(problem, solution, method, settings.stop, data.unit)
        diagnosed = time.perf_counter()
        result = assemble(problem, solution, diagnosis, method, data.unit)
        gate(result, problem, diagnosis, settings.gate)
        ended = time.perf_counter()
        for name, span in zip(
            times, (prepared - started, solved - prepared, diagnosed - solved, ended - diagnosed)
        ):
            times[name].append(span)
    return {name: statistics.median(spans[1:]) for name, spans in times.items()}


def staged_solves(samples, repeats: int) -> tuple:
    """(per IPOPT solve of the staged cycle: (stage, cycle, iterations, total, evaluations)
    medians [s]; the number of cycles), from the cycle re-run stage by stage (the same starts
    as the staged solve: every stage from the last)."""
    settings = CalibrationSettings.of(method="staged", reference_field=FIELD)
    moments = prepare(samples, settings).moments
    report = nlpcal.calibrate(samples, method="staged", reference_field=FIELD).solver
    cycles = max(stage.cycle for stage in report.stages)
    runs = []
    for _ in range(repeats + 1):
        theta, solves = np.zeros(9), []
        moments.cache.clear()  # the Newton checks start afresh, as on a new log
        for cycle in range(1, cycles + 1):
            for stage in STAGE_ORDER:
                step = block_step(moments, stage, theta)
                theta = step.theta
                outcome = step.outcome
                if outcome.finished_by == "ipopt" or outcome.status:  # IPOPT ran
                    solves.append(
                        (stage, cycle, step.iterations, outcome.wall_s, outcome.evaluations_s)
                    )
        runs.append(solves)
    table = [
        (*runs[-1][k][:3], *(statistics.median(run[k][j] for run in runs[1:]) for j in (3, 4)))
        for k in range(len(runs[-1]))
    ]
    return table, cycles


def floor_parts(samples, repeats: int) -> dict:
    """Median wall times [s] of what no warm calibration can skip: the moment pass, one Table 1
    pass at the solution, and the joint solve's Newton check of its algebraic start."""
    settings = CalibrationSettings.of(method="joint", reference_field=FIELD)
    data = prepare(samples, settings)
    problem = data.problem("full", settings)
    start = algebraic_start(data.moments)

    def newton_check():
        data.moments.cache.clear()
        return block_step(data.moments, "joint", start)

    theta = newton_check().theta
    parts = {
        "moment pass": lambda: accumulate(samples, FIELD),
        "Table 1 pass": lambda: problem.row("final", theta, iterations=0, wall_s=0.0),
        "joint Newton check": newton_check,
    }
    return {name: statistics.median(timed(call, repeats)) for name, call in parts.items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", type=float, default=2000, help="samples of the log")
    parser.add_argument("--repeats", type=int, default=31)
    args = parser.parse_args(argv)
    samples = simulate(int(args.n), noise=1.0, seed=1).to_numpy()
    print(f"# N = {int(args.n)}, reference field given; medians (min-max) of {args.repeats} calls")
    warm = {}
    for method in ("joint", "staged"):
        call = lambda m=method: nlpcal.calibrate(samples, method=m, reference_field=FIELD)  # noqa: E731
        call()
        warm[method] = timed(call, args.repeats)
        print(f"warm {method}: {ms(warm[method])}")
        split = step_times(samples, method, args.repeats)
        print("  steps: " + ", ".join(f"{k} {v * 1e3:.3f} ms" for k, v in split.items()))
    table, cycles = staged_solves(samples, args.repeats)
    print(f"staged cycle ({cycles} cycles): its IPOPT solves, CasADi's timers, medians [ms]")
    print("stage | cycle | iterations | solve | function evaluations | IPOPT's own")
    for stage, cycle, iterations, total, evaluations in table:
        print(
            f"{stage} | {cycle} | {iterations} | {total * 1e3:.3f} | {evaluations * 1e3:.3f} | "
            f"{(total - evaluations) * 1e3:.3f}"
        )
    ipopt = sum(row[3] for row in table)
    own = sum(row[3] - row[4] for row in table)
    print(
        f"{len(table)} solves, {sum(row[2] for row in table)} iterations: {ipopt * 1e3:.3f} ms, "
        f"of which IPOPT's own {own * 1e3:.3f} ms"
    )
    parts = floor_parts(samples, args.repeats)
    print("floor parts: " + ", ".join(f"{k} {v * 1e3:.3f} ms" for k, v in parts.items()))
    floors = {
        "joint": parts["moment pass"] + parts["Table 1 pass"] + parts["joint Newton check"],
        "staged": parts["moment pass"] + parts["Table 1 pass"] + ipopt,
    }
    for method, floor in floors.items():
        median = statistics.median(warm[method])
        print(f"{method}: floor {floor * 1e3:.3f} ms; the warm call is {median / floor:.2f} x it")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
