"""Verdicts: one rule ranks a result's quality fields, every result kind carries its verdict,
and the terminal summary of calibrate puts it first."""

from __future__ import annotations

import re

import pytest

import nlpcal
from nlpcal.cli import main
from nlpcal.drift.fit import MAX_SLOPE_RELATIVE_ERROR, DriftFit
from nlpcal.verdict import STATUSES, judge, worst
from synthetic import PAPER_FIELD, make_log

RM3100 = ("rasteiro_robot_multisensor", "MPU6050RM3100_derived.csv")


@pytest.mark.parametrize(
    "fields, status",
    [
        ({}, "ok"),
        ({"warnings": ["w"]}, "warnings"),
        ({"poorly_determined": ["p"], "warnings": ["w"]}, "poorly_determined"),
        ({"failures": ["f"], "poorly_determined": ["p"], "warnings": ["w"]}, "failed"),
    ],
)
def test_the_worst_quality_field_decides(fields, status):
    verdict = judge(**fields)
    assert verdict.status == status
    assert verdict.reasons == (
        *fields.get("failures", ()),
        *fields.get("poorly_determined", ()),
        *fields.get("warnings", ()),
    )
    assert verdict.to_dict() == {"status": status, "reasons": list(verdict.reasons)}
    assert worst(*STATUSES) == "failed" and worst("ok", status) == status


def test_the_line_names_the_serious_reasons_and_counts_the_warnings():
    line = judge(["the data do not determine z_z"], [], ["a", "b"]).line()
    assert line == "FAILED: the data do not determine z_z; 2 warnings"
    assert judge().line() == "ok" and judge(warnings=["a"]).line() == "ok, with warnings: 1 warning"


def test_a_calibration_is_ok_with_a_reference_and_keeps_its_gauge_note_out_of_the_warnings():
    samples, _ = make_log(n=2000, noise=1.0, seed=3)
    with_reference = nlpcal.calibrate(samples, reference_field=PAPER_FIELD, method="joint")
    assert with_reference.verdict.status == "ok" and with_reference.notes == []
    without = nlpcal.calibrate(samples, method="joint")
    assert without.verdict.status == "ok" and without.warnings == [] and without.notes
    document = without.to_dict()
    assert list(document)[:3] == ["format", "format_version", "verdict"]
    assert document["verdict"] == {"status": "ok", "reasons": []}
    assert nlpcal.CalibrationResult.from_dict(document).notes == without.notes


def test_a_drift_slope_with_a_large_standard_error_is_poorly_determined():
    fit = DriftFit(
        a=1.0,
        b=50000.0,
        base_temperature=20.0,
        fit_rmse=1.0,
        n=100,
        temperature_range=(10.0, 30.0),
        a_standard_error=2 * MAX_SLOPE_RELATIVE_ERROR,
        b_standard_error=1.0,
        diurnal_base=50000.0,
    )
    assert fit.verdict.status == "poorly_determined"
    assert fit.to_dict()["verdict"]["reasons"][0].startswith("a: ")
    fit.a_standard_error = MAX_SLOPE_RELATIVE_ERROR / 2
    assert fit.verdict.status == "ok"


def test_the_terminal_summary_starts_with_the_verdict_and_summarises_the_cycles(
    real_data, tmp_path, capsys
):
    path = real_data.joinpath(*RM3100)
    out = tmp_path / "p.json"
    assert main(["calibrate", str(path), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    summary = err[err.index("nlpcal: verdict:") :]
    assert summary.startswith("nlpcal: verdict: POORLY DETERMINED: ")
    cycles = len(nlpcal.CalibrationResult.load(out).statistics) - 1
    assert cycles > 50
    shown = re.findall(r"^cycle \d+", err, re.M)
    assert len(shown) < 10 and "rows not shown" in err and f"cycle {cycles} " in err
    assert err.count("note: no reference field") == 1 and "warning: no reference" not in err
    assert main(["calibrate", str(path), "-o", str(out), "-v"]) == 0
    assert len(re.findall(r"^cycle \d+", capsys.readouterr().err, re.M)) == cycles
