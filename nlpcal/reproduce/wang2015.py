"""Wang et al. (2015): the worst-case total-field error, the inversion and its repeatability.

Everything in [1] but the real probe's logs can be recomputed: the worst case of angles
(0.1, 0.1, 0.1) deg at 55 000 nT (Eq. 9, `nlpcal.orthogonality.worst_case`), the error that an
angle uncertainty of 0.004 deg implies, and the inversion of synthetic rotation data
(`nlpcal.orthogonality.invert`). The real probe is replaced by five synthetic logs with its
inverted angles (alpha 0.064 deg, 90 deg - gamma 0.103 deg; beta is not given, 0 here), 400
directions and 10 nT noise per axis each.

Angles follow the convention of Zhou et al. (2010), as everywhere in nlpcal (`nlpcal.models.
wang2015`).

References
----------
[1] Wang Y., Zong F., Zhao Y., Cheng D. (2015). Calibration and measurement on the orthogonal
    three-axes of three-components magnetic flux-gate sensor. Journal of Shandong Agricultural
    University (Natural Science Edition), 2015(2), 232-237.
"""

from __future__ import annotations

import numpy as np

from .. import orthogonality as ortho
from ..models import wang2015 as model
from ..plots import orthogonality_map_png
from .values import Reproduction, Value

REFERENCE = (
    "Wang, Zong, Zhao, Cheng (2015), Calibration and measurement on the orthogonal three-axes of "
    "three-components magnetic flux-gate sensor, sections 1-3"
)
FIELD = ortho.PAPER_FIELD_NT  # [nT]
#: The synthetic inversion: directions, seed, and the digits the paper prints for each angle.
SYNTHETIC_N, SYNTHETIC_SEED, SYNTHETIC_DECIMALS = 500, 7, (2, 2, 1)
#: The replica of the probe's repeated runs: runs, directions, noise per axis [nT], first seed.
RUNS, RUN_N, RUN_NOISE_NT, RUN_SEED = 5, 400, 10.0, 100

ABOUT_CAUSE = (
    "the paper gives 'about 95 nT', the largest value of its simulated map over all directions "
    "(Fig. 3); nlpcal's is the exact maximum over the sphere, B (sigma_max - 1) with sigma_max "
    "the largest singular value of T"
)
SPREAD_CAUSE = (
    "the real probe's logs are not public: the spread of repeated runs is set by the probe's "
    f"noise and the directions turned through, and the replica's {RUN_NOISE_NT:g} nT per axis "
    f"and {RUN_N} directions per run are assumed"
)


def reproduce() -> Reproduction:
    worst = ortho.worst_case(model.PAPER_WORST_ANGLES_DEG, FIELD)
    values = _worst_case_values(worst) + _synthetic_values() + _probe_values()

    def figure() -> bytes:
        angles = model.PAPER_WORST_ANGLES_DEG
        theta, phi, error = ortho.error_map(angles, FIELD, step_deg=1.0)
        return orthogonality_map_png(angles, FIELD, theta, phi, error, worst, dpi=80)

    return Reproduction(
        paper="wang2015",
        reference=REFERENCE,
        replica=f"synthetic rotations at {FIELD:g} nT: {SYNTHETIC_N} noiseless directions "
        f"(seed {SYNTHETIC_SEED}); {RUNS} runs of {RUN_N} directions with {RUN_NOISE_NT:g} nT "
        f"noise for the probe (seeds {RUN_SEED}-{RUN_SEED + RUNS - 1})",
        values=values,
        figure=figure,
        notes=[
            "angles in the convention of Zhou et al. (2010); the paper's gamma is 90 deg minus "
            "an angle between probe axes, the same small angle",
            "probe means: standard error from the spread of the runs",
        ],
    )


def _worst_case_values(worst) -> list:
    """The worst-case |dB|: at the paper's angles, and implied by its 0.004 deg
    repeatability. [nT]"""
    return [
        Value(
            "worst-case |dB| for angles (0.1, 0.1, 0.1) deg at 55 000 nT",
            "nT",
            model.PAPER_WORST_CASE_NT,
            0,
            worst.max_abs_error_nT,
            cause=ABOUT_CAUSE,
        ),
        Value(
            "worst-case |dB| implied by a 0.004 deg angle uncertainty",
            "nT",
            model.PAPER_IMPLIED_NT,
            1,
            ortho.implied_worst_case(model.PAPER_DEVIATION_DEG, FIELD),
        ),
    ]


def _synthetic_values() -> list:
    """The three angles inverted from noiseless synthetic rotations. [deg]"""
    truth = model.PAPER_SYNTHETIC_ANGLES_DEG
    data = ortho.synthetic_rotation(truth, FIELD, n=SYNTHETIC_N, seed=SYNTHETIC_SEED)
    inversion = ortho.invert(data, bound_deg=0.5, start_deg=(0.0, 0.0, 0.0))
    values = []
    for k, (name, paper) in enumerate(zip(ortho.ANGLE_NAMES, truth)):
        values.append(
            Value(
                f"synthetic inversion, noiseless, {name}",
                "deg",
                paper,
                SYNTHETIC_DECIMALS[k],
                float(inversion.angles_deg[k]),
                standard_error=_std(inversion.angles_std_deg, k),
            )
        )
    return values


def _probe_values() -> list:
    """The probe's angles, the mean of repeated noisy runs, and their largest deviation from
    that mean. [deg]"""
    probe = [model.PAPER_PROBE_ANGLES_DEG.get(name, 0.0) for name in ortho.ANGLE_NAMES]
    runs = [
        ortho.invert(
            ortho.synthetic_rotation(probe, FIELD, n=RUN_N, noise_nT=RUN_NOISE_NT, seed=seed)
        )
        for seed in range(RUN_SEED, RUN_SEED + RUNS)
    ]
    report = ortho.repeatability(runs, field_nT=FIELD)
    values = []
    for name, paper in model.PAPER_PROBE_ANGLES_DEG.items():
        k = ortho.ANGLE_NAMES.index(name)
        spread = np.std([run.angles_deg[k] for run in runs], ddof=1)
        values.append(
            Value(
                f"probe, mean of {RUNS} runs, {name}",
                "deg",
                paper,
                3,
                float(report.mean_angles_deg[k]),
                standard_error=float(spread / np.sqrt(RUNS)),
            )
        )
    values.append(
        Value(
            f"repeatability: largest deviation of {RUNS} runs from their mean",
            "deg",
            model.PAPER_DEVIATION_DEG,
            3,
            report.max_abs_deviation_deg,
            cause=SPREAD_CAUSE,
            bound=True,
        )
    )

    return values


def _std(std_deg, k: int) -> float | None:
    """The k-th standard error, when the inversion has them."""
    return None if std_deg is None else float(std_deg[k])
