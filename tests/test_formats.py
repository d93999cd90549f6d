"""Exports and imports: every format round-trips, and the exported corrections applied the way
MATLAB, ArduPilot and PX4 apply them reproduce `apply` on the bundled log.

Each system's formula is typed in again here, from its documentation and source, and the files
are parsed here with a few lines of their own, so that neither the formula nor the reading of
nlpcal's writers is checked against itself:

* MATLAB magcal: C = (D - b) * A, D one sample per row (Sensor Fusion Toolbox, magcal).
* ArduPilot (AP_Compass_Backend::correct_field): m' = D (k (m + OFS)) in milligauss, D the
  symmetric [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]], k COMPASS_SCALE.
* PX4 (calibration::Magnetometer::Correct): m' = S (m - OFF) in gauss, S the symmetric
  [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG], [YODIAG, ZODIAG, ZSCALE]].

The autopilots hold the symmetric factor P of A = R P, so they give R^T B1; R comes here from
scipy's polar decomposition (an independent implementation).
"""

import json
import re
from pathlib import Path

import numpy as np
import pytest

import nlpcal
from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.formats import export, import_file
from nlpcal.models.zhou2010 import Zhou2010Parameters, correction_matrix, from_correction

scipy_linalg = pytest.importorskip("scipy.linalg")

EXAMPLE = Path(__file__).resolve().parents[1] / "data" / "example_zhou2010.csv"
FORMATS = ("matlab", "matrix", "ardupilot", "px4", "c-header")
#: Round trips through text must give back the nine parameters to this relative error. [1]
ROUND_TRIP = 1e-9
#: The exported corrections must reproduce `apply` to this, in nT (a double-precision budget:
#: 17 significant digits of a 5e4 nT field leave ~1e-11 nT). [nT]
APPLY_NT = 1e-6


@pytest.fixture(scope="module")
def calibrated():
    log = nlpcal.read_log(EXAMPLE, reference_field=49462.0)
    result = nlpcal.calibration.calibrate_log(log, method="joint")
    return result, log


def _relative(a: dict, b: dict) -> float:
    names = list(a)
    x, y = np.array([a[n] for n in names]), np.array([b[n] for n in names])
    return float(np.max(np.abs(x - y) / np.abs(x)))


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_round_trips_through_import(calibrated, tmp_path, fmt):
    result, _ = calibrated
    path = tmp_path / f"out.{fmt}"
    path.write_text(export(result, fmt).text)
    back, notes = import_file(path, fmt)
    assert _relative(result.parameters, back.parameters) < ROUND_TRIP
    assert back.method == "imported" and back.unit == "nT"
    if fmt in ("ardupilot", "px4"):  # the symmetric factor: the rotation is reported
        assert back.input["rotation_not_carried"]["angle_deg"] == pytest.approx(1.3507, abs=1e-3)
        assert "rotation of 1.351 deg" in notes[-1]


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_of_other_parameters_and_units(tmp_path, fmt):
    params = Zhou2010Parameters(1234.5, -321.0, 55.5, 0.031, -0.012, 0.0205, 0.8, -1.7, 2.9)
    result = nlpcal.CalibrationResult(
        parameters=params.to_dict(), statistics=[], unit_source="option"
    )
    result.input = {"log_unit": "uT"}
    unit = None if fmt in ("ardupilot", "px4") else "uT"
    path = tmp_path / "x"
    path.write_text(export(result, fmt, unit=unit).text)
    back, _ = import_file(path, fmt)
    assert _relative(params.to_dict(), back.parameters) < ROUND_TRIP


def _symmetric_rotation(result):
    rotation, _ = scipy_linalg.polar(correction_matrix(result.model))
    return rotation


def test_matlab_export_applied_as_magcal_reproduces_apply(calibrated):
    result, log = calibrated
    text = export(result, "matlab").text
    code = re.sub(r"%[^\n]*", "", text).replace("...", "")
    a = np.array(
        [row.split() for row in re.search(r"A = \[(.*?)\]", code, re.S).group(1).split(";")],
        dtype=float,
    )
    b = np.array(re.search(r"b = \[(.*?)\]", code).group(1).split(), dtype=float)
    c = (log.samples - b) @ a  # magcal: C = (D - b) * A
    assert np.abs(c - result.apply(log.samples)).max() < APPLY_NT


def _parameters(text):
    values = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        fields = re.split(r"[,\t]", line)
        name, value = (fields[2], fields[3]) if len(fields) == 5 else fields
        values[name] = float(value)
    return values


@pytest.mark.parametrize("instance", [1, 2, 3])
def test_ardupilot_export_applied_as_ardupilot_reproduces_apply(calibrated, instance):
    result, log = calibrated
    p = _parameters(export(result, "ardupilot", instance=instance).text)
    n = "" if instance == 1 else str(instance)
    ofs = np.array([p[f"COMPASS_OFS{n}_{a}"] for a in "XYZ"])
    dia = [p[f"COMPASS_DIA{n}_{a}"] for a in "XYZ"]
    odi = [p[f"COMPASS_ODI{n}_{a}"] for a in "XYZ"]
    k = p[f"COMPASS_SCALE{n}"]
    d = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    m = log.samples / 100.0  # nT -> mGauss
    corrected = (k * (m + ofs)) @ d.T * 100.0  # m' = D (k (m + OFS)), back to nT
    b1 = result.apply(log.samples)
    assert np.abs(corrected - b1 @ _symmetric_rotation(result)).max() < APPLY_NT  # R^T B1
    magnitudes = np.linalg.norm(corrected, axis=1) - np.linalg.norm(b1, axis=1)
    assert np.abs(magnitudes).max() < APPLY_NT


@pytest.mark.parametrize("instance", [0, 3])
def test_px4_export_applied_as_px4_reproduces_apply(calibrated, instance):
    result, log = calibrated
    p = _parameters(export(result, "px4", instance=instance).text)
    key = f"CAL_MAG{instance}_"
    off = np.array([p[f"{key}{a}OFF"] for a in "XYZ"])
    sc = [p[f"{key}{a}SCALE"] for a in "XYZ"]
    od = [p[f"{key}{a}ODIAG"] for a in "XYZ"]
    s = np.array([[sc[0], od[0], od[1]], [od[0], sc[1], od[2]], [od[1], od[2], sc[2]]])
    corrected = (log.samples / 1e5 - off) @ s.T * 1e5  # m' = S (m - OFF) in gauss, to nT
    b1 = result.apply(log.samples)
    assert np.abs(corrected - b1 @ _symmetric_rotation(result)).max() < APPLY_NT


def test_c_header_keeps_full_precision(calibrated):
    result, log = calibrated
    text = export(result, "c-header").text
    numbers = re.findall(r"[-+]?\d\.\d{10,}e?[-+]?\d*", text)
    assert len(numbers) >= 6  # never rounded to 6 decimals
    a = np.array(
        re.findall(r"[-+0-9.e]+", re.search(r"NLPCAL_A\[3\]\[3\] = (\{.*?\}\});", text, re.S)[1]),
        dtype=float,
    ).reshape(3, 3)
    b = np.array(re.findall(r"[-+0-9.e]+", re.search(r"NLPCAL_B\[3\] = (\{.*?\})", text)[1]))
    corrected = (log.samples - b.astype(float)) @ a.T
    assert np.abs(corrected - result.apply(log.samples)).max() < APPLY_NT
    assert text.splitlines()[0].startswith("/*") and "nT" in text.splitlines()[0]


def test_cholesky_route_recovers_parameters_behind_any_rotation():
    rng = np.random.default_rng(4)
    for _ in range(20):
        truth = Zhou2010Parameters(
            *rng.normal(0, 100, 3), *rng.uniform(-0.3, 0.3, 3), *rng.uniform(-30, 30, 3)
        )
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.linalg.det(q))  # a proper rotation
        params, rotation = from_correction(q @ correction_matrix(truth), truth.offsets)
        np.testing.assert_allclose(params.as_vector(), truth.as_vector(), rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(rotation, q, atol=1e-12)
    with pytest.raises(ValueError, match="handedness"):
        from_correction(np.diag([1.0, 1.0, -1.0]), np.zeros(3))


def test_ardupilot_refuses_what_it_cannot_express():
    weak = Zhou2010Parameters(s_x=-0.85)  # gain 0.15: DIA_X = 6.7, outside ArduPilot's 0.2 .. 5
    result = nlpcal.CalibrationResult(
        parameters=weak.to_dict(), statistics=[], unit_source="option"
    )
    with pytest.raises(InputError, match=r"COMPASS_DIA_X = 6.66667 lies outside 0.2 .. 5"):
        export(result, "ardupilot")
    tilted = nlpcal.CalibrationResult(
        parameters=Zhou2010Parameters(alpha_deg=12.0).to_dict(), statistics=[], unit_source="names"
    )
    with pytest.raises(InputError, match="turns the axes by 6"):
        export(tilted, "px4")
    assert export(tilted, "px4", max_rotation_deg=10).rotation_deg == pytest.approx(6, abs=0.1)
    counts = nlpcal.CalibrationResult(parameters=weak.to_dict(), statistics=[], unit="raw")
    with pytest.raises(InputError, match="raw counts"):
        export(counts, "ardupilot")
    far = Zhou2010Parameters(z_x=150_000.0, z_y=100_000.0)  # 1 800 mG is 180 000 nT
    fixed = nlpcal.CalibrationResult(far.to_dict(), [], unit_source="option")
    notes = export(fixed, "ardupilot").notes
    assert "COMPASS_OFFS_MAX" in notes[0]
    with pytest.raises(InputError, match="instances are 1, 2 and 3"):
        export(counts.__class__(weak.to_dict(), []), "ardupilot", instance=4)
    with pytest.raises(InputError, match="--unit"):
        export(counts.__class__(weak.to_dict(), []), "px4", unit="uT")


def test_imports_of_files_written_elsewhere(tmp_path):
    magcal = tmp_path / "magcal.m"
    magcal.write_text(
        "% from MATLAB\nA = [1.02, 0.01, 0 ; 0.01 0.98 0; ...\n 0 0 1.0];\nb = [12.5, -3, 4];\n"
        "expmfs = 48.2;\n"
    )
    result, notes = import_file(magcal, "matlab", unit="uT", reference_field=48.7947)
    scale = 48.7947 / 48.2
    corrected = result.apply(np.array([[40.0, 10.0, -20.0]]), unit="uT")
    expected = (np.array([[40.0, 10.0, -20.0]]) - [12.5, -3, 4]) @ (
        scale * np.array([[1.02, 0.01, 0], [0.01, 0.98, 0], [0, 0, 1.0]])
    )
    assert np.linalg.norm(corrected) == pytest.approx(np.linalg.norm(expected), rel=1e-12)
    assert result.reference.to_dict() == {"mode": "constant", "field": pytest.approx(48794.7)}
    assert result.parameters["z_x"] == pytest.approx(12500.0)  # uT -> nT
    assert "scaled by" in notes[0]

    ardupilot = tmp_path / "a.param"
    ardupilot.write_text("COMPASS_OFS_X 10\nCOMPASS_OFS_Y,-20  # comment\nCOMPASS_SCALE,0\n")
    result, _ = import_file(ardupilot, "ardupilot")  # DIA all zero: identity; SCALE 0: none
    assert result.parameters["z_x"] == pytest.approx(-1000.0)
    assert result.parameters["z_y"] == pytest.approx(2000.0)
    assert result.parameters["s_x"] == pytest.approx(0.0, abs=1e-15)

    px4 = tmp_path / "p.params"
    px4.write_text("param set CAL_MAG1_XOFF 0.01\nparam set CAL_MAG1_YSCALE 0.5\n")
    result, _ = import_file(px4, "px4", instance=1)
    assert result.parameters["z_x"] == pytest.approx(1000.0)
    assert result.parameters["s_y"] == pytest.approx(1.0)  # gain 1 / 0.5
    with pytest.raises(InputError, match="CAL_MAG0_XOFF"):
        import_file(px4, "px4")
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps({"A": [[1, 0], [0, 1]], "b": [0, 0, 0]}))
    with pytest.raises(InputError, match="shape"):
        import_file(broken, "matrix")


def test_export_and_import_commands(calibrated, tmp_path, capsys):
    params = tmp_path / "params.json"
    calibrate = ["calibrate", str(EXAMPLE), "--method", "joint", "-o", str(params), "-q"]
    assert main(calibrate) == 0
    capsys.readouterr()  # the example's columns (bx, by, bz) carry no unit: nT is assumed
    assert main(["export", str(params), "--format", "ardupilot"]) == 2
    assert "--unit" in capsys.readouterr().err
    assert main([*calibrate, "--unit", "nT"]) == 0
    capsys.readouterr()
    assert main(["export", str(params), "--format", "ardupilot", "--instance", "2"]) == 0
    out, err = capsys.readouterr()
    assert "COMPASS_OFS2_X," in out and "turns nlpcal's axes by 1.35" in err
    exported = tmp_path / "c.params"
    assert main(["export", str(params), "--format", "px4", "-o", str(exported)]) == 0
    back = tmp_path / "back.json"
    assert main(["import", str(exported), "--format", "px4", "-o", str(back)]) == 0
    capsys.readouterr()
    assert main(["stats", str(EXAMPLE), "--params", str(back), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    original = json.loads(params.read_text())["statistics"][-1]
    assert rows[1]["std"] == pytest.approx(original["std"], rel=1e-6)
    corrected = tmp_path / "corrected.csv"
    assert main(["apply", str(back), str(EXAMPLE), "-o", str(corrected), "-q"]) == 0
    assert main(["export", str(params), "--format", "matlab", "--instance", "1"]) == 2
    assert "--instance applies" in capsys.readouterr().err


def test_an_export_in_a_field_unit_needs_a_unit_that_fixes_the_scale(calibrated, tmp_path):
    result, log = calibrated  # nT assumed (bx, by, bz), but a reference field fixes the scale
    assert (result.unit_source, result.scale_fixed_by()) == ("assumed", "the reference field")
    written = export(result, "ardupilot")
    assert any("reference field" in note and "assumed" in note for note in written.notes)
    # without the reference nothing fixes the scale: refused, naming the remedies
    bare = nlpcal.CalibrationResult(
        parameters=result.parameters, statistics=[], unit_source="assumed"
    )
    for fmt in FORMATS:
        with pytest.raises(InputError, match=r"--unit.*reference field"):
            export(bare, fmt)
    # raw counts: only in raw
    counts = nlpcal.calibrate(log.samples / 100.0, method="joint")  # nT ruled out: raw counts
    assert (counts.unit, counts.unit_source) == ("raw", "assumed")
    assert "far from Earth's field" in counts.warnings[0]
    assert "A =" in export(counts, "matlab").text
    for fmt, unit in (("ardupilot", None), ("matrix", "nT")):
        with pytest.raises(InputError, match=r"raw counts.*--unit"):
            export(counts, fmt, unit=unit)
    # a parameters file from before unit_source is treated as an assumed unit
    old = result.to_dict()
    del old["unit_source"], old["reference"]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    with pytest.raises(InputError, match="does not record"):
        export(nlpcal.CalibrationResult.load(path), "px4")
    given = nlpcal.calibrate(log.samples, unit="nT", method="joint")
    assert given.unit_source == "option" and export(given, "px4").notes[:1] != written.notes[:1]


@pytest.mark.parametrize("command, function", [("export", export), ("import", import_file)])
def test_the_python_keywords_mirror_the_command_line_flags(command, function):
    import argparse
    import inspect

    from nlpcal.cli import build_parser

    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    keywords = inspect.signature(function).parameters
    for action in commands.choices[command]._actions:
        flags = [f for f in action.option_strings if f.startswith("--")]
        shared = ("--help", "--output", "--verbose", "--quiet")  # every command's, not the data's
        if not flags or action.help == argparse.SUPPRESS or flags[0] in shared:
            continue
        assert flags[0][2:].replace("-", "_") in keywords, flags[0]


def test_the_former_keywords_are_still_accepted(calibrated, tmp_path):
    calibrated, _ = calibrated
    path = tmp_path / "calibration.m"
    path.write_text(export(calibrated, "matlab").text)
    assert export(calibrated, fmt="matlab").text == export(calibrated, format="matlab").text
    new, _ = import_file(path, format="matlab", reference_field=50000.0)
    old, _ = import_file(path, fmt="matlab", field=50000.0)
    assert new.to_dict() == old.to_dict()
    assert new.reference.to_dict()["field"] == pytest.approx(50000.0)
    with pytest.raises(InputError, match="reference_field"):
        import_file(path, "matlab", reference_field=50000.0, field=40000.0)
    with pytest.raises(InputError, match="format"):
        export(calibrated, "matlab", fmt="px4")
    with pytest.raises(InputError, match="format"):
        import_file(path)
