"""Regenerate the tables of docs/real-data.md: every real log of ../shared/data/real, calibrated by
the command the page shows, against a free ellipsoid fit of the same samples.

    python docs/real_data.py            # rewrite the generated blocks of docs/real-data.md
    python docs/real_data.py --check    # exit 1 if the page's tables are out of date
    python docs/real_data.py --print    # print the tables, touch nothing

Each log is calibrated through the command line (`nlpcal.cli.main`, the exact arguments of the
page's table) and its Table 1 rows are read from the parameters file. The free ellipsoid fit is
written here, in numpy, independently of nlpcal's solvers: an algebraic fit of the quadric
x^T A x + b^T x = 1 by linear least squares, then Levenberg-Marquardt steps on the geometric
residuals r_i = |R (x_i - c)| - 1 with R upper triangular (nine free numbers, the same count as
nlpcal's model), started from the algebraic fit. Its corrected |B| is scaled to nlpcal's mean
|B1| so that the two spreads compare in one unit. The samples are those nlpcal read (the same
rows: `nlpcal.io.read_log`). The logs are not part of the repository: without ../shared beside
the checkout the script says so and exits 0. Everything is deterministic; it takes ~15 s.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing

from generated import replace_block, update_page  # noqa: E402
from nlpcal.cli import main as nlpcal  # noqa: E402
from nlpcal.io import read_log  # noqa: E402

PAGE = HERE / "real-data.md"
SHARED = HERE.parent.parent / "shared"
REAL = SHARED / "data" / "real"
#: What the page calls the data folder in its commands.
SHOWN = "../shared/data/real"
#: nlpcal's corrected std must lie within this fraction of the free ellipsoid fit's. [1]
TOLERANCE = 0.02


@dataclass(frozen=True)
class RealLog:
    """One log: its file, the arguments the page gives, and why."""

    path: str
    arguments: tuple = ()
    note: str = ""


#: Every log of ../shared/data/real that holds magnetometer samples, with the fewest arguments
#: that calibrate it.
LOGS = (
    RealLog("bazhin_ellipsoid_fit/mag_out.txt", ("--unit", "raw"), "counts, no header row"),
    RealLog("broad_myon_rotation/imu_derived.csv", (), "uT from the names; 29 % repeated rows"),
    RealLog("ck_explorer_accmag/acc_mag_log.csv", ("--unit", "G"), "gauss, names carry no unit"),
    RealLog("freeimu_gui_accmag/magn.txt", ("--unit", "raw"), "counts, no header; 86 % repeats"),
    RealLog(
        "rasteiro_robot_multisensor/LSM9DS0_derived.csv",
        (),
        "a (0, 0, 0) first row left out",
    ),
    RealLog(
        "rasteiro_robot_multisensor/MPU6050RM3100_derived.csv",
        (),
        "a (0, 0, 0) first row left out",
    ),
    RealLog(
        "rasteiro_robot_multisensor/MPU6500RM3100_derived.csv",
        (),
        "a (0, 0, 0) first row left out",
    ),
    RealLog(
        "rasteiro_robot_multisensor/MPU9150_derived.csv",
        (),
        "mG from the names; a (0, 0, 0) row",
    ),
    RealLog("razor_ahrs_magnetom/magnetom_derived.csv", (), "counts from the names (_counts)"),
    RealLog("sunsided_hmc5883l_fullsphere/hmc5883l_mag_derived.csv", (), "gauss from the names"),
    RealLog("wagonwheel_magcal/data.csv", ("--unit", "raw"), "no header, leading time column"),
    RealLog("xio_fusion_ximu3/sensor_data.csv", (), "device kept upright: a cap of directions"),
)


# --- the free ellipsoid fit -----------------------------------------------------------------


def algebraic_ellipsoid(x: np.ndarray):
    """(centre c, upper-triangular R) of the quadric fitted by linear least squares, or None when
    the quadric is not an ellipsoid. The samples are centred and scaled first for conditioning."""
    shift, scale = x.mean(axis=0), x.std()
    X, Y, Z = ((x - shift) / scale).T
    design = np.column_stack([X * X, Y * Y, Z * Z, 2 * X * Y, 2 * X * Z, 2 * Y * Z, X, Y, Z])
    v = np.linalg.lstsq(design, np.ones(len(x)), rcond=None)[0]
    a = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    centre = -0.5 * np.linalg.solve(a, v[6:9])
    a = a / (1.0 + centre @ a @ centre)  # (x - c)^T A (x - c) = 1
    if np.linalg.eigvalsh(a).min() <= 0:
        return None
    return shift + scale * centre, np.linalg.cholesky(a).T / scale


def geometric_ellipsoid(x: np.ndarray, centre, r, iterations: int = 200):
    """Levenberg-Marquardt on r_i = |R (x_i - c)| - 1 over c (3) and upper-triangular R (6)."""
    upper = np.triu_indices(3)

    def residuals(p):
        rr = np.zeros((3, 3))
        rr[upper] = p[3:]
        v = (x - p[:3]) @ rr.T
        norm = np.linalg.norm(v, axis=1)
        return norm - 1.0, v, norm, rr

    p = np.concatenate([centre, r[upper]])
    res, v, norm, rr = residuals(p)
    cost, damping = res @ res, 1e-3
    for _ in range(iterations):
        d = x - p[:3]
        unit = v / norm[:, None]
        jac = np.empty((len(x), 9))
        jac[:, :3] = -unit @ rr  # d|v|/dc = -(R^T v)/|v|
        for column, (j, k) in enumerate(zip(*upper)):
            jac[:, 3 + column] = unit[:, j] * d[:, k]  # d|v|/dR_jk
        gradient, normal = jac.T @ res, jac.T @ jac
        while damping < 1e12:
            step = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), -gradient)
            trial = residuals(p + step)
            if trial[0] @ trial[0] < cost:
                break
            damping *= 10.0
        else:
            break
        improvement = cost - trial[0] @ trial[0]
        p = p + step
        res, v, norm, rr = trial
        cost, damping = res @ res, max(damping / 10.0, 1e-12)
        if improvement < 1e-15 * max(cost, 1e-300):
            break
    return p[:3], rr


def ellipsoid_spread(samples: np.ndarray) -> float | None:
    """std / mean of |B| corrected by the free ellipsoid fit, or None without an ellipsoid."""
    start = algebraic_ellipsoid(samples)
    if start is None:
        return None
    centre, r = geometric_ellipsoid(samples, *start)
    magnitude = np.linalg.norm((samples - centre) @ r.T, axis=1)
    return float(magnitude.std() / magnitude.mean())


# --- running the page's commands ------------------------------------------------------------


def command(log: RealLog) -> str:
    return " ".join(["nlpcal calibrate", f"{SHOWN}/{log.path}", *log.arguments])


def run(argv) -> tuple:
    """nlpcal with argv: (exit status, stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        status = nlpcal([str(a) for a in argv])
    return status, err.getvalue()


def read_options(arguments) -> dict:
    """The read_log options in a command's arguments (--unit, --columns)."""
    options: dict = {}
    args = list(arguments)
    if "--unit" in args:
        options["unit"] = args[args.index("--unit") + 1]
    if "--columns" in args:
        at = args.index("--columns")
        options["columns"] = args[at + 1 : at + 4]
    return options


def measure(log: RealLog, folder: Path) -> dict:
    """Run the page's command on one log and the free ellipsoid fit on the same samples."""
    path = REAL / log.path
    out = folder / "params.json"
    out.unlink(missing_ok=True)
    status, err = run(["calibrate", path, *log.arguments, "-q", "-o", out])
    row = {"log": log, "status": status, "err": err}
    samples = read_log(path, **read_options(log.arguments)).samples
    row["n"] = samples.shape[0]
    row["ellipsoid_relative"] = ellipsoid_spread(samples)
    if status == 0:
        result = json.loads(out.read_text())
        row["unit"] = "counts" if result["unit"] == "raw" else result["unit"]
        row["measured"], row["corrected"] = result["statistics"][0], result["statistics"][-1]
    if status != 0:
        row["message"] = next(
            (line for line in err.splitlines() if line.startswith("nlpcal calibrate:")), err
        )
    if "--unit" in log.arguments:  # the same command without --unit: is the mistake caught?
        at = log.arguments.index("--unit")
        bare = log.arguments[:at] + log.arguments[at + 2 :]
        _, bare_err = run(["calibrate", path, *bare, "-o", folder / "bare.json"])
        row["unit_warning"] = next(
            (line for line in bare_err.splitlines() if "far from Earth's field" in line), ""
        )
    return row


def fmt(value: float) -> str:
    """Four significant digits, thousands grouped (17 470, 387.7, 3.587)."""
    return f"{value:,.0f}".replace(",", " ") if abs(value) >= 1000 else f"{value:.4g}"


def results_table(rows) -> str:
    lines = [
        "| folder | command | what the log shows | exit | N | measured std of \\|B\\| "
        "| corrected std of \\|B1\\| | free ellipsoid fit | ratio |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        log = row["log"]
        name = log.path.split("/")[0]
        shown = f"`{command(log)}`"
        if row["status"] == 0:
            unit, corrected = row["unit"], row["corrected"]
            measured = f"{fmt(row['measured']['std'])} {unit}"
            ellipsoid = row["ellipsoid_relative"] * corrected["mean"]
            ratio = corrected["std"] / ellipsoid
            cells = [
                measured,
                f"{fmt(corrected['std'])} {unit}",
                f"{fmt(ellipsoid)} {unit}",
                f"{ratio:.4f}",
            ]
        else:
            reason = "not an ellipsoid" if row["ellipsoid_relative"] is None else "fitted"
            cells = ["–", "– (quality check failed)", reason, "–"]
        lines.append(
            f"| {name} | {shown} | {log.note} | {row['status']} | {row['n']} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines)


def units_table(rows) -> str:
    lines = [
        "| log | without --unit, nlpcal says |",
        "|---|---|",
    ]
    for row in rows:
        if "unit_warning" not in row:
            continue
        warning = row["unit_warning"].replace("nlpcal: warning: ", "")
        if not warning:  # the page promises that every unit mistake is warned about
            raise SystemExit(f"{row['log'].path}: no warning about the unit without --unit")
        lines.append(f"| {Path(row['log'].path).name} | {warning} |")
    return "\n".join(lines)


def summary(rows) -> str:
    calibrated = [r for r in rows if r["status"] == 0]
    within = [
        r
        for r in calibrated
        if abs(r["corrected"]["std"] / (r["ellipsoid_relative"] * r["corrected"]["mean"]) - 1)
        <= TOLERANCE
    ]
    failed = [Path(r["log"].path).name for r in rows if r["status"] != 0]
    return (
        f"{len(calibrated)} of {len(rows)} logs calibrate (exit 0), {len(within)} of them with a "
        f"corrected std within {TOLERANCE:.0%} of the free ellipsoid fit; "
        f"{len(failed)} {'fails' if len(failed) == 1 else 'fail'} the quality check (exit 1): "
        f"{', '.join(failed) or 'none'}."
    )


def failures(rows) -> str:
    """The message of every command that failed, as the user sees it."""
    blocks = []
    for row in rows:
        if row["status"] != 0:
            blocks.append(f"```\n$ {command(row['log'])}\n...\n{row['message']}\n```")
    return "\n\n".join(blocks) or "(none)"


def render(page: str) -> str:
    with tempfile.TemporaryDirectory() as folder:
        rows = [measure(log, Path(folder)) for log in LOGS]
    page = replace_block(page, "results", results_table(rows), str(PAGE))
    page = replace_block(page, "failure", failures(rows), str(PAGE))
    page = replace_block(page, "summary", summary(rows), str(PAGE))
    return replace_block(page, "units", units_table(rows), str(PAGE))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the page is out of date")
    parser.add_argument("--print", action="store_true", help="print the tables, touch nothing")
    args = parser.parse_args(argv)
    if not REAL.is_dir():
        print(f"skipped: {REAL} is absent (the real logs are not in the repository)")
        return 0
    missing = [log.path for log in LOGS if not (REAL / log.path).is_file()]
    if missing:
        print(f"skipped: {', '.join(missing)} absent from {REAL}")
        return 0
    updated = render(PAGE.read_text())
    if args.print:
        print(updated)
        return 0
    return update_page(PAGE, updated, check=args.check, script="docs/real_data.py")


if __name__ == "__main__":
    raise SystemExit(main())
