"""E-compass calibration and attitude after Qiu et al. (2017), every estimation a CasADi/IPOPT NLP.

Two calibration modes share one result type, `CompassCalibration`:

- turn mode (`calibrate_turns`, `nlpcal.compass.turns`), the paper's protocol: turns about the
  housing x, y and z axes, compensation angles (Eq. 4-8), then axis-aligned ellipsoid fits;
- free-rotation mode (`calibrate_free`, `nlpcal.compass.free`), for logs without turns: general
  ellipsoid fits and the constancy of the dip angle.

`attitude` gives roll, pitch and heading through a calibration (Eq. 9-10); `evaluate` their
errors against a reference. The model is `nlpcal.models.qiu2017`; the NLPs are in
`nlpcal.nlp.compass`; a replica of the experiment is `nlpcal.simulation.qiu2017`.
"""

from __future__ import annotations

from ..errors import InputError
from ..io.sensors import SensorLog
from ..io.tables import column_name
from .ellipsoids import fit_axis_ellipsoid, fit_general_ellipsoid
from .free import DEFAULT_REST_TOLERANCE, MIN_FREE_SAMPLES, calibrate_free, dip_alignment
from .orientation import (
    DEFAULT_PITCH_BANDS,
    NEAR_VERTICAL_DEG,
    Attitude,
    attitude,
    evaluate,
    format_evaluation,
    wrap_deg,
)
from .result import CompassCalibration, SensorCalibration
from .turns import (
    MIN_TURN_SAMPLES,
    calibrate_turns,
    compensation_angles,
    parse_turn_labels,
    within_turn_scatter,
)


def calibrate_sensor_log(
    log: SensorLog,
    *,
    turn_column: str | None = None,
    field_nt: float | None = None,
    ellipsoid_seed: str = "linear",
    rest_tolerance: float | None = DEFAULT_REST_TOLERANCE,
) -> CompassCalibration:
    """Calibrate both sensors of a log read by `nlpcal.io.read_sensor_log`: turn mode with the
    turn labels of `turn_column` (a name or 0-based position), free-rotation mode without. The
    field magnitude is `field_nt` [nT], else the log's reference field, else estimated. The result
    records the log."""
    if field_nt is None:
        field_nt = log.reference_field
    if turn_column:
        turn_column = column_name(log.frame, turn_column, "turn column")
        labels = log.frame[turn_column].to_numpy(dtype=object)[log.kept]
        result = calibrate_turns(
            log.mag, log.acc, labels, field_nt=field_nt, ellipsoid_seed=ellipsoid_seed
        )
    else:
        result = calibrate_free(
            log.mag,
            log.acc,
            field_nt=field_nt,
            ellipsoid_seed=ellipsoid_seed,
            rest_tolerance=rest_tolerance,
        )
    result.input.update(log.metadata(turn_column=turn_column))
    return result


__all__ = [
    "DEFAULT_PITCH_BANDS",
    "DEFAULT_REST_TOLERANCE",
    "MIN_FREE_SAMPLES",
    "MIN_TURN_SAMPLES",
    "NEAR_VERTICAL_DEG",
    "Attitude",
    "CompassCalibration",
    "InputError",
    "SensorCalibration",
    "attitude",
    "calibrate_free",
    "calibrate_sensor_log",
    "calibrate_turns",
    "compensation_angles",
    "dip_alignment",
    "evaluate",
    "fit_axis_ellipsoid",
    "fit_general_ellipsoid",
    "format_evaluation",
    "parse_turn_labels",
    "within_turn_scatter",
    "wrap_deg",
]
