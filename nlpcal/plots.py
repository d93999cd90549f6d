"""Every figure nlpcal draws, with matplotlib (optional: pip install 'nlpcal[plot]').

Figures are drawn on matplotlib's Agg canvas through `Figure`, never through pyplot's global
state, and returned as PNG bytes for an atomic writer.
"""

from __future__ import annotations

import io
import textwrap

import numpy as np

from .errors import InputError
from .inference import rounded
from .models import wang2015
from .models.zhou2010 import PARAMETER_NAMES

PLOT_HINT = "pip install 'nlpcal[plot]'"


def require_matplotlib(three_d: bool = False) -> None:
    """Raise InputError with the install command when matplotlib (or its 3-d axes) is missing."""
    try:
        import matplotlib  # noqa: F401
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401

        if three_d:
            from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the 3d projection)
    except ImportError:
        raise InputError(f"the figure needs matplotlib; {PLOT_HINT}") from None


def _png(figure, dpi: int, *, palette: bool = True) -> bytes:
    """The figure as a PNG with a 256-colour palette (a third of the bytes of full colour for
    line plots; Pillow comes with matplotlib), or in full colour when `palette` is False: a
    continuous colour scale would be cut into bands."""
    from PIL import Image

    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    if not palette:
        return buffer.getvalue()
    image = Image.open(io.BytesIO(buffer.getvalue())).convert("RGB")
    out = io.BytesIO()
    quantized = image.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    quantized.save(out, "PNG", optimize=True, dpi=(dpi, dpi))  # the dpi stays in the pHYs chunk
    return out.getvalue()


# --- the comparison of methods (Fig. 2 of Zhou et al. 2010) -----------------------------------

#: Most samples drawn per curve; longer logs are strided evenly.
PLOT_SAMPLES = 4000
#: Most cycles drawn one by one in panel (a) (the paper shows seven); the last is always drawn.
PLOT_CYCLES = 7
#: Resolution of the comparison figure. [dpi]
COMPARISON_DPI = 150
#: Font sizes of nlpcal's figures, legible at 100 % zoom. [pt]
STYLE: dict = {
    "font.size": 10,
    "axes.titlesize": 11,
    "axes.labelsize": 10,
    "legend.fontsize": 9,
    "xtick.labelsize": 9,
    "ytick.labelsize": 9,
}


def comparison_png(comparison, *, dpi: int = COMPARISON_DPI, title: str | None = None) -> bytes:
    """PNG of Fig. 2 of [1] for this comparison, plus the convergence of every method.

    (a) |B1| over the samples after each cycle of the staged method; (b) before and after: the
    measured |B_M|, one pass, the last cycle and the joint solve, each on its own axis so that
    each is visible at its own scale; (c) objective against cumulative solver iterations for
    every method, log scales. Uses the Agg canvas, never pyplot's global state.
    """
    require_matplotlib()
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    unit = comparison.unit
    n = comparison.samples.shape[0]
    stride = max(1, -(-n // PLOT_SAMPLES))
    index = np.arange(0, n, stride)

    def magnitude(row):
        return comparison.magnitudes(row)[::stride]

    cycles = comparison.staged[1:]
    curves = [("measured |B_M|", comparison.staged[0], "0.45")]
    if cycles:
        curves.append(("one pass (cycle 1)", cycles[0], "C1"))
        curves.append((f"last staged cycle ({len(cycles)})", cycles[-1], "C0"))
    curves.append(("joint IPOPT", comparison.joint, "C3"))

    with rc_context(STYLE):
        figure = Figure(figsize=(13.0, 7.0), dpi=dpi, layout="constrained")
        FigureCanvasAgg(figure)
        grid = figure.add_gridspec(len(curves), 3, width_ratios=(1.0, 1.0, 1.0))
        ax_a = figure.add_subplot(grid[:, 0])
        ax_c = figure.add_subplot(grid[:, 2])
        stack = [figure.add_subplot(grid[k, 1]) for k in range(len(curves))]

        _draw_staged_cycles(ax_a, cycles, index, magnitude, unit)
        _draw_before_after(stack, curves, index, magnitude, unit)
        _draw_convergence(ax_c, comparison.trajectories, unit)
        if title:
            figure.suptitle(title, fontsize=12)
        return _png(figure, dpi)


def _draw_staged_cycles(ax, cycles: list, index, magnitude, unit: str) -> None:
    """Panel (a): |B1| after the first `PLOT_CYCLES` staged cycles and the last, first dark,
    last light. [unit]"""
    from matplotlib import colormaps

    shown = list(range(min(PLOT_CYCLES, len(cycles))))
    if cycles and len(cycles) - 1 not in shown:
        shown.append(len(cycles) - 1)
    palette = colormaps["viridis"]
    for rank, k in enumerate(shown):  # first cycle dark, last cycle light, drawn on top
        ax.plot(
            index,
            magnitude(cycles[k]),
            lw=0.6,
            color=palette(0.9 * rank / max(len(shown) - 1, 1)),
            label=f"{cycles[k]['label']} (std {cycles[k]['std']:.3g})",
        )
    ax.set_title("(a) |B1| after each staged cycle")
    ax.set_xlabel("sample")
    ax.set_ylabel(f"|B1| [{unit}]")
    ax.legend(loc="upper right")


def _draw_before_after(stack: list, curves: list, index, magnitude, unit: str) -> None:
    """Panel (b): one axis per (name, row, colour) of `curves`, each |B| on its own scale and
    labelled with its std, the axes sharing the sample axis. [unit]"""
    for k, (ax, (name, row, colour)) in enumerate(zip(stack, curves)):
        ax.plot(index, magnitude(row), lw=0.6, color=colour)
        ax.text(
            0.01,
            0.96,
            f"{name}: std {row['std']:.3g} {unit}",
            transform=ax.transAxes,
            va="top",
            ha="left",
            fontsize=9,
            bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.8, "pad": 1.5},
        )
        ax.set_ylabel(unit)
        ax.margins(x=0.0, y=0.25)
        if k < len(curves) - 1:
            ax.tick_params(labelbottom=False)
        if k > 0:
            ax.sharex(stack[0])
    stack[0].set_title("(b) |B| before and after, each on its own scale")
    stack[-1].set_xlabel("sample")


def _draw_convergence(ax, trajectories: dict, unit: str) -> None:
    """Panel (c): the objective [unit^2] against cumulative solver iterations of every method,
    log scales (an exact zero objective is not drawn)."""
    styles = {
        "staged": ("staged cycle, IPOPT stages", "C0", ".-"),
        "joint": ("joint IPOPT", "C3", "s-"),
        "cg_joint": ("CG joint, paper units", "C1", "-"),
        "cg_joint_scaled": ("CG joint, scaled", "C4", "-"),
        "cg_staged": ("CG staged cycle", "C2", "-"),
    }
    for name, (label, colour, style) in styles.items():
        path = trajectories.get(name)
        if not path:
            continue
        its = np.asarray(path["iterations"], dtype=float)
        values = np.asarray(path["objective"], dtype=float)
        positive = values > 0  # a log axis; an exact zero objective is not drawn
        ax.plot(its[positive], values[positive], style, color=colour, lw=1.2, ms=4, label=label)
    ax.set_xscale("symlog", linthresh=10)
    ax.set_yscale("log")
    ax.set_xlim(left=0)
    ax.set_title("(c) objective vs cumulative iterations")
    ax.set_xlabel("cumulative solver iterations")
    ax.set_ylabel(f"objective [{unit}²]")
    ax.legend(loc="upper right")


# --- the total-field error of non-orthogonal axes (Fig. 3 and 4 of Wang et al. 2015) -------


def orthogonality_map_png(
    angles_deg,
    field_nT,
    theta,
    phi,
    error,
    worst=None,
    *,
    dpi: int = 90,
    sphere_step_deg: float = 4.0,
) -> bytes:
    """PNG of the sphere (Fig. 3 in Wang et al. 2015) beside the theta-phi map (Fig. 4).

    theta [deg] (n_theta,), phi [deg] (n_phi,), error [nT] (n_phi, n_theta) as returned by
    `nlpcal.models.wang2015.error_map`; worst an optional `WorstCase` whose extremes are marked.
    Uses matplotlib's Agg canvas through `Figure`, never pyplot's global state.
    """
    require_matplotlib(three_d=True)
    from matplotlib import colormaps
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    limit = float(np.abs(error).max()) or 1.0
    norm = Normalize(-limit, limit)
    cmap = colormaps["RdBu_r"]  # red positive, blue negative, as in the paper
    figure = Figure(figsize=(11.0, 4.4), dpi=dpi, layout="constrained")
    sphere = figure.add_subplot(1, 2, 1, projection="3d")
    plane = figure.add_subplot(1, 2, 2)

    _draw_error_sphere(sphere, angles_deg, field_nT, cmap, norm, sphere_step_deg)
    mesh = _draw_error_map(plane, angles_deg, field_nT, theta, phi, error, cmap, norm, worst)
    figure.colorbar(mesh, ax=plane, label=r"$\Delta B = |B'| - |B|$ [nT]")
    return _png(figure, dpi, palette=False)


def _draw_error_sphere(ax, angles_deg, field_nT, cmap, norm, step_deg: float) -> None:
    """Fig. 3 of Wang et al. (2015): the sphere of directions coloured by the total-field error
    dB [nT] of the angles [deg] at field_nT [nT], every `step_deg` [deg]."""
    s_theta = np.arange(0.0, 360.0 + step_deg / 2, step_deg)
    s_phi = np.linspace(-90.0, 90.0, int(round(180.0 / step_deg)) + 1)
    g_theta, g_phi = np.meshgrid(s_theta, s_phi)
    u = wang2015.direction(g_theta, g_phi)
    s_error = wang2015.total_field_error(angles_deg, field_nT, g_theta, g_phi)
    ax.plot_surface(
        u[..., 0],
        u[..., 1],
        u[..., 2],
        facecolors=cmap(norm(s_error)),
        rstride=1,
        cstride=1,
        linewidth=0,
        antialiased=False,
        shade=False,
    )
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("X")
    ax.set_ylabel("Y")
    ax.set_zlabel("Z")
    ax.set_title("total-field error on the sphere of directions")


def _draw_error_map(ax, angles_deg, field_nT, theta, phi, error, cmap, norm, worst):
    """Fig. 4 of Wang et al. (2015): dB [nT] on the theta-phi plane [deg], the extremes of
    `worst` marked; the mesh, for the colour bar."""
    mesh = ax.pcolormesh(
        theta, phi, error, cmap=cmap, norm=norm, shading="nearest", rasterized=True
    )
    ax.set_xlim(0, 360)
    ax.set_ylim(-90, 90)
    ax.set_xticks(np.arange(0, 361, 60))
    ax.set_yticks(np.arange(-90, 91, 30))
    ax.set_xlabel(r"$\theta$ [deg]")
    ax.set_ylabel(r"$\varphi$ [deg]")
    if worst is not None:
        for extreme, marker, label in (
            (worst.largest_positive, "^", "max"),
            (worst.most_negative, "v", "min"),
        ):
            ax.plot(
                extreme.theta_deg,
                extreme.phi_deg,
                marker,
                color="k",
                ms=8,
                label=f"{label} {extreme.delta_B_nT:+.2f} nT",
            )
        ax.legend(loc="lower right", fontsize=8)
    a, b, g = (float(v) for v in angles_deg)
    ax.set_title(
        rf"$\Delta B(\theta, \varphi)$, angles ({a:g}, {b:g}, {g:g}) deg, "
        rf"$|B|$ = {field_nT:g} nT"
    )
    return mesh


# --- the reproductions of Liu et al. (2022) and Qiu et al. (2017) ------------------------------

#: Resolution of the reproduction figures. [dpi]
REPRODUCTION_DPI = 100


def drift_reproduction_png(
    temperature, modulus, *, fitted, published, rmse, paper_rmse, rows, dpi: int = REPRODUCTION_DPI
) -> bytes:
    """PNG of the drift experiment of Liu et al. (2022) beside its RMSE table.

    (a) the diurnal-corrected modulus [nT] of the static log against temperature [degC], with
    the fitted line of Eq. 1 and the published one (`fitted`, `published`: (a [nT/degC],
    b [nT])); (b) the RMSE of Eq. 10 [nT] of each row (`rows`) for each log, nlpcal's (`rmse`)
    beside the paper's (`paper_rmse`, both {log: values}), on a log scale.
    """
    require_matplotlib()
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t = np.asarray(temperature, dtype=float)
    line_t = np.array([t.min(), t.max()])
    with rc_context(STYLE):
        figure = Figure(figsize=(11.0, 4.2), dpi=dpi, layout="constrained")
        FigureCanvasAgg(figure)
        line, bars = figure.subplots(1, 2)
        line.plot(t, modulus, ".", ms=2, color="0.55", label="replica, diurnal-corrected")
        for (a, b), label, colour in (
            (fitted, "nlpcal fit", "C0"),
            (published, "paper", "C3"),
        ):
            line.plot(line_t, a * line_t + b, color=colour, label=f"{label}: {a:.4f} t + {b:.2f}")
        line.set_xlabel("temperature [degC]")
        line.set_ylabel("|B_m| - (F_i - F_1) [nT]")
        line.set_title("(a) Eq. 1 on the static log")
        line.legend(loc="best")
        width = 0.2
        x = np.arange(len(rows))
        for k, log in enumerate(rmse):
            for j, (values, source, hatch) in enumerate(
                ((paper_rmse[log], "paper", "//"), (rmse[log], "nlpcal", ""))
            ):
                bars.bar(
                    x + (2 * k + j - 1.5) * width,
                    values,
                    width,
                    color=f"C{k}",
                    hatch=hatch,
                    alpha=0.5 if hatch else 1.0,
                    label=f"{log} log, {source}",
                )
        bars.set_yscale("log")
        bars.set_xticks(x, list(rows))
        bars.set_ylabel("RMSE of Eq. 10 [nT]")
        bars.set_title("(b) raw -> system -> system + temperature")
        bars.legend(loc="upper right")
    return _png(figure, dpi)


def attitude_errors_png(
    true_pitch, errors, bounds, *, dpi: int = REPRODUCTION_DPI, title: str | None = None
) -> bytes:
    """PNG of roll, pitch and heading errors [deg] against the true pitch [deg], with the bounds
    that Qiu et al. (2017) publish for each (`bounds`: roll, pitch, heading [deg])."""
    require_matplotlib()
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    errors = np.asarray(errors, dtype=float)
    with rc_context(STYLE):
        figure = Figure(figsize=(11.0, 3.6), dpi=dpi, layout="constrained")
        FigureCanvasAgg(figure)
        for k, (axes, name, bound) in enumerate(
            zip(figure.subplots(1, 3, sharex=True), ("roll", "pitch", "heading"), bounds)
        ):
            axes.plot(true_pitch, errors[:, k], ".", ms=2, color="C0")
            for sign in (1, -1):
                axes.axhline(sign * bound, color="C3", ls="--", lw=1)
            axes.set_xlabel("true pitch [deg]")
            axes.set_ylabel(f"{name} error [deg]")
            axes.set_title(f"{name} (paper: within +-{bound:g} deg)")
        if title:
            figure.suptitle(title)
    return _png(figure, dpi)


# --- a calibration at a glance: before and after, residuals, directions, cycles --------------

#: Most points drawn on the direction map (a strided subsample of longer logs).
MAP_SAMPLES = 20000
#: Most tick labels on an axis of the calibration figure, before `legible_ticks` thins them.
MAX_TICKS = 7
#: Space kept between neighbouring tick labels. [px]
TICK_GAP_PX = 4.0
#: Colour of the verdict in the figure's title, by status (`nlpcal.verdict.STATUSES`).
VERDICT_COLOURS = {
    "ok": "#1d7a2e",
    "warnings": "#a86400",
    "poorly_determined": "#b00020",
    "failed": "#b00020",
}
#: The parameter names in the figure's title.
SHORT_NAMES = {"alpha_deg": "alpha", "beta_deg": "beta", "gamma_deg": "gamma"}


def calibration_png(view, *, dpi: int = 150) -> bytes:
    """PNG of `calibration_figure` (a log before and after its correction)."""
    return _png(calibration_figure(view, dpi=dpi), dpi)


def calibration_figure(view, *, dpi: int = 150):
    """The figure of a log before and after its correction (a `nlpcal.report.CalibrationView`).

    Title: the verdict and the nine parameters rounded by their standard errors (poorly
    determined ones marked). (a) |B_M| and |B1| against time (the log's time column) or the sample
    index, with the reference F when there is one; (b) the std of |B1| per staged cycle (when the
    view has cycles), with sqrt(objective) and the objective axis when a reference makes them
    differ; (c) and (d) histograms of |B| - F before and after (|B| - its mean without a
    reference); (e) the direction of B1 in the sensor frame on an equal-area (Hammer) map,
    coloured by its residual, with the 26 direction bins marked visited or missing. Tick labels
    are thinned until none overlap (`legible_ticks`). Uses the Agg canvas, never pyplot.
    """
    require_matplotlib()
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with rc_context(STYLE):
        figure = Figure(figsize=(15.0, 9.4), dpi=dpi, layout="constrained")
        FigureCanvasAgg(figure)
        grid = figure.add_gridspec(2, 3)
        _draw_total_field(figure, grid, view)
        if view.cycles:
            _cycles_panel(figure.add_subplot(grid[0, 2]), view.cycles, view.unit)
        _draw_residual_histograms(figure, grid, view)
        _draw_directions(figure, grid, view)
        _title(figure, view)
        legible_ticks(figure)
    return figure


def _draw_total_field(figure, grid, view) -> None:
    """(a): |B_M| above |B1| against time or the sample index, with the reference F when there
    is one. [unit]"""
    unit, target = view.unit, view.target
    stride = max(1, -(-view.n // PLOT_SAMPLES))
    if view.time is not None:
        x, x_label = view.time[::stride], "time since the first sample [s]"
    else:
        x, x_label = np.arange(0, view.n, stride), "sample index"
    top = (grid[0, :2] if view.cycles else grid[0, :]).subgridspec(2, 1, hspace=0.0)
    series = figure.add_subplot(top[0])
    zoom = figure.add_subplot(top[1], sharex=series)
    for axes, values, colour, label in (
        (series, view.before, "0.45", "measured |B_M|"),
        (zoom, view.after, "C0", "corrected |B1|"),
    ):
        axes.plot(x, values[::stride], lw=0.7, color=colour, label=label)
        if target is not None:
            axes.plot(x, target[::stride], "--", lw=1.0, color="k", label=view.target_label)
        axes.set_ylabel(f"{label.split()[-1]} [{unit}]")
        axes.legend(loc="upper right", fontsize=8, ncol=2)
        axes.grid(alpha=0.3)
        axes.ticklabel_format(axis="y", useOffset=False, style="plain")
    series.tick_params(labelbottom=False)
    zoom.set_xlabel(x_label)
    series.set_title("(a) total field before (top) and after (bottom) the correction")


def _draw_residual_histograms(figure, grid, view) -> None:
    """(c) and (d): histograms of |B| - F (or |B| - its mean) before and after. [unit]"""
    unit, target = view.unit, view.target
    against = "F" if target is not None else "its mean"
    for column, (label, magnitude, colour) in enumerate(
        (("(c) before: |B_M|", view.before, "0.45"), ("(d) after: |B1|", view.after, "C0"))
    ):
        residual = view.residuals(magnitude)
        axes = figure.add_subplot(grid[1, column])
        axes.hist(residual, bins=60, color=colour, alpha=0.85)
        axes.set_xlabel(f"|B| − {view.target_label} [{unit}]")
        axes.set_ylabel("samples")
        mean = f", mean {np.mean(residual):+.3g}" if target is not None else ""
        axes.set_title(f"{label} − {against}: std {np.std(residual):.3g}{mean} {unit}", fontsize=10)
        axes.grid(alpha=0.3)


def _draw_directions(figure, grid, view) -> None:
    """(e): the direction of B1 in the sensor frame on a Hammer map, coloured by its residual
    [unit], with the 26 direction bins marked visited or missing."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    unit = view.unit
    sky = figure.add_subplot(grid[1, 2], projection="hammer")
    residual_after = view.residuals(view.after)
    step = max(1, -(-view.n // MAP_SAMPLES))
    d = view.directions[::step]
    limit = float(np.percentile(np.abs(residual_after), 99)) or 1.0
    azimuth, elevation = _hammer(d)
    points = sky.scatter(
        azimuth,
        elevation,
        c=residual_after[::step],
        s=4,
        cmap=colormaps["RdBu_r"],
        norm=Normalize(-limit, limit),
        rasterized=True,
    )
    _bins_on(sky, view.bins)
    sky.grid(alpha=0.4)
    sky.set_xticks(np.radians([-120, -60, 0, 60, 120]))
    sky.set_yticks(np.radians([-60, -30, 0, 30, 60]))
    sky.tick_params(labelsize=7)
    where = f", {view.covered} of 26 bins visited" if view.bins else ""
    sky.set_title(f"(e) direction of B1 in the sensor frame{where}", fontsize=10)
    sky.set_xlabel("azimuth atan2(y, x), elevation asin(z / |B1|) [deg]", fontsize=8)
    figure.colorbar(
        points, ax=sky, shrink=0.7, pad=0.02, label=f"|B1| − {view.target_label} [{unit}]"
    )


def _hammer(directions) -> tuple:
    """(azimuth, elevation) of unit vectors (N, 3) for a Hammer map. [rad]"""
    directions = np.atleast_2d(directions)
    return (
        np.arctan2(directions[:, 1], directions[:, 0]),
        np.arcsin(np.clip(directions[:, 2], -1, 1)),
    )


def _bins_on(sky, bins) -> None:
    """The 26 direction bins on the map: visited as open circles, missing as red crosses with
    their names."""
    if not bins:
        return
    visited = np.array([vector for _, vector, seen in bins if seen]).reshape(-1, 3)
    missing = [(name, vector) for name, vector, seen in bins if not seen]
    sky.plot(*_hammer(visited), "o", mfc="none", mec="k", ms=7, label="bin visited")
    if missing:
        where = np.array([vector for _, vector in missing])
        sky.plot(*_hammer(where), "x", color="#b00020", ms=9, mew=2.0, label="bin missing")
        for (name, _), lon, lat in zip(missing, *_hammer(where)):
            sky.annotate(
                name,
                (lon, lat),
                xytext=(4, 3),
                textcoords="offset points",
                fontsize=7,
                color="#b00020",
            )
    sky.legend(loc="lower center", bbox_to_anchor=(0.5, -0.32), ncol=2, fontsize=8)


def _cycles_panel(cycles, rows, unit: str) -> None:
    """(b): the std of |B1| per staged cycle; sqrt(objective) and the objective axis only when a
    reference makes the objective differ from the variance."""
    number = np.arange(len(rows))
    rms = np.sqrt([row["objective"] for row in rows])
    std = np.array([row["std"] for row in rows], dtype=float)
    cycles.semilogy(number, std, "o-", color="C0", ms=4, label="std of |B1|")
    if not np.allclose(rms, std, rtol=1e-6):
        cycles.semilogy(number, rms, "s--", color="C3", ms=4, label="sqrt(objective)")
        objective = cycles.secondary_yaxis("right", functions=(np.square, np.sqrt))
        objective.set_ylabel(f"objective [{unit}$^2$]")
        cycles.set_ylabel(f"std of |B1|, sqrt(objective) [{unit}]")
    else:
        cycles.set_ylabel(f"std of |B1| [{unit}]")
    cycles.set_xlabel("staged cycle (0: measured)")
    cycles.set_title("(b) convergence of the staged cycle")
    cycles.legend(loc="upper right", fontsize=8)
    cycles.grid(alpha=0.3, which="both")


def parameter_lines(result) -> list:
    """Two lines: the offsets, then the scale errors and angles, each rounded by its standard
    error (`nlpcal.inference.rounded`), the poorly determined or undetermined ones marked *."""
    errors = result.standard_errors or {}
    block = result.identifiability or {}
    marked = {*block.get("poorly_determined", []), *block.get("not_identifiable", [])}
    parts = []
    for k, name in enumerate(PARAMETER_NAMES):
        value, error = rounded(result.parameters[name], errors.get(name))
        tail = f" {result.unit}" if k == 2 else " deg" if k == 8 else ""
        text = (
            f"{SHORT_NAMES.get(name, name)} {value} ± {error}"
            if error != "-"
            else (f"{SHORT_NAMES.get(name, name)} {value}")
        )
        parts.append(text + ("*" if name in marked else "") + tail)
    note = "   (* poorly determined)" if marked else ""
    return [",  ".join(parts[:3]) + note, ",  ".join(parts[3:])]


def _title(figure, view) -> None:
    """The title: the verdict first, then the parameters and what the figure shows."""
    lines = []
    result = view.result
    colour = "k"
    if result is not None and getattr(result, "verdict", None) is not None:
        verdict = result.verdict
        lines.append(textwrap.shorten(f"verdict: {verdict.line()}", 170, placeholder=" ..."))
        lines.extend(parameter_lines(result))
        colour = VERDICT_COLOURS[verdict.status]
    if view.title:
        lines.append(view.title)
    if lines:
        figure.suptitle("\n".join(lines), fontsize=11, color=colour)


def _overlaps(labels, renderer, horizontal: bool) -> bool:
    """Whether any two neighbouring tick labels (closer than TICK_GAP_PX) overlap."""
    boxes = sorted(
        (t.get_window_extent(renderer) for t in labels if t.get_visible() and t.get_text()),
        key=lambda b: b.x0 if horizontal else b.y0,
    )
    if horizontal:
        return any(a.x1 + TICK_GAP_PX > b.x0 for a, b in zip(boxes, boxes[1:]))
    return any(a.y1 + TICK_GAP_PX > b.y0 for a, b in zip(boxes, boxes[1:]))


def legible_ticks(figure, most: int = MAX_TICKS) -> None:
    """At most `most` ticks on each linear axis of the figure, fewer until no two tick labels
    overlap at the figure's size (MaxNLocator; the labels are measured on the drawn canvas)."""
    from matplotlib.ticker import MaxNLocator

    axes_list = [
        a for a in figure.axes if a.name == "rectilinear" and a.get_label() != "<colorbar>"
    ]
    bins = {}
    for axes in axes_list:
        for axis in (axes.xaxis, axes.yaxis):
            if axis.get_scale() == "linear":
                bins[axis] = most
                axis.set_major_locator(MaxNLocator(nbins=most, steps=[1, 2, 2.5, 5, 10]))
    for _ in range(most):
        figure.canvas.draw()
        renderer = figure.canvas.get_renderer()
        crowded = [
            axis
            for axis in bins
            if bins[axis] > 2 and _overlaps(axis.get_ticklabels(), renderer, axis.axis_name == "x")
        ]
        if not crowded:
            return
        for axis in crowded:
            bins[axis] -= 1
            axis.set_major_locator(MaxNLocator(nbins=bins[axis], steps=[1, 2, 2.5, 5, 10]))
