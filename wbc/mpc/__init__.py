"""Model predictive control over a condensed double-integrator prediction."""

from wbc.mpc.context import HorizonContext
from wbc.mpc.planner import MpcPlan, MpcPlanner
from wbc.mpc.prediction import CondensedPrediction, predict_base_pose

__all__ = ["CondensedPrediction", "HorizonContext", "MpcPlan", "MpcPlanner",
           "predict_base_pose"]
