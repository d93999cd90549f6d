"""The docs `--check` comparison (docs/generated.py): statistics to their last printed digit,
cycle and iteration counts within a few, wall times aside, words exactly."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs"))

from generated import differences

PAGE = """Some prose, exit 0, stopped by rtol after 1834 cycles, 0.029 standard errors.

| set | staged: cycles run (stop) | std [nT] | wall [s] | iterations, IPOPT / CG | after 7 cycles |
|---|---|---|---|---|---|
| turntable | 221 (rtol) | 6.852 | 0.004 | 369 / 11687 | 1 |
| cycle 221 | 3 | 17 465 nT | 0.1 | 3 | 93 600 |
"""


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("6.852", "6.853"),  # one unit of the last digit
        ("17 465", "17 466"),
        ("93 600", "93 700"),  # printed to 3 figures
        ("0.029 standard", "0.03 standard"),  # printed to fewer digits
        ("0.004", "0.250"),  # wall times are not compared
        ("221 (rtol)", "216 (rtol)"),  # cycles within 3 %
        ("cycle 221", "cycle 226"),
        ("1834 cycles", "1852 cycles"),
        ("369 /", "424 /"),  # iterations within 25 %
    ],
)
def test_the_last_digit_and_a_few_counts_are_not_a_change(old, new):
    assert differences(PAGE, PAGE.replace(old, new, 1)) == []


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("6.852", "6.854"),  # two units of the last digit
        ("17 465", "17 467"),
        ("93 600", "93 800"),
        ("221 (rtol)", "232 (rtol)"),
        ("1834 cycles", "1900 cycles"),
        ("369 /", "480 /"),
        ("exit 0", "exit 1"),  # a status: the same or not
        ("| 1 |", "| 2 |"),  # not a count: "after 7 cycles" names its own
        ("(rtol)", "(max_cycles)"),  # words
        ("| 3 | 17 465", "| 3 | 4 | 17 465"),  # a cell more
    ],
)
def test_a_real_change_is_one(old, new):
    changed = PAGE.replace(old, new, 1)
    assert changed != PAGE
    assert len(differences(PAGE, changed)) == 1


def test_an_escaped_bar_stays_in_its_cell():
    page = "| quantity | nlpcal |\n|---|---|\n| largest roll error, \\|pitch\\| 0-60 | 0.070 |\n"
    assert differences(page, page.replace("0.070", "0.071")) == []
    assert len(differences(page, page.replace("0.070", "0.072"))) == 1
