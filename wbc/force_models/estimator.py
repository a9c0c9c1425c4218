"""The project's normal-force estimator, as the MPC's force model and its closure.

Both take the payload mass at run time (`estimators.payload.PayloadEstimator`: an input of
the compiled kernels), so an observer's payload estimate or a pick changes the
model without a compile in the control loop.
"""

from __future__ import annotations

from estimators.payload import PayloadEstimator
from models.description import Machine
from wbc.errors import ForceModelError

__all__ = ["ESTIMATOR_METHODS", "load_closure", "load_estimator"]

ESTIMATOR_METHODS = ("full", "quasi-static")


def _checked_method(method: str) -> str:
    if not isinstance(method, str) or method not in ESTIMATOR_METHODS:
        raise ForceModelError(f"unknown estimator method '{method}'; valid: "
                              f"{', '.join(ESTIMATOR_METHODS)}")
    return method


def load_estimator(machine: Machine, method: str) -> PayloadEstimator:
    """The estimator with the d-beta fourth row (eq. 29), ``method`` full or quasi-static.

    Strokes outside their ranges are clipped (``strokes="clip"``): the MPC evaluates it at
    nominal states ahead that can lie a little outside, and MuJoCo's soft joint limits let
    a measured stroke overshoot.

    Raises:
        ForceModelError: Unknown ``method``.
    """
    return PayloadEstimator(machine, method=_checked_method(method), strokes="clip")


def load_closure(machine: Machine, method: str) -> PayloadEstimator:
    """The estimator with the cylinder-force fourth row (the measured load split).

    Raises:
        ForceModelError: Unknown ``method``.
    """
    return PayloadEstimator(machine, method=_checked_method(method), fourth="cylinder-force",
                            strokes="clip")
