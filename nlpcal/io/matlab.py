"""MATLAB .mat files: version 5 (and its compressed form, 7) through scipy, 7.3 (HDF5) through h5py.

A .mat file holds named variables. The field is one of them: the one `--variable NAME` names,
else the only numeric array of N x 3 (or 3 x N) values with N > 3, else the only such array whose
name says it is magnetic ("mag", "SENSmag", "B_uT"), else the only struct whose fields name a
magnetometer's axes (mx/my/mz, x/y/z, ...). Vectors of N values (times, temperatures) come along
as further columns. The field columns are called VAR_x, VAR_y, VAR_z; a unit the variable's name
carries (mag_uT) is kept in them (mag_x_uT), so that the reader takes it from the names. Both
readers are optional (`pip install 'nlpcal[mat]'`).
"""

from __future__ import annotations

import io
import warnings

import numpy as np
import pandas as pd

from .. import units
from ..errors import InputError

INSTALL = {
    "scipy": "reading a MATLAB .mat file needs scipy: pip install 'nlpcal[mat]'",
    "h5py": "reading a MATLAB v7.3 .mat file needs h5py: pip install 'nlpcal[mat]'",
}
#: Where a MATLAB v7.3 file's HDF5 part starts (after its 512-byte text header).
HDF5_AT = 512
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
AXES = ("x", "y", "z")


def is_mat(head: bytes) -> bool:
    """Whether the start of a file is a MATLAB 5, 7 or 7.3 header ("MATLAB 5.0 MAT-file, ..."),
    not a text log whose first column is called MATLABtime."""
    return head.startswith(b"MATLAB") and b"MAT-file" in head[:116]


def _load_v5(name: str, data) -> dict:
    try:
        from scipy.io import loadmat
    except ImportError:
        raise InputError(INSTALL["scipy"]) from None
    try:
        with warnings.catch_warnings():  # opaque objects, repeated names: not the field
            warnings.simplefilter("ignore")
            return loadmat(data, simplify_cells=True)
    except Exception as exc:  # scipy raises many kinds on a damaged file
        raise InputError(f"{name}: cannot be read as a MATLAB .mat file ({_first(exc)})") from None


def _load_v73(name: str, data) -> dict:
    try:
        import h5py
    except ImportError:
        raise InputError(INSTALL["h5py"]) from None
    try:
        with h5py.File(data, "r") as handle:
            return _group(handle, h5py)
    except Exception as exc:
        raise InputError(
            f"{name}: cannot be read as a MATLAB v7.3 .mat file ({_first(exc)})"
        ) from None


def _group(group, h5py) -> dict:
    """An HDF5 group of a v7.3 file as MATLAB sees it: datasets transposed (MATLAB stores
    column-major), structs (groups) as dicts; references, text and cells left out."""
    found: dict = {}
    for key, item in group.items():
        if key.startswith("#"):
            continue
        if isinstance(item, h5py.Group):
            found[key] = _group(item, h5py)
        elif isinstance(item, h5py.Dataset) and _numeric(item.dtype):
            if item.attrs.get("MATLAB_class", b"") in (b"char", "char", b"logical", "logical"):
                continue
            found[key] = np.asarray(item[()]).T
    return found


def _first(exc: Exception) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:160]


def _numeric(dtype) -> bool:
    return np.issubdtype(dtype, np.number) and not np.issubdtype(dtype, np.bool_)


def _triple(value) -> np.ndarray | None:
    """An N x 3 or 3 x N numeric array (N > 3) as N x 3 floats, else None."""
    if not isinstance(value, np.ndarray) or not _numeric(value.dtype):
        return None
    value = np.squeeze(value)
    if value.ndim != 2:
        return None
    if value.shape[1] == 3 and value.shape[0] > 3:
        return value.astype(float)
    if value.shape[0] == 3 and value.shape[1] > 3:
        return value.T.astype(float)
    return None


def _vector(value, n: int) -> np.ndarray | None:
    if isinstance(value, np.ndarray) and _numeric(value.dtype):
        value = np.squeeze(value)
        if value.shape == (n,):
            return value.astype(float)
    return None


def axis_names(variable: str) -> list:
    """The field columns of a variable: VAR_x ..., its unit kept last (mag_uT: mag_x_uT ...)."""
    if units.unit_in_name(variable) and "_" in variable:
        stem, unit = variable.rsplit("_", 1)
        return [f"{stem}_{axis}_{unit}" for axis in AXES]
    return [f"{variable}_{axis}" for axis in AXES]


def _columns(variables: dict, n: int) -> dict:
    """The vectors of N values among `variables`, by name."""
    found = {}
    for key, value in variables.items():
        vector = _vector(value, n)
        if vector is not None:
            found[key] = vector
    return found


def _struct_field(variable: str, struct: dict) -> tuple | None:
    """(table, whether its first three columns are the field) of a struct whose fields hold a
    magnetometer's axes (mx, my, mz ...) or one N x 3 array, else None."""
    triples = {key: t for key, t in ((k, _triple(v)) for k, v in struct.items()) if t is not None}
    if len(triples) == 1:
        key, triple = next(iter(triples.items()))
        return _table(f"{variable}.{key}", triple, struct), True
    lengths = [np.squeeze(v).shape[0] for v in struct.values() if _vector_like(v)]
    if not lengths:
        return None
    n = max(set(lengths), key=lengths.count)
    frame = pd.DataFrame(_columns(struct, n))
    recognised = [
        template
        for template in units.axis_templates(list(frame.columns))
        if units.is_axis_template(template, units.MAGNETIC_PREFIXES, units.FIELD_SUFFIXES)
    ]
    return (frame, False) if len(recognised) == 1 else None


def _vector_like(value) -> bool:
    return isinstance(value, np.ndarray) and _numeric(value.dtype) and np.squeeze(value).ndim == 1


def _magnetic(name: str) -> bool:
    low = name.lower()
    return "mag" in low or units.clean(low.split("_")[0]) in ("b", "h", "field", "compass")


def _chosen(name: str, variables: dict, variable: str | None) -> tuple:
    """(variable name, its table, whether the field columns are its own VAR_x ...)."""
    listing = ", ".join(f"{key} {_shape(value)}" for key, value in variables.items()) or "nothing"
    if variable is not None:
        if variable not in variables:
            raise InputError(
                f"{name}: no variable {variable!r}; the file holds {listing}; pass --variable "
                f"with one of those names"
            )
        value = variables[variable]
        triple = _triple(value)
        if triple is not None:
            return variable, _table(variable, triple, variables), True
        found = _struct_field(variable, value) if isinstance(value, dict) else None
        if found is None:
            raise InputError(
                f"{name}: variable {variable!r} is {_shape(value)}, not an N x 3 numeric array "
                f"or a struct with magnetometer fields"
            )
        return (variable, *found)
    arrays = {key: t for key, t in ((k, _triple(v)) for k, v in variables.items()) if t is not None}
    if len(arrays) > 1:
        arrays = {key: t for key, t in arrays.items() if _magnetic(key)} or arrays
    if len(arrays) == 1:
        key, triple = next(iter(arrays.items()))
        return key, _table(key, triple, variables), True
    if arrays:
        raise InputError(
            f"{name}: several N x 3 arrays could be the field ({', '.join(arrays)}); pass "
            f"--variable NAME, for example --variable {next(iter(arrays))}"
        )
    structs = {
        key: found
        for key, found in (
            (k, _struct_field(k, v)) for k, v in variables.items() if isinstance(v, dict)
        )
        if found is not None
    }
    if len(structs) == 1:
        key, found = next(iter(structs.items()))
        return (key, *found)
    raise InputError(
        f"{name}: no variable is an N x 3 numeric array or a struct with magnetometer fields "
        f"({listing}); pass --variable NAME"
        + (f", for example --variable {next(iter(structs))}" if structs else "")
    )


def _shape(value) -> str:
    if isinstance(value, dict):
        return "(struct)"
    if isinstance(value, np.ndarray):
        return f"({' x '.join(map(str, value.shape))} {value.dtype})"
    return f"({type(value).__name__})"


def _table(variable: str, triple: np.ndarray, variables: dict) -> pd.DataFrame:
    frame = pd.DataFrame(triple, columns=axis_names(variable))
    more = {k: v for k, v in _columns(variables, triple.shape[0]).items() if k not in frame}
    return frame.assign(**more)


def read_mat(name: str, source, variable: str | None = None) -> tuple:
    """(frame, field columns or None to detect them by name, notes) of a .mat file.

    source : a path or the file's bytes.
    """
    if isinstance(source, (bytes, bytearray)):
        head, data = bytes(source[: HDF5_AT + 8]), io.BytesIO(source)
    else:
        with open(source, "rb") as handle:
            head = handle.read(HDF5_AT + 8)
        data = source
    v73 = head[HDF5_AT : HDF5_AT + 8] == HDF5_MAGIC
    loaded = _load_v73(name, data) if v73 else _load_v5(name, data)
    variables = {k: v for k, v in loaded.items() if not k.startswith("__")}
    key, frame, own = _chosen(name, variables, variable)
    version = "v7.3 (HDF5, h5py)" if v73 else "v5 (scipy)"
    notes = [f"{name}: MATLAB {version}, the field from variable {key!r} ({frame.shape[0]} rows)"]
    return frame, list(frame.columns[:3]) if own else None, notes
