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

import numpy as np
import pandas as pd

from .errors import InputError
from .models.zhou2010 import Zhou2010Parameters, forward

#: Final parameters and mean field of the laboratory application in [1] (section 6, Table 1).
ZHOU2010_PARAMETERS = Zhou2010Parameters(
    z_x=-71.55, z_y=188.13, z_z=116.29,
    s_x=0.0072, s_y=-0.0024, s_z=-0.0049,
    alpha_deg=-2.34, beta_deg=1.29, gamma_deg=-0.27,
)
ZHOU2010_FIELD_NT = 49462.0


@dataclass(frozen=True)
class Preset:
    parameters: Zhou2010Parameters
    field: float  # [nT]
    description: str


PRESETS = {
    "zhou2010": Preset(ZHOU2010_PARAMETERS, ZHOU2010_FIELD_NT,
                       "final parameters and field (49 462 nT) of Zhou et al. 2010, Table 1"),
}


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """n rotation matrices drawn uniformly (Haar measure) from unit quaternions. [1]"""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=1)


def uniform_attitudes(n: int, rng: np.random.Generator) -> np.ndarray:
    """Attitudes uniform over all rotations: (n, 3, 3) world-to-sensor matrices."""
    return random_rotations(n, rng)


def _axis_rotations(axes, angles) -> np.ndarray:
    """(n, 3, 3) rotations by `angles` [rad] about `axes`, one (3,) axis or (n, 3) axes.

    Rodrigues' formula R = I + sin t K + (1 - cos t) K^2, K the cross-product matrix of the
    unit axis. A zero axis gives the identity. [1]
    """
    angles = np.atleast_1d(np.asarray(angles, dtype=float))
    axes = np.broadcast_to(np.asarray(axes, dtype=float), (angles.size, 3))
    length = np.linalg.norm(axes, axis=1, keepdims=True)
    unit = np.divide(axes, length, out=np.zeros_like(axes), where=length > 0)
    x, y, z = unit.T
    zero = np.zeros_like(x)
    k = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1),
                  np.stack([-y, x, zero], -1)], axis=1)
    c, s = np.cos(angles)[:, None, None], np.sin(angles)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


#: Mountings of the sensor on the turntable (table-to-sensor rotations): the sensor's z, x and y
#: axis in turn along the vertical turntable axis, and one oblique mounting (the fourth turn of
#: Qiu et al. 2017 is about a tilted axis).
TURNTABLE_MOUNTINGS = (
    np.eye(3),
    np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
    np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    _axis_rotations(np.array([1.0, 1.0, 0.0]), np.radians(45.0))[0],
)


def turntable_attitudes(n: int, rng: np.random.Generator, *, mountings=TURNTABLE_MOUNTINGS,
                        wobble_deg: float = 0.2) -> np.ndarray:
    """Full turns about the vertical of a turntable, with the sensor in a few fixed mountings.

    Like the laboratory data of [1]: the log is one turn per mounting, one after the other (about
    n/len(mountings) samples each), at headings drawn uniformly in [0, 360) deg about the vertical
    (the down axis of the world frame) and sorted as the table turns, with a small random wobble
    of the table axis. The field directions seen by the sensor lie on one cone per mounting, not
    over the whole sphere.

    wobble_deg : standard deviation of the tilt of the turntable axis. [deg]
    Returns (n, 3, 3) world-to-sensor rotations. [1]
    """
    which = np.arange(n) * len(mountings) // max(n, 1)  # one turn after the other
    mount = np.asarray(mountings, dtype=float)[which]
    angles = rng.uniform(0.0, 2.0 * np.pi, n)
    angles = angles[np.lexsort((angles, which))]  # increasing within each turn
    heading = _axis_rotations(np.array([0.0, 0.0, 1.0]), angles)
    tilt_axis = np.column_stack([rng.normal(size=(n, 2)), np.zeros(n)])  # horizontal axes
    wobble = _axis_rotations(tilt_axis, np.radians(wobble_deg) * rng.normal(size=n))
    return mount @ wobble @ heading


def tilt_band_attitudes(n: int, rng: np.random.Generator, *,
                        max_tilt_deg: float = 30.0) -> np.ndarray:
    """Any heading, but roll and pitch limited to +-max_tilt_deg (a vehicle, a hand-held swing).

    Heading uniform in [0, 360) deg about the vertical; roll and pitch uniform in
    [-max_tilt_deg, max_tilt_deg]. The sensor z axis stays within the band around the vertical,
    so the vertical field component it sees hardly changes: z offset and z scale are coupled.

    max_tilt_deg : largest roll and pitch. [deg]
    Returns (n, 3, 3) world-to-sensor rotations. [1]
    """
    limit = np.radians(max_tilt_deg)
    heading = _axis_rotations(np.array([0.0, 0.0, 1.0]), rng.uniform(0.0, 2.0 * np.pi, n))
    pitch = _axis_rotations(np.array([0.0, 1.0, 0.0]), rng.uniform(-limit, limit, n))
    roll = _axis_rotations(np.array([1.0, 0.0, 0.0]), rng.uniform(-limit, limit, n))
    return roll @ pitch @ heading


def clustered_attitudes(n: int, rng: np.random.Generator, *, clusters: int = 6,
                        spread_deg: float = 12.0) -> np.ndarray:
    """A few clusters of attitudes: the sensor set down in `clusters` random orientations and
    jiggled around each by a rotation of about `spread_deg` (uneven, patchy coverage). The log
    visits the clusters one after the other; their sizes are random.

    clusters : number of cluster centres, drawn uniformly over all rotations.
    spread_deg : standard deviation of the rotation angle about a random axis around a centre.
        [deg]
    Returns (n, 3, 3) world-to-sensor rotations. [1]
    """
    centres = random_rotations(clusters, rng)
    which = np.sort(rng.integers(0, clusters, n))
    jiggle = _axis_rotations(rng.normal(size=(n, 3)), np.radians(spread_deg) * rng.normal(size=n))
    return jiggle @ centres[which]


#: Attitude distributions: name -> f(n, rng) returning (n, 3, 3) world-to-sensor rotations.
ATTITUDES = {
    "uniform": uniform_attitudes,
    "turntable": turntable_attitudes,
    "tilt_band": tilt_band_attitudes,
    "clustered": clustered_attitudes,
}


def world_field(field: float, inclination_deg: float = 60.0) -> np.ndarray:
    """Field vector in north-east-down coordinates, pointing north and down. [nT]"""
    inc = np.radians(inclination_deg)
    return field * np.array([np.cos(inc), 0.0, np.sin(inc)])


def simulate(n: int = 2000, *, parameters: Zhou2010Parameters = ZHOU2010_PARAMETERS,
             field: float = ZHOU2010_FIELD_NT, noise: float = 1.0, seed: int = 0,
             attitudes: str = "uniform", inclination_deg: float = 60.0) -> pd.DataFrame:
    """A log of n samples with columns bx, by, bz. [nT]

    parameters : the truth of Eq. 4 in [1].
    field : magnitude of the constant field. [nT]
    noise : standard deviation of white noise on each axis. [nT]
    attitudes : a name in ATTITUDES.
    """
    if n < 1:
        raise InputError(f"-n must be positive, got {n}")
    if noise < 0 or not np.isfinite(noise):
        raise InputError(f"--noise must be a non-negative number, got {noise}")
    if not field > 0:
        raise InputError(f"the field must be positive, got {field}")
    if attitudes not in ATTITUDES:
        raise InputError(f"unknown attitude set {attitudes!r}; expected one of "
                         f"{', '.join(ATTITUDES)}")
    rng = np.random.default_rng(seed)
    rotations = ATTITUDES[attitudes](n, rng)
    true_field = rotations @ world_field(field, inclination_deg)  # A B, ideal sensor frame
    output = forward(true_field, parameters) + noise * rng.normal(size=(n, 3))
    return pd.DataFrame(output, columns=["bx", "by", "bz"])


def parameters_from_json(document) -> tuple[Zhou2010Parameters, float | None]:
    """Truth from a JSON document: {"parameters": {...}, "field_nT": F} or the nine keys alone."""
    if not isinstance(document, dict):
        raise InputError("the parameters JSON must be an object")
    values = document.get("parameters", document)
    try:
        params = Zhou2010Parameters.from_dict(values)
    except KeyError as exc:
        raise InputError(f"parameters JSON: {exc.args[0]}") from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"parameters JSON: {exc}") from None
    field = document.get("field_nT", document.get("field"))
    if field is not None:
        try:
            field = float(field)
        except (TypeError, ValueError):
            raise InputError(f"parameters JSON: field_nT must be a number, got {field!r}") from None
    return params, field
