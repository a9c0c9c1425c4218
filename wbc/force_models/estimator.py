"""Loading the project's normal-force estimator as a `NormalForceModel`."""

from __future__ import annotations

from models.description import Machine
from wbc.errors import ForceModelError
from wbc.force_models.protocol import NormalForceModel

__all__ = ["load_estimator"]

ESTIMATOR_METHODS = ("full", "quasi-static")


def load_estimator(machine: Machine, method: str) -> NormalForceModel:
    """``estimators.NormalForceEstimator(machine, method=method)``.

    Raises:
        ForceModelError: The `estimators` package has no `NormalForceEstimator` yet, or it
            does not provide the methods of `NormalForceModel`.
    """
    if method not in ESTIMATOR_METHODS:
        raise ForceModelError(f"unknown estimator method '{method}'; valid: "
                              f"{', '.join(ESTIMATOR_METHODS)}")
    try:
        from estimators import NormalForceEstimator
    except ImportError:
        try:  # the class's module, before the package re-exports it
            from estimators.estimator import NormalForceEstimator
        except ImportError as exc:
            raise ForceModelError(
                "estimators.NormalForceEstimator is not available; pass force_model= "
                f"explicitly (for example wbc.AffineForceModel) ({exc})") from exc
    model = NormalForceEstimator(machine, method=method)
    missing = [m for m in ("estimate", "constraint", "constraint_derivatives")
               if not callable(getattr(model, m, None))]
    if missing:
        raise ForceModelError(f"NormalForceEstimator lacks {', '.join(missing)}")
    return model
