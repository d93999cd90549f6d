"""The Tolles-Lawson fit of a platform's field and the compensation it gives.

`fit_tolles_lawson` reads the record once (`nlpcal.passes.reduce`, in threads or on Dask): each
block of rows becomes the Tolles-Lawson terms (`nlpcal.platform.terms`) and the auxiliary
channels, band-passed with the scalar by a causal filter whose state crosses the blocks
(`nlpcal.platform.bandpass`), and leaves the sums of a Gram matrix. The coefficients are the
ridge solution of those sums, the ridge parameter chosen by generalised cross-validation
(`nlpcal.platform.ridge`): the fit is linear least squares, solved in closed form (Gnadt et al.
2022, Eq. 7 and 8, with the ridge term of MagNav.jl's `linreg`).

The compensated scalar is the scalar minus the platform's field the terms predict, unfiltered,
less its mean over the record (MagNav.jl's `detrend(..., mean_only = true)`): the band-pass
cannot see a constant, so the compensation keeps the scalar's mean.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import passes
from ..errors import InputError
from ..results import Document, DocumentReader
from . import bandpass, ridge
from .terms import TERM_SETS, cosine_rates, design, term_names, term_units

#: Rows per chunk of the pass (about 3 MB of 20 float64 columns per chunk and thread).
CHUNK_ROWS = 1 << 14
#: A coefficient whose variance inflation exceeds this is not individually meaningful (the
#: usual rule of thumb of regression diagnostics, Marquardt 1970). [1]
MAX_VARIANCE_INFLATION = 10.0
#: The fit needs at least this many counted rows per coefficient. [1]
ROWS_PER_TERM = 10
#: A band-passed column whose sum of squares is below this fraction of the largest does not vary
#: within the band (a constant channel, filtered to rounding). [1]
SILENT_COLUMN = 1e-24
#: The base units a scalar or vector is computed in (`nlpcal.units.base_unit`).
BASE_UNITS = ("nT", "raw")


@dataclass
class TollesLawsonFit(Document):
    """A Tolles-Lawson compensation of a scalar magnetometer on a platform (`fit_tolles_lawson`).

    Attributes
    ----------
    terms : int
        The term set: 18 (3 permanent, 6 induced, 9 eddy) or 16 (without cos^2 Z and
        cos Z d(cos Z)/dt).
    names : list of str
        The name of every coefficient: the terms (`nlpcal.platform.terms.term_names`), then the
        auxiliary channels.
    coefficients : numpy.ndarray
        The coefficient of every name. [coefficient_units]
    coefficient_units : list of str
        The unit of each coefficient: the scalar's unit for a permanent term, per vector unit
        for an induced one, times seconds for an eddy one, per channel unit for a channel.
    variance_inflation : numpy.ndarray
        The variance inflation factor of each coefficient (the diagonal of the inverse of the
        band-passed terms' correlation matrix). [1]
    band_hz : tuple of float
        The band-pass (low, high). [Hz]
    sample_rate_hz : float
        The sample rate of the record. [Hz]
    ridge_parameter : float
        lambda, chosen by generalised cross-validation, for the columns scaled to unit norm. [1]
    effective_terms : float
        tr H, the degrees of freedom the ridge fit uses. [1]
    condition_number : float
        Of the band-passed design with its columns scaled to unit norm. [1]
    uncompensated_std : float
        The standard deviation (ddof = 0) of the band-passed scalar. [unit]
    compensated_std : float
        That of the band-passed compensated scalar: the figure-of-merit style number. [unit]
    n : int
        The rows in the sums (the record less the first `settling_rows`).
    settling_rows : int
        The rows at the start left out while the band-pass settles.
    unit : str
        The scalar's base unit ("nT", or "raw").
    vector_unit : str
        The vector magnetometer's base unit.
    scalar_column, time_column : str or None
        The log's columns of the scalar and of the times, if read from a log.
    columns : list of str
        The vector magnetometer's three columns, if read from a log.
    aux_columns : list of str
        The auxiliary channels, in the order of their coefficients after the terms.
    input : dict
        Where the record came from.

    Examples
    --------
    >>> import numpy as np, nlpcal
    >>> t = np.arange(3000) / 10.0  # [s]
    >>> tilt = 0.3 + 0.2 * np.sin(2.5 * t)  # a slow turn, nodding at 0.4 Hz [rad]
    >>> c = np.column_stack([np.cos(0.3 * t), np.sin(0.3 * t), np.tan(tilt)])
    >>> c *= np.cos(tilt)[:, None]  # unit vectors: the direction cosines [1]
    >>> noise = 0.01 * np.random.default_rng(0).standard_normal(3000)  # [nT]
    >>> fit = nlpcal.fit_tolles_lawson(5e4 * c, 5e4 + c @ [8.0, -5.0, 3.0] + noise, rate_hz=10)
    >>> back = nlpcal.TollesLawsonFit.from_json(fit.to_json())  # the document read back
    >>> back.names[:4], back.improvement_ratio > 10, back.coefficients_meaningful
    (['permanent_x', 'permanent_y', 'permanent_z', 'induced_xx'], True, False)
    """

    FORMAT = "nlpcal-platform"
    READS_VERSIONS = (2,)
    WHAT = "platform compensation"

    terms: int
    names: list
    coefficients: np.ndarray
    coefficient_units: list
    variance_inflation: np.ndarray
    band_hz: tuple
    sample_rate_hz: float
    ridge_parameter: float
    effective_terms: float
    condition_number: float
    uncompensated_std: float
    compensated_std: float
    n: int
    settling_rows: int
    unit: str = "nT"
    vector_unit: str = "nT"
    scalar_column: str | None = None
    time_column: str | None = None
    columns: list = field(default_factory=list)
    aux_columns: list = field(default_factory=list)
    input: dict = field(default_factory=dict)

    @property
    def improvement_ratio(self) -> float:
        """The std of the band-passed scalar before over after compensation. [1]"""
        floor = np.finfo(float).eps * self.uncompensated_std  # nothing left but rounding
        return self.uncompensated_std / max(self.compensated_std, floor, np.finfo(float).tiny)

    @property
    def coefficients_meaningful(self) -> bool:
        """Whether every coefficient's variance inflation is at most MAX_VARIANCE_INFLATION."""
        return bool(np.max(self.variance_inflation) <= MAX_VARIANCE_INFLATION)

    @property
    def statement(self) -> str:
        """What the coefficients and the compensation are worth, in a sentence or two."""
        worst = int(np.argmax(self.variance_inflation))
        inflation = f"{self.variance_inflation[worst]:.3g} for {self.names[worst]}"
        if self.coefficients_meaningful:
            return (
                f"The terms are well conditioned (largest variance inflation {inflation}): the "
                f"coefficients are individually meaningful, and so is the compensation."
            )
        return (
            f"The terms are nearly collinear (condition number {self.condition_number:.3g}, "
            f"largest variance inflation {inflation}): the coefficients are not individually "
            f"meaningful and say nothing about the platform one by one, while the compensation "
            f"they give together is (improvement ratio {self.improvement_ratio:.3g})."
        )

    def interference(self, vector, aux=None) -> np.ndarray:
        """The platform's field at the scalar the coefficients predict, less its mean over the
        rows given, for vector readings (N, 3) [vector unit] sampled at `sample_rate_hz` and
        the auxiliary channels (N, k) [channel units]. [unit]"""
        vector = _vectors(vector)
        rates = cosine_rates(vector, self.sample_rate_hz)
        channels = _channels(aux, vector.shape[0], len(self.aux_columns))
        field = self.coefficients[: self.terms] @ design(vector, rates, self.terms)
        field += channels @ self.coefficients[self.terms :]
        return field - field.mean()

    def compensate(self, vector, scalar, aux=None) -> np.ndarray:
        """The scalar [unit] less the platform's field (`interference`). [unit]"""
        scalar = np.asarray(scalar, dtype=float).reshape(-1)
        return scalar - self.interference(vector, aux)

    def body(self) -> dict:
        return {
            "model": "tolles-lawson",
            "terms": self.terms,
            "coefficients": [
                {"name": name, "value": float(value), "unit": unit, "variance_inflation": float(v)}
                for name, value, unit, v in zip(
                    self.names, self.coefficients, self.coefficient_units, self.variance_inflation
                )
            ],
            "improvement_ratio": self.improvement_ratio,
            "compensated_std": self.compensated_std,
            "uncompensated_std": self.uncompensated_std,
            "unit": self.unit,
            "vector_unit": self.vector_unit,
            "coefficients_meaningful": self.coefficients_meaningful,
            "statement": self.statement,
            "condition_number": self.condition_number,
            "ridge_parameter": self.ridge_parameter,
            "ridge_selection": "generalised cross-validation",
            "effective_terms": self.effective_terms,
            "band_hz": list(self.band_hz),
            "filter": (
                f"Butterworth band-pass of order {bandpass.ORDER}, applied twice, causal, from "
                f"the steady state of the first row"
            ),
            "sample_rate_hz": self.sample_rate_hz,
            "n": self.n,
            "settling_rows": self.settling_rows,
            "scalar_column": self.scalar_column,
            "columns": list(self.columns),
            "aux_columns": list(self.aux_columns),
            "time_column": self.time_column,
            "input": self.input,
        }

    @classmethod
    def from_body(cls, reader: DocumentReader) -> TollesLawsonFit:
        terms = reader.integer("terms")
        if terms not in TERM_SETS:
            raise InputError(f"{reader.source}: terms must be 18 or 16, got {terms}")
        entries = [
            DocumentReader(item, reader.source, f"coefficients[{k}].")
            for k, item in enumerate(reader.items("coefficients"))
        ]
        aux = reader.strings("aux_columns", [])
        names = [e.string("name") for e in entries]
        if names != term_names(terms) + list(aux):
            raise InputError(
                f"{reader.source}: the coefficients must be named {', '.join(term_names(terms))} "
                f"and then the aux_columns"
            )
        band = reader.array("band_hz", (2,))
        rate = reader.number("sample_rate_hz", positive=True)
        bandpass.check_band(band, rate)
        return cls(
            terms=terms,
            names=names,
            coefficients=np.array([e.number("value") for e in entries]),
            coefficient_units=[e.string("unit") for e in entries],
            variance_inflation=np.array(
                [e.number("variance_inflation", minimum=0) for e in entries]
            ),
            band_hz=(float(band[0]), float(band[1])),
            sample_rate_hz=rate,
            ridge_parameter=reader.number("ridge_parameter", minimum=0),
            effective_terms=reader.number("effective_terms", minimum=0),
            condition_number=reader.number("condition_number", minimum=1),
            uncompensated_std=reader.number("uncompensated_std", minimum=0),
            compensated_std=reader.number("compensated_std", positive=True),
            n=reader.integer("n", minimum=1),
            settling_rows=reader.integer("settling_rows"),
            unit=reader.string("unit", options=BASE_UNITS),
            vector_unit=reader.string("vector_unit", options=BASE_UNITS),
            scalar_column=reader.string("scalar_column", None),
            time_column=reader.string("time_column", None),
            columns=reader.strings("columns", []),
            aux_columns=aux,
            input=reader.provenance(),
        )


class PlatformBlock:
    """The work of the pass (`nlpcal.passes.reduce`): rows [vector (3), cosine rates (3),
    channels (k), scalar (1)] -> the `bandpass.Segment` of their terms, channels and scalar."""

    def __init__(self, terms: int, sos: np.ndarray, settling: int, chunk_rows: int, first_row):
        self.terms, self.sos, self.settling, self.chunk_rows = terms, sos, settling, chunk_rows
        self.free = bandpass.FreeResponse(sos)
        self.origin = np.zeros(1)
        self.origin = self.columns(np.asarray(first_row, dtype=float).reshape(1, -1))[:, 0]

    def columns(self, rows: np.ndarray) -> np.ndarray:
        """The regressors (`nlpcal.platform.terms.design`), the channels and the scalar of rows,
        one row each, less those of the record's first row (the steady-state start of
        `nlpcal.platform.bandpass`)."""
        columns = np.empty((self.terms + rows.shape[1] - 6, rows.shape[0]))
        design(rows[:, :3], rows[:, 3:6], self.terms, out=columns)
        columns[self.terms :] = rows[:, 6:].T
        columns -= np.reshape(self.origin, (-1, 1))
        return columns

    def __call__(self, block, reference, start: int) -> bandpass.Segment:
        block = np.asarray(block, dtype=float)
        result: bandpass.Segment | None = None
        for begin in range(0, block.shape[0], self.chunk_rows):
            rows = block[begin : begin + self.chunk_rows]
            skip = min(rows.shape[0], max(0, self.settling - (start + begin)))
            part = bandpass.segment(self.columns(rows), self.sos, self.free, skip)
            result = part if result is None else result.then(part)
        if result is None:  # a block of no rows (a Dask chunk can be empty)
            return bandpass.segment(self.columns(block), self.sos, self.free)
        return result


def fit_tolles_lawson(
    vector,
    scalar,
    *,
    rate_hz: float,
    terms: int = 18,
    band_hz=bandpass.DEFAULT_BAND_HZ,
    aux=None,
    aux_names=None,
    unit: str = "nT",
    vector_unit: str = "nT",
    chunk_rows: int = CHUNK_ROWS,
) -> TollesLawsonFit:
    """Fit the Tolles-Lawson model of a platform's field to a record, in one pass.

    Parameters
    ----------
    vector : array-like or Dask array, shape (N, 3)
        The vector magnetometer's readings, whose direction cosines the terms are made of,
        sampled regularly. [vector_unit]
    scalar : array-like or Dask array, shape (N,)
        The scalar magnetometer's readings on the same rows. [unit]
    rate_hz : float
        The sample rate. [Hz]
    terms : int
        18 (3 permanent, 6 induced, 9 eddy) or the reduced 16.
    band_hz : (float, float)
        The band-pass (`--band`); default 0.1 to 0.9, MagNav.jl's at 10 Hz. [Hz]
    aux : array-like, shape (N, k), optional
        Auxiliary channels (motor current, say) taken as further regressors. [channel units]
    aux_names : sequence of str, optional
        Their names (default aux_1, aux_2 ...).
    unit, vector_unit : str
        The base units of the scalar and of the vector ("nT" or "raw"), for the coefficients'
        units.
    chunk_rows : int
        Rows per chunk of the pass.

    Returns
    -------
    TollesLawsonFit
        The coefficients, the band-passed std before and after, the ridge parameter, the
        condition number and the variance inflation of every term.

    Raises
    ------
    InputError
        Arrays of the wrong shape or with non-finite values, a band the rate cannot carry, a
        record too short for the band-pass and the terms, a channel or scalar that does not
        vary within the band.

    Notes
    -----
    Eq. 1 of Leliak (1961) and Eq. 3-8 of Gnadt et al. (2022) (`nlpcal.platform.terms`); the
    causal band-pass and its carried state in `nlpcal.platform.bandpass`; the ridge and GCV in
    `nlpcal.platform.ridge`.

    Examples
    --------
    >>> import numpy as np, nlpcal
    >>> t = np.arange(3000) / 10.0  # 5 minutes at 10 Hz [s]
    >>> heading, pitch = 0.3 * t + 0.4 * np.sin(1.6 * t), 0.8 + 0.2 * np.sin(2.5 * t)
    >>> c = np.column_stack(
    ...     [np.cos(pitch) * np.cos(heading), np.cos(pitch) * np.sin(heading), np.sin(pitch)])
    >>> scalar = 5e4 + 8 * c[:, 0] - 5 * c[:, 1] + 10 * c[:, 0] * c[:, 2]  # [nT]
    >>> scalar += 0.01 * np.random.default_rng(0).standard_normal(3000)
    >>> fit = nlpcal.fit_tolles_lawson(5e4 * c, scalar, rate_hz=10.0, terms=16)
    >>> len(fit.coefficients), fit.compensated_std < 0.01  # the band-passed noise is left [nT]
    (16, True)
    >>> bool(fit.compensate(5e4 * c, scalar).std() < 0.1)  # the platform's field is gone [nT]
    True
    """
    if terms not in TERM_SETS:
        raise InputError(f"terms {terms!r}: expected one of {', '.join(map(str, TERM_SETS))}")
    low, high = bandpass.check_band(band_hz, float(rate_hz))
    sos = bandpass.sections(low, high, float(rate_hz))
    settling = bandpass.settling_rows(sos, low, float(rate_hz))
    rows, k = _pass_rows(vector, scalar, aux, float(rate_hz))
    names = term_names(terms) + _aux_names(aux_names, k)
    needed = settling + ROWS_PER_TERM * len(names)
    if rows.shape[0] < needed:
        raise InputError(
            f"{rows.shape[0]} rows: the band-pass settles in {settling} rows at {rate_hz:g} Hz "
            f"and {len(names)} coefficients need {ROWS_PER_TERM * len(names)} more; give at "
            f"least {needed} rows"
        )
    first = rows.array[:1].compute() if isinstance(rows, passes.LazySamples) else rows[:1]
    work = PlatformBlock(terms, sos, settling, chunk_rows, first)  # no survey of a Dask log
    whole = passes.reduce(rows, None, work, bandpass.Segment.then, chunk_rows, indexed=True)
    gram, sums = whole.sums()
    n = rows.shape[0] - settling
    _check_sums(gram, names)
    solution = ridge.solve(gram[:-1, :-1], gram[:-1, -1], float(gram[-1, -1]), n)
    residual_mean = (sums[-1] - solution.coefficients @ sums[:-1]) / n
    return TollesLawsonFit(
        terms=terms,
        names=names,
        coefficients=solution.coefficients,
        coefficient_units=term_units(terms, unit, vector_unit)
        + [f"{unit} per unit of {name}" for name in names[len(names) - k :]],
        variance_inflation=solution.variance_inflation,
        band_hz=(low, high),
        sample_rate_hz=float(rate_hz),
        ridge_parameter=solution.parameter,
        effective_terms=solution.effective_terms,
        condition_number=solution.condition_number,
        uncompensated_std=float(np.sqrt(max(gram[-1, -1] / n - (sums[-1] / n) ** 2, 0.0))),
        compensated_std=float(np.sqrt(max(solution.residual_sum / n - residual_mean**2, 0.0))),
        n=n,
        settling_rows=settling,
        unit=unit,
        vector_unit=vector_unit,
        aux_columns=names[len(names) - k :],
    )


def _vectors(vector) -> np.ndarray:
    array = np.asarray(vector, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3:
        raise InputError(f"the vector readings must have shape (N, 3), got {array.shape}")
    if not np.isfinite(array).all():
        raise InputError("the vector readings contain NaN or infinite values")
    if not (np.einsum("ij,ij->i", array, array) > 0).all():
        raise InputError("a vector reading is (0, 0, 0): it has no direction")
    return array


def _channels(aux, n: int, k: int) -> np.ndarray:
    """Auxiliary channels as (n, k) finite floats (k = 0: an empty array)."""
    if aux is None or k == 0:
        if k:
            raise InputError(f"the fit has {k} auxiliary channel(s): pass their values as aux")
        return np.empty((n, 0))
    array = np.asarray(aux, dtype=float).reshape(n, -1) if np.size(aux) else np.empty((n, 0))
    if array.shape != (n, k):
        raise InputError(f"the auxiliary channels must have shape ({n}, {k}), got {array.shape}")
    if not np.isfinite(array).all():
        raise InputError("the auxiliary channels contain NaN or infinite values")
    return array


def _aux_names(aux_names, k: int) -> list:
    names = [f"aux_{j + 1}" for j in range(k)] if aux_names is None else [str(a) for a in aux_names]
    if len(names) != k:
        raise InputError(f"{len(names)} aux_names for {k} auxiliary channel(s)")
    return names


def _pass_rows(vector, scalar, aux, rate_hz: float) -> tuple:
    """The rows the pass reads, [vector, cosine rates, channels, scalar], in memory or as a
    Dask array (`nlpcal.passes.LazySamples`); and the number of channels."""
    if passes.is_dask(vector) or passes.is_dask(scalar) or passes.is_dask(aux):
        return _dask_rows(vector, scalar, aux, rate_hz)
    vector = _vectors(vector)
    n = vector.shape[0]
    scalar = np.asarray(scalar, dtype=float).reshape(-1)
    if scalar.shape != (n,):
        raise InputError(f"the scalar readings must have shape ({n},), got {scalar.shape}")
    if not np.isfinite(scalar).all():
        raise InputError("the scalar readings contain NaN or infinite values")
    k = 0 if aux is None else (np.asarray(aux).reshape(n, -1).shape[1] if np.size(aux) else 0)
    channels = _channels(aux, n, k)
    rows = np.column_stack([vector, cosine_rates(vector, rate_hz), channels, scalar])
    return rows, k


def _dask_rows(vector, scalar, aux, rate_hz: float) -> tuple:
    import dask.array as da

    vector = da.asarray(vector).astype(float)
    if vector.ndim != 2 or vector.shape[1] != 3:
        raise InputError(f"the vector readings must have shape (N, 3), got {vector.shape}")
    vector = vector.rechunk({1: -1})
    n = vector.shape[0]
    parts = [vector]
    cosines = vector / da.sqrt((vector**2).sum(axis=1, keepdims=True))
    parts.append(da.gradient(cosines, 1.0 / rate_hz, axis=0))  # as numpy.gradient, by overlap
    k = 0
    if aux is not None:
        channels = da.asarray(aux).astype(float).reshape(n, -1)
        k = channels.shape[1]
        parts.append(channels)
    parts.append(da.asarray(scalar).astype(float).reshape(n, 1))
    rows = da.concatenate([p.rechunk({0: vector.chunks[0]}) for p in parts], axis=1)
    return passes.LazySamples(rows), k


def _check_sums(gram: np.ndarray, names: list) -> None:
    """Refuse sums with non-finite values, or a column (or the scalar) that does not vary
    within the band."""
    if not np.isfinite(gram).all():
        raise InputError("the record contains NaN or infinite values (or a zero vector reading)")
    power = np.diag(gram)
    silent = power <= SILENT_COLUMN * power.max()
    if silent[-1]:
        raise InputError("the scalar does not vary within the band: there is nothing to compensate")
    if silent.any():
        named = ", ".join(name for name, quiet in zip(names, silent) if quiet)
        raise InputError(
            f"{named} does not vary within the band, so its coefficient cannot be fitted; "
            f"leave it out or widen --band"
        )
