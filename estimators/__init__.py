"""Wheel-ground normal-force estimators (Paz, Bahari & Mattila; full dynamics and ref. [13]).

Public API::

    est = NormalForceEstimator(machine, method="full", fourth="d-beta", D=0.5, beta=0.0)
    e = est.estimate(state)              # Estimate: f_z (4,), order FL, RL, FR, RR
    b = est.estimate_batch(states)       # BatchEstimate over a log (StateBatch or states)
    G, g0 = est.constraint(state)        # f_z = G a + g0, a = [base acc (6), qdd (13)]
    lin = est.linearize(state)           # ForceLinearization: what a controller needs
    cal = est.calibrate(states, normal_forces_gt, window=None)   # eq. (30)
"""

from estimators.calibration import (
    CalibrationResult,
    SlidingCalibration,
    calibrate_d_beta,
    calibrate_d_beta_sliding,
)
from estimators.errors import EstimatorError, EstimatorInputError, SingularSystemError
from estimators.estimator import NormalForceEstimator
from estimators.linearization import N_GENERALIZED, ForceLinearization
from estimators.quasi_static import QuasiStaticMask
from estimators.results import BatchEstimate, Estimate
from estimators.tree import TreeModel
from models.state_batch import StateBatch

__all__ = [
    "BatchEstimate",
    "CalibrationResult",
    "Estimate",
    "EstimatorError",
    "EstimatorInputError",
    "ForceLinearization",
    "N_GENERALIZED",
    "NormalForceEstimator",
    "QuasiStaticMask",
    "SingularSystemError",
    "SlidingCalibration",
    "StateBatch",
    "TreeModel",
    "calibrate_d_beta",
    "calibrate_d_beta_sliding",
]
