"""Exceptions shared by the library and the command line."""


class NlpcalError(Exception):
    """Base class of nlpcal's own errors."""


class InputError(NlpcalError, ValueError):
    """The input data or options are unusable; the command line exits with status 2."""


class SolveError(NlpcalError, RuntimeError):
    """IPOPT did not solve a problem; the command line exits with status 1.

    `status` holds IPOPT's return status (for example "Maximum_Iterations_Exceeded").
    """

    def __init__(self, message: str, status: str = "", result=None):
        super().__init__(message)
        self.status = status
        self.result = result


class QualityError(SolveError):
    """The solve ended, but the result fails a quality check (parameters the data do not
    determine); `result` holds it for inspection. The command line exits with status 1 and writes
    no output.

    `overrides` are the keyword arguments that would return the result anyway (for example
    {"require_identifiable": False, "allow_unconverged": True}); the message names them, and
    `reason` is the message without them.
    """

    def __init__(self, message: str, status: str = "", result=None, overrides=None):
        self.reason = message
        self.overrides = dict(overrides or {})
        if self.overrides:
            given = ", ".join(f"{name}={value!r}" for name, value in self.overrides.items())
            message = f"{message} ({given} returns it anyway)"
        super().__init__(message, status, result)


class WriteError(NlpcalError, OSError):
    """An output could not be written (no space left, an I/O error); the command line exits
    with status 1. Nothing is left behind and an existing output is unchanged."""
