"""`nlpcal compare`: staged cycle vs joint IPOPT vs the paper's conjugate gradient on one log.

    nlpcal compare LOG [--cycles K] [--reference-field F | --reference-column COL]
                   [--columns X Y Z] -o compare.json [--plot compare.png]

JSON keys: "staged" (measured row, then one per cycle), "joint" (one row), "cg_joint" (the
conjugate gradient on all nine: paper units, then scaled), "cg_staged" (measured row, then one per
cycle); every row has max, min, mean, std, range, objective, iterations and wall_s. The Table 1
layout goes to stderr. Exit status: 0 success (a conjugate gradient that does not converge is a
finding, reported as a warning), 1 the solve failed, 2 bad usage or input (also --plot without
matplotlib).
"""

from __future__ import annotations

from pathlib import Path

from ..defaults import CYCLES_DEFAULT, RTOL_DEFAULT
from .calibrate import ipopt_option
from .common import (
    add_command,
    add_log_arguments,
    add_loss_arguments,
    add_reference_arguments,
    add_threads_argument,
    log_options,
    report_log,
    say,
    solver_log,
    tell_written,
    warning,
)


def register(sub):
    parser = add_command(
        sub,
        "compare",
        help="compare the solvers on one log: staged cycle, joint solve, the paper's gradient",
        description="""\
Run, on the same log, the three ways of finding the nine parameters of 'nlpcal calibrate':
the staged cycle of Zhou et al. (2010) Fig. 1 with IPOPT for each stage, one joint IPOPT solve
of all nine, and the paper's own conjugate-gradient method (section 5), jointly and stage by
stage. Prints the |B| statistics of each (the paper's Table 1) on stderr, writes them as JSON,
and with --plot draws |B1| after each cycle, before and after calibration, and the objective
against solver iterations. A conjugate gradient that does not converge is a finding, reported
as a warning (exit 0).""",
        examples=(
            "nlpcal compare log.csv -o compare.json --plot compare.png",
            "nlpcal compare mag.txt --unit raw --cycles 20 --plot compare.png",
        ),
    )
    parser.add_argument("log", metavar="LOG", help="the log: delimited text, or - for stdin")
    add_log_arguments(parser)
    parser.add_argument(
        "--cycles",
        type=int,
        default=CYCLES_DEFAULT,
        metavar="K",
        help=f"most cycles of the staged and conjugate-gradient staged runs (default "
        f"{CYCLES_DEFAULT}, as calibrate); both stop earlier when a cycle no longer lowers the "
        f"objective",
    )
    parser.add_argument(
        "--rtol",
        type=float,
        default=RTOL_DEFAULT,
        metavar="R",
        help="stop a cycle run when the objective improves by less than this "
        f"fraction (default {RTOL_DEFAULT:g})",
    )
    parser.add_argument(
        "--cg-max-iter",
        type=int,
        default=5000,
        metavar="N",
        help="iteration cap of every conjugate-gradient solve (default 5000)",
    )
    parser.add_argument(
        "--cg-step-factor",
        type=float,
        default=1.0,
        metavar="C",
        help="conjugate-gradient step constant a = C / (largest Hessian eigenvalue at the "
        "start), e.g. 0.25 for smaller steps (default 1)",
    )
    parser.add_argument(
        "--cg-rel-eps",
        type=float,
        default=1e-6,
        metavar="R",
        help="stop the conjugate gradient when |grad f| <= R |grad f at the start| (default 1e-6)",
    )
    add_reference_arguments(parser)
    add_loss_arguments(parser)
    add_threads_argument(parser)
    parser.add_argument(
        "--ipopt-option",
        action="append",
        type=ipopt_option,
        metavar="KEY=VALUE",
        help="an IPOPT option for the staged and joint solves, as for calibrate (repeatable); "
        "the comparison records every IPOPT option under settings.ipopt_options",
    )
    parser.add_argument(
        "-o", "--output", metavar="COMPARE.json", help="write the JSON here (stdout when absent)"
    )
    parser.add_argument(
        "--plot",
        metavar="COMPARE.png",
        help="write the figure here, a PNG at 150 dpi titled with the log's file name (needs "
        "matplotlib: pip install 'nlpcal[plot]')",
    )
    parser.set_defaults(func=run)


def run(args) -> int:
    from ..comparison import CompareSettings, compare_log
    from ..comparison.conjugate_gradient import CGOptions
    from ..io import Outputs, check_output_path, read_log
    from ..nlp.solver import check_ipopt_options
    from ..plots import comparison_png, require_matplotlib
    from ..results import distinct

    settings = CompareSettings(
        cycles=args.cycles,
        rtol=args.rtol,
        cg=CGOptions(
            step_factor=args.cg_step_factor, rel_eps=args.cg_rel_eps, max_iter=args.cg_max_iter
        ),
    )
    ipopt_options = distinct(args.ipopt_option or (), "--ipopt-option", "option") or None
    if ipopt_options:  # checked before the log is read
        check_ipopt_options(ipopt_options)
    check_output_path(args.output, args.log)
    check_output_path(args.plot, args.log)
    if args.plot:
        require_matplotlib()
    log = read_log(args.log, **log_options(args))
    report_log(log)
    with solver_log():
        result = compare_log(
            log,
            settings=settings,
            loss=args.loss,
            loss_scale=args.loss_scale,
            threads=args.threads,
            ipopt_options=ipopt_options,
        )
    png = comparison_png(result, title=Path(log.path).name) if args.plot else None
    say(result.table())
    for message in result.warnings:
        warning(message)
    with Outputs() as outputs:
        outputs.json(args.output, result.to_dict())
        if png is not None:
            outputs.bytes(args.plot, png)
    tell_written(args.output, args.plot)
    return 0
