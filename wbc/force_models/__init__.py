"""Normal-force models usable as QP constraints."""

from wbc.force_models.estimator import ESTIMATOR_METHODS, load_estimator
from wbc.force_models.protocol import (
    N_GENERALIZED,
    ForceLinearization,
    NormalForceEstimate,
    NormalForceModel,
    contact_flags,
    linearize_forces,
    split_derivatives,
)
from wbc.force_models.synthetic import AffineForceEstimate, AffineForceModel

__all__ = [
    "ESTIMATOR_METHODS", "N_GENERALIZED", "AffineForceEstimate", "AffineForceModel",
    "ForceLinearization", "NormalForceEstimate", "NormalForceModel", "contact_flags",
    "linearize_forces",
    "load_estimator", "split_derivatives",
]
