"""Typed records inside documents (`nlpcal.results.Record`): a Table 1 row, read by its fields,
writes exactly the JSON object it was read from, and its keys are those of the schema."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import pytest

import nlpcal
from nlpcal.calibration import calibrate_log
from nlpcal.calibration.result import Identifiability
from nlpcal.errors import InputError
from nlpcal.results import Provenance, TableRow

HERE = Path(__file__).resolve().parent
LEGACY = HERE / "expected" / "params-0.1.0.json"


def schema_defs(name: str) -> dict:
    text = resources.files("nlpcal.schemas").joinpath(name).read_text()
    return json.loads(text)["$defs"]


def test_a_rows_fields_are_the_schemas_keys():
    # one spelling of the keys: the dataclass's fields, checked against the shipped schema
    schema = schema_defs("common.json")["tableRowFields"]["properties"]
    assert set(TableRow.keys_of()) == set(schema)


def test_a_row_writes_the_object_it_was_read_from():
    document = {
        "label": "cg cycle 2",
        "mean": 49462.0,
        "std": 16.25,
        "objective": 264.0,
        "from_moments": True,
        "iterations": 7,
        "wall_s": 0.5,
        "status": "converged",  # a key of another document: kept, in order
        "stage_status": {"orthogonal": "converged"},
    }
    row = TableRow.from_dict(document)
    assert row.std == 16.25 and row.max is None and row.extra["status"] == "converged"
    assert list(row.to_dict().items()) == list(document.items())
    assert row == document and dict(row) == document
    assert "max" not in row and row.get("max", 1.0) == 1.0 and row["max"] is None
    with pytest.raises(KeyError):
        row["no such key"]
    row["status"] = "diverged"  # writing by key sets the field or the extra entry
    row["range"] = 2.0
    assert row.extra["status"] == "diverged" and row.range == 2.0
    with pytest.raises(AttributeError):
        row.standard_deviation  # noqa: B018  a typo is an error, not a missing key


def test_the_legacy_file_reads_into_rows_and_writes_them_back_unchanged():
    document = json.loads(LEGACY.read_text())
    result = nlpcal.CalibrationResult.from_dict(document)
    assert all(isinstance(row, TableRow) for row in result.statistics)
    assert result.statistics[-1].label == document["statistics"][-1]["label"]
    assert result.to_dict()["statistics"] == document["statistics"]


@pytest.mark.parametrize(
    ("row", "field"),
    [
        ({"label": "x", "std": "16"}, "std"),
        ({"label": 3}, "label"),
        ({"label": "x", "mean": 1e400}, "mean"),
    ],
)
def test_a_malformed_row_in_a_document_is_named(row, field):
    parameters = dict.fromkeys(nlpcal.Zhou2010Parameters().to_dict(), 0.0)
    with pytest.raises(InputError, match=f"statistics\\[0\\]: {field}"):
        nlpcal.CalibrationResult.from_dict({"parameters": parameters, "statistics": [row]})


def test_a_calibrations_rows_are_typed_records():
    samples = nlpcal.simulate(600, seed=2)[["bx", "by", "bz"]].to_numpy()
    result = nlpcal.calibrate(samples, method="joint")
    assert [type(row) for row in result.statistics] == [TableRow, TableRow]
    final = result.statistics[-1]
    assert final.label == "joint" and final.std is not None and final.std > 0
    again = nlpcal.CalibrationResult.from_json(result.to_json())
    assert again.statistics == result.statistics


def test_identifiability_is_a_typed_record_read_by_its_fields():
    samples = nlpcal.simulate(600, seed=2)[["bx", "by", "bz"]].to_numpy()
    result = nlpcal.calibrate(samples, method="joint")
    block = result.identifiability
    assert isinstance(block, Identifiability)
    assert block.not_identifiable == [] and block.coverage is not None
    assert block.covariance_form == "sandwich" and not block.planar
    again = nlpcal.CalibrationResult.from_json(result.to_json())
    assert again.identifiability == block and isinstance(again.identifiability, Identifiability)
    # a document's block keeps the keys of other kinds, in order
    document = {"not_identifiable": ["z_z"], "gauss_newton_eigenvalues_scaled": [1.0, 2.0]}
    assert list(Identifiability.from_dict(document).to_dict().items()) == list(document.items())


def test_a_malformed_identifiability_block_is_named():
    parameters = dict.fromkeys(nlpcal.Zhou2010Parameters().to_dict(), 0.0)
    document = {"parameters": parameters, "identifiability": {"not_identifiable": "z_z"}}
    with pytest.raises(InputError, match=r"identifiability\.not_identifiable"):
        nlpcal.CalibrationResult.from_dict(document)


def test_provenance_is_a_typed_record_that_keeps_its_documents_order(tmp_path):
    log = tmp_path / "log.csv"
    nlpcal.simulate(600, seed=2).to_csv(log, index=False)
    read = nlpcal.read_log(log)
    result = calibrate_log(read, method="joint")
    assert isinstance(result.input, Provenance)
    assert result.input.log == str(log) and result.input.columns == ["bx", "by", "bz"]
    assert result.log_unit == result.input.log_unit == "nT"
    # an imported correction's block: its keys in the order it was written, the rest in extra
    document = {"imported_from": "a.params", "format": "px4", "log_unit": "nT", "sha256": "0"}
    block = Provenance.from_dict(document)
    assert block.log_unit == "nT" and block.extra["format"] == "px4"
    assert list(block.to_dict()) == list(document)


def test_records_given_as_objects_are_read_into_their_types():
    parameters = dict.fromkeys(nlpcal.Zhou2010Parameters().to_dict(), 0.0)
    result = nlpcal.CalibrationResult(parameters, [{"label": "measured", "std": 1.0}])
    assert isinstance(result.statistics[0], TableRow) and result.statistics[0].std == 1.0
    result.input = {"log_unit": "uT", "sha256": "0"}  # type: ignore[assignment]
    result.identifiability = {"not_identifiable": []}  # type: ignore[assignment]
    assert isinstance(result.input, Provenance) and result.log_unit == "uT"
    assert isinstance(result.identifiability, Identifiability)
