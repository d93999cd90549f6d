"""`nlpcal orthogonality`: worst-case total-field error, error map and angle inversion (seed 003).

    nlpcal orthogonality worst-case --angles-deg A B G --field F [-o out.json] [-v]
    nlpcal orthogonality map --angles-deg A B G --field F [-o map.png] [--csv map.csv|-]
                             [--step-deg 1]
    nlpcal orthogonality invert LOG.csv [LOG2.csv ...] [--field F] [--bound-deg B [B B]]
                             [--columns X Y Z] [--unit nT] [--drop-invalid] [-o out.json] [-v]

Angles are alpha, beta, gamma of Zhou et al. (2010) in degrees; fields in nT. `invert` with two or
more logs of the same probe also reports their repeatability (Table 4 of Wang et al. 2015).
JSON goes to -o or, without it, to stdout; messages and warnings go to stderr. Exit status: 0
success (also when a bound is active: that is a warning), 1 IPOPT failed, 2 bad usage or input.
"""

from __future__ import annotations

import contextlib
import io as _stdio
import sys

import numpy as np
import pandas as pd

from .. import orthogonality as ortho
from ..errors import InputError
from ..io import check_output_path, write_bytes_atomic
from . import emit_csv, emit_json
from .core import read_log

PLOT_HINT = "pip install 'nlpcal[plot]'"


def register(sub):
    parser = sub.add_parser(
        "orthogonality", help="non-orthogonality: worst-case error, error map, angle inversion",
        description=__doc__.splitlines()[0].split(": ", 1)[1])
    inner = parser.add_subparsers(dest="orthogonality_command", metavar="SUBCOMMAND")
    inner.required = True

    worst = inner.add_parser(
        "worst-case", help="largest total-field error over all field directions",
        description="Largest positive and most negative total-field error |TB| - |B| over all "
                    "directions (theta, phi), solved with IPOPT from several starts and "
                    "certified by the singular values of T.")
    _add_angles_and_field(worst)
    worst.add_argument("-o", "--output", metavar="OUT.json",
                       help="write the JSON here (default: stdout)")
    worst.add_argument("-v", "--verbose", action="store_true", help="show IPOPT's log (on stderr)")

    mapping = inner.add_parser(
        "map", help="theta-phi map and sphere picture of the total-field error",
        description="The total-field error over a (theta, phi) grid: a PNG with the sphere "
                    "(Fig. 3 of Wang et al. 2015) and the theta-phi map (Fig. 4), and/or a CSV "
                    "with columns theta_deg, phi_deg, delta_B_nT.")
    _add_angles_and_field(mapping)
    mapping.add_argument("-o", "--output", metavar="MAP.png",
                         help="write the figure here (needs matplotlib: " + PLOT_HINT + ")")
    mapping.add_argument("--csv", metavar="MAP.csv", help="write the grid here ('-': stdout)")
    mapping.add_argument("--step-deg", type=float, default=1.0, metavar="DEG",
                         help="grid step in theta and phi, in (0, 10] [deg] (default 1)")

    invert = inner.add_parser(
        "invert", help="the three angles from rotation logs (bounded IPOPT problem)",
        description="Invert alpha, beta, gamma from logs of a probe rotated in a constant field "
                    "(unit sensitivities and zero offsets assumed). With --field, the corrected "
                    "total field is fitted to that field; without it, its spread around the mean "
                    "is minimised (the paper's objective). With two or more logs of the same "
                    "probe, also reports the mean, the largest deviation from it and the "
                    "worst-case total-field error that deviation implies. Give the logs "
                    "before --bound-deg/--columns (or end those with --).")
    invert.add_argument("logs", nargs="+", metavar="LOG.csv", help="rotation log(s), CSV")
    invert.add_argument("--field", type=float, metavar="NT",
                        help="known total field for the reference variant [nT]")
    invert.add_argument("--bound-deg", type=float, nargs="+", default=[ortho.DEFAULT_BOUND_DEG],
                        metavar="DEG",
                        help="bound |angle| <= DEG, one value or three (alpha beta gamma) [deg] "
                             f"(default {ortho.DEFAULT_BOUND_DEG:g})")
    invert.add_argument("--columns", nargs="+", metavar="COL",
                        help="the three field columns (default: recognised bx/by/bz, x/y/z, ...)")
    invert.add_argument("--unit", default=None, choices=["nT", "uT", "mT", "mG", "G", "T"],
                        help="unit of the field columns (default: from the column names, "
                             "mx_uT, \"X (uT)\" ..., else nT)")
    invert.add_argument("--drop-invalid", action="store_true",
                        help="drop rows with missing or non-numeric values instead of failing")
    invert.add_argument("-o", "--output", metavar="OUT.json",
                        help="write the JSON here (default: stdout)")
    invert.add_argument("-v", "--verbose", action="store_true", help="show IPOPT's log (on stderr)")

    parser.set_defaults(func=run)


def _add_angles_and_field(parser):
    parser.add_argument("--angles-deg", type=float, nargs=3, required=True,
                        metavar=("ALPHA", "BETA", "GAMMA"),
                        help="non-orthogonality angles, Zhou 2010 convention [deg]")
    parser.add_argument("--field", type=float, required=True, metavar="NT",
                        help="total field magnitude [nT]")


def run(args) -> int:
    handlers = {"worst-case": _run_worst_case, "map": _run_map, "invert": _run_invert}
    return handlers[args.orthogonality_command](args)


# ------------------------------------------------------------------------------------------------


def _run_worst_case(args) -> int:
    angles = ortho.check_angles(args.angles_deg)
    field = ortho.check_field(args.field)
    check_output_path(args.output)
    with _solver_log(args.verbose):
        result = ortho.worst_case(angles, field, verbose=args.verbose)
    emit_json(result.as_dict(), args.output)
    if args.output:
        _info(f"max |dB| = {result.max_abs_error_nT:.4f} nT at theta = "
              f"{result.worst.theta_deg:.2f} deg, phi = {result.worst.phi_deg:.2f} deg; "
              f"wrote {args.output}")
    return 0


def _run_map(args) -> int:
    angles = ortho.check_angles(args.angles_deg)
    field = ortho.check_field(args.field)
    if not args.output and not args.csv:
        raise InputError("nothing to write; pass -o MAP.png and/or --csv MAP.csv (or --csv - "
                         "for stdout)")
    if args.output:
        _require_matplotlib()
        check_output_path(args.output)
    if args.csv and args.csv != "-":
        check_output_path(args.csv)
    theta, phi, error = ortho.error_map(angles, field, args.step_deg)
    png = None
    if args.output:
        png = render_map_png(angles, field, theta, phi, error, ortho.worst_case(angles, field))
    table = None
    if args.csv:
        grid_theta, grid_phi = np.meshgrid(theta, phi)
        table = pd.DataFrame({"theta_deg": grid_theta.ravel(), "phi_deg": grid_phi.ravel(),
                              "delta_B_nT": error.ravel()})
    # everything is computed: only now touch the outputs
    if png is not None:
        write_bytes_atomic(args.output, png)
        _info(f"wrote {args.output} (grid max |dB| = {np.abs(error).max():.4f} nT)")
    if table is not None:
        emit_csv(table, None if args.csv == "-" else args.csv, "%.10g")
        if args.csv != "-":
            _info(f"wrote {args.csv} ({len(table)} grid points)")
    return 0


def _run_invert(args) -> int:
    bounds = ortho.check_bounds(args.bound_deg)
    field = None if args.field is None else ortho.check_field(args.field, "reference field")
    check_output_path(args.output)
    samples = [_read_log(path, args.columns, args.unit, args.drop_invalid) for path in args.logs]
    runs = []
    for path, data in zip(args.logs, samples):
        try:
            with _solver_log(args.verbose):
                runs.append(ortho.invert(data, field_nT=field, bound_deg=bounds,
                                         source=str(path), verbose=args.verbose))
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
    if len(runs) == 1:
        result = runs[0]
        document = result.as_dict()
    else:
        result = ortho.repeatability(runs, field_nT=field)
        document = result.as_dict()
    for message in result.warnings:
        _info(f"warning: {message}")
    emit_json(document, args.output)
    if args.output:
        angles = ", ".join(f"{name} = {value:+.5f}" for name, value in
                           zip(ortho.ANGLE_NAMES, document["angles_deg"]))
        extra = ""
        if len(runs) > 1:
            extra = (f"; {len(runs)} runs, largest deviation from the mean "
                     f"{result.max_abs_deviation_deg:.5f} deg -> at most "
                     f"{result.implied_worst_case_nT:.2f} nT")
        _info(f"{angles} deg{extra}; wrote {args.output}")
    return 0


def _read_log(path, columns, unit, drop_invalid) -> np.ndarray:
    """The field samples of one log in nT (unit: --unit, else the column names, else nT)."""
    try:
        return read_log(path, columns, unit, drop_invalid).samples
    except InputError as exc:
        message = str(exc)
        raise InputError(message if message.startswith(str(path)) else f"{path}: {message}") \
            from None


# ------------------------------------------------------------------------------------------------
# output


def _solver_log(verbose: bool):
    """With -v, IPOPT's log (printed through Python's stdout by CasADi) goes to stderr."""
    return contextlib.redirect_stdout(sys.stderr) if verbose else contextlib.nullcontext()


def _info(message: str) -> None:
    print(f"nlpcal orthogonality: {message}", file=sys.stderr)


# ------------------------------------------------------------------------------------------------
# figures (matplotlib is optional: the `plot` extra)


def _require_matplotlib():
    try:
        import matplotlib  # noqa: F401
        from matplotlib.figure import Figure  # noqa: F401
        from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the 3d projection)
    except ImportError:
        raise InputError(f"the figure needs matplotlib; {PLOT_HINT} (or write only --csv)") \
            from None


def render_map_png(angles_deg, field_nT, theta, phi, error, worst=None, *, dpi: int = 90,
                   sphere_step_deg: float = 4.0) -> bytes:
    """PNG of the sphere (Fig. 3 in Wang et al. 2015) beside the theta-phi map (Fig. 4).

    theta [deg] (n_theta,), phi [deg] (n_phi,), error [nT] (n_phi, n_theta) as returned by
    `orthogonality.error_map`; worst an optional `WorstCase` whose extremes are marked.
    Uses matplotlib's Agg canvas through `Figure`, never pyplot's global state.
    """
    _require_matplotlib()
    from matplotlib import colormaps
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    limit = float(np.abs(error).max()) or 1.0
    norm = Normalize(-limit, limit)
    cmap = colormaps["RdBu_r"]  # red positive, blue negative, as in the paper
    figure = Figure(figsize=(11.0, 4.4), dpi=dpi, layout="constrained")
    sphere = figure.add_subplot(1, 2, 1, projection="3d")
    plane = figure.add_subplot(1, 2, 2)

    # Fig. 3: the sphere coloured by dB
    s_theta = np.arange(0.0, 360.0 + sphere_step_deg / 2, sphere_step_deg)
    s_phi = np.linspace(-90.0, 90.0, int(round(180.0 / sphere_step_deg)) + 1)
    g_theta, g_phi = np.meshgrid(s_theta, s_phi)
    u = ortho.direction(g_theta, g_phi)
    s_error = ortho.total_field_error(angles_deg, field_nT, g_theta, g_phi)
    sphere.plot_surface(u[..., 0], u[..., 1], u[..., 2], facecolors=cmap(norm(s_error)),
                        rstride=1, cstride=1, linewidth=0, antialiased=False, shade=False)
    sphere.set_box_aspect((1, 1, 1))
    sphere.set_xlabel("X")
    sphere.set_ylabel("Y")
    sphere.set_zlabel("Z")
    sphere.set_title("total-field error on the sphere of directions")

    # Fig. 4: the theta-phi map
    mesh = plane.pcolormesh(theta, phi, error, cmap=cmap, norm=norm, shading="nearest",
                            rasterized=True)
    plane.set_xlim(0, 360)
    plane.set_ylim(-90, 90)
    plane.set_xticks(np.arange(0, 361, 60))
    plane.set_yticks(np.arange(-90, 91, 30))
    plane.set_xlabel(r"$\theta$ [deg]")
    plane.set_ylabel(r"$\varphi$ [deg]")
    if worst is not None:
        for extreme, marker, label in ((worst.largest_positive, "^", "max"),
                                       (worst.most_negative, "v", "min")):
            plane.plot(extreme.theta_deg, extreme.phi_deg, marker, color="k", ms=8,
                       label=f"{label} {extreme.delta_B_nT:+.2f} nT")
        plane.legend(loc="lower right", fontsize=8)
    a, b, g = (float(v) for v in angles_deg)
    plane.set_title(rf"$\Delta B(\theta, \varphi)$, angles ({a:g}, {b:g}, {g:g}) deg, "
                    rf"$|B|$ = {field_nT:g} nT")
    figure.colorbar(mesh, ax=plane, label=r"$\Delta B = |B'| - |B|$ [nT]")
    buffer = _stdio.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()
