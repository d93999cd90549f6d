"""MotionCal serial captures: the `Raw:` lines a Teensy or Arduino sketch prints for MotionCal.

Each reading is one line `Raw:ax,ay,az,gx,gy,gz,mx,my,mz`: nine signed 16-bit integer counts,
accelerometer, gyroscope, magnetometer (MotionCal's `ascii_parse` in serialdata.c, which hands
`data[6..8]` to its magnetometer fit in rawdata.c). MotionCal reads the magnetometer counts at
0.1 uT each (`#define UT_PER_COUNT 0.1F` in imuread.h, PaulStoffregen/MotionCal), and the sketches
written for it scale their sensors to that: one count is 0.1 uT = 1 mG = 100 nT, the unit the
format fixes here. Lines of other kinds (`Uni:` readings in physical units, `Cal1:`/`Cal2:`
calibrations sent back to the board, `Ori:` orientations) and lines cut by the start or end of a
capture are left out and counted in a note.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

from ..errors import InputError

#: The columns of a `Raw:` line, in order: accelerometer, gyroscope, magnetometer counts.
COLUMNS = ("ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz")
#: The magnetometer's columns.
FIELD_COLUMNS = ["mx", "my", "mz"]
#: The unit of one magnetometer count, UT_PER_COUNT = 0.1 uT in MotionCal's imuread.h.
FIELD_UNIT = "mG"
#: The line kinds MotionCal's serial protocol has besides `Raw:`.
OTHER_KINDS = ("Uni:", "Cal1:", "Cal2:", "Ori:")

_RAW = re.compile(rb"^\s*Raw:", re.M)
_COUNTS = re.compile(r"^-?\d{1,5}$")
#: The range of a signed 16-bit count.
INT16 = (-32768, 32767)


def is_capture(head: bytes) -> bool:
    """Whether the start of a file holds MotionCal `Raw:` lines."""
    return bool(_RAW.search(head))


def raw_counts(line: str) -> list | None:
    """The nine counts of one `Raw:` line (stripped, starting with "Raw:"), or None for a line
    cut short or malformed: not nine signed 16-bit integers."""
    cells = line[4:].split(",")
    if len(cells) != len(COLUMNS) or not all(_COUNTS.match(c.strip()) for c in cells):
        return None
    counts = [int(c) for c in cells]
    if min(counts) < INT16[0] or max(counts) > INT16[1]:
        return None
    return counts


def read_capture(name: str, data: bytes) -> tuple:
    """(frame of the nine count columns, notes) of a MotionCal capture's bytes."""
    rows: list = []
    other = cut = 0
    for line in data.decode("latin-1").splitlines():
        line = line.strip()
        if not line:
            continue
        if not line.startswith("Raw:"):
            other += 1
            continue
        counts = raw_counts(line)
        if counts is None:
            cut += 1
            continue
        rows.append(counts)
    if not rows:
        raise InputError(
            f"{name}: a MotionCal capture without one complete Raw: line (nine integers "
            f"ax,ay,az,gx,gy,gz,mx,my,mz); capture the sketch's output for longer"
        )
    notes = [
        f"{name}: MotionCal capture, {len(rows)} Raw: lines; the field is mx, my, mz in counts "
        f"of 0.1 uT (1 mG), MotionCal's scale"
    ]
    if other:
        notes.append(f"{other} line(s) other than Raw: left out ({', '.join(OTHER_KINDS)} ...)")
    if cut:
        notes.append(f"{cut} incomplete or malformed Raw: line(s) left out")
    frame = pd.DataFrame(np.asarray(rows, dtype=np.int64), columns=list(COLUMNS))
    return frame, notes
