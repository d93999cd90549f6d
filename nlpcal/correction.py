"""Applying results to logs: the library verbs behind `nlpcal apply` and `nlpcal stats`.

A `Correction` is what is applied to a log: the nine parameters of a calibration (Eq. 4 of Zhou
et al. 2010), optionally with the temperature model of a joint temperature calibration, or the
k(t) of a drift fit (Eq. 9 of Liu et al. 2022) before them. It knows which log columns it needs
(the temperature column; the times for a drift of the scale factors in time) and says what it
decided on the user's behalf in `notes`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from . import units, validation
from .calibration.result import CalibrationResult
from .drift.evaluation import evaluation_row
from .drift.fit import DriftFit
from .drift.temperature import TemperatureCalibrationResult
from .errors import InputError
from .io.logs import Log, read_log
from .io.observatory import TIME_COLUMN
from .io.output import aligned
from .io.reference import log_times
from .io.stream import LogStream
from .io.tables import column_name
from .models.liu2022 import rmse
from .models.zhou2010 import correct
from .results import load_any
from .robust import robust_std
from .statistics import field_statistics
from .timing import seconds

#: The columns `nlpcal apply` adds to a corrected log: |B1|, and the outlier flags.
TOTAL_COLUMN = "b_total"
OUTLIER_COLUMN = "outlier"
#: 1 on the rows of a corrected log that are readings, 0 on those that are not (exact-zero
#: vectors, repeats left out with --drop-invalid), which keep their raw values.
VALID_COLUMN = "valid"
#: Note when a log's temperatures lie further than this outside the fitted range. [degC]
EXTRAPOLATION_NOTE_DEGC = 1.0
#: References further apart than this fraction are named when a log is compared with one. [1]
REFERENCE_MISMATCH = 0.005
#: Without a robust loss scale, a corrected sample is an outlier beyond this many robust standard
#: deviations of the residuals (1.4826 MAD; a Gaussian exceeds 4 once in 16 000 samples). [1]
OUTLIER_ROBUST_STDS = 4.0


def load_parameters(path) -> CalibrationResult | TemperatureCalibrationResult:
    """A parameters file: the nine parameters, with or without a temperature model.

    Parameters
    ----------
    path : str or os.PathLike
        A document written by `calibrate` (`params.json`) or by a temperature calibration.

    Returns
    -------
    CalibrationResult or TemperatureCalibrationResult
        The result the file holds, checked field by field.

    Raises
    ------
    InputError
        A file that is not such a document, or holds unusable values.

    Examples
    --------
    >>> import os, tempfile
    >>> import nlpcal
    >>> samples = nlpcal.simulate(300, seed=0)[["bx", "by", "bz"]].to_numpy()
    >>> path = os.path.join(tempfile.mkdtemp(), "params.json")
    >>> nlpcal.calibrate(samples, method="joint").save(path)
    >>> type(nlpcal.load_parameters(path)).__name__
    'CalibrationResult'
    """
    return load_any(path, (TemperatureCalibrationResult, CalibrationResult))


@dataclass
class Correction:
    """What is applied to a log (`nlpcal apply`): the nine parameters, a temperature drift, or both.

    Attributes
    ----------
    parameters : CalibrationResult, TemperatureCalibrationResult or None
        The calibration, or None (drift alone).
    drift : DriftFit or None
        A drift fit whose k(t) divides the raw vector first (Eq. 9 of Liu et al. 2022), or None.
    temperature_column : str or None
        The log's temperature column [degC], or None (no temperature step).
    time_column : str or None
        The log's column of times [s] for parameters whose scale factors drift in time
        (`nlpcal.models.time_drift`), or None.
    aux_columns : dict
        Channel of the calibration -> the log's column it is read from, for parameters with
        auxiliary channels (`nlpcal.auxiliary`); their stray field is subtracted from the raw
        vector first, B_M - sum_k v_k c_k.
    notes : list of str
        What was decided on the user's behalf.

    Examples
    --------
    >>> import nlpcal
    >>> samples = nlpcal.simulate(300, seed=0)[["bx", "by", "bz"]].to_numpy()
    >>> correction = nlpcal.Correction(parameters=nlpcal.calibrate(samples, unit="nT"))
    >>> correction.unit
    'nT'
    """

    parameters: CalibrationResult | TemperatureCalibrationResult | None = None
    drift: DriftFit | None = None
    temperature_column: str | None = None
    notes: list = field(default_factory=list)
    time_column: str | None = None
    aux_columns: dict = field(default_factory=dict)

    @classmethod
    def plan(
        cls,
        parameters=None,
        drift: DriftFit | None = None,
        temperature_column: str | None = None,
        *,
        log_columns=(),
        require_temperature: bool = True,
        time_column: str | None = None,
        aux_columns=None,
    ) -> Correction:
        """Check that the pieces fit together and choose the temperature column.

        log_columns : the columns of the log it will be applied to (to find the temperature
            column the model was fitted with, and the aux channels).
        aux_columns : log column -> the calibration's channel it holds (`--aux-columns
            NEW=OLD`), for channels recorded under another name; the others are read under
            their own.
        require_temperature : a temperature model without its column is an error (apply);
            False leaves the temperature step out with a note (stats).
        time_column : the log's column of times (--time-column), for parameters whose scale
            factors drift in time; default the column they were fitted with, else an
            observatory file's `time`.
        """
        notes: list = []
        joint = parameters if isinstance(parameters, TemperatureCalibrationResult) else None
        if joint is not None and joint.drifts_in_time:
            time_column = drift_time_column(joint, time_column, log_columns)
        else:
            time_column = None
        model = joint if joint is not None and joint.temperature_model is not None else None
        if drift is not None and model is not None:
            raise InputError(
                "the parameters file already carries a temperature model; --drift "
                "applies only to parameters without one, so drop --drift"
            )
        if temperature_column and drift is None and model is None:
            raise InputError(
                "--temperature-column needs --drift DRIFT.json or parameters with a "
                "temperature model"
            )
        if temperature_column is None and (drift is not None or model is not None):
            if drift is not None:
                source, stored = "drift file", drift.input.get("temperature_column")
            else:
                source, stored = "temperature model", model.temperature_column  # type: ignore
            if stored and stored in log_columns:
                temperature_column = stored
            elif require_temperature or drift is not None:
                have = ", which the log lacks" if stored else ""
                raise InputError(
                    f"the {source} needs a temperature column (fitted with "
                    f"{stored!r}{have}); pass --temperature-column COL"
                )
            else:
                notes.append(
                    f"the log has no column {stored!r} for the temperature model; "
                    f"pass --temperature-column COL for the temperature row"
                )
        channels = list(getattr(parameters, "aux", None) or [])
        aux = aux_sources(channels, aux_columns or {}, log_columns)
        return cls(
            parameters, drift, temperature_column, notes, time_column=time_column, aux_columns=aux
        )

    @property
    def unit(self) -> str:
        """The unit the correction works in (the parameters', else the drift fit's)."""
        if self.parameters is not None:
            return self.parameters.unit
        return self.drift.unit if self.drift is not None else "nT"

    @property
    def fallback_unit(self) -> str:
        """The unit to read a log in when neither the user nor its column names give one."""
        if self.parameters is not None:
            return self.parameters.input.get("log_unit") or self.parameters.unit
        return self.unit

    def temperature(self, log: Log) -> np.ndarray:
        """The log's temperatures [degC], with a note when they leave the fitted range."""
        values = log.values(self.temperature_column)
        self.note_range(float(values.min()), float(values.max()))
        return values

    def note_range(self, low_seen: float, high_seen: float) -> None:
        """A note when a log's temperatures, from `low_seen` to `high_seen` [degC], reach
        beyond the range the temperature model was fitted over."""
        if self.drift is not None:
            low, high, what = *self.drift.temperature_range, "the drift fit"
        else:
            low, high = self.parameters.temperature_range  # type: ignore[union-attr]
            what = "the temperature calibration"
        beyond = max(float(low) - low_seen, high_seen - float(high))
        if np.isfinite(beyond) and beyond > EXTRAPOLATION_NOTE_DEGC:
            self.notes.append(
                f"the log's temperatures {low_seen:g} .. {high_seen:g} degC "
                f"reach {beyond:.3g} degC beyond the range {low:g} .. {high:g} "
                f"degC of {what}; the linear temperature model is extrapolated"
            )

    @property
    def time_drift_alone(self) -> bool:
        """Whether the parameters drift in time without a temperature model (then applied
        without a temperature column)."""
        joint = self.parameters
        return (
            isinstance(joint, TemperatureCalibrationResult)
            and joint.temperature_model is None
            and self.time_column is not None
        )

    def times(self, log: Log) -> np.ndarray | None:
        """The log's times [s] for a drift of the scale factors in time, else None."""
        if self.time_column is None:
            return None
        return log_times(log, self.time_column, "the time drift of the parameters")[1]

    def apply(self, log: Log) -> np.ndarray:
        """Corrected samples of the log. [base unit]"""
        temperature = self.temperature(log) if self.temperature_column is not None else None
        return self.correct(
            log.samples, log.base_unit, temperature, self.times(log), self.channels(log)
        )

    def channels(self, log: Log) -> dict:
        """The aux channels of the calibration, name -> the log's values. [channel unit]"""
        return {name: log.values(column) for name, column in self.aux_columns.items()}

    def without_stray(self, log: Log) -> np.ndarray:
        """The log's raw samples less the stray field of the aux channels, B_M - sum_k v_k c_k
        (the samples themselves without aux channels). [base unit]"""
        if not self.aux_columns:
            return log.samples
        return log.samples - self.parameters.stray_field(self.channels(log))  # type: ignore[union-attr]

    def correct(
        self, samples, base_unit: str, temperature=None, times=None, channels=None
    ) -> np.ndarray:
        """Corrected `samples` [base_unit] (Eq. 4, after the temperature step with the
        `temperature` of each sample [degC] when the correction has one, and the time drift's
        gains at the samples' `times` [s] when the parameters have one; the stray field of the
        aux channels, `channels` name -> (N,) values, subtracted first)."""
        units.check_compatible(self.unit, base_unit, "the log", "the calibration")
        if self.aux_columns:
            samples = samples - self.parameters.stray_field(channels or {})  # type: ignore[union-attr]
        if self.time_drift_alone:
            assert isinstance(self.parameters, TemperatureCalibrationResult)
            return self.parameters.apply(samples, None, times=times)
        if self.temperature_column is None:
            if self.parameters is None:
                raise InputError("nothing to apply: give parameters or a drift file")
            return correct(samples, self.parameters.model)  # Eq. 4 (at t0 with a model)
        if isinstance(self.parameters, TemperatureCalibrationResult):
            return self.parameters.apply(samples, temperature, times=times)
        params = None if self.parameters is None else self.parameters.model
        return self.drift.correct(samples, temperature, params)  # type: ignore[union-attr]


def drift_time_column(model: TemperatureCalibrationResult, given, log_columns) -> str:
    """The log column of times a drift of the scale factors in time is applied with: `given`
    (--time-column), else the column the parameters were fitted with, else an observatory
    file's TIME_COLUMN; InputError when the log has none of them."""
    head = pd.DataFrame(columns=[str(c) for c in log_columns])
    if given is not None:
        return column_name(head, given, "time column")
    for name in (model.time_column, TIME_COLUMN):
        if name and name.lower() in {column.lower() for column in head.columns}:
            return column_name(head, name, "time column")
    fitted = f" (fitted with times from {model.time_column!r})" if model.time_column else ""
    raise InputError(
        f"the parameters' scale factors drift in time{fitted} and the log has no column of "
        f"times; pass --time-column COL (ISO 8601 or seconds on the calibration log's clock)"
    )


def chunk_times(chunk, column: str | None, valid) -> np.ndarray | None:
    """The times [s] of a streamed chunk's readings (`valid`) in `column`, or None without a
    column; InputError when a reading has no time."""
    if column is None:
        return None
    times = seconds(chunk.frame[column].to_numpy())[valid]
    bad = int(np.isnan(times).sum())
    if bad:
        raise InputError(
            f"{bad} reading(s) have no time in {column!r} (ISO 8601 text or seconds); fix "
            f"them or drop them from the log"
        )
    return times


def outliers(correction: Correction, corrected) -> np.ndarray:
    """Which corrected samples [base unit] are outliers: |(|B1| - centre)| beyond
    OUTLIER_ROBUST_STDS robust standard deviations (1.4826 MAD) of the calibration's residuals,
    or of this log's when the calibration does not record them. The centre is the calibration's
    constant reference field, else the median |B1| of this log."""
    magnitude = np.linalg.norm(corrected, axis=1)
    centre, limit = outlier_bounds(correction, magnitude)
    return np.abs(magnitude - centre) > limit


def outlier_bounds(correction: Correction, magnitude) -> tuple:
    """(centre, largest distance from it) of the corrected |B1| [base unit] of a log's readings
    that are not outliers (`outliers`)."""
    robust = correction.parameters.robust if correction.parameters is not None else {}
    reference = correction.parameters.reference if correction.parameters is not None else None
    centre = reference.field if reference is not None and reference.mode == "constant" else None
    centre = float(np.median(magnitude)) if centre is None else float(centre)
    spread = robust.get("residual_robust_std") or robust_std(magnitude - centre)
    return centre, OUTLIER_ROBUST_STDS * spread


def corrected_chunks(
    stream: LogStream,
    correction: Correction,
    precision=None,
    bounds: tuple | None = None,
    tally=None,
):
    """The chunks of a log corrected, to be written back (`nlpcal.io.output.write_frames`):
    every row of numbers in its place, the readings corrected (Eq. 4, after the temperature
    step), the rows that are not readings with their raw values, a magnitude column
    TOTAL_COLUMN and a VALID_COLUMN of 1/0, and with `bounds` (`outlier_bounds`) an
    OUTLIER_COLUMN. `precision` (`nlpcal.io.output.Precision`) is shown each chunk's field
    cells before the chunk is written. The temperatures seen end in a note of `correction`
    (`Correction.note_range`) once the log is read. `tally(measured, corrected)`, when given,
    is called with the |B| of each chunk's readings before and after the correction. [base
    unit]"""
    seen = [np.inf, -np.inf]
    # the stream's names of the extra columns, in the order `extra_columns_for` asked for them
    resolved = dict(zip(extra_columns_for(correction).values(), stream.extra))
    temperature_column = resolved.get(correction.temperature_column)
    aux = {name: resolved[column] for name, column in correction.aux_columns.items()}
    for chunk in stream:
        if precision is not None:
            precision.observe(chunk.frame[column] for column in stream.columns)
        valid = chunk.valid
        temperature = None
        if temperature_column is not None:
            temperature = chunk.extras[temperature_column][valid]
            if temperature.size:
                seen = [min(seen[0], temperature.min()), max(seen[1], temperature.max())]
        samples = chunk.raw[valid] * stream.factor
        times = chunk_times(chunk, correction.time_column, valid)
        channels = {name: chunk.extras[column][valid] for name, column in aux.items()}
        corrected = correction.correct(samples, stream.base_unit, temperature, times, channels)
        magnitude = np.linalg.norm(corrected, axis=1)
        if tally is not None:
            tally(np.linalg.norm(samples, axis=1), magnitude)
        values = chunk.raw.copy()
        values[valid] = units.from_base(corrected, stream.unit)
        extra = {}
        if bounds is not None:
            flags = np.zeros(len(valid), dtype=bool)
            centre, limit = bounds
            flags[valid] = np.abs(magnitude - centre) > limit
            extra[OUTLIER_COLUMN] = flags
        yield aligned(chunk.frame, stream.columns, values, valid, TOTAL_COLUMN, VALID_COLUMN, extra)
    if temperature_column is not None and np.isfinite(seen[0]):
        correction.note_range(float(seen[0]), float(seen[1]))


def aux_sources(channels: list, mapping: dict, log_columns) -> dict:
    """Channel name -> the log column it is read from: `mapping` (log column -> channel) where
    given, else the channel's own name; InputError naming a channel the log lacks, or a mapped
    name the calibration has no channel of."""
    names = [c.name for c in channels]
    for column, name in mapping.items():
        if name not in names:
            have = f"its channels are {', '.join(names)}" if names else "it has none"
            raise InputError(
                f"--aux-columns {column}={name}: the calibration has no aux channel {name!r} "
                f"({have})"
            )
    by_channel = {name: column for column, name in mapping.items()}
    sources = {name: by_channel.get(name, name) for name in names}
    present = {str(c) for c in log_columns}
    for name, column in sources.items():
        if column not in present:
            raise InputError(
                f"the calibration needs the aux channel {name!r}, and the log has no column "
                f"{column!r}; pass --aux-columns NEW={name} for a column named otherwise"
            )
    return sources


def extra_columns_for(correction: Correction) -> dict:
    """The log columns a correction reads besides the field, by role: the temperature column
    and the aux channels' columns."""
    column = correction.temperature_column
    extra = {"the temperature column of the calibration": column} if column else {}
    for name, source in correction.aux_columns.items():
        extra[f"the aux channel {name!r}"] = source
    return extra


def read_log_for(path, correction: Correction, *, reference_column=None, **kw) -> Log:
    """Read a log to apply `correction` to: its temperature and aux columns come along, and its
    unit defaults to the unit of the log the parameters were estimated from."""
    extra = extra_columns_for(correction)
    return read_log(
        path,
        reference_column=reference_column,
        extra_columns=extra,
        fallback_unit=correction.fallback_unit,
        **kw,
    )


def _compare_references(correction: Correction, mean: float, unit: str) -> None:
    """A note when the log's reference [unit] is not the one the calibration was made against:
    the corrected |B1| follows the calibration's, and the RMSE then holds the difference."""
    made = correction.parameters.reference if correction.parameters is not None else None
    calibrated = made.level if made is not None else None
    if calibrated and abs(mean / calibrated - 1.0) > REFERENCE_MISMATCH:
        correction.notes.append(
            f"the calibration was made against a reference of {calibrated:.6g} {unit}, and the "
            f"log's reference averages {mean:.6g} {unit} ({abs(mean / calibrated - 1):.1%} "
            f"apart): the corrected row's RMSE includes that difference"
        )


def statistics_rows(log: Log, correction: Correction | None = None) -> tuple:
    """Table 1 rows of a log: measured, corrected (with parameters), corrected with temperature;
    with the log's reference every row carries the RMSE of Eq. 10 (Liu et al. 2022).

    Returns (rows, extra columns to print).
    """
    reference = log.reference
    if reference is not None:  # the check of calibrate: the same unit, the same field
        validation.reference_scale(reference, validation.mean_magnitude(log.samples))
    rows = [{"label": "measured", **field_statistics(log.samples)}]
    if correction is not None and correction.parameters is not None:
        if reference is not None:
            mean = float(np.mean(np.asarray(reference, dtype=float)))
            _compare_references(correction, mean, log.base_unit)
        params = correction.parameters.model  # the nine parameters (at t0 with a model)
        raw = correction.without_stray(log)  # less the stray field of aux channels
        rows.append({"label": "corrected", **field_statistics(raw, params.theta)})
        if reference is not None:
            corrected = correct(raw, params)  # Eq. 4
            rows[1]["rmse"] = rmse(np.linalg.norm(corrected, axis=1), reference)  # Eq. 10
    if reference is not None:
        rows[0]["rmse"] = rmse(np.linalg.norm(log.samples, axis=1), reference)  # Eq. 10
    if correction is not None and correction.time_drift_alone:
        rows.append(evaluation_row("corrected + time drift", correction.apply(log), reference))
    elif correction is not None and correction.temperature_column is not None:
        label = "corrected + temperature" if correction.parameters is not None else "temperature"
        rows.append(evaluation_row(label, correction.apply(log), reference))
    for row in rows:
        row.pop("max_abs_u", None)
    return rows, (("rmse",) if reference is not None else ())
