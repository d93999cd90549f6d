"""Regenerate the "nlpcal reproduce" section of the four paper pages with one command:

    python docs/reproduce.py            # rewrite the blocks and the two figures
    python docs/reproduce.py --check    # compare at the printed resolution; exit 1 on drift

For each paper, `nlpcal.reproduce.reproduce` (the code behind `nlpcal reproduce PAPER`) runs on
the paper's replica, and its table (the published numbers beside nlpcal's, with verdicts and
causes) replaces the block between `<!-- BEGIN generated:reproduce -->` and
`<!-- END generated:reproduce -->` of the paper's page. The figures of the drift and compass
reproductions go to docs/figures/ (comparison.py and orthogonality_table.py draw the other two).
About 10 s. Figures need matplotlib (pip install 'nlpcal[plot]').
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing

from generated import check_page, check_parser, replace_block, update_page  # noqa: E402
from nlpcal.io import write_bytes_atomic  # noqa: E402
from nlpcal.reproduce import PAPERS, reproduce  # noqa: E402

#: The page of each paper.
PAGES = {
    "zhou2010": "comparison.md",
    "wang2015": "orthogonality.md",
    "liu2022": "drift.md",
    "qiu2017": "compass.md",
}
#: The figures drawn here (the others are the pages' own).
FIGURES = {"liu2022": "drift_reproduction.png", "qiu2017": "compass_reproduction.png"}


def block(reproduction) -> str:
    """The page's block: the summary, the table and the causes."""
    return f"{reproduction.summary()}.\n\n{reproduction.table(markdown=True)}"


def main(argv=None) -> int:
    args = check_parser(__doc__.splitlines()[0]).parse_args(argv)
    status = 0
    for paper in PAPERS:
        reproduction = reproduce(paper)
        path = HERE / PAGES[paper]
        page = path.read_text()
        text = replace_block(page, "reproduce", block(reproduction), str(path))
        if args.check:
            status |= check_page(path, text, "docs/reproduce.py", page)
            continue
        update_page(path, text, check=False, script="docs/reproduce.py")
        if paper in FIGURES:
            figure = HERE / "figures" / FIGURES[paper]
            write_bytes_atomic(figure, reproduction.figure())
            print(f"wrote {figure.relative_to(HERE.parent)}", file=sys.stderr)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
