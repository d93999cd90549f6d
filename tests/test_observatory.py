"""Geomagnetic observatory files: IAGA-2002 text and INTERMAGNET ImagCDF, each written here to its
format's specification from the independent forward model in synthetic.py, read by the one
reader with their header kept, calibrated end to end, and their terms of use printed wherever
results are shown; the real Conrad Observatory file of ../shared (skipped without it); broken
files exit 2 with one sentence."""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import pytest

from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.io import read_log
from synthetic import PAPER_FIELD, PAPER_TRUTH, make_log

#: A recovered parameter lies within this many of its standard errors of the truth (the noise is
#: fixed by the seed; five standard errors leave a margin for any BLAS kernel's rounding). [1]
WITHIN_SE = 5.0
TERMS = (
    "Data of the Test Observatory are licensed under CC-BY-4.0. Publications should "
    "acknowledge: The results presented rely on data collected at the Test Observatory."
)
START = np.datetime64("2024-05-10T00:00:00", "ns")


def field(n=1500, noise=2.0, seed=7):
    """Sensor output [nT] of the forward model and the true magnitude of the field [nT]."""
    samples, _ = make_log(n=n, noise=noise, seed=seed)
    return samples, np.full(n, PAPER_FIELD)


def iaga_text(values: dict, step_s=1.0, comments=(), code="TST", reported=None) -> str:
    """An IAGA-2002 file: fixed-width header records, comments, column names, data lines."""

    def record(key, value):
        return f" {key:<23}{value:<44}|"

    elements = list(values)
    header = [
        record("Format", "IAGA-2002"),
        record("Source of Data", "Test Institute"),
        record("Station Name", "Test Observatory"),
        record("IAGA CODE", code),
        record("Geodetic Latitude", "47.928"),
        record("Geodetic Longitude", "15.866"),
        record("Elevation", "1087"),
        record("Reported", reported or "".join(elements)),
        record("Sensor Orientation", "XYZ"),
        record("Digital Sampling", "0.1 second"),
        record("Data Interval Type", f"{step_s:g}-second"),
        record("Data Type", "variation"),
        *(f" # {c:<66}|" for c in comments),
    ]
    names = "DATE       TIME         DOY " + "".join(f"    {code}{e:<5}" for e in elements)
    times = START + (np.arange(len(next(iter(values.values())))) * step_s * 1e9).astype(
        "timedelta64[ns]"
    )
    lines = []
    for k, t in enumerate(times):
        stamp = str(t)[:23].replace("T", " ")
        doy = (t.astype("datetime64[D]") - t.astype("datetime64[Y]")).astype(int) + 1
        cells = "".join(f" {values[e][k]:9.2f}" for e in elements)
        lines.append(f"{stamp} {doy:03d}   {cells}")
    return "\n".join([*header, f"{names:<69}|", *lines]) + "\n"


def write_imagcdf(path, values: dict, units=None, terms=TERMS, step_s=1.0, attributes=None):
    """An ImagCDF file through cdflib: DataTimes (TT2000), one variable per element."""
    cdflib = pytest.importorskip("cdflib")
    from cdflib.cdfwrite import CDF as Writer

    n = len(next(iter(values.values())))
    times = START + (np.arange(n) * step_s * 1e9).astype("timedelta64[ns]")
    tt2000 = cdflib.cdfepoch.compute_tt2000(
        [
            [int(x) for x in str(t)[:19].replace("T", "-").replace(":", "-").split("-")]
            for t in times
        ]
    )
    globals_ = {
        "FormatDescription": {0: "INTERMAGNET CDF Format"},
        "FormatVersion": {0: "1.3"},
        "IagaCode": {0: "TST"},
        "ObservatoryName": {0: "Test Observatory"},
        "ElementsRecorded": {0: "".join(e for e in values if not e.startswith("T"))},
        "VectorSensOrient": {0: "XYZ"},
        **({"TermsOfUse": {0: terms}} if terms else {}),
        **(attributes or {}),
    }
    writer = Writer(str(path), cdf_spec={"Compressed": False}, delete=True)
    writer.write_globalattrs(globals_)
    time_spec = {"Variable": "DataTimes", "Data_Type": 33, "Num_Elements": 1, "Rec_Vary": True,
                 "Dim_Sizes": []}  # fmt: skip
    writer.write_var(time_spec, var_attrs={}, var_data=np.asarray(tt2000, dtype=np.int64))
    for element, data in values.items():
        name = (
            f"Temperature{element[1:]}" if element.startswith("T") else f"GeomagneticField{element}"
        )
        spec = {"Variable": name, "Data_Type": 45, "Num_Elements": 1, "Rec_Vary": True,
                "Dim_Sizes": []}  # fmt: skip
        attrs = {
            "DEPEND_0": "DataTimes",
            "FILLVAL": 99999.0,
            "VALIDMIN": -273.0 if element.startswith("T") else -88880.0,
            "VALIDMAX": 88880.0,
            "UNITS": (units or {}).get(element, "Celsius" if element.startswith("T") else "nT"),
        }
        writer.write_var(spec, var_attrs=attrs, var_data=np.asarray(data, dtype=float))
    writer.close()
    return path


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_recovers(document: dict) -> None:
    for name, value in PAPER_TRUTH.items():
        gap = abs(document["parameters"][name] - value) / document["standard_errors"][name]
        assert gap < WITHIN_SE, (name, document["parameters"][name], value)


# --- IAGA-2002 ----------------------------------------------------------------------------------


def test_an_iaga2002_file_calibrates_against_its_scalar_with_its_header_kept(tmp_path, capsys):
    samples, total = field()
    path = tmp_path / "tst20240510vsec.sec"
    values = {"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2], "F": total}
    comments = ("CONDITIONS OF USE: Data of the Test Observatory are licensed under", "CC-BY-4.0.")
    path.write_text(iaga_text(values, comments=comments))
    output = tmp_path / "params.json"
    code, _, err = run(capsys, "calibrate", path, "--reference-column", "F", "-o", output)
    assert code == 0, err
    document = json.loads(output.read_text())
    assert_recovers(document)
    assert document["input"]["columns"] == ["X", "Y", "Z"]
    assert document["input"]["unit_source"] == "format"
    record = document["input"]["observatory"]
    assert record["format"] == "IAGA-2002" and record["iaga_code"] == "TST"
    assert record["station"] == "Test Observatory" and record["elements"] == "XYZF"
    assert record["sampling_interval_s"] == 1.0
    assert record["terms_of_use"] == " ".join(comments)
    assert record["header"]["Geodetic Latitude"] == "47.928"
    assert f"terms of use of the data: {' '.join(comments)}" in err


def test_iaga2002_missing_and_not_recorded_values_are_counted_and_dropped(tmp_path, capsys):
    samples, total = field(n=400)
    total = total.copy()
    samples = samples.copy()
    samples[5, 1] = 99999.0  # missing
    total[[7, 8]] = 88888.0  # not recorded
    values = {"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2], "F": total}
    path = tmp_path / "gaps.min"
    path.write_text(iaga_text(values, step_s=60.0))
    with pytest.raises(InputError):
        read_log(path, reference_column="F")
    log = read_log(path, reference_column="F", drop_invalid=True)
    assert log.n == 397 and log.dropped == 3
    assert log.observatory.missing_values == {"Y": 1, "F": 2}
    assert log.observatory.sampling_interval_s == 60.0
    assert any("Y 1, F 2" in note for note in log.notes)


def test_an_iaga2002_file_with_declination_names_no_field_columns(tmp_path, capsys):
    samples, total = field(n=100)
    values = {"H": samples[:, 0], "D": samples[:, 1] / 1000, "Z": samples[:, 2], "F": total}
    path = tmp_path / "hdz.sec"
    path.write_text(iaga_text(values))
    code, _, err = run(capsys, "stats", path)
    assert code == 2 and "--columns" in err and "Traceback" not in err
    log = read_log(path, columns=["H", "D", "Z"])  # the user's own choice, D in arcmin
    assert log.observatory.units["D"] == "arcmin"


# --- ImagCDF ------------------------------------------------------------------------------------


def test_an_imagcdf_file_calibrates_against_its_scalar_with_its_header_kept(tmp_path, capsys):
    samples, total = field()
    temperature = np.linspace(10, 12, len(total))
    values = {"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2], "S": total,
              "T1": temperature}  # fmt: skip
    path = write_imagcdf(tmp_path / "tst.cdf", values)
    output = tmp_path / "params.json"
    code, _, err = run(capsys, "calibrate", path, "--reference-column", "S", "-o", output)
    assert code == 0, err
    document = json.loads(output.read_text())
    assert_recovers(document)
    record = document["input"]["observatory"]
    assert record["format"] == "ImagCDF" and record["elements"] == "XYZS"
    assert record["units"] == {"X": "nT", "Y": "nT", "Z": "nT", "S": "nT", "T1": "degC"}
    assert record["terms_of_use"] == TERMS and f"terms of use of the data: {TERMS}" in err
    log = read_log(path)
    assert np.allclose(log.frame["T1"].to_numpy(), temperature)
    assert log.frame["time"].iloc[1] - log.frame["time"].iloc[0] == np.timedelta64(1, "s")
    assert str(log.frame["time"].iloc[0]) == "2024-05-10 00:00:00"


def test_the_terms_of_use_follow_the_parameters_into_apply_stats_and_report(tmp_path, capsys):
    samples, total = field(n=600)
    values = {"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2], "S": total}
    path = write_imagcdf(tmp_path / "tst.cdf", values)
    params = tmp_path / "params.json"
    code, _, err = run(capsys, "-q", "calibrate", path, "--reference-column", "S", "-o", params)
    assert code == 0 and err.count("terms of use") == 1  # a condition of use, printed with -q
    csv = tmp_path / "other.csv"
    csv.write_text("bx,by,bz\n" + "\n".join(",".join(map(str, row)) for row in samples) + "\n")
    for argv in (
        ("apply", params, csv, "-o", tmp_path / "out.csv"),
        ("stats", csv, "--params", params),
        ("report", params, path, "-o", tmp_path / "report.html"),
    ):
        code, _, err = run(capsys, *argv)
        assert code == 0, err
        assert err.count(f"terms of use of the data: {TERMS}") == 1, argv
    assert TERMS in (tmp_path / "report.html").read_text()
    code, _, err = run(capsys, "stats", csv)
    assert "terms of use" not in err  # nothing from the observatory here
    plain = tmp_path / "plain.json"
    code, _, err = run(capsys, "calibrate", csv, "--reference-field", PAPER_FIELD, "-o", plain)
    assert code == 0 and "terms of use" not in err
    for argv in (  # the observatory's data through a calibration of other data
        ("apply", plain, path, "-o", tmp_path / "cdf.csv"),
        ("stats", path, "--params", plain),
    ):
        code, _, err = run(capsys, *argv)
        assert code == 0 and err.count(f"terms of use of the data: {TERMS}") == 1, argv


def test_imagcdf_fill_values_and_values_outside_the_valid_range_are_missing(tmp_path):
    samples, total = field(n=200)
    total = total.copy()
    total[3], total[4] = 99999.0, np.nan
    samples = samples.copy()
    samples[9, 2] = 95000.0  # above VALIDMAX
    values = {"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2], "S": total}
    path = write_imagcdf(tmp_path / "tst.cdf", values)
    log = read_log(path, reference_column="S", drop_invalid=True)
    assert log.dropped == 3 and log.observatory.missing_values == {"Z": 1, "S": 2}


def test_an_imagcdf_scalar_on_its_own_times_is_placed_where_they_coincide(tmp_path):
    """GeomagneticFieldS every 5 s on GeomagneticScalarTimes, the vector every second on
    GeomagneticVectorTimes: S is read on the vector's rows at the coinciding times, and as a
    reference log it is interpolated between them."""
    cdflib = pytest.importorskip("cdflib")
    from cdflib.cdfwrite import CDF as Writer

    from nlpcal.io.reference import ReferenceLog

    n = 300
    samples, _ = make_log(n=n, noise=1.0, seed=2)
    unix_s = START.astype("int64") / 1e9 + np.arange(n)
    path = tmp_path / "own.cdf"
    writer = Writer(str(path), cdf_spec={"Compressed": False}, delete=True)
    writer.write_globalattrs({"IagaCode": {0: "TST"}, "ElementsRecorded": {0: "XYZS"}})
    for name, times in (
        ("GeomagneticVectorTimes", unix_s),
        ("GeomagneticScalarTimes", unix_s[::5]),
    ):
        spec = {"Variable": name, "Data_Type": 33, "Num_Elements": 1, "Rec_Vary": True,
                "Dim_Sizes": []}  # fmt: skip
        tt2000 = np.asarray(cdflib.cdfepoch.timestamp_to_tt2000(times), dtype=np.int64)
        writer.write_var(spec, var_attrs={}, var_data=tt2000)
    scalar = PAPER_FIELD + np.arange(0, n, 5) * 0.1  # a slow ramp, 0.1 nT/s [nT]
    for element, data, times in (
        *((e, samples[:, k], "GeomagneticVectorTimes") for k, e in enumerate("XYZ")),
        ("S", scalar, "GeomagneticScalarTimes"),
    ):
        spec = {"Variable": f"GeomagneticField{element}", "Data_Type": 45, "Num_Elements": 1,
                "Rec_Vary": True, "Dim_Sizes": []}  # fmt: skip
        attrs = {"DEPEND_0": times, "FILLVAL": 99999.0, "UNITS": "nT"}
        writer.write_var(spec, var_attrs=attrs, var_data=np.asarray(data, dtype=float))
    writer.close()
    log = read_log(path, reference_column="S", drop_invalid=True)
    assert log.n == n // 5 and np.allclose(log.reference, scalar)
    assert any("its own times (GeomagneticScalarTimes)" in note for note in log.notes)
    spec = ReferenceLog(path=str(path), column="S")
    log = read_log(path, reference_log=spec)
    assert log.n == n - 4  # after the scalar's last sample
    assert np.allclose(log.reference, PAPER_FIELD + np.arange(n - 4) * 0.1)


def test_a_missing_cdflib_names_its_extra(tmp_path, capsys, monkeypatch):
    samples, total = field(n=50)
    path = write_imagcdf(tmp_path / "tst.cdf", {"X": samples[:, 0], "Y": samples[:, 1],
                                                  "Z": samples[:, 2]})  # fmt: skip
    monkeypatch.setitem(sys.modules, "cdflib", None)  # import fails as if not installed
    code, _, err = run(capsys, "calibrate", path, "-o", tmp_path / "p.json")
    assert code == 2 and "pip install 'nlpcal[cdf]'" in err and "Traceback" not in err
    assert err.count("\n") == 1


def test_an_imagcdf_read_from_stdin_leaves_no_file_behind(tmp_path, monkeypatch):
    import io
    import tempfile

    samples, _ = field(n=80)
    path = write_imagcdf(tmp_path / "tst.cdf", {"X": samples[:, 0], "Y": samples[:, 1],
                                                  "Z": samples[:, 2]})  # fmt: skip
    spool = tmp_path / "spool"
    spool.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spool))
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(path.read_bytes())))
    log = read_log("-")
    assert log.n == 80 and log.observatory.format == "ImagCDF"
    assert list(spool.iterdir()) == []


# --- broken files -------------------------------------------------------------------------------


def broken_files(tmp_path) -> list:
    samples, total = field(n=30)
    good = iaga_text({"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2], "F": total})
    head, _, body = good.partition("DATE")
    lines = good.splitlines()
    cases = {
        "no_names.sec": head,
        "no_data.sec": head + "DATE" + body.splitlines()[0] + "\n",
        "bad_date.sec": "\n".join([*lines[:-1], "2024-13-45 99:00:00.000 001 1 2 3 4"]) + "\n",
        "text_value.sec": "\n".join([*lines[:-1], lines[-1].rsplit(" ", 1)[0] + " abc"]) + "\n",
        "ragged.sec": "\n".join([*lines[:-1], lines[-1] + " 5 6 7"]) + "\n",
        "repeated.sec": good.replace("TSTY", "TSTX", 1),
        "short_names.sec": head + "DATE TIME\n",
        "cut.sec": good[: len(good) // 2 + 7],
    }
    paths = []
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        paths.append(tmp_path / name)
    for name, data in (
        ("cut.cdf", b"\xcd\xf3\x00\x01\x00\x00\xff\xff" + b"\x00" * 40),
        ("garbage.cdf", b"\xcd\xf3\x00\x01\xcc\xcc\x00\x01" + bytes(range(256)) * 4),
        ("v26.cdf", b"\xcd\xf2\x60\x02" + b"\xff" * 300),
    ):
        (tmp_path / name).write_bytes(data)
        paths.append(tmp_path / name)
    return paths


def test_broken_observatory_files_exit_2_with_one_sentence(tmp_path, capsys):
    pytest.importorskip("cdflib")
    for path in broken_files(tmp_path):
        code, _, err = run(capsys, "calibrate", path, "-o", tmp_path / "p.json")
        assert code == 2, (path.name, err)
        assert "Traceback" not in err and err.count("\n") == 1, (path.name, err)
        assert not (tmp_path / "p.json").exists()


def test_a_cdf_that_is_not_imagcdf_and_a_cut_imagcdf_are_refused(tmp_path):
    cdflib = pytest.importorskip("cdflib")
    from cdflib.cdfwrite import CDF as Writer

    path = tmp_path / "other.cdf"
    writer = Writer(str(path), cdf_spec={"Compressed": False}, delete=True)
    spec = {"Variable": "Density", "Data_Type": 45, "Num_Elements": 1, "Rec_Vary": True,
            "Dim_Sizes": []}  # fmt: skip
    writer.write_var(spec, var_attrs={}, var_data=np.arange(10.0))
    writer.close()
    with pytest.raises(InputError, match="ImagCDF"):
        read_log(path)
    samples, _ = field(n=200)
    whole = write_imagcdf(tmp_path / "tst.cdf", {"X": samples[:, 0], "Y": samples[:, 1],
                                                  "Z": samples[:, 2]})  # fmt: skip
    data = whole.read_bytes()
    assert cdflib  # the writer above is cdflib's
    for cut in (len(data) // 3, len(data) // 2, len(data) - 9):
        (tmp_path / "cut.cdf").write_bytes(data[:cut])
        with pytest.raises(InputError):
            read_log(tmp_path / "cut.cdf")


def test_random_bytes_after_an_observatory_signature_exit_2(tmp_path, capsys):
    """A small fuzz: the signature of each format, then random bytes or random lines."""
    pytest.importorskip("cdflib")
    rng = np.random.default_rng(0)
    samples, total = field(n=20)
    good = iaga_text({"X": samples[:, 0], "Y": samples[:, 1], "Z": samples[:, 2], "F": total})
    for k in range(40):
        if k % 2:
            data = (
                b"\xcd\xf3\x00\x01"
                + rng.integers(0, 256, int(rng.integers(4, 600))).astype(np.uint8).tobytes()
            )
        else:
            lines = good.splitlines()
            at = int(rng.integers(1, len(lines)))
            chars = rng.choice(list("0123456789 .-:|#ABCXYZ\t"), int(rng.integers(1, 60)))
            lines[at] = "".join(chars)
            data = ("\n".join(lines) + "\n").encode()
        path = tmp_path / f"fuzz{k}"
        path.write_bytes(data)
        code = main(["stats", str(path)])
        _, err = capsys.readouterr()
        assert code in (0, 2), err
        assert "Traceback" not in err and "internal error" not in err


# --- the real Conrad Observatory file -----------------------------------------------------------

CONRAD = "conrad_wic_lemi036_imagcdf/wic_lemi036_20240509_20240512.cdf"


def test_the_conrad_imagcdf_reads_in_seconds_with_its_terms(real_data, capsys):
    """Four days at 1 Hz of a LEMI036 fluxgate and the scalar F (SOURCE.md): the figures SOURCE.md
    gives (345 600 samples, 2 NaN in S, delta F 11.722 nT mean and 0.0307 nT std)."""
    pytest.importorskip("cdflib")
    path = real_data / CONRAD
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    started = time.process_time()  # CPU time: what the reader costs, whatever else runs
    log = read_log(path, reference_column="S", drop_invalid=True)
    read_s = time.process_time() - started
    assert read_s < 5.0  # the 10 MB file, decompressed and read (about 0.3 s here)
    assert log.columns == ["H", "E", "Z"] and log.unit == "nT" and log.n == 345_598
    record = log.observatory
    assert record.iaga_code == "WIC" and record.elements == "HEZS"
    assert record.missing_values == {"S": 2} and record.sampling_interval_s == 1.0
    assert (
        "Conrad Observatory" in record.terms_of_use and "GeoSphere Austria" in record.terms_of_use
    )
    delta = np.linalg.norm(log.samples, axis=1) - log.reference
    assert abs(delta.mean() - 11.722) < 0.001 and abs(delta.std() - 0.0307) < 0.0005
    assert log.frame["time"].iloc[0] == np.datetime64("2024-05-09T00:00:00")
    code, _, err = run(capsys, "stats", path, "--reference-column", "S", "--drop-invalid")
    assert code == 0 and "We thank GeoSphere Austria" in err
