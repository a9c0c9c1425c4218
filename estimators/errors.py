"""Exception hierarchy of the `estimators` package."""

from __future__ import annotations


class EstimatorError(Exception):
    """Base class of every error raised by `estimators`."""


class EstimatorInputError(EstimatorError, ValueError):
    """An input has a wrong shape, a non-finite entry or a value outside its valid range.

    The message names the offending field and the valid range or shape.
    """


class SingularSystemError(EstimatorError, ArithmeticError):
    """The linear system for the normal forces is singular (or numerically so).

    Attributes:
        condition: 1-norm condition number of the system that failed [-].
    """

    def __init__(self, message: str, condition: float = float("inf")):
        super().__init__(message)
        self.condition = condition


def range_message(name: str, unit: str, index: int, value: float,
                  rng: tuple[float, float]) -> str:
    """The message of a coordinate outside its range (a chain's stroke or a joint's)."""
    what = (f"stroke of cylinder chain '{name}'" if unit == "m stroke"
            else f"position of joint '{name}'")
    unit = unit.split()[0]
    return (f"q[{index}] ({what}) = {value:.6g} {unit} outside [{rng[0]:.6g}, "
            f"{rng[1]:.6g}] {unit}")
