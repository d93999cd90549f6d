"""Looking at a calibration: the figure, the self-contained HTML report (rendered in a headless
browser when one is installed), the covariance in results, -q and --version."""

import hashlib
import html
import json
import os
import re
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

import nlpcal
from nlpcal.cli import main
from nlpcal.errors import InputError
from nlpcal.inference import rounded

EXAMPLE = Path(__file__).resolve().parents[1] / "data" / "example_zhou2010.csv"


def _png_size_and_dpi(data: bytes):
    """(width, height, dots per inch) from a PNG's IHDR and pHYs chunks."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    at = data.index(b"pHYs")
    per_metre = struct.unpack(">I", data[at + 4 : at + 8])[0]
    return width, height, per_metre * 0.0254


@pytest.fixture(scope="module")
def params(tmp_path_factory):
    path = tmp_path_factory.mktemp("report") / "params.json"
    assert main(["calibrate", str(EXAMPLE), "--reference-field", "49462", "-o", str(path)]) == 0
    return path


@pytest.mark.slow  # end to end, seconds
def test_calibrate_plot_is_a_lab_notebook_figure(params, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    figure = tmp_path / "fig.png"
    code = main(["calibrate", str(EXAMPLE), "-o", str(tmp_path / "p.json"), "--plot", str(figure)])
    assert code == 0 and f"wrote {figure}" in capsys.readouterr().err
    width, height, dpi = _png_size_and_dpi(figure.read_bytes())
    assert dpi == pytest.approx(150, abs=1) and width >= 2000 and height >= 1200
    applied = tmp_path / "applied.png"
    assert (
        main(
            [
                "apply",
                str(params),
                str(EXAMPLE),
                "-o",
                str(tmp_path / "c.csv"),
                "--plot",
                str(applied),
            ]
        )
        == 0
    )
    assert _png_size_and_dpi(applied.read_bytes())[2] == pytest.approx(150, abs=1)


@pytest.mark.slow  # end to end, seconds
def test_figure_panels_are_labelled_with_units():
    matplotlib = pytest.importorskip("matplotlib")
    from nlpcal.plots import calibration_png
    from nlpcal.report import CalibrationView

    log = nlpcal.read_log(EXAMPLE, reference_field=49462.0)
    result = nlpcal.calibration.calibrate_log(log)
    view = CalibrationView.build(log, result.apply(log.samples), result, "example")
    labels = []
    original = matplotlib.figure.Figure.savefig

    def spy(figure, *args, **kwargs):
        for axes in figure.axes:
            labels.extend([axes.get_xlabel(), axes.get_ylabel()])
        return original(figure, *args, **kwargs)

    matplotlib.figure.Figure.savefig = spy
    try:
        calibration_png(view)
    finally:
        matplotlib.figure.Figure.savefig = original
    assert {"|B_M| [nT]", "|B1| [nT]", "samples", "sample index"} <= set(labels)
    assert "std of |B1|, sqrt(objective) [nT]" in labels and "|B| − F [nT]" in labels
    assert any("[deg]" in label for label in labels)
    rows = view.rows()
    assert rows[1]["std"] < rows[0]["std"] / 100 and "rmse" in rows[1]


@pytest.mark.slow  # end to end, seconds
def test_report_is_one_self_contained_html_file(params, tmp_path, capsys):
    out = tmp_path / "report.html"
    code = main(["report", str(params), str(EXAMPLE), "-o", str(out), "--reference-field", "49462"])
    assert code == 0, capsys.readouterr().err
    text = out.read_text()
    assert text.startswith("<!DOCTYPE html>")
    assert "<script" not in text and not re.search(r"(src|href)=[\"']?(https?:|//)", text)
    sources = re.findall(r"src=\"([^\"]{0,30})", text)
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    digest = hashlib.sha256(EXAMPLE.read_bytes()).hexdigest()
    assert digest in text and hashlib.sha256(params.read_bytes()).hexdigest() in text
    for needle in (
        "Correlations",
        "standard error",
        "alpha_deg",
        "cycle 1",
        "Identifiability",
        "Provenance",
        "Warnings",
        "49462",
        "report",
    ):
        assert needle in text, needle
    document = json.loads(params.read_text())
    value, error = rounded(document["parameters"]["z_x"], document["standard_errors"]["z_x"])
    assert f'<td class="num">{value}</td><td class="num">{error}</td>' in text
    assert "<pre>" not in text and '"mode"' not in text  # no raw JSON
    # the verdict first, then the warnings, then the parameters, then the rest
    order = [
        text.index(k) for k in ('id="verdict"', "<h2>Warnings", "<h2>Parameters", "<h2>Before")
    ]
    assert order == sorted(order)


def _browser():
    """A headless Chromium or Chrome; skips without one, but fails in CI (CI=true), which must
    install it."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if shutil.which(name):
            return shutil.which(name)
    if os.environ.get("CI", "").lower() == "true":
        pytest.fail("CI=true but no headless Chromium is installed (apt-get install chromium)")
    pytest.skip("no headless Chromium or Chrome installed (apt-get install chromium)")


def _browser_flags(tmp_path, width: int, height: int) -> list:
    """Flags of a headless run that stays off the network, in a fresh profile."""
    profile = tmp_path / "profile"
    profile.mkdir(exist_ok=True)
    return [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={profile}",
        f"--window-size={width},{height}",
        "--hide-scrollbars",
    ]


def _screenshot(browser, flags, page, shot):
    """The browser's screenshot of `page` as an image array, checked to be drawn (not blank)."""
    subprocess.run(
        [browser, *flags, f"--screenshot={shot}", page.as_uri()],
        capture_output=True,
        timeout=120,
        check=False,
    )
    image = pytest.importorskip("matplotlib.image").imread(shot)
    assert float(np.std(image[..., :3])) > 0.05  # text and figure drawn, not a blank page
    return image


#: Injected into a copy of a report (the report itself has no script): the page-space box of the
#: verdict banner and of every marked parameter row, written into the DOM for --dump-dom.
MEASURE = """<script>
window.addEventListener("load", () => {
  const box = (e) => { const r = e.getBoundingClientRect();
    return {text: e.innerText.slice(0, 60), top: r.top + scrollY, bottom: r.bottom + scrollY}; };
  const out = document.createElement("pre");
  out.id = "measured";
  out.textContent = JSON.stringify({
    viewport: [innerWidth, innerHeight],
    verdict: box(document.getElementById("verdict")),
    marked: [...document.querySelectorAll("tr.poor, tr.undetermined")].map(box),
  });
  document.body.appendChild(out);
});
</script>"""


def test_report_of_a_poorly_determined_log_shows_the_verdict_on_the_first_screen(
    real_data, tmp_path
):
    """The RM3100 log of the robot data set (15 of 26 direction bins, 8 poorly determined
    parameters): the verdict and every marked parameter lie within the first 1400 x 900 screen."""
    browser = _browser()
    pytest.importorskip("matplotlib")
    log = real_data / "rasteiro_robot_multisensor" / "MPU6050RM3100_derived.csv"
    params, page = tmp_path / "params.json", tmp_path / "report.html"
    assert main(["calibrate", str(log), "-o", str(params), "-q"]) == 0
    document = json.loads(params.read_text())
    assert document["verdict"]["status"] == "poorly_determined"
    poor = document["identifiability"]["poorly_determined"]
    assert len(poor) >= 3
    assert main(["report", str(params), str(log), "-o", str(page), "-q"]) == 0
    probe = tmp_path / "probe.html"
    probe.write_text(page.read_text().replace("</body>", MEASURE + "</body>"))
    flags = _browser_flags(tmp_path, 1400, 900)
    dom = subprocess.run(
        [browser, *flags, "--virtual-time-budget=5000", "--dump-dom", probe.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    found = re.search(r'<pre id="measured">(.*?)</pre>', dom.stdout, re.S)
    assert found, dom.stderr[-2000:]
    measured = json.loads(html.unescape(found.group(1)))
    # the layout's width is the screen's; positions are in the page, from its top
    assert measured["viewport"][0] == 1400
    screen = 900
    assert "POORLY DETERMINED" in measured["verdict"]["text"]
    assert measured["verdict"]["bottom"] <= screen
    marked = [row["text"].split()[0] for row in measured["marked"]]
    assert len(marked) == len(poor)  # one marked row per poorly determined parameter
    assert all(row["bottom"] <= screen for row in measured["marked"]), measured["marked"]
    image = _screenshot(browser, flags, page, tmp_path / "shot.png")
    assert image.shape[:2] == (900, 1400)


@pytest.mark.slow  # end to end, seconds
def test_report_renders_in_a_headless_browser(params, tmp_path):
    browser = _browser()
    pytest.importorskip("matplotlib")
    page = tmp_path / "report.html"
    assert main(["report", str(params), str(EXAMPLE), "-o", str(page), "-q"]) == 0
    flags = _browser_flags(tmp_path, 1200, 1600)
    dom = subprocess.run(
        [browser, *flags, "--dump-dom", page.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert "Correlations" in dom.stdout and "data:image/png;base64," in dom.stdout
    image = _screenshot(browser, flags, page, tmp_path / "shot.png")
    assert image.shape[0] >= 1600 and image.shape[1] >= 1200


def test_covariance_is_stored_and_read_back():
    log = nlpcal.read_log(EXAMPLE)
    result = nlpcal.calibration.calibrate_log(log, method="joint")
    again = nlpcal.CalibrationResult.from_json(result.to_json())
    np.testing.assert_allclose(again.covariance, result.covariance, rtol=1e-15)
    for name, k in zip(result.parameters, range(9)):
        assert np.sqrt(result.covariance[k, k]) == pytest.approx(result.standard_errors[name])
    correlation = again.correlation()
    np.testing.assert_allclose(np.diag(correlation), 1.0)
    # the gauge s_x + s_y + s_z = 0 makes the three scale errors' sum exactly zero
    assert result.covariance[3:6, 3:6].sum() == pytest.approx(
        0.0, abs=1e-6 * result.covariance[3, 3]
    )
    document = result.to_dict()
    del document["covariance"]
    assert nlpcal.CalibrationResult.from_dict(document).covariance is None  # older files
    document["covariance"] = {"parameters": list(result.parameters), "matrix": np.eye(9).tolist()}
    document["covariance"]["matrix"][0][1] = 0.5
    with pytest.raises(InputError, match="symmetric"):
        nlpcal.CalibrationResult.from_dict(document)


def test_quiet_silences_messages_but_not_errors(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main(["-q", "calibrate", str(EXAMPLE), "-o", str(out)]) == 0
    assert capsys.readouterr().err == ""
    assert main(["calibrate", str(EXAMPLE), "-o", str(out), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    assert main(["calibrate", str(tmp_path / "missing.csv"), "-q"]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"nlpcal {nlpcal.__version__}"


def test_the_report_judges_against_the_reference_stored_in_the_parameters(params, tmp_path):
    """Without a reference option the stored constant reference is used, and said to be; with no
    reference anywhere the spread of |B| about its mean is shown as that, not as a reference."""
    stored = tmp_path / "stored.html"
    assert main(["report", str(params), str(EXAMPLE), "-o", str(stored), "-q"]) == 0
    text = stored.read_text()
    assert "the reference stored in the parameters file" in text and "rmse [nT]" in text
    bare = tmp_path / "bare.json"
    assert main(["calibrate", str(EXAMPLE), "-o", str(bare), "-q"]) == 0
    page = tmp_path / "bare.html"
    assert main(["report", str(bare), str(EXAMPLE), "-o", str(page), "-q"]) == 0
    # the page's words, without its embedded figures (base64 can spell any four letters)
    text = re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", page.read_text())
    assert "rmse" not in text and "spread of |B| about its mean" in text
    assert "Note: no reference field" in text


def test_a_long_table_1_is_folded_after_its_first_rows():
    from nlpcal.report.html import TABLE_ROWS, _folded

    rows = [{"label": f"cycle {k}", "mean": 1.0, "std": 0.1} for k in range(40)]
    text = _folded(rows, "nT")
    head, tail = text.split("<details>")
    assert head.count("<tr>") == TABLE_ROWS + 1 and tail.count("<tr>") == 40 - TABLE_ROWS + 1
    assert "<details>" not in _folded(rows[:TABLE_ROWS], "nT")


def test_the_report_reads_the_reference_column_the_calibration_used(tmp_path, capsys):
    from synthetic import PAPER_FIELD, make_log

    samples, _ = make_log(n=1500, noise=1.0, seed=4)
    field = PAPER_FIELD + np.random.default_rng(4).normal(0.0, 0.5, len(samples))
    log = tmp_path / "log.csv"
    np.savetxt(
        log, np.column_stack([samples, field]), delimiter=",", header="bx,by,bz,F", comments=""
    )
    params, page = tmp_path / "p.json", tmp_path / "r.html"
    assert main(["calibrate", str(log), "--reference-column", "F", "-o", str(params), "-q"]) == 0
    assert main(["report", str(params), str(log), "-o", str(page)]) == 0
    assert "reference column 'F'" in capsys.readouterr().err
    assert "rmse [nT]" in page.read_text() and "F_i, given to this report" in page.read_text()
