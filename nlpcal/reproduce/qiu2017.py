"""Qiu et al. (2017): attitude errors of a calibrated e-compass, on the replica.

The replica (`nlpcal.simulation.qiu2017`, seed 0) turns a magnetometer and an accelerometer with
random mounting, sensitivity and bias errors through the paper's four turns (48 samples), and
through 2000 random attitudes with |pitch| <= 85 deg for the test. The turn-mode calibration
(`nlpcal.compass.calibrate_turns`, Eq. 4-8 then the ellipsoid fits) is applied to the test
attitudes (Eq. 2, 9, 10) and the errors against the truth are evaluated per band of |pitch|
(`nlpcal.compass.evaluate`).

The paper states bounds, not values: roll and pitch within +-0.15 deg and heading within +-0.5 deg
for pitch up to +-85 deg. Each is compared with the largest error of the replica in its band.

References
----------
[1] Qiu X., Shi W., Sun C., Shen H. (2017). A simplified high-precision calibration method for 3D
    electronic compass. Ship Electronic Engineering 37(2). doi:10.3969/j.issn.1672-9730.2017.02.020
"""

from __future__ import annotations

import numpy as np

from ..compass import attitude, calibrate_turns, evaluate
from ..models import qiu2017 as model
from ..plots import attitude_errors_png
from ..simulation import qiu2017 as replica
from .values import Reproduction, Value

REFERENCE = (
    "Qiu, Shi, Sun, Shen (2017), A simplified high-precision calibration method for 3D electronic "
    "compass, section 4"
)
SEED = 0
#: The digits [1] prints after the decimal point of each bound (`model.PAPER_ATTITUDE_BOUNDS_DEG`).
BOUND_DECIMALS = {"roll": 2, "pitch": 2, "heading": 1}
#: Bands of |true pitch| compared with the bounds: the roll error grows near the vertical. [deg]
PITCH_BANDS = (0.0, 60.0, model.PAPER_MAX_PITCH_DEG)

STEEP_CAUSE = (
    "near the vertical an accelerometer noise n turns into a roll error of about n / cos(pitch) "
    f"(the replica's {1e3 * replica.REPLICA_ACC_NOISE_G:g} mg per axis is 0.13 deg at 85 deg); "
    "the paper's accelerometer noise is not given"
)


def _readings(frame):
    mag = frame[[f"m{axis}_nT" for axis in "xyz"]].to_numpy()
    acc = frame[[f"a{axis}_g" for axis in "xyz"]].to_numpy()
    return mag, acc


def reproduce() -> Reproduction:
    data = replica.replica(seed=SEED)
    turns, test = data["turns"], data["test"]
    mag, acc = _readings(turns)
    calibration = calibrate_turns(mag, acc, turns["turn"].to_numpy(dtype=object))
    found = attitude(calibration, *_readings(test))
    estimate = np.column_stack([found.roll_deg, found.pitch_deg, found.heading_deg])
    truth = test[["true_roll_deg", "true_pitch_deg", "true_heading_deg"]].to_numpy()
    stats = evaluate(estimate, truth, pitch_bands=PITCH_BANDS)
    values = []
    for band in stats["bands"]:
        where = f"|pitch| {band['pitch_min_deg']:g}-{band['pitch_max_deg']:g} deg"
        steep = band["pitch_min_deg"] > 0
        for name, bound in model.PAPER_ATTITUDE_BOUNDS_DEG.items():
            values.append(
                Value(
                    f"largest {name} error, {where} ({band['n']} attitudes)",
                    "deg",
                    bound,
                    BOUND_DECIMALS[name],
                    band[name]["max_abs"],
                    cause=STEEP_CAUSE if steep else None,
                    bound=True,
                )
            )
    errors = (estimate - truth + 180.0) % 360.0 - 180.0

    def figure() -> bytes:
        return attitude_errors_png(
            truth[:, 1],
            errors,
            list(model.PAPER_ATTITUDE_BOUNDS_DEG.values()),
            title=f"qiu2017 replica, seed {SEED}: turn-mode calibration, {len(test)} test "
            "attitudes",
        )

    return Reproduction(
        paper="qiu2017",
        reference=REFERENCE,
        replica=f"nlpcal simulate --preset qiu2017 --seed {SEED} (four turns of 12 samples; "
        f"{len(test)} random test attitudes; {replica.REPLICA_MAG_NOISE_NT:g} nT and "
        f"{1e3 * replica.REPLICA_ACC_NOISE_G:g} mg noise per axis)",
        values=values,
        figure=figure,
        notes=["the paper states bounds: a value matches when it is at or below the bound"],
    )
