"""nlpcal: three-axis magnetometer calibration as CasADi/IPOPT nonlinear programs.

    result = nlpcal.calibrate(samples, unit="uT", reference_field=50.1)
    corrected = result.apply(samples, unit="uT")

Every verb and result type of the four papers is importable from here:

    calibrate, CalibrationResult, compare, Comparison        Zhou et al. (2010)
    worst_case, invert, repeatability, error_map, ...        Wang et al. (2015)
    fit_drift, DriftFit, calibrate_temperature, ...          Liu et al. (2022)
    calibrate_turns, calibrate_free, attitude, evaluate ...  Qiu et al. (2017)
    simulate, read_log, load                                 synthetic logs, reading files
    export, import_file, ReferenceModel                      other formats, IGRF/WMM references

The names are resolved on first use, so `import nlpcal` (and the command line's --help) stays
quick.
"""

from __future__ import annotations

import importlib

from .version import __version__

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
    "read_log": "io",
    "Log": "io",
    "Zhou2010Parameters": "models.zhou2010",
    "InputError": "errors",
    "SolveError": "errors",
    "QualityError": "errors",
}


#: Subpackages and modules reachable as attributes (nlpcal.orthogonality, ...).
_SUBMODULES = (
    "calibration",
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


__all__ = ["__version__", *_EXPORTS]
