"""Exception hierarchy of the `wbc` package.

Every error the controller raises derives from `WbcError`. Input errors also derive from
`ValueError` so that callers that only know the standard library can catch them.
"""

from __future__ import annotations

__all__ = [
    "ConfigurationError",
    "ForceModelError",
    "IKError",
    "QPSolveError",
    "TrajectoryError",
    "UnknownControllerError",
    "UnknownSolverError",
    "WbcError",
    "WbcInputError",
]


class WbcError(Exception):
    """Base class of every error raised by `wbc`."""


class WbcInputError(WbcError, ValueError):
    """An input (state, goal, array) has a wrong type, shape or a non-finite entry."""


class ConfigurationError(WbcInputError):
    """A controller, task or constraint parameter is outside its valid range."""


class UnknownControllerError(WbcInputError):
    """A controller name is not one of the registered names."""

    def __init__(self, name: str, valid: tuple[str, ...]):
        self.name = name
        self.valid = valid
        super().__init__(f"unknown controller '{name}'; valid names: {', '.join(valid)}")


class UnknownSolverError(WbcInputError):
    """A QP solver name is not available through qpsolvers."""

    def __init__(self, name: str, valid: tuple[str, ...]):
        self.name = name
        self.valid = valid
        super().__init__(f"unknown or unavailable QP solver '{name}'; available: "
                         f"{', '.join(valid)}")


class QPSolveError(WbcError):
    """The QP solver did not return a solution (infeasible, max iterations, non-finite).

    Attributes:
        status: The solver's status string.
    """

    def __init__(self, message: str, status: str = "unknown"):
        self.status = status
        super().__init__(message)


class TrajectoryError(WbcError):
    """Ruckig could not compute a reference trajectory."""


class IKError(WbcError):
    """The tool-point inverse kinematics did not reach the target within tolerance."""


class ForceModelError(WbcError):
    """The normal-force model is unavailable or returned arrays of the wrong shape."""
