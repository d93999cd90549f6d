"""Looking at a calibration: the figure, the self-contained HTML report (rendered in a headless
browser when one is installed), the covariance in results, -q and --version."""

import hashlib
import json
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
    assert f"{document['parameters']['z_x']:.10g}" in text


def _browser():
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if shutil.which(name):
            return shutil.which(name)
    return None


@pytest.mark.slow  # end to end, seconds
def test_report_renders_in_a_headless_browser(params, tmp_path):
    browser = _browser()
    if browser is None:
        pytest.skip("no headless Chromium or Chrome installed")
    pytest.importorskip("matplotlib")
    page = tmp_path / "report.html"
    assert main(["report", str(params), str(EXAMPLE), "-o", str(page), "-q"]) == 0
    shot = tmp_path / "shot.png"
    flags = ["--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1200,1600"]
    dom = subprocess.run(
        [browser, *flags, "--dump-dom", page.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert "Correlations" in dom.stdout and "data:image/png;base64," in dom.stdout
    subprocess.run(
        [browser, *flags, f"--screenshot={shot}", page.as_uri()],
        capture_output=True,
        timeout=120,
        check=False,
    )
    image = pytest.importorskip("matplotlib.image").imread(shot)
    assert image.shape[0] >= 1600 and image.shape[1] >= 1200
    assert float(np.std(image[..., :3])) > 0.05  # text and figure drawn, not a blank page


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
