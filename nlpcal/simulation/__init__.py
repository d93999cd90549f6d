"""Synthetic logs with known truth: attitudes, the forward model of Eq. 4 in [1], noise.

The field is a constant vector in the world frame (north-east-down, magnitude `field`,
inclination `inclination_deg`); each sample sees it through one attitude of the sensor, and the
sensor output is the forward model B_M = diag(1 + s) T (A B) + Z_p plus white Gaussian noise on
each axis.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .. import validation
from ..calibration.result import read_parameters
from ..errors import InputError
from ..models.zhou2010 import Zhou2010Parameters, forward
from ..results import DocumentReader
from . import liu2022, qiu2017
from .attitudes import (
    ATTITUDE_ALIASES,
    ATTITUDES,
    MAX_TILT_LIMIT_DEG,
    TILTED,
    random_rotations,
    world_field,
)

__all__ = [
    "ATTITUDES",
    "DIRECTORY_PRESETS",
    "PRESETS",
    "ZHOU2010_FIELD_NT",
    "ZHOU2010_PARAMETERS",
    "Preset",
    "liu2022",
    "parameters_from_json",
    "qiu2017",
    "random_rotations",
    "simulate",
    "world_field",
    "write_directory_preset",
]

#: Final parameters and mean field of the laboratory application in [1] (section 6, Table 1).
ZHOU2010_PARAMETERS = Zhou2010Parameters(
    z_x=-71.55,
    z_y=188.13,
    z_z=116.29,
    s_x=0.0072,
    s_y=-0.0024,
    s_z=-0.0049,
    alpha_deg=-2.34,
    beta_deg=1.29,
    gamma_deg=-0.27,
)
ZHOU2010_FIELD_NT = 49462.0


@dataclass(frozen=True)
class Preset:
    parameters: Zhou2010Parameters
    field: float  # [nT]
    description: str


PRESETS = {
    "zhou2010": Preset(
        ZHOU2010_PARAMETERS,
        ZHOU2010_FIELD_NT,
        "final parameters and field (49 462 nT) of Zhou et al. 2010, Table 1",
    ),
}

#: Presets that write a folder of logs rather than one log: name -> writer, called as
#: writer(out_dir, seed=..., noise=..., n=...) and returning the paths it wrote (all together,
#: `nlpcal.io.files.Outputs`).
DIRECTORY_PRESETS = {
    "liu2022": liu2022.write_replica,
    "qiu2017": qiu2017.write_replica,
}


def simulate(
    n: int = 2000,
    *,
    parameters: Zhou2010Parameters = ZHOU2010_PARAMETERS,
    reference_field: float | None = None,
    field: float | None = None,
    noise: float = 1.0,
    seed: int = 0,
    attitudes: str = "uniform",
    inclination_deg: float = 60.0,
    max_tilt_deg: float | None = None,
) -> pd.DataFrame:
    """A synthetic log: a sensor with the errors of Eq. 4 in [1] turned through many attitudes.

    Parameters
    ----------
    n : int
        Number of samples (`-n`).
    parameters : Zhou2010Parameters
        The truth of Eq. 4 in [1] (`--params`); default the paper's Table 1 truth.
    reference_field : float, optional
        Magnitude of the constant field (`--reference-field`; default 49 462 nT, Table 1 of
        [1]). [nT]
    field : float, optional
        The former name of `reference_field`, still accepted. [nT]
    noise : float
        Standard deviation of white noise on each axis (`--noise`). [nT]
    seed : int
        Random seed of the attitudes and the noise (`--seed`).
    attitudes : str
        The attitude set: "uniform", "turntable", "tilt_band" (or "tilt"), ...
    inclination_deg : float
        Inclination of the field below the horizontal. [deg]
    max_tilt_deg : float, optional
        With attitudes "tilt": the largest roll and pitch, each uniform within +-max_tilt_deg,
        heading free (at most 90). [deg]

    Returns
    -------
    pandas.DataFrame
        Columns bx, by, bz, the raw sensor output B_M. [nT]

    Raises
    ------
    InputError
        An unusable count, noise, field or attitude set.

    References
    ----------
    [1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> import nlpcal
    >>> log = nlpcal.simulate(300, noise=0.5, seed=7)
    >>> list(log.columns), len(log)
    (['bx', 'by', 'bz'], 300)
    """
    n = validation.count(n, "the number of samples (-n)")
    noise = validation.number(noise, "the noise (--noise)", minimum=0.0, unit="nT")
    field = validation.renamed(reference_field, field, "reference_field", "field")
    field = validation.number(
        ZHOU2010_FIELD_NT if field is None else field, "the field", positive=True, unit="nT"
    )
    validation.choice(attitudes, "attitude set", [*ATTITUDES, *ATTITUDE_ALIASES])
    attitudes = ATTITUDE_ALIASES.get(attitudes, attitudes)
    rng = np.random.default_rng(seed)
    rotations = ATTITUDES[attitudes](n, rng, **_attitude_options(attitudes, max_tilt_deg))
    true_field = rotations @ world_field(field, inclination_deg)  # A B, ideal sensor frame
    output = forward(true_field, parameters) + noise * rng.normal(size=(n, 3))
    return pd.DataFrame(output, columns=["bx", "by", "bz"])


def _attitude_options(attitudes: str, max_tilt_deg) -> dict:
    """The keyword arguments of the attitude set: the largest tilt [deg] of the tilt set when
    given (InputError for another set)."""
    if max_tilt_deg is None:
        return {}
    if attitudes != TILTED:
        raise InputError(
            f"the largest tilt (--max-tilt-deg) applies to --attitudes tilt, not {attitudes}"
        )
    return {
        "max_tilt_deg": validation.number(
            max_tilt_deg,
            "the largest tilt (--max-tilt-deg)",
            positive=True,
            maximum=MAX_TILT_LIMIT_DEG,
            unit="deg",
        )
    }


def write_directory_preset(name: str, out_dir, *, seed: int = 0, noise=None, n=None) -> list:
    """Write the folder of logs of a directory preset; returns the paths written."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    return DIRECTORY_PRESETS[name](out_dir, seed=seed, noise=noise, n=n)


def parameters_from_json(document, source: str = "the parameters JSON"):
    """Truth from a JSON document: {"parameters": {...}, "field_nT": F} or the nine keys alone.

    Returns (Zhou2010Parameters, field [nT] or None); every value is checked.
    """
    reader = DocumentReader(document, source)
    if not reader.has("parameters"):
        reader = DocumentReader(
            {
                "parameters": document,
                **{k: v for k, v in document.items() if k in ("field_nT", "field")},
            },
            source,
        )
    params = read_parameters(reader)
    key = "field_nT" if reader.has("field_nT") else "field"
    return params, reader.number(key, None, positive=True)
