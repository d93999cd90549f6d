"""Reading logs and documents, writing outputs: the one home of nlpcal's file handling.

`files` writes atomically and strictly (no NaN in JSON), `tables` reads CSV tables and picks their
columns, `logs` turns a table into samples, reference and extra columns in base units.
"""

from .files import (
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
from .logs import Log, SensorLog, read_columns, read_log, read_sensor_log
from .tables import (
    column_name,
    csv_engine,
    csv_to_memmap,
    numeric_columns,
    read_table,
    read_table_header,
    resolve_columns,
)

__all__ = [
    "Log",
    "SensorLog",
    "check_output_path",
    "column_name",
    "csv_engine",
    "csv_to_memmap",
    "json_text",
    "numeric_columns",
    "plain",
    "read_columns",
    "read_json",
    "read_log",
    "read_sensor_log",
    "read_table",
    "read_table_header",
    "resolve_columns",
    "sha256_file",
    "write_bytes_atomic",
    "write_csv_atomic",
    "write_json_atomic",
    "write_text_atomic",
]
