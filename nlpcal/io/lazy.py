"""Logs read where they are, for a Dask cluster: the rows of CSV or Parquet files (one file, a
pattern or a folder) as a Dask array read block by block (`nlpcal.passes`).

Each block is one task: a Parquet row group (pyarrow writes row groups of 2^20 rows by default),
or a byte range of a text file (BLOCK_BYTES, cut at line ends; a compressed file, or one not in
UTF-8 or Latin-1, is one block). A block is read in the layout detected for its file, its columns
chosen, checked and converted to the base unit as `read_log` does (`nlpcal.io.tables`), and its
rows screened (`nlpcal.io.rows`: zero vectors left out, repeats counted and dropped with
drop_invalid; a repeat across the boundary of two blocks is not seen; a block whose rows were all
kept is not screened again in later passes). A bad value fails the read with its file named.

When the blocks' row counts are known beforehand (Parquet footers), reading is no pass of its
own: the log is taken to hold the rows its footers declare, and the checks of every block (its
values, its rows left out, the notes on them) wait for the first pass over it, which reads each
block once for its own work, the survey of `nlpcal.passes` and these checks (`Reading`, a
`nlpcal.passes.Pending`). A bad value then fails that first pass, with its file named; rows left
out make it find the blocks shorter than declared: the arrays are rebuilt on the rows counted
and that pass runs again. Otherwise (CSV) a pass counts the rows of every block first. The unit's
plausibility is checked on the first block (`nlpcal.passes.first_block_sample`): the unit is the
file's, the same in every block.

A log whose values fit in the memory the current scheduler may give them
(`nlpcal.cluster.memory_to_keep`) is read once, when opened, and its blocks kept there
(`Reading.keep`, Dask's persist): their checks and row counts come from the kept blocks then
(a bad value fails the reading, and no pass runs again for rows left out), and every pass
reads them in memory. Otherwise every pass reads the files again.
"""

from __future__ import annotations

import io
import os
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .. import cluster, passes, units
from ..errors import InputError
from ..geomagnetic import ReferenceModel
from . import sources
from .layout import BROKEN_STREAM
from .logs import (
    Log,
    constant_reference,
    model_reference,
    one_reference,
    reference_unit,
    sensor_unit,
    settle_unit,
)
from .recorders import check_options, declared_unit
from .rows import QUOTED_ROWS, RowScreen
from .tables import (
    column_name,
    log_files,
    named,
    numeric_columns,
    resolve_columns,
    unreadable,
)

#: Bytes of text per block (one task). [byte]
BLOCK_BYTES = 64 * 2**20
#: Encodings whose bytes can be cut at any newline byte.
SPLITTABLE = ("utf-8", "utf-8-sig", "latin-1", "ascii")


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
    """The table of one block: ("parquet", path, row group, columns, its first row in the file)
    gives a pyarrow Table; ("text", name, bytes, file, block number in the file) a DataFrame in
    the file's layout, bytes None for a file read whole (decompressed, or decoded, here)."""
    kind, name, where, extra, number = spec
    if kind == "parquet":
        return sources.parquet_row_group(name, where, extra)
    layout, columns = extra.layout, list(extra.preview.columns)
    options = layout.pandas_options()
    source: str | io.BytesIO
    if where is None:  # a file read whole here (compressed, or in an encoding not split)
        source = os.path.abspath(str(extra.source))  # as read_bytes takes it: any worker's cwd
    else:  # the bytes of a block, as they are in the file
        source, options["compression"] = io.BytesIO(where), None
    if number:  # the header row and comment lines are in the first block only
        options.update(header=None, names=columns if layout.header else None)
    try:
        frame = pd.read_csv(source, engine="c", **options)
    except pd.errors.EmptyDataError:
        return pd.DataFrame(columns=columns)
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError, *BROKEN_STREAM) as exc:
        raise unreadable(_block_name(name, number), layout, exc) from None
    return named(frame, layout)


def _block_name(name: str, number: int) -> str:
    """A CSV block's name in messages: a block after the first does not know how many lines
    came before it."""
    return name if number == 0 else f"{name} (its block {number + 1}, counted from its start)"


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


def _block(spec, wanted, factors, drop_invalid: bool, clean: bool = False) -> tuple:
    """(values in the base unit, rows read, rows with a missing or non-numeric value, the
    RowScreen or None) of one block; `clean`: an earlier pass kept every row of it, so its rows
    are not screened again."""
    kind, name, where, extra, number = spec
    table = _table_of(spec)
    values = _finite_block(table, wanted, factors)
    rows = table.num_rows if hasattr(table, "num_rows") else len(table)
    if clean and values is not None:
        return values, rows, 0, None
    invalid = 0
    if values is None:  # numeric_columns says where a bad value is, or drops its row
        if kind == "parquet":  # rows counted from the file's first, as read_log counts them
            frame, source, first_row = sources.arrow_frame(table), name, number
            decimal = "."
        else:  # a CSV block does not know how many rows came before it
            frame, first_row, decimal = table, 0, extra.layout.decimal
            source = _block_name(name, number)
        numeric = numeric_columns(
            frame,
            wanted,
            drop_invalid=drop_invalid,
            source=source,
            decimal=decimal,
            first_row=first_row,
        )
        values, invalid = numeric.values * factors, numeric.dropped
    screen = RowScreen(drop_repeats=drop_invalid)
    keep = screen.keep(values[:, :3])
    if not keep.all():
        values = values[keep]
    return values, rows, invalid, screen


def _specs(files, block_bytes: int) -> list:
    """(spec, rows or None) of every block of a log's files, in row order."""
    from dask.bytes import read_bytes

    specs: list = []
    for part in files:
        if part.parquet:
            first = 0
            for index, rows in enumerate(sources.parquet_row_groups(part.source)):
                specs.append((("parquet", part.name, index, None, first), rows))
                first += rows
            continue
        layout = part.layout
        if layout.compression or layout.encoding not in SPLITTABLE:  # one block, read whole
            specs.append((("text", part.name, None, part, 0), None))
            continue
        _, blocks = read_bytes(
            str(part.source), delimiter=b"\n", blocksize=block_bytes, sample=False
        )
        for k, block in enumerate(blocks[0]):
            specs.append((("text", part.name, block, part, k), None))
    return specs


def _screen_notes(screens: list, offsets: list, drop_invalid: bool) -> list:
    """The notes of the blocks' row screens, as one screen of the whole log would say them."""
    whole = RowScreen(drop_repeats=drop_invalid)
    for screen, offset in zip(screens, offsets):
        whole.rows += screen.rows
        whole.zeros += screen.zeros
        whole.repeats += screen.repeats
        room = QUOTED_ROWS - len(whole.zero_rows)
        whole.zero_rows.extend(offset + r for r in screen.zero_rows[: max(room, 0)])
        if screen.longest > whole.longest:
            whole.longest, whole.longest_at = screen.longest, offset + screen.longest_at
    return whole.notes()


def _checks(block: tuple) -> tuple:
    """(rows kept, rows read, rows not numeric, RowScreen) of a block read by `_block`."""
    return block[0].shape[0], *block[1:]


def _take_values(block: tuple) -> np.ndarray:
    return block[0]


def _notes(checked: list, drop_invalid: bool) -> tuple:
    """(rows left out, notes) of the blocks' `_checks`, in row order."""
    read_offsets = np.concatenate([[0], np.cumsum([c[1] for c in checked])]).astype(int)
    invalid = sum(c[2] for c in checked)
    lost = int(read_offsets[-1]) - sum(c[0] for c in checked)
    notes = [f"dropped {invalid} row(s) with missing or non-numeric values"] if invalid else []
    notes += _screen_notes([c[3] for c in checked], list(read_offsets[:-1]), drop_invalid)
    return lost, notes


@dataclass
class Reading:
    """How the blocks of a log in its files are read, and the rows each declares.

    specs : (spec, rows declared or None) of every block, in row order (`_specs`).
    wanted, factors, drop_invalid : the columns read, their factors to the base unit, and
        whether rows with a bad value are dropped (`_block`).
    name : the first file's name, for messages.
    """

    specs: list
    wanted: list
    factors: np.ndarray
    drop_invalid: bool
    name: str
    kept: list | None = None  # the blocks read once and held in memory (`keep`)

    @property
    def declared(self) -> bool:
        """Whether every block declares its rows (Parquet footers)."""
        return all(n is not None for _, n in self.specs)

    def reads(self, checked: list | None = None) -> list:
        """One Dask object per block: `_block` of it; `checked`, the blocks' `_checks` by an
        earlier pass: a block whose rows were all kept is not screened again. The blocks held
        in memory when they are kept (`keep`): every pass reads them there."""
        import dask

        if self.kept is not None:
            return self.kept
        clean = [c[0] == c[1] for c in checked] if checked else [False] * len(self.specs)
        return [
            dask.delayed(_block)(spec, self.wanted, self.factors, self.drop_invalid, ok)
            for (spec, _), ok in zip(self.specs, clean)
        ]

    def table(self, rows: list, reads: list | None = None):
        """The Dask array (N, k) of the blocks (`reads`, else new ones), holding `rows` rows
        each."""
        import dask
        import dask.array as da

        reads = reads or self.reads()
        blocks = [
            da.from_delayed(dask.delayed(_take_values)(read), (n, len(self.wanted)), float)
            for read, n in zip(reads, rows)
            if n
        ]
        if not blocks:
            raise InputError(f"{self.name}: no data rows")
        return da.concatenate(blocks, axis=0)

    def as_declared(self) -> tuple:
        """(the Dask array of the rows the blocks declare, the Dask objects of their `_checks`):
        no pass; the checks read the same blocks as the array, in the same pass."""
        import dask

        reads = self.reads()
        checks = [dask.delayed(_checks)(read) for read in reads]
        return self.table([n for _, n in self.specs], reads), checks

    def keep(self) -> None:
        """Read every block now (on a dask.distributed cluster: start reading) and hold it in
        memory on the current scheduler, for every pass to read there."""
        import dask

        self.kept = list(dask.persist(*self.reads()))

    def counted(self) -> tuple:
        """(Dask array, rows left out, notes) after a pass that counts the rows every block
        keeps (and checks them)."""
        import dask

        checked = list(dask.compute(*[dask.delayed(_checks)(read) for read in self.reads()]))
        lost, notes = _notes(checked, self.drop_invalid)
        return self.table([c[0] for c in checked], self.reads(checked)), lost, notes


@dataclass
class Deferred:
    """The checks of a log read on the rows its files declare, settled by the first pass over
    it (`nlpcal.passes.Pending`): the rows left out, the notes on them (into `log`), and the
    arrays of its columns read again, without the screen, from the blocks whose rows were all
    kept (rebuilt on the rows counted when some were left out).

    columns : (LazySamples, the columns of the table it holds) of the log.
    """

    reading: Reading
    log: Log | None = None
    columns: list = field(default_factory=list)

    def settle(self, checked: list) -> bool:
        """Take the first pass's `_checks` of every block; True when the pass stands (no row
        left out), False when the arrays were rebuilt and the pass is to run again."""
        checked = list(checked)
        lost, notes = _notes(checked, self.reading.drop_invalid)
        if self.log is not None:
            self.log.dropped += lost
            self.log.notes.extend(notes)
        # later passes read the blocks whose rows were all kept without the screen
        table = self.reading.table([c[0] for c in checked], self.reading.reads(checked))
        for lazy, selection in self.columns:
            lazy.pending = None
            if lost:
                lazy.rebuilt(table[:, selection])
            else:
                lazy.reread(table[:, selection])
        return not lost


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
    header: bool | None = None,
    block_bytes: int = BLOCK_BYTES,
    variable: str | None = None,
    instance: int | None = None,
    reference_log=None,
    keep: bool = True,
) -> Log:
    """`nlpcal.io.read_log` for a Dask cluster: the same columns, units and checks, the samples
    (and a reference column) left in the files as `nlpcal.passes.LazySamples`.

    Reading a Parquet log is no pass: the footers give its rows, and the first pass over it (on
    the current Dask scheduler) checks every value, counts the rows left out (into `dropped` and
    `notes`) and gathers what the calibration takes from the log without a pass of its own; a
    CSV log's rows are counted by a pass here. The unit's plausibility is checked on the first
    block. A per-sample geomagnetic reference and extra columns (temperatures) need the log in
    memory (`read_log`).

    keep : read the files once, now, and hold their blocks in memory on the current scheduler,
    for every pass of the calibration to read there, when they fit in the memory it may take
    (`nlpcal.cluster.memory_to_keep`; not on Dask's processes scheduler), for as long as the
    log is kept; otherwise, and without `keep`, every pass reads the files again. The notes
    say which.
    """
    one_reference(reference_column, reference_field, reference_model)
    if reference_log is not None:
        raise InputError("--reference-log needs the log in memory; drop --scheduler")
    if str(source) == "-":  # Dask's tasks read files; a stream is read once, here
        raise InputError("a log read from stdin (-) is read in memory; drop --scheduler")
    _require_lazy(extra_columns, reference_model)
    check_options(str(source), None, variable=variable, instance=instance)
    notes: list = []
    files = log_files(source, header, notes=notes)
    first = files[0]
    chosen = first.field_columns(columns, notes)
    declared = declared_unit(chosen, notes)
    unit, how = sensor_unit(chosen, unit, fallback_unit, notes, declared=declared)
    wanted, factors = list(chosen), [units.field_factor(unit)] * 3
    name, ref_unit = _reference_column(first, reference_column, chosen, unit, notes)
    if name is not None:
        wanted.append(name)
        factors.append(units.field_factor(ref_unit))
    started = time.perf_counter()
    reading = Reading(
        _specs(files, block_bytes), wanted, np.asarray(factors, float), drop_invalid, first.name
    )
    held, why = _held(reading, files) if keep else (None, "")
    samples, column, deferred, lost, screened = _lazy_columns(reading, name is not None)
    notes.extend(screened)
    if held is not None:  # read once and counted: the passes read memory
        samples.ledger.record("keep", time.perf_counter() - started, whole=False)
    elif deferred is None:  # counted: a pass
        samples.ledger.record("read", time.perf_counter() - started)
    with np.errstate(all="ignore"):  # values the first pass's survey has yet to check
        _, settled, check = settle_unit(passes.first_block_sample(samples), unit, how)
    if settled != unit:  # an assumed unit ruled out: the file's numbers, as raw counts
        samples, unit = passes.scaled(samples, 1.0 / units.field_factor(unit)), settled
    reference: passes.LazySamples | float | None = None
    model = None
    if column is not None and name is not None:
        if unit == "raw" and units.unit_in_name(name) is None:  # read in the assumed unit
            factor = units.field_factor(ref_unit)
            column, ref_unit = (column if factor == 1.0 else column * (1.0 / factor)), "raw"
        units.check_compatible(unit, ref_unit, f"reference column {name!r}")
        reference = column  # its values checked with the log's, by the first pass (`prepare`)
    elif reference_model is not None:
        reference, model = model_reference(reference_model, unit, notes)
    elif reference_field is not None:
        reference = constant_reference(reference_field, reference_field_unit, unit)
    notes.append(_where_note(held, why, len(reading.specs), files))
    log = Log(
        path=str(source),
        columns=list(chosen),
        samples=samples,  # rows that stay on the cluster (LazySamples)
        unit=unit,
        unit_source=how,
        reference=reference,
        reference_column=name,
        reference_source=model,
        dropped=lost,
        engine="pyarrow" if files[0].parquet else "c",
        notes=notes,
        warnings=[check] if check else [],
        layout=first.layout,
    )
    if deferred is not None:  # what the first pass finds goes to the log
        deferred.log = log
    return log


def _where_note(held: str | None, why: str, blocks: int, files) -> str:
    """Where the passes read a log: in memory (`held`, from `_held`) or in its files (`why`,
    when it was to be kept)."""
    what = "Parquet row group" if all(part.parquet for part in files) else "block"
    what += "" if blocks == 1 else "s"
    if held is not None:
        verb = "is" if blocks == 1 else "are"
        return f"the log's {blocks} {what} {verb} read once and kept in memory ({held})"
    return f"the log stays in its files: {blocks} {what} read in every pass" + (
        f" ({why})" if why else ""
    )


#: The most memory the values of a text file can take once read, in times its size: a value of
#: one digit and its separator, 2 bytes, becomes 8 (`_memory_needed`). [1]
TEXT_EXPANSION = 4.0


def _held(reading: Reading, files) -> tuple:
    """Keep the blocks of a log in memory on the current scheduler (`Reading.keep`) when they
    fit in what it may take there (`nlpcal.cluster.memory_to_keep`): (where, and how much of it
    they take; "") when kept, else (None, why not)."""
    room = cluster.memory_to_keep()
    needed = _memory_needed(reading, files)
    if room is None:
        return None, "this scheduler keeps no log in memory, or does not tell how much it has"
    if needed is None:
        return None, "the size of its values once read is not known"
    if needed > room[0]:
        return None, f"its {_mib(needed)} exceed the {_mib(room[0])} {room[1]} may take"
    reading.keep()
    return f"{_mib(needed)} on {room[1]}, which may take {_mib(room[0])}", ""


def _mib(size: float) -> str:
    """A memory size in MiB for a note: 0.686 MiB, 2,365 MiB. [byte]"""
    mib = size / 2**20
    return f"{mib:.3g} MiB" if mib < 1000 else f"{mib:,.0f} MiB"


def _memory_needed(reading: Reading, files) -> float | None:
    """The memory a log's blocks take once read: 8 bytes per value of the rows Parquet footers
    declare, and at most TEXT_EXPANSION times the size of a text file; None when that cannot be
    told: a compressed file (one block, read whole, whose values' size is not known), or a file
    whose size cannot be read. [byte]"""
    needed = 8.0 * len(reading.wanted) * sum(n for _, n in reading.specs if n is not None)
    for part in files:
        if part.parquet:
            continue
        if part.layout.compression:
            return None
        try:
            size = float(os.stat(str(part.source)).st_size)
        except (OSError, TypeError, ValueError):
            return None
        needed += TEXT_EXPANSION * size
    return needed


def _lazy_columns(reading: Reading, with_reference: bool) -> tuple:
    """(samples, the reference column or None, their `Deferred` checks or None, rows left out,
    notes) of a log's blocks: on the rows the blocks declare, checked by the first pass, or
    counted by a pass now (a log kept in memory: on its kept blocks, every row count known)."""
    deferred: Deferred | None = None
    if reading.declared and reading.kept is None:
        table, checks = reading.as_declared()
        deferred = Deferred(reading)
        pending = passes.Pending(checks, deferred.settle)
        lost, notes = 0, []
    else:
        table, lost, notes = reading.counted()
        pending = None
    samples = passes.LazySamples(table[:, :3], pending=pending)
    column = None
    if with_reference:
        column = passes.LazySamples(table[:, 3], pending=pending, ledger=samples.ledger)
    if deferred is not None:
        deferred.columns = [(samples, slice(0, 3)), *([(column, 3)] if column is not None else [])]
    return samples, column, deferred, lost, notes


def _require_lazy(extra_columns, reference_model) -> None:
    """InputError unless a log can stay in its files: no temperature columns, no reference from
    position or time columns, and dask installed."""
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


def _reference_column(first, reference_column, chosen: list, unit: str, notes: list) -> tuple:
    """The name of the reference column in the log's first file and its unit (None, None
    without one): InputError when it is a field column or its unit does not suit the
    field's."""
    if reference_column is None:
        return None, None
    name = column_name(first.preview, reference_column)
    if name in chosen:
        raise InputError(
            f"column {name!r} is one of the field columns ({', '.join(chosen)}); pass the "
            f"reference column, or --columns X Y Z"
        )
    ref_unit = reference_unit(name, unit, notes)
    units.check_compatible(unit, ref_unit, f"reference column {name!r}")
    return name, ref_unit
