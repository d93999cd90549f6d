"""Logs in the formats people record in: MotionCal Raw: lines, phyphox CSV, ROS CSV exports,
MATLAB .mat (v5, v7.3) and ArduPilot DataFlash .bin, each written here to its format's
specification and calibrated end to end through the command line with no flags (but --instance
where a log has several compasses); the parameters recovered are checked against the truth of
the independent forward model in synthetic.py. Every suggestion the reader prints is followed."""

from __future__ import annotations

import json
import re
import struct
import sys

import numpy as np
import pandas as pd
import pytest

from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.io import read_log
from synthetic import PAPER_TRUTH, make_log

#: The paper's truth with scale errors that sum to zero, the gauge a fit without a reference
#: field fixes, so that every parameter is compared with its true value.
TRUTH = {**PAPER_TRUTH, "s_z": -(PAPER_TRUTH["s_x"] + PAPER_TRUTH["s_y"])}
#: A recovered parameter lies within this many of its standard errors of the truth (the noise is
#: fixed by the seed; five standard errors leave a margin for any BLAS kernel's rounding). [1]
WITHIN_SE = 5.0
#: nT per count of MotionCal (0.1 uT) and per milligauss of a DataFlash MAG message.
NT_PER_COUNT = 100.0


def field_nt(n=2000, noise=20.0, seed=5):
    """Synthetic sensor output [nT] and the time of each sample [s]."""
    samples, _ = make_log(n=n, noise=noise, seed=seed, truth=TRUTH)
    return samples, np.arange(n) * 0.01


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def calibrated(capsys, tmp_path, path, *flags) -> dict:
    """`nlpcal calibrate PATH -o out.json` (exit 0), the result document."""
    output = tmp_path / "out.json"
    code, out, err = run(capsys, "calibrate", path, "-o", output, *flags)
    assert code == 0, err
    return json.loads(output.read_text())


def assert_recovers(document: dict) -> None:
    """Every parameter within WITHIN_SE standard errors of TRUTH, in nT and degrees."""
    assert document["unit"] == "nT"
    for name, value in TRUTH.items():
        gap = abs(document["parameters"][name] - value) / document["standard_errors"][name]
        assert gap < WITHIN_SE, (name, document["parameters"][name], value)


# --- MotionCal ----------------------------------------------------------------------------------


def motioncal_text(samples_nt, seed=1) -> str:
    """What a MotionCal sketch prints: Raw: lines of nine int16 counts (the field in 0.1 uT),
    with Uni: and Cal1:/Cal2: lines between them and a line cut by the start of the capture."""
    rng = np.random.default_rng(seed)
    counts = np.rint(samples_nt / NT_PER_COUNT).astype(int)
    lines = ["w:12,-3,8190,0,1,-2,3,4,5"]  # the capture started mid-line
    for k, (mx, my, mz) in enumerate(counts):
        acc = rng.integers(-8192, 8192, 3)
        gyro = rng.integers(-20, 20, 3)
        lines.append("Raw:" + ",".join(str(v) for v in [*acc, *gyro, mx, my, mz]))
        if k % 100 == 0:
            lines.append("Uni:0.01,-0.02,0.99,0.0012,0.0000,-0.0011,12.30,-4.50,40.10")
    lines.insert(50, "Cal1:0.000,0.000,0.000,0.000,0.000,0.000,0.000,0.000,0.000,50.000")
    lines.insert(51, "Cal2:1.000,0.000,0.000,0.000,1.000,0.000,0.000,0.000,1.000")
    return "\r\n".join(lines) + "\r\n"


def test_a_motioncal_capture_calibrates_with_no_flags(tmp_path, capsys):
    samples, _ = field_nt()
    path = tmp_path / "capture.txt"
    path.write_text(motioncal_text(samples))
    document = calibrated(capsys, tmp_path, path)
    assert document["input"]["columns"] == ["mx", "my", "mz"]
    assert document["input"]["log_unit"] == "mG" and document["input"]["unit_source"] == "format"
    assert_recovers(document)
    log = read_log(path)
    assert log.n == len(samples)  # the cut line, Uni: and Cal lines left out
    np.testing.assert_array_equal(log.samples, np.rint(samples / 100.0) * 100.0)


def test_malformed_raw_lines_are_left_out_and_counted(tmp_path):
    samples, _ = field_nt(n=50)
    path = tmp_path / "capture.txt"
    path.write_text(motioncal_text(samples) + "Raw:1,2,3\nRaw:1,2,3,4,5,6,7,8,99999\nRaw:1,2\n")
    log = read_log(path)
    assert log.n == 50 and any("3 incomplete or malformed" in note for note in log.notes)


def test_a_capture_without_a_complete_raw_line_exits_2(tmp_path, capsys):
    path = tmp_path / "capture.txt"
    path.write_text("Uni:1,2,3\nRaw:1,2,3\n")
    code, out, err = run(capsys, "calibrate", path, "-o", tmp_path / "p.json")
    assert code == 2 and "Raw:" in err and "Traceback" not in err
    assert not (tmp_path / "p.json").exists()


def test_motioncal_from_stdin(tmp_path, capsys, monkeypatch):
    import io

    samples, _ = field_nt(n=300)
    stream = io.TextIOWrapper(io.BytesIO(motioncal_text(samples).encode()))
    monkeypatch.setattr(sys, "stdin", stream)
    assert read_log("-").n == 300


def test_the_suggested_positions_of_a_headerless_log_are_its_own_and_work(tmp_path, capsys):
    """A log whose first column is text: the suggestion names the last three columns by their
    own positions, and following it calibrates the right columns."""
    samples, _ = field_nt()
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 100.0, (len(samples), 5))
    rows = [
        ",".join(["tag", *(f"{v:.3f}" for v in [*other, *field])])
        for other, field in zip(noise, samples)
    ]
    path = tmp_path / "nine.csv"
    path.write_text("\n".join(rows) + "\n")
    code, out, err = run(capsys, "calibrate", path, "-o", tmp_path / "p.json")
    assert code == 2
    suggestion = err.split("for example ")[1].split()
    assert suggestion == ["--columns", "6", "7", "8"]
    assert_recovers(calibrated(capsys, tmp_path, path, *suggestion))


# --- phyphox ------------------------------------------------------------------------------------

PHYPHOX_HEADER = ["Time (s)", "Magnetic field x (µT)", "Magnetic field y (µT)"]
PHYPHOX_HEADER += ["Magnetic field z (µT)", "Absolute field (µT)"]


def phyphox_text(samples_nt, times, delimiter=",", decimal=".") -> str:
    """phyphox's "Raw data" export of its Magnetometer experiment: quoted names, values in E
    notation with ten significant digits; "CSV (Semicolon, decimal comma)" and "CSV
    (Tabulator, ...)" differ only in the delimiter and decimal mark."""
    ut = samples_nt / 1000.0
    values = np.column_stack([times, ut, np.linalg.norm(ut, axis=1)])
    lines = [delimiter.join(f'"{name}"' for name in PHYPHOX_HEADER)]
    for row in values:
        cells = [f"{v:.9E}".replace("E+0", "E").replace("E-0", "E-") for v in row]
        lines.append(delimiter.join(c.replace(".", decimal) for c in cells))
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("delimiter, decimal", [(",", "."), (";", ","), ("\t", "."), ("\t", ",")])
def test_a_phyphox_export_calibrates_with_no_flags(tmp_path, capsys, delimiter, decimal):
    samples, times = field_nt()
    path = tmp_path / "Raw Data.csv"
    path.write_text(phyphox_text(samples, times, delimiter, decimal), encoding="utf-8")
    document = calibrated(capsys, tmp_path, path)
    assert document["input"]["columns"] == PHYPHOX_HEADER[1:4]
    assert document["input"]["log_unit"] == "uT" and document["input"]["unit_source"] == "names"
    assert_recovers(document)


# --- ROS CSV exports ----------------------------------------------------------------------------


def ros1_text(samples_nt, times) -> str:
    """`rostopic echo -p /imu/mag` (sensor_msgs/MagneticField): the field in tesla."""
    header = ["%time", "field.header.seq", "field.header.stamp", "field.header.frame_id"]
    header += [f"field.magnetic_field.{a}" for a in "xyz"]
    header += [f"field.magnetic_field_covariance{k}" for k in range(9)]
    lines = [",".join(header)]
    for k, (row, t) in enumerate(zip(samples_nt * 1e-9, times)):
        stamp = int(1.7e18 + t * 1e9)
        cells = [str(stamp + 1000), str(k), str(stamp), "imu_link"]
        cells += [repr(float(v)) for v in row] + ["0.0"] * 9
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def ros2_text(samples_nt, times) -> str:
    """A ROS 2 bag exported to CSV: the message's own field names, in tesla."""
    header = ["header.stamp.sec", "header.stamp.nanosec", "header.frame_id"]
    header += [f"magnetic_field.{a}" for a in "xyz"]
    lines = [",".join(header)]
    for row, t in zip(samples_nt * 1e-9, times):
        cells = [str(int(t)), str(int((t % 1) * 1e9)), "mag"] + [repr(float(v)) for v in row]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("writer", [ros1_text, ros2_text])
def test_a_ros_csv_export_calibrates_with_no_flags(tmp_path, capsys, writer):
    samples, times = field_nt()
    path = tmp_path / "mag.csv"
    path.write_text(writer(samples, times))
    document = calibrated(capsys, tmp_path, path)
    assert document["input"]["log_unit"] == "T" and document["input"]["unit_source"] == "format"
    assert_recovers(document)
    streamed = calibrated(capsys, tmp_path, path, "--low-memory")
    assert streamed["input"]["log_unit"] == "T"


def test_ros_names_fix_tesla_over_the_fallback_but_not_over_unit(tmp_path):
    samples, times = field_nt(n=200)
    path = tmp_path / "mag.csv"
    path.write_text(ros1_text(samples, times))
    assert read_log(path, unit="T").unit_source == "option"
    assert read_log(path).unit_source == "format"


# --- MATLAB .mat --------------------------------------------------------------------------------


def write_v5(path, variables):
    scipy_io = pytest.importorskip("scipy.io")
    scipy_io.savemat(path, variables)


def write_v73(path, variables):
    """A MATLAB v7.3 file: a 512-byte text header, then HDF5 with every array stored
    transposed (MATLAB is column-major) and its MATLAB_class; structs are groups."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "w", userblock_size=512) as handle:
        _write_group(handle, variables)
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Nov 23 10:00:00 2026 HDF5"
    with open(path, "r+b") as handle:
        handle.write(header.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM")


def _write_group(group, variables):
    for name, value in variables.items():
        if isinstance(value, dict):
            child = group.create_group(name)
            child.attrs["MATLAB_class"] = np.bytes_("struct")
            _write_group(child, value)
        else:
            array = np.atleast_2d(np.asarray(value, dtype=float))
            dataset = group.create_dataset(name, data=array.T)
            dataset.attrs["MATLAB_class"] = np.bytes_("double")


@pytest.mark.parametrize("writer", [write_v5, write_v73])
def test_a_mat_file_calibrates_with_no_flags(tmp_path, capsys, writer):
    samples, times = field_nt()
    path = tmp_path / "flight.mat"
    rng = np.random.default_rng(2)
    writer(
        path,
        {
            "time_s": times,
            "acc": rng.normal(0, 1, (len(times), 3)),
            "gyro": rng.normal(0, 1, (3, len(times))),
            "mag_nT": samples.T,  # 3 x N, as MATLAB users often keep it
            "n": 5.0,
        },
    )
    document = calibrated(capsys, tmp_path, path)
    assert document["input"]["columns"] == ["mag_x_nT", "mag_y_nT", "mag_z_nT"]
    assert document["input"]["unit_source"] == "names"
    assert_recovers(document)
    assert "time_s" in read_log(path).frame.columns


@pytest.mark.parametrize("writer", [write_v5, write_v73])
def test_a_mat_struct_with_named_axes_is_found(tmp_path, writer):
    samples, times = field_nt(n=100)
    path = tmp_path / "s.mat"
    writer(
        path, {"imu": {"t": times, "mx": samples[:, 0], "my": samples[:, 1], "mz": samples[:, 2]}}
    )
    log = read_log(path)
    assert log.columns == ["mx", "my", "mz"]
    np.testing.assert_allclose(log.samples, samples)


@pytest.mark.parametrize("writer", [write_v5, write_v73])
def test_a_mat_struct_with_one_n_by_3_field_is_found(tmp_path, writer):
    samples, times = field_nt(n=100)
    path = tmp_path / "s.mat"
    writer(path, {"flight": {"t": times, "B_nT": samples}, "other": 1.0})
    log = read_log(path)
    assert log.columns == ["flight.B_x_nT", "flight.B_y_nT", "flight.B_z_nT"]
    assert (log.unit, log.unit_source) == ("nT", "names") and "t" in log.frame.columns
    np.testing.assert_allclose(log.samples, samples)


@pytest.mark.parametrize("writer", [write_v5, write_v73])
def test_several_candidate_arrays_ask_for_variable_and_the_suggestion_works(
    tmp_path, capsys, writer
):
    samples, _ = field_nt()
    path = tmp_path / "two.mat"
    writer(path, {"magA": samples, "magB": samples[::-1] + 1000.0})
    code, out, err = run(capsys, "calibrate", path, "-o", tmp_path / "p.json")
    assert code == 2 and "--variable" in err and "Traceback" not in err
    suggestion = err.split("for example ")[1].split()
    assert suggestion == ["--variable", "magA"]
    assert_recovers(calibrated(capsys, tmp_path, path, *suggestion))
    code, out, err = run(capsys, "calibrate", path, "--variable", "nope", "-o", tmp_path / "q")
    assert code == 2 and "magA" in err and "magB" in err


def test_variable_and_instance_are_refused_for_other_files(tmp_path, capsys):
    samples, times = field_nt(n=100)
    path = tmp_path / "mag.csv"
    path.write_text(ros1_text(samples, times))
    for flag, value in (("--variable", "mag"), ("--instance", "0")):
        code, out, err = run(capsys, "calibrate", path, flag, value, "-o", tmp_path / "p.json")
        assert code == 2 and flag in err


def test_real_mat_file_reads_as_its_derived_csv(real_data):
    """Rasteiro et al.'s LSM9DS0 recording (MATLAB v5 with an opaque object; SENSmag 3 x N
    among SENSacc, SENSgyro and ABBposition): the field is found by its name."""
    pytest.importorskip("scipy")
    folder = real_data / "rasteiro_robot_multisensor"
    log = read_log(folder / "LSM9DS0.mat", unit="uT")
    assert log.columns == ["SENSmag_x", "SENSmag_y", "SENSmag_z"]
    derived = read_log(folder / "LSM9DS0_derived.csv")
    np.testing.assert_allclose(log.samples, derived.samples, rtol=1e-5)


# --- ArduPilot DataFlash ------------------------------------------------------------------------

FMT_TYPE = 128


def fmt_message(kind: int, name: str, fmt: str, columns: str) -> bytes:
    """A FMT message: header A3 95 80, then Type, Length, Name[4], Format[16], Columns[64]."""
    sizes = {"Q": 8, "B": 1, "h": 2, "I": 4, "n": 4, "N": 16, "Z": 64}
    length = 3 + sum(sizes[c] for c in fmt)
    body = struct.pack("<BB4s16s64s", kind, length, name.encode(), fmt.encode(), columns.encode())
    return b"\xa3\x95" + bytes([FMT_TYPE]) + body


NEW_MAG = ("QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S")
OLD_MAG = ("QhhhhhhhhhB", "TimeUS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ,Health")


def dataflash_log(fields_mg: list, current: bool = True) -> bytes:
    """A DataFlash log to its specification: FMT of FMT, FMT of the compass messages, then one
    compass message per sample and compass, MagX.. in mG; `current` logs one MAG type with the
    instance in I, older logs MAG, MAG2, MAG3."""
    out = [fmt_message(FMT_TYPE, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")]
    if current:
        out.append(fmt_message(51, "MAG", *NEW_MAG))
    else:
        for k, name in enumerate(["MAG", "MAG2", "MAG3"][: len(fields_mg)]):
            out.append(fmt_message(51 + k, name, *OLD_MAG))
    for row in range(len(fields_mg[0])):
        time_us = 1_000_000 + 10_000 * row
        for instance, field in enumerate(fields_mg):
            x, y, z = (int(v) for v in field[row])
            if current:
                body = struct.pack(
                    "<QBhhhhhhhhhBI", time_us, instance, x, y, z, 5, -3, 2, 0, 0, 0, 1, 0
                )
                out.append(b"\xa3\x95" + bytes([51]) + body)
            else:
                body = struct.pack("<QhhhhhhhhhB", time_us, x, y, z, 5, -3, 2, 0, 0, 0, 1)
                out.append(b"\xa3\x95" + bytes([51 + instance]) + body)
    return b"".join(out)


@pytest.mark.parametrize("current", [True, False])
def test_a_dataflash_log_calibrates_with_instance(tmp_path, capsys, current):
    pytest.importorskip("pymavlink")
    samples, _ = field_nt()
    other, _ = field_nt(seed=9)
    mg = [np.rint(other / NT_PER_COUNT), np.rint(samples / NT_PER_COUNT)]
    path = tmp_path / "00000042.BIN"
    path.write_bytes(dataflash_log(mg, current))
    code, out, err = run(capsys, "calibrate", path, "-o", tmp_path / "p.json")
    assert code == 2 and "--instance" in err and "0, 1" in err and "Traceback" not in err
    assert not (tmp_path / "p.json").exists()
    suggestion = err.split("for example ")[1].split()
    assert suggestion == ["--instance", "0"]
    calibrated(capsys, tmp_path, path, *suggestion)  # following it works
    document = calibrated(capsys, tmp_path, path, "--instance", "1")
    assert document["input"]["columns"] == ["MagX", "MagY", "MagZ"]
    assert document["input"]["log_unit"] == "mG" and document["input"]["unit_source"] == "format"
    assert_recovers(document)
    log = read_log(path, instance=1)
    assert log.extras == {} and log.frame["TimeUS"].iloc[1] - log.frame["TimeUS"].iloc[0] == 1e4
    code, out, err = run(capsys, "calibrate", path, "--instance", "2", "-o", tmp_path / "p.json")
    assert code == 2 and "instance 2" in err


def test_a_dataflash_log_with_one_compass_needs_no_flag(tmp_path, capsys):
    pytest.importorskip("pymavlink")
    samples, _ = field_nt()
    path = tmp_path / "one.bin"
    path.write_bytes(dataflash_log([np.rint(samples / NT_PER_COUNT)]))
    assert_recovers(calibrated(capsys, tmp_path, path))


# --- optional dependencies ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "module, extra, sample",
    [
        ("scipy.io", "mat", "v5"),
        ("h5py", "mat", "v73"),
        ("pymavlink", "ardupilot", "bin"),
    ],
)
def test_a_missing_reader_names_its_extra(tmp_path, capsys, monkeypatch, module, extra, sample):
    samples, _ = field_nt(n=50)
    path = tmp_path / f"log.{sample}"
    if sample == "v5":
        write_v5(path, {"mag": samples})
    elif sample == "v73":
        write_v73(path, {"mag": samples})
    else:
        path.write_bytes(dataflash_log([np.rint(samples / NT_PER_COUNT)]))
    monkeypatch.setitem(sys.modules, module, None)  # import fails as if not installed
    code, out, err = run(capsys, "calibrate", path, "-o", tmp_path / "p.json")
    assert code == 2 and f"pip install 'nlpcal[{extra}]'" in err and "Traceback" not in err
    assert err.count("\n") == 1


def test_a_damaged_mat_or_bin_is_one_sentence(tmp_path, capsys):
    for name, data in (
        ("bad.mat", b"MATLAB 5.0 MAT-file" + b"\x00" * 200 + b"\xff" * 50),
        ("bad.bin", b"\xa3\x95\x80" + b"\x01" * 300),
    ):
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(InputError):
            read_log(path)


# --- the rest of the reader's contract on recorded logs -----------------------------------------


def test_apply_writes_every_recorded_row_back_with_its_columns(tmp_path, capsys):
    pytest.importorskip("pymavlink")
    samples, _ = field_nt()
    path = tmp_path / "log.bin"
    path.write_bytes(dataflash_log([np.rint(samples / NT_PER_COUNT)] * 2))
    calibrated(capsys, tmp_path, path, "--instance", "1")
    output = tmp_path / "applied.csv"
    code, out, err = run(
        capsys, "apply", tmp_path / "out.json", path, "--instance", "1", "-o", output
    )
    assert code == 0, err
    lines = output.read_text().splitlines()
    assert lines[0].split(",")[:4] == ["TimeUS", "MagX", "MagY", "MagZ"] and len(lines) == 2001
    assert lines[1].startswith("1000000,")  # the log's time as logged, in microseconds
    code, out, err = run(capsys, "apply", tmp_path / "out.json", path, "-o", output)
    assert code == 2 and "--instance" in err


def test_low_memory_reads_a_recorded_log_whole_and_scheduler_refuses_it(tmp_path, capsys):
    samples, _ = field_nt()
    path = tmp_path / "capture.txt"
    path.write_text(motioncal_text(samples))
    output = tmp_path / "out.json"
    code, out, err = run(capsys, "calibrate", path, "--low-memory", "-o", output)
    assert code == 0 and "read whole" in err
    pytest.importorskip("dask")
    code, out, err = run(capsys, "calibrate", path, "--scheduler", "threads", "-o", output)
    assert code == 2 and "--scheduler" in err


def test_other_columns_of_a_capture_are_not_in_the_format_unit(tmp_path):
    samples, _ = field_nt(n=100)
    path = tmp_path / "capture.txt"
    path.write_text(motioncal_text(samples))
    log = read_log(path, columns=["gx", "gy", "gz"], unit="raw")
    assert (log.unit, log.unit_source) == ("raw", "option")
    assert read_log(path, columns=["ax", "ay", "az"]).unit_source == "assumed"


def test_the_unit_suggested_for_a_mat_file_in_microtesla_works(tmp_path, capsys):
    """A .mat variable whose name carries no unit, in uT: read as nT the magnitudes are far
    from Earth's field; the warning suggests the unit, and following it recovers the truth."""
    samples, _ = field_nt()
    path = tmp_path / "log.mat"
    write_v5(path, {"B": samples / 1000.0})
    output = tmp_path / "out.json"
    code, out, err = run(capsys, "calibrate", path, "-o", output)
    suggested = re.findall(r"\((--unit \w+)\)", err)
    assert suggested == ["--unit uT"]
    assert_recovers(calibrated(capsys, tmp_path, path, *suggested[0].split()))


def test_text_logs_that_only_look_like_recorded_ones_stay_text(tmp_path):
    """A CSV whose first column is MATLABtime is not a .mat file, and magnetic_field_x columns
    of one's own are not ROS's tesla."""
    samples, times = field_nt(n=100)
    rows = [f"{t},{x},{y},{z}" for t, (x, y, z) in zip(times, samples)]
    path = tmp_path / "matlab_export.csv"
    path.write_text("MATLABtime,magnetic_field_x,magnetic_field_y,magnetic_field_z\n")
    with open(path, "a") as handle:
        handle.write("\n".join(rows) + "\n")
    log = read_log(path)
    assert log.columns == ["magnetic_field_x", "magnetic_field_y", "magnetic_field_z"]
    assert (log.unit, log.unit_source) == ("nT", "assumed")
    np.testing.assert_allclose(log.samples, samples)


def _bin(path, samples):
    pytest.importorskip("pymavlink")
    path.write_bytes(dataflash_log([np.rint(samples / NT_PER_COUNT)]))


def _mat(path, samples):
    write_v5(path, {"mag": samples})


def _capture(path, samples):
    path.write_text(motioncal_text(samples))


@pytest.mark.parametrize(
    "name, writer", [("log.bin", _bin), ("flight.mat", _mat), ("capture.txt", _capture)]
)
def test_apply_on_a_recorded_log_writes_one_row_per_input_row(tmp_path, capsys, name, writer):
    """apply reads a recorded log whole and writes every row in its place: the zero vector (not
    a reading) with its raw values and valid 0, the readings corrected to the true field."""
    samples, truth = make_log(n=2000, noise=20.0, seed=5, truth=TRUTH)
    samples[700] = 0.0
    path = tmp_path / name
    writer(path, samples)
    calibrated(capsys, tmp_path, path)
    output = tmp_path / "applied.csv"
    code, out, err = run(capsys, "apply", tmp_path / "out.json", path, "-o", output)
    assert code == 0, err
    written = pd.read_csv(output)
    assert len(written) == len(samples) and list(written.columns[-2:]) == ["b_total", "valid"]
    expected_valid = np.ones(len(samples), dtype=int)
    expected_valid[700] = 0
    np.testing.assert_array_equal(written["valid"], expected_valid)
    assert (written.loc[700, read_log(path).columns] == 0).all()
    # the field per row, to the noise and the format's resolution (0.1 uT or 1 mG: 100 nT steps)
    sigma = np.hypot(20.0, NT_PER_COUNT / np.sqrt(12.0))  # [nT] per axis
    readings = written["valid"] == 1
    scale = {"log.bin": NT_PER_COUNT, "capture.txt": NT_PER_COUNT, "flight.mat": 1.0}[name]
    total = written.loc[readings, "b_total"].to_numpy() * scale  # [nT]
    true_total = np.linalg.norm(truth[readings.to_numpy()], axis=1)
    assert np.max(np.abs(total - true_total)) < 8 * sigma
