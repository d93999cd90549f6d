"""Exceptions shared by the library and the command line."""


class NlpcalError(Exception):
    """Base class of nlpcal's own errors."""


class InputError(NlpcalError, ValueError):
    """The input data or options are unusable; the command line exits with status 2.

    A subclass of ValueError; the message is one sentence saying what was received and what
    would fix it.

    Examples
    --------
    >>> import nlpcal
    >>> try:
    ...     nlpcal.calibrate([[1.0, 2.0, 3.0]])
    ... except nlpcal.InputError as error:
    ...     print(type(error).__name__)
    InputError
    """


class SolveError(NlpcalError, RuntimeError):
    """IPOPT did not solve a problem; the command line exits with status 1.

    Attributes
    ----------
    status : str
        IPOPT's return status (for example "Maximum_Iterations_Exceeded").
    result : object or None
        The result, where one was made.
    identifiability : dict or None
        What the diagnosis of the failure found, in the keys of a calibration result's
        identifiability block ("not_identifiable", "flatness").

    Examples
    --------
    >>> import nlpcal
    >>> error = nlpcal.SolveError("IPOPT did not converge", status="Maximum_Iterations_Exceeded")
    >>> error.status
    'Maximum_Iterations_Exceeded'
    """

    def __init__(self, message: str, status: str = "", result=None, identifiability=None):
        super().__init__(message)
        self.status = status
        self.result = result
        self.identifiability = identifiability


class QualityError(SolveError):
    """The solve ended, but the result fails a quality check; the command line exits with status 1.

    The result (parameters the data do not determine, a staged cycle that did not converge) is in
    `result`, for inspection; the command line writes no output.

    Attributes
    ----------
    status : str
        The check that failed (for example "Not_Identifiable").
    result : object or None
        The result that failed the check.
    overrides : dict
        The keyword arguments that would return the result anyway (for example
        {"require_identifiable": False}); the message names them.
    reason : str
        The message without the overrides.
    identifiability : dict or None
        The result's identifiability block, when it has one.

    Examples
    --------
    >>> import nlpcal
    >>> error = nlpcal.QualityError(
    ...     "the attitudes do not determine z_z", "Not_Identifiable",
    ...     overrides={"require_identifiable": False},
    ... )
    >>> print(error)
    the attitudes do not determine z_z (require_identifiable=False returns it anyway)
    """

    def __init__(self, message: str, status: str = "", result=None, overrides=None):
        self.reason = message
        self.overrides = dict(overrides or {})
        if self.overrides:
            given = ", ".join(f"{name}={value!r}" for name, value in self.overrides.items())
            message = f"{message} ({given} returns it anyway)"
        super().__init__(message, status, result, getattr(result, "identifiability", None))


class WriteError(NlpcalError, OSError):
    """An output could not be written (no space left, an I/O error); the command line exits
    with status 1. Nothing is left behind and an existing output is unchanged."""
