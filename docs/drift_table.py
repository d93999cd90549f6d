"""Regenerate the tables of docs/drift.md (seed 002, Liu et al. 2022) from the liu2022 replica.

    python docs/drift_table.py            # rewrite the generated blocks of docs/drift.md
    python docs/drift_table.py --check    # exit 1 if the page's tables are out of date
    python docs/drift_table.py --print    # print the tables, touch nothing

The script writes the replica with `nlpcal simulate --preset liu2022`, runs the paper's two-step
pipeline and the joint temperature calibration through the command line (`nlpcal.cli.main`, the
same commands the page lists), and evaluates every result by the RMSE of Eq. 10 on the drift log
and on the field log: raw -> system -> system + temperature, the shape of the paper's results.
Each table goes between `<!-- BEGIN generated:NAME -->` and `<!-- END generated:NAME -->`; the rest
of the page is left as it is. Everything is deterministic (fixed seed).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from generated import replace_block, update_page
from nlpcal.cli import main as nlpcal
from nlpcal.drift import DriftFit, TemperatureCalibrationResult, rmse_rows
from nlpcal.models import liu2022
from nlpcal.models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters
from nlpcal.simulation.liu2022 import replica_truth

HERE = Path(__file__).resolve().parent
PAGE = HERE / "drift.md"
SEED = 0
T0 = liu2022.PAPER_BASE_TEMPERATURE_DEGC
COLUMNS = ["--temperature-column", "temp_c", "--reference-column", "proton_nT"]


def run(*argv) -> str:
    """nlpcal with argv; returns stdout, raises on a non-zero exit status."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = nlpcal([str(a) for a in argv])
    if status != 0:
        raise SystemExit(f"nlpcal {' '.join(map(str, argv))} failed ({status}):\n{err.getvalue()}")
    return out.getvalue()


def load(path):
    frame = pd.read_csv(path)
    return (
        frame[["bx", "by", "bz"]].to_numpy(),
        frame["temp_c"].to_numpy(),
        frame["proton_nT"].to_numpy(),
    )


def experiment(folder: Path) -> dict:
    """Run every estimate on the replica in `folder`; returns the tables' numbers."""
    run("simulate", "--preset", "liu2022", "--seed", SEED, "-o", folder)
    d = folder
    # the paper's pipeline: system calibration at t0, drift fit on the static log
    run("calibrate", d / "base.csv", "--reference-column", "proton_nT", "-o", d / "base.json")
    # the paper's diurnal correction exactly (--diurnal paper), and nlpcal's default beside it
    drift_fit = ("drift", "fit", d / "drift.csv", *COLUMNS, "--base-temperature", T0)
    run(*drift_fit, "--diurnal", "paper", "-o", d / "drift.json")
    run(*drift_fit, "-o", d / "drift_fitted.json")
    # the joint estimate on the same data (base + drift logs in one file), and on the sweep log
    both = pd.concat([pd.read_csv(d / "base.csv"), pd.read_csv(d / "drift.csv")])
    both.to_csv(d / "base_drift.csv", index=False)
    run(
        "calibrate",
        d / "base_drift.csv",
        *COLUMNS,
        "--temperature-model",
        "common",
        "--base-temperature",
        T0,
        "-o",
        d / "joint_base_drift.json",
    )
    for model in ("common", "per-axis"):
        run(
            "calibrate",
            d / "sweep.csv",
            *COLUMNS,
            "--temperature-model",
            model,
            "--base-temperature",
            T0,
            "-o",
            d / f"joint_sweep_{model}.json",
        )

    params, model = replica_truth(d / "truth.json")
    base = Zhou2010Parameters.from_dict(json.loads((d / "base.json").read_text())["parameters"])
    fit = DriftFit.load(d / "drift.json")
    fitted = DriftFit.load(d / "drift_fitted.json")
    joints = {
        name: TemperatureCalibrationResult.load(d / f"{name}.json")
        for name in ("joint_base_drift", "joint_sweep_common", "joint_sweep_per-axis")
    }
    estimates = {
        "pipeline": (base, fit),
        "joint_base_drift": (joints["joint_base_drift"].model, joints["joint_base_drift"]),
        "joint_sweep_common": (joints["joint_sweep_common"].model, joints["joint_sweep_common"]),
        "joint_sweep_per-axis": (
            joints["joint_sweep_per-axis"].model,
            joints["joint_sweep_per-axis"],
        ),
        "truth": (params, None),
    }
    rmse = {}
    for log in ("drift", "field"):
        samples, temperature, reference = load(d / f"{log}.csv")
        for name, (nine, correction) in estimates.items():
            if name == "truth":
                rows = rmse_rows(samples, reference, params=nine)
                corrected = liu2022.correct(samples, temperature, params, model)
                rows.append({"rmse": liu2022.rmse(np.linalg.norm(corrected, axis=1), reference)})
            else:
                rows = rmse_rows(
                    samples, reference, params=nine, temperature=temperature, correction=correction
                )
            rmse[log, name] = [row["rmse"] for row in rows]
    # the stats command gives the pipeline's rows too (check that the CLI agrees)
    stats = json.loads(
        run(
            "stats",
            d / "field.csv",
            "--params",
            d / "base.json",
            "--drift",
            d / "drift.json",
            *COLUMNS,
            "--json",
        )
    )
    cli = [row["rmse"] for row in stats["rows"]]
    if not np.allclose(cli, rmse["field", "pipeline"], rtol=1e-9):
        raise SystemExit(f"nlpcal stats disagrees with the library: {cli}")
    return {
        "rmse": rmse,
        "fit": fit,
        "fitted": fitted,
        "truth": (params, model),
        "base": base,
        "joints": joints,
        "truth_doc": json.loads((d / "truth.json").read_text()),
    }


LABELS = ("raw", "system", "system + temperature")
ESTIMATES = (
    ("pipeline", "pipeline: base + drift logs"),
    ("joint_base_drift", "joint common: base + drift logs"),
    ("joint_sweep_common", "joint common: sweep log"),
    ("joint_sweep_per-axis", "joint per-axis: sweep log"),
    ("truth", "true parameters"),
)


def rmse_table(results: dict, log: str) -> str:
    paper = liu2022.PAPER_DRIFT_RMSE_NT if log == "drift" else liu2022.PAPER_FIELD_RMSE_NT
    header = "| row | paper | " + " | ".join(title for _, title in ESTIMATES) + " |"
    lines = [header, "|---" * (2 + len(ESTIMATES)) + "|"]
    for i, label in enumerate(LABELS):
        cells = [f"{results['rmse'][log, name][i]:.2f}" for name, _ in ESTIMATES]
        lines.append(f"| {label} | {paper[i]:.2f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def fit_table(results: dict) -> str:
    fit, fitted = results["fit"], results["fitted"]
    truth = results["truth_doc"]
    joints = results["joints"]
    paper_a, paper_b = liu2022.PAPER_A_NT_PER_DEGC, liu2022.PAPER_B_NT
    paper_c = paper_a / float(liu2022.modulus_line(T0, paper_a, paper_b))
    fit_c_se = fit.a_standard_error / float(liu2022.modulus_line(T0, fit.a, fit.b))
    both = (fit, fitted)
    lines = [
        "| quantity | paper | replica truth | drift fit (pipeline, `--diurnal paper`) | "
        "drift fit (default, `--diurnal fitted`) |",
        "|---|---|---|---|---|",
        f"| a [nT/°C] | {liu2022.PAPER_A_NT_PER_DEGC} | {truth['a_nT_per_degC']} | "
        + " | ".join(f"{f.a:.4f} ± {f.a_standard_error:.4f}" for f in both)
        + " |",
        f"| b [nT] | {liu2022.PAPER_B_NT:.0f} | {truth['b_nT']:.0f} | "
        + " | ".join(f"{f.b:.2f} ± {f.b_standard_error:.2f}" for f in both)
        + " |",
        f"| diurnal gain g | 1 (assumed) | – | 1 (assumed) | "
        f"{fitted.diurnal_gain:.4f} ± {fitted.diurnal_gain_standard_error:.4f} |",
        f"| fit RMSE [nT] | {liu2022.PAPER_FIT_RMSE_NT} | – | "
        + " | ".join(f"{f.fit_rmse:.4f}" for f in both)
        + " |",
        "| temperature range [°C] | 5.1 – 6.8 | 5.1 – 6.8 | "
        + " | ".join(f"{f.temperature_range[0]:.2f} – {f.temperature_range[1]:.2f}" for f in both)
        + " |",
        f"| k slope c = a/(a t0 + b) [1e-6/°C] | {1e6 * paper_c:.3f} | "
        f"{1e6 * truth['temperature_model']['k_slope_per_degC']:.3f} | "
        + " | ".join(f"{1e6 * f.k_slope:.3f}" for f in both)
        + " |",
    ]
    lines += [
        "",
        "| estimate | c [1e-6/°C] (± s.e.) | largest offset error [nT] | "
        "largest scale error [1e-6] | largest angle error [mdeg] |",
        "|---|---|---|---|---|",
    ]
    params = results["truth"][0]

    def errors(nine):
        diff = nine.as_vector() - params.as_vector()
        return (
            np.max(np.abs(diff[0:3])),
            1e6 * np.max(np.abs(diff[3:6])),
            1e3 * np.max(np.abs(diff[6:9])),
        )

    rows = [
        (
            "pipeline (base calibration + drift fit)",
            results["base"],
            f"{1e6 * fit.k_slope:.3f} ± {1e6 * fit_c_se:.3f}",
        )
    ]
    for name, title in (
        ("joint_base_drift", "joint common: base + drift logs"),
        ("joint_sweep_common", "joint common: sweep log"),
    ):
        result = joints[name]
        se = (result.temperature_standard_errors or {}).get("k_slope_per_degC", float("nan"))
        rows.append(
            (
                title,
                result.model,
                f"{1e6 * result.temperature_model.k_slope_per_degC:.3f} ± {1e6 * se:.3f}",
            )
        )
    result = joints["joint_sweep_per-axis"]
    sigma = result.temperature_model.scale_slope_per_degC
    rows.append(
        (
            "joint per-axis: sweep log (σ x, y, z)",
            result.model,
            ", ".join(f"{1e6 * v:.2f}" for v in sigma),
        )
    )
    for title, nine, c in rows:
        dz, ds, da = errors(nine)
        lines.append(f"| {title} | {c} | {dz:.3f} | {ds:.2f} | {da:.3f} |")
    return "\n".join(lines)


def truth_table(results: dict) -> str:
    params, _ = results["truth"]
    doc = results["truth_doc"]
    names = ", ".join(PARAMETER_NAMES)
    values = ", ".join(f"{v:g}" for v in params.as_vector())
    return (
        f"Replica truth ({names}): {values}; field F0 = {doc['field_nT']:.2f} nT, "
        f"inclination {doc['inclination_deg']:g}°, fluxgate noise {doc['noise_nT']:g} nT per "
        f"axis, proton noise {doc['proton_noise_nT']:g} nT, seed {doc['seed']}."
    )


BLOCKS = {
    "drift_rmse": lambda r: rmse_table(r, "drift"),
    "field_rmse": lambda r: rmse_table(r, "field"),
    "fit": fit_table,
    "truth": truth_table,
}


def render(page: str, results: dict) -> str:
    for name, make in BLOCKS.items():
        page = replace_block(page, name, make(results), str(PAGE))
    return page


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--check", action="store_true", help="exit 1 if docs/drift.md is out of date; write nothing"
    )
    group.add_argument("--print", action="store_true", help="print the tables; write nothing")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        results = experiment(Path(folder))
    if args.print:
        for name, make in BLOCKS.items():
            print(f"## {name}\n{make(results)}\n")
        return 0
    return update_page(
        PAGE, render(PAGE.read_text(), results), check=args.check, script="docs/drift_table.py"
    )


if __name__ == "__main__":
    sys.exit(main())
