"""One command per paper: the published numbers beside nlpcal's, each with a verdict.

`reproduce(paper)` regenerates a paper's table from its replica (`nlpcal.simulation`: the papers'
data are not public) and returns a `Reproduction`: one `Value` per published number, with the
number nlpcal finds for the same quantity, a tolerance whose basis is written down, and a verdict:

* ``matches``: within the tolerance (for a bound the paper states, at or below it);
* ``differs``: outside it, for a stated cause (the replica cannot be the paper's sensor, and
  which of its properties moves the number is named);
* ``unexplained``: outside it with no stated cause. A reproduction with such a value fails.

Tolerances come from the resolution of the two numbers: half a unit of the last digit the paper
prints, plus three standard errors of nlpcal's estimate where it has one. Counts that vary with the
floating-point kernel (iterations, cycles) are never compared.

Papers (`PAPERS`): zhou2010 (Table 1 and the final parameters), wang2015 (worst case, inversion,
repeatability), liu2022 (drift fit and the RMSE of Eq. 10), qiu2017 (attitude errors).
"""

from __future__ import annotations

from ..errors import InputError
from . import liu2022, qiu2017, wang2015, zhou2010
from .values import Reproduction, Value

#: The papers, in the order of the documentation: name -> the function that reproduces it.
PAPERS = {
    "zhou2010": zhou2010.reproduce,
    "wang2015": wang2015.reproduce,
    "liu2022": liu2022.reproduce,
    "qiu2017": qiu2017.reproduce,
}


def reproduce(paper: str) -> Reproduction:
    """Regenerate the published numbers of `paper` (one of `PAPERS`) from its replica.

    Raises InputError for an unknown paper.
    """
    if paper not in PAPERS:
        raise InputError(f"unknown paper {paper!r}; expected one of {', '.join(PAPERS)}")
    return PAPERS[paper]()


__all__ = ["PAPERS", "Reproduction", "Value", "reproduce"]
