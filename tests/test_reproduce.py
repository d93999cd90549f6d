"""`nlpcal reproduce PAPER`: every published number beside nlpcal's, with a verdict that is real.

Each paper runs once through the command line (module fixture, seconds each); the verdict logic is
tested on its own and by perturbing a published number end to end.
"""

import contextlib
import io
import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from nlpcal.cli import main
from nlpcal.models import wang2015 as wang_model
from nlpcal.reproduce import PAPERS, wang2015
from nlpcal.reproduce.values import Reproduction, Value, half_unit

DOCS = Path(__file__).resolve().parents[1] / "docs"
#: Every number each paper publishes, as printed, that its table must show.
PUBLISHED = {
    "zhou2010": [
        "50776", "48147", "49506", "744.38", "2629.30", "53.06", "219.55", "16.29", "115.08",
        "-71.55", "188.13", "116.29", "0.0072", "-0.0024", "-0.0049", "-2.34", "1.29", "-0.27",
    ],
    "wang2015": ["95", "3.8", "0.004", "0.07", "0.04", "0.1", "0.064", "0.103"],
    "liu2022": [
        "7.0805", "50906", "0.0113", "891.43", "15.50", "2.76", "1064.70", "41.25", "9.40",
    ],
    "qiu2017": ["0.15", "0.5"],
}  # fmt: skip


def run(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Each paper through the command line, once: (status, stdout, stderr, output folder).
    capsys is per test, so the streams are captured here by hand."""
    results = {}
    for paper in PAPERS:
        folder = tmp_path_factory.mktemp(paper) / "out"
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main(["reproduce", paper, "-o", str(folder)])
        results[paper] = (status, out.getvalue(), err.getvalue(), folder)
    return results


@pytest.mark.slow  # four papers end to end, about 12 s together
@pytest.mark.parametrize("paper", list(PAPERS))
def test_every_paper_reproduces_with_its_numbers_side_by_side(runs, paper):
    status, out, err, folder = runs[paper]
    assert status == 0, err
    rows = [line for line in out.splitlines() if line.endswith(("matches", ")"))]
    for printed in PUBLISHED[paper]:  # each published number, as the paper prints it, in a row
        assert any(f" {printed} " in f" {row} " for row in rows), printed
    document = json.loads((folder / f"{paper}.json").read_text())
    assert document["format"] == "nlpcal-reproduction" and document["paper"] == paper
    assert len(document["values"]) >= len(PUBLISHED[paper])
    assert document["counts"]["unexplained"] == 0
    assert sum(document["counts"].values()) == len(document["values"])
    for value in document["values"]:  # a verdict for every number, a cause for each difference
        assert value["verdict"] in ("matches", "differs")
        assert (value["verdict"] == "differs") == ("cause" in value)
    assert (folder / f"{paper}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"{len(document['values'])} published numbers" in err


@pytest.mark.slow
def test_the_values_that_must_agree_do(runs):
    """The numbers a replica is built from come back: Zhou's final parameters, Wang's synthetic
    angles and probe means, Liu's slope; Qiu's bounds hold where the accelerometer's noise is not
    amplified by a steep pitch."""
    must = {
        "zhou2010": [f"final parameter {name}" for name in ("z_x", "s_y", "alpha_deg")],
        "wang2015": ["synthetic inversion, noiseless, alpha", "probe, mean of 5 runs, gamma"],
        "liu2022": ["Eq. 1 slope a"],
        "qiu2017": ["largest heading error, |pitch| 0-60 deg"],
    }
    for paper, quantities in must.items():
        document = json.loads((runs[paper][3] / f"{paper}.json").read_text())
        verdicts = {v["quantity"]: v["verdict"] for v in document["values"]}
        for quantity in quantities:
            found = [q for q in verdicts if q.startswith(quantity)]
            assert found and all(verdicts[q] == "matches" for q in found), (paper, quantity)


def test_a_verdict_follows_the_printed_digits_and_the_standard_error():
    assert half_unit(2) == pytest.approx(0.005)
    assert half_unit(0) == pytest.approx(0.5)
    assert half_unit(4) == pytest.approx(0.00005)
    assert Value("range", "nT", 115.6, 2, 115.6).printed == "115.60"
    assert Value("std", "nT", 16.29, 2, 16.294).verdict == "matches"
    assert Value("std", "nT", 16.29, 2, 16.296).verdict == "unexplained"
    assert Value("std", "nT", 16.29, 2, 16.296, cause="the replica").verdict == "differs"
    # three standard errors widen it
    assert Value("z_x", "nT", -71.55, 2, -71.80, standard_error=0.1).verdict == "matches"
    assert Value("z_x", "nT", -71.55, 2, -71.90, standard_error=0.1).verdict == "unexplained"
    # a bound: anything at or below it matches, above it does not
    assert Value("roll", "deg", 0.15, 2, -3.0, bound=True).verdict == "matches"
    assert Value("roll", "deg", 0.15, 2, 0.154, bound=True).verdict == "matches"
    assert Value("roll", "deg", 0.15, 2, 0.156, bound=True).verdict == "unexplained"
    assert Value("roll", "deg", 0.15, 2, float("nan"), cause="x").verdict == "unexplained"


def test_a_perturbed_published_number_flips_its_verdict():
    reproduction = wang2015.reproduce()
    assert reproduction.ok
    values = reproduction.values
    k = next(i for i, v in enumerate(values) if v.verdict == "matches" and v.cause is None)
    flipped = replace(values[k], paper=values[k].paper + 3 * values[k].tolerance)
    assert flipped.verdict == "unexplained"
    changed = Reproduction(**{**reproduction.__dict__, "values": [*values[:k], flipped]})
    assert not changed.ok and changed.counts()["unexplained"] == 1
    # and a difference whose cause is taken away is no longer explained
    d = next(v for v in values if v.verdict == "differs")
    assert replace(d, cause=None).verdict == "unexplained"


def test_an_unexplained_difference_exits_1_and_writes_nothing(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(wang_model, "PAPER_IMPLIED_NT", 4.8)  # the paper's 3.8 nT, perturbed
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "wang2015.json").write_text("kept")
    status, out, err = run(capsys, "reproduce", "wang2015", "-o", folder)
    assert status == 1
    assert "4.8" in out and "unexplained" in out  # the table still shows why
    assert "no stated cause" in err
    assert (folder / "wang2015.json").read_text() == "kept"
    assert sorted(p.name for p in folder.iterdir()) == ["wang2015.json"]
    status, _, _ = run(capsys, "reproduce", "wang2015", "-o", tmp_path / "new")
    assert status == 1 and not (tmp_path / "new").exists()  # no folder made for nothing


def test_bad_paper_and_bad_folder_exit_2_with_a_sentence(capsys, tmp_path):
    status, out, err = run(capsys, "reproduce", "zhou2011")
    assert status == 2 and out == ""
    assert "zhou2011" in err and "zhou2010" in err and "Traceback" not in err
    afile = tmp_path / "table.txt"
    afile.write_text("mine")
    status, out, err = run(capsys, "reproduce", "wang2015", "-o", afile)
    assert status == 2 and out == "" and "not a folder" in err
    assert afile.read_text() == "mine"
    status, out, err = run(capsys, "reproduce", "wang2015", "-o", tmp_path / "no" / "dir")
    assert status == 2 and out == "" and not (tmp_path / "no").exists()


def test_an_existing_folder_keeps_its_other_files_and_json_goes_to_stdout(
    capsys, tmp_path, monkeypatch
):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as without the plot extra
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    (folder / "wang2015.json").write_text("old")
    status, out, err = run(capsys, "reproduce", "wang2015", "-o", folder, "--json")
    assert status == 0, err
    document = json.loads(out)
    assert document["paper"] == "wang2015"
    assert json.loads((folder / "wang2015.json").read_text()) == document
    assert (folder / "notes.txt").read_text() == "mine"
    assert "figure skipped" in err and "pip install 'nlpcal[plot]'" in err
    assert not (folder / "wang2015.png").exists()
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt", "wang2015.json"]


def test_the_help_names_every_paper(capsys):
    from nlpcal.cli.reproduce import PAPER_NAMES

    assert tuple(PAPERS) == PAPER_NAMES
    assert main(["reproduce", "--help"]) == 0
    text = capsys.readouterr().out
    for paper in PAPERS:
        assert paper in text
    assert main(["--help"]) == 0
    assert "reproduce" in capsys.readouterr().out


@pytest.mark.slow  # the four papers again, about 6 s
def test_the_docs_pages_hold_the_reproductions(capsys):
    """The `reproduce` block of each paper's page is the command's table, at the printed
    resolution (docs/generated.py): the pages are generated from the package."""
    sys.path.insert(0, str(DOCS))
    try:
        from reproduce import main as check_docs
    finally:
        sys.path.remove(str(DOCS))
    assert check_docs(["--check"]) == 0, capsys.readouterr().err
