"""What wrote each output of a batch folder: the options of the run, so that a rerun reuses an
output only when it would be made again the same way.

`DIR/batch.json` maps each output's file name to a digest of the options of the run that wrote
it (the reading options, the calibration or correction options, and which command):

    {"format": "nlpcal-batch", "format_version": 1,
     "outputs": {"sensor_0.params.json": "3f1c...", ...}}

A rerun skips a log when its output is newer than the log (and than its parameters and drift
files) and was written from that log (its resolved path is part of the digest) with the same
options; otherwise it is done again. Options that do not change a result (threads, the memory
map of --low-memory) are left out of the digest. A log whose run fails loses its old output, so
that the folder never holds a result its summary disowns. Before a run starts, the outputs it
is about to redo lose their entries (the file is saved then), and the file is saved again when
the run ends, also when it is interrupted: an output rewritten by a run killed midway has no
entry, and is made again.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from pathlib import Path

from ..errors import InputError
from ..io import read_json, write_json_atomic
from ..io.files import passes_through
from ..io.strict import strict

FILE = "batch.json"
FORMAT = "nlpcal-batch"
FORMAT_VERSION = 1


#: Options that do not change a result: left out of the digest.
NEUTRAL = ("threads", "low_memory")


def digest(command: str, log, **options) -> str:
    """A digest of a command, the log it reads (its resolved path) and its options (dicts of
    JSON-able values; others by their text), less the NEUTRAL ones."""
    settled = {
        name: {k: v for k, v in value.items() if k not in NEUTRAL}
        if isinstance(value, dict)
        else value
        for name, value in options.items()
    }
    document = {"command": command, "log": str(Path(log).resolve()), **settled}
    text = json.dumps(document, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


class Ledger:
    """The record of an output folder's outputs and the options that wrote them."""

    def __init__(self, out_dir: Path):
        self.path = Path(out_dir) / FILE
        self.outputs: dict = {}
        self.note = ""
        if self.path.exists():
            try:
                self.outputs = _outputs(read_json(self.path))
            except InputError as exc:
                said = str(exc) if str(exc).startswith(str(self.path)) else f"{self.path}: {exc}"
                self.note = f"{said}; every log is done again"

    def current(self, output: Path, key: str, *inputs) -> bool:
        """Whether `output` was written with the options `key` and is newer than every input."""
        if self.outputs.get(Path(output).name) != key:
            return False
        try:
            written = Path(output).stat().st_mtime
            return all(written > Path(p).stat().st_mtime for p in inputs if p)
        except OSError:
            return False

    def written(self, output: Path, key: str) -> None:
        self.outputs[Path(output).name] = key

    def redoing(self, outputs) -> None:
        """Forget the outputs a run is about to redo, and save: until each is written again it
        is not current, whatever happens to the run."""
        for output in outputs:
            self.outputs.pop(Path(output).name, None)
        self.save()

    def failed(self, output: Path) -> None:
        """Forget an output whose log failed now, and remove the file an earlier run left (a
        character device or a FIFO in its place holds nothing and stays, as does a folder)."""
        self.outputs.pop(Path(output).name, None)
        with contextlib.suppress(FileNotFoundError, InputError):
            if not passes_through(output):
                Path(output).unlink()

    def document(self) -> dict:
        document = {"format": FORMAT, "format_version": FORMAT_VERSION, "outputs": self.outputs}
        return strict(document, "the batch ledger")

    def save(self) -> None:
        write_json_atomic(self.path, self.document())


def _outputs(document) -> dict:
    """The outputs of a ledger document, checked: file names to hexadecimal digests."""
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        raise InputError(f'not an nlpcal batch record ("format": "{FORMAT}")')
    if document.get("format_version") != FORMAT_VERSION:
        raise InputError(f"batch record version {document.get('format_version')!r} unknown")
    outputs = document.get("outputs")
    if not isinstance(outputs, dict) or not all(
        isinstance(name, str)
        and "/" not in name
        and isinstance(key, str)
        and len(key) == 64
        and all(c in "0123456789abcdef" for c in key)
        for name, key in outputs.items()
    ):
        raise InputError("the batch record's outputs must map file names to SHA-256 digests")
    return dict(outputs)
