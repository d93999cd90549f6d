"""Units of the field and of the specific force, and the units that column names carry.

nlpcal computes in base units: the magnetic field in nT (or in the log's own counts, "raw"), the
specific force of an accelerometer in g (standard gravity, 9.80665 m/s2). Every reader and every
verb of the library converts at the door with the functions here, so a Python caller with samples
in uT and a reference in nT passes both units and gets nT results.
"""

from __future__ import annotations

import numpy as np

from . import passes
from .errors import InputError

#: Field units and their size in nT. "raw" keeps the log's own unit (counts, arbitrary units).
FIELD_UNITS_NT = {"nT": 1.0, "uT": 1e3, "mT": 1e6, "mG": 1e2, "G": 1e5, "T": 1e9, "raw": 1.0}

#: Accelerometer units and their size in g (standard gravity 9.80665 m/s2).
ACC_UNITS_G = {"g": 1.0, "mg": 1e-3, "m/s2": 1.0 / 9.80665}

#: Unit suffixes of field column names, and the unit they suggest ("raw" for counts).
FIELD_SUFFIXES = {
    "nt": "nT",
    "ut": "uT",
    "µt": "uT",  # the micro sign (phyphox: "Magnetic field x (µT)")
    "μt": "uT",  # the Greek letter mu
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
    return passes.scaled(values, factor)


def from_base(values, unit: str):
    """Field values from the base unit back to `unit`."""
    factor = field_factor(unit)
    if np.ndim(values) == 0:
        return float(values) / factor
    values = np.asarray(values, dtype=float)
    return values if factor == 1.0 else values / factor


def check_compatible(
    unit: str, other: str, what: str = "the reference", against: str = "the samples"
) -> None:
    """Counts and field units do not mix: both "raw" or neither (`what` is in `other`,
    `against` in `unit`)."""
    if (unit == "raw") != (other == "raw"):
        verb = "are" if against.endswith("s") else "is"
        raise InputError(
            f"{what} is in {other!r} but {against} {verb} in {unit!r}; counts (raw) "
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
    "magneticfield",  # phyphox "Magnetic field x (µT)", ROS 2 magnetic_field.x
    "fieldmagneticfield",  # ROS 1 `rostopic echo -p`: field.magnetic_field.x
)
#: Prefixes of accelerometer axes (ax, acc_x, accel_x, "Accelerometer X (g)").
ACC_PREFIXES = ("a", "acc", "accel", "accelerometer", "acceleration", "f")


def is_axis_template(template, prefixes, suffixes) -> bool:
    """Whether (prefix, suffix) around an axis letter names a sensor of `prefixes`."""
    prefix, suffix = (clean(part) for part in template)
    return prefix in prefixes and (suffix == "" or suffix in suffixes)


def suggested_unit(columns, prefixes=MAGNETIC_PREFIXES, suffixes=FIELD_SUFFIXES):
    """The unit a column suffix such as _uT, (uT) or _gauss suggests for an axis triple, or None;
    also for three columns of any prefix that differ only in their axis letter and end in the
    same unit ("flight.B_x_nT", "flight.B_y_nT", "flight.B_z_nT")."""
    low = columns[0].lower()
    for i, ch in enumerate(low):
        if ch in "xyz" and is_axis_template((low[:i], low[i + 1 :]), prefixes, suffixes):
            return suffixes.get(clean(low[i + 1 :]))
    named = {unit_in_name(str(c), suffixes) for c in columns}
    if len(named) == 1 and tuple(map(str, columns)) in axis_templates(map(str, columns)).values():
        return named.pop()
    return None


# --- where a unit came from, and plausibility of magnitudes against it ------------------------

#: Where the unit of a log's field columns came from, as every result records it ("unit_source"):
#: "option" (given by the caller: --unit), "names" (the column names carry it), "format" (the
#: file format fixes it, `nlpcal.io.tables.Table.field_unit`) or "assumed" (a fallback).
UNIT_SOURCES = ("option", "names", "format", "assumed")
#: Sources that fix the physical scale of a result; "assumed" does not, and neither does a record
#: without a source (written before results recorded one).
FIXING_SOURCES = ("option", "names", "format")

#: Earth's field at the surface, from the magnetic equator to the poles. [nT]
EARTH_FIELD_NT = (22_000.0, 67_000.0)
#: Standard gravity at rest is 1 g; a hand-held or moving accelerometer reads around it. [g]
GRAVITY_G = (0.5, 2.0)
#: A magnitude more than this factor outside the expected range is taken for a unit mistake:
#: hard iron, indoor disturbances and motion rarely move it that far, a wrong unit moves it by
#: 10 to 10^9. [1]
IMPLAUSIBLE_FACTOR = 2.0


def _plausible(value: float, band, factor: float = 1.0) -> bool:
    low, high = band
    return low / factor <= value <= high * factor


#: `readable` writes a magnitude outside 1e-6 .. 1e15 with an exponent (3e-296, 5e+304).
READABLE_RANGE = (1e-6, 1e15)


def readable(value: float, figures: int = 3) -> str:
    """A magnitude for a message: `figures` significant digits, thousands grouped (with an
    exponent outside READABLE_RANGE)."""
    if value == 0 or not np.isfinite(value):
        return f"{value:g}"
    if not READABLE_RANGE[0] <= abs(value) < READABLE_RANGE[1]:
        return f"{value:.{figures}g}"
    digits = figures - 1 - int(np.floor(np.log10(abs(value))))
    return f"{round(value, digits):,.{max(digits, 0)}f}".replace(",", " ")


def unit_warning(
    magnitudes,
    unit: str,
    how: str,
    *,
    sensor: str = "magnetometer",
    flag: str = "--unit",
    raw_allowed: bool = True,
) -> str | None:
    """A warning when the typical magnitude of a sensor's samples does not fit its unit.

    magnitudes : candidate typical magnitudes in `unit` (the median |v|, the radius of a fitted
        sphere); the unit is implausible only when every one of them is.
    unit : the unit the samples are read in. how : where it came from, one of UNIT_SOURCES; an
        assumed unit that the magnitudes rule out is replaced by raw counts (`settle_unit`).
    sensor : "magnetometer" (judged against Earth's field, EARTH_FIELD_NT) or "accelerometer"
        (against gravity, GRAVITY_G).
    raw_allowed : whether the caller takes raw counts (the e-compass does not).
    Returns None when plausible, or for raw counts (they have no physical scale).
    """
    if unit == "raw":
        return None
    if sensor == "magnetometer":
        table, band, base, what = FIELD_UNITS_NT, EARTH_FIELD_NT, "nT", "Earth's field"
    else:
        table, band, base, what = ACC_UNITS_G, GRAVITY_G, "g", "gravity at rest"
    values = [float(m) for m in np.atleast_1d(magnitudes) if np.isfinite(m) and m > 0]
    if not values or any(_plausible(m * table[unit], band, IMPLAUSIBLE_FACTOR) for m in values):
        return None
    typical = values[0]
    fits = [u for u in table if u != "raw" and _plausible(typical * table[u], band)]
    fits = fits or [
        u for u in table if u != "raw" and _plausible(typical * table[u], band, IMPLAUSIBLE_FACTOR)
    ]
    said = {
        "option": f"as given ({flag} {unit})",
        "names": f"as the column names say ({unit})",
        "format": f"in {unit}, as the file format fixes it",
        "assumed": f"in {unit}, assumed because the column names carry no unit",
    }[how]
    converted = "" if unit == base else f" = {readable(typical * table[unit])} {base}"
    low, high = (f"{v:,g}".replace(",", " ") for v in band)
    read = (
        f"read {said}, the {sensor} magnitude is about {readable(typical)} {unit}{converted}, "
        f"far from {what} ({low} to {high} {base})"
    )
    if fits:
        options = ", ".join(
            f"{readable(typical * table[u])} {base} in {u} ({flag} {u})" for u in fits
        )
        advice = f"it would be {options}"
    else:
        advice = f"no {sensor} unit nlpcal knows puts it there"
    if how == "assumed" and "raw" in table and raw_allowed:
        return (
            f"{read}: the samples are kept as raw counts, not {unit}, and no export in a field "
            f"unit can be made from them; {advice}"
        )
    counts = (
        f"; if the numbers are raw counts, {flag} raw keeps them as counts"
        if "raw" in table and raw_allowed
        else f"; raw counts must be scaled to {'g' if base == 'g' else 'a field unit'} first"
    )
    kept = "; the unit given is used" if how == "option" else ""
    return f"{read}: {advice}{counts}{kept}"
