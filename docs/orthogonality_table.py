"""Regenerate the tables and the figure of docs/orthogonality.md (seed 003, Wang et al. 2015).

    python docs/orthogonality_table.py            # rewrite the generated blocks and the figure
    python docs/orthogonality_table.py --check    # exit 1 if the page's tables are out of date
    python docs/orthogonality_table.py --no-figure

Each table is written between `<!-- BEGIN generated:NAME -->` and `<!-- END generated:NAME -->` in
the page; everything else in the page is left as it is. The figure needs matplotlib (the `plot`
extra). All numbers are deterministic (fixed seeds).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from generated import replace_block, update_page
from nlpcal import orthogonality as ortho
from nlpcal.models import wang2015

HERE = Path(__file__).resolve().parent
PAGE = HERE / "orthogonality.md"
FIGURE = HERE / "figures" / "orthogonality_map.png"
FIELD = ortho.PAPER_FIELD_NT  # [nT]

#: Typical angle sets (alpha, beta, gamma) [deg] for the forward-modelling table (Table 1 of the
#: paper; its own rows were an image and are lost, so these are chosen to show the pattern).
TYPICAL_ANGLES = (
    (0.01, 0.01, 0.01),
    (0.05, 0.05, 0.05),
    (0.1, 0.0, 0.0),
    (0.0, 0.1, 0.0),
    (0.0, 0.0, 0.1),
    (0.1, 0.1, 0.0),
    (0.1, -0.1, 0.1),
    (0.1, 0.1, 0.1),
    (0.2, 0.2, 0.2),
    (0.5, 0.5, 0.5),
    (1.0, 1.0, 1.0),
    (0.07, 0.04, 0.1),
    (0.064, 0.0, 0.103),
    (-2.34, 1.29, -0.27),
)
PAPER_ANGLES = wang2015.PAPER_SYNTHETIC_ANGLES_DEG  # the synthetic inversion of section 2 [deg]
#: The paper's real probe (section 3), beta not given: 0. [deg]
REPEAT_ANGLES = tuple(wang2015.PAPER_PROBE_ANGLES_DEG.get(name, 0.0) for name in ortho.ANGLE_NAMES)


def _g(value, digits=4) -> str:
    return f"{value:.{digits}f}"


def forward_table() -> str:
    rows = [
        "| alpha [deg] | beta [deg] | gamma [deg] | max abs dB [nT] | largest dB [nT] "
        "at (theta, phi) [deg] | most negative dB [nT] at (theta, phi) [deg] | "
        "small-angle value [nT] |",
        "|---:|---:|---:|---:|---|---|---:|",
    ]
    for angles in TYPICAL_ANGLES:
        w = ortho.worst_case(angles, FIELD)
        pos, neg = w.largest_positive, w.most_negative
        rows.append(
            f"| {angles[0]:g} | {angles[1]:g} | {angles[2]:g} | {_g(w.max_abs_error_nT, 2)} | "
            f"{pos.delta_B_nT:+.2f} at ({pos.theta_deg:.1f}, {pos.phi_deg:.1f}) | "
            f"{neg.delta_B_nT:+.2f} at ({neg.theta_deg:.1f}, {neg.phi_deg:.1f}) | "
            f"{_g(w.small_angle_nT, 2)} |"
        )
    return "\n".join(rows)


def inversion_table() -> str:
    rows = [
        "| variant | noise per axis [nT] | alpha [deg] | beta [deg] | gamma [deg] | "
        "largest error [deg] | IPOPT iterations | rms of dB before -> after [nT] |",
        "|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for noise in (0.0, 1.0, 5.0):
        data = ortho.synthetic_rotation(PAPER_ANGLES, FIELD, n=500, noise_nT=noise, seed=7)
        for field in (None, FIELD):
            r = ortho.invert(data, field_nT=field, bound_deg=0.5, start_deg=(0, 0, 0))
            error = float(np.abs(r.angles_deg - PAPER_ANGLES).max())
            a, b, g = r.angles_deg
            # below 1e-9 deg and 1e-6 nT the digits are rounding noise that differs by platform
            error_text = "< 1e-9" if error < 1e-9 else f"{error:.1e}"
            after_text = "< 1e-6" if r.rms_after_nT < 1e-6 else f"{r.rms_after_nT:.3g}"
            rows.append(
                f"| {r.variant} | {noise:g} | {a:.6f} | {b:.6f} | {g:.6f} | {error_text} | "
                f"{r.iterations} | {r.rms_before_nT:.2f} -> {after_text} |"
            )
    return "\n".join(rows)


def repeatability_table() -> str:
    runs = [
        ortho.invert(
            ortho.synthetic_rotation(REPEAT_ANGLES, FIELD, n=400, noise_nT=10.0, seed=100 + k)
        )
        for k in range(5)
    ]
    report = ortho.repeatability(runs, field_nT=FIELD)
    rows = [
        "| run | alpha [deg] | beta [deg] | gamma [deg] | deviation from the mean, largest [deg] |",
        "|---|---:|---:|---:|---:|",
    ]
    for k, (run, dev) in enumerate(zip(runs, report.deviations_deg), start=1):
        a, b, g = run.angles_deg
        rows.append(f"| {k} | {a:.5f} | {b:.5f} | {g:.5f} | {np.abs(dev).max():.5f} |")
    a, b, g = report.mean_angles_deg
    rows.append(f"| mean | {a:.5f} | {b:.5f} | {g:.5f} | {report.max_abs_deviation_deg:.5f} |")
    rows.append("")
    rows.append(
        f"Largest deviation {report.max_abs_deviation_deg:.5f} deg -> worst-case "
        f"total-field error {report.implied_worst_case_nT:.2f} nT at {FIELD:g} nT. "
        f"The paper's 0.004 deg gives "
        f'{ortho.implied_worst_case(0.004, FIELD):.2f} nT ("at most 3.8 nT").'
    )
    return "\n".join(rows)


BLOCKS = {
    "forward": forward_table,
    "inversion": inversion_table,
    "repeatability": repeatability_table,
}


def render(page: str) -> str:
    for name, make in BLOCKS.items():
        page = replace_block(page, name, make(), str(PAGE))
    return page


def write_figure() -> None:
    from nlpcal.io import write_bytes_atomic
    from nlpcal.plots import orthogonality_map_png

    angles = (0.1, 0.1, 0.1)
    theta, phi, error = ortho.error_map(angles, FIELD, step_deg=1.0)
    worst = ortho.worst_case(angles, FIELD)
    png = orthogonality_map_png(angles, FIELD, theta, phi, error, worst, dpi=80)
    FIGURE.parent.mkdir(exist_ok=True)
    write_bytes_atomic(FIGURE, png)
    print(f"wrote {FIGURE.relative_to(HERE.parent)} ({len(png) // 1024} kB)", file=sys.stderr)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--check",
        action="store_true",
        help="only compare the page's tables with freshly computed ones",
    )
    parser.add_argument("--no-figure", action="store_true", help="do not redraw the figure")
    args = parser.parse_args(argv)
    status = update_page(
        PAGE, render(PAGE.read_text()), check=args.check, script="docs/orthogonality_table.py"
    )
    if not (args.check or args.no_figure):
        write_figure()
    return status


if __name__ == "__main__":
    sys.exit(main())
