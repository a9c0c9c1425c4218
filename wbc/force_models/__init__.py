"""Normal-force models usable as QP constraints: the seam to the estimator."""

from estimators.linearization import N_GENERALIZED, ForceLinearization
from wbc.force_models.estimator import ESTIMATOR_METHODS, load_closure, load_estimator
from wbc.force_models.protocol import (
    MODEL_ERRORS,
    NormalForceEstimate,
    NormalForceModel,
    contact_flags,
    linearize_forces,
    linearized_contact_flags,
)

__all__ = [
    "ESTIMATOR_METHODS", "MODEL_ERRORS", "N_GENERALIZED", "ForceLinearization",
    "NormalForceEstimate", "NormalForceModel", "contact_flags", "linearize_forces",
    "linearized_contact_flags", "load_closure", "load_estimator",
]
