"""The calibration figure stays legible: no two tick labels overlap at any N, no empty axes, the
26 direction bins drawn, time on the x axis, the verdict and the parameters in the title."""

from __future__ import annotations

import numpy as np
import pytest

import nlpcal
from synthetic import PAPER_FIELD, make_log

matplotlib = pytest.importorskip("matplotlib")
pytest.importorskip("matplotlib.figure")

from nlpcal.plots import calibration_png  # noqa: E402
from nlpcal.report import CalibrationView  # noqa: E402


def _drawn(view):
    """The figure calibration_png draws for `view`, caught as it is saved."""
    caught = []
    original = matplotlib.figure.Figure.savefig

    def spy(figure, *args, **kwargs):
        caught.append(figure)
        return original(figure, *args, **kwargs)

    matplotlib.figure.Figure.savefig = spy
    try:
        calibration_png(view, dpi=100)
    finally:
        matplotlib.figure.Figure.savefig = original
    return caught[0]


def _overlaps(figure) -> list:
    """Every pair of tick labels on one axis whose boxes on the drawn canvas touch."""
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    found = []
    for axes in figure.axes:
        for axis in (axes.xaxis, axes.yaxis):
            labels = [t for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
            boxes = [t.get_window_extent(renderer) for t in labels]
            for i in range(len(boxes)):
                for j in range(i + 1, len(boxes)):
                    if boxes[i].overlaps(boxes[j]):
                        found.append((axes.get_title(), labels[i].get_text(), labels[j].get_text()))
    return found


def _empty_axes(figure) -> list:
    """Axes with nothing drawn in them (colour bars aside)."""
    return [
        axes.get_title() or axes.get_ylabel()
        for axes in figure.axes
        if axes.get_label() != "<colorbar>"
        and not (axes.lines or axes.patches or axes.collections or axes.images)
    ]


def test_the_rm3100_figure_is_legible_and_says_what_it_is_worth(real_data, tmp_path):
    """A poorly determined real log with a time column and no reference: no overlapping ticks,
    time on the x axis, no objective axis, the missing bins marked, the verdict in the title."""
    path = real_data / "rasteiro_robot_multisensor" / "MPU6050RM3100_derived.csv"
    log = nlpcal.read_log(path)
    result = nlpcal.calibration.calibrate_log(log)
    assert result.verdict.status == "poorly_determined"
    figure = _drawn(CalibrationView.build(log, result.apply(log.samples), result, path.name))
    assert _overlaps(figure) == [] and _empty_axes(figure) == []
    labels = {text for axes in figure.axes for text in (axes.get_xlabel(), axes.get_ylabel())}
    assert "time since the first sample [s]" in labels
    assert not any("objective" in label for label in labels)  # equal to the std without F
    title = figure._suptitle.get_text()
    assert title.startswith("verdict: POORLY DETERMINED")
    for name in result.identifiability["poorly_determined"]:
        short = name.replace("_deg", "")
        assert f"{short} " in title and "*" in title
    sky = next(axes for axes in figure.axes if axes.name == "hammer")
    legend = [text.get_text() for text in sky.get_legend().get_texts()]
    assert legend == ["bin visited", "bin missing"]
    missing = [text.get_text() for text in sky.texts]
    assert sorted(missing) == sorted(result.identifiability["coverage"]["missing"])


def test_ticks_do_not_overlap_at_a_large_n():
    """A long log of a large field (sample indices in the millions, field values of 10^5 nT)."""
    samples, _ = make_log(n=3000, seed=5)
    result = nlpcal.calibrate(samples, reference_field=PAPER_FIELD, method="joint")
    n = 2_000_000
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    before = 1.2e5 + 4e4 * np.sin(np.linspace(0, 40, n)) + rng.normal(0, 50, n)
    after = PAPER_FIELD + rng.normal(0, 5, n)
    view = CalibrationView(
        unit="nT",
        before=before,
        after=after,
        reference=PAPER_FIELD,
        directions=directions,
        cycles=[],
        title="long log",
        reference_source="given",
        result=result,
    )
    figure = _drawn(view)
    assert _overlaps(figure) == [] and _empty_axes(figure) == []
    assert figure._suptitle.get_text().startswith("verdict: ")
