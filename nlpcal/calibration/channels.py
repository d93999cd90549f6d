"""Auxiliary channels in the calibration: the joint solve of the nine parameters of Eq. 4 in [1]
and the stray fields v_k c_k of (*) in `nlpcal.auxiliary.model`, their standard errors and
what the data cannot tell apart.

`calibrate` hands the channels here (`prepare_channels`), solves the joint problem
(`fit_channels`: `nlpcal.nlp.channels` on the moments of `nlpcal.auxiliary.moments`), then runs
its own nine-parameter estimate on the samples with the fitted stray field removed
(`compensated`), whose optimum is the joint one (the joint optimum is stationary in theta at v
fixed); its Table 1 rows, warnings and identifiability describe that compensated log. `attach`
then widens its standard errors by what the uncertainty of v adds (the ratio of the marginal
to the conditional standard error, both from the covariance of the joint scores,
`nlpcal.calibration.channel_errors`), and records v with its standard errors.

Identifiability: a channel that never varies is an offset (refused, InputError); one that
varies only with the attitude (a linear fit on the sample direction and its squares explains
at least ATTITUDE_R2 of its variance) is a change of the correction matrix: QualityError
(Not_Identifiable) naming it, or, when allowed, its stray field held at zero and the channel
named under `identifiability.aux.not_identifiable`.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from .. import passes, validation
from ..auxiliary.model import DEFAULT_KIND, KINDS, AuxChannel
from ..auxiliary.moments import accumulate_channels, dask_rows, subsample
from ..errors import InputError, QualityError, SolveError
from ..moments import Moments, accumulate, sphere_frame
from ..nlp.blocks import variable_scale, variables
from ..nlp.channels import channel_derivatives, channel_parameters, channel_problem, v_scale
from ..nlp.solver import IpoptOptions, solve
from ..passes import LazySamples
from ..results import TableRow
from .channel_errors import joint_covariance

#: A channel whose variance a quadratic fit on the sample direction explains to this fraction
#: varies only with the attitude: its stray field is a change of O_p S_p. [1]
ATTITUDE_R2 = 0.99
#: A channel whose range (max - min) is below this fraction of its largest magnitude never
#: varies. [1]
CONSTANT_SPREAD = 1e-9
#: Newton steps that finish the joint solve (each accepted only where f does not rise).
NEWTON_STEPS = 6
#: Rows per chunk of the scores pass.
CHUNK_ROWS = 8192
#: Rows per block written to a temporary memory map (`spooled`): 64 k rows of 3 doubles, 1.5 MB.
SPOOL_ROWS = 65536


@dataclass(frozen=True)
class Channels:
    """The auxiliary channels of a calibration: names, kinds and values (N, K), in memory or on
    Dask. [channel unit]"""

    names: tuple
    kinds: tuple
    values: Any

    @property
    def count(self) -> int:
        return len(self.names)


def _check_options(loss: str, model: str) -> None:
    """InputError for the options the joint solve with channels does not take."""
    if loss != "l2":
        raise InputError("aux columns are fitted by least squares; drop --loss (or use l2)")
    if model == "auto":
        raise InputError(
            "aux columns take a model of Eq. 4 chosen beforehand: --model full, diagonal or "
            "offset, not auto"
        )


def _kinds(aux_kind, count: int) -> tuple:
    if aux_kind is None:
        return (DEFAULT_KIND,) * count
    kinds = [aux_kind] if isinstance(aux_kind, str) else list(aux_kind)
    if len(kinds) == 1:
        kinds = kinds * count
    if len(kinds) != count:
        raise InputError(
            f"got {len(kinds)} aux kinds for {count} aux columns; give one kind for all or one "
            f"per column"
        )
    for kind in kinds:
        if kind not in KINDS:
            raise InputError(f"unknown aux kind {kind!r}; expected one of {', '.join(KINDS)}")
    return tuple(kinds)


def _names(aux_columns) -> list:
    """The channels' names: at least one, none empty, none twice."""
    names = [str(name) for name in aux_columns]
    if not names or any(not name.strip() for name in names):
        raise InputError("aux_columns must name at least one channel, each by a non-empty name")
    if len(set(names)) != len(names):
        raise InputError(f"aux_columns names a channel twice: {', '.join(names)}")
    return names


def log_channels(log, names) -> dict:
    """name -> values of the aux columns of a log read with them (`nlpcal.io.read_log`)."""
    return {name: log.values(name) for name in _names(names)}


def prepare_channels(samples, settings) -> tuple:
    """(samples, Channels) from `calibrate`'s settings (`CalibrationSettings`): their
    `aux.columns` name columns of a pandas or Dask DataFrame `samples`, or map names to (N,)
    values; `aux.kind` is one kind for all, or one per channel. Checks the names, the kinds,
    the values (finite, N rows, varying) and that the other settings are ones the joint solve
    takes."""
    _check_options(settings.loss.kind, settings.model)
    aux_columns, aux_kind = settings.aux.columns, settings.aux.kind
    if isinstance(aux_columns, str) or not isinstance(aux_columns, (Mapping, list, tuple)):
        raise InputError("aux_columns must be a list of column names (or a name -> values map)")
    names = _names(aux_columns)
    kinds = _kinds(aux_kind, len(names))
    if isinstance(aux_columns, Mapping):
        values: object = _stacked_columns([aux_columns[name] for name in aux_columns], names)
    else:
        values, samples = _from_frame(samples, names)
    channels = Channels(tuple(names), kinds, passes.as_rows(values))
    _check_values(channels, len(samples))
    return samples, channels


def _stacked_columns(columns: list, names: list) -> np.ndarray:
    """(N, K) of the channels' values: in memory, or in a temporary memory map when any of them
    is one (a log read with low_memory stays out of memory). Checked to be numbers; finiteness
    and variation are `_check_values`'."""
    mapped = [c for c in columns if _mapped(c)]
    if not mapped:
        return np.column_stack(
            [validation.channel(c, None, f"aux column {n!r}") for c, n in zip(columns, names)]
        )
    rows = mapped[0].shape[0]
    for column, name in zip(columns, names):
        if np.ndim(column) != 1 or len(column) != rows:
            raise InputError(f"aux column {name!r} must be {rows} numbers, as the others")
    return spooled(lambda start, stop: np.column_stack([c[start:stop] for c in columns]), rows)


def _mapped(values) -> bool:
    """Whether an array is, or views, a memory map (a log read with low_memory)."""
    while isinstance(values, np.ndarray):
        if isinstance(values, np.memmap):
            return True
        values = values.base
    return isinstance(values, np.memmap)


def spooled(block, rows: int) -> np.ndarray:
    """A read-only (rows, k) float64 memory map on an unlinked temporary file, written block by
    block from block(start, stop) (freed when dropped): O(chunk) memory for any N."""
    store = tempfile.TemporaryFile()
    width = 0
    for start in range(0, rows, SPOOL_ROWS):
        values = np.ascontiguousarray(block(start, min(start + SPOOL_ROWS, rows)), dtype=float)
        width = values.shape[1]
        store.write(values.tobytes())
    store.flush()
    return np.memmap(store, dtype=np.float64, mode="r", shape=(rows, width))


def _from_frame(samples, names) -> tuple:
    """The channel columns of a pandas or Dask DataFrame, and the frame without them."""
    if not hasattr(samples, "columns"):
        raise InputError(
            "aux_columns names columns of a DataFrame; pass samples as a DataFrame, or "
            "aux_columns as a mapping of names to values"
        )
    present = {str(c): c for c in samples.columns}
    missing = [name for name in names if name not in present]
    if missing:
        raise InputError(
            f"aux column {missing[0]!r} is not in the log (its columns: {', '.join(present)})"
        )
    picked = samples[[present[name] for name in names]]
    rest = samples.drop(columns=[present[name] for name in names])
    if passes.is_dask(picked):
        return picked.astype(float).to_dask_array(lengths=True), rest
    try:
        return np.asarray(picked.apply(pd.to_numeric), dtype=float), rest
    except (ValueError, TypeError):
        raise InputError(f"aux columns {', '.join(names)} must hold numbers") from None


def _check_values(channels: Channels, n: int) -> None:
    values = channels.values
    if values.shape[0] != n:
        raise InputError(f"the aux channels have {values.shape[0]} rows, the samples {n}")
    if isinstance(values, LazySamples):
        low, high = values.survey().low, values.survey().high
    else:
        low, high = passes.column_ranges(values)
    for k, name in enumerate(channels.names):
        if not (np.isfinite(low[k]) and np.isfinite(high[k])):
            raise InputError(f"aux column {name!r} holds NaN or infinite values")
        if high[k] - low[k] <= CONSTANT_SPREAD * max(abs(low[k]), abs(high[k]), 1e-300):
            raise InputError(
                f"aux column {name!r} never varies (always {low[k]:g}): its stray field "
                f"cannot be told apart from the offsets Z_p; leave it out"
            )


def attitude_r2(samples, channels: Channels, centre) -> dict:
    """name -> the fraction of each channel's variance that a linear fit on the sample
    direction (about `centre`) and its squares explains, on an even stride of the log. [1]"""
    raw = subsample(samples) - np.asarray(centre)
    unit = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    x, y, z = unit.T
    design = np.column_stack([np.ones_like(x), x, y, z, x * x, y * y, x * y, x * z, y * z])
    values = subsample(channels.values)
    r2 = {}
    for k, name in enumerate(channels.names):
        c = values[:, k] - values[:, k].mean()
        fit, *_ = np.linalg.lstsq(design, c, rcond=None)
        total = float(c @ c)
        residual = c - design @ fit
        r2[name] = 1.0 - float(residual @ residual) / total if total > 0 else 1.0
    return r2


@dataclass
class ChannelFit:
    """The joint solve of the nine parameters and the stray fields.

    theta : the nine parameters [internal units]; v : (K, 3) v_k [field per channel unit];
    v_errors : (K, 3) their standard errors, or None; inflation : the nine parameters' standard
    errors at v estimated over those at v fixed (name -> factor >= 1); r2 : `attitude_r2`;
    solve : how the solve ended (IPOPT's status and iterations, Newton steps taken).
    errors : how the standard errors were estimated (`channel_errors.joint_covariance`).
    """

    channels: Channels
    theta: np.ndarray
    v: np.ndarray
    v_errors: np.ndarray | None
    inflation: dict
    r2: dict
    solve: dict
    errors: dict = field(default_factory=dict)

    @property
    def not_identifiable(self) -> list:
        return blind_channels(self.r2)

    def compensated(self, samples):
        """B_M - sum_k v_k c_k, the samples without the stray field (a Dask log stays lazy).
        [field unit]"""
        values = self.channels.values
        if isinstance(samples, LazySamples) or isinstance(values, LazySamples):
            lazy_samples, lazy_values = dask_rows(samples, values)
            return LazySamples(lazy_samples - lazy_values @ self.v)
        if _mapped(samples) or _mapped(values):
            return spooled(lambda a, b: samples[a:b] - values[a:b] @ self.v, len(samples))
        return np.asarray(samples, dtype=float) - np.asarray(values) @ self.v


def _start(samples, channels: Channels, moments: Moments, model: str, held) -> tuple:
    """(theta, v, frame): v by least squares of the raw samples on the channels (attitudes
    independent of the channels average out; zero for the `held` ones), the offsets at the
    centre of a sphere fitted to the samples less that stray field, unit scales (with a
    reference, the common scale that maps the sphere's radius on the field) and zero angles."""
    raw, values = subsample(samples), subsample(channels.values)
    design = np.column_stack([np.ones(len(values)), values])
    v0 = np.linalg.lstsq(design, raw, rcond=None)[0][1:]  # (K, 3)
    v0[held] = 0.0
    frame = sphere_frame(raw - values @ v0)
    theta = np.zeros(9)
    theta[0:3] = frame.centre
    if moments.reference != "none":
        theta[3:6] = frame.radius / moments.length - 1.0
    return variables("joint", moments.reference, model).project(theta), v0, frame


def fit_channels(
    data, channels: Channels, model: str, ipopt: IpoptOptions, require_identifiable: bool = True
) -> ChannelFit:
    """The joint least-squares solve (IPOPT, then Newton steps with the exact Hessian) and the
    covariance of its scores (`joint_covariance`) on `data` (`nlpcal.calibration.steps.Prepared`:
    the samples [field unit], the reference, the moments of the raw samples); channels [channel
    unit]. Channels that vary only with the attitude are judged first, about the centre of the
    raw samples' sphere (`check_identifiable`); without `require_identifiable` their stray
    fields are held at zero (the data cannot tell them)."""
    samples, reference, moments = data.samples, data.reference, data.moments
    kind, k = moments.reference, channels.count
    r2 = attitude_r2(samples, channels, moments.frame.centre)
    check_identifiable(r2, require_identifiable)
    held = np.array([name in blind_channels(r2) for name in channels.names])
    theta0, v0, frame = _start(samples, channels, moments, model, held)
    length = frame.radius if kind == "none" else moments.length
    cm = accumulate_channels(samples, channels.values, reference, frame, length, kind)
    free = variables("joint", kind, model)
    derivatives = channel_derivatives(kind, k, model)
    p = channel_parameters(cm, theta0, v0.ravel(), 1.0)
    f0 = float(derivatives(np.zeros(free.size + 3 * k), p)[0])
    p[-1] = f0 if f0 > 0 else 1.0
    bounds = {"lbg": 0.0, "ubg": 0.0} if free.gauge else {}
    fixed = np.concatenate([np.zeros(free.size, dtype=bool), np.repeat(held, 3)])
    limit = np.where(fixed, 0.0, np.inf)
    outcome = solve(
        channel_problem(kind, k, model, ipopt), x0=0.0, p=p, lbx=-limit, ubx=limit, **bounds
    )
    basis = _basis(free, k)[:, ~_held_columns(free, k, held)]
    x, steps = _newton(derivatives, outcome.x, p, basis)
    if not (outcome.success or steps):
        raise SolveError("IPOPT did not solve the joint problem with aux channels", outcome.status)
    scale = np.concatenate([variable_scale(frame.radius), v_scale(cm)])
    directions = _directions(free.matrix, k)
    y = np.concatenate([theta0, v0.ravel()]) / scale + directions @ x
    theta, v = y[:9] * scale[:9], (y[9:] * scale[9:]).reshape(k, 3)
    fit = ChannelFit(channels, theta, v, None, {}, r2, {})
    fit.solve = {
        "status": outcome.status,
        "iterations": outcome.iterations,
        "newton_steps": steps,
    }
    fit.errors = joint_covariance(fit, samples, reference, kind, scale, directions @ basis)
    return fit


def compensated(data, fit: ChannelFit):
    """`data` (`nlpcal.calibration.steps.Prepared`) without the fitted stray field: its samples
    less sum_k v_k c_k and their moments, gathered again."""
    samples = fit.compensated(data.samples)
    return replace(data, samples=samples, moments=accumulate(samples, data.reference))


def _directions(matrix: np.ndarray, channels: int) -> np.ndarray:
    """(9 + 3K, k + 3K): the scaled parameters y moved by the variables x."""
    size = matrix.shape[1]
    d = np.zeros((9 + 3 * channels, size + 3 * channels))
    d[:9, :size] = matrix
    d[9:, size:] = np.eye(3 * channels)
    return d


def _basis(free, channels: int) -> np.ndarray:
    """Orthonormal directions of x the problem moves along (the gauge's null space in theta)."""
    inner = free.gauge_basis if free.gauge else np.eye(free.size)
    q = np.zeros((free.size + 3 * channels, inner.shape[1] + 3 * channels))
    q[: free.size, : inner.shape[1]] = inner
    q[free.size :, inner.shape[1] :] = np.eye(3 * channels)
    return q


def _held_columns(free, channels: int, held) -> np.ndarray:
    """Which columns of `_basis` move the stray field of a `held` channel."""
    inner = free.gauge_basis.shape[1] if free.gauge else free.size
    return np.concatenate([np.zeros(inner, dtype=bool), np.repeat(held, 3)])


def _newton(derivatives, x, p, basis) -> tuple:
    """x after at most NEWTON_STEPS Newton steps within `basis`, each kept only where the
    objective does not rise; and how many were kept."""
    x = np.array(x, dtype=float)
    f, grad, hess = derivatives(x, p)
    kept = 0
    for _ in range(NEWTON_STEPS):
        reduced = basis.T @ hess @ basis
        try:
            step = -basis @ np.linalg.solve(reduced, basis.T @ grad)
        except np.linalg.LinAlgError:
            break
        f_new, grad_new, hess_new = derivatives(x + step, p)
        if not f_new <= f:
            break
        done = f - f_new <= 1e-13 * abs(f)
        x, f, grad, hess = x + step, f_new, grad_new, hess_new
        kept += 1
        if done:
            break
    return x, kept


def blind_channels(r2: dict) -> list:
    """The channels that vary only with the attitude (`attitude_r2` >= ATTITUDE_R2)."""
    return [name for name, value in r2.items() if value >= ATTITUDE_R2]


def check_identifiable(r2: dict, require: bool) -> None:
    """QualityError (Not_Identifiable) naming the channels that vary only with the attitude
    (`attitude_r2`), when `require`."""
    blind = blind_channels(r2)
    if require and blind:
        named = ", ".join(f"{name} (R^2 {r2[name]:.4f})" for name in blind)
        raise QualityError(
            f"aux channel {named} varies only with the attitude: its stray field cannot be told "
            f"apart from the scale errors and angles; record the channel while it changes "
            f"independently of the attitude",
            "Not_Identifiable",
            overrides={"require_identifiable": False},
        )


def attach(result, fit: ChannelFit, raw_moments: Moments) -> None:
    """Record the stray fields on `result` (`CalibrationResult`): its `aux` channels, the nine
    parameters' standard errors and covariance widened by what v's uncertainty adds, the
    identifiability of the channels, and the measured row of the raw log."""
    result.aux = [
        AuxChannel(
            name,
            kind,
            fit.v[k].copy(),
            None
            if fit.v_errors is None or name in fit.not_identifiable
            else fit.v_errors[k].copy(),
        )
        for k, (name, kind) in enumerate(zip(fit.channels.names, fit.channels.kinds))
    ]
    block = {
        "channels": list(fit.channels.names),
        "attitude_r2": dict(fit.r2),
        "not_identifiable": fit.not_identifiable,
        "standard_error_inflation": dict(fit.inflation),
        "solve": dict(fit.solve),
        "standard_errors": dict(fit.errors),
    }
    result.identifiability["aux"] = block
    if fit.not_identifiable:
        result.warnings.append(
            f"aux channels {', '.join(fit.not_identifiable)} vary only with the attitude: "
            f"their stray fields cannot be told apart from the scale errors and angles, and "
            f"are held at zero"
        )
    if fit.v_errors is None:
        result.warnings.append(
            "the joint problem of the nine parameters and the aux channels is singular: no "
            "standard errors for the stray fields"
        )
    if result.standard_errors is not None and fit.inflation:
        factor = {n: fit.inflation.get(n, 1.0) for n in result.standard_errors}
        result.standard_errors = {n: se * factor[n] for n, se in result.standard_errors.items()}
        if result.covariance is not None:
            f = np.array([factor.get(n, 1.0) for n in result.estimated_parameters])
            result.covariance = np.asarray(result.covariance) * np.outer(f, f)
    if result.statistics and result.statistics[0].get("label") == "measured":
        result.statistics[0] = TableRow.of(
            {"label": "measured", **raw_moments.measured, "iterations": 0, "wall_s": 0.0}
        )
    result.notes.append(
        f"the stray fields of {', '.join(fit.channels.names)} were estimated jointly with the "
        f"nine parameters, B1 = O_p S_p (B_M - Z_p - sum_k v_k c_k); the rows after the "
        f"first describe the log without them"
    )
