"""What the calibration figure and report show: a log before and after its correction.

`CalibrationView` gathers, for one log and one correction, the total field before (|B_M|) and
after (|B1|, Eq. 4 of Zhou et al. 2010), the reference F it is judged against, the direction of
the corrected field in the sensor frame and the rows of the staged cycle, all in the log's base
unit. `nlpcal.plots.calibration_png` draws it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..io.logs import Log
from ..statistics import field_statistics


@dataclass
class CalibrationView:
    """A log before and after a correction.

    unit : the unit of every field value here ("nT", or "raw").
    before, after : (N,) |B_M| and |B1|. [unit]
    reference : None, a number or (N,) values F_i of the field. [unit]
    directions : (N, 3) unit vectors of B1 in the sensor frame. [1]
    cycles : Table 1 rows of the calibration (measured, then one per cycle), or [].
    coverage : the direction coverage block of the calibration, or None.
    title : a line that names the log and the correction.
    """

    unit: str
    before: np.ndarray
    after: np.ndarray
    reference: Any
    directions: np.ndarray
    cycles: list = field(default_factory=list)
    coverage: dict | None = None
    title: str = ""

    @classmethod
    def build(cls, log: Log, corrected, result=None, title: str = "") -> CalibrationView:
        """The view of `log` [base unit] and its `corrected` samples [base unit]; `result` (a
        CalibrationResult) adds its cycle rows and coverage when it was estimated from this log."""
        corrected = np.asarray(corrected, dtype=float)
        after = np.linalg.norm(corrected, axis=1)
        cycles, coverage = [], None
        if result is not None:
            cycles = [r for r in result.statistics if str(r.get("label", "")).startswith("cycle")]
            if cycles:
                cycles = [result.statistics[0], *cycles]
            coverage = (result.identifiability or {}).get("coverage")
        return cls(
            unit=log.base_unit,
            before=np.linalg.norm(log.samples, axis=1),
            after=after,
            reference=log.reference,
            directions=corrected / np.where(after > 0, after, 1.0)[:, None],
            cycles=cycles,
            coverage=coverage,
            title=title,
        )

    @property
    def n(self) -> int:
        return int(self.after.size)

    @property
    def target(self) -> np.ndarray:
        """F per sample: the reference, else the mean of |B1|. [unit]"""
        if self.reference is None:
            return np.full(self.n, float(self.after.mean()))
        return np.broadcast_to(np.asarray(self.reference, dtype=float), (self.n,))

    @property
    def target_label(self) -> str:
        if self.reference is None:
            return "mean |B1|"
        return "F" if np.ndim(self.reference) == 0 else "F_i"

    def rows(self) -> list:
        """Table 1 rows of |B_M| and |B1| on this log (ddof 0), with the RMSE against F when a
        reference is given. [unit]"""
        rows = []
        for label, magnitude in (("measured", self.before), ("corrected", self.after)):
            stats = field_statistics(np.column_stack([magnitude, 0 * magnitude, 0 * magnitude]))
            row = {"label": label, **{k: stats[k] for k in ("max", "min", "mean", "std", "range")}}
            if self.reference is not None:
                row["rmse"] = float(np.sqrt(np.mean((magnitude - self.target) ** 2)))
            rows.append(row)
        return rows
