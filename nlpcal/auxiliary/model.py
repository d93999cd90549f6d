"""The stray field of auxiliary channels: what a result holds and how it corrects a log.

For channels c_k (motor current, throttle, a heater's power) the field the sensor sees gains a
stray field that follows each channel linearly, an offset v_k c_k that moves with it, as
ArduPilot's CompassMot models a motor's field. Eq. 4 of [1] becomes

    B1 = O_p S_p (B_M - Z_p - sum_k v_k c_k)                                        (*)

with v_k three coefficients per channel. [field unit per channel unit]

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import units
from ..errors import InputError
from ..results import DocumentReader

#: What a channel measures, and its unit: a motor current [A], a throttle as a fraction of full
#: throttle [1, from 0 to 1], or anything else, in its own unit.
KINDS = {"current": "A", "throttle": "throttle fraction", "other": "channel unit"}
DEFAULT_KIND = "other"


@dataclass(frozen=True)
class AuxChannel:
    """One auxiliary channel of a calibration.

    name : its column in the calibration log. kind : "current", "throttle" or "other" (KINDS).
    coefficients : (3,) v_k, the stray field per unit of the channel. [field unit per channel
        unit]
    standard_errors : (3,) their standard errors, or None. [field unit per channel unit]
    """

    name: str
    kind: str
    coefficients: np.ndarray
    standard_errors: np.ndarray | None = None

    @property
    def channel_unit(self) -> str:
        return KINDS[self.kind]

    def unit(self, field_unit: str) -> str:
        """The unit of the coefficients, "<field unit> per <channel unit>"."""
        return f"{field_unit} per {self.channel_unit}"

    def to_dict(self, field_unit: str) -> dict:
        block = {
            "coefficients": [float(v) for v in self.coefficients],
            "standard_errors": None
            if self.standard_errors is None
            else [float(v) for v in self.standard_errors],
            "unit": self.unit(field_unit),
            "kind": self.kind,
        }
        return {k: v for k, v in block.items() if v is not None}


def stray_field(channels: list, values: np.ndarray) -> np.ndarray:
    """sum_k v_k c_k of (*) for (N, K) channel values, K = len(channels). [field unit]"""
    coefficients = np.array([c.coefficients for c in channels], dtype=float)  # (K, 3)
    return np.asarray(values, dtype=float) @ coefficients


def read_aux(reader: DocumentReader, field_unit: str) -> list:
    """The "aux" block of a parameters file: column -> {coefficients, standard_errors, unit,
    kind}, checked (finite numbers, a known kind, the unit "<field unit> per <channel unit>")."""
    if not reader.has("aux"):
        return []
    block = reader.reader("aux")
    channels = []
    for name in block.document:
        entry = block.reader(name)
        kind = entry.string("kind", DEFAULT_KIND, options=list(KINDS))
        errors = entry.array("standard_errors", (3,), None)
        if errors is not None and (errors < 0).any():
            raise InputError(f"{reader.source}: aux.{name}.standard_errors must be >= 0")
        channel = AuxChannel(str(name), kind, entry.array("coefficients", (3,)), errors)
        stated = entry.string("unit", channel.unit(field_unit))
        if stated != channel.unit(field_unit):
            raise InputError(
                f"{reader.source}: aux.{name}.unit must be {channel.unit(field_unit)!r} (the "
                f"file's field unit per the unit of a {kind} channel), got {stated!r}"
            )
        channels.append(channel)
    return channels


def in_unit(channels: list, factor: float) -> list:
    """The channels with coefficients and standard errors times `factor` (a field unit's
    conversion; `nlpcal.units`)."""
    return [
        AuxChannel(
            c.name,
            c.kind,
            c.coefficients * factor,
            None if c.standard_errors is None else c.standard_errors * factor,
        )
        for c in channels
    ]


def converted(channels: list, source_unit: str, target_unit: str) -> list:
    """The channels' coefficients from `source_unit` to `target_unit` (field units). [target
    unit per channel unit]"""
    return in_unit(channels, units.field_factor(source_unit) / units.field_factor(target_unit))
