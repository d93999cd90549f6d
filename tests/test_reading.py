"""Reading logs as people write them: any delimiter, header or not, columns by position, stdin,
binary files refused, units checked, rows that are not readings, and logs written back as read."""

import io
import json
import re
import sys

import numpy as np
import pandas as pd
import pytest

import nlpcal
from nlpcal import units
from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.io import read_columns, read_log, read_sensor_log, read_table
from synthetic import make_log

SAMPLES, _ = make_log(n=400, noise=1.0, seed=41)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def lines(samples, delimiter=",", decimal=".", fmt="{:.4f}"):
    rows = []
    for row in samples:
        cells = [fmt.format(v) for v in row]
        if decimal == ",":
            cells = [c.replace(".", ",") for c in cells]
        rows.append(delimiter.join(cells))
    return rows


# --- layouts --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, text",
    [
        ("comma.csv", "bx,by,bz\n" + "\n".join(lines(SAMPLES)) + "\n"),
        ("semicolon.csv", "bx;by;bz\n" + "\n".join(lines(SAMPLES, ";")) + "\n"),
        ("decimal_comma.csv", "bx;by;bz\n" + "\n".join(lines(SAMPLES, ";", ",")) + "\n"),
        ("tab.tsv", "bx\tby\tbz\n" + "\n".join(lines(SAMPLES, "\t", ",")) + "\n"),
        ("spaces.txt", "\n".join(lines(SAMPLES, "   ")) + "\n"),
        ("crlf_comments.txt", "# logger v2\r\n# x y z\r\n" + "\r\n".join(lines(SAMPLES, " "))),
        ("comma_space.csv", "bx, by, bz\n" + "\n".join(lines(SAMPLES, ", ")) + "\n"),
    ],
)
def test_every_layout_gives_the_same_samples(tmp_path, name, text):
    path = tmp_path / name
    path.write_bytes(text.encode())  # the line endings as given
    log = read_log(path)
    np.testing.assert_allclose(log.samples, np.round(SAMPLES, 4), atol=1e-9)
    assert log.n == len(SAMPLES)


def test_a_header_row_is_detected_and_can_be_forced(tmp_path):
    path = tmp_path / "h.csv"
    path.write_text("bx,by,bz\n" + "\n".join(lines(SAMPLES[:50])) + "\n")
    assert read_table(path).layout.header
    bare = tmp_path / "n.csv"
    bare.write_text("\n".join(lines(SAMPLES[:50])) + "\n")
    table = read_table(bare)
    assert not table.layout.header and table.columns == ["0", "1", "2"]
    # --header takes the first line as names even when it is numeric
    forced = read_table(bare, header=True)
    assert forced.layout.header and len(forced.frame) == 49
    # --no-header on a file with names: the names become a non-numeric row
    with pytest.raises(InputError, match="non-numeric"):
        read_log(path, header=False)


def test_a_leading_time_column_is_recognised_without_a_header(tmp_path):
    t = 1711531763.0 + 0.066 * np.arange(len(SAMPLES))
    path = tmp_path / "timed.csv"
    path.write_text("\n".join(f"{ti:.6f}," + row for ti, row in zip(t, lines(SAMPLES))) + "\n")
    log = read_log(path)
    assert log.columns == ["1", "2", "3"]
    assert any("read as time" in note for note in log.notes)
    np.testing.assert_allclose(log.samples, np.round(SAMPLES, 4))


def test_columns_by_0_based_position_and_messages_that_list_them(tmp_path):
    frame = pd.DataFrame(SAMPLES, columns=["a", "b", "c"])
    frame.insert(0, "time", np.arange(len(frame)))
    path = tmp_path / "abc.csv"
    frame.to_csv(path, index=False)
    with pytest.raises(InputError) as failure:
        read_log(path)
    assert "0 time, 1 a, 2 b, 3 c" in str(failure.value) and "positions" in str(failure.value)
    log = read_log(path, columns=["1", "2", "3"])
    assert log.columns == ["a", "b", "c"]
    assert read_log(path, columns=["A", "b", "3"]).columns == ["a", "b", "c"]
    with pytest.raises(InputError, match="'7' is out of range"):
        read_log(path, columns=["1", "2", "7"])
    np.testing.assert_allclose(read_columns(path, [0, "a"])[:, 1], SAMPLES[:, 0])


def test_a_headerless_file_with_many_columns_asks_for_positions(tmp_path):
    path = tmp_path / "six.txt"
    wide = np.hstack([SAMPLES, SAMPLES[::-1]])
    path.write_text("\n".join(lines(wide, " ")) + "\n")
    with pytest.raises(InputError, match="--columns 3 4 5"):
        read_log(path)
    assert read_log(path, columns=[3, 4, 5]).columns == ["3", "4", "5"]


def test_stdin_is_read_with_a_dash(tmp_path, capsys, monkeypatch):
    text = "\n".join(lines(SAMPLES, " ")) + "\n"
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(text.encode())))
    code, out, err = run(capsys, "stats", "-", "--json")
    assert code == 0, err
    rows = json.loads(out)["rows"]
    assert rows[0]["mean"] == pytest.approx(np.linalg.norm(SAMPLES, axis=1).mean(), rel=1e-6)


def test_stdin_streams_into_a_memory_map_too(monkeypatch):
    text = "bx,by,bz\n" + "\n".join(lines(SAMPLES)) + "\n"
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(text.encode())))
    log = read_log("-", low_memory=True)
    assert log.path == "stdin"
    np.testing.assert_allclose(log.samples, np.round(SAMPLES, 4))


@pytest.mark.parametrize(
    "name, head, what",
    [
        ("log.h5", b"\x89HDF\r\n\x1a\n\x00\x00\x00" * 50, "an HDF5 file"),
        ("magnetom.float", np.arange(30, dtype=">f4").tobytes(), "a binary file"),
    ],
)
def test_binary_files_are_refused_in_one_printable_sentence(tmp_path, capsys, name, head, what):
    path = tmp_path / name
    path.write_bytes(head)
    code, out, err = run(capsys, "calibrate", path)
    assert code == 2 and out == ""
    assert what in err and "delimited text log" in err
    assert err.isprintable() or all(line.isprintable() for line in err.splitlines())
    assert len(err.strip().splitlines()) == 1


def test_a_broken_parquet_file_is_refused_in_one_printable_sentence(tmp_path, capsys):
    pytest.importorskip("pyarrow", reason="pyarrow (the 'parquet' extra) reads Parquet")
    path = tmp_path / "log.parquet"
    path.write_bytes(b"PAR1\x15\x04\x15\x80\x01\x00\xff\xfe" * 50)
    code, out, err = run(capsys, "calibrate", path)
    assert code == 2 and out == "" and "cannot be read as Parquet" in err
    assert err.isprintable() or all(line.isprintable() for line in err.splitlines())
    assert len(err.strip().splitlines()) == 1


def test_ragged_and_empty_files_say_what_is_wrong(tmp_path):
    ragged = tmp_path / "ragged.csv"
    ragged.write_text("a\nb,c\nd;e;f;g\n")
    with pytest.raises(InputError, match="cannot tell how the columns are separated"):
        read_log(ragged)
    comments = tmp_path / "comments.csv"
    comments.write_text("# only a comment\n\n")
    with pytest.raises(InputError, match="empty"):
        read_log(comments)


# --- units ----------------------------------------------------------------------------------


def write(tmp_path, name, samples, columns=("x", "y", "z")):
    path = tmp_path / name
    pd.DataFrame(samples, columns=list(columns)).to_csv(path, index=False)
    return path


def test_gauss_and_counts_read_as_nt_are_warned_about(tmp_path):
    gauss = write(tmp_path, "gauss.csv", SAMPLES / 1e5)
    log = read_log(gauss)
    assert len(log.warnings) == 1
    warning = log.warnings[0]
    assert "assumed" in warning and "--unit G" in warning and "raw counts" in warning
    # an assumed unit the magnitudes rule out is not kept: the numbers are counts
    assert (log.unit, log.unit_source) == ("raw", "assumed")
    np.testing.assert_array_equal(log.samples, pd.read_csv(gauss).to_numpy())
    # the unit that fits is quiet
    given = read_log(gauss, unit="G")
    assert given.warnings == [] and (given.unit, given.unit_source) == ("G", "option")
    counts = write(tmp_path, "counts.csv", np.round(SAMPLES / 100.0))
    assert "kept as raw counts" in read_log(counts).warnings[0]
    assert read_log(counts, unit="raw").warnings == []
    # a unit given or carried by the names is kept, with the warning
    named = write(tmp_path, "named.csv", SAMPLES / 1e5, ("mx_nT", "my_nT", "mz_nT"))
    log = read_log(named)
    assert (log.unit, log.unit_source) == ("nT", "names") and "--unit G" in log.warnings[0]
    assert read_log(gauss, unit="nT").unit == "nT"


def test_a_format_that_fixes_the_unit_is_recorded_as_the_source(tmp_path):
    table = read_table(write(tmp_path, "ros.csv", SAMPLES / 1e9, ("mx_G", "my_G", "mz_G")))
    table.field_unit = "T"  # what a reader of ROS sensor_msgs/MagneticField declares
    log = read_log(table)
    assert (log.unit, log.unit_source, log.warnings) == ("T", "format", [])
    assert "format fixes T" in " ".join(log.notes)
    np.testing.assert_allclose(log.samples, SAMPLES)
    assert read_log(table, unit="nT").unit_source == "option"  # the option still wins


def test_an_explicit_unit_wins_but_a_wrong_one_is_still_warned_about(tmp_path):
    path = write(tmp_path, "ut.csv", SAMPLES / 1e3)
    log = read_log(path, unit="nT")
    assert log.unit == "nT"
    assert "as given (--unit nT)" in log.warnings[0] and "--unit uT" in log.warnings[0]
    assert "the unit given is used" in log.warnings[0]
    named = write(tmp_path, "named.csv", SAMPLES, ("mx_uT", "my_uT", "mz_uT"))
    assert "as the column names say (uT)" in read_log(named).warnings[0]


def test_hard_iron_larger_than_the_field_is_not_a_unit_mistake(tmp_path):
    # An RM3100-like offset of 110 uT: the median |B| is 2.5 times Earth's, but the sphere fitted
    # to the samples has the field's radius.
    path = write(tmp_path, "iron.csv", (SAMPLES + [0.0, 0.0, 110_000.0]) / 1e3)
    assert read_log(path, unit="uT").warnings == []


def test_the_compass_reads_units_from_names_and_checks_both_sensors(tmp_path):
    rng = np.random.default_rng(3)
    acc = rng.standard_normal((len(SAMPLES), 3))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    frame = pd.DataFrame(
        np.hstack([SAMPLES / 1e3, acc * 9.80665]),
        columns=["mx_uT", "my_uT", "mz_uT", "ax", "ay", "az"],
    )
    path = tmp_path / "compass.csv"
    frame.to_csv(path, index=False)
    log = read_sensor_log(path)
    assert log.mag_unit == "uT"
    np.testing.assert_allclose(log.mag, SAMPLES)
    assert len(log.warnings) == 1 and "--acc-unit m/s2" in log.warnings[0]
    assert read_sensor_log(path, acc_unit="m/s2").warnings == []


def test_the_unit_warning_reads_well():
    message = units.unit_warning([0.55, 0.31], "nT", "assumed")
    assert "0.550 nT" in message and "55 000 nT in G (--unit G)" in message
    assert "22 000 to 67 000 nT" in message
    assert units.unit_warning([48_000.0], "nT", "assumed") is None
    assert units.unit_warning([300.0], "raw", "given") is None


# --- rows -----------------------------------------------------------------------------------


def test_zero_vectors_are_left_out_and_repeats_reported(tmp_path):
    samples = np.vstack([np.zeros(3), SAMPLES, np.repeat(SAMPLES[-1:], 30, axis=0)])
    path = write(tmp_path, "rows.csv", samples)
    log = read_log(path)
    assert log.n == len(SAMPLES) + 30
    assert log.dropped == 1 and not log.kept[0]
    text = " ".join(log.notes)
    assert "(0, 0, 0) (data row 1)" in text
    assert "30 of 431 rows" in text and "31 identical readings" in text
    dropped = read_log(path, drop_invalid=True)
    assert dropped.n == len(SAMPLES) and dropped.dropped == 31
    assert any("dropped the repeats" in note for note in dropped.notes)
    mapped = read_log(path, drop_invalid=True, low_memory=True)
    np.testing.assert_array_equal(np.asarray(mapped.samples), dropped.samples)
    assert mapped.dropped == 31


def test_repeats_are_counted_across_chunks(tmp_path):
    from nlpcal.io import csv_to_memmap

    samples = np.repeat(SAMPLES[:20], 7, axis=0)  # every reading 7 times in a row
    samples[70:84] = samples[70]  # and one stuck stretch of 14 across chunk edges
    path = write(tmp_path, "oversampled.csv", samples)
    whole = " ".join(read_log(path).notes)
    for chunk_rows in (9, 13, 1000):
        mapped = " ".join(csv_to_memmap(path, chunk_rows=chunk_rows).notes)
        assert mapped == whole
    assert "121 of 140 rows" in whole and "14 identical readings from data row 71" in whole


# --- writing back ---------------------------------------------------------------------------


def test_apply_writes_the_log_back_in_its_own_layout(tmp_path, capsys):
    log = tmp_path / "log.csv"
    pd.DataFrame(SAMPLES, columns=["bx", "by", "bz"]).to_csv(log, index=False)
    params = tmp_path / "p.json"
    assert main(["calibrate", str(log), "--method", "joint", "-o", str(params), "-q"]) == 0
    capsys.readouterr()
    rows = [
        f"{k * 0.5:.2f}".replace(".", ",") + f";{cells};lab {k};0{k % 3}"
        for k, cells in enumerate(lines(SAMPLES, ";", ",", "{:.3f}"))
    ]
    text = "# field log\r\n# units nT\r\n" + "\r\n".join(rows) + "\r\n"
    source = tmp_path / "semi.txt"
    source.write_bytes(text.encode())
    out = tmp_path / "out.txt"
    code, _, err = run(capsys, "apply", params, source, "--columns", "1", "2", "3", "-o", out)
    assert code == 0, err
    written = out.read_bytes().decode()
    assert written.startswith("# field log\r\n# units nT\r\n")
    body = written.splitlines()[2:]
    assert len(body) == len(SAMPLES)
    for original, new in zip(rows, body):
        before, after = original.split(";"), new.split(";")
        assert len(after) == len(before) + 2  # b_total and valid appended, no header added
        assert after[0] == before[0] and after[4:6] == before[4:6]  # text untouched ("00")
        assert "," in after[1] and "." not in after[1]  # decimal comma kept
    assert all(line.split(";")[-1] == "1" for line in body)
    total = np.array([float(line.split(";")[-2].replace(",", ".")) for line in body])
    assert total.std() < 0.05 * np.linalg.norm(SAMPLES, axis=1).std()


def test_apply_keeps_whitespace_and_headerless_logs_as_they_were(tmp_path, capsys):
    log = tmp_path / "mag.txt"
    log.write_text("\n".join(lines(SAMPLES, " ")) + "\n")
    params = tmp_path / "p.json"
    assert main(["calibrate", str(log), "--method", "joint", "-q", "-o", str(params)]) == 0
    code, out, err = run(capsys, "apply", params, log)
    assert code == 0, err
    first = out.splitlines()[0].split(" ")
    assert len(first) == 5 and all(float(v) for v in first[:4]) and first[4] == "1"


# --- the command line -----------------------------------------------------------------------


def test_quiet_and_verbose(tmp_path, capsys):
    path = write(tmp_path, "g.csv", SAMPLES / 1e5)
    code, _, err = run(capsys, "stats", path)
    assert code == 0 and "nlpcal: warning: read in nT" in err
    code, _, err = run(capsys, "stats", path, "-q")
    assert code == 0 and err == ""
    code, _, err = run(capsys, "-q", "calibrate", path, "--unit", "G", "-o", tmp_path / "p.json")
    assert code == 0 and "measured" not in err and "wrote" not in err
    code, _, err = run(capsys, "stats", path, "--unit", "G", "-v")
    assert code == 0 and "comma-separated, with a header row" in err
    code, _, err = run(capsys, "stats", path, "-q", "-v")
    assert code == 2 and "not allowed with" in err


@pytest.mark.slow  # end to end, seconds
def test_allow_unidentifiable_writes_the_result_with_its_warning(tmp_path, capsys):
    # The field only ever within 32 deg of -z, with much noise: the offsets trade off against the
    # radius of a far-away sphere, and the staged cycle walks along that valley.
    from synthetic import uniform_directions

    directions = uniform_directions(40000, np.random.default_rng(1))
    directions = directions[directions[:, 2] < -0.85][:1500]
    samples, _ = make_log(n=len(directions), noise=800.0, seed=2, directions=directions)
    path = write(tmp_path, "cap.csv", samples, ("bx", "by", "bz"))
    out = tmp_path / "p.json"
    code, _, err = run(capsys, "calibrate", path, "-o", out)
    assert code == 1 and not out.exists()
    assert "quality check failed: " in err and "do not determine" in err and "z_x" in err
    assert "never pointed along +x, -x, +y, -y, +z" in err  # -z is the direction it did see
    assert "--allow-unidentifiable" in err
    allow = ["--allow-unidentifiable", "--allow-unconverged"]  # the cycle wanders, too
    code, _, err = run(capsys, "calibrate", path, *allow, "-o", out)
    assert code == 0, err
    document = json.loads(out.read_text())
    assert {"z_x", "z_z"} <= set(document["identifiability"]["not_identifiable"])
    assert any(w.startswith("not identifiable") for w in document["warnings"])
    # written anyway, it still says it failed, first on the terminal and in the file
    assert document["verdict"]["status"] == "failed"
    assert any("do not determine" in r and "z_x" in r for r in document["verdict"]["reasons"])
    assert err.startswith("nlpcal: verdict: FAILED") or "\nnlpcal: verdict: FAILED" in err
    assert nlpcal.CalibrationResult.load(out).verdict.status == "failed"  # recomputed on reading


def test_poorly_determined_states_the_standard_error_and_its_limit(tmp_path):
    from nlpcal import calibrate

    samples, _ = make_log(n=60, noise=2000.0, seed=5)  # 4 % noise on 60 samples
    result = calibrate(samples, method="joint")
    warning = next(w for w in result.warnings if w.startswith("poorly determined"))
    name = result.identifiability["poorly_determined"][0]
    limit = result.identifiability["poorly_determined_limits"][name]
    assert f"{name} ± " in warning and "limit" in warning
    assert result.standard_errors[name] > limit
    assert "a steadier field" in warning and "--reference-field" in warning
    verdict = result.verdict
    assert verdict.status == "poorly_determined" and name in verdict.reasons[0]
    assert verdict.line().startswith("POORLY DETERMINED: ") and warning in verdict.reasons


def test_small_numbers_keep_their_digits_in_the_table():
    from nlpcal.statistics import format_table

    rows = [
        {"label": "measured", "max": 0.73, "min": 0.12, "mean": 0.547, "std": 0.1747, "range": 0.61}
    ]
    assert "0.17470" in format_table(rows, "G")
    rows[0].update(mean=49460.0, std=0.99)
    assert "       0.99" in format_table(rows, "nT")


def test_a_long_table_shows_its_first_a_few_and_its_last_rows():
    from nlpcal.statistics import format_table

    rows = [{"label": f"cycle {k}", "mean": 1e4, "std": 1.0 / (k + 1)} for k in range(300)]
    text = format_table(rows, "nT", most=10)
    shown = [line.split()[1] for line in text.splitlines() if line.startswith("cycle ")]
    assert shown[:3] == ["0", "1", "2"] and shown[-2:] == ["298", "299"] and len(shown) <= 10
    skipped = [int(n) for n in re.findall(r"\((\d+) rows? not shown\)", text)]
    assert sum(skipped) + len(shown) == 300
    assert format_table(rows, "nT").count("\ncycle ") == 300  # all of them without a limit


def test_a_bad_value_is_placed_alike_in_memory_and_in_chunks(tmp_path):
    from nlpcal.io import csv_to_memmap

    samples, _ = make_log(n=1000, noise=1.0, seed=42)
    rows = ["bx,by,bz"] + [",".join(f"{v:.4f}" for v in row) for row in samples]
    rows[701] = "1,,3"
    path = tmp_path / "gap.csv"
    path.write_text("\n".join(rows) + "\n")
    for read in (lambda: read_log(path), lambda: csv_to_memmap(path, chunk_rows=300)):
        with pytest.raises(InputError, match="first at data row 701\\)"):
            read()


@pytest.mark.parametrize("drop_repeats", [False, True])
def test_a_row_screen_says_the_same_chunk_by_chunk_as_over_the_whole(drop_repeats):
    from nlpcal.io.rows import RowScreen

    field = np.random.default_rng(3).normal(size=(200, 3))
    field[[5, 6, 77, 140]] = 0.0  # zero vectors, two of them in a row
    field[20:34] = field[19]  # a run of 15 identical readings across the chunks' boundary
    field[100:103] = field[99]
    rows = np.arange(1, 201)
    whole = RowScreen(drop_repeats)
    kept = whole.keep(field)  # rows numbered 1 to N
    chunked = RowScreen(drop_repeats)
    parts = [chunked.keep(field[k : k + 30], rows[k : k + 30]) for k in range(0, 200, 30)]
    np.testing.assert_array_equal(np.concatenate(parts), kept)
    assert whole.notes() == chunked.notes()
    assert (whole.zeros, whole.zero_rows, whole.repeats) == (4, [6, 7, 78, 141], 17)
    assert (whole.longest + 1, whole.longest_at) == (15, 20)
    assert kept.sum() == 200 - 4 - (17 if drop_repeats else 0)


def test_files_of_one_size_are_read_whole_only_when_their_ends_are_the_same(tmp_path, monkeypatch):
    from nlpcal.io import sources

    monkeypatch.setattr(sources, "ENDS_BYTES", 64)
    rows = [f"{k},{2 * k},{3 * k}" for k in range(100, 200)]  # fixed width: one size
    texts = {
        "a.csv": rows,
        "b.csv": rows[:50] + [rows[50].replace("1", "7")] + rows[51:],  # the middle differs
        "c.csv": rows[:-1] + [rows[-1].replace("1", "9")],  # the end differs
    }
    for name, lines in texts.items():
        (tmp_path / name).write_text("bx,by,bz\n" + "\n".join(lines) + "\n")
    hashed = []
    original = sources.sha256_file
    monkeypatch.setattr(sources, "sha256_file", lambda path: hashed.append(path) or original(path))
    paths = sorted(tmp_path.glob("*.csv"))
    assert len({p.stat().st_size for p in paths}) == 1
    assert sources.distinct_files(paths) == paths  # none the same, although a and b nearly
    assert sorted(p.name for p in hashed) == ["a.csv", "b.csv"]  # c's end tells it apart
    (tmp_path / "copy.csv").write_bytes((tmp_path / "a.csv").read_bytes())
    with pytest.raises(InputError, match="same content"):
        sources.distinct_files(sorted(tmp_path.glob("*.csv")))
