"""What nlpcal writes holds finite numbers only, and no number written as null.

Every document (JSON) and table (CSV, Parquet) nlpcal produces passes through here just before
it is written: a quantity that does not exist is left out (a None in an object drops its key),
and a number that is NaN or infinite, which no reader can use, stops the write with an
`InputError` naming where it is, so that nothing is written rather than a number nlpcal itself
would then refuse.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ..errors import InputError


def strict(value, what: str = "the output", where: str = ""):
    """`value` as plain JSON values: numpy scalars and arrays as Python numbers and lists, the
    keys of an object whose value is None left out; InputError at a NaN or infinite number, or
    a None in a list (`what` names the document in the message, `where` the path to `value`)."""
    if isinstance(value, Mapping):  # a dict, or a typed record (`nlpcal.results.Record`)
        return {str(k): strict(v, what, f"{where}{k}.") for k, v in value.items() if v is not None}
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [strict(v, what, f"{where}{k}.") for k, v in enumerate(value)]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        number = float(value)
        if not math.isfinite(number):
            raise _not_finite(what, where.rstrip("."), number)
        return number
    if value is None:
        raise InputError(f"{what} would hold null at {where.rstrip('.')}; nothing was written")
    return value


def finite_table(frame, what: str = "the output", missing: bool = False):
    """`frame` when every number nlpcal computed in it (its float columns) is finite; with
    `missing`, NaN stands for a value that does not exist and is written as an empty cell.
    InputError naming the column otherwise."""
    for name in frame.columns:
        column = frame[name]
        if column.dtype.kind != "f":
            continue
        values = column.to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if missing:
            bad &= ~np.isnan(values)
        if bad.any():
            raise _not_finite(what, f"column {name!s}", float(values[np.argmax(bad)]))
    return frame


def _not_finite(what: str, where: str, number: float) -> InputError:
    return InputError(
        f"{what} would hold the non-finite number {number:g} at {where}: the input gives a "
        f"result no reader can use (check its magnitudes); nothing was written"
    )
