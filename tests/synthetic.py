"""Synthetic fluxgate logs for the tests, written independently of nlpcal's simulator and model.

The forward model is typed in again from Eq. 4 of Zhou et al. (2010): the sensor axes in the ideal
frame are the rows of T, each axis reads (1 + s) times the projection of the field on it, plus
its offset. Directions come from normalised Gaussian vectors (uniform on the sphere).
"""

import numpy as np

PAPER_TRUTH = {  # final parameters of Zhou et al. (2010), section 6
    "z_x": -71.55,
    "z_y": 188.13,
    "z_z": 116.29,
    "s_x": 0.0072,
    "s_y": -0.0024,
    "s_z": -0.0049,
    "alpha_deg": -2.34,
    "beta_deg": 1.29,
    "gamma_deg": -0.27,
}
PAPER_FIELD = 49462.0


def sensor_axes(alpha_deg, beta_deg, gamma_deg):
    a, b, g = np.radians([alpha_deg, beta_deg, gamma_deg])
    x_axis = [np.cos(a) * np.cos(g), np.cos(a) * np.sin(g), -np.sin(a)]
    y_axis = [0.0, np.cos(b), np.sin(b)]
    z_axis = [0.0, 0.0, 1.0]
    return np.array([x_axis, y_axis, z_axis])


def sensor_output(field_ideal, truth):
    """B_M for true field vectors given in the ideal orthogonal frame. [nT]"""
    axes = sensor_axes(truth["alpha_deg"], truth["beta_deg"], truth["gamma_deg"])
    out = np.empty_like(field_ideal)
    for k, name in enumerate("xyz"):
        out[:, k] = (1 + truth[f"s_{name}"]) * field_ideal @ axes[k] + truth[f"z_{name}"]
    return out


def uniform_directions(n, rng):
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def make_log(n=2500, noise=2.5, seed=11, truth=PAPER_TRUTH, field=PAPER_FIELD, directions=None):
    """(B_M, true field vectors) with white noise of `noise` nT on each axis."""
    rng = np.random.default_rng(seed)
    if directions is None:
        directions = uniform_directions(n, rng)
    field_ideal = field * directions
    samples = sensor_output(field_ideal, truth) + noise * rng.standard_normal(field_ideal.shape)
    return samples, field_ideal


def planar_directions(n, rng):
    """Field directions confined to the sensor's x-y plane: rotation about z only."""
    phi = rng.uniform(0, 2 * np.pi, n)
    return np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n)])


def circle_directions(n, rng, axis, half_angle_deg):
    """Field directions on one circle, `half_angle_deg` from `axis`: the sensor turned about one
    axis only (a turntable), the field at a fixed angle to it."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    phi = rng.uniform(0, 2 * np.pi, n)
    half = np.radians(half_angle_deg)
    ring = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    return np.cos(half) * axis + np.sin(half) * ring


def band_directions(n, rng, tilt_deg):
    """Field directions within `tilt_deg` of the sensor's x-y plane: turns about z with tilts."""
    phi = rng.uniform(0, 2 * np.pi, n)
    lift = np.radians(rng.uniform(-tilt_deg, tilt_deg, n))
    return np.column_stack([np.cos(lift) * np.cos(phi), np.cos(lift) * np.sin(phi), np.sin(lift)])


def tilt_directions(n, rng, max_tilt_deg=20.0, inclination_deg=60.0):
    """Field directions in the sensor frame of a sensor turned to any heading but rolled and
    pitched by at most `max_tilt_deg` (uniform), in a field `inclination_deg` below the horizon
    (north, east, down): a vehicle, or a device carried upright. The world field is turned into
    the sensor frame by the heading about z, then the pitch about y, then the roll about x."""
    heading = rng.uniform(0, 2 * np.pi, n)
    roll, pitch = np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, (2, n)))
    dip = np.radians(inclination_deg)
    north, down = np.cos(dip), np.sin(dip)
    v = (np.cos(heading) * north, -np.sin(heading) * north, np.full(n, down))  # heading
    v = (
        np.cos(pitch) * v[0] - np.sin(pitch) * v[2],
        v[1],
        np.sin(pitch) * v[0] + np.cos(pitch) * v[2],
    )
    v = (
        v[0],
        np.cos(roll) * v[1] + np.sin(roll) * v[2],
        -np.sin(roll) * v[1] + np.cos(roll) * v[2],
    )
    return np.column_stack(v)


def smooth_directions(n, rng, coefficient=0.98, rate=0.03, start=None):
    """Field directions in the frame of a sensor turned smoothly (by hand, by a vehicle): body
    rates an AR(1) process with `coefficient` and about `rate` rad per sample in magnitude, each
    sample's direction the last one turned by the rate (Rodrigues' formula)."""
    spread = rate / np.sqrt(3.0)
    innovation = np.sqrt(1.0 - coefficient**2) * spread
    omega = spread * rng.standard_normal(3)
    v = uniform_directions(1, rng)[0] if start is None else np.asarray(start, dtype=float)
    out = np.empty((n, 3))
    for i in range(n):
        out[i] = v
        omega = coefficient * omega + innovation * rng.standard_normal(3)
        angle = np.linalg.norm(omega)
        axis = omega / angle
        v = (
            v * np.cos(angle)
            + np.cross(axis, v) * np.sin(angle)
            + axis * (axis @ v) * (1.0 - np.cos(angle))
        )
        v /= np.linalg.norm(v)
    return out


def slow_field(n, rng, mean=50_000.0, amplitude=30.0, cycles=1.5):
    """A field magnitude that changes slowly over the log (a survey day): mean + amplitude
    sin(2 pi cycles t / T + phase), the phase uniform. [nT]"""
    t = np.arange(n) / n
    return mean + amplitude * np.sin(2 * np.pi * cycles * t + rng.uniform(0, 2 * np.pi))


def scenario_log(n, noise, rng, directions, magnitude, truth=PAPER_TRUTH):
    """B_M for unit field `directions` (n, 3) in the ideal frame and field `magnitude` (a number
    or (n,)) with white noise of `noise` nT on each axis. [nT]"""
    field_ideal = np.asarray(magnitude, dtype=float).reshape(-1, 1) * directions
    return sensor_output(field_ideal, truth) + noise * rng.standard_normal(field_ideal.shape)


def gauge_truth(truth=PAPER_TRUTH):
    """The true parameters as a calibration without a reference reports them: the scale factors
    1 + s divided by their mean, so that s_x + s_y + s_z = 0."""
    mean = np.mean([1.0 + truth[f"s_{a}"] for a in "xyz"])
    return {**truth, **{f"s_{a}": (1.0 + truth[f"s_{a}"]) / mean - 1.0 for a in "xyz"}}


def motor_current_log(n=20_000, noise=5.0, seed=27, per_amp=(120.0, -80.0, 300.0), amps=40.0):
    """(B_M, current [A]) of a sensor near a motor: Eq. 4 typed in again (`sensor_output`) plus
    a stray field per_amp * current [nT/A] added in the sensor's axes, the offset that follows
    the current; the current uniform on 0..amps A, drawn independently of the attitudes."""
    rng = np.random.default_rng(seed)
    field_ideal = PAPER_FIELD * uniform_directions(n, rng)
    current = rng.uniform(0.0, amps, n)
    stray = current[:, None] * np.asarray(per_amp, dtype=float)[None, :]
    samples = sensor_output(field_ideal, PAPER_TRUTH) + stray
    return samples + noise * rng.standard_normal(samples.shape), current


def smooth_motor_log(n=20_000, noise=5.0, seed=0, per_amp=(120.0, -80.0, 300.0)):
    """(B_M, current [A]) of a vehicle turned smoothly (`smooth_directions`) whose motor
    current swings slowly between 5 and 35 A with a random walk on top, and whose field carries
    a slowly drifting error along (1, 1, 1) nT: residuals and scores alike in neighbours."""
    rng = np.random.default_rng(seed)
    directions = smooth_directions(n, rng)
    phase = rng.uniform(0.0, 2 * np.pi)
    current = 20.0 + 15.0 * np.sin(np.linspace(0.0, 6 * np.pi, n) + phase)
    current += np.cumsum(rng.normal(0.0, 0.05, n))
    drift = np.cumsum(rng.normal(0.0, 0.3, n))
    samples = sensor_output(PAPER_FIELD * directions, PAPER_TRUTH)
    samples += np.outer(current, per_amp) + np.outer(drift - drift.mean(), (1.0, 1.0, 1.0))
    return samples + noise * rng.standard_normal(samples.shape), current


# --- a platform's own field: the Tolles-Lawson figure-of-merit box ------------------------------

#: True Tolles-Lawson coefficients of a platform: permanent [nT], induced [1] (x x, x y, x z, y y,
#: y z, z z), eddy [s] (x dx, x dy, x dz, y dx, ..., z dz), the scale of a small aircraft's.
TL_TRUTH = {
    "permanent": np.array([12.0, -25.0, 18.0]),
    "induced": np.array([2.0e-4, -1.5e-4, 0.8e-4, -1.0e-4, 2.5e-4, 0.6e-4]),
    "eddy": np.array([3e-3, -2e-3, 1e-3, 2.5e-3, -1.5e-3, 2e-3, -1e-3, 3e-3, 1.5e-3]),
}


def box_attitudes(t):
    """(roll, pitch, heading) [rad] of a figure-of-merit box flown at times t [s]: four legs
    (north, east, south, west) of equal length joined by 30 s turns, each leg with pitch, roll
    and yaw manoeuvres of +/-5, +/-10 and +/-5 deg at periods of 5 to 8 s, one after the other."""
    leg = t[-1].real / 4
    k = np.clip(np.floor(t.real / leg), 0, 3)
    into = t - k * leg  # time into the leg [s]
    turn = _ramp(into / 30.0)
    heading = np.radians(90.0) * (k - 1 + 0.5 * (1 - np.cos(np.pi * turn)))
    third = (leg - 30.0) / 3
    window = [_bump((into - 30.0 - j * third) / third) for j in range(3)]
    pitch = np.radians(5.0) * window[0] * np.sin(2 * np.pi * into / 6.0)
    roll = np.radians(10.0) * window[1] * np.sin(2 * np.pi * into / 8.0)
    yaw = np.radians(5.0) * window[2] * np.sin(2 * np.pi * into / 5.0)
    return roll, pitch, heading + yaw


def _ramp(x):
    """min(max(x, 0), 1), for complex x by its real part (the complex step passes through)."""
    return np.where(x.real < 0, 0 * x, np.where(x.real > 1, 0 * x + 1, x))


def _bump(x):
    """sin^2(pi x) on 0 <= x <= 1, zero elsewhere: a smooth window."""
    inside = (x.real >= 0) & (x.real <= 1)
    return np.where(inside, np.sin(np.pi * x) ** 2, 0 * x)


def body_directions(t, inclination_deg=65.0, declination_deg=3.0):
    """The unit vector of the Earth's field in the platform's axes (x forward, y right, z down)
    at times t [s] of the box: R(roll, pitch, heading)' times the field's north-east-down
    direction, R = Rz(heading) Ry(pitch) Rx(roll)."""
    roll, pitch, heading = box_attitudes(t)
    inc, dec = np.radians(inclination_deg), np.radians(declination_deg)
    ned = np.array([np.cos(inc) * np.cos(dec), np.cos(inc) * np.sin(dec), np.sin(inc)])
    # R' n for R = Rz Ry Rx: undo the heading, then the pitch, then the roll
    n1 = np.cos(heading) * ned[0] + np.sin(heading) * ned[1]
    e1 = -np.sin(heading) * ned[0] + np.cos(heading) * ned[1]
    d1 = ned[2] + 0 * heading
    x = np.cos(pitch) * n1 - np.sin(pitch) * d1
    d2 = np.sin(pitch) * n1 + np.cos(pitch) * d1
    y = np.cos(roll) * e1 + np.sin(roll) * d2
    z = -np.sin(roll) * e1 + np.cos(roll) * d2
    return np.stack([x, y, z], axis=-1)


def platform_record(n=12_000, rate_hz=10.0, noise=0.01, seed=5, truth=TL_TRUTH, field=50_000.0):
    """(vector [nT], scalar [nT], platform field [nT], Earth's field magnitude [nT]) of a box
    flown at `rate_hz`: the vector magnetometer reads the Earth's field in the platform's axes,
    the scalar its magnitude (with a slow variation below the band) plus the Tolles-Lawson field
    of `truth` (Eq. 1 of Leliak 1961, typed in here with the exact derivative of the direction
    cosines, by a complex step) plus white noise of `noise` nT."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    cosines = body_directions(t)
    step = 1e-20  # complex-step derivative: exact to rounding
    rates = body_directions(t + 1j * step).imag / step
    magnitude = field + 20.0 * np.sin(2 * np.pi * t / 3000.0)  # geology, diurnal: below the band
    induced_pairs = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    platform = cosines @ truth["permanent"]
    for b, (i, j) in zip(truth["induced"], induced_pairs):
        platform += b * magnitude * cosines[:, i] * cosines[:, j]
    for c, (i, j) in zip(truth["eddy"], [(i, j) for i in range(3) for j in range(3)]):
        platform += c * magnitude * cosines[:, i] * rates[:, j]
    vector = magnitude[:, None] * cosines
    scalar = magnitude + platform + noise * rng.standard_normal(n)
    return vector, scalar, platform, magnitude


def drifting_sensor_output(field_ideal, truth, dt, days, sigma, zeta, eta_deg, drift_per_day):
    """B_M of a sensor whose parameters drift, for true field vectors in the ideal frame [nT]:
    per axis j the gain (1 + s_j)(1 + sigma_j dt)(1 + d_j days) [1] and the offset
    z_j + zeta_j dt [nT], each angle alpha + eta_alpha dt [deg] (each sample its own axes).

    dt : temperature minus the base temperature [degC]; days : time from the reference time [d];
    sigma [1/degC], zeta [nT/degC], eta_deg [deg/degC], drift_per_day [1/d]: three values each.
    """
    dt = np.asarray(dt, dtype=float)
    a, b, g = (
        np.radians(truth[f"{name}_deg"] + slope * dt)
        for name, slope in zip(("alpha", "beta", "gamma"), eta_deg)
    )
    x_axis = np.column_stack([np.cos(a) * np.cos(g), np.cos(a) * np.sin(g), -np.sin(a)])
    y_axis = np.column_stack([np.zeros_like(b), np.cos(b), np.sin(b)])
    projections = np.column_stack(
        [
            np.sum(field_ideal * x_axis, axis=1),
            np.sum(field_ideal * y_axis, axis=1),
            field_ideal[:, 2],
        ]
    )
    out = np.empty_like(projections)
    for k, name in enumerate("xyz"):
        gain = (1 + truth[f"s_{name}"]) * (1 + sigma[k] * dt) * (1 + drift_per_day[k] * days)
        out[:, k] = gain * projections[:, k] + truth[f"z_{name}"] + zeta[k] * dt
    return out


def varying_magnitude(rng, rms_rate=1.0, periods=(20.0, 300.0), terms=12, base=PAPER_FIELD):
    """A field magnitude F(t) = base + sum_k a_k sin(w_k t + phi_k), periods drawn uniformly in
    `periods` [s], each term the same share of dF/dt, scaled to an rms dF/dt of `rms_rate`.
    Returns the function t [s] -> F [nT]."""
    omega = 2 * np.pi / rng.uniform(periods[0], periods[1], terms)
    phase = rng.uniform(0, 2 * np.pi, terms)
    amplitude = (
        np.full(terms, rms_rate / np.sqrt(terms / 2)) / omega
    )  # rms of a_k w_k cos: a w/sqrt2

    def magnitude(t):
        t = np.asarray(t, dtype=float)
        return base + np.sin(np.multiply.outer(t, omega) + phase) @ amplitude

    return magnitude


def lagged_log(
    seed=0,
    rate_hz=10.0,
    seconds=3600.0,
    tau=0.037,
    noise=0.05,
    reference_noise=0.05,
    rms_rate=1.0,
    truth=PAPER_TRUTH,
):
    """(B_M, R, t, F): a log of uniform attitudes in a field whose magnitude F(t) varies
    (`varying_magnitude`), and a scalar reference late by `tau` [s]: R(t) = F(t - tau) + noise.
    White noise of `noise` nT on each sensor axis and `reference_noise` nT on R."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(rate_hz * seconds)) / rate_hz
    magnitude = varying_magnitude(rng, rms_rate)
    field_ideal = magnitude(t)[:, None] * uniform_directions(t.size, rng)
    samples = sensor_output(field_ideal, truth) + noise * rng.standard_normal(field_ideal.shape)
    reference = magnitude(t - tau) + reference_noise * rng.standard_normal(t.size)
    return samples, reference, t, magnitude
