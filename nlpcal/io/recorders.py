"""Logs in the formats of the tools people record with, recognised by their content.

- MotionCal serial captures, `Raw:` lines (`nlpcal.io.motioncal`), the field in MotionCal's
  counts of 0.1 uT;
- MATLAB .mat files, v5 and v7.3 (`nlpcal.io.matlab`), the variable named by `--variable` or
  detected;
- ArduPilot DataFlash .bin logs (`nlpcal.io.dataflash`), the compass chosen by `--instance`;
- geomagnetic observatory data, IAGA-2002 text (`nlpcal.io.iaga2002`) and INTERMAGNET ImagCDF
  (`nlpcal.io.imagcdf`), with their header kept (`nlpcal.io.observatory.Observatory`);
- ROS `sensor_msgs/MagneticField` exported to CSV (`rostopic echo -p`, rosbag-to-CSV tools):
  columns `field.magnetic_field.x` (ROS 1) or `magnetic_field.x` (ROS 2 tools), in tesla as the
  message definition fixes (`declared_unit`); read as any CSV, only the unit comes from here;
- phyphox exports ("Magnetic field x (µT)", comma, tab or semicolon with a decimal comma) are
  plain delimited text whose names carry their unit (`nlpcal.units`).

`read_recorded` reads the first four, with the field columns and unit the format fixes (which
`nlpcal.io.tables.read_table` keeps in its `Table`); every other file is left to the delimited
text reader.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import pandas as pd

from ..errors import InputError
from . import dataflash, motioncal, sources
from .dataflash import is_dataflash, read_dataflash
from .iaga2002 import is_iaga2002, read_iaga2002
from .imagcdf import is_imagcdf, read_imagcdf
from .layout import head_bytes
from .matlab import is_mat, read_mat
from .motioncal import is_capture, read_capture
from .observatory import Observatory

#: What reads each recorded format (`Log.engine`), for messages and result documents.
ENGINES = {
    "motioncal": "MotionCal line reader",
    "mat": "scipy/h5py MATLAB reader",
    "dataflash": "pymavlink DFReader",
    "iaga2002": "IAGA-2002 reader",
    "imagcdf": "cdflib ImagCDF reader",
}
#: What each recorded format is, for messages.
NAMES = {
    "motioncal": "a MotionCal capture",
    "mat": "a MATLAB .mat file",
    "dataflash": "an ArduPilot DataFlash log",
    "iaga2002": "an IAGA-2002 observatory file",
    "imagcdf": "an INTERMAGNET ImagCDF file",
}
#: What the reading options apply to, for messages.
OPTION_FORMATS = {
    "--variable": "MATLAB .mat files",
    "--instance": "ArduPilot DataFlash .bin logs",
}
#: ROS sensor_msgs/MagneticField columns: `field.magnetic_field.x` of `rostopic echo -p`,
#: `magnetic_field.x` of ROS 2 exports (a topic or message name may precede them).
_ROS_FIELD = re.compile(r"(^|[./])(field\.)?magnetic_field\.[xyz]$")
#: The unit of sensor_msgs/MagneticField: "Measurement of the Magnetic Field vector at a specific
#: location in Tesla" (its message definition).
ROS_UNIT = "T"


def kind(head: bytes) -> str | None:
    """The recorded format the start of a file shows ("motioncal", "mat", "dataflash",
    "iaga2002", "imagcdf"), or None for delimited text (and everything else)."""
    if is_mat(head):
        return "mat"
    if is_dataflash(head):
        return "dataflash"
    if is_capture(head):
        return "motioncal"
    return _observatory_kind(head)


#: The observatory formats: their test and reader, (name, source) -> (frame, field columns,
#: notes, Observatory).
OBSERVATORY = {"iaga2002": (is_iaga2002, read_iaga2002), "imagcdf": (is_imagcdf, read_imagcdf)}


def _observatory_kind(head: bytes) -> str | None:
    return next((name for name, (test, _) in OBSERVATORY.items() if test(head)), None)


@dataclass
class Recorded:
    """A log read from a recorded format.

    frame : its columns. field_columns : the field columns the format fixes (None: recognised
    from the names). field_unit : the unit the format fixes, or None. engine : what read it.
    notes : what the reader decided, for the user to read. observatory : the header of an
    observatory file (station, sensor, units, terms of use), else None.
    """

    frame: pd.DataFrame
    field_columns: list | None
    field_unit: str | None
    engine: str
    notes: list = field(default_factory=list)
    observatory: Observatory | None = None


def is_recorded(path) -> bool:
    """Whether a log named by `path` (a file, a glob pattern or a folder; not stdin) is, or
    holds, a file in a recorded format read whole (a MotionCal capture, a .mat file, a DataFlash
    log)."""
    text = str(path)
    if text == "-":
        return False
    if sources.is_pattern(text):
        return any(is_recorded(item) for item in sources.log_paths(text))
    return os.path.isfile(text) and kind(head_bytes(text)) is not None


def refuse_streaming(name: str, source) -> None:
    """InputError when a file that is read whole (a recorded format) is to be read in chunks
    (--low-memory on a pattern) or blocks (--scheduler)."""
    found = kind(head_bytes(source))
    if found is not None:
        raise InputError(
            f"{name} is {NAMES[found]}, which nlpcal reads whole, not in chunks or blocks; "
            f"drop --low-memory or --scheduler"
        )


def read_recorded(name: str, source, *, variable=None, instance=None) -> Recorded | None:
    """A MotionCal capture, .mat file or DataFlash log (a path, or the bytes of stdin), or None
    when the file is none of those; `variable` and `instance` choose within a .mat file and a
    DataFlash log and are refused for other files."""
    found = kind(head_bytes(source))
    check_options(name, found, variable=variable, instance=instance)
    if found is None:
        return None
    columns: list | None
    unit: str | None
    if found in OBSERVATORY:
        frame, columns, notes, record = OBSERVATORY[found][1](name, source)
        return Recorded(frame, columns, "nT" if columns else None, ENGINES[found], notes, record)
    if found == "motioncal":
        frame, notes = read_capture(name, _bytes(source))
        columns, unit = motioncal.FIELD_COLUMNS, motioncal.FIELD_UNIT
    elif found == "mat":
        frame, columns, notes = read_mat(name, source, variable)
        unit = None
    else:
        frame, notes = read_dataflash(name, source, instance)
        columns, unit = dataflash.FIELD_COLUMNS, dataflash.FIELD_UNIT
    return Recorded(frame, columns, unit, ENGINES[found], notes)


def check_options(name: str, found: str | None, *, variable=None, instance=None) -> None:
    """InputError when --variable or --instance is given for a file they do not apply to."""
    for flag, value, applies in (
        ("--variable", variable, "mat"),
        ("--instance", instance, "dataflash"),
    ):
        if value is not None and found != applies:
            raise InputError(
                f"{flag} applies to {OPTION_FORMATS[flag]}, and {name} is not one; leave it out"
            )


def _bytes(source) -> bytes:
    if isinstance(source, (bytes, bytearray)):
        return bytes(source)
    with open(source, "rb") as handle:
        return handle.read()


def declared_unit(columns, notes: list | None = None) -> str | None:
    """The unit a recorded format fixes for field columns of these names: tesla for ROS
    `sensor_msgs/MagneticField` columns (said in `notes`), else None."""
    names = [str(c).strip() for c in columns]
    prefixes = {_ROS_FIELD.sub("", name) for name in names}
    axes = [name[-1:] for name in names]
    if (
        all(_ROS_FIELD.search(name) for name in names)
        and len(prefixes) == 1
        and axes == ["x", "y", "z"]
    ):
        if notes is not None:
            notes.append(
                f"the field columns ({', '.join(names)}) are a ROS sensor_msgs/MagneticField, "
                f"in tesla"
            )
        return ROS_UNIT
    return None
