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


def range_message(name: str, index: int, value: float, rng: tuple[float, float]) -> str:
    """The message of a coordinate outside its chain's stroke range."""
    return (f"q[{index}] (stroke of cylinder chain '{name}') = {value:.6g} m outside "
            f"[{rng[0]:.6g}, {rng[1]:.6g}] m")
