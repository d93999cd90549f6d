"""The worst-case total-field error of non-orthogonal axes (Eq. 9 of Wang et al. 2015).

The problem is non-convex in (theta, phi) but it is a Rayleigh quotient in disguise
(`nlpcal.models.wang2015`): the exact extremes B (sigma - 1) certify the multistart IPOPT result
and give two of its starts.

References
----------
[1] Wang et al. (2015), see `nlpcal.models.wang2015`.
[2] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import validation
from ..errors import SolveError
from ..models.wang2015 import small_angle_worst_case
from ..models.zhou2010 import axis_matrix_entries
from ..nlp.orthogonality import worst_case_solver
from ..nlp.solver import SolveOutcome, solve
from ..results import Document, DocumentReader

# Deterministic multistart directions for the worst case (theta, phi) [deg]: four azimuths at three
# latitudes, away from the poles where the (theta, phi) chart is singular.
_FIXED_STARTS_DEG = tuple(
    (theta, phi) for phi in (-45.0, 0.0, 45.0) for theta in (45.0, 135.0, 225.0, 315.0)
)


@dataclass(frozen=True)
class Extremum:
    """One signed extreme of dB over the sphere."""

    delta_B_nT: float  #: the extreme total-field error. [nT]
    theta_deg: float  #: azimuth where it occurs, in [0, 360). [deg]
    phi_deg: float  #: elevation where it occurs, in [-90, 90]. [deg]
    status: str  #: IPOPT return status of the best start.
    iterations: int  #: IPOPT iterations of the best start.

    def to_dict(self) -> dict:
        return {
            "delta_B_nT": self.delta_B_nT,
            "theta_deg": self.theta_deg,
            "phi_deg": self.phi_deg,
            "ipopt_status": self.status,
            "iterations": self.iterations,
        }


@dataclass(frozen=True)
class WorstCase(Document):
    """Worst-case total-field error of a probe with known angles (Eq. 9 in [1]).

    Attributes
    ----------
    angles_deg : tuple
        (alpha, beta, gamma). [deg]
    field_nT : float
        Total field magnitude. [nT]
    largest_positive, most_negative : Extremum
        Max and min of dB over all directions, with their directions theta, phi [deg].
    exact_min_nT, exact_max_nT : float
        B (sigma_min(T) - 1) and B (sigma_max(T) - 1), the analytic brackets. [nT]
    small_angle_nT : float
        (B / 2) max |eig(G)|, first order in the angles. [nT]
    starts : int
        IPOPT starts per sign.

    References
    ----------
    [1] Wang et al. (2015), see `nlpcal.models.wang2015`.

    Examples
    --------
    >>> import nlpcal
    >>> case = nlpcal.worst_case((0.1, 0.1, 0.1), 55_000.0)
    >>> abs(case.most_negative.delta_B_nT - case.exact_min_nT) < 1e-3  # certified [nT]
    True
    """

    FORMAT = "nlpcal-orthogonality-worst-case"
    LEGACY_FORMATS = (("schema", "nlpcal.orthogonality.worst_case/1"),)
    WHAT = "nlpcal worst-case file"

    angles_deg: tuple
    field_nT: float
    largest_positive: Extremum
    most_negative: Extremum
    exact_min_nT: float
    exact_max_nT: float
    small_angle_nT: float
    starts: int

    @property
    def max_abs_error_nT(self) -> float:
        """max |dB| over all directions. [nT]"""
        return max(self.largest_positive.delta_B_nT, -self.most_negative.delta_B_nT)

    @property
    def worst(self) -> Extremum:
        """The signed extreme with the larger magnitude."""
        if self.largest_positive.delta_B_nT >= -self.most_negative.delta_B_nT:
            return self.largest_positive
        return self.most_negative

    def body(self) -> dict:
        worst = self.worst
        return {
            "schema": "nlpcal.orthogonality.worst_case/1",
            "angles_deg": list(self.angles_deg),
            "angle_convention": "zhou2010",
            "field_nT": self.field_nT,
            "max_abs_error_nT": self.max_abs_error_nT,
            "theta_deg": worst.theta_deg,
            "phi_deg": worst.phi_deg,
            "largest_positive": self.largest_positive.to_dict(),
            "most_negative": self.most_negative.to_dict(),
            "analytic": {
                "exact_min_nT": self.exact_min_nT,
                "exact_max_nT": self.exact_max_nT,
                "small_angle_max_abs_nT": self.small_angle_nT,
            },
            "starts_per_sign": self.starts,
        }

    @classmethod
    def from_body(cls, reader: DocumentReader) -> WorstCase:
        def extremum(key):
            part = reader.reader(key)
            return Extremum(
                part.number("delta_B_nT"),
                part.number("theta_deg"),
                part.number("phi_deg"),
                part.string("ipopt_status", ""),
                part.integer("iterations", 0),
            )

        analytic = reader.reader("analytic")
        return cls(
            angles_deg=tuple(reader.array("angles_deg", (3,))),
            field_nT=reader.number("field_nT", positive=True),
            largest_positive=extremum("largest_positive"),
            most_negative=extremum("most_negative"),
            exact_min_nT=analytic.number("exact_min_nT"),
            exact_max_nT=analytic.number("exact_max_nT"),
            small_angle_nT=analytic.number("small_angle_max_abs_nT"),
            starts=reader.integer("starts_per_sign", 0),
        )


def _start_directions(vector) -> list:
    """The fixed starts plus +-`vector` (an extreme eigenvector of T^T T), as (theta, phi) [rad]."""
    starts = [(math.radians(t), math.radians(p)) for t, p in _FIXED_STARTS_DEG]
    for v in (vector, -vector):
        phi = math.asin(max(-1.0, min(1.0, float(v[2]))))
        # nudge off the pole, where theta is undefined and the phi bound would be active
        phi = max(-math.pi / 2 + 1e-6, min(math.pi / 2 - 1e-6, phi))
        starts.append((math.atan2(float(v[1]), float(v[0])), phi))
    return starts


def worst_case(
    angles_deg,
    reference_field: float | None = None,
    *,
    field_nT: float | None = None,
    verbose: bool = False,
) -> WorstCase:
    """Largest positive and most negative dB over all field directions (Eq. 9 in [1]).

    Each sign is solved by IPOPT from 14 starts (12 fixed directions and the two extreme
    eigenvectors of T^T T); the best is certified against the analytic bracket B (sigma - 1). The
    Rayleigh quotient u^T (T^T T) u has no local maxima on the sphere other than the global one, so
    a start that converges is global; the certificate guards against a start stalling at a saddle
    or at a pole of the (theta, phi) chart.

    Parameters
    ----------
    angles_deg : array_like, shape (3,)
        (alpha, beta, gamma) in the convention of [2] (`--angles-deg`). [deg]
    reference_field : float
        Total field magnitude B (`--reference-field`). [nT]
    field_nT : float, optional
        The former name of `reference_field`, still accepted. [nT]
    verbose : bool
        Print IPOPT's log.

    Returns
    -------
    WorstCase
        Both signed extremes with their directions, and the analytic brackets.

    Raises
    ------
    InputError
        Angles or field unusable.
    SolveError
        No start converged, or the best misses the analytic bracket.

    References
    ----------
    [1] Wang et al. (2015), see `nlpcal.models.wang2015`.
    [2] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> import nlpcal
    >>> case = nlpcal.worst_case((0.1, 0.1, 0.1), 55_000.0)
    >>> round(case.max_abs_error_nT)  # "about 95 nT" in [1] [nT]
    96
    """
    angles = validation.angles(angles_deg)
    b = validation.field(
        validation.renamed(reference_field, field_nT, "reference_field", "field_nT")
    )
    t = np.array(axis_matrix_entries(*np.radians(angles)), dtype=float)
    eigenvalues, eigenvectors = np.linalg.eigh(t.T @ t)
    sigma_min, sigma_max = math.sqrt(eigenvalues[0]), math.sqrt(eigenvalues[-1])
    kappa = max(sigma_max - 1.0, 1.0 - sigma_min)
    if kappa <= 1e-15:  # orthogonal axes: dB vanishes everywhere
        kappa = 1.0
    solver = worst_case_solver(bool(verbose))
    extremes = {}
    for sign, exact, vector in (
        (1.0, sigma_max - 1.0, eigenvectors[:, -1]),
        (-1.0, sigma_min - 1.0, eigenvectors[:, 0]),
    ):
        extremes[sign] = _extremum(solver, angles, b, sign, exact, vector, kappa)
    return WorstCase(
        angles_deg=tuple(float(a) for a in angles),
        field_nT=b,
        largest_positive=extremes[1.0],
        most_negative=extremes[-1.0],
        exact_min_nT=b * (sigma_min - 1.0),
        exact_max_nT=b * (sigma_max - 1.0),
        small_angle_nT=small_angle_worst_case(angles, b),
        starts=len(_FIXED_STARTS_DEG) + 2,  # per extremum: the fixed ones, +-its eigenvector
    )


def _extremum(solver, angles, b: float, sign: float, exact: float, vector, kappa: float):
    """The extremum of dB of one sign (+1 largest positive, -1 most negative) [nT], the best of
    IPOPT's starts about the singular vector `vector`, checked against its analytic value
    `exact` (dB / B); its direction in degrees with phi >= 0 (dB is even in B)."""
    starts = _start_directions(vector)
    best: SolveOutcome | None = None
    statuses = set()
    for theta0, phi0 in starts:
        outcome = solve(
            solver,
            x0=[theta0, phi0],
            p=[*np.radians(angles), sign, kappa],
            lbx=[-np.inf, -math.pi / 2],
            ubx=[np.inf, math.pi / 2],
        )
        statuses.add(outcome.status)
        if outcome.success and (best is None or outcome.f < best.f):
            best = outcome
    what = "largest positive" if sign > 0 else "most negative"
    if best is None:
        raise SolveError(
            f"no IPOPT start converged for the {what} total-field error",
            status=", ".join(sorted(statuses)),
        )
    relative = -sign * best.f * kappa  # back to dB / B
    if abs(relative - exact) > 1e-9 * kappa + 1e-13:
        raise SolveError(
            f"the {what} total-field error found by IPOPT ({b * relative:.6g} nT) misses the "
            f"analytic value ({b * exact:.6g} nT)",
            status=best.status,
        )
    theta_deg = math.degrees(best.x[0]) % 360.0
    phi_deg = float(np.clip(math.degrees(best.x[1]), -90.0, 90.0))
    if phi_deg < 0.0:  # dB is even in B: of the two antipodes, report the one with phi >= 0
        theta_deg, phi_deg = (theta_deg + 180.0) % 360.0, -phi_deg
    if theta_deg >= 360.0:
        theta_deg = 0.0
    return Extremum(b * relative, theta_deg, phi_deg, best.status, best.iterations)


def implied_worst_case(deviation_deg, field_nT) -> float:
    """Worst-case |dB| that an angle uncertainty of +-deviation_deg on every angle implies.

    The largest max |dB| over the eight corners (+-d, +-d, +-d) of the deviation box (one value d
    for all three angles, or three values). To first order every corner of a cube gives the same
    max |eig(G)| = 2 d, which by Gershgorin's theorem is also the largest over the whole box.

    Parameters
    ----------
    deviation_deg : float or array_like of shape (3,)
        The deviation d of every angle, or one per angle. [deg]
    field_nT : float
        Total field magnitude. [nT]

    Returns
    -------
    float
        The worst-case |dB|. [nT]

    Raises
    ------
    InputError
        Deviations or field unusable.

    References
    ----------
    [1] Wang et al. (2015), see `nlpcal.models.wang2015`.

    Examples
    --------
    >>> import nlpcal
    >>> round(nlpcal.implied_worst_case(0.004, 55_000.0), 1)  # "at most 3.8 nT" in [1] [nT]
    3.8
    """
    deviation = np.abs(np.asarray(deviation_deg, dtype=float).ravel())
    if deviation.size == 1:
        deviation = np.repeat(deviation, 3)
    deviation = validation.angles(deviation, what="deviations")
    b = validation.field(field_nT)
    worst = 0.0
    for signs in np.array(np.meshgrid([1, -1], [1, -1], [1, -1])).T.reshape(-1, 3):
        worst = max(worst, worst_case(signs * deviation, b).max_abs_error_nT)
    return worst
