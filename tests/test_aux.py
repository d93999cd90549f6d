"""Auxiliary channels: stray fields v_k c_k estimated with the nine parameters, applied, refused.

The logs come from `synthetic.motor_current_log`, Eq. 4 typed in again plus a stray field that
follows a motor current, not from nlpcal's model.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest
from test_formats import _parameters as parameter_values

import nlpcal
from nlpcal.calibration import CalibrationSettings, prepare
from nlpcal.calibration.channels import fit_channels, prepare_channels
from nlpcal.cli import main
from nlpcal.errors import InputError, QualityError
from nlpcal.models.zhou2010 import Zhou2010Parameters, correction_matrix
from nlpcal.nlp.blocks import OPTIONS
from nlpcal.schemas import validate
from synthetic import PAPER_FIELD, PAPER_TRUTH, make_log, motor_current_log, smooth_motor_log

PER_AMP = np.array([120.0, -80.0, 300.0])  # [nT/A]
#: A covering standard error: the truth within this many of them. A 4-sigma band fails a correct
#: estimate once in 16 000 per coordinate; a wrong one (bias, an SE too small by 2x) fails it.
COVER = 4.0
N = 20_000


@pytest.fixture(scope="module")
def motor():
    samples, current = motor_current_log(n=N, noise=5.0)
    result = nlpcal.calibrate(
        samples,
        reference_field=PAPER_FIELD,
        method="joint",
        aux_columns={"current": current},
        aux_kind="current",
    )
    return samples, current, result


def test_the_per_amp_field_is_recovered_within_one_percent_with_covering_errors(motor):
    _, _, result = motor
    (channel,) = result.aux
    assert channel.name == "current" and channel.kind == "current"
    assert np.all(np.abs(channel.coefficients / PER_AMP - 1) < 0.01)
    assert np.all(np.abs(channel.coefficients - PER_AMP) < COVER * channel.standard_errors)
    assert result.identifiability["aux"]["not_identifiable"] == []


def test_the_nine_stay_at_their_accuracy_without_the_channel(motor):
    samples, current, result = motor
    plain = nlpcal.calibrate(
        samples - current[:, None] * PER_AMP, reference_field=PAPER_FIELD, method="joint"
    )
    for name, truth in PAPER_TRUTH.items():
        se = result.standard_errors[name]
        assert abs(result.parameters[name] - truth) < COVER * se, name
        if not name.startswith("z_"):  # scales and angles: the current leaves them as they were
            assert se < 1.1 * plain.standard_errors[name], name
    # the offsets share the current's mean (20 A) with v: their errors widen, and say so
    inflation = result.identifiability["aux"]["standard_error_inflation"]
    assert all(inflation[f"z_{a}"] > 1.2 for a in "xyz")


def test_the_result_applies_and_round_trips(motor, tmp_path):
    samples, current, result = motor
    corrected = result.apply(samples, aux={"current": current})
    assert np.std(np.linalg.norm(corrected, axis=1)) < 6.0  # 5 nT of noise per axis
    document = result.to_dict()
    validate(document)
    assert document["aux"]["current"]["unit"] == "nT per A"
    again = nlpcal.CalibrationResult.from_dict(json.loads(json.dumps(document)))
    np.testing.assert_array_equal(again.apply(samples, aux={"current": current}), corrected)
    with pytest.raises(InputError, match="current"):
        result.apply(samples)


def test_a_data_frame_and_a_dask_frame_give_the_same_fit(motor):
    samples, current, result = motor
    frame = pd.DataFrame({"bx": samples[:, 0], "by": samples[:, 1], "bz": samples[:, 2]})
    frame["current"] = current
    dd = pytest.importorskip("dask.dataframe")
    lazy = dd.from_pandas(frame, npartitions=4)
    for source in (frame, lazy):
        again = nlpcal.calibrate(
            source,
            reference_field=PAPER_FIELD,
            method="joint",
            aux_columns=["current"],
            aux_kind="current",
        )
        (channel,) = again.aux
        # the same moments in another order of additions: 0.01 standard errors, the solver's
        # own resolution
        assert np.all(
            np.abs(channel.coefficients - result.aux[0].coefficients)
            < 0.01 * result.aux[0].standard_errors
        )


@pytest.mark.parametrize("reference", ["none", "series"])
def test_two_channels_under_every_reference_kind(motor, reference):
    samples, current, _ = motor
    throttle = np.random.default_rng(7).uniform(0.0, 1.0, N)
    per_throttle = np.array([50.0, 20.0, -40.0])  # [nT per full throttle]
    field = None if reference == "none" else np.full(N, PAPER_FIELD)
    result = nlpcal.calibrate(
        samples + np.outer(throttle, per_throttle),
        reference_field=field,
        method="joint",
        aux_columns={"current": current, "thr": throttle},
        aux_kind=["current", "throttle"],
    )
    amps, thr = result.aux
    assert (amps.kind, thr.kind, thr.unit(result.unit)) == (
        "current",
        "throttle",
        "nT per throttle fraction",
    )
    for channel, truth in ((amps, PER_AMP), (thr, per_throttle)):
        assert np.all(np.abs(channel.coefficients - truth) < COVER * channel.standard_errors)


def test_a_log_read_with_low_memory_stays_mapped_and_fits_alike(motor, tmp_path):
    samples, current, result = motor
    path = tmp_path / "log.csv"
    frame = pd.DataFrame({"bx": samples[:, 0], "by": samples[:, 1], "bz": samples[:, 2]})
    frame.assign(current=current).to_csv(path, index=False)
    fits = []
    for low_memory in (True, False):
        log = nlpcal.read_log(
            path, extra_columns=["current"], low_memory=low_memory, reference_field=PAPER_FIELD
        )
        fits.append(
            nlpcal.calibration.calibrate_log(
                log, method="joint", aux_columns=["current"], aux_kind="current"
            )
        )
        settings = CalibrationSettings.of(
            reference_field=PAPER_FIELD, unit="nT", aux_columns={"current": log.values("current")}
        )
        data = prepare(log.samples, settings)
        _, channels = prepare_channels(log.samples, settings)
        fit = fit_channels(data, channels, "full", OPTIONS)
        # the samples without the stray field: a memory map of their own for a mapped log
        assert isinstance(fit.compensated(data.samples), np.memmap) == low_memory
    mapped, whole = fits
    # the same sums in another order of additions: within 0.01 standard errors
    assert np.all(
        np.abs(mapped.aux[0].coefficients - whole.aux[0].coefficients)
        < 0.01 * whole.aux[0].standard_errors
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_a_smooth_flight_gets_standard_errors_that_follow_its_dependence(seed):
    samples, current = smooth_motor_log(seed=seed)
    result = nlpcal.calibrate(
        samples,
        reference_field=PAPER_FIELD,
        method="joint",
        aux_columns={"current": current},
        require_identifiable=False,  # a smooth path leaves some of the nine poorly determined
    )
    assert result.identifiability["aux"]["standard_errors"]["method"] == "moving-block-jackknife"
    (channel,) = result.aux
    # the sandwich of independent samples states errors 10-30 times too small here
    assert np.all(np.abs(channel.coefficients - PER_AMP) < COVER * channel.standard_errors)


def test_a_channel_that_never_varies_is_refused_by_name():
    samples, _ = make_log(n=2000)
    with pytest.raises(InputError, match="heater"):
        nlpcal.calibrate(samples, aux_columns={"heater": np.full(2000, 3.0)})


def test_a_channel_that_follows_the_attitude_is_named():
    samples, field = make_log(n=4000, seed=5)
    follows = field[:, 0] / PAPER_FIELD * 10.0 + 20.0  # a "current" that is the x direction
    with pytest.raises(QualityError) as failure:
        nlpcal.calibrate(
            samples + follows[:, None] * PER_AMP,
            reference_field=PAPER_FIELD,
            method="joint",
            aux_columns={"pump": follows},
        )
    assert failure.value.status == "Not_Identifiable"
    assert "pump" in str(failure.value)
    written = nlpcal.calibrate(
        samples + follows[:, None] * PER_AMP,
        reference_field=PAPER_FIELD,
        method="joint",
        aux_columns={"pump": follows},
        require_identifiable=False,  # --allow-unidentifiable: written, and failed
    )
    assert written.identifiability["aux"]["not_identifiable"] == ["pump"]
    assert written.verdict.status == "failed"


@pytest.mark.parametrize(
    "options",
    [
        {"aux_columns": "current"},
        {"aux_columns": []},
        {"aux_columns": {"current": np.ones(3)}},
        {"aux_columns": {"current": None}},
        {"aux_columns": ["current"]},  # an array has no columns
        {"aux_columns": {"c": np.linspace(0, 1, 2000)}, "aux_kind": "voltage"},
        {"aux_columns": {"c": np.linspace(0, 1, 2000)}, "aux_kind": ["current", "other"]},
        {"aux_columns": {"c": np.r_[np.nan, np.linspace(0, 1, 1999)]}},
        {"aux_columns": {"c": np.linspace(0, 1, 2000)}, "loss": "huber"},
        {"aux_columns": {"c": np.linspace(0, 1, 2000)}, "model": "auto"},
        {
            "aux_columns": {"c": np.linspace(0, 1, 2000)},
            "lag": "auto",
            "reference_field": np.full(2000, PAPER_FIELD),
            "times": np.arange(2000.0),
        },
    ],
)
def test_bad_channels_are_input_errors(options):
    samples, _ = make_log(n=2000)
    with pytest.raises(InputError):
        nlpcal.calibrate(samples, **options)


def _cli(*argv) -> int:
    return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("aux")
    samples, current = motor_current_log(n=4000, noise=5.0, seed=3)
    frame = pd.DataFrame({"bx": samples[:, 0], "by": samples[:, 1], "bz": samples[:, 2]})
    frame.assign(current=current).to_csv(folder / "log.csv", index=False)
    frame.assign(amps=current).to_csv(folder / "renamed.csv", index=False)
    params = folder / "params.json"
    assert (
        _cli(
            "calibrate",
            folder / "log.csv",
            "--aux-columns",
            "current",
            "--aux-kind",
            "current",
            "--reference-field",
            PAPER_FIELD,
            "-o",
            params,
        )
        == 0
    )
    return folder, samples, current, params


def test_streaming_apply_subtracts_the_stray_field_as_the_library_does(logs):
    folder, samples, current, params = logs
    out = folder / "out.csv"
    assert (
        _cli("apply", params, folder / "renamed.csv", "--aux-columns", "amps=current", "-o", out)
        == 0
    )
    written = pd.read_csv(out)[["bx", "by", "bz"]].to_numpy()
    expected = nlpcal.load_parameters(params).apply(samples, aux={"current": current})
    # the written digits: one significant digit more than the log's (every digit of a float)
    np.testing.assert_allclose(written, expected, rtol=1e-12, atol=1e-9)


def test_stats_subtracts_the_stray_field(logs, capsys):
    folder, _, _, params = logs
    argv = ["stats", folder / "renamed.csv", "--params", params, "--aux-columns", "amps=current"]
    assert _cli(*argv, "--json") == 0
    rows = {row["label"]: row for row in json.loads(capsys.readouterr().out)["rows"]}
    assert rows["measured"]["std"] > 1000.0 and rows["corrected"]["std"] < 6.0  # 5 nT noise


@pytest.mark.parametrize(
    "argv",
    [
        ("calibrate", "{log}", "--aux-columns", "nope"),
        ("calibrate", "{log}", "--aux-columns", "current", "current"),
        ("calibrate", "{log}", "--aux-columns", "current", "--aux-kind", "volts"),
        ("calibrate", "{log}", "--aux-kind", "current"),
        ("calibrate", "{log}", "--aux-columns", "current", "--aux-kind", "current", "other"),
        ("calibrate", "{log}", "--aux-columns", "bx"),
        ("calibrate", "{log}", "--aux-columns", "current", "--loss", "huber"),
        ("calibrate", "{log}", "--aux-columns", "current", "--model", "auto"),
        ("calibrate", "{log}", "--aux-columns", "current", "--temperature-column", "bx"),
        ("calibrate", "{log}", "--aux-columns"),
        ("apply", "{params}", "{renamed}"),
        ("apply", "{params}", "{renamed}", "--aux-columns", "amps=nope"),
        ("apply", "{params}", "{renamed}", "--aux-columns", "=current"),
        ("apply", "{params}", "{renamed}", "--aux-columns", "nope=current"),
        ("apply", "{params}", "{renamed}", "--aux-columns", "amps=current", "bx=current"),
    ],
)
def test_bad_aux_flags_exit_2_with_one_sentence(logs, argv, capsys):
    folder, _, _, params = logs
    names = {"log": folder / "log.csv", "renamed": folder / "renamed.csv", "params": params}
    argv = [a.format(**names) for a in argv]
    status = _cli(*argv, "-o", folder / "never.json")
    err = capsys.readouterr().err
    assert status == 2, err
    assert "Traceback" not in err and "internal error" not in err
    assert not (folder / "never.json").exists()


def test_a_parameters_file_with_a_bad_aux_block_is_refused(logs, tmp_path):
    _, samples, current, params = logs
    document = json.loads(params.read_text())
    for bad in (
        {"current": {"coefficients": [1, 2], "unit": "nT per A", "kind": "current"}},
        {"current": {"coefficients": [1, 2, 3], "unit": "nT per V", "kind": "current"}},
        {"current": {"coefficients": [1, 2, 3], "unit": "nT per A", "kind": "voltage"}},
        {"current": {"coefficients": [1, "x", 3], "unit": "nT per A", "kind": "current"}},
        {"current": [1, 2, 3]},
    ):
        path = tmp_path / "bad.json"
        path.write_text(json.dumps({**document, "aux": bad}))
        with pytest.raises(InputError):
            nlpcal.load_parameters(path)


# --- exports -------------------------------------------------------------------------------------
#
# ArduPilot 4.x, libraries/AP_Compass/AP_Compass_Backend.cpp, AP_Compass_Backend::correct_field
# (the 4.x source, read at a revision where _state is indexed by Compass::StateIndex): the offsets
# are added, the scale and the symmetric matrix applied, and then the motor offset is added,
#
#     mag = D (k (m + OFS));  motor_offset = MOT * c;  mag += motor_offset      [mGauss]
#
# c the battery current [A] (COMPASS_MOTCT 2, battery.current_amps) or the throttle 0..1
# (COMPASS_MOTCT 1, Compass::set_throttle). PX4, src/lib/sensor_calibration/Magnetometer.hpp,
# Correct: m' = S ((m + p COMP) - OFF) in gauss, p the throttle or the current in kA
# (VehicleMagnetometer: bat_stat.current_a * 0.001f). The autopilots hold the symmetric factor P
# of A = R P and give R^T B1; R comes from scipy's polar decomposition.

#: The exports must reproduce `apply` to this: a double-precision budget on a 5e4 nT field. [nT]
APPLY_NT = 1e-6


def _symmetric(values: dict, diagonal: list, off: list) -> np.ndarray:
    x, y, z = (values[k] for k in diagonal)
    a, b, c = (values[k] for k in off)
    return np.array([[x, a, b], [a, y, c], [b, c, z]])


def _rotation(result) -> np.ndarray:
    scipy_linalg = pytest.importorskip("scipy.linalg")
    return scipy_linalg.polar(correction_matrix(result.model))[0]


@pytest.mark.parametrize("instance", [1, 3])
def test_the_ardupilot_export_applied_as_ardupilot_reproduces_apply(motor, instance):
    samples, current, result = motor
    p = parameter_values(nlpcal.export(result, "ardupilot", instance=instance).text)
    n = "" if instance == 1 else str(instance)
    assert p["COMPASS_MOTCT"] == 2  # current
    ofs = np.array([p[f"COMPASS_OFS{n}_{a}"] for a in "XYZ"])
    mot = np.array([p[f"COMPASS_MOT{n}_{a}"] for a in "XYZ"])
    d = _symmetric(
        p, [f"COMPASS_DIA{n}_{a}" for a in "XYZ"], [f"COMPASS_ODI{n}_{a}" for a in "XYZ"]
    )
    k = p[f"COMPASS_SCALE{n}"]
    m = samples / 100.0  # nT -> mGauss
    ardupilot = ((k * (m + ofs)) @ d.T + np.outer(current, mot)) * 100.0  # correct_field, nT
    b1 = result.apply(samples, aux={"current": current})
    assert np.abs(ardupilot - b1 @ _rotation(result)).max() < APPLY_NT  # R^T B1


def test_the_px4_export_applied_as_px4_reproduces_apply(motor):
    samples, current, result = motor
    p = parameter_values(nlpcal.export(result, "px4", instance=1).text)
    assert p["CAL_MAG_COMP_TYP"] == 2
    off = np.array([p[f"CAL_MAG1_{a}OFF"] for a in "XYZ"])
    comp = np.array([p[f"CAL_MAG1_{a}COMP"] for a in "XYZ"])  # [G/kA]
    s = _symmetric(p, [f"CAL_MAG1_{a}SCALE" for a in "XYZ"], [f"CAL_MAG1_{a}ODIAG" for a in "XYZ"])
    power = current * 0.001  # [kA]
    px4 = ((samples / 1e5 + np.outer(power, comp)) - off) @ s.T * 1e5  # Correct, in nT
    b1 = result.apply(samples, aux={"current": current})
    assert np.abs(px4 - b1 @ _rotation(result)).max() < APPLY_NT


def _with_channels(result, *channels):
    return dataclasses.replace(result, aux=list(channels))


def test_a_throttle_channel_exports_as_throttle_compensation(motor):
    samples, current, result = motor
    (channel,) = result.aux
    throttle = dataclasses.replace(channel, name="thr", kind="throttle")
    fraction = current / 40.0
    scaled = dataclasses.replace(throttle, coefficients=channel.coefficients * 40.0)
    as_throttle = _with_channels(result, scaled)
    ap = parameter_values(nlpcal.export(as_throttle, "ardupilot").text)
    px = parameter_values(nlpcal.export(as_throttle, "px4").text)
    assert ap["COMPASS_MOTCT"] == 1 and px["CAL_MAG_COMP_TYP"] == 1
    b1 = as_throttle.apply(samples, aux={"thr": fraction}) @ _rotation(result)
    s = _symmetric(px, [f"CAL_MAG0_{a}SCALE" for a in "XYZ"], [f"CAL_MAG0_{a}ODIAG" for a in "XYZ"])
    comp = np.array([px[f"CAL_MAG0_{a}COMP"] for a in "XYZ"])  # [G per full throttle]
    off = np.array([px[f"CAL_MAG0_{a}OFF"] for a in "XYZ"])
    px4 = ((samples / 1e5 + np.outer(fraction, comp)) - off) @ s.T * 1e5
    assert np.abs(px4 - b1).max() < APPLY_NT


def test_exports_refuse_channels_they_cannot_hold(motor):
    _, _, result = motor
    (channel,) = result.aux
    other = _with_channels(result, dataclasses.replace(channel, name="heater", kind="other"))
    two = _with_channels(result, channel, dataclasses.replace(channel, name="second"))
    for fmt in ("ardupilot", "px4"):
        with pytest.raises(InputError, match="heater"):
            nlpcal.export(other, fmt)
        with pytest.raises(InputError, match="second"):
            nlpcal.export(two, fmt)
    for fmt in ("matrix", "matlab", "c-header"):
        with pytest.raises(InputError, match="current"):
            nlpcal.export(result, fmt)


@pytest.mark.parametrize(("fmt", "suffix"), [("ardupilot", "param"), ("px4", "params")])
def test_an_export_imports_back_with_its_channel(motor, tmp_path, fmt, suffix):
    _, _, result = motor
    path = tmp_path / f"out.{suffix}"
    path.write_text(nlpcal.export(result, fmt).text)
    back, _ = nlpcal.formats.import_file(path, fmt)
    (channel,) = back.aux
    assert channel.kind == "current" and channel.name == "current"
    # through the file's shortest round-trip digits: the coefficients to rounding
    np.testing.assert_allclose(channel.coefficients, result.aux[0].coefficients, rtol=1e-9)


def test_the_cli_export_of_an_other_channel_is_exit_2(logs, tmp_path, capsys):
    _, _, _, params = logs
    document = json.loads(params.read_text())
    document["aux"]["current"]["kind"] = "other"
    document["aux"]["current"]["unit"] = "nT per channel unit"
    path = tmp_path / "other.json"
    path.write_text(json.dumps(document))
    assert _cli("export", path, "--format", "ardupilot", "-o", tmp_path / "x.param") == 2
    assert "other" in capsys.readouterr().err
    assert not (tmp_path / "x.param").exists()


# --- fuzz: random values of the new flags -------------------------------------------------------

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

TOKENS = st.one_of(
    st.sampled_from(["current", "amps", "bx", "=", "current=", "=current", "a=b=c", "", " "]),
    st.sampled_from(["current", "throttle", "other", "CURRENT", "-1", "nan", "inf", "--"]),
    st.text(alphabet="abc=,-_ 0\u00e9", max_size=8),
)


def _contract(argv, capsys, never):
    status = _cli(*argv)
    err = capsys.readouterr().err
    assert status in (0, 1, 2), (argv, err)
    assert "Traceback" not in err and "internal error" not in err, (argv, err)
    if status:
        assert any(line.startswith("nlpcal") for line in err.splitlines()), (argv, err)
        assert not never.exists(), argv


@settings(
    max_examples=25,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(columns=st.lists(TOKENS, max_size=3), kinds=st.lists(TOKENS, max_size=3))
def test_fuzzed_aux_flags_never_crash(logs, capsys, columns, kinds):
    folder, _, _, params = logs
    never = folder / "fuzz-never.json"
    argv = ["calibrate", folder / "log.csv", "--reference-field", PAPER_FIELD]
    argv += ["--aux-columns", *columns] if columns else []
    argv += ["--aux-kind", *kinds] if kinds else []
    _contract([*argv, "-o", never], capsys, never)
    never.unlink(missing_ok=True)
    out = folder / "fuzz-never.csv"
    mapping = ["--aux-columns", *columns] if columns else []
    _contract(["apply", params, folder / "renamed.csv", *mapping, "-o", out], capsys, out)
    out.unlink(missing_ok=True)


@pytest.mark.parametrize("reference", ["none", "constant", "series"])
def test_the_moment_objective_matches_the_per_sample_one(reference):
    from nlpcal.auxiliary.moments import accumulate_channels
    from nlpcal.moments import sphere_frame
    from nlpcal.nlp.channels import channel_derivatives, channel_parameters
    from nlpcal.statistics import correction

    samples, current = motor_current_log(n=3000, seed=4)
    theta = Zhou2010Parameters.from_dict(PAPER_TRUTH).theta + 1e-4  # near, not at, the truth
    v = PER_AMP + 0.5  # [nT/A]
    field = {"none": None, "constant": PAPER_FIELD, "series": np.full(3000, PAPER_FIELD)}
    ref = field[reference]
    frame = sphere_frame(samples)
    length = frame.radius if reference == "none" else PAPER_FIELD
    moments = accumulate_channels(samples, current[:, None], ref, frame, length, reference)
    p = channel_parameters(moments, theta, v, 1.0)
    f = channel_derivatives(reference, 1)(np.zeros(9 + 3), p)[0]
    offset, matrix = correction(theta)
    magnitude = np.linalg.norm((samples - np.outer(current, v) - offset) @ matrix.T, axis=1)
    direct = np.var(magnitude) if reference == "none" else np.mean((magnitude - PAPER_FIELD) ** 2)
    # the series in u is cut after u^4: a relative error of the order of max|u|^3 (~1e-9 here)
    assert f == pytest.approx(direct, rel=1e-6)
