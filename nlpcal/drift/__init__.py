"""Temperature drift (Liu et al. 2022): the paper's two-step pipeline and a joint temperature
calibration.

* `fit_drift` (`nlpcal.drift.fit`): the diurnal correction and the least-squares line of Eq. 1 on
  a static log, k(t) of Eq. 9, with the standard errors of a and b and a warning when the
  temperature span is too small.
* `rmse_rows` (`nlpcal.drift.evaluation`): the paper's evaluation by the RMSE of Eq. 10,
  raw -> system -> system + temperature.
* `calibrate_temperature` (`nlpcal.drift.temperature`): beyond the paper, the nine parameters and
  the temperature coefficients from one log that spans temperatures.

The model is `nlpcal.models.liu2022`; a replica of the paper's experiment is
`nlpcal.simulation.liu2022`.
"""

from ..models.liu2022 import TemperatureModel, rmse
from .evaluation import evaluation_row, rmse_rows
from .fit import DriftFit, check_k, fit_drift
from .temperature import (
    TemperatureCalibrationResult,
    calibrate_temperature,
    coefficient_names,
    objective_value,
)

__all__ = [
    "DriftFit",
    "TemperatureCalibrationResult",
    "TemperatureModel",
    "calibrate_temperature",
    "check_k",
    "coefficient_names",
    "evaluation_row",
    "fit_drift",
    "objective_value",
    "rmse",
    "rmse_rows",
]
