"""What a result is worth, in one word and its reasons: the verdict every result carries.

    {"status": "ok" | "warnings" | "poorly_determined" | "failed", "reasons": [...]}

`judge` is the one rule that turns a result's quality fields into its verdict; each kind of result
says which of its fields are failed checks, poorly determined parameters and warnings, and `judge`
ranks them:

    failed              a quality check failed: the solve did not converge, or the data do not
                        determine some parameters (a result written anyway, with an allow flag)
    poorly_determined   every check passed, but some parameters have standard errors above the
                        limits the result states (the reasons name them)
    warnings            every check passed and every parameter is determined, with warnings
    ok                  none of these

The reasons are the failed checks, then the poorly determined parameters, then the warnings, each a
sentence. A verdict is derived, never read back: a document's stored verdict is recomputed from its
fields when it is read.
"""

from __future__ import annotations

from dataclasses import dataclass

#: The statuses, from the best to the worst.
STATUSES = ("ok", "warnings", "poorly_determined", "failed")
#: How a status reads in a line of text.
LABELS = {
    "ok": "ok",
    "warnings": "ok, with warnings",
    "poorly_determined": "POORLY DETERMINED",
    "failed": "FAILED",
}


@dataclass(frozen=True)
class Verdict:
    """A result's status (one of STATUSES) and the reasons for it, worst first.

    failures, poorly_determined, warnings : how many of the reasons are of each kind.
    """

    status: str
    reasons: tuple = ()
    failures: int = 0
    poorly_determined: int = 0

    @property
    def warnings(self) -> int:
        return len(self.reasons) - self.failures - self.poorly_determined

    @property
    def label(self) -> str:
        return LABELS[self.status]

    def to_dict(self) -> dict:
        return {"status": self.status, "reasons": list(self.reasons)}

    def line(self) -> str:
        """One line: the status, the failed checks and poorly determined parameters in full, and
        how many warnings follow. "FAILED: the data do not determine z_z; 2 warnings"."""
        serious = list(self.reasons[: self.failures + self.poorly_determined])
        if self.warnings:
            serious.append(f"{self.warnings} warning{'s' if self.warnings > 1 else ''}")
        return f"{self.label}: {'; '.join(serious)}" if serious else self.label


def judge(failures=(), poorly_determined=(), warnings=()) -> Verdict:
    """The verdict of a result from its quality fields, each a sequence of sentences.

    failures : the quality checks the result fails (an unconverged solve, parameters the data do
        not determine). poorly_determined : parameters with standard errors above their limits.
    warnings : the result's warnings (outlier flags among them).
    """
    reasons = (*failures, *poorly_determined, *warnings)
    if failures:
        status = "failed"
    elif poorly_determined:
        status = "poorly_determined"
    elif warnings:
        status = "warnings"
    else:
        status = "ok"
    return Verdict(status, tuple(reasons), len(failures), len(poorly_determined))


def worst(*statuses: str) -> str:
    """The worst of some statuses (STATUSES order)."""
    return max(statuses, key=STATUSES.index)
