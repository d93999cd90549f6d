"""Units of the field and of the specific force, and the units that column names carry.

nlpcal computes in base units: the magnetic field in nT (or in the log's own counts, "raw"), the
specific force of an accelerometer in g (standard gravity, 9.80665 m/s2). Every reader and every
verb of the library converts at the door with the functions here, so a Python caller with samples
in uT and a reference in nT passes both units and gets nT results.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .passes import LazySamples

#: Field units and their size in nT. "raw" keeps the log's own unit (counts, arbitrary units).
FIELD_UNITS_NT = {"nT": 1.0, "uT": 1e3, "mT": 1e6, "mG": 1e2, "G": 1e5, "T": 1e9, "raw": 1.0}

#: Accelerometer units and their size in g (standard gravity 9.80665 m/s2).
ACC_UNITS_G = {"g": 1.0, "mg": 1e-3, "m/s2": 1.0 / 9.80665}

#: Unit suffixes of field column names, and the unit they suggest ("raw" for counts).
FIELD_SUFFIXES = {
    "nt": "nT",
    "ut": "uT",
    "mt": "mT",
    "mg": "mG",
    "gauss": "G",
    "g": "G",
    "t": "T",
    "counts": "raw",
    "count": "raw",
    "lsb": "raw",
    "raw": "raw",
}

#: Unit suffixes of accelerometer column names.
ACC_SUFFIXES = {"g": "g", "mg": "mg", "mps2": "m/s2", "ms2": "m/s2", "m/s2": "m/s2"}


def clean(text: str) -> str:
    """Letters and digits of `text` only (spaces, brackets and punctuation dropped)."""
    return "".join(ch for ch in text if ch.isalnum())


def field_factor(unit: str) -> float:
    """Size of one `unit` of field in nT (1 for "raw"). [nT/unit]"""
    if unit not in FIELD_UNITS_NT:
        raise InputError(
            f"unknown field unit {unit!r}; expected one of {', '.join(FIELD_UNITS_NT)}"
        )
    return FIELD_UNITS_NT[unit]


def acc_factor(unit: str) -> float:
    """Size of one `unit` of specific force in g. [g/unit]"""
    if unit not in ACC_UNITS_G:
        raise InputError(
            f"unknown accelerometer unit {unit!r}; expected one of {', '.join(ACC_UNITS_G)}"
        )
    return ACC_UNITS_G[unit]


def base_unit(unit: str) -> str:
    """The unit nlpcal computes in for data given in `unit`: "nT", or "raw" for counts."""
    field_factor(unit)
    return "raw" if unit == "raw" else "nT"


def to_base(values, unit: str):
    """Field values (a number, an array or None) from `unit` to the base unit. [nT or raw]"""
    if values is None:
        return None
    factor = field_factor(unit)
    if np.ndim(values) == 0:
        return float(values) * factor
    if isinstance(values, LazySamples):  # a Dask log: scaled block by block in each pass
        return values if factor == 1.0 else values * factor
    values = np.asarray(values, dtype=float)
    return values if factor == 1.0 else values * factor  # base units pass through uncopied


def from_base(values, unit: str):
    """Field values from the base unit back to `unit`."""
    factor = field_factor(unit)
    if np.ndim(values) == 0:
        return float(values) / factor
    values = np.asarray(values, dtype=float)
    return values if factor == 1.0 else values / factor


def check_compatible(unit: str, other: str, what: str = "the reference") -> None:
    """Counts and field units do not mix: both "raw" or neither."""
    if (unit == "raw") != (other == "raw"):
        raise InputError(
            f"{what} is in {other!r} but the samples are in {unit!r}; counts (raw) "
            f"and field units cannot be converted into each other"
        )


def unit_in_name(name: str, suffixes=FIELD_SUFFIXES):
    """The unit a single column name carries ("proton_nT", "F (nT)", "field_uT"), or None."""
    low = name.lower().strip()
    if low.endswith(")") and "(" in low:
        return suffixes.get(clean(low[low.rindex("(") + 1 :]))
    if "_" in low:
        return suffixes.get(clean(low.rsplit("_", 1)[1]))
    return None


def axis_templates(columns):
    """Group column names that differ only in one letter x, y, z: (prefix, suffix) -> (X, Y, Z)."""
    groups: dict = {}
    for name in columns:
        low = name.lower()
        for i, ch in enumerate(low):
            if ch in "xyz":
                groups.setdefault((low[:i], low[i + 1 :]), {})[ch] = name
    return {t: (g["x"], g["y"], g["z"]) for t, g in groups.items() if len(g) == 3}


#: Prefixes of names recognised as magnetometer axes once the axis letter, spaces and
#: punctuation are taken out (bx, mag_x, mx_uT, "Magnetometer X (uT)", x ...).
MAGNETIC_PREFIXES = (
    "",
    "b",
    "m",
    "mag",
    "magn",
    "magnetometer",
    "magnetic",
    "h",
    "field",
    "compass",
    "b1",
)
#: Prefixes of accelerometer axes (ax, acc_x, accel_x, "Accelerometer X (g)").
ACC_PREFIXES = ("a", "acc", "accel", "accelerometer", "acceleration", "f")


def is_axis_template(template, prefixes, suffixes) -> bool:
    """Whether (prefix, suffix) around an axis letter names a sensor of `prefixes`."""
    prefix, suffix = (clean(part) for part in template)
    return prefix in prefixes and (suffix == "" or suffix in suffixes)


def suggested_unit(columns, prefixes=MAGNETIC_PREFIXES, suffixes=FIELD_SUFFIXES):
    """The unit a column suffix such as _uT, (uT) or _gauss suggests for an axis triple, or None."""
    low = columns[0].lower()
    for i, ch in enumerate(low):
        if ch in "xyz" and is_axis_template((low[:i], low[i + 1 :]), prefixes, suffixes):
            return suffixes.get(clean(low[i + 1 :]))
    return None
