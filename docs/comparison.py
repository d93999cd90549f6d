"""Regenerate the figures and tables of docs/comparison.md with one command:

    python docs/comparison.py            # rewrite the figures and the generated blocks
    python docs/comparison.py --check    # compare at the printed resolution; exit 1 on drift

For each attitude set of `nlpcal.simulation.ATTITUDES`, a log of the `zhou2010` preset (the final
parameters and field of Zhou et al. 2010) is simulated with a fixed seed and compared by
`nlpcal.comparison.compare`. The script writes docs/figures/compare_<set>.png (Fig. 2 of the paper
plus the convergence of every method) and replaces the blocks between
`<!-- BEGIN generated:name -->` and `<!-- END generated:name -->` in docs/comparison.md. The
prose around the blocks is written by hand; read it again when the numbers change.
Needs matplotlib (pip install 'nlpcal[plot]').
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing

from generated import check_page, check_parser, replace_block, update_page  # noqa: E402
from nlpcal.calibration.joint import joint_start  # noqa: E402
from nlpcal.calibration.problem import Problem  # noqa: E402
from nlpcal.comparison import CompareSettings, compare  # noqa: E402
from nlpcal.comparison.conjugate_gradient import CGOptions, run_cg_joint  # noqa: E402
from nlpcal.moments import accumulate  # noqa: E402
from nlpcal.plots import comparison_png  # noqa: E402
from nlpcal.reproduce.zhou2010 import PAPER_TABLE1  # noqa: E402
from nlpcal.simulation import ATTITUDES, PRESETS, simulate  # noqa: E402

PAGE = HERE / "comparison.md"
FIGURES = HERE / "figures"
#: The simulated logs: the zhou2010 preset, 2000 samples, 1 nT white noise, seed 1.
N, SEED, NOISE = 2000, 1, 1.0
#: Enough cycles to see where the staged method ends on every attitude set.
SETTINGS = CompareSettings(cg=CGOptions(max_iter=5000))  # the default 500 cycles, rtol 1e-9
#: Cycles shown one by one in the tables (the paper shows seven); the last is always shown.
SHOWN_CYCLES = 7
#: Step constants tried for the joint CG on the uniform set (a = factor / lambda_max).
STEP_FACTORS = (0.25, 1.0, 4.0)
#: Largest PNG written. [bytes]
MAX_PNG_BYTES = 200_000


def _row_line(row, extra=True) -> str:
    cells = [row["label"]] + [f"{row[k]:.2f}" for k in ("max", "min", "mean", "std", "range")]
    if extra:
        status = row.get("status", "")
        cells += [f"{row['objective']:.4g}", str(row["iterations"]), f"{row['wall_s']:.3f}", status]
    return "| " + " | ".join(cells) + " |"


HEADER = (
    "| row | max | min | mean | std | range | objective [nT^2] | iterations | wall [s] "
    "| status |\n|---|---|---|---|---|---|---|---|---|---|"
)


def _cycles_shown(rows):
    """The measured row, the first SHOWN_CYCLES cycles and the last."""
    keep = rows[: SHOWN_CYCLES + 1]
    if len(rows) > SHOWN_CYCLES + 1:
        keep = keep + [rows[-1]]
    return keep


def table_for(result) -> str:
    lines = [HEADER]
    for row in _cycles_shown(result.staged):
        lines.append(_row_line(row))
    lines.append(_row_line(result.joint))
    for row in result.cg_joint:
        lines.append(_row_line(row))
    for row in _cycles_shown(result.cg_staged)[1:]:
        lines.append(_row_line(row))
    return "\n".join(lines)


def summary_table(results) -> str:
    lines = [
        "| attitude set | staged: cycles run (stop) | staged: cycles to within 1 % of "
        "joint std | staged std after 7 cycles / joint | joint IPOPT iterations | "
        "CG joint (paper units) | CG joint (scaled) | CG staged: cycles to within 1 % | "
        "iterations, staged IPOPT / CG staged | every CG stage converged |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, result in results.items():
        s = result.summary
        seventh = result.staged[min(SHOWN_CYCLES, len(result.staged) - 1)]["std"]
        cg = s["cg_joint"]

        def cg_cell(v):
            return f"{v['status']}, {v['iterations']} it, std {v['std']:.3g} nT"

        lines.append(
            f"| {name} | {s['staged_cycles']} ({s['staged_stop_reason']}) | "
            f"{s['staged_cycles_to_joint'] if s['staged_cycles_to_joint'] else 'not reached'} | "
            f"{seventh / result.joint['std']:.3g} | {s['joint_iterations']} | "
            f"{cg_cell(cg['unscaled'])} | {cg_cell(cg['scaled'])} | "
            f"{s['cg_staged_cycles_to_joint'] if s['cg_staged_cycles_to_joint'] else 'not reached'}"
            f" | {s['staged_iterations']} / {s['cg_staged_iterations']} | "
            f"{'yes' if s['cg_staged_all_stages_converged'] else 'no'} |"
        )
    return "\n".join(lines)


def coupling_table(results) -> str:
    lines = [
        "| attitude set | rho (Gauss-Seidel) | rho^2 per cycle | cycles for 1e-6 | "
        "orthogonal-scale | orthogonal-offset | scale-offset |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, result in results.items():
        c = result.summary["block_coupling"]
        cc = c["canonical_correlations"]
        cycles = "-" if c["cycles_per_1e6"] is None else f"{c['cycles_per_1e6']:.0f}"
        lines.append(
            f"| {name} | {c['rho']:.4f} | {c['rho_squared']:.4f} | {cycles} | "
            f"{cc['orthogonal-scale']:.3f} | {cc['orthogonal-offset']:.3f} | "
            f"{cc['scale-offset']:.3f} |"
        )
    return "\n".join(lines)


def cg_sensitivity(samples) -> str:
    """The joint CG in paper units for a few step constants, from the joint start and from 0."""
    problem = Problem(samples=samples, reference=None, moments=accumulate(samples))
    lines = [
        "| start | step factor (a = factor / lambda_max) | status | iterations | std [nT] |",
        "|---|---|---|---|---|",
    ]
    for start_name, start in (
        ("sphere fit (as joint IPOPT)", joint_start(problem.moments)),
        ("zero (as the staged cycle)", np.zeros(9)),
    ):
        for factor in STEP_FACTORS:
            options = replace(SETTINGS.cg, step_factor=factor)
            _, row, _ = run_cg_joint(problem, start, options)
            lines.append(
                f"| {start_name} | {factor:g} | {row['status']} | {row['iterations']} | "
                f"{row['std']:.2f} |"
            )
    return "\n".join(lines)


def paper_table() -> str:
    lines = ["| row | max | min | mean | std | range |", "|---|---|---|---|---|---|"]
    for label, *values in PAPER_TABLE1:
        lines.append("| " + " | ".join([label] + [f"{v:.2f}" for v in values]) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = check_parser(__doc__.splitlines()[0]).parse_args(argv)
    FIGURES.mkdir(exist_ok=True)
    preset = PRESETS["zhou2010"]
    results, blocks = {}, {}
    for name in ATTITUDES:
        started = time.perf_counter()
        samples = simulate(
            N,
            parameters=preset.parameters,
            field=preset.field,
            noise=NOISE,
            seed=SEED,
            attitudes=name,
        ).to_numpy()
        result = compare(samples, settings=SETTINGS)
        results[name] = result
        png = comparison_png(
            result,
            title=f"zhou2010 preset, {name} attitudes, N = {N}, seed {SEED}, noise {NOISE:g} nT",
        )
        if len(png) > MAX_PNG_BYTES:
            raise SystemExit(f"compare_{name}.png is {len(png)} bytes, above {MAX_PNG_BYTES}")
        if not args.check:
            (FIGURES / f"compare_{name}.png").write_bytes(png)
        blocks[f"table-{name}"] = table_for(result)
        print(
            f"{name}: {time.perf_counter() - started:.1f} s, {len(png) // 1024} kB", file=sys.stderr
        )
        if name == "uniform":
            blocks["cg-sensitivity"] = cg_sensitivity(samples)
    blocks["summary"] = summary_table(results)
    blocks["coupling"] = coupling_table(results)
    blocks["paper-table1"] = paper_table()
    page = PAGE.read_text()
    text = page
    for name, body in blocks.items():
        text = replace_block(text, name, body, str(PAGE))
    if args.check:
        return check_page(PAGE, text, "docs/comparison.py", page)
    update_page(PAGE, text, check=False, script="docs/comparison.py")
    print(f"wrote {len(results)} figures in {FIGURES}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
