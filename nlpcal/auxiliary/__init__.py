"""Auxiliary channels: stray fields that follow a motor current, a throttle or a heater.

`nlpcal.auxiliary.model` holds what a result records and how it corrects a log;
`nlpcal.auxiliary.moments` the feature group the channels add to the moments of the |B1|
objectives. The joint solve is `nlpcal.calibration.channels` on `nlpcal.nlp.channels`.
"""

from .model import DEFAULT_KIND, KINDS, AuxChannel, stray_field

__all__ = ["DEFAULT_KIND", "KINDS", "AuxChannel", "stray_field"]
