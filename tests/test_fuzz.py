"""Hostile input through the whole command line: random tables, random and mutated documents,
output faults. Whatever comes in, nlpcal exits 0, 1 or 2 with a one-sentence message, never a
traceback, never changes an existing output when it fails, and writes only finite numbers.

NLPCAL_FUZZ_EXAMPLES sets the number of examples per test (default 25; a corpus run uses
thousands, and NLPCAL_FUZZ_RANDOM=1 draws new examples each run). The generators cover every
command: random tables through the older ones; random and mutated documents; exports with random
options and imports of random or mutated files of every format; random logs as one file, Parquet,
a pattern or a folder (with links and copies) through calibrate (losses included), apply, stats,
report and batch; random scheduler files. An output nlpcal writes must be finite, hold no null,
and read back (`readable`).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

from nlpcal.cli import main
from synthetic import PAPER_FIELD, make_log

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, event, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

EXAMPLES = int(os.environ.get("NLPCAL_FUZZ_EXAMPLES", "25"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=not os.environ.get("NLPCAL_FUZZ_RANDOM"),
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

COLUMN_NAMES = [
    "bx",
    "by",
    "bz",
    "x",
    "y",
    "z",
    "mag_x",
    "mag_y",
    "mag_z",
    "mx_uT",
    "my_uT",
    "mz_uT",
    "proton_nT",
    "temp_c",
    "ax",
    "ay",
    "az",
    "turn",
    "t",
    "note",
    "",
]
CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(min_value=-7e4, max_value=7e4),
    st.sampled_from(
        [
            "",
            "nan",
            "inf",
            "-inf",
            "1e308",
            "-1e308",
            "1e-300",
            "0",
            "x",
            "y2",
            " ",
            "1,5",
            '"',
            "1e999",
        ]
    ),
    st.integers(min_value=-(10**20), max_value=10**20),
)


def run(argv) -> tuple:
    """main(argv) -> (status, stdout, stderr), with the contract checked."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    text = err.getvalue()
    assert status in (0, 1, 2), (argv, status, text)
    assert "Traceback" not in text and "internal error" not in text, (argv, text)
    if status:
        lines = [line for line in text.splitlines() if line.startswith("nlpcal")]
        assert lines, (argv, text)  # the failure is said
    return status, out.getvalue(), text


def no_nan(text: str) -> None:
    """Strict JSON: NaN and Infinity are refused."""

    def refuse(constant):
        raise AssertionError(f"non-finite number {constant} in the output")

    json.loads(text, parse_constant=refuse)


def finite_csv(path: Path) -> None:
    import pandas as pd

    frame = pd.read_csv(path)
    numeric = frame.select_dtypes("number").to_numpy(dtype=float)
    assert np.isfinite(numeric[:, :]).all() or numeric.size == 0


@st.composite
def tables(draw):
    columns = draw(st.lists(st.sampled_from(COLUMN_NAMES), min_size=1, max_size=6))
    rows = draw(st.integers(min_value=0, max_value=40))
    body = [",".join(str(draw(CELLS)) for _ in columns) for _ in range(rows)]
    return ",".join(columns) + "\n" + "\n".join(body) + ("\n" if body else "")


def good_log(tmp_path, n=300, seed=3) -> Path:
    samples, _ = make_log(n=n, noise=1.0, seed=seed)
    path = tmp_path / "good.csv"
    lines = ["bx,by,bz,proton_nT,temp_c"]
    temperature = np.linspace(5.0, 15.0, n)
    lines += [
        f"{a:.6f},{b:.6f},{c:.6f},{PAPER_FIELD:.3f},{t:.3f}"
        for (a, b, c), t in zip(samples, temperature)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


COMMANDS = [
    ["calibrate", "{log}", "--method", "joint"],
    ["calibrate", "{log}", "--cycles", "3", "--allow-unconverged"],
    ["calibrate", "{log}", "--method", "joint", "--loss", "huber"],
    ["calibrate", "{log}", "--method", "joint", "--reference-column", "proton_nT"],
    ["calibrate", "{log}", "--low-memory", "--method", "joint"],
    ["calibrate", "{log}", "--reference-column", "proton_nT", "--temperature-column", "temp_c"],
    ["stats", "{log}", "--json"],
    ["compare", "{log}", "--cycles", "2", "--cg-max-iter", "20"],
    [
        "drift",
        "fit",
        "{log}",
        "--temperature-column",
        "temp_c",
        "--reference-column",
        "proton_nT",
        "--base-temperature",
        "20",
    ],
    ["orthogonality", "invert", "{log}"],
    ["compass", "calibrate", "{log}"],
]


@FUZZ
@given(text=tables(), command=st.sampled_from(COMMANDS))
def test_random_tables_through_every_command(tmp_path_factory, text, command):
    folder = tmp_path_factory.mktemp("fuzz")
    log = folder / "log.csv"
    log.write_text(text)
    output = folder / "out.json"
    output.write_text("previous")
    argv = [part.format(log=log) for part in command] + ["-o", output]
    status, _, _ = run(argv)
    if status:
        assert output.read_text() == "previous"
    else:
        readable(output)
    assert sorted(p.name for p in folder.iterdir()) == ["log.csv", "out.json"]  # no debris


JSON_VALUES = st.recursive(
    st.one_of(
        st.none(),
        st.booleans(),
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(),
        st.text(max_size=8),
    ),
    lambda children: st.one_of(
        st.lists(children, max_size=4), st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=12,
)


@pytest.fixture(scope="module")
def documents(tmp_path_factory):
    """Valid documents of every kind nlpcal reads, and a log to use them on."""
    folder = tmp_path_factory.mktemp("documents")
    log = good_log(folder)
    assert run(["simulate", "--preset", "qiu2017", "-o", folder / "q", "-n", "40"])[0] == 0
    made = {}
    for name, argv in {
        "params": ["calibrate", log, "--method", "joint"],
        "temperature": [
            "calibrate",
            log,
            "--reference-column",
            "proton_nT",
            "--temperature-column",
            "temp_c",
        ],
        "drift": [
            "drift",
            "fit",
            log,
            "--temperature-column",
            "temp_c",
            "--reference-column",
            "proton_nT",
            "--base-temperature",
            "20",
        ],
        "compass": ["compass", "calibrate", folder / "q" / "turns.csv", "--turn-column", "turn"],
    }.items():
        path = folder / f"{name}.json"
        assert run([*argv, "-o", path])[0] == 0
        made[name] = json.loads(path.read_text())
    return log, made


def mutate(document, path, value):
    """A copy of `document` with the entry at `path` (a list of keys) replaced by `value`."""
    copy = json.loads(json.dumps(document))
    node = copy
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return copy


def leaf_paths(document, prefix=()):
    if isinstance(document, dict):
        for key, value in document.items():
            yield (*prefix, key)
            yield from leaf_paths(value, (*prefix, key))
    elif isinstance(document, list):
        for k, value in enumerate(document[:3]):
            yield (*prefix, k)
            yield from leaf_paths(value, (*prefix, k))


@FUZZ
@given(data=st.data())
def test_mutated_and_random_documents(documents, tmp_path_factory, data):
    log, made = documents
    kind = data.draw(st.sampled_from(sorted(made)))
    paths = list(leaf_paths(made[kind]))
    if data.draw(st.booleans()):
        document = data.draw(JSON_VALUES)
    else:
        document = mutate(
            made[kind], list(data.draw(st.sampled_from(paths))), data.draw(JSON_VALUES)
        )
    folder = tmp_path_factory.mktemp("doc")
    doc_path = folder / "doc.json"
    doc_path.write_text(json.dumps(document))
    output = folder / "out.csv"
    output.write_text("previous")
    if kind == "drift":
        argv = ["apply", made_path(folder, made["params"]), log, "--drift", doc_path]
    elif kind == "compass":
        argv = ["compass", "attitude", doc_path, log.parent / "q" / "test.csv"]
    else:
        argv = ["apply", doc_path, log]
    status, _, _ = run([*argv, "-o", output])
    if status:
        assert output.read_text() == "previous"
    else:
        readable(output)
    if kind == "compass":
        return
    status, out, _ = run(
        [
            "stats",
            log,
            "--params" if kind != "drift" else "--drift",
            doc_path,
            "--json",
            *(["--temperature-column", "temp_c"] if kind == "drift" else []),
        ]
    )
    if status == 0:
        no_null(out)


def made_path(folder, document) -> Path:
    path = folder / "params.json"
    path.write_text(json.dumps(document))
    return path


# --- named regressions of the hostile corpus -------------------------------------------------


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), 1e308, "12", None, [1, 2], True])
def test_a_bad_parameter_value_is_refused(documents, tmp_path, bad):
    log, made = documents
    path = made_path(tmp_path, mutate(made["params"], ["parameters", "z_x"], bad))
    status, _, err = run(["apply", path, log, "-o", tmp_path / "c.csv"])
    assert status == 2 and "z_x" in err and not (tmp_path / "c.csv").exists()
    status, out, _ = run(["stats", log, "--params", path, "--json"])
    assert status == 2 and out == ""


def test_documents_that_are_folders_or_nested_too_deep(documents, tmp_path):
    log, _ = documents
    assert run(["apply", tmp_path, log])[0] == 2
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    assert run(["apply", deep, log])[0] == 2
    nested = tmp_path / "nested.json"
    nested.write_text(json.dumps({"parameters": json.loads("[" * 50 + "]" * 50)}))
    assert run(["apply", nested, log])[0] == 2


def test_a_singular_compass_matrix_is_refused(tmp_path):
    status = run(["simulate", "--preset", "qiu2017", "-o", tmp_path / "q", "-n", "50"])[0]
    assert status == 0
    turns = tmp_path / "q" / "turns.csv"
    compass = tmp_path / "compass.json"
    assert run(["compass", "calibrate", turns, "--turn-column", "turn", "-o", compass])[0] == 0
    document = json.loads(compass.read_text())
    document["magnetometer"]["correction_matrix"] = [[1, 0, 0], [0, 1, 0], [0, 0, 0]]
    compass.write_text(json.dumps(document))
    status, _, err = run(["compass", "attitude", compass, turns, "-o", tmp_path / "a.csv"])
    assert status == 2 and "singular" in err


def test_output_faults_are_one_sentence(documents, tmp_path):
    log, _ = documents
    long_name = tmp_path / ("x" * 300 + ".json")
    status, _, err = run(["calibrate", log, "--method", "joint", "-o", long_name])
    assert status == 2 and "File name too long" in err
    status, _, err = run(["calibrate", log, "--method", "joint", "-o", log])
    assert status == 2 and "also an input" in err
    readonly = tmp_path / "ro"
    readonly.mkdir()
    readonly.chmod(0o555)
    try:
        status, _, err = run(["calibrate", log, "--method", "joint", "-o", readonly / "p.json"])
        if os.geteuid() != 0:  # root writes anywhere
            assert status == 2 and "cannot be written" in err
    finally:
        readonly.chmod(0o755)


def test_no_space_left_is_a_failed_write(documents, tmp_path, monkeypatch):
    import errno

    from nlpcal.io import files

    log, _ = documents
    target = tmp_path / "p.json"
    target.write_text("previous")

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(files.os, "fsync", full)
    status, _, err = run(["calibrate", log, "--method", "joint", "-o", target])
    assert status == 1 and "No space left on device" in err
    assert target.read_text() == "previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.json"]


@pytest.mark.parametrize("scale", [1e300, 1e-300])
def test_extreme_magnitudes_are_input_errors(tmp_path, scale):
    samples, _ = make_log(n=200, noise=1.0, seed=5)
    path = tmp_path / "extreme.csv"
    path.write_text(
        "bx,by,bz\n"
        + "\n".join(",".join(repr(v * scale / 5e4) for v in row) for row in samples)
        + "\n"
    )
    for command in (
        ["calibrate", path],
        ["compare", path, "--cycles", "2"],
        ["orthogonality", "invert", path],
    ):
        status, _, err = run(command)
        assert status == 2, err


def test_a_reference_far_from_the_data_is_an_input_error(documents):
    log, _ = documents
    for field in ("1e300", "4.9"):  # 4.9: the field in uT against a log in nT
        status, _, err = run(["calibrate", log, "--reference-field", field])
        assert status == 2 and "times the mean magnitude" in err


def test_inversion_of_repeated_samples_fails_the_quality_check(tmp_path):
    path = tmp_path / "two.csv"
    path.write_text("bx,by,bz\n" + "30000,20000,30000\n-20000,30000,-30000\n" * 20)
    status, _, err = run(["orthogonality", "invert", path])
    assert status == 1 and "do not determine" in err


def test_compare_fails_the_quality_check_where_calibrate_does(tmp_path):
    from synthetic import planar_directions

    samples, _ = make_log(
        n=400, noise=1.0, seed=12, directions=planar_directions(400, np.random.default_rng(11))
    )
    path = tmp_path / "planar.csv"
    path.write_text("bx,by,bz\n" + "\n".join(",".join(f"{v:.4f}" for v in r) for r in samples))
    status, _, err = run(["compare", path, "--reference-field", PAPER_FIELD, "--cycles", "3"])
    assert status == 1 and "do not determine" in err


def test_repeated_columns_are_bad_usage(documents):
    log, _ = documents
    status, _, err = run(["calibrate", log, "--columns", "bx", "bx", "bz"])
    assert status == 2 and "repeat" in err


def test_low_memory_refuses_a_ragged_row_like_the_default_reader(tmp_path):
    samples, _ = make_log(n=100, noise=1.0, seed=6)
    lines = ["bx,by,bz"] + [",".join(f"{v:.4f}" for v in r) for r in samples]
    lines[20] += ",1"
    path = tmp_path / "ragged.csv"
    path.write_text("\n".join(lines) + "\n")
    for extra in ([], ["--low-memory"]):
        status, _, err = run(["calibrate", path, "--method", "joint", *extra])
        assert status == 2 and "has 4 fields where the lines before have 3" in err
        assert len(err.splitlines()) == 1


def test_written_json_is_strict(documents, tmp_path):
    log, _ = documents
    out = tmp_path / "p.json"
    assert run(["calibrate", log, "--method", "joint", "-o", out])[0] == 0
    no_nan(out.read_text())
    assert math.isfinite(json.loads(out.read_text())["parameters"]["z_x"])


# --- named regressions of the newer corpus (export, import, report, batch, schedulers, losses) -


def write_rows(path: Path, header: str, rows) -> Path:
    path.write_text(header + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows))
    return path


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
@pytest.mark.parametrize("method", ["staged", "joint"])
def test_a_given_loss_scale_works_in_both_methods(documents, tmp_path, loss, method):
    log, _ = documents
    out = tmp_path / "p.json"
    argv = ["calibrate", log, "--method", method, "--loss", loss, "--loss-scale", "5", "-o", out]
    status, _, err = run(argv)
    assert status == 0, err
    robust = json.loads(out.read_text())["robust"]
    assert robust["loss"] == loss and robust["scale"] == 5.0 and robust["scale_source"] == "given"


def test_a_batch_with_a_given_loss_scale_calibrates_every_log(tmp_path):
    for seed in (3, 4):
        good_log(tmp_path, seed=seed).rename(tmp_path / f"log{seed}.csv")
    out = tmp_path / "out"
    argv = ["batch", "calibrate", tmp_path / "log*.csv", "--out-dir", out]
    status, _, err = run([*argv, "--loss", "cauchy", "--loss-scale", "5"])
    assert status == 0, err
    import pandas as pd

    assert list(pd.read_csv(out / "summary.csv")["status"]) == ["ok", "ok"]


@pytest.mark.parametrize("scale", ["nan", "inf", "-1", "0", "1e-300"])
def test_a_loss_scale_must_be_finite_positive_and_usable(documents, scale):
    log, _ = documents
    status, _, err = run(["calibrate", log, "--loss", "cauchy", "--loss-scale", scale])
    assert status == 2 and "loss scale" in err


@pytest.fixture(scope="module")
def exported(documents, tmp_path_factory):
    """A calibration against a reference field, exported in every format."""
    log, _ = documents
    folder = tmp_path_factory.mktemp("exported")
    params = folder / "params.json"
    assert run(["calibrate", log, "--reference-column", "proton_nT", "-o", params])[0] == 0
    texts = {}
    for fmt in ("matlab", "matrix", "ardupilot", "px4", "c-header"):
        status, out, err = run(["export", params, "--format", fmt])
        assert status == 0, err
        texts[fmt] = out
    return texts


def _offset_line(fmt: str) -> str:
    """A pattern of the first offset of each format (its value is the group)."""
    return {
        "matlab": r"b = \[([^ \]]+)",
        "matrix": r'"b": \[\s*([^,\s]+)',
        "ardupilot": r"COMPASS_OFS_X,(\S+)",
        "px4": r"CAL_MAG0_XOFF\t(\S+)",
        "c-header": r"NLPCAL_B\[3\] = \{([^,]+)",
    }[fmt]


def _with_first_offset(text: str, fmt: str, value: str) -> str:
    match = re.search(_offset_line(fmt), text)
    assert match, (fmt, text)
    return text[: match.start(1)] + value + text[match.end(1) :]


def _import(tmp_path, fmt, text, *extra):
    source = tmp_path / f"in.{fmt}"
    source.write_text(text)
    out = tmp_path / "imported.json"
    status, _, err = run(["import", source, "--format", fmt, "-o", out, *extra])
    if status:
        assert not out.exists()
    return status, err, out


FORMATS = ["matlab", "matrix", "ardupilot", "px4", "c-header"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_import_round_trips_every_export(exported, tmp_path, fmt, documents):
    status, err, out = _import(tmp_path, fmt, exported[fmt])
    assert status == 0, err
    assert run(["apply", out, documents[0], "-o", tmp_path / "c.csv"])[0] == 0


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("value", ["1e300", "-1e300", "1e12"])
def test_import_refuses_offsets_nlpcal_would_refuse(exported, tmp_path, fmt, value):
    status, err, _ = _import(tmp_path, fmt, _with_first_offset(exported[fmt], fmt, value))
    assert status == 2 and ("z_x" in err or "b " in err or "OFF" in err or "OFS" in err), err


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("value", ["NaN", "nan", "Inf", "-Inf", "INFINITY", "-inf"])
def test_import_refuses_non_finite_values(exported, tmp_path, fmt, value):
    status, err, _ = _import(tmp_path, fmt, _with_first_offset(exported[fmt], fmt, value))
    assert status == 2, err


def test_compass_ofs_minus_inf_is_bad_input(tmp_path):
    status, err, _ = _import(tmp_path, "ardupilot", "COMPASS_OFS_X,-Inf\n")
    assert status == 2 and "COMPASS_OFS_X" in err


def test_c_header_nan_field_is_refused_not_written_as_null(exported, tmp_path):
    text = exported["c-header"]
    start = text.index("NLPCAL_FIELD = ") + len("NLPCAL_FIELD = ")
    text = text[:start] + "NAN" + text[text.index(";", start) :]
    status, err, _ = _import(tmp_path, "c-header", text)
    assert status == 2 and "NLPCAL_FIELD" in err


@pytest.mark.parametrize("fmt", ["matlab", "ardupilot", "px4"])
@pytest.mark.parametrize("field", ["nan", "0", "-1", "inf", "1e300"])
def test_import_refuses_a_bad_reference_field(exported, tmp_path, fmt, field):
    status, err, _ = _import(tmp_path, fmt, exported[fmt], "--reference-field", field)
    assert status == 2 and ("reference" in err or "field" in err), err


@pytest.mark.parametrize(
    "fmt, addition, key",
    [
        ("matlab", "b = [1 2 3];\n", "'b'"),
        ("ardupilot", "COMPASS_OFS_X,12.5\n", "COMPASS_OFS_X"),
        ("px4", "1\t1\tCAL_MAG0_XOFF\t0.125\t9\n", "CAL_MAG0_XOFF"),
        ("c-header", "static const double NLPCAL_B[3] = {1, 2, 3};\n", "'B'"),
    ],
)
def test_import_refuses_conflicting_repeated_keys(exported, tmp_path, fmt, addition, key):
    status, err, _ = _import(tmp_path, fmt, exported[fmt] + addition)
    assert status == 2 and key in err and "twice" in err


def test_import_refuses_a_repeated_json_key(exported, tmp_path):
    text = exported["matrix"].replace('"unit": "nT"', '"unit": "nT", "unit": "uT"', 1)
    status, err, _ = _import(tmp_path, "matrix", text)
    assert status == 2 and "'unit'" in err and "twice" in err
    same = exported["matrix"].replace('"unit": "nT"', '"unit": "nT", "unit": "nT"', 1)
    assert _import(tmp_path, "matrix", same)[0] == 0  # the same value twice says the same


def test_a_params_file_with_a_repeated_key_is_refused(documents, tmp_path):
    log, made = documents
    text = json.dumps(made["params"]).replace('"z_x": ', '"z_x": 1.0, "z_x": ', 1)
    path = tmp_path / "p.json"
    path.write_text(text)
    status, _, err = run(["apply", path, log])
    assert status == 2 and "'z_x'" in err


@pytest.mark.parametrize("value", ["nan", "inf", "-1", "181"])
def test_export_max_rotation_must_be_finite_and_in_range(exported, tmp_path, documents, value):
    log, _ = documents
    params = tmp_path / "p.json"
    assert run(["calibrate", log, "--method", "joint", "-o", params])[0] == 0
    status, out, err = run(["export", params, "--format", "px4", "--max-rotation-deg", value])
    assert status == 2 and "--max-rotation-deg" in err and out == ""


@pytest.mark.parametrize(
    "text", ["junk text", "{}", '{"address": 5}', "[1]", '{"address": "junk"}', ""]
)
def test_a_scheduler_file_of_junk_is_bad_input(documents, tmp_path, text):
    pytest.importorskip("distributed")
    log, _ = documents
    scheduler = tmp_path / "scheduler.json"
    scheduler.write_text(text)
    status, _, err = run(["calibrate", log, "--scheduler", scheduler])
    assert status == 2 and "scheduler" in err


@pytest.mark.parametrize(
    "junk",
    [
        (2**45).to_bytes(8, "little") + b"junk" * 8,  # a length Dask would try to allocate
        b"\xff" * 64,
        b"HTTP/1.1 200 OK\r\nContent-Length: 0\r\n\r\n",
    ],
)
def test_a_server_that_is_not_dask_is_bad_input(documents, monkeypatch, junk):
    import time

    pytest.importorskip("distributed")
    from nlpcal import cluster

    log, _ = documents
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 5)
    started = time.monotonic()
    with junk_server(junk) as port:
        status, _, err = run(["calibrate", log, "--scheduler", f"tcp://127.0.0.1:{port}"])
    assert status == 2 and "no Dask scheduler answers" in err
    assert time.monotonic() - started < 60


def test_a_failed_connection_leaves_dasks_default_scheduler_as_it_was(documents, monkeypatch):
    # a Client makes itself the default before connecting: left behind, later Dask work in
    # the same process would be sent to a cluster that is not there
    pytest.importorskip("distributed")
    import dask

    from nlpcal import cluster

    log, _ = documents
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 5)
    with dask.config.set(scheduler="sync"), junk_server(b"\xff" * 64) as port:
        status, _, _ = run(["calibrate", log, "--scheduler", f"tcp://127.0.0.1:{port}"])
        assert status == 2 and dask.config.get("scheduler") == "sync"
    assert dask.config.get("scheduler", None) is None


@contextlib.contextmanager
def junk_server(junk: bytes):
    """A local TCP server that answers every connection with `junk`; yields its port."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(20)  # the thread ends by itself if nothing connects

    def answer():
        with contextlib.suppress(OSError):
            while True:
                connection, _ = server.accept()
                with connection:
                    connection.sendall(junk)

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        server.close()


@pytest.fixture(scope="module")
def roles_log(tmp_path_factory):
    """A log with a column of every kind: field, reference, temperature, place and time."""
    samples, _ = make_log(n=200, noise=1.0, seed=8)
    n = len(samples)
    rows = np.column_stack(
        [
            samples,
            np.full(n, PAPER_FIELD),
            np.linspace(5.0, 15.0, n),
            np.full(n, 45.0),
            np.full(n, 7.0),
            np.full(n, 100.0),
            1.7e9 + np.arange(n),
        ]
    )
    folder = tmp_path_factory.mktemp("roles")
    return write_rows(folder / "roles.csv", "bx,by,bz,proton_nT,temp_c,lat,lon,alt,t", rows)


MODEL = ["--reference-model", "igrf"]
PROTON = ["--reference-column", "proton_nT"]


@pytest.mark.parametrize(
    "options, column, roles",
    [
        (["--reference-column", "temp_c", "--temperature-column", "temp_c"], "temp_c", 2),
        (["--reference-column", "3", "--temperature-column", "proton_nT"], "proton_nT", 2),
        (["--reference-column", "bx"], "bx", 1),
        (["--reference-column", "proton_nT", "--temperature-column", "bz"], "bz", 1),
        (["--columns", "by", "bx", "bz", "--temperature-column", "1", *PROTON], "by", 1),
        ([*MODEL, "--lat-column", "lat", "--lon-column", "lon", "--time-column", "lat"], "lat", 2),
        ([*MODEL, "--lat-column", "lat", "--lon-column", "lat", "--time-column", "t"], "lat", 2),
        ([*MODEL, "--lat-column", "bz", "--lon-column", "lon", "--time-column", "t"], "bz", 1),
        (
            [*MODEL, "--lat", "45", "--lon", "7", "--alt-column", "t", "--time-column", "t"],
            "t",
            2,
        ),
        (
            [*MODEL, "--lat-column", "lat", "--lon", "7", "--time-column", "t"]
            + ["--alt-column", "lat"],
            "lat",
            2,
        ),
    ],
)
def test_one_column_cannot_be_two_things(roles_log, options, column, roles):
    status, _, err = run(["calibrate", roles_log, *options])
    assert status == 2 and f"'{column}'" in err and "given as both" in err
    named = [o for o in options if o.endswith("-column")]
    assert sum(o in err for o in dict.fromkeys(named)) + ("field column" in err) >= 2, err
    if "--time-column" not in options:
        assert run(["calibrate", roles_log, *options, "--low-memory"])[0] == 2


def test_one_column_cannot_be_two_things_in_drift_stats_and_compass(roles_log, documents):
    both = ["--temperature-column", "proton_nT", "--reference-column", "proton_nT"]
    drift = ["drift", "fit", roles_log, *both, "--base-temperature", "20"]
    status, _, err = run(drift)
    assert status == 2 and "'proton_nT'" in err
    status, _, err = run(["stats", roles_log, "--reference-column", "bx"])
    assert status == 2 and "'bx'" in err
    truth = ["--truth-columns", "lat", "lon", "lat", "--estimate-columns", "t", "alt", "temp_c"]
    status, _, err = run(["compass", "evaluate", roles_log, *truth])
    assert status == 2 and "'lat'" in err


def test_report_reads_the_log_from_stdin(documents, tmp_path, monkeypatch):
    log, made = documents
    params = made_path(tmp_path, made["params"])
    stdin = io.TextIOWrapper(io.BytesIO(log.read_bytes()))
    monkeypatch.setattr("sys.stdin", stdin)
    status, _, err = run(["report", params, "-", "-o", tmp_path / "r.html"])
    assert status == 0, err
    assert "stdin" in (tmp_path / "r.html").read_text()


@pytest.fixture
def folder_of_logs(tmp_path):
    folder = tmp_path / "logs"
    folder.mkdir()
    good_log(tmp_path, n=150, seed=3).rename(folder / "a.csv")
    good_log(tmp_path, n=150, seed=4).rename(folder / "b.csv")
    return folder


@pytest.mark.parametrize("link", ["symlink", "hardlink"])
def test_a_file_named_twice_is_read_once(folder_of_logs, tmp_path, link):
    (os.symlink if link == "symlink" else os.link)(
        folder_of_logs / "a.csv", folder_of_logs / "c.csv"
    )
    out = tmp_path / "p.json"
    for source in (folder_of_logs / "*.csv", folder_of_logs):
        status, _, err = run(["calibrate", source, "--method", "joint", "-o", out])
        assert status == 0 and "c.csv is the same file as" in err and "read once" in err
        assert json.loads(out.read_text())["n_samples"] == 300
    status, _, err = run(["calibrate", folder_of_logs / "*.csv", "--low-memory", "-o", out])
    assert status == 0 and "read once" in err
    status, _, err = run(["batch", "calibrate", folder_of_logs, "--out-dir", tmp_path / "out"])
    assert status == 0 and "read once" in err
    import pandas as pd

    assert len(pd.read_csv(tmp_path / "out" / "summary.csv")) == 2


def test_the_same_path_twice_in_a_batch_is_read_once(folder_of_logs, tmp_path):
    a = folder_of_logs / "a.csv"
    status, _, err = run(["batch", "calibrate", a, a, "--out-dir", tmp_path / "out"])
    assert status == 0 and "read once" in err


def test_two_files_with_the_same_content_are_refused(folder_of_logs, tmp_path):
    import shutil

    shutil.copy(folder_of_logs / "a.csv", folder_of_logs / "copy.csv")
    out = tmp_path / "p.json"
    out.write_text("previous")
    for argv in (
        ["calibrate", folder_of_logs / "*.csv", "-o", out],
        ["calibrate", folder_of_logs, "--low-memory", "-o", out],
        ["batch", "calibrate", folder_of_logs, "--out-dir", tmp_path / "out"],
    ):
        status, _, err = run(argv)
        assert status == 2 and "a.csv" in err and "copy.csv" in err and "same content" in err
    assert out.read_text() == "previous"


def test_stats_refuses_a_reference_in_another_unit(documents, tmp_path):
    log, made = documents
    samples, _ = make_log(n=200, noise=1.0, seed=9)
    rows = np.column_stack([samples, np.full(len(samples), PAPER_FIELD / 1000.0)])
    path = write_rows(tmp_path / "ut.csv", "bx,by,bz,ref", rows)  # ref in uT, log in nT
    params = made_path(tmp_path, made["params"])
    for argv in (["stats", path, "--params", params], ["stats", path], ["calibrate", path]):
        status, _, err = run([*argv, "--reference-column", "ref"])
        assert status == 2 and "times the mean magnitude" in err


@pytest.mark.parametrize("scale", [1e300, 1e-300])
def test_apply_and_stats_refuse_extreme_magnitudes(documents, tmp_path, scale):
    log, made = documents
    samples, _ = make_log(n=200, noise=1.0, seed=5)
    path = write_rows(tmp_path / "extreme.csv", "bx,by,bz", samples * scale / 5e4)
    params = made_path(tmp_path, made["params"])
    out = tmp_path / "c.csv"
    out.write_text("previous")
    for argv in (
        ["apply", params, path, "-o", out],
        ["stats", path, "--json"],
        ["stats", path, "--params", params, "--json"],
    ):
        status, stdout, err = run(argv)
        assert status == 2 and stdout == "", err
    assert out.read_text() == "previous"


# --- every document nlpcal writes, nlpcal reads back ---------------------------------------


def no_null(text: str) -> None:
    """Strict JSON without null: a quantity that does not exist is left out."""
    no_nan(text)

    def walk(value, where="") -> None:
        assert value is not None, f"null at {where}"
        if isinstance(value, dict):
            for key, item in value.items():
                walk(item, f"{where}.{key}")
        elif isinstance(value, list):
            for k, item in enumerate(value):
                walk(item, f"{where}[{k}]")

    walk(json.loads(text))


def read_back(again, written, where: str) -> None:
    """What nlpcal read back from a document it wrote is what it wrote (derived items written
    for the reader, such as a compass's compensation angles, may be left out of the reading)."""
    if isinstance(again, dict):
        assert isinstance(written, dict), where
        for key, value in again.items():
            if key != "nlpcal_version":
                read_back(value, written[key], f"{where}.{key}")
    elif isinstance(again, list):
        assert isinstance(written, list) and len(again) == len(written), where
        for k, (a, b) in enumerate(zip(again, written)):
            read_back(a, b, f"{where}[{k}]")
    else:
        assert again == written, (where, again, written)


def test_every_document_nlpcal_writes_reads_back(documents, tmp_path):
    from nlpcal.calibration.result import CalibrationResult
    from nlpcal.comparison import Comparison
    from nlpcal.compass.result import CompassCalibration
    from nlpcal.drift.fit import DriftFit
    from nlpcal.drift.temperature import TemperatureCalibrationResult
    from nlpcal.formats import AffineCorrection
    from nlpcal.orthogonality.inversion import Inversion

    log, made = documents
    params = made_path(tmp_path, made["params"])
    turns = log.parent / "q" / "turns.csv"
    kinds = {
        "params": (CalibrationResult, ["calibrate", log, "--reference-column", "proton_nT"]),
        "robust": (CalibrationResult, ["calibrate", log, "--loss", "huber", "--loss-scale", "3"]),
        "moments": (CalibrationResult, ["calibrate", log, "--cycles", "4", "--allow-unconverged"]),
        "temperature": (
            TemperatureCalibrationResult,
            ["calibrate", log, "--reference-column", "proton_nT", "--temperature-column", "temp_c"],
        ),
        "drift": (
            DriftFit,
            ["drift", "fit", log, "--temperature-column", "temp_c"]
            + ["--reference-column", "proton_nT", "--base-temperature", "20"],
        ),
        "compass": (CompassCalibration, ["compass", "calibrate", turns, "--turn-column", "turn"]),
        "comparison": (Comparison, ["compare", log, "--cycles", "2", "--cg-max-iter", "20"]),
        "inversion": (Inversion, ["orthogonality", "invert", log]),
        "matrix": (AffineCorrection, ["export", params, "--format", "matrix"]),
        "import": (CalibrationResult, ["import", tmp_path / "matrix.json", "--format", "matrix"]),
    }
    for name, (kind, argv) in kinds.items():
        path = tmp_path / f"{name}.json"
        status, _, err = run([*argv, "-o", path])
        assert status == 0, (name, err)
        text = path.read_text()
        no_null(text)
        read_back(json.loads(kind.load(path).to_json()), json.loads(text), name)
    status, out, _ = run(
        ["stats", log, "--params", params, "--reference-column", "proton_nT", "--json"]
    )
    assert status == 0
    no_null(out)


def test_every_table_nlpcal_writes_reads_back(documents, tmp_path):
    pytest.importorskip("pyarrow")
    import pandas as pd

    log, made = documents
    params = made_path(tmp_path, made["params"])
    corrected = tmp_path / "c.csv"
    assert run(["apply", params, log, "-o", corrected])[0] == 0
    finite_csv(corrected)
    assert run(["stats", corrected, "--json"])[0] == 0  # read back as a log
    logs = tmp_path / "logs"
    logs.mkdir()
    pd.read_csv(log).to_parquet(logs / "one.parquet")
    out = tmp_path / "out"
    status, _, err = run(["batch", "apply", params, logs, "--out-dir", out])
    assert status == 0, err
    written = out / "one.corrected.parquet"
    assert np.isfinite(pd.read_parquet(written).select_dtypes("number").to_numpy()).all()
    assert run(["stats", written, "--json"])[0] == 0
    summary = pd.read_csv(out / "summary.csv")
    assert not np.isinf(summary.select_dtypes("number").to_numpy()).any()


# --- generators over the newer commands: export, import, report, batch, Parquet, patterns,
# --- scheduler files, losses ------------------------------------------------------------------

NUMBER_TEXT = st.one_of(
    st.sampled_from(
        ["nan", "NaN", "inf", "-Inf", "INFINITY", "1e300", "-1e300", "1e-300", "0", "-0", "1e12"]
        + ["", "x", "1,5", "0x10", "1e999", "5", "-5", "0.5", "3"]
    ),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=-1e4, max_value=1e4).map(repr),
)


def readable(path: Path) -> None:
    """An output nlpcal wrote is finite, has no null, and nlpcal reads it back."""
    from nlpcal.calibration.result import CalibrationResult
    from nlpcal.comparison import Comparison
    from nlpcal.compass.result import CompassCalibration
    from nlpcal.drift.fit import DriftFit
    from nlpcal.drift.temperature import TemperatureCalibrationResult
    from nlpcal.formats import AffineCorrection
    from nlpcal.io import read_table
    from nlpcal.orthogonality.inversion import Inversion
    from nlpcal.results import load_any

    if path.suffix == ".json":
        no_null(path.read_text())
        kinds = (
            CalibrationResult,
            TemperatureCalibrationResult,
            DriftFit,
            CompassCalibration,
            Comparison,
            Inversion,
            AffineCorrection,
        )
        if json.loads(path.read_text()).get("format") != "nlpcal-batch":
            load_any(path, kinds)
    elif path.suffix in (".csv", ".parquet"):
        import pandas as pd

        frame = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
        assert not np.isinf(frame.select_dtypes("number").to_numpy(dtype=float)).any()
        if path.name != "summary.csv":
            assert np.isfinite(frame.select_dtypes("float").to_numpy(dtype=float)).all()
        read_table(path)


def fuzz_folder(tmp_path_factory) -> tuple:
    folder = tmp_path_factory.mktemp("fuzz")
    output = folder / "out"
    return folder, output


@FUZZ
@given(data=st.data())
def test_random_exports_and_imports(documents, exported, tmp_path_factory, data):
    """export with random options, and import of random or mutated files of every format."""
    log, made = documents
    folder = tmp_path_factory.mktemp("formats")
    fmt = data.draw(st.sampled_from(FORMATS))
    output = folder / "out.txt"
    output.write_text("previous")
    if data.draw(st.booleans()):  # export
        params = made_path(folder, made[data.draw(st.sampled_from(["params", "temperature"]))])
        options = []
        if data.draw(st.booleans()):
            options += ["--max-rotation-deg", data.draw(NUMBER_TEXT)]
        if data.draw(st.booleans()):
            options += ["--unit", data.draw(st.sampled_from(["nT", "uT", "G", "raw"]))]
        if data.draw(st.booleans()):
            options += ["--instance", data.draw(st.sampled_from(["0", "1", "2", "3", "4", "x"]))]
        status, _, _ = run(["export", params, "--format", fmt, *options, "-o", output])
        event(f"export {fmt}: exit {status}")
        if status:
            assert output.read_text() == "previous"
            return
        instance = options[options.index("--instance") + 1] if "--instance" in options else None
        back = folder / "back.json"
        extra = ["--instance", instance] if instance else []
        status, _, err = run(["import", output, "--format", fmt, *extra, "-o", back])
        assert status == 0, err  # what nlpcal exports, nlpcal imports
        readable(back)
        return
    text = exported[fmt]
    numbers = list(re.finditer(r"-?\d[\d.eE+-]*", text))
    for _ in range(data.draw(st.integers(0, 3))):
        match = data.draw(st.sampled_from(numbers))
        text = text[: match.start()] + data.draw(NUMBER_TEXT) + text[match.end() :]
        numbers = list(re.finditer(r"-?\d[\d.eE+-]*", text))
    lines = text.splitlines(keepends=True)
    if data.draw(st.booleans()):  # a line repeated, changed or not
        line = data.draw(st.sampled_from(lines))
        lines.insert(data.draw(st.integers(0, len(lines))), line)
    if data.draw(st.booleans()):
        del lines[data.draw(st.integers(0, len(lines) - 1))]
    if data.draw(st.integers(0, 9)) == 0:
        lines = [data.draw(st.text(max_size=60))]
    source = folder / f"in.{fmt}"
    source.write_text("".join(lines))
    options = []
    if data.draw(st.booleans()):
        options += ["--reference-field", data.draw(NUMBER_TEXT)]
    status, _, _ = run(["import", source, "--format", fmt, *options, "-o", output])
    event(f"import {fmt}: exit {status}")
    if status:
        assert output.read_text() == "previous"
    else:
        readable(output.rename(folder / "imported.json"))


LOG_CONTAINERS = ("file", "parquet", "pattern", "folder", "linked", "copies")


def _log_source(folder: Path, texts, container: str) -> Path:
    """The log as one file, a Parquet file, a pattern or a folder of files (with a link to one
    of them, or a copy)."""
    logs = folder / "logs"
    logs.mkdir()
    paths = []
    for k, text in enumerate(texts):
        path = logs / f"part{k}.csv"
        path.write_text(text)
        paths.append(path)
    if container == "parquet":
        import pandas as pd

        try:
            frame = pd.read_csv(paths[0])
            frame.columns = [str(c) for c in frame.columns]
            frame.to_parquet(logs / "part0.parquet")
        except Exception:  # a table pandas cannot read or store: keep the CSV
            return paths[0]
        paths[0].unlink()
        return logs / "part0.parquet"
    if container == "file":
        return paths[0]
    if container == "linked":
        os.symlink(paths[0].name, logs / "link.csv")
    if container == "copies":
        (logs / "copy.csv").write_text(texts[0])
    return logs if container == "folder" else logs / "*.csv"


LOG_COMMANDS = [
    ["calibrate", "{log}", "--method", "joint", "-o", "{out}.json"],
    ["calibrate", "{log}", "--loss", "{loss}", "--loss-scale", "{scale}", "-o", "{out}.json"],
    ["calibrate", "{log}", "--method", "joint", "--loss", "{loss}", "-o", "{out}.json"],
    ["calibrate", "{log}", "--low-memory", "--method", "joint", "-o", "{out}.json"],
    ["apply", "{params}", "{log}", "-o", "{out}.csv"],
    ["stats", "{log}", "--params", "{params}", "--json"],
    ["report", "{params}", "{log}", "-o", "{out}.html"],
    ["batch", "calibrate", "{log}", "--out-dir", "{out}", "--loss", "{loss}"],
    ["batch", "apply", "{params}", "{log}", "--out-dir", "{out}"],
]


@FUZZ
@given(
    data=st.data(),
    command=st.sampled_from(LOG_COMMANDS),
    container=st.sampled_from(LOG_CONTAINERS),
)
def test_random_logs_through_patterns_parquet_report_batch_and_losses(
    documents, tmp_path_factory, data, command, container
):
    log, made = documents
    folder = tmp_path_factory.mktemp("logs")
    good = log.read_text()
    other = good_log(folder, seed=7).read_text()
    texts = [data.draw(st.one_of(st.just(good), st.just(good), tables()))]  # 2 of 3 good
    if container not in ("file", "parquet"):
        texts.append(data.draw(st.one_of(st.just(other), st.just(other), tables())))
    source = _log_source(folder, texts, container)
    params = made_path(folder, made["params"])
    out = folder / "out"
    fields = {
        "log": source,
        "params": params,
        "out": out,
        "loss": data.draw(st.sampled_from(["l2", "huber", "cauchy"])),
        "scale": data.draw(NUMBER_TEXT),
    }
    argv = [part.format(**fields) for part in command]
    written = [Path(a) for a in argv if a.startswith(str(out))]
    for path in written:
        path.write_text("previous")
    status, stdout, _ = run(argv)
    event(f"{argv[0]} {container}: exit {status}")
    for path in written:
        if status:
            assert path.read_text() == "previous"
        elif path.suffix == ".html":  # no non-finite number in its text (figures aside)
            text = re.sub(r"base64,[A-Za-z0-9+/=]+", "", path.read_text())
            assert not re.search(r"\b(nan|inf|infinity)\b", text, re.IGNORECASE)
        else:
            readable(path)
    if status == 0 and "--json" in argv:
        no_null(stdout)
    if argv[0] == "batch" and status in (0, 1) and out.is_dir():
        for path in out.iterdir():
            readable(path)


SCHEDULER_TEXTS = st.one_of(
    st.text(max_size=80),
    JSON_VALUES.map(json.dumps),
    st.builds(
        lambda value: json.dumps({"address": value}),
        st.one_of(
            JSON_VALUES,
            st.sampled_from(
                ["tcp://", "tcp://127.0.0.1:1", "junk://x", "tcp://127.0.0.1:notaport", ""]
            ),
        ),
    ),
)


@FUZZ
@given(text=SCHEDULER_TEXTS, suffix=st.sampled_from([".json", ".txt"]))
def test_random_scheduler_files(documents, tmp_path_factory, text, suffix):
    from unittest import mock

    pytest.importorskip("distributed")
    from nlpcal import cluster

    log, _ = documents
    folder = tmp_path_factory.mktemp("scheduler")
    scheduler = folder / f"scheduler{suffix}"
    scheduler.write_text(text)
    output = folder / "p.json"
    output.write_text("previous")
    with mock.patch.object(cluster, "CONNECT_TIMEOUT_S", 2):
        status, _, _ = run(["calibrate", log, "--scheduler", scheduler, "-o", output])
    assert status == 2 and output.read_text() == "previous"


# --- recorded formats: MotionCal Raw: lines, MATLAB .mat, ArduPilot DataFlash .bin -------------

RAW_CELLS = st.one_of(
    st.integers(min_value=-40000, max_value=40000).map(str),
    st.sampled_from(["", "-", "1.5", "x", "--3", " 7", "1e3", "nan"]),
)
RAW_LINES = st.one_of(
    st.lists(RAW_CELLS, min_size=0, max_size=11).map(lambda cells: "Raw:" + ",".join(cells)),
    st.sampled_from(["Uni:0.1,0.2", "Cal1:1,2", "Cal2:", "Ori:1,2,3", "Raw:", "garbage", ""]),
)


@pytest.fixture(scope="module")
def recorded_samples(tmp_path_factory):
    """Valid bytes of each recorded format, to be cut and mutated."""
    from test_recorders import dataflash_log, write_v5, write_v73

    samples, _ = make_log(n=60, noise=1.0, seed=5)
    folder = tmp_path_factory.mktemp("recorded")
    found = {"bin": dataflash_log([np.rint(samples / 100.0), np.rint(samples / 90.0)])}
    for name, writer in (("v5", write_v5), ("v73", write_v73)):
        writer(folder / f"{name}.mat", {"mag": samples, "t": np.arange(60.0)})
        found[name] = (folder / f"{name}.mat").read_bytes()
    return found


@FUZZ
@given(data=st.data())
def test_garbage_recorded_logs_are_bad_input(recorded_samples, tmp_path_factory, data):
    """Cut or mutated .mat and .bin files and random Raw: lines: exit 0, 1 or 2, one sentence,
    never a traceback."""
    folder = tmp_path_factory.mktemp("recorded_fuzz")
    kind = data.draw(st.sampled_from(["raw", "v5", "v73", "bin"]))
    if kind == "raw":
        lines = data.draw(st.lists(RAW_LINES, min_size=0, max_size=30))
        content = ("\r\n".join(lines) + "\n").encode()
        log = folder / "capture.txt"
        if not any(line.startswith("Raw:") for line in lines):
            content = b"Raw:" + content
    else:
        content = bytearray(recorded_samples[kind])
        cut = data.draw(st.integers(min_value=3, max_value=len(content)))
        for _ in range(data.draw(st.integers(min_value=0, max_value=8))):
            at = data.draw(st.integers(min_value=0, max_value=len(content) - 1))
            content[at] = data.draw(st.integers(min_value=0, max_value=255))
        content = bytes(content[:cut])
        log = folder / ("log.bin" if kind == "bin" else "log.mat")
    log.write_bytes(content)
    event(kind)
    output = folder / "out.json"
    output.write_text("previous")
    extra = ["--instance", "1"] if kind == "bin" and data.draw(st.booleans()) else []
    status, _, _ = run(["calibrate", log, "-o", output, *extra])
    if status:
        assert output.read_text() == "previous"
