"""A replica of the e-compass experiment of Qiu et al. (2017) for `nlpcal simulate --preset
qiu2017`: the paper's four turns and random test attitudes, with known errors and noise.

References
----------
[1] Qiu et al. (2017), see `nlpcal.models.qiu2017`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from ..io.files import Outputs
from ..io.strict import finite_table, strict
from ..models import qiu2017 as model

#: Noise of the replica per axis at noise=None: magnetometer [nT], accelerometer [g].
REPLICA_MAG_NOISE_NT = 10.0
REPLICA_ACC_NOISE_G = 0.2e-3


def replica(*, seed: int = 0, noise: float | None = None, n: int | None = None) -> dict:
    """The paper's four turns (48 samples) and `n` random attitudes, with known errors and noise.

    Turns (a sample every 30 degrees, starting level at heading 30 degrees): about housing x, y,
    z; then the housing rolled 90 degrees and turned about the table's horizontal axis, which is
    then the housing z axis (label z2): the paper's "table X set to 90 degrees, one turn about Y".
    That turn is what gives the accelerometer's z-axis mounting (the level turn about z does not
    move gravity).

    Parameters
    ----------
    seed : int
        Random seed of the errors, attitudes and noise.
    noise : float, optional
        Magnetometer noise per axis [nT], default 10; the accelerometer's is 0.2 mg per 10 nT.
    n : int, optional
        Number of random test attitudes (pitch within +-85 degrees), default 2000.
    """
    rng = np.random.default_rng(seed)
    mag_noise = REPLICA_MAG_NOISE_NT if noise is None else float(noise)
    if not (np.isfinite(mag_noise) and mag_noise >= 0):
        raise InputError(f"noise must be a non-negative number of nT, got {noise}")
    acc_noise = REPLICA_ACC_NOISE_G * mag_noise / REPLICA_MAG_NOISE_NT
    n = 2000 if n is None else int(n)
    if n < 1:
        raise InputError(f"n must be a positive number of test attitudes, got {n}")
    field_total, dip_deg = 54000.0, 58.5
    truth = _random_errors(rng)
    B = model.field_ned(field_total, np.radians(dip_deg))
    noises = {"magnetometer": mag_noise, "accelerometer": acc_noise}

    steps = np.radians(np.arange(0, 360, 30))
    C0 = model.attitude_matrix(0.0, 0.0, np.radians(30.0))
    turn_C = {
        "x": model.rotation_x(steps) @ C0,
        "y": model.rotation_y(steps) @ C0,
        "z": model.rotation_z(steps) @ C0,
        "z2": model.rotation_z(steps) @ model.rotation_x(np.pi / 2) @ C0,
    }
    C_turns = np.concatenate(list(turn_C.values()))
    labels = np.repeat(list(turn_C), len(steps))
    roll = rng.uniform(-180, 180, n)
    pitch = rng.uniform(-85, 85, n)
    heading = rng.uniform(0, 360, n)
    C_test = model.attitude_matrix(np.radians(roll), np.radians(pitch), np.radians(heading))
    r_turn = _readings(C_turns, B, truth, noises, rng)
    r_test = _readings(C_test, B, truth, noises, rng)
    turns = _frame(r_turn, C_turns, {"turn": labels, "step_deg": np.tile(np.degrees(steps), 4)})
    test = _frame(r_test, C_test, {})
    doc = {
        "preset": "qiu2017",
        "seed": int(seed),
        "field": {"total_nT": field_total, "dip_deg": dip_deg},
        "noise": {"magnetometer_nT": mag_noise, "accelerometer_g": acc_noise},
        "conventions": "NED world, housing x forward y right z down, "
        "C = R_x(roll) R_y(pitch) R_z(heading); "
        "reading = diag(1 + s) E v_body + bias, E from the six angles (Eq. 3)",
        "files": {
            "turns.csv": "the four turns, 12 samples each, turn label in column 'turn'",
            "test.csv": f"{n} random attitudes, |pitch| <= 85 deg, true_* columns",
        },
        "truth": {
            name: {
                "mounting_deg": dict(zip(model.ANGLE_NAMES, map(float, t["mounting_deg"]))),
                "sensitivity": [float(v) for v in t["sensitivity"]],
                "bias": [float(v) for v in t["bias"]],
                "unit": "nT" if name == "magnetometer" else "g",
            }
            for name, t in truth.items()
        },
    }
    return {"turns": turns, "test": test, "truth": doc}


def _random_errors(rng) -> dict:
    """Sensor -> the true errors of the replica: six mounting angles [deg], three sensitivity
    errors [1] and three biases [nT for the magnetometer, g for the accelerometer]."""
    return {
        "magnetometer": {
            "mounting_deg": rng.uniform(-1.5, 1.5, 6),
            "sensitivity": rng.uniform(-0.03, 0.03, 3),
            "bias": rng.uniform(-2000, 2000, 3),
        },
        "accelerometer": {
            "mounting_deg": rng.uniform(-1.5, 1.5, 6),
            "sensitivity": rng.uniform(-0.03, 0.03, 3),
            "bias": rng.uniform(-0.03, 0.03, 3),
        },
    }


def _readings(C, B, truth: dict, noises: dict, rng) -> dict:
    """Sensor -> its readings (N, 3) at the attitudes C (N, 3, 3) in the field B [nT] and
    gravity: Eq. 3 with the sensor's true errors, plus noise of the standard deviation in
    `noises` [nT or g]."""
    f_body, b_body = model.body_vectors(C, B)
    out = {}
    for name, v in (("magnetometer", b_body), ("accelerometer", f_body)):
        t = truth[name]
        out[name] = model.sensor_reading(
            v, np.radians(t["mounting_deg"]), t["sensitivity"], t["bias"]
        ) + rng.normal(0, noises[name], v.shape)
    return out


def _frame(r: dict, C, extra: dict) -> pd.DataFrame:
    """The table of readings `r` ([nT] and [g] columns) beside `extra` columns and the true
    roll, pitch and heading of the attitudes C. [deg]"""
    ro, pi_, he = (np.degrees(v) + 0.0 for v in model.euler_from_matrix(C))  # no "-0"
    data = dict(extra)
    for name, prefix, unit in (("magnetometer", "m", "nT"), ("accelerometer", "a", "g")):
        for i, axis in enumerate(model.AXES):
            data[f"{prefix}{axis}_{unit}"] = r[name][:, i]
    data.update(true_roll_deg=ro, true_pitch_deg=pi_, true_heading_deg=he)
    return pd.DataFrame(data)


def write_replica(
    out_dir, *, seed: int = 0, noise: float | None = None, n: int | None = None
) -> list:
    """Write turns.csv, test.csv and truth.json of `replica` into out_dir (together: `Outputs`).

    Returns the paths written. Suggested use:
    nlpcal compass calibrate DIR/turns.csv --mag-columns mx_nT my_nT mz_nT --acc-columns ax_g
    ay_g az_g --turn-column turn -o compass.json.
    """
    out_dir = Path(out_dir)
    data = replica(seed=seed, noise=noise, n=n)
    paths = [out_dir / "turns.csv", out_dir / "test.csv", out_dir / "truth.json"]
    with Outputs() as outputs:  # the three files appear together, or none of them
        outputs.csv(paths[0], finite_table(data["turns"]))
        outputs.csv(paths[1], finite_table(data["test"]))
        outputs.json(paths[2], strict(data["truth"]))
    return paths
