"""Files: atomic writers, strict JSON, and the checks of output paths.

An output is written to a temporary file beside it and renamed over it at the end, so a failed or
killed run never leaves a half-written file nor replaces an existing one. JSON written by nlpcal
never contains NaN or Infinity: non-finite numbers become null.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import hashlib
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError, WriteError


def plain(value):
    """`value` with numpy scalars and arrays turned into Python numbers and lists, and every
    non-finite float into None, so that it serialises as strict JSON."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return [plain(v) for v in value.tolist()]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    return value


def json_text(document) -> str:
    """Strict JSON (no NaN, no Infinity) of a document, indented, with a final newline."""
    return json.dumps(plain(document), indent=2, allow_nan=False) + "\n"


PARQUET_SUFFIXES = (".parquet", ".parq", ".pq")
#: Files of a folder taken as a log's files: CSV and other delimited text, compressed or not,
#: and Parquet.
TEXT_SUFFIXES = (".csv", ".txt", ".tsv", ".dat")
COMPRESSED_SUFFIXES = (".gz", ".bz2", ".xz", ".zip", ".zst")


def check_output_path(path, *inputs) -> None:
    """Fail before any work when an output's folder does not exist, the path is a folder, or it
    is one of the `inputs` (writing there would replace the data being read)."""
    if not path or str(path) == "-":
        return
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise InputError(f"{path}: the folder {directory} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a file name")
    if not path.exists():
        return
    for source in inputs:
        files = matching_files(source) if source and str(source) != "-" else []
        if any(os.path.samefile(path, item) for item in files):
            raise InputError(
                f"{path}: is also an input; writing it would replace the data being read, so "
                f"choose another output name"
            )


def is_log_file(path: Path) -> bool:
    """Whether a file in a folder looks like a log (by its suffixes)."""
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] in COMPRESSED_SUFFIXES:
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] in TEXT_SUFFIXES + PARQUET_SUFFIXES


def matching_files(source) -> list:
    """The existing files a log's name stands for, sorted: itself, the log files of a folder
    (`is_log_file`), or the files a glob pattern matches; none when nothing matches."""
    text = str(source)
    if Path(text).is_dir():
        return sorted(p for p in Path(text).iterdir() if p.is_file() and is_log_file(p))
    if Path(text).exists():
        return [Path(text)]
    return sorted(Path(p) for p in glob.glob(text, recursive=True) if Path(p).is_file())


#: Error numbers of a write that failed after its path was accepted (exit status 1); any other
#: OSError of an output is a path that cannot be written (exit status 2).
WRITE_FAILURES = {errno.ENOSPC, errno.EIO, errno.EDQUOT, errno.EFBIG}


def output_error(path, error: OSError) -> Exception:
    """An OSError of writing `path` as one sentence: WriteError (exit 1) for a failed write,
    InputError (exit 2) for a path that cannot be written."""
    reason = error.strerror or str(error)
    if error.errno in WRITE_FAILURES:
        return WriteError(f"{path}: could not be written ({reason}); nothing was changed")
    return InputError(f"{path}: cannot be written ({reason})")


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def _unnamed_file(directory: Path):
    """A file descriptor of an unnamed file in `directory` (Linux O_TMPFILE), or None where the
    system or the file system has none."""
    flag = getattr(os, "O_TMPFILE", None)
    if flag is None or not os.path.isdir("/proc/self/fd"):
        return None
    try:
        return os.open(directory, flag | os.O_WRONLY, 0o666 & ~_umask())
    except OSError:
        return None


def _atomic_write(path, write, binary: bool = False) -> None:
    """Write through `write(handle)` to a file that appears at `path` whole, or not at all.

    On Linux the data go to an unnamed file (O_TMPFILE), which a killed run leaves nowhere; it is
    linked beside `path` and renamed over it only once complete. Elsewhere a named temporary
    file is used and removed on any error or interruption (SIGINT, and SIGTERM through the
    command line's handler).
    """
    path = Path(path)
    check_output_path(path)
    directory = path.parent if str(path.parent) else Path(".")
    tmp = None
    try:
        fd = _unnamed_file(directory)
        if fd is None:
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
            os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        with os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", newline="") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
            if tmp is None:  # name the complete file beside its target, then rename it
                tmp = str(directory / f".{path.name}.{os.getpid()}.{id(handle):x}.tmp")
                _link_unnamed(handle.fileno(), tmp)
        os.replace(tmp, path)
    except OSError as error:
        _remove(tmp)
        raise output_error(path, error) from None
    except BaseException:
        _remove(tmp)
        raise


def _link_unnamed(fd: int, name: str) -> None:
    """Give the unnamed file behind `fd` a name: linkat(2) with AT_SYMLINK_FOLLOW through
    /proc/self/fd (os.link takes that route only when given a directory descriptor)."""
    root = os.open("/", os.O_RDONLY)
    try:
        os.link(f"/proc/self/fd/{fd}", name, src_dir_fd=root, follow_symlinks=True)
    finally:
        os.close(root)


def _remove(tmp) -> None:
    if tmp is not None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def write_text_atomic(path, text: str) -> None:
    """Write text to a temporary file beside `path`, then rename it over `path`."""
    _atomic_write(path, lambda handle: handle.write(text))


def write_bytes_atomic(path, data: bytes) -> None:
    """Write bytes (a PNG, say) to a temporary file beside `path`, then rename it over `path`."""
    _atomic_write(path, lambda handle: handle.write(data), binary=True)


def write_json_atomic(path, document) -> None:
    """Strict JSON (`json_text`) written atomically."""
    write_text_atomic(path, json_text(document))


def write_csv_atomic(path, frame, float_format: str | None = None) -> None:
    """Write a table atomically; without float_format every value round-trips exactly."""
    _atomic_write(path, lambda handle: frame.to_csv(handle, index=False, float_format=float_format))


def existing_file(path, what: str = "a CSV file") -> Path:
    """`path` as a Path, or InputError when it does not exist or is a folder."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected {what}")
    return path


def read_json(path, what: str = "JSON file"):
    """The parsed JSON of a file, or InputError naming the file and what is wrong with it."""
    path = existing_file(path, f"a {what}")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid {what} ({exc})") from None


def sha256_file(path, chunk_bytes: int = 1 << 20) -> str:
    """The SHA-256 of a file's bytes, as hex: what a result records of its input."""
    digest = hashlib.sha256()
    with open(existing_file(path, "a file"), "rb") as handle:
        for block in iter(lambda: handle.read(chunk_bytes), b""):
            digest.update(block)
    return digest.hexdigest()
