"""Every document nlpcal writes validates against the schema its kind ships (`nlpcal.schemas`);
the schemas refuse what nlpcal never writes; a parameters file written by nlpcal 0.1.0 applies
identically."""

import copy
import csv
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from jsonschema import Draft202012Validator, ValidationError

import nlpcal
from nlpcal.calibration.result import CalibrationResult
from nlpcal.cli import main
from nlpcal.schemas import BATCH_SUMMARY_ROW, SCHEMAS, schema, validate
from synthetic import platform_record

REPO = Path(__file__).resolve().parents[1]
BUNDLED = REPO / "data" / "example_zhou2010.csv"
EXPECTED = REPO / "tests" / "expected"


def run(*argv) -> int:
    return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def replicas(tmp_path_factory):
    folder = tmp_path_factory.mktemp("replicas")
    assert run("simulate", "--preset", "liu2022", "-o", folder / "liu", "-q") == 0
    assert run("simulate", "--preset", "qiu2017", "-o", folder / "qiu", "-q") == 0
    for seed in (1, 2):
        assert run("simulate", "--seed", seed, "-o", folder / f"s{seed}.csv", "-q") == 0
    return folder


CALIBRATE_VARIANTS = {
    "staged, unit assumed": [BUNDLED],
    "joint": [BUNDLED, "--method", "joint"],
    "reference": [BUNDLED, "--reference-field", "49460", "--unit", "nT"],
    "robust": [BUNDLED, "--loss", "huber"],
    "robust joint": [BUNDLED, "--loss", "cauchy", "--method", "joint"],
    "diagonal model": [BUNDLED, "--model", "diagonal"],
    "offset model": [BUNDLED, "--model", "offset", "--reference-field", "49460"],
    "model auto": [BUNDLED, "--model", "auto", "--method", "joint"],
    "ipopt options": [BUNDLED, "--ipopt-option", "max_iter=1", "--unit", "nT"],
}


@pytest.mark.parametrize("argv", CALIBRATE_VARIANTS.values(), ids=CALIBRATE_VARIANTS.keys())
def test_every_calibration_variant_validates(argv, tmp_path, capsys):
    out = tmp_path / "params.json"
    assert run("calibrate", *argv, "-o", out, "-q") == 0, capsys.readouterr().err
    document = json.loads(out.read_text())
    assert document["format"] == "nlpcal-calibration" and document["format_version"] == 2
    validate(document)


def written(tmp_path, capsys, name, *argv) -> dict:
    out = tmp_path / name
    assert run(*argv, "-o", out, "-q") == 0, capsys.readouterr().err
    return json.loads(out.read_text())


def platform_log(path: Path) -> Path:
    """A short figure-of-merit box (tests/synthetic.py) as a CSV."""
    vector, scalar, _, _ = platform_record(n=3000)
    columns = {"flux_x": vector[:, 0], "flux_y": vector[:, 1], "flux_z": vector[:, 2]}
    pd.DataFrame({**columns, "mag_1_nT": scalar}).to_csv(path, index=False)
    return path


def test_every_other_kind_validates(replicas, tmp_path, capsys):
    liu, qiu, logs = replicas / "liu", replicas / "qiu", [replicas / "s1.csv", replicas / "s2.csv"]
    made = {}
    made["temperature"] = written(
        tmp_path, capsys, "t.json", "calibrate", liu / "sweep.csv",
        "--reference-column", "proton_nT", "--temperature-column", "temp_c",
    )  # fmt: skip
    made["drift"] = written(
        tmp_path, capsys, "d.json", "drift", "fit", liu / "drift.csv", "--temperature-column",
        "temp_c", "--reference-column", "proton_nT", "--base-temperature", "7.3",
    )  # fmt: skip
    made["compass turns"] = written(
        tmp_path, capsys, "c1.json", "compass", "calibrate", qiu / "turns.csv"
    )
    made["compass ellipsoids"] = written(
        tmp_path, capsys, "c2.json", "compass", "calibrate", qiu / "test.csv"
    )
    made["inversion"] = written(tmp_path, capsys, "i.json", "orthogonality", "invert", logs[0])
    made["repeatability"] = written(tmp_path, capsys, "r.json", "orthogonality", "invert", *logs)
    made["worst case"] = written(
        tmp_path, capsys, "w.json", "orthogonality", "worst-case", "--angles-deg", "0.1", "0.1",
        "0.1", "--reference-field", "55000",
    )  # fmt: skip
    made["comparison"] = written(tmp_path, capsys, "k.json", "compare", logs[0], "--cycles", "3")
    unit_known = written(tmp_path, capsys, "p.json", "calibrate", logs[0], "--unit", "nT")
    made["affine correction"] = written(
        tmp_path, capsys, "m.json", "export", tmp_path / "p.json", "--format", "matrix"
    )
    made["import"] = written(
        tmp_path, capsys, "back.json", "import", tmp_path / "m.json", "--format", "matrix"
    )
    made["parameters, unit given"] = unit_known
    assert run("reproduce", "wang2015", "-o", tmp_path / "reproduced", "-q") == 0
    made["reproduction"] = json.loads((tmp_path / "reproduced" / "wang2015.json").read_text())
    assert run("batch", "calibrate", *logs, "--out-dir", tmp_path / "batch", "-q") == 0
    made["batch record"] = json.loads((tmp_path / "batch" / "batch.json").read_text())
    made["platform"] = written(
        tmp_path, capsys, "tl.json", "platform", "fit", platform_log(tmp_path / "box.csv"),
        "--scalar-column", "mag_1_nT", "--columns", "flux_x", "flux_y", "flux_z", "--rate", "10",
    )  # fmt: skip
    kinds = {document["format"] for document in made.values()}
    assert kinds == set(SCHEMAS)  # every kind nlpcal writes was made here
    for what, document in made.items():
        try:
            validate(document)
        except ValidationError as error:
            pytest.fail(f"{what}: {error.message}")
    with (tmp_path / "batch" / "summary.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2
    for row in rows:
        validate(_typed(row), BATCH_SUMMARY_ROW)


def _typed(row: dict) -> dict:
    """A summary row as a reader types it: integers and numbers where the cell holds one."""
    typed = {}
    for name, cell in row.items():
        for kind in (int, float):
            try:
                typed[name] = kind(cell)
                break
            except ValueError:
                continue
        else:
            typed[name] = cell
    return typed


def test_the_shipped_schemas_are_valid_and_name_their_kind():
    for fmt, name in SCHEMAS.items():
        Draft202012Validator.check_schema(schema(name))
        assert schema(name)["properties"]["format"] == {"const": fmt}
    Draft202012Validator.check_schema(schema("common.json"))
    Draft202012Validator.check_schema(schema(BATCH_SUMMARY_ROW))


@pytest.fixture(scope="module")
def calibration_document():
    samples = pd.read_csv(BUNDLED).to_numpy()
    return nlpcal.calibrate(samples, method="joint").to_dict()


@pytest.mark.parametrize(
    "change",
    [
        lambda d: d.update(unknown_key=1),
        lambda d: d.pop("parameters"),
        lambda d: d.pop("solver"),
        lambda d: d["parameters"].update(z_x=float("nan")),
        lambda d: d["parameters"].update(z_x=float("inf")),
        lambda d: d["parameters"].update(z_x="1.0"),
        lambda d: d["solver"].update(status="At_Stationary_Point"),
        lambda d: d["solver"]["stages"][0].update(ipopt_status="At_Data_Resolution"),
        lambda d: d["solver"]["stages"][0].update(finished_by="luck"),
        lambda d: d["statistics"][1].update(unknown_key=1.0),
        lambda d: d.update(format_version=3),
        lambda d: d.update(sensor_id=["mag"]),
    ],
    ids=[
        "unknown key",
        "missing parameters",
        "missing solver report",
        "NaN",
        "infinity",
        "number as text",
        "status beside the report",
        "nlpcal's status as IPOPT's",
        "unknown finisher",
        "unknown row key",
        "future version",
        "sensor id a list",
    ],
)
def test_a_schema_refuses_what_nlpcal_never_writes(calibration_document, change):
    validate(calibration_document)
    broken = copy.deepcopy(calibration_document)
    change(broken)
    with pytest.raises(ValidationError):
        validate(broken)


def test_keys_other_work_adds_are_accepted(calibration_document):
    document = copy.deepcopy(calibration_document)
    document.update(
        sensor_id="mag-7", orientation={"system": "px4", "parameter": "CAL_MAG0_ROT", "value": 0}
    )
    document["identifiability"]["second_order_bias"] = {"bias": {"z_x": 0.1}}
    document["identifiability"]["score_dependence"] = {"method": "block-jackknife"}
    document["identifiability"].pop("standard_error_inflation", None)
    validate(document)


def test_a_parameters_file_written_by_0_1_0_applies_identically(tmp_path, capsys):
    """tests/expected/params-0.1.0.json and applied-0.1.0.csv were written by nlpcal 0.1.0
    (`calibrate data/example_zhou2010.csv --reference-field 49460`, then `apply` on the first
    200 rows of the log)."""
    old = EXPECTED / "params-0.1.0.json"
    document = json.loads(old.read_text())
    assert document["format_version"] == 1 and document["nlpcal_version"] == "0.1.0"
    validate(document)  # the schema still accepts the version it reads
    result = CalibrationResult.load(old)
    assert result.solver.last.finished_by == "newton"  # read with its statuses told apart
    raw = pd.read_csv(BUNDLED).to_numpy()[:200]
    expected = pd.read_csv(EXPECTED / "applied-0.1.0.csv")
    # the same formula on the same numbers: equal to the rounding of a few float64 operations
    np.testing.assert_allclose(
        result.apply(raw), expected[["bx", "by", "bz"]].to_numpy(), rtol=1e-13, atol=1e-9
    )
    log = tmp_path / "head.csv"
    pd.read_csv(BUNDLED).head(200).to_csv(log, index=False)
    out = tmp_path / "applied.csv"
    assert run("apply", old, log, "-o", out, "-q") == 0, capsys.readouterr().err
    applied = pd.read_csv(out)
    # 0.2.0's apply adds the `valid` column (every row of this log is a reading) and writes one
    # significant digit more than the log's numbers carry: equal to half a unit of that digit
    assert list(applied.columns) == [*expected.columns, "valid"]
    assert (applied["valid"] == 1).all()
    digits = max(
        len(cell.replace("-", "").replace(".", "").lstrip("0"))
        for cell in log.read_text().split()[1].split(",")
    )
    written = applied[expected.columns].to_numpy()
    unit = 10.0 ** (np.floor(np.log10(np.abs(expected.to_numpy()))) - digits)  # [nT]
    assert (np.abs(written - expected.to_numpy()) <= 0.5 * unit * (1 + 1e-9)).all()
