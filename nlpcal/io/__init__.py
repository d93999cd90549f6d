"""Reading logs and documents, writing outputs: the one home of nlpcal's file handling.

`files` writes outputs (files atomically, devices and pipes through, several together) and
strict JSON (no NaN), `layout` detects how a delimited text log is laid out, `tables` reads it
(or, through `recorders`, a MotionCal capture, a MATLAB .mat file or an ArduPilot DataFlash log)
and picks its columns, `rows` screens rows that are not readings, `logs` turns a table into
samples, reference and extra columns in base units, `stream` reads a log in chunks with every
row in its place, `output` writes tables (Parquet or text by the extension, at the precision
the data warrant), `progress` shows how far a long pass has got.
"""

from .files import (
    Outputs,
    check_distinct_outputs,
    check_output_path,
    json_text,
    plain,
    read_json,
    sha256_file,
    write_bytes_atomic,
    write_csv_atomic,
    write_json_atomic,
    write_text_atomic,
)
from .layout import Layout, detect_layout
from .logs import Log, read_columns, read_log
from .mapped import csv_to_memmap
from .output import Precision, is_parquet_output, write_frames, write_table
from .sensors import SensorLog, read_sensor_log
from .tables import (
    Table,
    column_name,
    csv_engine,
    numeric_columns,
    read_table,
    resolve_columns,
)

__all__ = [
    "Layout",
    "Log",
    "Outputs",
    "Precision",
    "SensorLog",
    "Table",
    "check_distinct_outputs",
    "check_output_path",
    "column_name",
    "csv_engine",
    "csv_to_memmap",
    "detect_layout",
    "is_parquet_output",
    "json_text",
    "numeric_columns",
    "plain",
    "read_columns",
    "read_json",
    "read_log",
    "read_sensor_log",
    "read_table",
    "resolve_columns",
    "sha256_file",
    "write_bytes_atomic",
    "write_csv_atomic",
    "write_frames",
    "write_json_atomic",
    "write_table",
    "write_text_atomic",
]
