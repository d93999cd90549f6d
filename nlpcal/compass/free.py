"""Free-rotation mode, for logs without turns: a general ellipsoid fit per sensor, then the
magnetometer-to-accelerometer rotation from the constancy of the angle between the two calibrated
vectors (the dip angle; an NLP). What it cannot identify: the orientation of the sensor pair
relative to the housing (a rotation common to both sensors leaves every ellipsoid and every dip
angle unchanged). The accelerometer frame, corrected by a symmetric matrix (no rotation), stands
in for the housing frame; the magnetometer is rotated into it.

References
----------
[1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.
"""

from __future__ import annotations

import numpy as np

from .. import inference, validation
from ..errors import InputError
from ..models import qiu2017 as model
from ..nlp.compass import dip_alignment_nlp
from ..nlp.solver import solve
from .ellipsoids import fit_general_ellipsoid
from .result import ESTIMATED_SCALE, GRAVITY_SCALE, CompassCalibration, SensorCalibration

#: Fewest samples accepted in free-rotation mode (nine ellipsoid parameters, then four more).
MIN_FREE_SAMPLES = 20
#: Warn when a component of the magnetometer-to-accelerometer rotation is this uncertain. [deg]
ALIGNMENT_WARN_STD_DEG = 0.5
#: Samples whose calibrated |acc| is further than this from 1 g are moving. [g]
DEFAULT_REST_TOLERANCE = 0.02
#: Most refits of the accelerometer on the samples at rest.
REST_ITERATIONS = 5


def _gibbs_matrix(r) -> np.ndarray:
    rx = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    return np.eye(3) + 2 / (1 + r @ r) * (rx + rx @ rx)


def dip_alignment(down, field_dir) -> dict:
    """Rotation R of the magnetometer frame into the accelerometer frame from dip constancy.

    Minimises mean_i (d_i^T R b_i - sin I)^2 over R and the dip I (an NLP): at rest, the angle
    between gravity and the field is the same in every attitude. Identifiable only as far as the
    attitudes differ: rotations of the housing about a single axis leave the component of R about
    that axis (in body coordinates) undetermined; the standard deviations returned show it.

    Parameters
    ----------
    down : (N, 3) array
        Calibrated gravity directions (unit vectors, accelerometer frame).
    field_dir : (N, 3) array
        Calibrated field directions (unit vectors, magnetometer frame).

    Returns R, the rotation vector [rad], its standard deviations [rad], the dip [rad] and its
    standard deviation, the residual RMS of the dip [rad] before and after, and the IPOPT record.
    """
    n = len(down)
    psi = np.column_stack([np.einsum("ni,nj->nij", down, field_dir).reshape(n, 9), np.ones(n)])
    Psi = psi.T @ psi / n
    c0 = float(np.mean(np.sum(down * field_dir, axis=1)))
    out = solve(
        dip_alignment_nlp(),
        x0=np.r_[0.0, 0.0, 0.0, c0],
        p=Psi.ravel(order="F"),
        lbx=np.r_[np.full(3, -0.5), -1.0],
        ubx=np.r_[np.full(3, 0.5), 1.0],
    ).checked("magnetometer-to-accelerometer alignment (dip constancy)")
    r, c = out.x[:3], float(out.x[3])
    R = _gibbs_matrix(r)
    rb = field_dir @ R.T
    residual = np.sum(down * rb, axis=1) - c
    # Gauss-Newton information of (small rotation delta applied after R, c):
    # d/d delta of d^T exp([delta]x) R b = (R b x d)
    J = np.column_stack([np.cross(rb, down), -np.ones(n)])
    # A free-rotation log is a time series: neighbouring scores alike carry less information.
    uncertainty, dependence = inference.least_squares_uncertainty(J, residual, n - 4)
    std = (
        uncertainty.standard_errors
        if uncertainty.standard_errors is not None
        else np.full(4, np.inf)
    )
    angle = 2 * np.arctan(np.linalg.norm(r))
    axis = r / np.linalg.norm(r) if np.linalg.norm(r) > 0 else np.zeros(3)
    before = np.sum(down * field_dir, axis=1)
    slope = max(np.sqrt(1 - c**2), 1e-12)  # d sin(I) / dI: residuals of sin(I) to angles
    return {
        "R": R,
        "rotation": angle * axis,
        "rotation_std": std[:3],
        "dip": float(np.arcsin(c)),
        "dip_std": float(std[3] / slope),
        "dip_residual_rms_before": float(np.std(before) / slope),
        "dip_residual_rms": float(np.sqrt(np.mean(residual**2)) / slope),
        "score_dependence": dependence,
        "ipopt": out.record(),
    }


FREE_IDENTIFIABILITY = (
    "free-rotation mode: per sensor, the zero bias and a symmetric correction (sensitivities and "
    "non-orthogonality) are identified by its own ellipsoid fit, and the rotation of the "
    "magnetometer relative to the accelerometer by the constancy of the dip angle. Not "
    "identifiable: the orientation of the sensor pair relative to the housing (a rotation common "
    "to both sensors changes neither ellipsoid nor the dip), so attitudes refer to the "
    "accelerometer frame with its symmetric correction, not to the housing axes; 'mounting_deg' "
    "are angles relative to that frame. Components of the magnetometer-to-accelerometer rotation "
    "about body axes the housing never left are not identifiable either (see alignment."
    "rotation_std_deg). The magnetometer's overall scale is fixed by the given field or by "
    "det(correction_matrix) = 1."
)


def calibrate_free(
    mag,
    acc,
    *,
    reference_field: float | None = None,
    field_nt: float | None = None,
    ellipsoid_seed: str = "linear",
    rest_tolerance: float | None = DEFAULT_REST_TOLERANCE,
) -> CompassCalibration:
    """Free-rotation mode: each sensor's general ellipsoid fit, then the dip-angle constancy.

    Parameters
    ----------
    mag : array_like, shape (N, 3)
        Magnetometer readings, taken at rest (or moving slowly) in many attitudes. [nT]
    acc : array_like, shape (N, 3)
        Accelerometer readings of the same rows. [g]
    reference_field : float, optional
        Local total field (`--reference-field`); default estimated under
        det(correction_matrix) = 1. [nT]
    field_nt : float, optional
        The former name of `reference_field`, still accepted. [nT]
    ellipsoid_seed : {"linear", "centroid"}
        Start of the ellipsoid NLPs.
    rest_tolerance : float or None
        Samples whose calibrated specific force differs from 1 g by more than this are taken as
        moving: they are left out of the accelerometer fit (refitted until the kept set no longer
        changes, at most REST_ITERATIONS times) and of the dip alignment, and kept for the
        magnetometer fit. None keeps every sample. [g]

    Returns
    -------
    CompassCalibration
        Both sensors' corrections and the rotation between them.

    Raises
    ------
    InputError
        Unusable readings.
    SolveError
        IPOPT failed.

    Examples
    --------
    >>> import nlpcal
    >>> from nlpcal.simulation.qiu2017 import replica
    >>> test = replica(seed=0, n=300)["test"]  # random attitudes, pitch within +-85 deg
    >>> mag, acc = test[["mx_nT", "my_nT", "mz_nT"]], test[["ax_g", "ay_g", "az_g"]]
    >>> nlpcal.calibrate_free(mag.to_numpy(), acc.to_numpy()).mode
    'free-rotation'
    """
    mag = validation.finite_vectors(mag, "magnetometer readings", minimum=MIN_FREE_SAMPLES)
    acc = validation.finite_vectors(acc, "accelerometer readings", minimum=MIN_FREE_SAMPLES)
    if len(mag) != len(acc):
        raise InputError(
            f"got {len(mag)} magnetometer and {len(acc)} accelerometer samples; they "
            f"must be the same rows"
        )
    field_nt = validation.renamed(reference_field, field_nt, "reference_field", "field_nt")
    if field_nt is not None and not (np.isfinite(field_nt) and field_nt > 0):
        raise InputError(f"the field must be a positive number of nT, got {field_nt}")
    if rest_tolerance is not None and not (np.isfinite(rest_tolerance) and rest_tolerance > 0):
        raise InputError(f"the rest tolerance must be a positive number of g, got {rest_tolerance}")
    warnings = []
    mag_fit = fit_general_ellipsoid(mag, magnitude=1.0, seed=ellipsoid_seed, sensor="magnetometer")
    acc_fit, a, rest, iterations = _fit_at_rest(acc, rest_tolerance, ellipsoid_seed)
    if rest.sum() < 0.5 * len(acc):
        warnings.append(
            f"only {int(rest.sum())} of {len(acc)} samples look at rest (calibrated "
            f"|acc| within {rest_tolerance:g} g of 1 g); the accelerometer fit and the "
            f"alignment use those alone"
        )
    b = (mag[rest] - mag_fit["offset"]) @ mag_fit["L"].T
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    d = -a[rest] / np.linalg.norm(a[rest], axis=1, keepdims=True)
    align = dip_alignment(d, b)
    K_mag = align["R"] @ mag_fit["L"]
    if field_nt is None:
        factor = abs(np.linalg.det(K_mag)) ** (-1.0 / 3.0)
        magnitude, source = factor, ESTIMATED_SCALE
    else:
        magnitude, source = float(field_nt), "given"
    K_mag = K_mag * magnitude
    rotation_std_deg = np.degrees(align["rotation_std"])
    poorly = [model.AXES[i] for i in range(3) if not rotation_std_deg[i] <= ALIGNMENT_WARN_STD_DEG]
    if poorly:
        warnings.append(
            f"the magnetometer-to-accelerometer rotation about body {', '.join(poorly)} is poorly "
            f"determined (std {', '.join(f'{s:.2g}' for s in rotation_std_deg)} deg about "
            f"x, y, z); "
            f"the log needs more varied attitudes"
        )
    mag_cal = _magnetometer_calibration(mag, mag_fit, align, K_mag, magnitude, source)
    acc_cal = _accelerometer_calibration(acc_fit, a[rest], rest_tolerance, iterations)
    return CompassCalibration(
        mode="free-rotation",
        magnetometer=mag_cal,
        accelerometer=acc_cal,
        identifiability=FREE_IDENTIFIABILITY,
        alignment=_alignment_document(align, rotation_std_deg),
        warnings=warnings,
        input={"samples": len(mag)},
    )


def _fit_at_rest(acc, rest_tolerance: float | None, seed) -> tuple:
    """The accelerometer's ellipsoid fit on the samples at rest: fitted on all, then (with a
    rest tolerance [g]) refitted on the samples whose calibrated |acc| lies within it of 1 g
    until that set stops changing, at most REST_ITERATIONS times. Returns the fit, the
    calibrated readings of every sample [g], the rest mask and the refits made."""
    rest = np.ones(len(acc), dtype=bool)
    iterations = 0
    while True:
        acc_fit = fit_general_ellipsoid(
            acc[rest], magnitude=1.0, seed=seed, sensor="accelerometer (samples at rest)"
        )
        a = (acc - acc_fit["offset"]) @ acc_fit["L"].T
        if rest_tolerance is None or iterations == REST_ITERATIONS:
            break
        iterations += 1
        new_rest = np.abs(np.linalg.norm(a, axis=1) - 1.0) <= rest_tolerance
        if new_rest.sum() < MIN_FREE_SAMPLES:
            raise InputError(
                f"only {int(new_rest.sum())} samples look at rest (calibrated |acc| within "
                f"{rest_tolerance:g} g of 1 g); record more slow or still attitudes or pass a "
                f"larger rest tolerance"
            )
        if np.array_equal(new_rest, rest):
            break
        rest = new_rest
    return acc_fit, a, rest, iterations


def _alignment_document(align: dict, rotation_std_deg) -> dict:
    """The "alignment" block: the rotation of the magnetometer's frame into the
    accelerometer's and the dip angle, with their standard deviations. [deg]"""
    return {
        "rotation_deg": [float(v) for v in np.degrees(align["rotation"])],
        "rotation_std_deg": [float(v) for v in rotation_std_deg],
        "rotation_matrix": [[float(v) for v in row] for row in align["R"]],
        "dip_deg": float(np.degrees(align["dip"])),
        "dip_std_deg": float(np.degrees(align["dip_std"])),
        "dip_residual_rms_deg_before": float(np.degrees(align["dip_residual_rms_before"])),
        "dip_residual_rms_deg": float(np.degrees(align["dip_residual_rms"])),
        "score_dependence": align["score_dependence"],
        "note": "standard deviations from the scores of the dip residuals, widened for their "
        "dependence on their neighbours (docs/uncertainty.md); "
        "rotation vector (axis times angle) taking the magnetometer's calibrated frame "
        "into the accelerometer's, body x, y, z components",
    }


def _magnetometer_calibration(mag, fit: dict, align: dict, K_mag, magnitude, source: str):
    """The magnetometer's `SensorCalibration`: its ellipsoid fit rotated into the
    accelerometer's frame and scaled to `magnitude` [nT], with its residual."""
    mag_norm = np.linalg.norm((mag - fit["offset"]) @ K_mag.T, axis=1)
    return SensorCalibration(
        sensor="magnetometer",
        unit="nT",
        correction=K_mag,
        bias=fit["offset"],
        magnitude=float(magnitude),
        magnitude_source=source,
        frame="accelerometer (rotated into it by the dip-angle constancy)",
        quality={
            "magnitude_residual_rms": float(np.sqrt(np.mean((mag_norm - magnitude) ** 2))),
            "ellipsoid_condition": fit["condition"],
            "ellipsoid_seed": fit["seed"],
            "ipopt": {"ellipsoid": fit["ipopt"], "alignment": align["ipopt"]},
        },
    )


def _accelerometer_calibration(fit: dict, a_rest, rest_tolerance, refits: int):
    """The accelerometer's `SensorCalibration` from its fit on the samples at rest, whose
    calibrated readings are `a_rest` [g]."""
    acc_norm = np.linalg.norm(a_rest, axis=1)
    return SensorCalibration(
        sensor="accelerometer",
        unit="g",
        correction=fit["L"],
        bias=fit["offset"],
        magnitude=1.0,
        magnitude_source=GRAVITY_SCALE,
        frame="accelerometer, symmetric correction (orientation relative to the housing unknown)",
        quality={
            "magnitude_residual_rms": float(np.sqrt(np.mean((acc_norm - 1.0) ** 2))),
            "rest_samples": len(a_rest),
            "rest_tolerance_g": rest_tolerance,
            "rest_refits": refits,
            "ellipsoid_condition": fit["condition"],
            "ellipsoid_seed": fit["seed"],
            "ipopt": {"ellipsoid": fit["ipopt"]},
        },
    )
