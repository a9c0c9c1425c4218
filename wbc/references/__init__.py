"""Task references: goals and jerk-limited Ruckig trajectories."""

from wbc.references.goals import JointGoal, TcpGoal
from wbc.references.ruckig_reference import RuckigReference

__all__ = ["JointGoal", "RuckigReference", "TcpGoal"]
