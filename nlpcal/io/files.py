"""Files: outputs that respect what they write to, strict JSON, and the checks of output paths.

An output that is a file is written to a temporary file beside it and renamed over it at the
end, so a failed or killed run never leaves a half-written file nor replaces an existing one; a
symbolic link keeps pointing at the new file. A character device (/dev/null) or a FIFO is written
through, never replaced. A command's outputs are put in place together (`Outputs`), once all are
complete. JSON written by nlpcal never contains NaN or Infinity: non-finite numbers become null.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import hashlib
import json
import math
import os
import re
import stat
import sys
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from ..errors import InputError, NlpcalError, WriteError


def plain(value):
    """`value` with numpy scalars and arrays turned into Python numbers and lists, and every
    non-finite float into None, so that it serialises as strict JSON."""
    if isinstance(value, Mapping):  # a dict, or a typed record (`nlpcal.results.Record`)
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
    """Fail before any work when an output's folder does not exist, the path is a folder or
    something else no output is written to (`output_target`), or it is one of the `inputs`
    (writing there would replace the data being read)."""
    if not path or str(path) == "-":
        return
    path = Path(path)
    target = output_target(path)
    if target.kind == "replace":  # the folder of the file replaced (a link's target)
        directory = target.path.parent
        if not directory.is_dir():
            raise InputError(f"{path}: the folder {directory} does not exist")
    if target.kind != "replace" or not target.path.exists():
        return
    for source in inputs:
        files = matching_files(source) if source and str(source) != "-" else []
        if any(os.path.samefile(target.path, item) for item in files):
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


#: Whether outputs are written to unnamed files (Linux O_TMPFILE) where the system and the file
#: system have them. False uses the named temporary file of other systems everywhere: the tests set
#: it to check that writer on this system too.
UNNAMED_FILES = True

#: Kinds of file no output is written to, by their `stat.S_IFMT` (folders are refused too).
REFUSED_KINDS = {stat.S_IFBLK: "block device", stat.S_IFSOCK: "socket"}


@dataclass(frozen=True)
class Target:
    """What writing an output path means (`output_target`).

    kind : "replace": `path` (a regular file, a new name, or the file a symbolic link points
        to) is replaced by a complete file renamed over it; "through": `path` (a character
        device or a FIFO) is opened and written; "descriptor": this process's open file `fd`
        (named through /proc: /dev/stdout, /dev/fd/N) is written, as a shell does; "stdout":
        Python's sys.stdout (an output of "-" or None).
    path : the file replaced, or the path opened.
    fd : the descriptor of kind "descriptor".
    mode : the permissions the new file gets: those of the file it replaces, else the usual
        0666 less the umask.
    """

    kind: str
    path: Path
    fd: int = -1
    mode: int = 0o666


def output_target(path) -> Target:
    """How `path` is written (`Target`): "-", "" or None is stdout; a character device (/dev/null)
    or a FIFO, after symbolic links, is written through, never replaced; a regular file or a new
    name is replaced atomically, a symbolic link's target in its place so that the link stays a
    link. A folder, a block device or a socket is InputError."""
    if path is None or str(path) in ("", "-"):
        return Target("stdout", Path("-"))
    path = Path(path)
    fd = _own_descriptor(path)
    if fd is not None:
        return Target("descriptor", path, fd=fd)
    try:
        status = os.stat(path)
    except FileNotFoundError:  # a new file, or the missing file a symbolic link points to
        return Target("replace", Path(os.path.realpath(path)), mode=0o666 & ~_umask())
    except OSError as error:
        raise output_error(path, error) from None
    kind = stat.S_IFMT(status.st_mode)
    if kind in (stat.S_IFCHR, stat.S_IFIFO):
        return Target("through", path)
    if kind == stat.S_IFDIR:
        raise InputError(f"{path}: is a directory, expected a file name")
    if kind in REFUSED_KINDS:
        raise InputError(
            f"{path}: is a {REFUSED_KINDS[kind]}; an output is a file, a character device "
            f"(/dev/null) or a pipe"
        )
    real = Path(os.path.realpath(path))
    with contextlib.suppress(OSError):
        if os.path.samestat(os.stat(real), status):
            return Target("replace", real, mode=stat.S_IMODE(status.st_mode) & 0o777)
    return Target("through", path)  # a file reached by a link its name does not resolve to


def destination(target: Target) -> tuple | None:
    """Where an output of `target` ends, for outputs that would overwrite or interleave each
    other there: stdout and descriptor 1 are one place; None for a character device (/dev/null
    takes any number of outputs)."""
    if target.kind == "stdout" or (target.kind == "descriptor" and target.fd == 1):
        return ("stdout",)
    if target.kind == "descriptor":
        return ("descriptor", target.fd)
    if target.kind == "through":
        status = os.stat(target.path)
        if stat.S_ISCHR(status.st_mode):
            return None
        return ("through", status.st_dev, status.st_ino)
    return ("replace", str(target.path))


def check_distinct_outputs(*paths) -> None:
    """Fail before any work when two of a command's outputs (None or "-": stdout) go to the same
    place (`destination`)."""
    seen: dict = {}
    for path in paths:
        _claim(seen, destination(output_target(path)), path)


def _claim(places: dict, place, path) -> None:
    """Record that the output `path` goes to `place` in `places` (its destinations so far);
    InputError when another output went there already."""
    name = "-" if path is None else str(path)
    if place is not None and place in places:
        raise InputError(
            f"{name}: {places[place]} is written there already; two outputs cannot share one "
            f"destination, so give each its own"
        )
    places.setdefault(place, name)


def passes_through(path) -> bool:
    """Whether an output at `path` is written through (a character device, a FIFO, an open
    descriptor), not replaced; InputError where no output can be written."""
    return output_target(path).kind != "replace"


def _own_descriptor(path: Path) -> int | None:
    """N when `path` names this process's open file N through /proc (/dev/stdout, /dev/fd/N,
    /proc/self/fd/N), directly or through symbolic links; None otherwise."""
    own = re.compile(rf"/proc/{os.getpid()}(/task/\d+)?/fd")
    current = os.path.abspath(path)
    for _ in range(40):  # the links the kernel follows at most
        folder = os.path.realpath(os.path.dirname(current))
        name = os.path.basename(current)
        if own.fullmatch(folder) and name.isdigit():
            return int(name)
        if not os.path.islink(current):
            return None
        current = os.path.join(folder, os.readlink(current))
    return None


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def _unnamed_file(directory: Path):
    """A file descriptor of an unnamed file in `directory` (Linux O_TMPFILE), or None where the
    system or the file system has none (or UNNAMED_FILES is False)."""
    flag = getattr(os, "O_TMPFILE", None)
    if not UNNAMED_FILES or flag is None or not os.path.isdir("/proc/self/fd"):
        return None
    try:
        return os.open(directory, flag | os.O_WRONLY, 0o600)
    except OSError:
        return None


@contextlib.contextmanager
def _writing(name):
    """OSErrors of writing the output `name` as `output_error`; a broken pipe as it is (the
    reader went away: the command line ends quietly)."""
    try:
        yield
    except (BrokenPipeError, NlpcalError):
        raise
    except OSError as error:
        raise output_error(name, error) from None


def _fill(fd: int, write, binary: bool) -> None:
    """Call `write(handle)` on a handle of `fd` (left open) and flush it."""
    handle: IO = (
        os.fdopen(fd, "wb", closefd=False)
        if binary
        else os.fdopen(fd, "w", newline="", closefd=False)
    )
    with handle:
        write(handle)


class _Replacement:
    """An output complete in a temporary file beside the file it replaces, renamed over it by
    `place`. On Linux the temporary file is unnamed (O_TMPFILE), so that a killed run leaves it
    nowhere, and is named only by `complete`, at the commit; elsewhere it is a named file,
    removed by `discard` on any error or interruption (SIGINT, and SIGTERM through the command
    line's handler)."""

    def __init__(self, name, target: Target, write, binary: bool):
        self.name, self.path = name, target.path
        self.fd = -1  # the temporary file while it is open
        self.tmp = ""  # its name, once it has one
        directory = self.path.parent
        try:
            with _writing(name):
                unnamed = _unnamed_file(directory)
                if unnamed is None:
                    self.fd, self.tmp = tempfile.mkstemp(
                        prefix=f".{self.path.name}.", suffix=".tmp", dir=directory
                    )
                else:
                    self.fd = unnamed
                with contextlib.suppress(OSError):  # file systems without permissions
                    os.fchmod(self.fd, target.mode)
                _fill(self.fd, write, binary)
                os.fsync(self.fd)
        except BaseException:
            self.discard()
            raise

    def complete(self) -> None:
        """Give the complete file its temporary name beside its target."""
        with _writing(self.name):
            if not self.tmp:
                tmp = str(self.path.parent / f".{self.path.name}.{os.getpid()}.{id(self):x}.tmp")
                _link_unnamed(self.fd, tmp)
                self.tmp = tmp
            os.close(self.fd)
            self.fd = -1

    def place(self) -> None:
        with _writing(self.name):
            os.replace(self.tmp, self.path)
        self.tmp = ""

    def discard(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
        if self.tmp:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.tmp)
            self.tmp = ""


class _Passage:
    """An output written through at the commit, where nothing can be replaced: a character
    device, a FIFO, an open descriptor, stdout."""

    def __init__(self, name, target: Target, write, binary: bool):
        self.name, self.target, self.write, self.binary = name, target, write, binary

    def complete(self) -> None:
        kind = self.target.kind
        if kind == "stdout":
            sys.stdout.flush()
            self.write(sys.stdout.buffer if self.binary else sys.stdout)
            (sys.stdout.buffer if self.binary else sys.stdout).flush()
            return
        with _writing(self.name):
            sys.stdout.flush()  # what this process wrote before comes first
            if kind == "descriptor":
                fd = os.dup(self.target.fd)
            else:  # as a shell's `>`, less O_CREAT: a device or a FIFO, never a new file
                fd = os.open(self.target.path, os.O_WRONLY | os.O_TRUNC | os.O_NOCTTY)
            try:
                _fill(fd, self.write, self.binary)
            finally:
                os.close(fd)

    def place(self) -> None:
        pass

    def discard(self) -> None:
        pass


class Outputs:
    """Outputs written together: each is complete before any is put in place.

        with Outputs() as outputs:
            outputs.json(args.output, result.to_dict())
            outputs.bytes(args.plot, png)

    Each output is written on its call to a temporary file beside it (`output_target`: files
    are replaced, a symbolic link's target in its place); on leaving the block without an error
    the complete files are named, the outputs written through (devices, FIFOs, stdout) are
    written, and only then is every file renamed into place. An error or an interruption
    anywhere before leaves every output as it was and no temporary file. A path of None or "-"
    is stdout.
    """

    def __init__(self):
        self._pending: list = []
        self._places: dict = {}

    def write(self, path, write, binary: bool = False) -> None:
        """The output `write(handle)` writes, to `path` (a text handle, or binary); InputError
        when another output of the same commit goes to the same place (stdout twice would
        interleave a document and a figure)."""
        target = output_target(path)
        _claim(self._places, destination(target), path)
        kind = _Replacement if target.kind == "replace" else _Passage
        self._pending.append(kind(path, target, write, binary))

    def text(self, path, text: str) -> None:
        self.write(path, lambda handle: handle.write(text))

    def bytes(self, path, data: bytes) -> None:
        """Bytes (a PNG, a Parquet file)."""
        self.write(path, lambda handle: handle.write(data), binary=True)

    def json(self, path, document) -> None:
        """Strict JSON (`json_text`)."""
        self.text(path, json_text(document))

    def csv(self, path, frame, float_format: str | None = None) -> None:
        """A table; without float_format every value round-trips exactly."""
        self.write(
            path, lambda handle: frame.to_csv(handle, index=False, float_format=float_format)
        )

    def commit(self) -> None:
        """Put every output in place (see the class); nothing is left pending."""
        pending, self._pending = self._pending, []
        self._places = {}
        gone = None  # a reader that went away has what it wanted: the files still take place
        try:  # files first: nothing is written through before every file is complete
            for output in sorted(pending, key=lambda output: isinstance(output, _Passage)):
                try:
                    output.complete()
                except BrokenPipeError as error:
                    if not isinstance(output, _Passage):
                        raise
                    gone = error
            for output in pending:
                output.place()
        finally:
            for output in pending:
                output.discard()
        if gone is not None:
            raise gone

    def discard(self) -> None:
        """Forget every pending output: the existing ones stay as they are."""
        pending, self._pending = self._pending, []
        self._places = {}
        for output in pending:
            output.discard()

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, kind, error, trace) -> None:
        if kind is None:
            self.commit()
        else:
            self.discard()


def _link_unnamed(fd: int, name: str) -> None:
    """Give the unnamed file behind `fd` a name: linkat(2) with AT_SYMLINK_FOLLOW through
    /proc/self/fd (os.link takes that route only when given a directory descriptor)."""
    root = os.open("/", os.O_RDONLY)
    try:
        os.link(f"/proc/self/fd/{fd}", name, src_dir_fd=root, follow_symlinks=True)
    finally:
        os.close(root)


def write_text_atomic(path, text: str) -> None:
    """Text to `path` (`Outputs`: a file replaced atomically, a device or FIFO written through,
    stdout for None or "-")."""
    with Outputs() as outputs:
        outputs.text(path, text)


def write_bytes_atomic(path, data: bytes) -> None:
    """Bytes (a PNG, say) to `path`, as `write_text_atomic`."""
    with Outputs() as outputs:
        outputs.bytes(path, data)


def write_json_atomic(path, document) -> None:
    """Strict JSON (`json_text`) to `path`, as `write_text_atomic`."""
    with Outputs() as outputs:
        outputs.json(path, document)


def write_csv_atomic(path, frame, float_format: str | None = None) -> None:
    """A table to `path`, as `write_text_atomic`; without float_format every value round-trips
    exactly."""
    with Outputs() as outputs:
        outputs.csv(path, frame, float_format)


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
