"""What the calibration figure and report show: a log before and after its correction.

`CalibrationView` gathers, for one log and one correction, the total field before (|B_M|) and
after (|B1|, Eq. 4 of Zhou et al. 2010), the reference F it is judged against (given with the log,
else the one stored in the calibration, else none), the direction of the corrected field in the
sensor frame, the rows of the staged cycle, the log's time column when it has one and the
calibration itself, all in the log's base unit. `nlpcal.plots.calibration_png` draws it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from ..calibration.coverage import bin_hits, direction_bins, subsample
from ..io.logs import Log
from ..statistics import field_statistics

#: Column names taken for a time axis (case-insensitive): t, time, timestamp, with a unit tail.
TIME_NAMES = re.compile(r"^(t|time|timestamp|times|elapsed)(_?(s|sec|seconds))?$", re.IGNORECASE)


def time_axis(log: Log) -> np.ndarray | None:
    """Seconds since the first kept row, from the log's time column (`TIME_NAMES`: numbers in
    seconds, or date-time text), or None when it has none or its times do not increase. [s]"""
    frame = log.frame
    if frame is None:
        return None
    name = next((c for c in frame.columns if TIME_NAMES.match(str(c).strip())), None)
    if name is None:
        return None
    column = frame[name] if log.kept is None else frame[name][np.asarray(log.kept)]
    values = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float)
    if not np.isfinite(values).all():
        stamps = pd.to_datetime(column, errors="coerce", utc=True)
        if stamps.isna().any():
            return None
        values = (stamps - stamps.iloc[0]).dt.total_seconds().to_numpy(dtype=float)
    if values.size != log.n or values.size < 2 or (np.diff(values) < 0).any():
        return None
    return values - values[0]


@dataclass
class CalibrationView:
    """A log before and after a correction.

    unit : the unit of every field value here ("nT", or "raw").
    before, after : (N,) |B_M| and |B1|. [unit]
    reference : None, a number or (N,) values F_i of the field. [unit]
    reference_source : "given" (with the log), "stored" (the calibration's constant reference)
        or "none".
    time : (N,) seconds since the first sample, from the log's time column, or None. [s]
    result : the calibration (its parameters, standard errors and verdict), or None.
    bins : the 26 direction bins (`nlpcal.calibration.coverage`): (name, unit vector, visited by
        B1 here) each.
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
    reference_source: str = "none"
    time: np.ndarray | None = None
    result: Any = None
    bins: list = field(default_factory=list)

    @classmethod
    def build(cls, log: Log, corrected, result=None, title: str = "") -> CalibrationView:
        """The view of `log` [base unit] and its `corrected` samples [base unit]; `result` (a
        CalibrationResult) adds its cycle rows, coverage and verdict, and its constant reference
        field when the log comes without one."""
        corrected = np.asarray(corrected, dtype=float)
        after = np.linalg.norm(corrected, axis=1)
        cycles, coverage = [], None
        reference, source = log.reference, "none" if log.reference is None else "given"
        stored = result.reference.field if result is not None else None
        if reference is None and stored is not None and result.unit == log.base_unit:
            reference, source = float(stored), "stored"  # a constant reference field
        if result is not None:
            cycles = [r for r in result.statistics if str(r.get("label", "")).startswith("cycle")]
            if cycles:
                cycles = [result.statistics[0], *cycles]
            coverage = (result.identifiability or {}).get("coverage")
        return cls(
            unit=log.base_unit,
            before=np.linalg.norm(log.samples, axis=1),
            after=after,
            reference=reference,
            directions=corrected / np.where(after > 0, after, 1.0)[:, None],
            cycles=cycles,
            coverage=coverage,
            title=title,
            reference_source=source,
            time=time_axis(log),
            result=result,
            bins=_bins(corrected),
        )

    @property
    def covered(self) -> int:
        """How many of the 26 direction bins B1 visits here."""
        return sum(visited for _, _, visited in self.bins)

    @property
    def n(self) -> int:
        return int(self.after.size)

    @property
    def target(self) -> np.ndarray | None:
        """F per sample, or None without a reference. [unit]"""
        if self.reference is None:
            return None
        return np.broadcast_to(np.asarray(self.reference, dtype=float), (self.n,))

    @property
    def target_label(self) -> str:
        """What the residuals are taken against: "F", "F_i", or "its mean" without a reference."""
        if self.reference is None:
            return "its mean"
        return "F" if np.ndim(self.reference) == 0 else "F_i"

    def residuals(self, magnitude: np.ndarray) -> np.ndarray:
        """|B| - F, or |B| - mean |B| without a reference (a spread, not an error). [unit]"""
        target = self.target
        return magnitude - (float(np.mean(magnitude)) if target is None else target)

    def rows(self) -> list:
        """Table 1 rows of |B_M| and |B1| on this log (ddof 0), with the RMSE against F when a
        reference is given. [unit]"""
        rows = []
        for label, magnitude in (("measured", self.before), ("corrected", self.after)):
            stats = field_statistics(np.column_stack([magnitude, 0 * magnitude, 0 * magnitude]))
            row = {"label": label, **{k: stats[k] for k in ("max", "min", "mean", "std", "range")}}
            if self.reference is not None:
                row["rmse"] = float(np.sqrt(np.mean(self.residuals(magnitude) ** 2)))
            rows.append(row)
        return rows


def _bins(corrected) -> list:
    """(name, unit vector, visited) of each of the 26 direction bins for the corrected field."""
    names, vectors = direction_bins()
    hits = bin_hits(subsample(corrected)) if len(corrected) else np.zeros(26)
    return [(name, vector, bool(hit)) for name, vector, hit in zip(names, vectors, hits)]
