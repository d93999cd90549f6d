"""Generated blocks of the docs pages, shared by the scripts that regenerate them.

A block sits between `<!-- BEGIN generated:NAME -->` and `<!-- END generated:NAME -->`; the prose
around it is written by hand and left alone.
"""

from __future__ import annotations

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


def update_page(path: Path, updated: str, *, check: bool, script: str) -> int:
    """Write `updated` over the page at `path` (atomically), or with `check` only compare.

    Returns 1 when checking finds the page out of date, else 0.
    """
    page = path.read_text()
    if check:
        if updated != page:
            print(f"{path.name} is out of date; run python {script}", file=sys.stderr)
            return 1
        print(f"{path.name} is up to date", file=sys.stderr)
        return 0
    if updated != page:
        write_text_atomic(path, updated)
        print(f"updated {path.name}", file=sys.stderr)
    else:
        print(f"{path.name} already up to date", file=sys.stderr)
    return 0
