"""The data of one nine-parameter calibration, and its Table 1 rows.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models.zhou2010 import Zhou2010Parameters
from ..moments import Moments
from ..nlp.blocks import objective_function, pack
from ..nlp.solver import IpoptOptions
from ..statistics import field_statistics


@dataclass
class Problem:
    """The data of one calibration: samples, reference and their moments.

    samples : (N, 3) raw sensor output B_M. [field unit]
    reference : None, a number or (N,) values F_i. [field unit]
    moments : `nlpcal.moments.Moments` of the samples and the reference.
    ipopt : the IPOPT settings of every solve (print_level > 0 shows IPOPT's log).
    """

    samples: np.ndarray
    reference: float | np.ndarray | None
    moments: Moments
    ipopt: IpoptOptions = IpoptOptions()

    def measured_row(self) -> dict:
        """The Table 1 row of the raw |B_M|, gathered with the moments."""
        return {"label": "measured", **self.moments.measured, "iterations": 0, "wall_s": 0.0}

    def row(self, label, theta, series: float | None = None, *, iterations, wall_s) -> dict:
        """A Table 1 row of |B1| for `theta`, with the relative gap between the moment objective
        (`series`, evaluated here when not given) and the exact per-sample one."""
        stats = field_statistics(self.samples, theta, self.reference)
        if series is None:
            p = pack(self.moments, theta, np.ones(9), 1.0)
            series = float(objective_function(self.moments.reference)(theta, p)[0])
        exact = stats["objective"]
        stats["series_rel_error"] = abs(series - exact) / exact if exact > 0 else 0.0
        stats["parameters"] = Zhou2010Parameters.from_theta(theta).to_dict()
        return {"label": label, **stats, "iterations": int(iterations), "wall_s": float(wall_s)}

    def reference_document(self) -> dict:
        """The "reference" block of a result: the mode and the field (or its mean)."""
        mode = self.moments.reference
        document: dict = {"mode": mode}
        field = np.asarray(self.reference, dtype=float)
        if mode == "constant":
            document["field"] = float(field)
        elif mode == "series":
            document["field_mean"] = float(field.mean())
        return document
