"""Non-orthogonality of a triaxial probe: worst-case total-field error, error map, angle inversion.

Wang, Zong, Zhao and Cheng [1] consider only the non-orthogonality of the three axes (unit
sensitivities, zero offsets). With the probe output written as

    B' = T B                                                      Eq. 1-2 in [1]

the total-field error is

    dB = |B'| - |B|                                               Eq. 4 in [1]

and for a field of magnitude B along the direction (theta, phi),

    B = B (cos(phi) cos(theta), cos(phi) sin(theta), sin(phi))     Eq. 5 in [1]
    dB(theta, phi) = B (|T u(theta, phi)| - 1)                    Eq. 7-8 in [1]

nlpcal uses the angle convention of Zhou et al. (2010) [2] throughout, so T is the axis matrix of
`nlpcal.models.zhou2010` (rows: the sensor axes in the ideal frame):

    T = [[cos(alpha) cos(gamma), cos(alpha) sin(gamma), -sin(alpha)],
         [0,                     cos(beta),              sin(beta)  ],
         [0,                     0,                      1          ]]

[1] names its angles alpha, beta and 90 deg - gamma between probe axes; the mapping to [2] is in
`../shared/REFERENCE.md`. The surviving text of [1] lost its equation images; the numbers above
follow the text's own references to Eq. 4, 6 and 9.

Three problems are built here, each once per process as a CasADi NLP solved by IPOPT:

* worst case (Eq. 9 in [1]): max over (theta, phi) of +dB and of -dB. The problem is non-convex in
  (theta, phi) but it is a Rayleigh quotient in disguise: |T u|^2 = u^T (T^T T) u on the unit
  sphere, so the exact extremes are B (sigma_max - 1) and B (sigma_min - 1) with sigma the singular
  values of T. That analytic bracket certifies the multistart result (and gives two of its starts).
  To first order in the angles [rad], T^T T = I + G with

      G = [[0, gamma, -alpha], [gamma, 0, beta], [-alpha, beta, 0]]

  and dB ~= (B / 2) u^T G u, so max |dB| ~= (B / 2) max |eig(G)| (the small-angle value). For
  alpha = beta = gamma = e the eigenvalues of G are (e, e, -2e), giving max |dB| ~= B e: 96.0 nT
  for 0.1 deg at 55 000 nT (the paper reports "about 95 nT").
* inversion (section 2 of [1]): the three angles minimising the spread of the corrected total
  field |T^-1 B'_i| around its mean (the paper's objective), or around a known field B (the
  reference variant, Eq. 4 in [1] summed over the samples), under bounds on the angles.
* repeatability (Table 4 in [1]): several inversions of the same probe, their mean, the largest
  deviation from the mean, and the worst-case total-field error that deviation implies.

References
----------
[1] Wang Y., Zong F., Zhao Y., Cheng D. (2015). Calibration and measurement on the orthogonal
    three-axes of three-components magnetic flux-gate sensor. Journal of Shandong Agricultural
    University (Natural Science Edition), 2015(2), 232-237. (No DOI in the source text.)
[2] Zhou C., Jin J., Li H., Zhang B., Yan H. (2010). Cyclic optimisation algorithm for the
    calibration of triaxial fluxgate sensors. Hydrographic Surveying and Charting 30(4), 63-66.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np

from .errors import InputError, SolveError
from .io import check_samples
from .models.zhou2010 import axis_matrix_entries, correction_matrix_entries
from .solver import IpoptOptions, SolveOutcome, build_nlpsol, solve
from .statistics import lag1_autocorrelation, standard_error_inflation

#: Angle names in the order used everywhere (Zhou 2010 convention).
ANGLE_NAMES = ("alpha", "beta", "gamma")
#: Largest accepted |angle|: at 90 deg the axis matrix T is singular. [deg]
MAX_ANGLE_DEG = 89.0
#: Default bound of the inversion, as in section 2 of [1]. [deg]
DEFAULT_BOUND_DEG = 0.5
#: Fewest samples the inversion accepts (three angles plus the mean field).
MIN_INVERSION_SAMPLES = 10
#: A solution within this fraction of its bound counts as on the bound. [1]
BOUND_ACTIVE_REL_TOL = 1e-3
#: Field of the paper's forward modelling and synthetic inversion. [nT]
PAPER_FIELD_NT = 55_000.0

# Deterministic multistart directions for the worst case (theta, phi) [deg]: four azimuths at three
# latitudes, away from the poles where the (theta, phi) chart is singular.
_FIXED_STARTS_DEG = tuple((theta, phi) for phi in (-45.0, 0.0, 45.0)
                          for theta in (45.0, 135.0, 225.0, 315.0))


# --------------------------------------------------------------------------------------------
# validation shared by the library and the command line


def check_angles(angles_deg, what: str = "angles") -> np.ndarray:
    """Three finite non-orthogonality angles (alpha, beta, gamma), each |angle| <= 89 deg. [deg]"""
    try:
        angles = np.asarray(angles_deg, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(f"{what} must be three numbers (alpha beta gamma) in degrees") from None
    if angles.size != 3:
        raise InputError(f"got {angles.size} {what}, expected 3 (alpha beta gamma) in degrees")
    if not np.isfinite(angles).all():
        raise InputError(f"{what} must be finite, got {_fmt_list(angles)} deg")
    if (np.abs(angles) > MAX_ANGLE_DEG).any():
        raise InputError(
            f"{what} must lie within +-{MAX_ANGLE_DEG:g} deg (the axes become parallel at 90 deg), "
            f"got {_fmt_list(angles)} deg")
    return angles


def check_field(field_nT, what: str = "field") -> float:
    """A positive finite field magnitude. [nT]"""
    try:
        value = float(field_nT)
    except (TypeError, ValueError):
        raise InputError(f"the {what} must be a positive number in nT, got {field_nT!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise InputError(f"the {what} must be a positive number in nT, got {value:g}")
    return value


def check_bounds(bound_deg) -> np.ndarray:
    """One bound for all three angles or three bounds; each in (0, 89] deg. [deg]"""
    try:
        bounds = np.asarray(bound_deg, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError("the bound must be one or three positive numbers in degrees") from None
    if bounds.size == 1:
        bounds = np.repeat(bounds, 3)
    if bounds.size != 3:
        raise InputError(f"got {bounds.size} bounds, expected 1 or 3 (alpha beta gamma) in degrees")
    if not np.isfinite(bounds).all() or (bounds <= 0).any() or (bounds > MAX_ANGLE_DEG).any():
        raise InputError(
            f"bounds must lie in (0, {MAX_ANGLE_DEG:g}] deg, got {_fmt_list(bounds)} deg")
    return bounds


def _fmt_list(values) -> str:
    return "[" + ", ".join(f"{v:g}" for v in np.asarray(values, dtype=float).ravel()) + "]"


# --------------------------------------------------------------------------------------------
# forward model (numpy)


def direction(theta_deg, phi_deg) -> np.ndarray:
    """Unit vectors u(theta, phi) of Eq. 5 in [1], shape (..., 3).

    theta_deg : azimuth in the ideal frame, in [0, 360). [deg]
    phi_deg : elevation above the x-y plane, in [-90, 90]. [deg]
    """
    theta, phi = np.broadcast_arrays(np.radians(np.asarray(theta_deg, dtype=float)),
                                     np.radians(np.asarray(phi_deg, dtype=float)))
    return np.stack([np.cos(phi) * np.cos(theta), np.cos(phi) * np.sin(theta), np.sin(phi)],
                    axis=-1)


def axis_matrix_deg(angles_deg) -> np.ndarray:
    """T of Eq. 2 in [1] in the angle convention of [2] (unit scale, zero offset). [1]"""
    return np.array(axis_matrix_entries(*np.radians(check_angles(angles_deg))), dtype=float)


def total_field_error(angles_deg, field_nT, theta_deg, phi_deg) -> np.ndarray:
    """dB = |T B| - |B| for a field of magnitude `field_nT` along (theta, phi). [nT]

    Eq. 4 and 8 in [1]. theta_deg and phi_deg broadcast against each other. [deg]
    """
    t = axis_matrix_deg(angles_deg)
    b = check_field(field_nT)
    u = direction(theta_deg, phi_deg)
    return b * (np.linalg.norm(u @ t.T, axis=-1) - 1.0)                    # Eq. 8


def small_angle_form(angles_deg) -> np.ndarray:
    """G, the first-order part of T^T T - I in the angles, symmetric 3 x 3. [1]

    dB ~= (B / 2) u^T G u, so max |dB| ~= (B / 2) max |eig(G)|.
    """
    alpha, beta, gamma = np.radians(check_angles(angles_deg))
    return np.array([[0.0, gamma, -alpha], [gamma, 0.0, beta], [-alpha, beta, 0.0]])


def small_angle_worst_case(angles_deg, field_nT) -> float:
    """max |dB| to first order in the angles: (B / 2) max |eig(G)|. [nT]"""
    return 0.5 * check_field(field_nT) * float(np.max(np.abs(
        np.linalg.eigvalsh(small_angle_form(angles_deg)))))


def exact_bracket(angles_deg, field_nT) -> tuple:
    """(min dB, max dB) over all directions, exactly: B (sigma_min - 1), B (sigma_max - 1). [nT]

    |T u|^2 = u^T (T^T T) u is a Rayleigh quotient, so its extremes on the unit sphere are the
    extreme eigenvalues of T^T T, the squared singular values of T.
    """
    b = check_field(field_nT)
    sigma = np.linalg.svd(axis_matrix_deg(angles_deg), compute_uv=False)
    return b * (float(sigma.min()) - 1.0), b * (float(sigma.max()) - 1.0)


def error_map(angles_deg, field_nT, step_deg: float = 1.0):
    """dB on a regular (theta, phi) grid: the map of Fig. 4 in [1].

    step_deg : grid step in both angles, in (0, 10]. [deg]
    Returns theta [deg] (n_theta,), phi [deg] (n_phi,), dB [nT] (n_phi, n_theta).
    """
    step = float(step_deg)
    if not math.isfinite(step) or step <= 0 or step > 10:
        raise InputError(f"the map step must lie in (0, 10] deg, got {step_deg!r}")
    theta = np.arange(0.0, 360.0, step)
    phi = np.linspace(-90.0, 90.0, int(round(180.0 / step)) + 1)
    error = total_field_error(angles_deg, field_nT, theta[None, :], phi[:, None])
    return theta, phi, error


# --------------------------------------------------------------------------------------------
# worst case: Eq. 9 in [1] as an NLP in (theta, phi)


@lru_cache(maxsize=None)
def _worst_case_solver(verbose: bool = False):
    """min_{theta, phi} -s (|T u| - 1) / kappa, built once per process.

    x = (theta, phi) [rad]; p = (alpha, beta, gamma [rad], s = +1 or -1, kappa [1]). kappa, the
    size of the analytic bracket, scales the objective to order 1. dB / B does not depend on B,
    so B is applied afterwards.
    """
    x = ca.SX.sym("x", 2)
    p = ca.SX.sym("p", 5)
    theta, phi = x[0], x[1]
    alpha, beta, gamma, sign, kappa = (p[i] for i in range(5))
    u = ca.vertcat(ca.cos(phi) * ca.cos(theta), ca.cos(phi) * ca.sin(theta), ca.sin(phi))  # Eq. 5
    t = ca.vertcat(*[ca.horzcat(*row) for row in
                     axis_matrix_entries(alpha, beta, gamma, cos=ca.cos, sin=ca.sin)])  # Eq. 2
    relative_error = ca.sqrt(ca.sumsqr(ca.mtimes(t, u))) - 1.0                        # Eq. 8 / B
    objective = -sign * relative_error / kappa                                        # Eq. 9
    options = IpoptOptions(tol=1e-10, acceptable_tol=1e-8, max_iter=100,
                           print_level=5 if verbose else 0)
    return build_nlpsol("nlpcal_orthogonality_worst_case", x, objective, p, options=options)


@dataclass(frozen=True)
class Extremum:
    """One signed extreme of dB over the sphere."""

    delta_B_nT: float  #: the extreme total-field error. [nT]
    theta_deg: float  #: azimuth where it occurs, in [0, 360). [deg]
    phi_deg: float  #: elevation where it occurs, in [-90, 90]. [deg]
    status: str  #: IPOPT return status of the best start.
    iterations: int  #: IPOPT iterations of the best start.

    def as_dict(self) -> dict:
        return {"delta_B_nT": self.delta_B_nT, "theta_deg": self.theta_deg,
                "phi_deg": self.phi_deg, "ipopt_status": self.status,
                "iterations": self.iterations}


@dataclass(frozen=True)
class WorstCase:
    """Worst-case total-field error of a probe with known angles (Eq. 9 in [1])."""

    angles_deg: tuple  #: (alpha, beta, gamma). [deg]
    field_nT: float  #: total field magnitude. [nT]
    largest_positive: Extremum  #: max of dB over all directions.
    most_negative: Extremum  #: min of dB over all directions.
    exact_min_nT: float  #: B (sigma_min(T) - 1), the analytic lower bracket. [nT]
    exact_max_nT: float  #: B (sigma_max(T) - 1), the analytic upper bracket. [nT]
    small_angle_nT: float  #: (B / 2) max |eig(G)|, first order in the angles. [nT]
    starts: int  #: IPOPT starts per sign.

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

    def as_dict(self) -> dict:
        worst = self.worst
        return {
            "schema": "nlpcal.orthogonality.worst_case/1",
            "angles_deg": list(self.angles_deg),
            "angle_convention": "zhou2010",
            "field_nT": self.field_nT,
            "max_abs_error_nT": self.max_abs_error_nT,
            "theta_deg": worst.theta_deg,
            "phi_deg": worst.phi_deg,
            "largest_positive": self.largest_positive.as_dict(),
            "most_negative": self.most_negative.as_dict(),
            "analytic": {
                "exact_min_nT": self.exact_min_nT,
                "exact_max_nT": self.exact_max_nT,
                "small_angle_max_abs_nT": self.small_angle_nT,
            },
            "starts_per_sign": self.starts,
        }


def _start_directions(vector) -> list:
    """The fixed starts plus +-`vector` (an extreme eigenvector of T^T T), as (theta, phi) [rad]."""
    starts = [(math.radians(t), math.radians(p)) for t, p in _FIXED_STARTS_DEG]
    for v in (vector, -vector):
        phi = math.asin(max(-1.0, min(1.0, float(v[2]))))
        # nudge off the pole, where theta is undefined and the phi bound would be active
        phi = max(-math.pi / 2 + 1e-6, min(math.pi / 2 - 1e-6, phi))
        starts.append((math.atan2(float(v[1]), float(v[0])), phi))
    return starts


def worst_case(angles_deg, field_nT, *, verbose: bool = False) -> WorstCase:
    """Largest positive and most negative dB over all field directions (Eq. 9 in [1]).

    angles_deg : (alpha, beta, gamma) in the convention of [2]. [deg]
    field_nT : total field magnitude B. [nT]

    Each sign is solved by IPOPT from 14 starts (12 fixed directions and the two extreme
    eigenvectors of T^T T); the best is certified against the analytic bracket
    B (sigma - 1). The Rayleigh quotient u^T (T^T T) u has no local maxima on the sphere other
    than the global one, so a start that converges is global; the certificate guards against a
    start stalling at a saddle or at a pole of the (theta, phi) chart.

    Raises SolveError when no start converges or the best misses the analytic bracket.
    """
    angles = check_angles(angles_deg)
    b = check_field(field_nT)
    t = np.array(axis_matrix_entries(*np.radians(angles)), dtype=float)
    eigenvalues, eigenvectors = np.linalg.eigh(t.T @ t)
    sigma_min, sigma_max = math.sqrt(eigenvalues[0]), math.sqrt(eigenvalues[-1])
    kappa = max(sigma_max - 1.0, 1.0 - sigma_min)
    if kappa <= 1e-15:  # orthogonal axes: dB vanishes everywhere
        kappa = 1.0
    solver = _worst_case_solver(bool(verbose))
    extremes = {}
    for sign, exact, vector in ((1.0, sigma_max - 1.0, eigenvectors[:, -1]),
                                (-1.0, sigma_min - 1.0, eigenvectors[:, 0])):
        starts = _start_directions(vector)
        best: SolveOutcome | None = None
        statuses = set()
        for theta0, phi0 in starts:
            outcome = solve(solver, x0=[theta0, phi0],
                            p=[*np.radians(angles), sign, kappa],
                            lbx=[-np.inf, -math.pi / 2], ubx=[np.inf, math.pi / 2])
            statuses.add(outcome.status)
            if outcome.success and (best is None or outcome.f < best.f):
                best = outcome
        what = "largest positive" if sign > 0 else "most negative"
        if best is None:
            raise SolveError(f"no IPOPT start converged for the {what} total-field error",
                             status=", ".join(sorted(statuses)))
        relative = -sign * best.f * kappa  # back to dB / B
        if abs(relative - exact) > 1e-9 * kappa + 1e-13:
            raise SolveError(
                f"the {what} total-field error found by IPOPT ({b * relative:.6g} nT) misses the "
                f"analytic value ({b * exact:.6g} nT)", status=best.status)
        theta_deg = math.degrees(best.x[0]) % 360.0
        phi_deg = float(np.clip(math.degrees(best.x[1]), -90.0, 90.0))
        if phi_deg < 0.0:  # dB is even in B: of the two antipodes, report the one with phi >= 0
            theta_deg, phi_deg = (theta_deg + 180.0) % 360.0, -phi_deg
        if theta_deg >= 360.0:
            theta_deg = 0.0
        extremes[sign] = Extremum(b * relative, theta_deg, phi_deg, best.status, best.iterations)
    return WorstCase(
        angles_deg=tuple(float(a) for a in angles), field_nT=b,
        largest_positive=extremes[1.0], most_negative=extremes[-1.0],
        exact_min_nT=b * (sigma_min - 1.0), exact_max_nT=b * (sigma_max - 1.0),
        small_angle_nT=small_angle_worst_case(angles, b), starts=len(starts))


def implied_worst_case(deviation_deg, field_nT) -> float:
    """Worst-case |dB| that an angle uncertainty of +-deviation_deg on every angle implies. [nT]

    The largest max |dB| over the eight corners (+-d, +-d, +-d) of the deviation box (one value d
    for all three angles, or three values). To first order every corner of a cube gives the same
    max |eig(G)| = 2 d, which by Gershgorin's theorem is also the largest over the whole box; at
    55 000 nT, d = 0.004 deg gives 3.84 nT ("at most 3.8 nT" in section 3 of [1]).
    """
    deviation = np.abs(np.asarray(deviation_deg, dtype=float).ravel())
    if deviation.size == 1:
        deviation = np.repeat(deviation, 3)
    deviation = check_angles(deviation, what="deviations")
    b = check_field(field_nT)
    worst = 0.0
    for signs in np.array(np.meshgrid([1, -1], [1, -1], [1, -1])).T.reshape(-1, 3):
        worst = max(worst, worst_case(signs * deviation, b).max_abs_error_nT)
    return worst


# --------------------------------------------------------------------------------------------
# inversion: section 2 of [1] as a bounded NLP in the three angles


def _capacity(n: int) -> int:
    """Width of the built problem for n samples: the next power of two, at least 64."""
    return max(64, 1 << (int(n) - 1).bit_length())


@lru_cache(maxsize=None)
def _inversion_solver(capacity: int, verbose: bool = False):
    """The inversion NLP for up to `capacity` samples, built once per (capacity, verbose).

    x = (alpha, beta, gamma) [deg], scaled to order 0.1-1 like the bounds.
    p = (vec(D), w, r, c, k): D (3 x capacity) the probe output B' divided by a nominal field,
    w the weights (1/N for the samples, 0 for the padding), r = 1 for the reference variant and 0
    for the spread variant, c the reference field over the nominal field, k an objective scale.

    Every operation is a matrix-valued MX node, so the graph has the same few nodes for any
    capacity; only the width of the parameter grows.
    """
    x = ca.MX.sym("angles_deg", 3)
    data = ca.MX.sym("D", 3, capacity)
    weights = ca.MX.sym("w", 1, capacity)
    extra = ca.MX.sym("q", 3)
    reference_flag, reference, scale = extra[0], extra[1], extra[2]
    angles = x * (math.pi / 180.0)
    t_inv = ca.vertcat(*[ca.horzcat(*row) for row in correction_matrix_entries(
        angles[0], angles[1], angles[2], 0.0, 0.0, 0.0, cos=ca.cos, sin=ca.sin)])
    corrected = ca.mtimes(t_inv, data)                                   # B''_i = T_inv B'_i
    magnitude = ca.sqrt(ca.sum1(corrected ** 2))                         # |B''_i|
    mean = ca.mtimes(magnitude, weights.T)                               # mean_i |B''_i|
    centre = reference_flag * reference + (1.0 - reference_flag) * mean  # B or the mean
    objective = scale * ca.mtimes((magnitude - centre) ** 2, weights.T)  # H_obj of section 2
    p = ca.vertcat(ca.vec(data), ca.vec(weights), extra)
    # the adaptive barrier update halves the iterations here: the objective is flat at roundoff
    # level near the optimum, where the monotone update stalls in the line search
    options = IpoptOptions(tol=1e-10, acceptable_tol=1e-8, max_iter=200,
                           print_level=5 if verbose else 0,
                           extra={"mu_strategy": "adaptive"})
    return build_nlpsol(f"nlpcal_orthogonality_inversion_{capacity}", x, objective, p,
                        options=options)


@lru_cache(maxsize=None)
def _correction_jacobian():
    """d vec(T_inv) / d(alpha, beta, gamma) [1/deg] as a CasADi Function, built once."""
    x = ca.SX.sym("angles_deg", 3)
    a = x * (math.pi / 180.0)
    t_inv = ca.vertcat(*[ca.horzcat(*row) for row in correction_matrix_entries(
        a[0], a[1], a[2], 0.0, 0.0, 0.0, cos=ca.cos, sin=ca.sin)])
    return ca.Function("nlpcal_orthogonality_dtinv", [x],
                       [t_inv, ca.jacobian(ca.vec(t_inv), x)])


def corrected_magnitude(samples, angles_deg) -> np.ndarray:
    """|T^-1 B'_i| for probe output B' (N, 3) [nT] and angles (alpha, beta, gamma) [deg]. [nT]"""
    t_inv = np.array(correction_matrix_entries(*np.radians(check_angles(angles_deg)),
                                               0.0, 0.0, 0.0), dtype=float)
    return np.linalg.norm(np.asarray(samples, dtype=float) @ t_inv.T, axis=1)


@dataclass
class Inversion:
    """Angles inverted from one rotation log (section 2 in [1])."""

    angles_deg: np.ndarray  #: (alpha, beta, gamma). [deg]
    angles_std_deg: np.ndarray | None  #: standard errors scaled by the residual variance. [deg]
    variant: str  #: "reference" (known field) or "spread" (around the mean, the paper's).
    field_nT: float | None  #: the reference field of the reference variant. [nT]
    n_samples: int
    objective_nT2: float  #: mean squared residual at the solution. [nT^2]
    rms_before_nT: float  #: rms of |B'| - centre before correction. [nT]
    rms_after_nT: float  #: rms of |B''| - centre after correction. [nT]
    corrected_mean_nT: float  #: mean of |B''| after correction. [nT]
    bound_deg: np.ndarray  #: the bounds +-bound. [deg]
    bound_active: list  #: per angle: the solution lies on a bound.
    status: str  #: IPOPT return status.
    success: bool
    iterations: int
    warnings: list = field(default_factory=list)
    source: str | None = None  #: the log the samples came from, if any.

    def as_dict(self) -> dict:
        document = {
            "schema": "nlpcal.orthogonality.inversion/1",
            "angles_deg": [float(a) for a in self.angles_deg],
            "angles_std_deg": (None if self.angles_std_deg is None
                               else [float(a) for a in self.angles_std_deg]),
            "angle_convention": "zhou2010",
            "variant": self.variant,
            "field_nT": self.field_nT,
            "n_samples": self.n_samples,
            "objective": self.objective_nT2,
            "objective_nT2": self.objective_nT2,
            "rms_before_nT": self.rms_before_nT,
            "rms_after_nT": self.rms_after_nT,
            "corrected_mean_nT": self.corrected_mean_nT,
            "bound_deg": [float(b) for b in self.bound_deg],
            "bound_active": list(self.bound_active),
            "any_bound_active": any(self.bound_active),
            "status": self.status,
            "success": self.success,
            "iterations": self.iterations,
            "warnings": list(self.warnings),
        }
        if self.source is not None:
            document = {"log": self.source, **document}
        return document


def invert(samples, *, field_nT=None, bound_deg=DEFAULT_BOUND_DEG, start_deg=(0.0, 0.0, 0.0),
           source: str | None = None, verbose: bool = False) -> Inversion:
    """The three non-orthogonality angles from a rotation log, as a bounded IPOPT problem.

    samples : (N, 3) probe output B' from attitudes spread over the sphere in a constant field;
        unit sensitivities and zero offsets are assumed (remove them first). [nT]
    field_nT : the known field B. With it, minimise mean_i (|T^-1 B'_i| - B)^2 (reference
        variant); without it, mean_i (|T^-1 B'_i| - mean_j |T^-1 B'_j|)^2 (spread variant, the
        objective of section 2 in [1]). [nT]
    bound_deg : |angle| <= bound, one value or three (section 2 of [1] uses 0.5). [deg]
    start_deg : IPOPT's start, (0, 0, 0) as in [1]. [deg]

    A solution on a bound gets a warning: the true angle may lie outside the bounds.
    Raises InputError for unusable samples or options, SolveError when IPOPT fails.
    """
    try:
        samples = np.asarray(samples, dtype=float)
    except (TypeError, ValueError):
        raise InputError("samples must be numeric, an (N, 3) array-like") from None
    if samples.ndim == 2 and samples.shape[1] == 3 and samples.shape[0] < MIN_INVERSION_SAMPLES:
        raise InputError(f"got {samples.shape[0]} samples, need at least "
                         f"{MIN_INVERSION_SAMPLES} attitudes to invert three angles")
    samples = check_samples(samples, minimum=MIN_INVERSION_SAMPLES)
    bounds = check_bounds(bound_deg)
    start = check_angles(start_deg, what="start angles")
    if (np.abs(start) > bounds).any():
        raise InputError(f"the start {_fmt_list(start)} deg lies outside the bounds "
                         f"+-{_fmt_list(bounds)} deg")
    reference = None if field_nT is None else check_field(field_nT, what="reference field")
    magnitude = np.linalg.norm(samples, axis=1)
    nominal = float(np.mean(magnitude))
    if (magnitude <= 1e-9 * nominal).any():
        bad = int((magnitude <= 1e-9 * nominal).sum())
        raise InputError(f"{bad} sample(s) have zero magnitude; drop those rows")
    n = samples.shape[0]
    capacity = _capacity(n)
    data = np.empty((capacity, 3))
    data[:n] = samples / nominal
    data[n:] = data[0]  # padding: a valid sample with weight 0 (keeps sqrt differentiable)
    weights = np.zeros(capacity)
    weights[:n] = 1.0 / n

    def centre_of(values):
        return reference if reference is not None else float(np.mean(values))

    before = magnitude - centre_of(magnitude)
    f0 = float(np.mean(before ** 2)) / nominal ** 2
    scale = 1.0 / max(f0, 1e-16)
    flag, ref = (1.0, reference / nominal) if reference is not None else (0.0, 1.0)
    solver = _inversion_solver(capacity, bool(verbose))
    outcome = solve(solver, x0=start, p=np.concatenate([data.ravel(), weights, [flag, ref, scale]]),
                    lbx=-bounds, ubx=bounds)
    where = f"{source}: " if source else ""
    if not outcome.success:
        raise SolveError(f"{where}IPOPT did not converge on the angles", status=outcome.status,
                         result=outcome)
    angles = np.clip(outcome.x, -bounds, bounds)
    after_magnitude = corrected_magnitude(samples, angles)
    after = after_magnitude - centre_of(after_magnitude)
    active = [bool(bounds[i] - abs(angles[i]) <= BOUND_ACTIVE_REL_TOL * bounds[i])
              for i in range(3)]
    warnings = []
    for name, is_active, value, bound in zip(ANGLE_NAMES, active, angles, bounds):
        if is_active:
            warnings.append(
                f"{where}{name} = {value:+.6g} deg lies on its bound +-{bound:g} deg: the true "
                f"angle may lie outside the bounds; widen the bound and invert again")
    std = _standard_errors(samples, angles, after, reference is None)
    if std is None:
        warnings.append(f"{where}the attitudes do not determine all three angles (singular "
                        f"normal matrix); rotate the probe through directions spread over the "
                        f"whole sphere")
    return Inversion(
        angles_deg=angles, angles_std_deg=std,
        variant="spread" if reference is None else "reference", field_nT=reference,
        n_samples=n, objective_nT2=float(np.mean(after ** 2)),
        rms_before_nT=float(np.sqrt(np.mean(before ** 2))),
        rms_after_nT=float(np.sqrt(np.mean(after ** 2))),
        corrected_mean_nT=float(np.mean(after_magnitude)), bound_deg=bounds,
        bound_active=active, status=outcome.status, success=outcome.success,
        iterations=outcome.iterations, warnings=warnings, source=source)


def _standard_errors(samples, angles_deg, residual, spread: bool):
    """Gauss-Newton standard errors s sqrt(diag((J^T J)^-1)), s^2 = sum r^2 / (N - p), widened
    for the lag-1 autocorrelation of the residuals (`nlpcal.statistics`). [deg]

    J_ij = d|B''_i| / d angle_j [nT/deg]; for the spread variant the columns are centred (the
    mean is a fourth, implicit parameter) and p = 4, otherwise p = 3. Returns None when J^T J is
    singular to working precision.
    """
    t_inv, jac = _correction_jacobian()(angles_deg)
    t_inv = np.array(t_inv)
    jac = np.array(jac)  # (9, 3), column-major vec of T_inv
    corrected = samples @ t_inv.T
    magnitude = np.linalg.norm(corrected, axis=1)
    columns = []
    for j in range(3):
        d_t_inv = jac[:, j].reshape(3, 3, order="F")
        columns.append(np.einsum("ij,ij->i", corrected, samples @ d_t_inv.T) / magnitude)
    design = np.stack(columns, axis=1)
    if spread:
        design = design - design.mean(axis=0)
    n_params = 4 if spread else 3
    dof = samples.shape[0] - n_params
    normal = design.T @ design
    if dof <= 0 or np.linalg.cond(normal) > 1e12:
        return None
    variance = float(np.sum(residual ** 2)) / dof
    widen = standard_error_inflation(lag1_autocorrelation(residual))  # neighbours alike in a log
    return np.sqrt(variance * np.diag(np.linalg.inv(normal))) * widen


# --------------------------------------------------------------------------------------------
# repeatability: Table 4 in [1]


@dataclass
class Repeatability:
    """Several inversions of the same probe (Table 4 in [1])."""

    runs: list  #: the Inversion of each log.
    mean_angles_deg: np.ndarray  #: mean over the runs. [deg]
    deviations_deg: np.ndarray  #: each run minus the mean, (runs, 3). [deg]
    max_deviation_deg: np.ndarray  #: largest |deviation| per angle. [deg]
    max_abs_deviation_deg: float  #: largest |deviation| over all angles and runs. [deg]
    field_nT: float  #: field at which the deviation is turned into a total-field error. [nT]
    field_source: str  #: "reference" (the given field) or "corrected mean" (of all runs).
    implied_worst_case_nT: float  #: implied_worst_case(max_abs_deviation_deg, field_nT). [nT]

    @property
    def warnings(self) -> list:
        return [w for run in self.runs for w in run.warnings]

    def as_dict(self) -> dict:
        return {
            "schema": "nlpcal.orthogonality.repeatability/1",
            "angles_deg": [float(a) for a in self.mean_angles_deg],
            "angle_convention": "zhou2010",
            "n_runs": len(self.runs),
            "runs": [run.as_dict() for run in self.runs],
            "mean_angles_deg": [float(a) for a in self.mean_angles_deg],
            "deviations_deg": [[float(v) for v in row] for row in self.deviations_deg],
            "max_deviation_deg": [float(v) for v in self.max_deviation_deg],
            "max_abs_deviation_deg": self.max_abs_deviation_deg,
            "field_nT": self.field_nT,
            "field_source": self.field_source,
            "implied_worst_case_nT": self.implied_worst_case_nT,
            "any_bound_active": any(any(run.bound_active) for run in self.runs),
            "warnings": self.warnings,
        }


def repeatability(runs, field_nT=None) -> Repeatability:
    """Mean, spread and implied total-field error of several inversions of one probe.

    runs : Inversion results of the same probe (at least two).
    field_nT : field for the implied error; default the mean corrected field of the runs. [nT]
    The implied error is the worst case over all directions when every angle is off by the
    largest deviation from the mean (section 3 of [1]: 0.004 deg -> at most 3.8 nT).
    """
    runs = list(runs)
    if len(runs) < 2:
        raise InputError(f"repeatability needs at least two inversions, got {len(runs)}")
    angles = np.array([run.angles_deg for run in runs], dtype=float)
    mean = angles.mean(axis=0)
    deviations = angles - mean
    max_deviation = np.abs(deviations).max(axis=0)
    if field_nT is None:
        b, source = float(np.mean([run.corrected_mean_nT for run in runs])), "corrected mean"
    else:
        b, source = check_field(field_nT), "reference"
    largest = float(max_deviation.max())
    return Repeatability(
        runs=runs, mean_angles_deg=mean, deviations_deg=deviations,
        max_deviation_deg=max_deviation, max_abs_deviation_deg=largest, field_nT=b,
        field_source=source, implied_worst_case_nT=implied_worst_case(largest, b))


# --------------------------------------------------------------------------------------------
# synthetic rotation data (section 2 of [1]: directions spread evenly over the sphere)


def fibonacci_directions(n: int) -> np.ndarray:
    """n unit vectors spread evenly over the sphere (a Fibonacci lattice), shape (n, 3). [1]"""
    n = int(n)
    if n < 1:
        raise InputError(f"need at least one direction, got {n}")
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    azimuth = math.pi * (1.0 + math.sqrt(5.0)) * k
    r = np.sqrt(1.0 - z ** 2)
    return np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], axis=1)


def synthetic_rotation(angles_deg, field_nT=PAPER_FIELD_NT, n: int = 500, noise_nT: float = 0.0,
                       seed: int = 0) -> np.ndarray:
    """Probe output B' = T B + noise for n directions spread over the sphere. [nT]

    angles_deg : (alpha, beta, gamma). [deg]; field_nT : |B|. [nT]; noise_nT : standard deviation
    of white noise added to each axis. [nT]
    """
    b = check_field(field_nT)
    t = axis_matrix_deg(angles_deg)
    probe = b * fibonacci_directions(n) @ t.T                                   # Eq. 1
    if noise_nT:
        probe = probe + np.random.default_rng(seed).normal(0.0, float(noise_nT), probe.shape)
    return probe
