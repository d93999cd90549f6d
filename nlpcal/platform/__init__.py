"""Fields of the platform a magnetometer rides on: Tolles-Lawson compensation of a scalar
magnetometer from a vector magnetometer's direction cosines (`fit_tolles_lawson`), fitted in one
pass with a causal band-pass and a ridge solve (`nlpcal.platform.terms`, `.bandpass`, `.ridge`).
Needs scipy (the `platform` extra)."""

from .fit import TollesLawsonFit, fit_tolles_lawson
from .logs import apply_platform_log, fit_platform_log, read_platform_log

__all__ = [
    "TollesLawsonFit",
    "apply_platform_log",
    "fit_platform_log",
    "fit_tolles_lawson",
    "read_platform_log",
]
