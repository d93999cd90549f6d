"""nlpcal: three-axis magnetometer calibration as CasADi/IPOPT nonlinear programs.

    result = nlpcal.calibrate(samples, unit="uT", reference_field=50.1)
    corrected = result.apply(samples, unit="uT")

Every verb and result type of the four papers is importable from here:

    calibrate, CalibrationResult, compare, Comparison        Zhou et al. (2010)
    worst_case, invert, repeatability, error_map, ...        Wang et al. (2015)
    fit_drift, DriftFit, calibrate_temperature, ...          Liu et al. (2022)
    calibrate_turns, calibrate_free, attitude, evaluate ...  Qiu et al. (2017)
    simulate, read_log, load                                 synthetic logs, reading files
    calibrate_many, apply_many                               fleets of logs, on Dask or not
    fit_tolles_lawson, TollesLawsonFit                       a platform's field (Tolles-Lawson)
    export, import_file, ReferenceModel                      other formats, IGRF/WMM references

The names are resolved on first use, so `import nlpcal` (and the command line's --help) stays
quick; type checkers see them through the TYPE_CHECKING imports below.

The public API is `__all__`: those names, their signatures, and the attributes and methods of
what they return. Every other module is internal: importable, but free to change in any
release (docs/api.md).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .version import __version__

if TYPE_CHECKING:  # what the lazy __getattr__ below returns, for type checkers
    from .batch import BatchReport, apply_many, calibrate_many
    from .calibration import CalibrationResult, StopRule, calibrate
    from .comparison import CompareSettings, Comparison, compare
    from .compass import CompassCalibration, attitude, calibrate_free, calibrate_turns, evaluate
    from .correction import Correction, load_parameters
    from .drift import (
        DriftFit,
        TemperatureCalibrationResult,
        TemperatureModel,
        calibrate_temperature,
        fit_drift,
        rmse_rows,
    )
    from .errors import InputError, QualityError, SolveError
    from .formats import AffineCorrection, export, import_file
    from .geomagnetic import ReferenceModel
    from .io import Log, read_log
    from .models.zhou2010 import Zhou2010Parameters
    from .orthogonality import (
        Inversion,
        Repeatability,
        WorstCase,
        error_map,
        implied_worst_case,
        invert,
        repeatability,
        synthetic_rotation,
    )
    from .orthogonality.worst_case import worst_case  # the function, not its module
    from .platform import TollesLawsonFit, fit_tolles_lawson
    from .simulation import simulate

#: Public name -> the module that defines it.
_EXPORTS = {
    "calibrate": "calibration",
    "CalibrationResult": "calibration",
    "StopRule": "calibration",
    "compare": "comparison",
    "Comparison": "comparison",
    "CompareSettings": "comparison",
    "worst_case": "orthogonality",
    "WorstCase": "orthogonality",
    "invert": "orthogonality",
    "Inversion": "orthogonality",
    "repeatability": "orthogonality",
    "Repeatability": "orthogonality",
    "error_map": "orthogonality",
    "implied_worst_case": "orthogonality",
    "synthetic_rotation": "orthogonality",
    "fit_drift": "drift",
    "DriftFit": "drift",
    "calibrate_temperature": "drift",
    "TemperatureCalibrationResult": "drift",
    "TemperatureModel": "drift",
    "rmse_rows": "drift",
    "calibrate_turns": "compass",
    "calibrate_free": "compass",
    "CompassCalibration": "compass",
    "attitude": "compass",
    "evaluate": "compass",
    "simulate": "simulation",
    "export": "formats",
    "import_file": "formats",
    "AffineCorrection": "formats",
    "ReferenceModel": "geomagnetic",
    "Correction": "correction",
    "load_parameters": "correction",
    "calibrate_many": "batch",
    "apply_many": "batch",
    "BatchReport": "batch",
    "fit_tolles_lawson": "platform",
    "TollesLawsonFit": "platform",
    "read_log": "io",
    "Log": "io",
    "Zhou2010Parameters": "models.zhou2010",
    "InputError": "errors",
    "SolveError": "errors",
    "QualityError": "errors",
}


#: Subpackages and modules reachable as attributes (nlpcal.orthogonality, ...).
_SUBMODULES = (
    "batch",
    "calibration",
    "cluster",
    "comparison",
    "compass",
    "correction",
    "drift",
    "formats",
    "geomagnetic",
    "inference",
    "io",
    "models",
    "nlp",
    "orthogonality",
    "passes",
    "platform",
    "plots",
    "report",
    "results",
    "simulation",
    "statistics",
    "units",
    "validation",
)


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'nlpcal' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted([*globals(), *_EXPORTS, *_SUBMODULES])


#: The public API: these names, their signatures and the attributes and methods of what they
#: return. Every other module of the package is internal (see the API reference).
__all__ = [  # noqa: RUF022 (grouped by paper, as in the API reference)
    "__version__",
    "calibrate",
    "CalibrationResult",
    "StopRule",
    "compare",
    "Comparison",
    "CompareSettings",
    "worst_case",
    "WorstCase",
    "invert",
    "Inversion",
    "repeatability",
    "Repeatability",
    "error_map",
    "implied_worst_case",
    "synthetic_rotation",
    "fit_drift",
    "DriftFit",
    "calibrate_temperature",
    "TemperatureCalibrationResult",
    "TemperatureModel",
    "rmse_rows",
    "calibrate_turns",
    "calibrate_free",
    "CompassCalibration",
    "attitude",
    "evaluate",
    "simulate",
    "export",
    "import_file",
    "AffineCorrection",
    "ReferenceModel",
    "Correction",
    "load_parameters",
    "calibrate_many",
    "apply_many",
    "BatchReport",
    "fit_tolles_lawson",
    "TollesLawsonFit",
    "read_log",
    "Log",
    "Zhou2010Parameters",
    "InputError",
    "SolveError",
    "QualityError",
]
