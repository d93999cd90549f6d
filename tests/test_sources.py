"""Logs of many files and Parquet files: the same columns, units and checks as one CSV."""

import sys

import numpy as np
import pandas as pd
import pytest

import nlpcal
from nlpcal.cli import main
from nlpcal.io import read_log
from nlpcal.io.sources import log_paths
from resolution import assert_same_optimum
from synthetic import PAPER_FIELD, make_log


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def frame():
    samples, _ = make_log(n=3000, noise=1.0, seed=41)
    table = pd.DataFrame(samples / 1000.0, columns=["mx_uT", "my_uT", "mz_uT"])
    table["proton_nT"] = PAPER_FIELD
    table["site"] = "lab"
    return table


def test_a_folder_or_pattern_of_csv_files_is_one_log_in_file_order(tmp_path, frame):
    parts = np.array_split(np.arange(len(frame)), 3)
    for k, rows in zip((2, 0, 1), parts):  # written out of order: read in name order
        frame.iloc[rows].to_csv(tmp_path / f"log_{k}.csv", index=False)
    (tmp_path / "notes.md").write_text("not a log\n")
    whole = tmp_path / "whole.csv"
    pd.concat([frame.iloc[parts[1]], frame.iloc[parts[2]], frame.iloc[parts[0]]]).to_csv(
        whole, index=False
    )
    expected = read_log(whole, reference_column="proton_nT")
    for source in (tmp_path / "log_*.csv", str(tmp_path / "log_?.csv")):
        log = read_log(source, reference_column="proton_nT")
        np.testing.assert_array_equal(log.samples, expected.samples)
        assert log.unit == "uT" and log.path == str(source)
    folder = read_log(tmp_path)  # whole.csv too: the folder's every CSV file
    assert folder.n == 2 * len(frame)
    assert [p.name for p in log_paths(tmp_path)] == [
        "log_0.csv",
        "log_1.csv",
        "log_2.csv",
        "whole.csv",
    ]


def test_the_files_of_a_log_must_have_the_same_columns(tmp_path, frame, capsys):
    frame.to_csv(tmp_path / "a.csv", index=False)
    frame.rename(columns={"site": "place"}).to_csv(tmp_path / "b.csv", index=False)
    for low_memory in ([], ["--low-memory"]):
        code, out, err = run(capsys, "calibrate", tmp_path / "*.csv", *low_memory)
        assert code == 2 and "b.csv: its columns" in err and len(err.splitlines()) == 1
    code, _, err = run(capsys, "calibrate", tmp_path / "*.parquet")
    assert code == 2 and "no file matches" in err
    (tmp_path / "empty").mkdir()
    code, _, err = run(capsys, "calibrate", tmp_path / "empty")
    assert code == 2 and "has no CSV or Parquet files" in err


def test_parquet_reads_like_csv_in_memory_and_streamed(tmp_path, frame, capsys):
    pytest.importorskip("pyarrow")
    frame.to_csv(tmp_path / "log.csv", index=False)
    for k, rows in enumerate(np.array_split(np.arange(len(frame)), 2)):
        frame.iloc[rows].to_parquet(tmp_path / f"log_{k}.parquet", index=False)
    frame.to_parquet(tmp_path / "no_suffix", index=False)  # known by its leading bytes
    expected = read_log(tmp_path / "log.csv", reference_column="proton_nT")
    for source, low_memory in (
        (tmp_path / "log_*.parquet", False),
        (tmp_path / "log_*.parquet", True),
        (tmp_path / "no_suffix", False),
        (tmp_path / "no_suffix", True),
    ):
        log = read_log(source, reference_column="proton_nT", low_memory=low_memory)
        np.testing.assert_allclose(log.samples, expected.samples, rtol=1e-15)
        np.testing.assert_allclose(log.reference, expected.reference, rtol=1e-15)
        assert log.unit == "uT" and log.notes == expected.notes
    out_csv, out_parquet = tmp_path / "a.json", tmp_path / "b.json"
    code, _, _ = run(capsys, "calibrate", tmp_path / "log.csv", "--method", "joint", "-o", out_csv)
    assert code == 0
    code, _, err = run(
        capsys, "calibrate", tmp_path / "log_*.parquet", "--method", "joint", "-o", out_parquet
    )
    assert code == 0, err
    a, b = (nlpcal.CalibrationResult.load(p) for p in (out_csv, out_parquet))
    assert_same_optimum(b.parameters, a.parameters, a.standard_errors)
    corrected = tmp_path / "corrected.csv"
    code, _, err = run(capsys, "apply", out_parquet, tmp_path / "log_1.parquet", "-o", corrected)
    assert code == 0, err
    assert list(pd.read_csv(corrected).columns) == [*frame.columns, "b_total", "valid"]


def test_a_bad_parquet_file_is_bad_input_in_one_line(tmp_path, frame, capsys, monkeypatch):
    pytest.importorskip("pyarrow")
    (tmp_path / "broken.parquet").write_bytes(b"PAR1 this is not a Parquet file PAR1")
    code, out, err = run(capsys, "calibrate", tmp_path / "broken.parquet")
    assert code == 2 and "cannot be read as Parquet" in err and len(err.splitlines()) == 1
    holed = frame.copy()
    holed.loc[10, "my_uT"] = np.nan
    holed.to_parquet(tmp_path / "holed.parquet", index=False)
    code, _, err = run(capsys, "calibrate", tmp_path / "holed.parquet")
    assert code == 2 and "first at data row 11" in err
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)  # as if pyarrow were missing
    code, _, err = run(capsys, "calibrate", tmp_path / "holed.parquet")
    assert code == 2 and "pip install 'nlpcal[parquet]'" in err


def test_a_file_whose_name_looks_like_a_pattern_is_that_file(tmp_path, frame):
    path = tmp_path / "log[1].csv"
    frame.to_csv(path, index=False)
    assert read_log(path).n == len(frame)
