"""Where a log's rows come from: one CSV or Parquet file, or many of them.

A log may be one file, a glob pattern (`logs/*.parquet`, `logs/**/*.csv`) or a folder; the
files of a pattern or folder are one log, their rows in the order of the sorted file names, and
must have the same columns. Parquet (pyarrow, the `dask` or `parquet` extra) is recognised by its
suffix (.parquet, .parq, .pq) or its leading bytes, and read with the same column detection,
units and validation as CSV (`nlpcal.io.tables` reads the columns it gets from here).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pandas as pd

from ..errors import InputError
from .files import (
    PARQUET_SUFFIXES,
    TEXT_SUFFIXES,
    existing_file,
    matching_files,
    sha256_file,
)

#: The leading (and trailing) bytes of every Parquet file.
PARQUET_MAGIC = b"PAR1"
INSTALL_PARQUET = "Parquet needs pyarrow: pip install 'nlpcal[parquet]' (or 'nlpcal[dask]')"
#: Bytes at each end of a file whose digest tells files of the same size apart before their
#: whole content is (`distinct_files`): logs of a fixed row count in a binary format are often of
#: one size, and hashing them whole read the log once more before its first pass. [byte]
ENDS_BYTES = 1 << 20


def is_pattern(source) -> bool:
    """Whether `source` names several files: a glob pattern or a folder."""
    text = str(source)
    if Path(text).is_file():  # a file whose name has brackets is that file
        return False
    return any(ch in text for ch in "*?[") or Path(text).is_dir()


def log_paths(source, notes: list | None = None) -> list:
    """The files of a log: [source] for one file; the sorted matches of a glob pattern; the
    sorted log files (`is_log_file`) of a folder (`matching_files`), each once
    (`distinct_files`, which says in `notes` what it left out). InputError when nothing
    matches."""
    text = str(source)
    found = matching_files(text)
    if found:
        return distinct_files(found, notes)
    if Path(text).is_dir():
        raise InputError(
            f"{text}: the folder has no CSV or Parquet files "
            f"({', '.join(TEXT_SUFFIXES + PARQUET_SUFFIXES)})"
        )
    if is_pattern(text):
        raise InputError(f"{text}: no file matches the pattern")
    return [existing_file(text)]  # which says why the one file named is not there


def distinct_files(paths, notes: list | None = None) -> list:
    """`paths` with each file once: a file named twice (the same path, or a link to the same
    file: the same device and inode) is read once and said in `notes`; two files with the same
    content (the same SHA-256, compared among files of the same size whose ends are the same)
    are refused, since their rows would count twice."""
    kept: list = []
    first_of: dict = {}
    size_of: dict = {}
    for path in paths:
        status = os.stat(path)
        same = first_of.setdefault((status.st_dev, status.st_ino), path)
        if same is not path:
            if notes is not None:
                notes.append(f"{path} is the same file as {same}: read once")
            continue
        kept.append(path)
        size_of[path] = status.st_size
    for group in _alike(kept, size_of.__getitem__):
        for candidates in _alike(group, _ends_digest):  # only these are read whole
            digests: dict = {}
            for path in candidates:
                other = digests.setdefault(sha256_file(path), path)
                if other is not path:
                    raise InputError(
                        f"{other} and {path} have the same content (SHA-256): the same data "
                        f"twice; leave the copy out"
                    )
    return kept


def _alike(paths: list, key) -> list:
    """The groups of two or more of `paths` with the same `key(path)`."""
    groups: dict = {}
    for path in paths:
        groups.setdefault(key(path), []).append(path)
    return [group for group in groups.values() if len(group) > 1]


def _ends_digest(path) -> str:
    """The SHA-256 of a file's first and last ENDS_BYTES (of all of it when shorter than
    twice that)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        digest.update(handle.read(ENDS_BYTES))
        handle.seek(max(ENDS_BYTES, os.fstat(handle.fileno()).st_size - ENDS_BYTES))
        digest.update(handle.read())
    return digest.hexdigest()


def is_parquet(path) -> bool:
    """Whether a file is Parquet: by its suffix, else by its leading bytes."""
    path = Path(path)
    if path.suffix.lower() in PARQUET_SUFFIXES:
        return True
    try:
        with open(path, "rb") as handle:
            return handle.read(4) == PARQUET_MAGIC
    except OSError:
        return False


def pyarrow_parquet():
    """pyarrow.parquet, or InputError saying how to install it."""
    try:
        import pyarrow.parquet
    except ImportError:
        raise InputError(INSTALL_PARQUET) from None
    return pyarrow.parquet


def _parquet_file(path):
    """A pyarrow ParquetFile, or InputError saying why the file cannot be read as Parquet."""
    parquet = pyarrow_parquet()
    path = existing_file(path, "a Parquet file")
    try:
        return parquet.ParquetFile(path)
    except Exception as exc:  # pyarrow's ArrowInvalid, OSError ...
        raise InputError(f"{path}: cannot be read as Parquet ({_first_line(exc)})") from None


def distinct_names(names) -> list:
    """Column names stripped, a repeated one numbered as pandas numbers the repeats of a CSV
    header (bx, bx.1, bx.2): every column of a log is found by its name."""
    seen: dict = {}
    out = []
    for name in (str(n).strip() for n in names):
        count = seen.get(name, 0)
        seen[name] = count + 1
        out.append(name if count == 0 else f"{name}.{count}")
    return out


def _first_line(exc: Exception) -> str:
    text = " ".join(str(exc).split())
    return text[:200] or type(exc).__name__


def parquet_columns(path) -> list:
    """The column names of a Parquet file, from its footer (no data read)."""
    return distinct_names(_parquet_file(path).schema_arrow.names)


def parquet_row_groups(path) -> list:
    """The number of rows of every row group of a Parquet file (its footer)."""
    metadata = _parquet_file(path).metadata
    return [metadata.row_group(i).num_rows for i in range(metadata.num_row_groups)]


def _frame(table) -> pd.DataFrame:
    frame = table.to_pandas()
    frame.columns = distinct_names(frame.columns)
    return frame


def _renamed(handle) -> list | None:
    """The names `distinct_names` gives the columns of a ParquetFile `handle`, or None where
    they are the names as stored: pyarrow then reads only the columns asked for by name."""
    stored = [str(n) for n in handle.schema_arrow.names]
    names = distinct_names(stored)
    return None if names == stored else names


def _named(handle, read, columns=None):
    """read(columns=...) of a ParquetFile `handle` for the columns named as `distinct_names`
    names them (all when None), the table's columns so named."""
    names = _renamed(handle)
    if names is None:
        return read(columns=columns)
    table = read(columns=None)
    if columns is not None:
        table = table.select([names.index(name) for name in columns])
        names = list(columns)
    return table.rename_columns(names)


def read_parquet(path, columns=None) -> pd.DataFrame:
    """A Parquet file (the `columns` only, when given) as a DataFrame."""
    handle = _parquet_file(path)
    try:
        return _frame(_named(handle, handle.read, columns))
    except Exception as exc:
        raise InputError(f"{path}: cannot be read as Parquet ({_first_line(exc)})") from None


def parquet_row_group(path, index: int, columns=None):
    """One row group of a Parquet file as a pyarrow Table (what one block of a Dask log
    reads), its columns named as `distinct_names` names them."""
    handle = _parquet_file(path)
    try:
        return _named(
            handle, lambda columns: handle.read_row_group(index, columns=columns), columns
        )
    except Exception as exc:
        raise InputError(
            f"{path}: row group {index} cannot be read as Parquet ({_first_line(exc)})"
        ) from None


def arrow_frame(table) -> pd.DataFrame:
    """A pyarrow Table as a DataFrame, its column names stripped."""
    return _frame(table)


def parquet_chunks(path, chunk_rows: int, columns=None):
    """The rows of a Parquet file as DataFrames of at most `chunk_rows` rows, O(chunk) memory."""
    handle = _parquet_file(path)
    exact = _renamed(handle) is None  # else read whole, and chosen by `distinct_names`
    try:
        for batch in handle.iter_batches(batch_size=chunk_rows, columns=columns if exact else None):
            frame = _frame(batch)
            yield frame if exact or columns is None else frame[list(columns)]
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"{path}: cannot be read as Parquet ({_first_line(exc)})") from None


def same_columns(named) -> list:
    """The column names shared by every file of a log, given (name, columns) per file, or
    InputError naming the first file whose columns differ from the first file's."""
    first_name, first = named[0]
    for name, columns in named[1:]:
        if list(columns) != list(first):
            raise InputError(
                f"{name}: its columns ({', '.join(map(str, columns))}) differ from those of "
                f"{first_name} ({', '.join(map(str, first))}); the files of one log must have "
                f"the same columns"
            )
    return list(first)


def concatenated(paths, frames) -> pd.DataFrame:
    """The tables of a log's files, one after another; they must have the same columns."""
    same_columns([(path, [str(c) for c in frame.columns]) for path, frame in zip(paths, frames)])
    return frames[0] if len(frames) == 1 else pd.concat(frames, ignore_index=True)
