"""Logs that stay where they are, for a Dask cluster: the rows of CSV or Parquet files (one file,
a pattern or a folder) as a Dask array read block by block in every pass (`nlpcal.passes`).

Each block is one task: a Parquet row group (pyarrow writes row groups of 1 Mi rows by default),
or a byte range of a CSV file (BLOCK_BYTES, cut at line ends). A block is read, its columns
chosen, checked and converted to the base unit exactly as `read_log` does with a whole file
(`nlpcal.io.tables.numeric_columns`); a bad row fails the read with the file and row group named.
The rows of every block are known before the first pass: from the Parquet footers, otherwise (CSV,
or rows dropped with drop_invalid) from one counting pass, which also counts the rows dropped.
Reading ends with the survey pass (`nlpcal.passes.survey_together`) that checks every value.
"""

from __future__ import annotations

import io

import numpy as np
import pandas as pd

from .. import passes, units, validation
from ..errors import InputError
from ..geomagnetic import ReferenceModel
from . import sources
from .logs import Log, log_unit, reference_unit
from .tables import column_name, numeric_columns, read_table_header, resolve_columns

#: Bytes of CSV per block (one task). [byte]
BLOCK_BYTES = 64 * 2**20


def field_samples(values):
    """The field columns of a DataFrame (pandas or Dask) chosen by the column detection of
    `nlpcal.io.tables.resolve_columns` (a frame of three other columns: those three); a Dask
    DataFrame becomes a Dask array with its block lengths computed. Other values pass through."""
    is_dask_frame = passes.is_dask(values) and hasattr(values, "columns")
    if not (isinstance(values, pd.DataFrame) or is_dask_frame):
        return values
    header = pd.DataFrame(columns=[str(c) for c in values.columns])
    try:
        chosen = resolve_columns(header)
    except InputError:
        if len(header.columns) != 3:
            raise
        chosen = list(header.columns)
    picked = values[[c for c in values.columns if str(c) in chosen]]
    picked = picked[[c for name in chosen for c in picked.columns if str(c) == name]]
    return picked.astype(float).to_dask_array(lengths=True) if is_dask_frame else picked


def _table_of(spec):
    """The table of one block: ("parquet", path, row group, columns) gives a pyarrow Table,
    ("csv", path, bytes, header line) a DataFrame."""
    kind, path, where, extra = spec
    if kind == "parquet":
        return sources.parquet_row_group(path, where, extra)
    try:
        frame = pd.read_csv(io.BytesIO(extra + where), engine="c")
    except pd.errors.EmptyDataError:
        return pd.DataFrame(columns=pd.read_csv(io.BytesIO(extra), nrows=0).columns)
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read as CSV ({' '.join(str(exc).split())})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame


def _column(table, name):
    """A column of a block as a float numpy array when it holds numbers only, else None."""
    if isinstance(table, pd.DataFrame):
        column = table[name]
        numeric = pd.api.types.is_numeric_dtype(column) and not pd.api.types.is_bool_dtype(column)
        return column.to_numpy(dtype=float) if numeric and not column.hasnans else None
    import pyarrow as pa

    column = table.column(name)
    numeric = pa.types.is_floating(column.type) or pa.types.is_integer(column.type)
    return np.asarray(column.to_numpy(), dtype=float) if numeric and not column.null_count else None


def _finite_block(table, wanted, factors):
    """The wanted columns times their factors as one (rows, k) array when every value is a
    finite number (the common case, without copies of the table), else None. Column-major, so
    that each column is one contiguous run of memory."""
    rows = table.num_rows if hasattr(table, "num_rows") else len(table)
    out = np.empty((rows, len(wanted)), order="F")
    for k, name in enumerate(wanted):
        column = _column(table, name)
        if column is None or not np.isfinite(column).all():
            return None
        np.multiply(column, factors[k], out=out[:, k])
    return out


def _block(spec, wanted, factors, drop_invalid: bool):
    """(values in the base unit, rows dropped) of one block; a block with a missing, non-numeric
    or non-finite value goes through `numeric_columns`, which says where or drops the row."""
    kind, path, where, _ = spec
    table = _table_of(spec)
    values = _finite_block(table, wanted, factors)
    if values is not None:
        return values, 0
    frame = sources.arrow_frame(table) if kind == "parquet" else table
    source = f"{path} (row group {where})" if kind == "parquet" else f"{path} (a block)"
    numeric = numeric_columns(frame, wanted, drop_invalid=drop_invalid, source=source)
    return numeric.values * factors, numeric.dropped


def _values(spec, wanted, factors, drop_invalid):
    return _block(spec, wanted, factors, drop_invalid)[0]


def _counts(spec, wanted, factors, drop_invalid):
    values, dropped = _block(spec, wanted, factors, drop_invalid)
    return values.shape[0], dropped


def _specs(paths, wanted, block_bytes: int) -> list:
    """(spec, rows or None) of every block of a log's files, in row order."""
    from dask.bytes import read_bytes

    specs = []
    for path in paths:
        if sources.is_parquet(path):
            for index, rows in enumerate(sources.parquet_row_groups(path)):
                specs.append((("parquet", str(path), index, wanted), rows))
            continue
        with open(path, "rb") as handle:
            header = handle.readline()
        _, blocks = read_bytes(str(path), delimiter=b"\n", blocksize=block_bytes, sample=False)
        for k, block in enumerate(blocks[0]):
            # The first block starts with the header line; the others are given it.
            specs.append((("csv", str(path), block, b"" if k == 0 else header), None))
    return specs


def lazy_table(source, wanted, factors, *, drop_invalid: bool = False, block_bytes=BLOCK_BYTES):
    """(Dask array (N, k) of the `wanted` columns times `factors`, rows dropped) of a log."""
    import dask
    import dask.array as da

    paths = sources.log_paths(source)
    specs = _specs(paths, wanted, block_bytes)
    factors = np.asarray(factors, dtype=float)
    rows = [n for _, n in specs]
    dropped = 0
    if drop_invalid or any(n is None for n in rows):  # one counting pass
        counted = dask.compute(
            *[dask.delayed(_counts)(spec, wanted, factors, drop_invalid) for spec, _ in specs]
        )
        rows = [kept for kept, _ in counted]
        dropped = sum(lost for _, lost in counted)
    blocks = [
        da.from_delayed(
            dask.delayed(_values)(spec, wanted, factors, drop_invalid),
            shape=(n, len(wanted)),
            dtype=float,
        )
        for (spec, _), n in zip(specs, rows)
        if n
    ]
    if not blocks:
        raise InputError(f"{source}: no data rows")
    return da.concatenate(blocks, axis=0), dropped


def read_lazy_log(
    source,
    columns=None,
    *,
    unit: str | None = None,
    reference_column: str | None = None,
    reference_field=None,
    reference_field_unit: str | None = None,
    reference_model: ReferenceModel | None = None,
    extra_columns=(),
    drop_invalid: bool = False,
    fallback_unit: str = "nT",
    block_bytes: int = BLOCK_BYTES,
) -> Log:
    """`nlpcal.io.read_log` for a Dask cluster: the same columns, units and checks, the samples
    (and a reference column) left in the files as `nlpcal.passes.LazySamples`.

    Reading runs the survey pass (every value checked, the subsamples the calibration needs
    gathered) on the current Dask scheduler. A per-sample geomagnetic reference and extra
    columns (temperatures) need the log in memory (`read_log`).
    """
    given = [reference_column, reference_field, reference_model]
    if sum(value is not None for value in given) > 1:
        raise InputError("give one reference: a column, a field or a geomagnetic model")
    if extra_columns or (
        reference_model is not None
        and (reference_model.numeric_columns() or reference_model.time_column)
    ):
        raise InputError(
            "temperature columns and a reference from position or time columns need the log "
            "in memory; drop --scheduler"
        )
    try:
        import dask  # noqa: F401
    except ImportError:
        raise InputError("a log on a Dask cluster needs dask: pip install 'nlpcal[dask]'") from None
    notes: list = []
    header = read_table_header(source)
    chosen = resolve_columns(header, columns)
    unit = log_unit(chosen, unit, fallback_unit, notes)
    wanted, factors = list(chosen), [units.field_factor(unit)] * 3
    name = None
    if reference_column is not None:
        name = column_name(header, reference_column)
        if name in chosen:
            raise InputError(
                f"column {name!r} is one of the field columns ({', '.join(chosen)}); pass the "
                f"reference column, or --columns X Y Z"
            )
        ref_unit = reference_unit(name, unit, notes)
        units.check_compatible(unit, ref_unit, f"reference column {name!r}")
        wanted.append(name)
        factors.append(units.field_factor(ref_unit))
    table, dropped = lazy_table(
        source, wanted, factors, drop_invalid=drop_invalid, block_bytes=block_bytes
    )
    if dropped:
        notes.append(f"dropped {dropped} row(s) with missing or non-numeric values")
    samples = passes.LazySamples(table[:, :3])
    reference, model = None, None
    if name is not None:
        reference = passes.LazySamples(table[:, 3])
    passes.survey_together(samples, reference)
    if name is not None:
        reference = validation.reference(reference, samples.n, f"the reference column {name!r}")
    elif reference_model is not None:
        if unit == "raw":
            raise InputError(
                "a geomagnetic model gives the field in nT, and raw counts cannot be compared "
                "with it; give the log's unit (--unit)"
            )
        reference, model = reference_model.field({}, None)
        notes.append(
            f"reference field {model['total_nT']:.1f} nT from {model['name']} "
            f"({model['package']} {model['package_version']})"
        )
    elif reference_field is not None:
        ref_unit = reference_field_unit or unit
        units.check_compatible(unit, ref_unit)
        reference = units.to_base(
            validation.number(reference_field, "the reference field", positive=True), ref_unit
        )
    parquet = all(sources.is_parquet(path) for path in sources.log_paths(source))
    blocks = len(samples.block_offsets())
    notes.append(
        f"the log stays in its files: {blocks} {'Parquet row groups' if parquet else 'CSV blocks'}"
        f" read in every pass"
    )
    return Log(
        path=str(source),
        columns=list(chosen),
        samples=samples,  # type: ignore[arg-type]  # rows that stay on the cluster
        unit=unit,
        reference=reference,
        reference_column=name,
        reference_source=model,
        dropped=dropped,
        engine="pyarrow" if parquet else "c",
        notes=notes,
    )
