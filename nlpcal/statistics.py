"""Table 1 of [1]: statistics of the total field |B1| over the samples.

A row holds max, min, mean, std and range (max - min) of |B1|. The std is the population standard
deviation (ddof = 0, the 1/N of Eq. 8), so that std^2 equals the Eq. 8 objective. Each row also
carries the exact per-sample objective of the run (Eq. 8 or its reference variant), which is how
the moment expansion of `nlpcal.objective` is checked on every run.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import numpy as np

from .models.zhou2010 import correction_matrix_entries
from .moments import CHUNK_ROWS

#: Delta degrees of freedom of the reported std.
STD_DDOF = 0
STAT_KEYS = ("max", "min", "mean", "std", "range")


def field_statistics(samples, theta=None, reference=None, chunk_rows: int = 8 * CHUNK_ROWS) -> dict:
    """One chunked pass: Table 1 statistics of |B1| and the exact objective.

    samples : (N, 3) raw output B_M. [field unit]
    theta : internal parameters (z [field], s [1], angles [rad]); None gives the measured row |B_M|.
    reference : None, a float or an (N,) series F_i. [field unit]

    Returns max, min, mean, std, range [field unit], objective [field^2] and max_abs_u, the largest
    |(|B1| / F)^2 - 1| (F the reference, or the mean without one) [1].
    """
    samples = np.asarray(samples, dtype=float)
    n = samples.shape[0]
    if theta is None:
        offset, matrix = np.zeros(3), np.eye(3)
    else:
        theta = np.asarray(theta, dtype=float)
        offset = theta[0:3]
        matrix = np.array(correction_matrix_entries(theta[6], theta[7], theta[8],
                                                    theta[3], theta[4], theta[5]), dtype=float)
    shift = None
    total = total_sq = ref_sq = 0.0
    high, low = -np.inf, np.inf
    u_high = u_low = 0.0
    for start in range(0, n, chunk_rows):
        block = (samples[start:start + chunk_rows] - offset) @ matrix.T
        magnitude = np.sqrt(np.einsum("ij,ij->i", block, block))
        if shift is None:
            shift = float(magnitude.mean())  # sums of deviations from a shift avoid cancellation
        deviation = magnitude - shift
        total += deviation.sum()
        total_sq += deviation @ deviation
        high, low = max(high, magnitude.max()), min(low, magnitude.min())
        if reference is not None:
            f_i = reference if np.ndim(reference) == 0 else reference[start:start + chunk_rows]
            residual = magnitude - f_i
            ref_sq += residual @ residual
            ratio = (magnitude / f_i) ** 2 - 1.0
            u_high, u_low = max(u_high, ratio.max()), min(u_low, ratio.min())
    mean_dev = total / n
    variance = max(total_sq / n - mean_dev**2, 0.0)
    mean = shift + mean_dev
    if reference is None:
        objective = variance
        u_high, u_low = (high / mean) ** 2 - 1.0, (low / mean) ** 2 - 1.0
    else:
        objective = ref_sq / n
    return {
        "max": float(high), "min": float(low), "mean": float(mean),
        "std": float(np.sqrt(variance * n / (n - STD_DDOF))), "range": float(high - low),
        "objective": float(objective), "max_abs_u": float(max(abs(u_high), abs(u_low))),
    }


def format_table(rows, unit: str = "nT", extra=()) -> str:
    """Rows in the layout of Table 1 of [1], as text for a terminal."""
    columns = ["max", "min", "mean", "std", "range", *extra]
    width = max([len("row")] + [len(str(r["label"])) for r in rows])
    header = f"{'row':<{width}}  " + "  ".join(f"{c:>12}" for c in columns)
    lines = [f"|B1| statistics [{unit}], std with ddof={STD_DDOF}", header, "-" * len(header)]
    for row in rows:
        cells = []
        for c in columns:
            value = row.get(c)
            if isinstance(value, (int, np.integer)):
                cells.append(f"{value:>12d}")
            elif value is None:
                cells.append(f"{'':>12}")
            else:
                cells.append(f"{value:>12.6g}" if c not in STAT_KEYS else f"{value:>12.2f}")
        lines.append(f"{str(row['label']):<{width}}  " + "  ".join(cells))
    return "\n".join(lines)
