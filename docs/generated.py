"""Generated blocks of the docs pages, shared by the scripts that regenerate them.

A block sits between `<!-- BEGIN generated:NAME -->` and `<!-- END generated:NAME -->`; the prose
around it is written by hand and left alone.

`--check` compares a regenerated page with the committed one at the resolution of what is
printed, not character by character, because the floating-point kernel (the BLAS that sums the
moments) changes last digits and the stop decisions that compare them (`differences`):

- the words and the layout must be the same;
- a statistic (a number with a decimal point or an exponent) must agree within one unit of its
  last printed digit (of the coarser of the two printings; an integer's unit is that of its last
  non-zero digit, so 93 600 printed to 3 figures is compared to within 100, and an integer below
  10, an exit status or a label, must be the same);
- a cycle or iteration count (an integer beside the word cycle(s), iteration(s) or it, or in a
  table column whose header counts them) agrees within the slack of its kind (CYCLE_SLACK,
  ITERATION_SLACK, of the page's count):
  these counts vary with the kernel, since a stop rule compares quantities whose last digits
  the kernel decides: cycles by a few (216 to 222 staged cycles on the turntable set of
  docs/comparison.md on three kernels), IPOPT iterations summed over hundreds of solves by up
  to about 15 % (369 to 424);
- wall times (a table column whose header says wall) are not compared.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from nlpcal.io import write_text_atomic


def replace_block(page: str, name: str, body: str, where: str = "the page") -> str:
    """`page` with the block `name` replaced by `body`."""
    pattern = re.compile(
        rf"(<!-- BEGIN generated:{re.escape(name)} -->\n).*?"
        rf"(<!-- END generated:{re.escape(name)} -->)",
        re.S,
    )
    if not pattern.search(page):
        raise SystemExit(f"{where}: the markers of block {name!r} are missing")
    return pattern.sub(lambda m: m.group(1) + body.rstrip() + "\n" + m.group(2), page)


def check_parser(description: str) -> argparse.ArgumentParser:
    """The parser of a page's script, with its --check option."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument(
        "--check",
        action="store_true",
        help="compare the page's tables (statistics to their last printed digit, counts within "
        "a few) without writing anything; exit 1 when they are out of date",
    )
    return parser


#: Cycle counts agree within this many counts or this fraction, whichever is larger.
CYCLE_SLACK = (3, 0.03)
#: Iteration counts agree within this many counts or this fraction, whichever is larger.
ITERATION_SLACK = (3, 0.25)
#: A number as the pages print it: 17 465 (groups of three), -0.029, 3.9e-04, 1e-6.
NUMBER = re.compile(r"[-+]?(?:\d{1,3}(?: \d{3})+(?![\d.])|\d+\.?\d*(?:[eE][-+]?\d+)?|\.\d+)")
#: Words that make the integers beside them counts of cycles, of iterations.
CYCLE_WORDS = re.compile(r"\bcycles?\b", re.I)
ITERATION_WORDS = re.compile(r"(?:\b|_)(?:iterations?|it)\b", re.I)


def _slack(text: str) -> tuple | None:
    """The slack of counts named by `text` (the looser of its words), or None."""
    if ITERATION_WORDS.search(text):
        return ITERATION_SLACK
    return CYCLE_SLACK if CYCLE_WORDS.search(text) else None


def _column_slack(title: str) -> tuple | None:
    """The slack of a column whose header counts cycles or iterations ("cycles run"; not
    "after 7 cycles", which names a count of its own)."""
    return _slack(re.sub(rf"(?:{NUMBER.pattern})\s+\w+", "", title))


def _beside(text: str, start: int, end: int) -> str:
    """The words just before and just after text[start:end]."""
    before = re.search(r"([\w-]+)\s*$", text[:start])
    after = re.match(r"\s*([\w-]+)", text[end:])
    return " ".join(m.group(1) for m in (before, after) if m)


def _unit(token: str) -> float:
    """One unit of the last printed digit of a number."""
    mantissa, _, exponent = token.replace(" ", "").lower().partition("e")
    mantissa = mantissa.lstrip("+-")
    if "." in mantissa:
        unit = 10.0 ** -len(mantissa.split(".")[1])
    else:
        unit = 10.0 ** (len(mantissa) - len(mantissa.rstrip("0"))) if mantissa.strip("0") else 1.0
    return unit * 10.0 ** int(exponent or 0)


def _value(token: str) -> float:
    return float(token.replace(" ", ""))


def _numbers_agree(old: str, new: str, slack: tuple | None) -> bool:
    a, b = _value(old), _value(new)
    integers = not any(c in old + new for c in ".eE")
    if integers and slack:
        return abs(a - b) <= max(slack[0], slack[1] * abs(a))
    if integers and max(abs(a), abs(b)) < 10:
        return a == b
    return abs(a - b) <= max(_unit(old), _unit(new)) * (1 + 1e-9)


def _pieces(text: str, title: str = ""):
    """(the words, the numbers with their slack as counts) of a table cell (under the header
    `title`) or of a prose line."""
    column = _column_slack(title)
    numbers = [
        (m.group(), _slack(_beside(text, m.start(), m.end())) or column)
        for m in NUMBER.finditer(text)
    ]
    return NUMBER.sub("#", text), numbers


def _cells(line: str) -> list:
    """The cells of a Markdown table row (an escaped \\| stays inside its cell)."""
    return re.split(r"(?<!\\)\|", line)


def _line_pieces(line: str, header: list | None):
    """The words and numbers of a line; in a table row cell by cell, with its column's header
    telling counts, and wall-time cells left out."""
    if header is None or not line.startswith("|"):
        return [_pieces(line)]
    cells = _cells(line)
    if len(cells) != len(header):
        return [(line, [])]
    pieces = []
    for cell, title in zip(cells, header):
        if "wall" in title.lower():
            pieces.append(("(wall time)", []))
        else:
            pieces.append(_pieces(cell, title))
    return pieces


def differences(page: str, updated: str) -> list:
    """The lines of `updated` that differ from `page` beyond the printed resolution, as
    "line N: was ... now ..."; empty when they agree (the rules of the module's docstring)."""
    old_lines, new_lines = page.split("\n"), updated.split("\n")
    if len(old_lines) != len(new_lines):
        return [f"{len(new_lines)} lines, the page has {len(old_lines)}"]
    problems, header = [], None
    for number, (old, new) in enumerate(zip(old_lines, new_lines), start=1):
        if old.startswith("|") and not old.startswith("|-"):
            following = old_lines[number] if number < len(old_lines) else ""
            if following.startswith("|-") or following.startswith("|:"):
                header = _cells(old)  # a table's header row: the same on both sides
        elif not old.startswith("|"):
            header = None
        agree = old == new
        if not agree:
            old_pieces, new_pieces = _line_pieces(old, header), _line_pieces(new, header)
            agree = len(old_pieces) == len(new_pieces) and all(
                words_a == words_b
                and len(nums_a) == len(nums_b)
                and all(_numbers_agree(x, y, c) for (x, c), (y, _) in zip(nums_a, nums_b))
                for (words_a, nums_a), (words_b, nums_b) in zip(old_pieces, new_pieces)
            )
        if not agree:
            problems.append(f"line {number}: was {old!r}\n  now {new!r}")
    return problems


def check_page(path: Path, updated: str, script: str, page: str | None = None) -> int:
    """Compare the regenerated page with the one at `path` (or `page`, its text) at the printed
    resolution; say which lines moved. Returns 1 when the page is out of date, else 0."""
    problems = differences(path.read_text() if page is None else page, updated)
    if problems:
        print(f"{path.name} is out of date; run python {script}", file=sys.stderr)
        for line in problems:
            print(f"  {line}", file=sys.stderr)
        return 1
    print(
        f"{path.name} is up to date (statistics within one unit of their last digit, cycle "
        f"and iteration counts within a few, wall times aside)",
        file=sys.stderr,
    )
    return 0


def update_page(path: Path, updated: str, *, check: bool, script: str) -> int:
    """Write `updated` over the page at `path` (atomically), or with `check` only compare
    (`check_page`).

    Returns 1 when checking finds the page out of date, else 0.
    """
    page = path.read_text()
    if check:
        return check_page(path, updated, script, page)
    if updated != page:
        write_text_atomic(path, updated)
        print(f"updated {path.name}", file=sys.stderr)
    else:
        print(f"{path.name} already up to date", file=sys.stderr)
    return 0
