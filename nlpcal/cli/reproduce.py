"""`nlpcal reproduce PAPER`: a paper's published numbers beside nlpcal's, each with a verdict.

    nlpcal reproduce zhou2010|wang2015|liu2022|qiu2017 [-o DIR] [--json]

The comparison table is the command's data: it goes to stdout (aligned text, or with --json the
document). DIR (default reproduce-PAPER in the current folder, made when missing) receives
PAPER.json (the document) and PAPER.png (the figure, when matplotlib is installed), written
together and atomically. Exit status: 0 when every number matches or differs for a stated cause,
1 when one differs beyond its tolerance with no stated cause (nothing is written to DIR), 2 for
bad usage (an unknown paper, a DIR that is a file or whose parent folder is missing).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from .common import add_command, solver_log, tell_written, warn, warning

#: The papers, as the help names them (`nlpcal.reproduce.PAPERS`, not imported for a fast --help).
PAPER_NAMES = ("zhou2010", "wang2015", "liu2022", "qiu2017")


def register(sub):
    parser = add_command(
        sub,
        "reproduce",
        help="regenerate a paper's published numbers from its replica, each with a verdict",
        description="""\
Regenerate the table of one of the four papers behind nlpcal from a simulated replica of its
experiment (the papers' data are not public), and print the paper's numbers beside nlpcal's:

  zhou2010  Zhou et al. (2010): Table 1 of the staged cycle and the final nine parameters
  wang2015  Wang et al. (2015): worst-case total-field error, angle inversion, repeatability
  liu2022   Liu et al. (2022): the temperature drift line and the RMSE before and after
  qiu2017   Qiu et al. (2017): e-compass roll, pitch and heading errors after calibration

Each number gets a verdict: 'matches' (within half a unit of the paper's last printed digit
plus three standard errors of nlpcal's estimate; a bound the paper states must not be
exceeded), 'differs' with its cause (a property of the replica or of the paper's report,
printed below the table), or 'unexplained'. Iteration and cycle counts are never compared: they
vary with the floating-point library. The table goes to stdout; the document (JSON) and the
figure go to DIR.""",
        examples=(
            "nlpcal reproduce zhou2010",
            "nlpcal reproduce qiu2017 -o qiu --json > qiu.json",
        ),
    )
    parser.add_argument(
        "paper",
        metavar="PAPER",
        help=f"the paper: {', '.join(PAPER_NAMES[:-1])} or {PAPER_NAMES[-1]}",
    )
    parser.add_argument(
        "-o",
        "--output",
        metavar="DIR",
        help="folder for PAPER.json and PAPER.png (default reproduce-PAPER in the current "
        "folder; made when missing, existing files in it replaced atomically)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the document (JSON) on stdout instead of the table",
    )
    parser.set_defaults(func=run)


def _folder(path: Path) -> Path:
    """The output folder, checked before any work: a folder, or a new one in an existing one."""
    from ..errors import InputError

    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a folder; give -o a folder")
    if not path.exists() and not path.absolute().parent.is_dir():
        raise InputError(f"{path}: the folder {path.absolute().parent} does not exist")
    return path


def _figure(reproduction):
    """The figure's PNG, or None with a message when matplotlib is missing."""
    from ..errors import InputError
    from ..plots import PLOT_HINT, require_matplotlib

    try:
        require_matplotlib()
    except InputError:
        warn(f"figure skipped: it needs matplotlib ({PLOT_HINT})")
        return None
    return reproduction.figure()


def _write(folder: Path, paper: str, document: dict, png) -> list:
    """PAPER.json and PAPER.png into `folder`, together; a folder made here is removed again when
    the writing fails."""
    from ..io import Outputs

    made = not folder.exists()
    folder.mkdir(exist_ok=True)
    paths = [folder / f"{paper}.json"] + ([folder / f"{paper}.png"] if png is not None else [])
    try:
        with Outputs() as outputs:
            outputs.json(paths[0], document)
            if png is not None:
                outputs.bytes(paths[1], png)
    except BaseException:
        if made:
            folder.rmdir()
        raise
    return paths


def run(args) -> int:
    from ..errors import InputError
    from ..io.files import json_text
    from ..io.strict import strict
    from ..reproduce import PAPERS, reproduce

    if args.paper not in PAPERS:
        raise InputError(f"unknown paper {args.paper!r}; expected one of {', '.join(PAPERS)}")
    folder = _folder(Path(args.output or f"reproduce-{args.paper}"))
    started = time.perf_counter()
    with solver_log():
        reproduction = reproduce(args.paper)
        png = _figure(reproduction) if reproduction.ok else None
    document = strict(reproduction.to_dict())
    sys.stdout.write(json_text(document) if args.json else reproduction.table() + "\n")
    sys.stdout.flush()
    warn(f"{reproduction.summary()} ({time.perf_counter() - started:.1f} s)")
    if not reproduction.ok:
        wrong = [v.quantity for v in reproduction.values if v.verdict == "unexplained"]
        warning(f"beyond tolerance with no stated cause: {'; '.join(wrong)}; nothing written")
        return 1
    tell_written(*_write(folder, args.paper, document, png))
    return 0
