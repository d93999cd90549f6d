"""A published number beside nlpcal's, with its tolerance and verdict, and a paper's set of them.

Verdicts: ``matches`` (within the tolerance; for a bound the paper states, at or below it),
``differs`` (outside it, for a stated cause), ``unexplained`` (outside it with no stated cause: the
reproduction fails). A tolerance is half a unit of the last digit the paper prints plus
STANDARD_ERRORS standard errors of nlpcal's number where it is an estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

from ..version import __version__

#: The verdicts, best first.
VERDICTS = ("matches", "differs", "unexplained")
#: Standard errors of nlpcal's estimate that a tolerance allows.
STANDARD_ERRORS = 3.0
#: The format name of the JSON document of a reproduction.
FORMAT = "nlpcal-reproduction"


def half_unit(decimals: int) -> float:
    """Half a unit of the last digit of a number printed with `decimals` digits after the point:
    16.29 (2) -> 0.005, 95 (0) -> 0.5."""
    return 0.5 * 10.0**-decimals


@dataclass(frozen=True)
class Value:
    """One published number beside nlpcal's.

    quantity : what it is, in the paper's words ("Table 1, cycle 7, std").
    unit : its unit ("nT", "deg", "1").
    paper : the paper's number. [unit]
    decimals : the digits the paper prints after the decimal point (2 for 16.29, 0 for 95).
    nlpcal : nlpcal's number for the same quantity. [unit]
    standard_error : of nlpcal's number, when it is an estimate. [unit]
    cause : why the two may differ (a property of the replica or of the paper's report), or None
        when they must agree.
    bound : the paper states an upper bound ("within 0.15 deg"): nlpcal's number must not exceed it.
    """

    quantity: str
    unit: str
    paper: float
    decimals: int
    nlpcal: float
    standard_error: float | None = None
    cause: str | None = None
    bound: bool = False

    @property
    def printed(self) -> str:
        """The paper's number as it prints it."""
        return f"{self.paper:.{self.decimals}f}"

    @property
    def tolerance(self) -> float:
        """Half a unit of the paper's last printed digit plus STANDARD_ERRORS standard errors of
        nlpcal's number. [unit]"""
        spread = STANDARD_ERRORS * self.standard_error if self.standard_error else 0.0
        return half_unit(self.decimals) + spread

    @property
    def basis(self) -> str:
        """The reason for the tolerance, in words."""
        parts = [f"half a unit of the paper's last digit ({self.printed})"]
        if self.standard_error:
            parts.append(f"{STANDARD_ERRORS:g} standard errors of nlpcal's estimate")
        return " + ".join(parts)

    @property
    def difference(self) -> float:
        """nlpcal's number minus the paper's. [unit]"""
        return self.nlpcal - self.paper

    @property
    def within(self) -> bool:
        if self.bound:
            return self.nlpcal <= self.paper + self.tolerance
        return abs(self.difference) <= self.tolerance

    @property
    def verdict(self) -> str:
        if not math.isfinite(self.nlpcal):
            return "unexplained"
        if self.within:
            return "matches"
        return "differs" if self.cause else "unexplained"

    def nlpcal_text(self) -> str:
        """nlpcal's number with one digit more than the paper prints."""
        return f"{self.nlpcal:.{self.decimals + 1}f}"

    def to_dict(self) -> dict:
        return {
            "quantity": self.quantity,
            "unit": self.unit,
            "paper": self.paper,
            "paper_printed": self.printed,
            "bound": self.bound,
            "nlpcal": self.nlpcal,
            "standard_error": self.standard_error,
            "difference": self.difference,
            "tolerance": self.tolerance,
            "tolerance_basis": self.basis,
            "verdict": self.verdict,
            "cause": self.cause if self.verdict == "differs" else None,
        }


@dataclass
class Reproduction:
    """A paper's numbers reproduced on its replica.

    paper : its key in `PAPERS`. reference : the citation. replica : how the data were made.
    values : one `Value` per published number. figure : draws the figure as PNG bytes (needs
    matplotlib), or None. notes : what else the reader should know.
    """

    paper: str
    reference: str
    replica: str
    values: list
    figure: Callable[[], bytes] | None = None
    notes: list = field(default_factory=list)

    def counts(self) -> dict:
        """How many values have each verdict."""
        return {verdict: sum(v.verdict == verdict for v in self.values) for verdict in VERDICTS}

    @property
    def ok(self) -> bool:
        """Every value matches or differs for a stated cause."""
        return self.counts()["unexplained"] == 0

    def causes(self) -> list:
        """The distinct causes of the values that differ, in order of first appearance."""
        return list(dict.fromkeys(v.cause for v in self.values if v.verdict == "differs"))

    def summary(self) -> str:
        c = self.counts()
        return (
            f"{self.paper}: {len(self.values)} published numbers, {c['matches']} match, "
            f"{c['differs']} differ for a stated cause, {c['unexplained']} differ unexplained"
        )

    def table(self, markdown: bool = False) -> str:
        """The values as a table: a Markdown table, or aligned plain text for a terminal."""
        causes = self.causes()
        header = ["quantity", "unit", "paper", "nlpcal", "tolerance", "verdict"]
        rows = []
        for v in self.values:
            verdict = v.verdict
            if verdict == "differs":
                verdict = f"differs ({causes.index(v.cause) + 1})"
            paper = f"<= {v.printed}" if v.bound else v.printed
            rows.append([v.quantity, v.unit, paper, v.nlpcal_text(), f"{v.tolerance:.2g}", verdict])
        notes = [f"({k}) {cause}" for k, cause in enumerate(causes, start=1)]
        if markdown:
            lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
            cells = [[cell.replace("|", "\\|") for cell in row] for row in rows]  # |pitch|
            lines += ["| " + " | ".join(row) + " |" for row in cells]
            return "\n".join([*lines, "", *(f"- {note}" for note in notes)]).rstrip()
        widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
        lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]
        title = "  ".join(cell.ljust(w) for cell, w in zip(header, widths)).rstrip()
        return "\n".join(
            [self.reference, f"replica: {self.replica}", "", title, *lines, "", *notes]
        ).rstrip()

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "format_version": 1,
            "paper": self.paper,
            "reference": self.reference,
            "replica": self.replica,
            "counts": self.counts(),
            "values": [v.to_dict() for v in self.values],
            "notes": list(self.notes),
            "nlpcal_version": __version__,
        }
