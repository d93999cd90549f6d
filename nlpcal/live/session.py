"""A live calibration: samples in, an update every half second, a stop when the data suffice.

The session adds the samples of a stream to its moments (`nlpcal.live.accumulator`), solves
them as `calibrate` does (`nlpcal.live.solve`) when an update is due, and judges each solve
against the targets: every parameter of the model with a standard error below its target
(`Targets`) and at least `nlpcal.live.grid.COVERAGE_TARGET` of the equal-area cells visited by
the corrected field. Each update is one document (`Update.to_dict`), the line `nlpcal live`
prints.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..calibration.result import CalibrationResult
from ..errors import InputError, SolveError
from ..models.zhou2010 import PARAMETER_NAMES, Zhou2010Parameters, correct
from .accumulator import StreamMoments
from .grid import COVERAGE_TARGET, Coverage, coverage
from .solve import solve

#: Seconds between updates (each one a solve). [s]
UPDATE_INTERVAL = 0.5
#: Most points of the corrected cloud an update hands to a view.
CLOUD_POINTS = 1500


@dataclass(frozen=True)
class Targets:
    """The standard errors below which a parameter counts as determined.

    offset_fraction : of the mean corrected field |B1|, for z_x, z_y, z_z (0.1 %). [1]
    scale : for s_x, s_y, s_z. [1]
    angle_deg : for alpha, beta, gamma. [deg]
    """

    offset_fraction: float = 0.001
    scale: float = 0.001
    angle_deg: float = 0.05

    def limits(self, field_mean: float) -> dict:
        """name -> the largest standard error that counts as determined, in the result's
        units (offsets in the field's: `field_mean` is the mean |B1| [field unit])."""
        per_kind = (self.offset_fraction * abs(field_mean), self.scale, self.angle_deg)
        return {name: per_kind[k // 3] for k, name in enumerate(PARAMETER_NAMES)}


@dataclass
class Update:
    """One solve of the stream so far and what it says.

    n_samples : samples in the solve. elapsed_s : seconds since the session started. [s]
    result : the calibration (None when the solve failed: `failure` says why).
    limits : the target standard error of each estimated parameter. [result units]
    poorly_determined : the estimated parameters above their target (all when the result states
        no standard errors).
    """

    n_samples: int
    elapsed_s: float
    model: str
    coverage: Coverage
    result: CalibrationResult | None = None
    failure: str | None = None
    limits: dict = field(default_factory=dict)
    poorly_determined: list = field(default_factory=list)
    #: time.time() when the newest sample of the solve arrived (the line's "data_time"; its
    #: "emitted_time" is when the line was made, after the solve). [s]
    data_time: float = 0.0

    @property
    def determined(self) -> bool:
        """Every parameter of the model below its target, and the coverage complete."""
        return self.result is not None and not self.poorly_determined and self.coverage.complete

    def to_dict(self) -> dict:
        """The JSON line of the update."""
        result = self.result
        document: dict = {
            "n_samples": self.n_samples,
            "elapsed_s": self.elapsed_s,
            "model": self.model,
            "unit": None if result is None else result.unit,
            "parameters": None if result is None else result.parameters,
            "standard_errors": None if result is None else result.standard_errors,
            "target_standard_errors": self.limits,
            "poorly_determined": self.poorly_determined,
            "coverage": self.coverage.to_dict(),
            "verdict": (
                {"status": "failed", "reasons": [self.failure]}
                if result is None
                else result.verdict.to_dict()
            ),
            "table1": None if result is None else result.statistics[-1],
            "determined": self.determined,
            "data_time": self.data_time,
            "emitted_time": time.time(),
        }
        return document


class LiveSession:
    """Samples in, updates out.

    unit : the base unit of the samples, nT or raw. reference : None or a constant field F.
    [unit] model : a form of `nlpcal.live.solve.LIVE_MODELS`. forgetting : lambda
    (`nlpcal.live.accumulator`). [1] coverage_target : the fraction of the grid's cells to
    cover. [1] interval : seconds between updates. [s]
    """

    def __init__(
        self,
        unit: str,
        *,
        reference: float | None = None,
        model: str = "full",
        targets: Targets | None = None,
        forgetting: float = 1.0,
        coverage_target: float = COVERAGE_TARGET,
        interval: float = UPDATE_INTERVAL,
        clock=time.monotonic,
    ):
        self.unit = unit
        self.reference = reference
        self.model = model
        self.targets = targets or Targets()
        self.stream = StreamMoments(reference, forgetting)
        self.interval = interval
        self.coverage_target = coverage_target
        self.clock = clock
        self.started = clock()
        self.last_solve: float | None = None
        self.latest: Update | None = None
        self.determined_at: int | None = None  # the sample count of the first determined update
        self.arrived = 0.0  # time.time() of the newest sample

    @property
    def n(self) -> int:
        return self.stream.n

    def add(self, rows) -> None:
        """Add samples (k, 3). [unit]"""
        self.stream.add(rows)
        self.arrived = time.time()

    def due(self) -> bool:
        """Whether an update is due: the frame is fixed, new samples came, and `interval`
        passed since the last solve."""
        if self.stream.frame is None:
            return False
        if self.latest is not None and self.latest.n_samples == self.n:
            return False
        return self.last_solve is None or self.clock() - self.last_solve >= self.interval

    def update(self) -> Update:
        """Solve the samples so far and judge the solve."""
        self.last_solve = self.clock()
        self.stream.check_frame()
        moments = self.stream.moments()
        samples = self.stream.samples
        result, failure = None, None
        if moments is None:
            failure = "too few samples to fix the frame of the moments"
        else:
            try:
                result = solve(samples, moments, self.reference, self.model, self.unit, final=False)
            except SolveError as error:
                failure = f"the solve failed: {error}"
        update = Update(
            n_samples=self.n,
            elapsed_s=self.clock() - self.started,
            model=self.model,
            coverage=coverage(self.directions(result), self.coverage_target),
            result=result,
            failure=failure,
            data_time=self.arrived,
        )
        if result is not None:
            update.limits = self._limits(result)
            update.poorly_determined = self._poor(result, update.limits)
        if update.determined and self.determined_at is None:
            self.determined_at = update.n_samples
        self.latest = update
        return update

    def final(self) -> CalibrationResult:
        """`calibrate`'s solve of every sample, with its quality checks (QualityError when the
        data leave parameters undetermined; SolveError when IPOPT fails)."""
        self.stream.check_frame()
        moments = self.stream.moments()
        if moments is None:
            raise InputError(
                f"the stream ended after {self.n} samples, too few to calibrate; turn the sensor "
                f"through many orientations for longer"
            )
        return solve(
            self.stream.samples, moments, self.reference, self.model, self.unit, final=True
        )

    def directions(self, result: CalibrationResult | None, max_points: int = 20000):
        """(M, 3) the corrected field of an even stride of the samples (about the frame's centre
        before the first solve). [unit]"""
        samples = self.stream.samples[:: max(1, -(-self.n // max_points))]  # at most max_points
        if result is None:
            centre = self.stream.frame.centre if self.stream.frame is not None else 0.0
            return samples - centre
        return correct(samples, Zhou2010Parameters.from_dict(result.parameters))

    def cloud(self, max_points: int = CLOUD_POINTS) -> dict:
        """The corrected samples of the latest update for a view: points (M, 3) and each one's
        residual |B1| - mean |B1|. [unit]"""
        result = self.latest.result if self.latest is not None else None
        points = self.directions(result, max_points)
        magnitude = np.linalg.norm(points, axis=1)
        residual = magnitude - (magnitude.mean() if len(magnitude) else 0.0)
        return {"points": points, "residuals": residual}

    def _limits(self, result: CalibrationResult) -> dict:
        field_mean = float(result.statistics[-1]["mean"])
        limits = self.targets.limits(field_mean)
        return {name: limits[name] for name in result.estimated_parameters}

    @staticmethod
    def _poor(result: CalibrationResult, limits: dict) -> list:
        errors = result.standard_errors
        unidentified = set(result.identifiability.not_identifiable or [])
        if errors is None:
            return list(limits)
        return [
            name
            for name, limit in limits.items()
            if name in unidentified or not (errors.get(name, np.inf) < limit)
        ]
