"""Non-orthogonality of a triaxial probe (Wang et al. 2015): worst-case total-field error, error
map, angle inversion and the repeatability of several inversions.

The forward model is `nlpcal.models.wang2015`; the NLPs are in `nlpcal.nlp.orthogonality`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .. import validation
from ..errors import InputError
from ..models import wang2015
from .inversion import (
    BOUND_ACTIVE_REL_TOL,
    DEFAULT_BOUND_DEG,
    MIN_INVERSION_SAMPLES,
    Inversion,
    Repeatability,
    invert,
    repeatability,
)
from .worst_case import Extremum, WorstCase, implied_worst_case, worst_case

ANGLE_NAMES = wang2015.ANGLE_NAMES
PAPER_FIELD_NT = wang2015.PAPER_FIELD_NT
#: Largest map step accepted. [deg]
MAX_MAP_STEP_DEG = 10.0


def error_map(angles_deg, field_nT, step_deg: float = 1.0):
    """dB on a regular (theta, phi) grid, the map of Fig. 4 in Wang et al. (2015).

    angles_deg : (alpha, beta, gamma). [deg]; field_nT : |B|. [nT]
    step_deg : grid step in both angles, in (0, 10]. [deg]
    Returns theta [deg] (n_theta,), phi [deg] (n_phi,), dB [nT] (n_phi, n_theta).
    """
    step = validation.number(
        step_deg, "the map step", positive=True, maximum=MAX_MAP_STEP_DEG, unit="deg"
    )
    return wang2015.error_map(validation.angles(angles_deg), validation.field(field_nT), step)


def synthetic_rotation(
    angles_deg, field_nT=PAPER_FIELD_NT, n: int = 500, noise_nT: float = 0.0, seed: int = 0
):
    """Probe output B' = T B + noise for n directions spread over the sphere. [nT]

    angles_deg : (alpha, beta, gamma). [deg]; field_nT : |B|. [nT]; noise_nT : standard deviation
    of white noise added to each axis. [nT]
    """
    return wang2015.synthetic_rotation(
        validation.angles(angles_deg),
        validation.field(field_nT),
        validation.count(n, "n"),
        validation.number(noise_nT, "the noise", minimum=0.0, unit="nT"),
        seed,
    )


def error_table(theta, phi, error) -> pd.DataFrame:
    """The map of `error_map` as a table with columns theta_deg, phi_deg, delta_B_nT."""
    grid_theta, grid_phi = np.meshgrid(theta, phi)
    return pd.DataFrame(
        {
            "theta_deg": grid_theta.ravel(),
            "phi_deg": grid_phi.ravel(),
            "delta_B_nT": np.asarray(error).ravel(),
        }
    )


def invert_logs(logs, *, field_nT=None, bound_deg=DEFAULT_BOUND_DEG, verbose: bool = False):
    """`invert` every log read by `nlpcal.io.read_log` (in nT); one log gives its Inversion,
    several give their Repeatability. Messages about a log name it."""
    runs = []
    for log in logs:
        if log.base_unit == "raw":
            raise InputError(
                f"{log.path}: the inversion needs the field in a field unit, not "
                f"raw counts; pass --unit"
            )
        try:
            runs.append(
                invert(
                    log.samples,
                    field_nT=field_nT,
                    bound_deg=bound_deg,
                    source=log.path,
                    verbose=verbose,
                )
            )
        except InputError as exc:
            message = str(exc)
            raise InputError(
                message if message.startswith(log.path) else f"{log.path}: {message}"
            ) from None
    return runs[0] if len(runs) == 1 else repeatability(runs, field_nT=field_nT)


__all__ = [
    "ANGLE_NAMES",
    "BOUND_ACTIVE_REL_TOL",
    "DEFAULT_BOUND_DEG",
    "MIN_INVERSION_SAMPLES",
    "PAPER_FIELD_NT",
    "Extremum",
    "Inversion",
    "Repeatability",
    "WorstCase",
    "error_map",
    "error_table",
    "implied_worst_case",
    "invert",
    "invert_logs",
    "repeatability",
    "synthetic_rotation",
    "worst_case",
]
