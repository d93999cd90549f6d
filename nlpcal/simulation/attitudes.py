"""Attitude sets for synthetic logs: (n, 3, 3) world-to-sensor rotations.

The world frame is north-east-down; each set describes how a sensor is turned while it logs.
"""

from __future__ import annotations

import numpy as np


def random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    """n rotation matrices drawn uniformly (Haar measure) from unit quaternions. [1]"""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=1,
    )


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
    k = np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)],
        axis=1,
    )
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


def turntable_attitudes(
    n: int, rng: np.random.Generator, *, mountings=TURNTABLE_MOUNTINGS, wobble_deg: float = 0.2
) -> np.ndarray:
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


#: Largest roll and pitch of the tilted attitudes by default, and the largest accepted. [deg]
MAX_TILT_DEFAULT_DEG = 30.0
MAX_TILT_LIMIT_DEG = 90.0


def tilt_band_attitudes(
    n: int, rng: np.random.Generator, *, max_tilt_deg: float = MAX_TILT_DEFAULT_DEG
) -> np.ndarray:
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


def clustered_attitudes(
    n: int, rng: np.random.Generator, *, clusters: int = 6, spread_deg: float = 12.0
) -> np.ndarray:
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
#: Other names of attitude sets: "tilt" (heading free, roll and pitch within +-max_tilt_deg).
ATTITUDE_ALIASES = {"tilt": "tilt_band"}
#: The attitude set whose largest roll and pitch can be chosen (max_tilt_deg).
TILTED = "tilt_band"


def world_field(field: float, inclination_deg: float = 60.0) -> np.ndarray:
    """Field vector in north-east-down coordinates, pointing north and down. [nT]"""
    inc = np.radians(inclination_deg)
    return field * np.array([np.cos(inc), 0.0, np.sin(inc)])
