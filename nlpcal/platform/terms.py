"""The Tolles-Lawson terms: the regressors of a platform's own field at a scalar magnetometer.

A scalar magnetometer on a moving platform reads the Earth's field plus the field of the platform
along it. Tolles and Lawson [1] write that field, projected on the Earth's field direction, as a
sum of terms in the direction cosines cos X_i = B_i / |B| of the Earth's field in the platform's
axes, which a vector magnetometer on the platform measures (Eq. 1 of Leliak [2], Eq. 3-6 of
Gnadt et al. [3]):

    permanent  H_p = sum_i a_i cos X_i                              3 terms   [nT]
    induced    H_i = |B| sum_{i<=j} b_ij cos X_i cos X_j            6 terms   [nT]
    eddy       H_e = |B| sum_{i,j} c_ij cos X_i d(cos X_j)/dt       9 terms   [nT]

The permanent terms are the field of the platform's magnetised parts, the induced terms that of
its soft iron magnetised by the Earth's field (hence |B|), the eddy terms that of currents the
changing flux induces in its conductors (hence the time derivative). Because
cos^2 X + cos^2 Y + cos^2 Z = 1, the three squared induced terms add up to |B| and the three
diagonal eddy terms to |B| d(1/2)/dt = 0 [2]: the 18 terms are (nearly) collinear, and the usual
reduced set of 16 leaves out cos^2 Z and cos Z d(cos Z)/dt (the "induced5" and "eddy8" of
MagNav.jl [3]).

The derivative is the central difference of the cosines over two sample intervals, one-sided at
the two ends of the record (`numpy.gradient`), as MagNav.jl's `fdm` takes it [3], but divided
by the interval so that an eddy coefficient is in seconds, whatever the sample rate. |B| is the
vector magnetometer's magnitude in its base unit, so an induced coefficient is in the scalar's
unit per vector unit ([1] when both are in nT) and an eddy coefficient in that times seconds.

References
----------
[1] Tolles W. E., Lawson J. D. (1950), Magnetic compensation of MAD equipped aircraft, Airborne
    Instruments Laboratory report 201-1.
[2] Leliak P. (1961), Identification and evaluation of magnetic-field sources of magnetic airborne
    detector equipped aircraft, IRE Transactions on Aerospace and Navigational Electronics
    ANE-8(3), 95-105. doi:10.1109/TANE3.1961.4201799
[3] Gnadt A. R., Belarge J., Canciani A., Conger L., Curro J., Edelman A., Morales P., O'Keeffe
    M. F., Taylor J., Rackauckas C. (2022), Signal enhancement for magnetic navigation challenge
    problem, arXiv:2007.12158. doi:10.48550/arXiv.2007.12158
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

#: The axis pairs (i, j), 0-based, of the six induced terms: cos X_i cos X_j with i <= j.
INDUCED_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
#: The axis pairs of the nine eddy terms: cos X_i d(cos X_j)/dt.
EDDY_PAIRS = tuple((i, j) for i in range(3) for j in range(3))
#: The term sets: 18 (all) and the usual 16 (without cos^2 Z and cos Z d(cos Z)/dt, which the
#: identity sum_i cos^2 X_i = 1 makes collinear with the others).
TERM_SETS = (18, 16)
AXES = "xyz"


def term_names(terms: int = 18) -> list:
    """The names of the Tolles-Lawson terms of a set, in the order of the design matrix:
    "permanent_x", "induced_xy", "eddy_x_dz" ... (`TERM_SETS`)."""
    if terms not in TERM_SETS:
        raise InputError(f"--terms {terms}: expected one of {', '.join(map(str, TERM_SETS))}")
    induced, eddy = _pairs(terms)
    return (
        [f"permanent_{a}" for a in AXES]
        + [f"induced_{AXES[i]}{AXES[j]}" for i, j in induced]
        + [f"eddy_{AXES[i]}_d{AXES[j]}" for i, j in eddy]
    )


def term_units(terms: int, scalar_unit: str, vector_unit: str) -> list:
    """The unit of each term's coefficient: the scalar's unit for a permanent term, per vector
    unit for an induced one, times seconds for an eddy one."""
    ratio = "1" if scalar_unit == vector_unit else f"{scalar_unit}/{vector_unit}"
    eddy = "s" if ratio == "1" else f"{ratio} s"
    kinds = {"permanent": scalar_unit, "induced": ratio, "eddy": eddy}
    return [kinds[name.split("_")[0]] for name in term_names(terms)]


def _pairs(terms: int) -> tuple:
    if terms == 16:
        return INDUCED_PAIRS[:-1], EDDY_PAIRS[:-1]
    return INDUCED_PAIRS, EDDY_PAIRS


def direction_cosines(vector) -> tuple:
    """(cos X_i, |B|) of vector readings (N, 3): the direction cosines of the field in the
    platform's axes [1], (N, 3), and its magnitude [vector unit], (N,)."""
    vector = np.asarray(vector, dtype=float)
    magnitude = np.sqrt(np.einsum("ij,ij->i", vector, vector))
    return vector / magnitude[:, None], magnitude


def cosine_rates(vector, rate_hz: float) -> np.ndarray:
    """d(cos X_i)/dt of vector readings (N, 3) sampled at `rate_hz`: the central difference,
    one-sided at the ends (module docstring). [1/s]"""
    cosines, _ = direction_cosines(vector)
    if cosines.shape[0] < 2:
        return np.zeros_like(cosines)
    return np.gradient(cosines, 1.0 / rate_hz, axis=0)


def design(vector, rates, terms: int = 18, out=None) -> np.ndarray:
    """The Tolles-Lawson regressors of vector readings (N, 3) [vector unit] and their cosine
    rates (N, 3) [1/s] (`cosine_rates`), one row per term of `term_names`: (terms, N), written
    into `out` (at least that many rows of N) when given."""
    vector, rates = np.asarray(vector, dtype=float), np.asarray(rates, dtype=float)
    rows = np.empty((terms, vector.shape[0])) if out is None else out
    magnitude = np.sqrt(np.einsum("ij,ij->i", vector, vector))
    cosines = rows[:3]
    np.divide(vector.T, magnitude, out=cosines)  # Eq. 3 of [3]: permanent
    scaled = magnitude * cosines  # |B| cos X_i
    induced, eddy = _pairs(terms)
    for k, (i, j) in enumerate(induced, start=3):  # Eq. 4: induced
        np.multiply(scaled[i], cosines[j], out=rows[k])
    for k, (i, j) in enumerate(eddy, start=3 + len(induced)):  # Eq. 5: eddy
        np.multiply(scaled[i], rates[:, j], out=rows[k])
    return rows
