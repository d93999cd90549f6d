"""ArduPilot DataFlash `.bin` logs: the compass messages, through pymavlink's DFReader.

A DataFlash log is a stream of messages, each `0xA3 0x95 TYPE` and a body laid out by an earlier
FMT message (type 128) of the log itself. The compasses log `MAG` messages: in current firmware
one per compass with its 0-based instance in the field `I`; in older firmware `MAG`, `MAG2` and
`MAG3` for the first, second and third compass. MagX, MagY and MagZ are in milligauss (the unit
the format fixes: 1 mG = 100 nT), as the vehicle used them: with its compass calibration of the
time applied (OfsX, OfsY, OfsZ are those offsets; they come along as columns); TimeUS is the
log's time since boot [us]. pymavlink is optional (`pip install 'nlpcal[ardupilot]'`).
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile

import pandas as pd

from ..errors import InputError

INSTALL = "reading an ArduPilot DataFlash .bin log needs pymavlink: pip install 'nlpcal[ardupilot]'"
#: The start of every DataFlash log: the header bytes and the type of its first FMT message.
MAGIC = b"\xa3\x95\x80"
#: The compass messages and the instance each stands for when it has no `I` field.
MESSAGES = {"MAG": 0, "MAG2": 1, "MAG3": 2}
#: The unit of MagX, MagY, MagZ.
FIELD_UNIT = "mG"
FIELD_COLUMNS = ["MagX", "MagY", "MagZ"]
#: Columns read from every compass message when present.
COLUMNS = ("TimeUS", "MagX", "MagY", "MagZ", "OfsX", "OfsY", "OfsZ")


def is_dataflash(head: bytes) -> bool:
    return head.startswith(MAGIC)


def _messages(path) -> list:
    """(instance, row of COLUMNS) of every compass message of a log file."""
    try:
        from pymavlink import DFReader
    except ImportError:
        raise InputError(INSTALL) from None
    found = []
    chatter = io.StringIO()  # DFReader prints what it skips; not for nlpcal's streams
    with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
        reader = DFReader.DFReader_binary(str(path))
        try:
            while True:
                message = reader.recv_match(type=list(MESSAGES))
                if message is None:
                    break
                kind = message.get_type()
                instance = int(getattr(message, "I", MESSAGES[kind]))
                found.append((instance, [getattr(message, name, None) for name in COLUMNS]))
        finally:
            reader.filehandle.close()
    return found


def read_dataflash(name: str, source, instance: int | None = None) -> tuple:
    """(frame of COLUMNS, notes) of one compass of a DataFlash log (a path or its bytes).

    instance : the compass, 0-based like the `I` field; needed when the log has several.
    """
    spool = None
    if isinstance(source, (bytes, bytearray)):  # DFReader maps a file
        spool = tempfile.NamedTemporaryFile(suffix=".bin", delete=False)
        spool.write(source)
        spool.close()
        source = spool.name
    try:
        messages = _messages(source)
    except InputError:
        raise
    except Exception as exc:  # DFReader raises many kinds on a damaged log
        text = " ".join(str(exc).split())[:160] or type(exc).__name__
        raise InputError(f"{name}: cannot be read as an ArduPilot DataFlash log ({text})") from None
    finally:
        if spool is not None:
            os.unlink(spool.name)
    present = sorted({k for k, _ in messages})
    if not present:
        raise InputError(f"{name}: an ArduPilot DataFlash log without compass (MAG) messages")
    listing = ", ".join(map(str, present))
    if instance is None and len(present) > 1:
        raise InputError(
            f"{name} holds {len(present)} compasses (MAG instances {listing}); pass --instance "
            f"N (0-based, as the log's I field) to choose one, for example --instance "
            f"{present[0]}"
        )
    chosen = present[0] if instance is None else instance
    if chosen not in present:
        raise InputError(
            f"{name}: no compass of instance {chosen} (MAG instances {listing}); pass "
            f"--instance with one of those"
        )
    rows = [row for k, row in messages if k == chosen]
    frame = pd.DataFrame(rows, columns=list(COLUMNS)).dropna(axis=1, how="all")
    notes = [
        f"{name}: ArduPilot DataFlash log, compass instance {chosen} ({len(rows)} MAG "
        f"messages; MagX, MagY, MagZ in mG with the vehicle's offsets applied)"
    ]
    return frame, notes
