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


def error_map(
    angles_deg,
    reference_field: float | None = None,
    step_deg: float = 1.0,
    *,
    field_nT: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """dB on a regular (theta, phi) grid, the map of Fig. 4 in Wang et al. (2015).

    Parameters
    ----------
    angles_deg : array_like, shape (3,)
        (alpha, beta, gamma). [deg]
    reference_field : float
        Total field magnitude |B| (`--reference-field`). [nT]
    step_deg : float
        Grid step in both angles, in (0, 10] (`--step-deg`). [deg]
    field_nT : float, optional
        The former name of `reference_field`, still accepted. [nT]

    Returns
    -------
    theta : numpy.ndarray, shape (n_theta,)
        Azimuths. [deg]
    phi : numpy.ndarray, shape (n_phi,)
        Elevations. [deg]
    error : numpy.ndarray, shape (n_phi, n_theta)
        dB = |T u| B - B. [nT]

    Raises
    ------
    InputError
        Angles, field or step unusable.

    Examples
    --------
    >>> import nlpcal
    >>> theta, phi, error = nlpcal.error_map((0.1, 0.1, 0.1), 55_000.0, step_deg=10.0)
    >>> error.shape
    (19, 36)
    """
    step = validation.number(
        step_deg, "the map step", positive=True, maximum=MAX_MAP_STEP_DEG, unit="deg"
    )
    field_nT = validation.renamed(reference_field, field_nT, "reference_field", "field_nT")
    return wang2015.error_map(validation.angles(angles_deg), validation.field(field_nT), step)


def synthetic_rotation(
    angles_deg, field_nT=PAPER_FIELD_NT, n: int = 500, noise_nT: float = 0.0, seed: int = 0
):
    """Probe output B' = T B + noise for n directions spread over the sphere.

    Parameters
    ----------
    angles_deg : array_like, shape (3,)
        (alpha, beta, gamma) of the probe. [deg]
    field_nT : float
        Total field magnitude |B|. [nT]
    n : int
        Number of directions.
    noise_nT : float
        Standard deviation of white noise added to each axis. [nT]
    seed : int
        Random seed of the directions and the noise.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        The probe output B'. [nT]

    Raises
    ------
    InputError
        Angles, field, n or noise unusable.

    Examples
    --------
    >>> import nlpcal
    >>> nlpcal.synthetic_rotation((0.1, 0.0, 0.0), n=200).shape
    (200, 3)
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


def invert_logs(logs, *, reference_field=None, bound_deg=DEFAULT_BOUND_DEG, verbose: bool = False):
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
                    reference_field=reference_field,
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
    return runs[0] if len(runs) == 1 else repeatability(runs, reference_field)


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
