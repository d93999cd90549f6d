"""The paper's evaluation (Liu et al. 2022): the RMSE of Eq. 10, raw -> system -> system +
temperature.

References
----------
[1] Liu H., Li Y., Ding X., Feng C. (2022), see `nlpcal.models.liu2022`.
[2] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import numpy as np

from ..models.liu2022 import rmse
from ..models.zhou2010 import Zhou2010Parameters
from ..models.zhou2010 import correct as zhou_correct
from ..statistics import field_statistics


def evaluation_row(label: str, corrected, reference=None) -> dict:
    """Table row of |B| for corrected (or raw) vectors, with the RMSE of Eq. 10 to `reference`."""
    stats = field_statistics(np.asarray(corrected, dtype=float), None, reference)
    stats.pop("max_abs_u", None)
    row = {"label": label, **stats}
    if reference is not None:
        row["rmse"] = rmse(np.linalg.norm(corrected, axis=1), reference)  # Eq. 10
    return row


def rmse_rows(
    samples,
    reference,
    *,
    params: Zhou2010Parameters | None = None,
    temperature=None,
    correction=None,
) -> list:
    """The three-row evaluation of [1] (sections 2-3): raw -> system -> system + temperature.

    samples : (N, 3) raw output. [nT]
    reference : (N,) proton values or one number. [nT]
    params : the nine parameters at the base temperature (system correction, Eq. 4 of [2]).
    temperature : (N,) temperatures [degC]; correction : a DriftFit (Eq. 9) or a
        TemperatureCalibrationResult (anything with `correct(samples, temperature, params)` and
        `carries_parameters`). Both are needed for the third row.
    """
    samples = np.asarray(samples, dtype=float)
    rows = [evaluation_row("raw", samples, reference)]
    if params is not None:
        rows.append(evaluation_row("system", zhou_correct(samples, params), reference))
    if correction is not None and temperature is not None:
        corrected = correction.correct(samples, temperature, params)
        system = params is not None or correction.carries_parameters
        rows.append(
            evaluation_row(
                "system + temperature" if system else "temperature", corrected, reference
            )
        )
    return rows
