"""A replica of the experiment of Liu et al. (2022) for `nlpcal simulate --preset liu2022`.

References
----------
[1] Liu H., Li Y., Ding X., Feng C. (2022), see `nlpcal.models.liu2022`.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError
from ..io.files import Outputs, read_json
from ..io.strict import finite_table, strict
from ..models import liu2022
from ..models.liu2022 import TemperatureModel, modulus_line
from ..models.zhou2010 import Zhou2010Parameters
from ..models.zhou2010 import forward as zhou_forward
from .attitudes import random_rotations

#: System errors of the replica sensor at t0. The paper's Table 1 (the HSF parameters at 7.3 degC)
#: was an image and is lost; these are chosen so that the replica's raw RMSE is close to the
#: paper's (about 890 nT on the drift log, about 1100 nT on the field log; paper 891.43, 1064.70).
REPLICA_PARAMETERS = Zhou2010Parameters(
    z_x=-236.0,
    z_y=128.0,
    z_z=72.0,
    s_x=0.0212,
    s_y=0.0179,
    s_z=0.0226,
    alpha_deg=0.42,
    beta_deg=-0.31,
    gamma_deg=0.18,
)
#: Inclination of the replica's field. [deg]
REPLICA_INCLINATION_DEG = 60.0
#: Default white noise per axis of the averaged fluxgate output. [nT]
REPLICA_NOISE_NT = 0.5
#: White noise of the proton magnetometer. [nT]
REPLICA_PROTON_NOISE_NT = 0.1
#: Default number of attitudes in the base calibration log and in the temperature sweep.
REPLICA_ATTITUDES = 600
#: Samples of the static drift log (one hour at the proton's 0.5 Hz) and of the field log.
REPLICA_DRIFT_SAMPLES = 1800
REPLICA_FIELD_SAMPLES = 200
REPLICA_FIELD_ATTITUDES = 80
#: Temperature range of the sweep log (beyond the paper, for the joint calibration). [degC]
REPLICA_SWEEP_RANGE_DEGC = (4.0, 14.0)


def replica_field(
    params: Zhou2010Parameters = REPLICA_PARAMETERS,
    a: float = liu2022.PAPER_A_NT_PER_DEGC,
    b: float = liu2022.PAPER_B_NT,
    t0: float = liu2022.PAPER_BASE_TEMPERATURE_DEGC,
    inclination_deg: float = REPLICA_INCLINATION_DEG,
):
    """The field F0 [nT] and static direction (ideal sensor frame) that make Eq. 1 exact.

    The static sensor of the drift log is level with x north, so it sees the field along
    u = (cos I, 0, sin I). F0 solves |diag(1 + s) T u F0 + Z_p| = a t0 + b: the static modulus is
    then k(t)(a t0 + b) = a t + b, the paper's line.
    """
    inc = np.radians(inclination_deg)
    u = np.array([np.cos(inc), 0.0, np.sin(inc)])
    g = zhou_forward(u[None, :], params)[0] - params.offsets  # diag(1 + s) T u
    z = params.offsets
    target = float(modulus_line(t0, a, b))
    # |F g + z|^2 = target^2, the positive root
    qa, qb, qc = g @ g, 2.0 * g @ z, z @ z - target**2
    f0 = (-qb + np.sqrt(qb * qb - 4.0 * qa * qc)) / (2.0 * qa)
    return float(f0), u


def _smooth_noise(n: int, rng: np.random.Generator, width: int, peak: float) -> np.ndarray:
    """Band-limited noise with largest |value| = peak (moving average of white noise)."""
    white = rng.normal(size=n + width)
    series = np.convolve(white, np.ones(width) / width, mode="valid")[:n]
    series -= series.mean()
    return peak * series / (np.max(np.abs(series)) or 1.0)


def replica(*, seed: int = 0, noise: float | None = None, n: int | None = None) -> tuple:
    """A replica of the experiment of [1]: (logs, truth), logs a dict of file name -> table.

    Tables (columns time_s, bx, by, bz [nT], temp_c [degC], proton_nT [nT]):

    * base.csv: calibration log at t0 = 7.3 degC, `n` attitudes (default 600).
    * drift.csv: static sensor, temperature falling from 6.8 to 5.1 degC over one hour at 0.5 Hz,
      with a diurnal trend and disturbances of up to 10 nT in the reference.
    * field.csv: 200 points over 80 attitudes at 12.8 degC, the reference varying by about
      100 nT.
    * sweep.csv: `n` attitudes while the temperature sweeps 4 -> 14 degC (beyond the paper: one log
      for the joint temperature calibration).

    The truth (written as truth.json) holds the true parameters, a, b, t0 and the field. It
    follows Eq. 2 and 9 of [1] with the paper's a = 7.0805 nT/degC, b = 50 906 nT and t0 =
    7.3 degC; the field F0 makes the static modulus exactly a t + b (`replica_field`).
    """
    noise = REPLICA_NOISE_NT if noise is None else float(noise)
    if noise < 0 or not np.isfinite(noise):
        raise InputError(f"--noise must be a non-negative number, got {noise}")
    attitudes = REPLICA_ATTITUDES if n is None else int(n)
    if attitudes < 20:
        raise InputError(f"-n must be at least 20 attitudes for the liu2022 replica, got {n}")
    rng = np.random.default_rng(seed)
    a, b = liu2022.PAPER_A_NT_PER_DEGC, liu2022.PAPER_B_NT
    t0 = liu2022.PAPER_BASE_TEMPERATURE_DEGC
    model = TemperatureModel.from_drift(a, b, t0)
    f0, u_static = replica_field(REPLICA_PARAMETERS, a, b, t0)
    inc = np.radians(REPLICA_INCLINATION_DEG)
    world = np.array([np.cos(inc), 0.0, np.sin(inc)])  # north-east-down unit vector
    log = partial(_log, model=model, noise=noise, rng=rng)
    logs = {  # in this order: each draws from rng in turn
        "base.csv": _base_log(log, rng, world, attitudes, t0, f0),
        "drift.csv": _drift_log(log, rng, u_static, f0),
        "field.csv": _field_log(log, rng, world, f0),
        "sweep.csv": _sweep_log(log, rng, world, attitudes, f0),
    }
    truth = {
        "description": "replica of Liu et al. (2022): nine parameters at t0 (Eq. 4 of Zhou et al."
        " 2010) and the temperature factor k(t) of Eq. 9",
        "parameters": REPLICA_PARAMETERS.to_dict(),
        "a_nT_per_degC": a,
        "b_nT": b,
        "base_temperature_degC": t0,
        "temperature_model": model.to_dict(),
        "field_nT": f0,
        "inclination_deg": REPLICA_INCLINATION_DEG,
        "noise_nT": noise,
        "proton_noise_nT": REPLICA_PROTON_NOISE_NT,
        "seed": seed,
        "files": {
            "base.csv": f"calibration log, {attitudes} attitudes at {t0} degC",
            "drift.csv": "static sensor, temperature 6.8 -> 5.1 degC, 1800 points at 0.5 Hz",
            "field.csv": "200 points over 80 attitudes at 12.8 degC",
            "sweep.csv": f"{attitudes} attitudes, temperature "
            f"{REPLICA_SWEEP_RANGE_DEGC[0]} -> {REPLICA_SWEEP_RANGE_DEGC[1]} "
            f"degC",
        },
    }
    return logs, truth


def _log(directions, temperature, proton_true, period_s, *, model, noise, rng) -> pd.DataFrame:
    """One replica log: the fluxgate's reading of the field `proton_true` [nT] along the unit
    `directions` at `temperature` [degC] (Eq. 2 of [1]) with `noise` [nT], and the proton
    magnetometer's reading of the same field, a sample every `period_s` [s]."""
    count = directions.shape[0]
    field = directions * proton_true[:, None]  # the fluxgate sees the same field
    raw = liu2022.forward(field, temperature, REPLICA_PARAMETERS, model)  # Eq. 2
    raw = raw + noise * rng.normal(size=raw.shape)
    proton = proton_true + REPLICA_PROTON_NOISE_NT * rng.normal(size=count)
    return pd.DataFrame(
        {
            "time_s": np.arange(count) * period_s,
            "bx": raw[:, 0],
            "by": raw[:, 1],
            "bz": raw[:, 2],
            "temp_c": np.round(temperature, 3),
            "proton_nT": proton,
        }
    )


def _base_log(log, rng, world, attitudes: int, t0: float, f0: float) -> pd.DataFrame:
    """The calibration log at t0 [degC]: `attitudes` random attitudes in the field f0 [nT]."""
    rot = random_rotations(attitudes, rng)
    t_base = t0 + 0.02 * rng.normal(size=attitudes)
    f_base = f0 + _smooth_noise(attitudes, rng, 50, 3.0)
    return log(rot @ world, t_base, f_base, 2.0)


def _drift_log(log, rng, u_static, f0: float) -> pd.DataFrame:
    """The static drift log: a temperature ramp 6.8 -> 5.1 degC, a diurnal trend and
    disturbances in the field f0 [nT]."""
    count = REPLICA_DRIFT_SAMPLES
    hi, lo = liu2022.PAPER_DRIFT_RANGE_DEGC[1], liu2022.PAPER_DRIFT_RANGE_DEGC[0]
    t_drift = np.linspace(hi, lo, count) + 0.01 * rng.normal(size=count)
    trend = 4.0 * np.sin(np.linspace(0.0, 0.5 * np.pi, count))
    f_drift = f0 + trend + _smooth_noise(count, rng, 15, 10.0)
    return log(np.tile(u_static, (count, 1)), t_drift, f_drift, 2.0)


def _field_log(log, rng, world, f0: float) -> pd.DataFrame:
    """The field log at 12.8 degC: 80 attitudes, 200 points, the reference varying by about
    100 nT about f0 [nT]."""
    count = REPLICA_FIELD_SAMPLES
    which = np.sort(np.arange(count) * REPLICA_FIELD_ATTITUDES // count)
    rot = random_rotations(REPLICA_FIELD_ATTITUDES, rng)[which]
    t_field = liu2022.PAPER_FIELD_TEMPERATURE_DEGC + 0.02 * rng.normal(size=count)
    f_field = (
        f0
        + 40.0 * np.sin(np.linspace(0.0, 2.5 * np.pi, count))
        + _smooth_noise(count, rng, 5, 10.0)
    )
    return log(rot @ world, t_field, f_field, 2.0)


def _sweep_log(log, rng, world, attitudes: int, f0: float) -> pd.DataFrame:
    """The temperature sweep (beyond the paper): `attitudes` random attitudes while the
    temperature sweeps `REPLICA_SWEEP_RANGE_DEGC`, in the field f0 [nT]."""
    rot = random_rotations(attitudes, rng)
    t_sweep = np.linspace(*REPLICA_SWEEP_RANGE_DEGC, attitudes) + 0.02 * rng.normal(size=attitudes)
    f_sweep = f0 + _smooth_noise(attitudes, rng, 50, 8.0)
    return log(rot @ world, t_sweep, f_sweep, 2.0)


def write_replica(
    out_dir, *, seed: int = 0, noise: float | None = None, n: int | None = None
) -> list:
    """Write the `replica` of the experiment of [1] to `out_dir`: its four logs and truth.json,
    together (`Outputs`); returns the paths written."""
    out_dir = Path(out_dir)
    logs, truth = replica(seed=seed, noise=noise, n=n)
    with Outputs() as outputs:  # the five files appear together, or none of them
        for name, frame in logs.items():
            outputs.csv(out_dir / name, finite_table(frame))
        outputs.json(out_dir / "truth.json", strict(truth))
    return [out_dir / name for name in [*logs, "truth.json"]]


def replica_truth(path) -> tuple:
    """(params, TemperatureModel) from a replica's truth.json."""
    document = read_json(path, "replica truth file")
    try:
        params = Zhou2010Parameters.from_dict(document["parameters"])
        model = TemperatureModel.from_dict(document["temperature_model"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: not a replica truth file ({exc})") from None
    return params, model
