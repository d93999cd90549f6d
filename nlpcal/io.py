"""Reading magnetometer logs, choosing columns, converting units and writing outputs atomically.

Validation lives here and is shared by the library and the command line: every problem with the
input raises `InputError` with one sentence that says what was received and how to fix it.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import InputError

#: Field units and their size in nT. "raw" keeps the log's own unit (counts, arbitrary units).
FIELD_UNITS_NT = {"nT": 1.0, "uT": 1e3, "mT": 1e6, "mG": 1e2, "G": 1e5, "T": 1e9, "raw": 1.0}

#: Prefixes of names recognised as magnetometer axes once the axis letter, spaces and
#: punctuation are taken out (bx, mag_x, mx_uT, "Magnetometer X (uT)", x ...).
MAGNETIC_PREFIXES = ("", "b", "m", "mag", "magn", "magnetometer", "magnetic", "h", "field",
                     "compass", "b1")

#: Unit suffixes of column names, and the unit they suggest ("raw" for counts).
UNIT_SUFFIXES = {"nt": "nT", "ut": "uT", "mt": "mT", "mg": "mG", "gauss": "G", "g": "G", "t": "T",
                 "counts": "raw", "count": "raw", "lsb": "raw", "raw": "raw"}


def _clean(text: str) -> str:
    return "".join(ch for ch in text if ch.isalnum())


def _axis_templates(columns):
    """Group column names that differ only in one letter x, y, z: template -> (X, Y, Z)."""
    groups: dict = {}
    for name in columns:
        low = name.lower()
        for i, ch in enumerate(low):
            if ch in "xyz":
                template = (low[:i], low[i + 1:])
                groups.setdefault(template, {})[ch] = name
    return {t: (g["x"], g["y"], g["z"]) for t, g in groups.items() if len(g) == 3}


def _is_magnetic(template) -> bool:
    prefix, suffix = (_clean(part) for part in template)
    return prefix in MAGNETIC_PREFIXES and (suffix == "" or suffix in UNIT_SUFFIXES)


def unit_in_name(name: str):
    """The unit a single column name carries ("proton_nT", "F (nT)", "field_uT"), or None."""
    low = name.lower().strip()
    if low.endswith(")") and "(" in low:
        return UNIT_SUFFIXES.get(_clean(low[low.rindex("(") + 1:]))
    if "_" in low:
        return UNIT_SUFFIXES.get(_clean(low.rsplit("_", 1)[1]))
    return None


def suggested_unit(columns):
    """The unit a column suffix such as _uT, (uT) or _gauss suggests, or None."""
    low = columns[0].lower()
    for i, ch in enumerate(low):
        if ch in "xyz" and _is_magnetic((low[:i], low[i + 1:])):
            return UNIT_SUFFIXES.get(_clean(low[i + 1:]))
    return None


#: Rows per chunk when validating, so that a memory-mapped log is never copied whole.
CHECK_CHUNK_ROWS = 65536

#: Fewest samples accepted: nine parameters plus the mean field of Eq. 8.
MIN_SAMPLES = 10


def csv_engine() -> str:
    """The fastest pandas CSV engine available here: "pyarrow" when installed, else "c"."""
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        return "c"
    return "pyarrow"


def read_table(path) -> pd.DataFrame:
    """Read a CSV log with the fastest available pandas engine."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a CSV file")
    engine = csv_engine()
    try:
        frame = pd.read_csv(path, engine=engine)
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: the file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        if engine != "c":  # pyarrow is stricter; let the C engine have a go before giving up
            try:
                frame = pd.read_csv(path, engine="c")
            except Exception:
                raise InputError(f"{path}: cannot be read as CSV ({exc})") from None
        else:
            raise InputError(f"{path}: cannot be read as CSV ({exc})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame


def resolve_columns(frame: pd.DataFrame, columns=None, what: str = "magnetometer") -> list:
    """The three field columns: the ones asked for, or the one recognised triple.

    Raises InputError listing the columns found when a column is missing or the choice is
    ambiguous.
    """
    found = list(frame.columns)
    if columns:
        columns = list(columns)
        if len(columns) != 3:
            raise InputError(f"got {len(columns)} {what} columns, expected 3; pass --columns X Y Z")
        lower = {c.lower(): c for c in found}
        resolved = []
        for name in columns:
            if name in frame.columns:
                resolved.append(name)
            elif name.lower() in lower:
                resolved.append(lower[name.lower()])
            else:
                raise InputError(
                    f"column {name!r} not found; the log has columns: {', '.join(found)}")
        return resolved
    matches = [triple for template, triple in _axis_templates(found).items()
               if _is_magnetic(template)]
    if len(matches) == 1:
        return list(matches[0])
    if not matches:
        raise InputError(
            f"no {what} columns recognised (bx/by/bz, x/y/z, mag_x/mag_y/mag_z, mx_uT/...); the "
            f"log has columns: {', '.join(found)}; pass --columns X Y Z")
    options = "; ".join(" ".join(m) for m in matches)
    raise InputError(
        f"ambiguous {what} columns ({options}); the log has columns: {', '.join(found)}; "
        f"pass --columns X Y Z")


def unit_factor(unit: str) -> float:
    """Size of one `unit` in nT."""
    if unit not in FIELD_UNITS_NT:
        raise InputError(f"unknown unit {unit!r}; expected one of {', '.join(FIELD_UNITS_NT)}")
    return FIELD_UNITS_NT[unit]


@dataclass
class NumericColumns:
    """Numeric columns taken from a table, with the rows that were dropped."""

    values: np.ndarray
    kept: np.ndarray  # boolean mask over the table's rows
    dropped: int


def numeric_columns(frame: pd.DataFrame, columns, *, drop_invalid: bool = False,
                    source: str = "log") -> NumericColumns:
    """Take `columns` as a float array; non-numeric, empty or non-finite cells are errors.

    With drop_invalid, such rows are dropped instead and counted.
    """
    data = np.empty((len(frame), len(columns)))
    for k, name in enumerate(columns):
        column = frame[name]
        if not pd.api.types.is_numeric_dtype(column) or pd.api.types.is_bool_dtype(column):
            column = pd.to_numeric(column, errors="coerce")
        data[:, k] = column.to_numpy(dtype=float, na_value=np.nan)
    valid = np.isfinite(data).all(axis=1)
    bad = int((~valid).sum())
    if bad and not drop_invalid:
        first = int(np.flatnonzero(~valid)[0])
        raise InputError(
            f"{source}: {bad} row(s) have a missing, non-numeric or non-finite value in "
            f"{', '.join(columns)} (first at data row {first + 1}); fix them or pass "
            f"--drop-invalid")
    return NumericColumns(values=data[valid], kept=valid, dropped=bad)


def as_samples(samples, *, minimum: int = MIN_SAMPLES,
               purpose: str = "for nine parameters") -> np.ndarray:
    """An (N, 3) float64 array of field samples with at least `minimum` rows, or InputError."""
    try:
        samples = np.asarray(samples, dtype=float)
    except (TypeError, ValueError):
        raise InputError("samples must be numeric, an (N, 3) array-like") from None
    if samples.ndim != 2 or samples.shape[1] != 3:
        raise InputError(f"samples must have shape (N, 3), got {samples.shape}")
    if samples.shape[0] < minimum:
        raise InputError(f"got {samples.shape[0]} samples, need at least {minimum} {purpose}")
    return samples


def check_samples(samples, *, minimum: int = MIN_SAMPLES) -> np.ndarray:
    """Validate an (N, 3) array of field samples from many attitudes; return it as float64.

    Non-finite values, all samples equal and a constant axis are errors.
    """
    samples = as_samples(samples, minimum=minimum)
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    for start in range(0, samples.shape[0], CHECK_CHUNK_ROWS):  # O(chunk) memory: memmaps too
        chunk = samples[start:start + CHECK_CHUNK_ROWS]
        if not np.isfinite(chunk).all():
            raise InputError("samples contain NaN or infinite values; drop or fix those rows")
        low, high = np.minimum(low, chunk.min(axis=0)), np.maximum(high, chunk.max(axis=0))
    if np.all(low == high):
        raise InputError("all samples are equal; calibration needs many attitudes")
    if np.any(low == high):
        axes = ", ".join("xyz"[k] for k in np.flatnonzero(low == high))
        raise InputError(f"the {axes} column is constant: that axis never saw the field change; "
                         f"calibration needs attitudes that turn every axis")
    return samples


def check_reference(reference, n: int):
    """Validate a reference field: None, a positive float, or N positive values. [nT]"""
    if reference is None:
        return None
    array = np.asarray(reference, dtype=float)
    if array.ndim == 0:
        value = float(array)
        if not np.isfinite(value) or value <= 0:
            raise InputError(f"the reference field must be a positive number, got {value}")
        return value
    array = array.ravel()
    if array.size != n:
        raise InputError(f"the reference series has {array.size} values for {n} samples")
    if not np.isfinite(array).all():
        raise InputError("the reference series contains NaN or infinite values")
    if (array <= 0).any():
        bad = int((array <= 0).sum())
        raise InputError(f"the reference series has {bad} non-positive value(s); a field "
                         f"magnitude must be positive")
    return array


def check_output_path(path) -> None:
    """Fail before any work when an output's folder does not exist or the path is a folder."""
    if not path:
        return
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise InputError(f"{path}: the folder {directory} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a file name")


def _atomic_write(path, write, binary: bool = False) -> None:
    path = Path(path)
    check_output_path(path)
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with (os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", newline="")) as handle:
            write(handle)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def write_text_atomic(path, text: str) -> None:
    """Write text to a temporary file beside `path`, then rename it over `path`."""
    _atomic_write(path, lambda handle: handle.write(text))


def write_bytes_atomic(path, data: bytes) -> None:
    """Write bytes (a PNG, say) to a temporary file beside `path`, then rename it over `path`."""
    _atomic_write(path, lambda handle: handle.write(data), binary=True)


def write_json_atomic(path, document) -> None:
    write_text_atomic(path, json.dumps(document, indent=2) + "\n")


def write_csv_atomic(path, frame: pd.DataFrame, float_format: str | None = None) -> None:
    """Write a table atomically; without float_format every value round-trips exactly."""
    _atomic_write(path, lambda handle: frame.to_csv(handle, index=False,
                                                    float_format=float_format))


def read_json(path, what: str = "JSON file") -> dict:
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid {what} ({exc})") from None


@dataclass
class MappedColumns:
    """Numeric columns of a CSV streamed into a memory-mapped temporary file.

    values : (N, k) float64, backed by an unlinked temporary file (freed when dropped).
    columns : the k column names.
    dropped : rows dropped as invalid.
    """

    values: np.ndarray
    columns: list
    dropped: int


def csv_to_memmap(path, columns=None, extra_columns=(), *, drop_invalid: bool = False,
                  scale: float = 1.0, chunk_rows: int = 250_000, directory=None) -> MappedColumns:
    """Stream the field columns (and `extra_columns`) of a CSV into a memory-mapped array.

    Memory stays O(chunk_rows) whatever the size of the log; the pandas C engine reads the chunks
    (the pyarrow engine cannot read in chunks). The three field columns come first; every column
    is multiplied by `scale` (a unit conversion) on the way.
    """
    path = Path(path)
    header = read_table_header(path)
    chosen = resolve_columns(header, columns)
    wanted = chosen + [c for c in extra_columns]
    for name in extra_columns:
        if name not in header.columns:
            raise InputError(f"column {name!r} not found; the log has columns: "
                             f"{', '.join(header.columns)}")
    store = tempfile.TemporaryFile(dir=directory)
    rows = dropped = 0
    try:
        reader = pd.read_csv(path, usecols=lambda c: str(c).strip() in wanted,
                             chunksize=chunk_rows, engine="c")
        for chunk in reader:
            chunk.columns = [str(c).strip() for c in chunk.columns]
            numeric = numeric_columns(chunk, wanted, drop_invalid=drop_invalid, source=str(path))
            dropped += numeric.dropped
            rows += numeric.values.shape[0]
            store.write(np.ascontiguousarray(numeric.values * scale).tobytes())
    except InputError as exc:
        store.close()
        if "first at data row" in str(exc):
            raise InputError(f"{exc} (in the chunk after row {rows + dropped})") from None
        raise
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        store.close()
        raise InputError(f"{path}: cannot be read as CSV ({exc})") from None
    store.flush()
    if rows == 0:
        store.close()
        raise InputError(f"{path}: no data rows")
    values = np.memmap(store, dtype=np.float64, mode="r", shape=(rows, len(wanted)))
    return MappedColumns(values=values, columns=wanted, dropped=dropped)


def read_table_header(path) -> pd.DataFrame:
    """The column names of a CSV (an empty frame), with the checks of `read_table`."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a CSV file")
    try:
        frame = pd.read_csv(path, nrows=0)
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: the file is empty") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read as CSV ({exc})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame
