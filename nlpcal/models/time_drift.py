"""Scale factors linear in time: the drift of a long record (satellite and observatory practice).

A fluxgate's scale factors age: over weeks and months its gains change by a few ppm, which
in-flight calibrations of satellite magnetometers model as a drift of the scale factors in time
([1]: the Swarm VFM's scale factors are estimated per period and drift by ppm per year). Here, on
top of the nine parameters of Eq. 4 (Zhou et al. 2010) and a temperature model, each gain is
multiplied by

    g_j(t) = 1 + d_j (t - t_ref) / 86 400                              (d_j per day)

with one d for all axes ("common") or one per axis ("per-axis"); t_ref is the middle of the
calibration log, where the nine parameters hold.

References
----------
[1] Toffner-Clausen L., Lesur V., Olsen N., Finlay C. C. (2016). In-flight scalar calibration
    and characterisation of the Swarm magnetometry package. Earth, Planets and Space 68, 129.
    https://doi.org/10.1186/s40623-016-0501-6
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The time drifts of the scale factors: none, one for all axes, one per axis.
TIME_DRIFTS = ("none", "common", "per-axis")
#: Seconds per day, the unit of the drift's time. [s/d]
DAY_S = 86_400.0


@dataclass(frozen=True)
class TimeDrift:
    """A drift of the scale factors linear in time.

    kind : "none", "common" or "per-axis" (TIME_DRIFTS).
    reference_time_s : t_ref, where the drift factor is 1: Unix seconds, or seconds since the
        origin of the log's times. [s]
    scale_slope_per_day : d of each axis (three equal values for "common"). [1/d]
    """

    kind: str = "none"
    reference_time_s: float = 0.0
    scale_slope_per_day: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if self.kind not in TIME_DRIFTS:
            raise ValueError(f"unknown time drift {self.kind!r}; expected one of {TIME_DRIFTS}")

    def days(self, times_s) -> np.ndarray:
        """(t - t_ref) in days of times in seconds. [d]"""
        return (np.asarray(times_s, dtype=float) - self.reference_time_s) / DAY_S

    def gains(self, times_s) -> np.ndarray:
        """g_j(t) = 1 + d_j (t - t_ref) / 86 400 at each time [s], shape (N, 3). [1]"""
        slopes = np.asarray(self.scale_slope_per_day, dtype=float)
        return 1.0 + self.days(times_s)[:, None] * slopes[None, :]

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "reference_time_s": float(self.reference_time_s),
            "scale_slope_per_day": [float(v) for v in self.scale_slope_per_day],
        }
