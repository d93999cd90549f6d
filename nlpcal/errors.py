"""Exceptions shared by the library and the command line."""


class NlpcalError(Exception):
    """Base class of nlpcal's own errors."""


class InputError(NlpcalError, ValueError):
    """The input data or options are unusable; the command line exits with status 2."""


class SolveError(NlpcalError, RuntimeError):
    """IPOPT did not solve a problem; the command line exits with status 1.

    `status` holds IPOPT's return status (for example "Maximum_Iterations_Exceeded").
    `identifiability` holds what the diagnosis of the failure found, in the keys of a
    calibration result's identifiability block ("not_identifiable", "flatness"), or None.
    """

    def __init__(self, message: str, status: str = "", result=None, identifiability=None):
        super().__init__(message)
        self.status = status
        self.result = result
        self.identifiability = identifiability


class QualityError(SolveError):
    """The solve ended, but the result fails a quality check (parameters the data do not
    determine); `result` holds it for inspection. The command line exits with status 1 and writes
    no output.

    `overrides` are the keyword arguments that would return the result anyway (for example
    {"require_identifiable": False, "allow_unconverged": True}); the message names them, and
    `reason` is the message without them. `identifiability` is the result's, when it has one.
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
