"""`nlpcal platform fit|apply` and `nlpcal.fit_tolles_lawson`: Tolles-Lawson compensation on a
synthetic figure-of-merit box made by the independent forward model of tests/synthetic.py (exact
derivatives of the direction cosines, a slow field variation below the band, white noise).

The reference of the fit is computed here, as MagNav.jl does it and independently of nlpcal:
the design typed in again, a zero-phase Butterworth band-pass over the whole record (filtfilt),
its ends trimmed, and a ridge solve on the scaled columns with the parameter chosen by
generalised cross-validation through a singular value decomposition."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_fuzz import CELLS, FUZZ, finite_csv, no_nan
from test_fuzz import run as run_checked

import nlpcal
from nlpcal.cli import main
from synthetic import platform_record

signal = pytest.importorskip("scipy.signal")

RATE_HZ = 10.0
BAND_HZ = (0.1, 0.9)


@pytest.fixture(scope="module")
def box():
    """The done-when box: 12 000 samples at 10 Hz, the 18 true terms, 0.01 nT of noise."""
    return platform_record(n=12_000, rate_hz=RATE_HZ, noise=0.01, seed=5)


def reference_design(vector, rate_hz):
    """MagNav.jl's create_TL_A typed in again: cosines, |B| cos_i cos_j, |B| cos_i d(cos_j)/dt
    (central differences, np.gradient)."""
    bt = np.linalg.norm(vector, axis=1)
    c = vector / bt[:, None]
    dc = np.gradient(c, 1.0 / rate_hz, axis=0)
    induced = [bt * c[:, i] * c[:, j] for i in range(3) for j in range(i, 3)]
    eddy = [bt * c[:, i] * dc[:, j] for i in range(3) for j in range(3)]
    return np.column_stack([c, *induced, *eddy])


def zero_phase_ridge(vector, scalar, rate_hz=RATE_HZ, band=BAND_HZ, trim=20):
    """The band-passed residual std of MagNav's fit (filtfilt, trimmed ends), the ridge
    parameter of the scaled columns chosen by GCV over a fine grid. [nT]"""
    sos = signal.butter(4, band, btype="bandpass", fs=rate_hz, output="sos")
    a = signal.sosfiltfilt(sos, reference_design(vector, rate_hz), axis=0)[trim:-trim]
    y = signal.sosfiltfilt(sos, scalar)[trim:-trim]
    scale = np.linalg.norm(a, axis=0)
    u, s, vt = np.linalg.svd(a / scale, full_matrices=False)
    uy = u.T @ y
    n = len(y)
    best = None
    for lam in np.logspace(-14, 2, 321) * s[0] ** 2:
        shrink = s**2 / (s**2 + lam)
        residual = y - u @ (shrink * uy)
        gcv = n * residual @ residual / (n - shrink.sum()) ** 2
        if best is None or gcv < best[0]:
            best = (gcv, residual)
    return float(np.std(best[1]))


def band_passed_noise_std(noise, rate_hz=RATE_HZ, band=BAND_HZ) -> float:
    """What an exact compensation leaves: the noise, band-passed (zero phase). [nT]"""
    sos = signal.butter(4, band, btype="bandpass", fs=rate_hz, output="sos")
    return float(np.std(signal.sosfiltfilt(sos, noise)[20:-20]))


@pytest.mark.parametrize("terms", [18, 16])
def test_the_box_is_compensated_as_well_as_the_zero_phase_reference(box, terms):
    vector, scalar, platform, magnitude = box
    fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=terms)
    reference = zero_phase_ridge(vector, scalar)
    # the done-when criterion: within 5 % of the zero-phase ridge reference
    assert fit.compensated_std == pytest.approx(reference, rel=0.05)
    # and both at the noise: the platform's 4 nT of band-passed field are gone
    noise = band_passed_noise_std(scalar - magnitude - platform)
    assert fit.compensated_std < 1.5 * noise
    assert fit.uncompensated_std > 500 * noise
    assert fit.improvement_ratio == pytest.approx(fit.uncompensated_std / fit.compensated_std)


def test_the_compensated_scalar_is_the_earth_field_plus_noise(box):
    vector, scalar, platform, magnitude = box
    fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ)
    left = fit.compensate(vector, scalar) - magnitude
    # at every frequency, not only in the band: 0.01 nT of noise, 7.8 nT of platform field;
    # the few rows at the ends where the derivative is one-sided add a little
    assert np.std(left) < 0.015
    assert np.std(platform) > 500 * np.std(left)
    assert np.mean(fit.compensate(vector, scalar)) == pytest.approx(np.mean(scalar), abs=1e-9)


def test_18_terms_are_not_individually_meaningful_and_it_says_so(box):
    vector, scalar, _, _ = box
    fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ)
    assert not fit.coefficients_meaningful
    assert fit.condition_number > 1e3
    assert max(fit.variance_inflation) > 1e6  # cos^2 sum to 1: induced_zz follows the others
    assert "not individually meaningful" in fit.statement
    assert fit.names == nlpcal.platform.terms.term_names(18)
    document = fit.to_dict()
    assert document["coefficients_meaningful"] is False
    assert [c["name"] for c in document["coefficients"]] == fit.names


def test_well_conditioned_terms_are_called_meaningful(box):
    """A channel alone, independent of the attitude: its coefficient means what it says."""
    vector, scalar, _, magnitude = box
    rng = np.random.default_rng(2)
    current = np.convolve(rng.uniform(0, 40, scalar.size), np.ones(10) / 10, mode="same")  # [A]
    recorded = magnitude + 0.05 * current + 0.01 * rng.standard_normal(scalar.size)
    fit = nlpcal.fit_tolles_lawson(
        vector, recorded, rate_hz=RATE_HZ, terms=16, aux=current, aux_names=["current_A"]
    )
    assert fit.names[-1] == "current_A"
    assert fit.coefficient_units[-1] == "nT per unit of current_A"
    # the band-passed current varies by about 2 A against 0.004 nT of band-passed noise over
    # 11 700 rows: a standard error near 2e-5 nT/A, far inside 1 %
    assert fit.coefficients[-1] == pytest.approx(0.05, rel=0.01)
    assert fit.variance_inflation[-1] < 10


def test_one_pass_over_blocks_is_the_causal_filter_over_the_whole_record(box):
    """The carried state: the sums gathered in blocks of 997 rows (threads) equal the causal
    filter run over the whole record at once from the steady state, computed here."""
    vector, scalar, _, _ = box
    small = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=16, chunk_rows=997)
    whole = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=16, chunk_rows=10**6)
    # the same sums to rounding; GCV's minimum is flat in lambda, which rounding moves by a few
    # per cent, so the coefficients are compared through what they do: the compensation, to
    # 1 % of the 0.01 nT noise
    assert small.compensated_std == pytest.approx(whole.compensated_std, rel=1e-7)
    left = small.compensate(vector, scalar) - whole.compensate(vector, scalar)
    assert np.abs(left).max() < 1e-4
    # the whole record filtered at once, causally, twice the Butterworth (|H|^2 as filtfilt)
    once = signal.butter(4, BAND_HZ, btype="bandpass", fs=RATE_HZ, output="sos")
    sos = np.vstack([once, once])
    full = reference_design(vector, RATE_HZ)  # 16 terms: without induced zz (8), eddy z dz (17)
    columns = np.column_stack([full[:, [*range(8), *range(9, 17)]], scalar])
    zi = signal.sosfilt_zi(sos)[:, :, None] * columns[0][None, None, :]
    filtered = signal.sosfilt(sos, columns, axis=0, zi=zi)[0][whole.settling_rows :]
    x, y = filtered[:, :-1], filtered[:, -1]
    scale = np.linalg.norm(x, axis=0)
    r = (x / scale).T @ (x / scale)
    beta = np.linalg.solve(r + whole.ridge_parameter * np.eye(16), (x / scale).T @ y) / scale
    np.testing.assert_allclose(whole.coefficients, beta, rtol=1e-6)
    assert whole.compensated_std == pytest.approx(np.std(y - x @ beta), rel=1e-9)


def test_dask_arrays_give_the_fit_of_numpy(box):
    da = pytest.importorskip("dask.array")
    vector, scalar, _, _ = box
    in_memory = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ, terms=16)
    lazy = nlpcal.fit_tolles_lawson(
        da.from_array(vector, chunks=(1500, 3)),
        da.from_array(scalar, chunks=1500),
        rate_hz=RATE_HZ,
        terms=16,
    )
    assert lazy.compensated_std == pytest.approx(in_memory.compensated_std, rel=1e-7)
    left = lazy.compensate(vector, scalar) - in_memory.compensate(vector, scalar)
    assert np.abs(left).max() < 1e-4  # 1 % of the noise (see the test above)


def test_the_document_reads_back_and_refuses_what_it_never_writes(box, tmp_path):
    vector, scalar, _, _ = box
    fit = nlpcal.fit_tolles_lawson(vector[:4000], scalar[:4000], rate_hz=RATE_HZ, terms=16)
    path = tmp_path / "tl.json"
    fit.save(path)
    back = nlpcal.TollesLawsonFit.load(path)
    np.testing.assert_array_equal(back.coefficients, fit.coefficients)
    assert back.to_dict() == fit.to_dict()
    document = json.loads(path.read_text())
    for key, value in [
        ("terms", 17),
        ("band_hz", [0.1, 20.0]),  # beyond the rate's Nyquist frequency
        ("sample_rate_hz", -10),
        ("coefficients", document["coefficients"][:-1]),  # a term missing
        ("format_version", 3),
    ]:
        path.write_text(json.dumps({**document, key: value}))
        with pytest.raises(nlpcal.InputError):
            nlpcal.TollesLawsonFit.load(path)
    path.write_text(json.dumps(document).replace('"value": ', '"value": NaN, "x": ', 1))
    with pytest.raises(nlpcal.InputError):
        nlpcal.TollesLawsonFit.load(path)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"rate_hz": 1.0}, "--band"),  # 0.9 Hz is beyond 0.5 Hz, half the rate
        ({"band_hz": (0.9, 0.1)}, "--band"),
        ({"terms": 17}, "17"),
        ({"aux": np.full(12_000, 3.0), "aux_names": ["heater"]}, "heater"),  # never varies
    ],
)
def test_bad_arguments_are_refused_by_name(box, change, named):
    vector, scalar, _, _ = box
    arguments = {"rate_hz": RATE_HZ, **change}
    with pytest.raises(nlpcal.InputError, match=named):
        nlpcal.fit_tolles_lawson(vector, scalar, **arguments)


def test_bad_records_are_refused(box):
    vector, scalar, _, _ = box
    with pytest.raises(nlpcal.InputError, match="rows"):  # too short for the band-pass
        nlpcal.fit_tolles_lawson(vector[:300], scalar[:300], rate_hz=RATE_HZ)
    broken = scalar.copy()
    broken[500] = np.nan
    with pytest.raises(nlpcal.InputError, match="NaN"):
        nlpcal.fit_tolles_lawson(vector, broken, rate_hz=RATE_HZ)
    with pytest.raises(nlpcal.InputError, match="shape"):
        nlpcal.fit_tolles_lawson(vector[:, :2], scalar, rate_hz=RATE_HZ)
    with pytest.raises(nlpcal.InputError, match="nothing to compensate"):
        nlpcal.fit_tolles_lawson(vector, np.full(12_000, 5e4), rate_hz=RATE_HZ)


# --- the command line ---------------------------------------------------------------------------


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def write_box(path, box, rows=12_000, times=None):
    vector, scalar, _, _ = box
    times = np.arange(rows) / RATE_HZ if times is None else times
    frame = pd.DataFrame(
        {
            "t": times,
            "flux_x": vector[:rows, 0],
            "flux_y": vector[:rows, 1],
            "flux_z": vector[:rows, 2],
            "mag_1_nT": scalar[:rows],
            "note": "ok",
        }
    )
    frame.to_csv(path, index=False)
    return path


FLUX = ("--columns", "flux_x", "flux_y", "flux_z")


def test_fit_and_apply_on_the_command_line(box, tmp_path, capsys):
    log = write_box(tmp_path / "box.csv", box)
    tl = tmp_path / "tl.json"
    code, out, err = run(
        capsys, "platform", "fit", log, "--scalar-column", "mag_1_nT", *FLUX,
        "--time-column", "t", "--terms", "16", "-o", tl,
    )  # fmt: skip
    assert code == 0, err
    assert out == ""
    document = json.loads(tl.read_text())
    assert document["format"] == "nlpcal-platform"
    assert document["terms"] == 16 and len(document["coefficients"]) == 16
    assert document["sample_rate_hz"] == pytest.approx(RATE_HZ)
    assert document["band_hz"] == list(BAND_HZ)
    assert document["improvement_ratio"] > 100
    assert document["compensated_std"] < 0.01  # nT, band-passed
    assert "improvement ratio" in err
    out_csv = tmp_path / "out.csv"
    code, out, err = run(capsys, "platform", "apply", tl, log, "-o", out_csv)
    assert code == 0, err
    written = pd.read_csv(out_csv)
    original = pd.read_csv(log)
    assert list(written.columns) == [*original.columns, "mag_1_nT_compensated"]
    pd.testing.assert_frame_equal(written[original.columns], original)
    _, _, platform, magnitude = box
    left = written["mag_1_nT_compensated"] - magnitude
    assert np.std(left) < 0.015  # nT: the noise (0.01 nT) and the one-sided ends
    # to stdout, in the log's layout
    code, out, _ = run(capsys, "platform", "apply", tl, log)
    assert code == 0 and out.splitlines()[0].endswith(",mag_1_nT_compensated")


def test_the_cli_fit_is_the_library_fit(box, tmp_path, capsys):
    log = write_box(tmp_path / "box.csv", box)
    code, out, err = run(
        capsys, "platform", "fit", log, "--scalar-column", "4", "--columns", "1", "2", "3",
        "--rate", "10", "--band", "0.1", "0.9",
    )  # fmt: skip
    assert code == 0, err
    vector, scalar, _, _ = box
    fit = nlpcal.fit_tolles_lawson(vector, scalar, rate_hz=RATE_HZ)
    document = json.loads(out)
    assert document["compensated_std"] == pytest.approx(fit.compensated_std, rel=1e-6)


def test_an_auxiliary_channel_through_the_command_line(box, tmp_path, capsys):
    vector, scalar, _, magnitude = box
    rng = np.random.default_rng(4)
    current = np.convolve(rng.uniform(0, 40, 12_000), np.ones(10) / 10, mode="same")
    frame = pd.read_csv(write_box(tmp_path / "box.csv", box))
    frame["current_A"] = current
    frame["mag_1_nT"] = frame["mag_1_nT"] + 0.05 * current
    frame.to_csv(tmp_path / "box.csv", index=False)
    tl = tmp_path / "tl.json"
    code, _, err = run(
        capsys, "platform", "fit", tmp_path / "box.csv", "--scalar-column", "mag_1_nT", *FLUX,
        "--aux-columns", "current_A", "--rate", "10", "-o", tl,
    )  # fmt: skip
    assert code == 0, err
    document = json.loads(tl.read_text())
    assert document["aux_columns"] == ["current_A"]
    assert document["coefficients"][-1]["name"] == "current_A"
    assert document["coefficients"][-1]["value"] == pytest.approx(0.05, rel=0.01)
    code, _, err = run(
        capsys, "platform", "apply", tl, tmp_path / "box.csv", "-o", tmp_path / "o.csv"
    )
    assert code == 0, err
    left = pd.read_csv(tmp_path / "o.csv")["mag_1_nT_compensated"] - magnitude
    assert np.std(left) < 0.015


@pytest.mark.parametrize(
    ("argv", "what"),
    [
        (["--time-column", "t", "--rate", "10"], "not both"),
        ([], "--time-column"),  # no rate at all
        (["--rate", "10", "--band", "0.2", "0.1"], "--band"),
        (["--rate", "10", "--band", "0.1", "9"], "--band"),
        (["--rate", "0"], "--rate"),
        (["--rate", "10", "--aux-columns", "nope"], "nope"),
        (["--rate", "10", "--aux-columns", "note"], "note"),  # not numbers
        (["--rate", "10", "--aux-columns", "flux_x"], "flux_x"),  # a column in two roles
        (["--time-column", "note"], "note"),
    ],
)
def test_bad_input_exits_2_with_a_sentence_and_leaves_the_output(box, tmp_path, capsys, argv, what):
    log = write_box(tmp_path / "box.csv", box, rows=3000)
    out = tmp_path / "tl.json"
    out.write_text("keep")
    code, stdout, err = run(
        capsys, "platform", "fit", log, "--scalar-column", "mag_1_nT", *FLUX, *argv, "-o", out
    )
    assert code == 2, err
    assert what in err and "Traceback" not in err and "internal error" not in err
    assert len(err.strip().splitlines()) <= 2 and stdout == ""
    assert out.read_text() == "keep"


def test_irregular_sampling_is_refused(box, tmp_path, capsys):
    times = np.arange(3000) / RATE_HZ
    times[1500:] += 2.0  # a gap of 2 s
    log = write_box(tmp_path / "box.csv", box, rows=3000, times=times)
    code, _, err = run(
        capsys, "platform", "fit", log, "--scalar-column", "mag_1_nT", *FLUX, "--time-column", "t"
    )
    assert code == 2 and "not regularly sampled" in err


def test_iso_times_give_the_rate(box, tmp_path, capsys):
    times = pd.date_range("2026-11-24T08:00:00", periods=3000, freq="100ms")
    iso = times.strftime("%Y-%m-%dT%H:%M:%S.%f")
    log = write_box(tmp_path / "box.csv", box, rows=3000, times=iso)
    code, out, err = run(
        capsys, "platform", "fit", log, "--scalar-column", "mag_1_nT", *FLUX, "--time-column", "t"
    )
    assert code == 0, err
    assert json.loads(out)["sample_rate_hz"] == pytest.approx(RATE_HZ)


def test_apply_refuses_a_bad_fit_file_and_another_rate(box, tmp_path, capsys):
    log = write_box(tmp_path / "box.csv", box, rows=3000)
    tl = tmp_path / "tl.json"
    argv = ["platform", "fit", log, "--scalar-column", "mag_1_nT", *FLUX, "--time-column", "t"]
    assert run(capsys, *argv, "-o", tl)[0] == 0
    slow = write_box(tmp_path / "slow.csv", box, rows=3000, times=np.arange(3000) / 5.0)
    out = tmp_path / "out.csv"
    code, _, err = run(capsys, "platform", "apply", tl, slow, "-o", out)
    assert code == 2 and "5 Hz" in err and not out.exists()
    (tmp_path / "bad.json").write_text('{"format": "nlpcal-platform", "format_version": 2}')
    code, _, err = run(capsys, "platform", "apply", tmp_path / "bad.json", log, "-o", out)
    assert code == 2 and "missing" in err and not out.exists()
    code, _, err = run(capsys, "platform", "apply", log, log, "-o", out)  # a CSV as the fit
    assert code == 2 and not out.exists()


# --- fuzz: hostile arguments, tables and documents through the command line -----------------------


NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -1.0, 0.05, 0.1, 0.9, 4.99, 5.0, 1e-300, 1e300]),
)
COLUMNS = st.sampled_from(["t", "flux_x", "flux_y", "flux_z", "mag_1_nT", "note", "nope", "7"])


@pytest.fixture(scope="module")
def fuzz_log(box, tmp_path_factory):
    folder = tmp_path_factory.mktemp("platform_fuzz")
    log = write_box(folder / "box.csv", box, rows=1500)
    tl = folder / "tl.json"
    status, _, _ = run_checked(
        ["platform", "fit", log, "--scalar-column", "mag_1_nT", *FLUX, "--rate", "10", "-o", tl]
    )
    assert status == 0
    return log, tl


def checked_output(status, out: Path, before: str) -> None:
    """A failed run leaves the output as it was; a finished one writes finite numbers."""
    if status:
        assert out.read_text() == before
    elif out.suffix == ".json":
        no_nan(out.read_text())
    else:
        finite_csv(out)


@FUZZ
@given(
    band=st.lists(NUMBERS, min_size=2, max_size=2),
    rate=NUMBERS,
    scalar=COLUMNS,
    aux=st.lists(COLUMNS, max_size=2),
    terms=st.sampled_from(["18", "16", "17", "0", "x"]),
    time=st.booleans(),
)
def test_fuzz_fit_arguments(fuzz_log, tmp_path, band, rate, scalar, aux, terms, time):
    log, _ = fuzz_log
    out = tmp_path / "tl.json"
    out.write_text("before")
    argv = ["platform", "fit", log, "--scalar-column", scalar, *FLUX, "--terms", terms]
    argv += ["--band", *map(repr, band)] + (["--aux-columns", *aux] if aux else [])
    argv += ["--time-column", "t"] if time else ["--rate", repr(rate)]
    status, _, _ = run_checked([*argv, "-o", out])
    assert status in (0, 2)
    checked_output(status, out, "before")


@FUZZ
@given(
    cells=st.lists(st.lists(CELLS, min_size=5, max_size=5), min_size=0, max_size=30),
    rows=st.integers(min_value=0, max_value=1500),
)
def test_fuzz_fit_tables(fuzz_log, tmp_path, cells, rows):
    """Hostile cells written over rows of a good log."""
    log, _ = fuzz_log
    lines = log.read_text().splitlines()[: rows + 1]
    for k, row in enumerate(cells):
        if 1 + k < len(lines):
            lines[1 + k] = ",".join(str(c) for c in row) + ",ok"
    path = tmp_path / "hostile.csv"
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "tl.json"
    out.write_text("before")
    argv = ["platform", "fit", path, "--scalar-column", "mag_1_nT", *FLUX, "--time-column", "t"]
    status, _, _ = run_checked([*argv, "-o", out])
    assert status in (0, 2)
    checked_output(status, out, "before")


JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), NUMBERS, st.text(max_size=8)),
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=5), inner, max_size=3)
    ),
    max_leaves=6,
)


@FUZZ
@given(data=st.data())
def test_fuzz_apply_documents(fuzz_log, tmp_path, data):
    """A fit document with one key (or one coefficient's key) replaced by a random value."""
    log, tl = fuzz_log
    document = json.loads(tl.read_text())
    key = data.draw(st.sampled_from(sorted(document)))
    target = document
    if key == "coefficients" and data.draw(st.booleans()):
        target = document["coefficients"][data.draw(st.integers(0, 17))]
        key = data.draw(st.sampled_from(sorted(target)))
    target[key] = data.draw(JSON_VALUES)
    fit = tmp_path / "tl.json"
    fit.write_text(json.dumps(document))
    out = tmp_path / "out.csv"
    out.write_text("before")
    status, _, _ = run_checked(["platform", "apply", fit, log, "-o", out])
    assert status in (0, 2)
    checked_output(status, out, "before")
