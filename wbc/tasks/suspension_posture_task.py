"""Keep the suspension strokes near their reference (a goal, or the strokes held)."""

from __future__ import annotations

from wbc.axes import SUSPENSION_AXES
from wbc.tasks.joint_task import JointTask

__all__ = ["SuspensionPostureTask"]


class SuspensionPostureTask(JointTask):
    """A soft PD task on the two suspension strokes.

    Its weight is meant to be low: the suspension is the controller's main lever on the
    normal forces, and the posture task only pulls it back once the forces allow.

    Args:
        kp: [1/s^2]. kd: [1/s]. weight: Scalar or one per stroke (L, R).
    """

    def __init__(self, kp=4.0, kd=4.0, weight=0.1):
        super().__init__(SUSPENSION_AXES, kp, kd, weight)
