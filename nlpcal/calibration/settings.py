"""The settings of a calibration: what `nlpcal.calibrate`'s keywords ask for, grouped by the step
that reads them.

`calibrate` packs its keywords into one `CalibrationSettings` at once (`CalibrationSettings.of`,
which checks each), and its steps (`nlpcal.calibration.steps`: prepare, solve, diagnose,
assemble, gate) take the groups they need instead of loose arguments:

    InputSettings      unit, threads                                 prepare
    ReferenceSettings  reference_field, reference_unit               prepare
    StopRule           cycles, target_std, target_range, rtol        solve (the staged cycle)
    Loss               loss, loss_scale                              solve, diagnose
    QualityGate        require_identifiable, allow_unconverged       gate
    IpoptOptions       ipopt_options, verbose                        solve
    LagSettings        lag, times                                    `nlpcal.calibration.lagged`

A new keyword is one field of the group it belongs to, packed in `CalibrationSettings.of`, and
read by the one step that needs it.

References
----------
[1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from .. import units, validation
from ..errors import InputError
from ..lag import LAG_TOLERANCE_S, lag_option, tolerance_option
from ..nlp.blocks import OPTIONS
from ..nlp.solver import IpoptOptions
from ..robust import Loss
from .selection import MODEL_CHOICES
from .staged import CYCLES_DEFAULT, RTOL_DEFAULT, StopRule

#: What `calibrate(method=...)` accepts.
METHODS = ("staged", "joint")


@dataclass(frozen=True)
class InputSettings:
    """How to read the samples of a calibration (`prepare`).

    Attributes
    ----------
    unit : str or None
        The unit of the samples (`--unit`): nT, uT, mT, mG, G, T, or raw; None assumes nT and
        takes the samples as raw counts when their magnitudes are far from Earth's field.
    threads : int or None
        Threads of the passes over the data (`--threads`); None: the cores available.
    """

    unit: str | None = None
    threads: int | None = None

    @property
    def unit_source(self) -> str:
        """Where the unit comes from: "option" when given, else "assumed"."""
        return "assumed" if self.unit is None else "option"

    @property
    def given_unit(self) -> str:
        """The unit the samples are read in before the plausibility check: nT unless given."""
        return "nT" if self.unit is None else self.unit


@dataclass(frozen=True)
class ReferenceSettings:
    """The reference field |B1| is fitted to (`prepare`).

    Attributes
    ----------
    field : None, float or array_like of shape (N,)
        None (Eq. 8 in [1]: |B1| as constant as possible, the scale fixed by the gauge), a
        number F, or N values F_i (`--reference-field`, `--reference-column`). [unit]
    unit : str or None
        The unit of `field`; None: the unit of the samples.
    """

    field: Any = field(default=None, compare=False)
    unit: str | None = None


@dataclass(frozen=True)
class QualityGate:
    """When a calibration refuses its result with QualityError (`gate`).

    Attributes
    ----------
    require_identifiable : bool
        Refuse a result whose data leave parameters undetermined (`--allow-unidentifiable`
        is False here).
    allow_unconverged : bool
        Return a staged result that stopped at its cycle limit, or away from the joint optimum
        of the same objective, with a warning (`--allow-unconverged`).
    """

    require_identifiable: bool = True
    allow_unconverged: bool = False


@dataclass(frozen=True)
class LagSettings:
    """The lag of a reference series (`nlpcal.calibration.lagged`, which runs calibrations of
    its own around the steps).

    Attributes
    ----------
    value : None, "auto" or float
        No lag, a lag estimated with the parameters, or one given and taken out (`--lag`). [s]
    times : None or array_like of shape (N,)
        The times of the samples, seconds from any origin (`--time-column`). [s]
    tolerance : float
        The standard error that determines a lag near zero (`--lag-tolerance`,
        `nlpcal.lag.is_determined`). [s]
    """

    value: str | float | None = None
    times: Any = field(default=None, compare=False)
    tolerance: float = LAG_TOLERANCE_S


@dataclass(frozen=True)
class AuxSettings:
    """The auxiliary channels whose stray fields are estimated with the nine parameters
    (`nlpcal.calibration.channels`).

    Attributes
    ----------
    columns : None, list of str or mapping
        None (no channels), columns of a DataFrame of samples, or names -> (N,) values
        (`--aux-columns`). [channel unit]
    kind : None, str or list of str
        "current", "throttle" or "other", one for all or one per channel (`--aux-kind`).
    """

    columns: Any = field(default=None, compare=False)
    kind: Any = None


#: The gate of a trial calibration (model "auto", the full model a restriction is judged
#: against): every result that solved is returned.
NO_GATE = QualityGate(require_identifiable=False, allow_unconverged=True)


@dataclass(frozen=True)
class CalibrationSettings:
    """Everything `nlpcal.calibrate` is asked besides the samples, grouped by the step that
    reads it.

    Attributes
    ----------
    method : {"staged", "joint"}
        The staged cycle of Fig. 1 in [1], or all nine parameters in one IPOPT problem.
    model : {"full", "diagonal", "offset", "auto"}
        The form of Eq. 4 estimated, or "auto".
    input : InputSettings
        The unit of the samples and the threads of the passes over them.
    reference : ReferenceSettings
        The reference field and its unit.
    stop : StopRule
        When the staged cycle stops; its targets in the base unit of the samples. [nT or raw]
    loss : nlpcal.robust.Loss
        Least squares or a robust loss, and its scale in the base unit of the samples. [nT or raw]
    gate : QualityGate
        When the result is refused.
    ipopt : nlpcal.nlp.solver.IpoptOptions
        IPOPT's settings for every solve.
    aux : AuxSettings
        Auxiliary channels, or none.

    References
    ----------
    [1] Zhou et al. (2010), see `nlpcal.models.zhou2010`.

    Examples
    --------
    >>> from nlpcal.calibration.settings import CalibrationSettings
    >>> settings = CalibrationSettings.of(method="joint", unit="uT", loss="huber", loss_scale=0.2)
    >>> settings.loss.scale, settings.stop.max_cycles  # [nT], [1]
    (200.0, 500)
    """

    method: str = "staged"
    model: str = "full"
    input: InputSettings = field(default_factory=InputSettings)
    reference: ReferenceSettings = field(default_factory=ReferenceSettings)
    stop: StopRule = field(default_factory=StopRule)
    loss: Loss = field(default_factory=Loss)
    gate: QualityGate = field(default_factory=QualityGate)
    ipopt: IpoptOptions = OPTIONS
    lag: LagSettings = field(default_factory=LagSettings)
    aux: AuxSettings = field(default_factory=AuxSettings)

    @classmethod
    def of(
        cls,
        *,
        method: str = "staged",
        model: str = "full",
        reference_field=None,
        unit: str | None = None,
        reference_unit: str | None = None,
        cycles: int = CYCLES_DEFAULT,
        target_std: float | None = None,
        target_range: float | None = None,
        rtol: float = RTOL_DEFAULT,
        loss: str = "l2",
        loss_scale: float | None = None,
        require_identifiable: bool = True,
        allow_unconverged: bool = False,
        verbose: bool = False,
        threads: int | None = None,
        ipopt_options: dict | None = None,
        lag=None,
        times=None,
        lag_tolerance=None,
        aux_columns=None,
        aux_kind=None,
    ) -> CalibrationSettings:
        """The settings of `nlpcal.calibrate`'s keywords (see there), each checked: InputError
        names the first that is unusable. Quantities are in `unit` (default nT) and are stored
        in its base unit. [nT or raw]"""
        if lag is not None and aux_columns is not None:
            raise InputError("a lag and aux channels are not estimated together; drop one of them")
        threads = validation.optional_whole(threads, "threads")
        validation.choice(method, "method", METHODS)
        validation.choice(model, "model", MODEL_CHOICES)
        ipopt = (replace(OPTIONS, print_level=5) if verbose else OPTIONS).with_options(
            ipopt_options
        )
        read = InputSettings(unit=unit, threads=threads)
        base = read.given_unit
        units.field_factor(base)
        stop = StopRule(
            max_cycles=validation.count(cycles, "cycles"),
            target_std=validation.optional_number(target_std, "target_std", positive=True),
            target_range=validation.optional_number(target_range, "target_range", positive=True),
            rtol=validation.number(rtol, "rtol", minimum=0.0),
            predict=not allow_unconverged,  # the user asked to run to the limit
            every_row_exact=False,
        )
        units.check_compatible(base, reference_unit or base)
        scale = validation.optional_number(loss_scale, "the loss scale", positive=True)
        return cls(
            method=method,
            model=model,
            input=read,
            reference=ReferenceSettings(field=reference_field, unit=reference_unit),
            stop=replace(
                stop,
                target_std=units.to_base(stop.target_std, base),
                target_range=units.to_base(stop.target_range, base),
            ),
            loss=Loss(loss, units.to_base(scale, base)),
            gate=QualityGate(
                require_identifiable=require_identifiable, allow_unconverged=allow_unconverged
            ),
            ipopt=ipopt,
            lag=LagSettings(lag_option(lag), times, tolerance_option(lag_tolerance)),
            aux=AuxSettings(columns=aux_columns, kind=aux_kind),
        )
