"""A causal band-pass whose state crosses the blocks of a pass, and the Gram matrix it leaves.

The Tolles-Lawson fit regresses the band-passed scalar on the band-passed terms (Gnadt et al.
2022, section III; `nlpcal.platform.terms`): the band-pass keeps the manoeuvres (0.1 to 0.9 Hz at
10 Hz in MagNav.jl) and removes the slow geology and diurnal variation and the fast noise. MagNav
filters the whole record forwards and backwards (`filtfilt`, zero phase). Here the filter runs
forwards only (`scipy.signal.sosfilt`), so that the record can be read once, block by block, on
threads or on Dask (`nlpcal.passes.reduce`). To keep the magnitude response of the zero-phase
filter, the Butterworth filter of order 4 is applied twice in cascade: |H|^2, the response of
filtfilt; only the phase differs, and a linear filter applied to the scalar and to every term
alike leaves the regression's model intact whatever its phase.

A block's rows cannot wait for the state of the filter at its start, which the blocks before it
set. The filter is linear, so a block is filtered from the zero state and what its true initial
state z adds is kept as linear maps of z (the state-space form of a cascade of sections):

    y = y0 + F z            the block's output, F its free response (rows, states)
    z' = e + P z            the state at its end

so that for the columns Y = Y0 + F Z, Y'Y = Y0'Y0 + Z'F'Y0 + Y0'F Z + Z'F'F Z and 1'Y = 1'Y0 +
1'F Z: a block keeps G0 = Y0'Y0, C = F'Y0, M = F'F, s0 = 1'Y0, f = 1'F, E and P (`Segment`),
whose size does not depend on its rows, and two neighbouring blocks merge into the segment of both
(`Segment.then`). The pass ends with the whole record's segment.

The filter starts in the steady state of a constant input equal to the first row (the state
`scipy.signal.sosfilt_zi` gives), so that it starts without a step. A band-pass does not pass a
constant: from that state a constant gives no output, so filtering the rows from it is
filtering the rows less the first row from the zero state, which is how it is done
(`origin`). That also keeps the large constant part of the columns (50 000 nT in the scalar)
out of the sums, where it would cancel to rounding against the 0.01 nT that are left after
compensation. The first `settling` rows of the record (`settling_rows`) still carry the
transient of the rest of the signal and are left out of the sums, as MagNav trims the ends of
its record.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..errors import InputError

#: Order of the Butterworth band-pass (MagNav.jl's `pole = 4`), applied twice (module docstring).
ORDER = 4
#: The default band of MagNav.jl's `create_TL_coef` (pass1, pass2 at fs = 10 Hz). [Hz]
DEFAULT_BAND_HZ = (0.1, 0.9)
#: The rows left out at the start hold the impulse response's first 1 - SETTLED of its energy.
SETTLED = 1e-4


def require_scipy():
    """scipy.signal, or an InputError naming the extra that installs it."""
    try:
        from scipy import signal
    except ImportError:
        raise InputError("the platform fit needs scipy: pip install 'nlpcal[platform]'") from None
    return signal


def check_band(band_hz, rate_hz: float) -> tuple:
    """(low, high) of a band-pass [Hz] that a rate of `rate_hz` [Hz] can carry, or InputError."""
    low, high = (float(b) for b in band_hz)
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"the sample rate must be a positive number of Hz, got {rate_hz!r}")
    nyquist = rate_hz / 2.0
    if not (np.isfinite(low) and np.isfinite(high) and 0.0 < low < high < nyquist):
        raise InputError(
            f"--band {low:g} {high:g}: expected 0 < LOW_HZ < HIGH_HZ < {nyquist:g} Hz (half the "
            f"sample rate of {rate_hz:g} Hz), e.g. --band 0.1 0.9 at 10 Hz"
        )
    return low, high


@lru_cache(maxsize=16)
def sections(low_hz: float, high_hz: float, rate_hz: float) -> np.ndarray:
    """The second-order sections of the band-pass: the Butterworth filter of `ORDER` between
    `low_hz` and `high_hz` [Hz] at `rate_hz` [Hz], twice in cascade (module docstring)."""
    signal = require_scipy()
    once = signal.butter(ORDER, [low_hz, high_hz], btype="bandpass", fs=rate_hz, output="sos")
    return np.vstack([once, once])


def states(sos: np.ndarray) -> int:
    """The length of the flattened state of a cascade of sections (two per section)."""
    return 2 * sos.shape[0]


def settling_rows(sos: np.ndarray, low_hz: float, rate_hz: float) -> int:
    """The rows after which the impulse response keeps less than `SETTLED` of its energy,
    looked for within 100 periods of the band's low edge. [1]"""
    length = int(min(1 << 22, max(64, 100 * rate_hz / low_hz)))
    impulse = np.zeros(length)
    impulse[0] = 1.0
    energy = np.cumsum(require_scipy().sosfilt(sos, impulse) ** 2)
    return int(np.searchsorted(energy, (1.0 - SETTLED) * energy[-1])) + 1


@dataclass
class Segment:
    """The sums of consecutive filtered rows as linear maps of the filter's state at their start
    (module docstring): y = y0 + F z, z' = e + P z, with z of shape (states, columns).

    rows : rows of the segment, counted or not. [1]
    gram0 : Y0'Y0 over the counted rows. (columns, columns)
    cross : F'Y0. (states, columns)
    free : F'F. (states, states)
    sum0 : 1'Y0. (columns,)
    free_sum : 1'F. (states,)
    end0 : e, the state at the end from the zero state. (states, columns)
    transition : P. (states, states)
    """

    rows: int
    gram0: np.ndarray
    cross: np.ndarray
    free: np.ndarray
    sum0: np.ndarray
    free_sum: np.ndarray
    end0: np.ndarray
    transition: np.ndarray

    def then(self, later: Segment) -> Segment:
        """The segment of these rows followed by `later`'s: `later` starts in the state
        e1 + P1 z, so its y0 gains F2 e1 and its F becomes F2 P1."""
        e1, p1 = self.end0, self.transition
        shifted = later.cross + later.free @ e1  # F2'(Y02 + F2 e1)
        return Segment(
            rows=self.rows + later.rows,
            gram0=self.gram0 + later.gram0 + later.cross.T @ e1 + e1.T @ shifted,
            cross=self.cross + p1.T @ shifted,
            free=self.free + p1.T @ later.free @ p1,
            sum0=self.sum0 + later.sum0 + later.free_sum @ e1,
            free_sum=self.free_sum + later.free_sum @ p1,
            end0=later.end0 + later.transition @ e1,
            transition=later.transition @ p1,
        )

    def sums(self) -> tuple:
        """(Y'Y, 1'Y) of the filtered columns over the counted rows, from the zero state at the
        segment's first row (that of the record's first row less itself: module docstring)."""
        return 0.5 * (self.gram0 + self.gram0.T), self.sum0


def flat_states(end: np.ndarray) -> np.ndarray:
    """The states sosfilt returns for a filter along the last axis, (sections, columns, 2), as
    (states, columns), state 2 s + k being delay k of section s."""
    return end.transpose(0, 2, 1).reshape(2 * end.shape[0], end.shape[1])


class FreeResponse:
    """F and the end state of each unit initial state, for blocks of a given length (kept: every
    block of a pass but the last has the same length)."""

    def __init__(self, sos: np.ndarray):
        self.sos = sos
        self._kept: dict = {}

    def __call__(self, length: int) -> tuple:
        """(F' (states, length), P (states, states)) for `length` rows."""
        if length not in self._kept:
            n = states(self.sos)
            zi = np.eye(n).reshape(self.sos.shape[0], 2, n).transpose(0, 2, 1)  # m: unit state m
            response, end = require_scipy().sosfilt(self.sos, np.zeros((n, length)), zi=zi)
            self._kept[length] = (response, flat_states(end))
        return self._kept[length]


def segment(columns: np.ndarray, sos: np.ndarray, free: FreeResponse, skip: int = 0) -> Segment:
    """The segment of rows given as columns (columns, rows), C-ordered so that sosfilt filters
    each column along its rows without a copy, from the zero state; its first `skip` rows
    filtered but not counted in the sums."""
    zero = np.zeros((sos.shape[0], columns.shape[0], 2))
    output, end = require_scipy().sosfilt(sos, columns, zi=zero)
    response, transition = free(columns.shape[1])
    counted, f = output[:, skip:], response[:, skip:]
    return Segment(
        rows=columns.shape[1],
        gram0=counted @ counted.T,
        cross=f @ counted.T,
        free=f @ f.T,
        sum0=counted.sum(axis=1),
        free_sum=f.sum(axis=1),
        end0=flat_states(end),
        transition=transition,
    )
