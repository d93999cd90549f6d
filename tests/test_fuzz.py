"""Hostile input through the whole command line: random tables, random and mutated documents,
output faults. Whatever comes in, nlpcal exits 0, 1 or 2 with a one-sentence message, never a
traceback, never changes an existing output when it fails, and writes only finite numbers.

NLPCAL_FUZZ_EXAMPLES sets the number of examples per test (default 25; a corpus run uses
thousands, and NLPCAL_FUZZ_RANDOM=1 draws new examples each run).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from nlpcal.cli import main
from synthetic import PAPER_FIELD, make_log

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
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
        no_nan(output.read_text())
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
        finite_csv(output)
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
        no_nan(out)


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
