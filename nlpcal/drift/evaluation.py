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

    Parameters
    ----------
    samples : array_like, shape (N, 3)
        Raw output. [nT]
    reference : float or array_like of shape (N,)
        Proton values, or one number. [nT]
    params : Zhou2010Parameters, optional
        The nine parameters at the base temperature (system correction, Eq. 4 of [2]).
    temperature : array_like of shape (N,), optional
        Temperatures, needed with `correction` for the third row. [degC]
    correction : DriftFit or TemperatureCalibrationResult, optional
        The temperature correction (Eq. 9), anything with `correct(samples, temperature, params)`
        and `carries_parameters`.

    Returns
    -------
    list of dict
        One Table 1 row of |B| per stage ("raw", "system", then the temperature correction), each
        with its `rmse` against the reference. [nT]

    Raises
    ------
    InputError
        Unusable input.

    References
    ----------
    [1] Liu et al. (2022), see `nlpcal.models.liu2022`.
    [2] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> import nlpcal
    >>> log = nlpcal.simulate(500, seed=4)
    >>> rows = nlpcal.rmse_rows(
    ...     log[["bx", "by", "bz"]].to_numpy(), 49462.0, params=nlpcal.Zhou2010Parameters()
    ... )
    >>> len(rows)
    2
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
