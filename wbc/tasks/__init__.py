"""Tasks: cost terms ``1/2 ||J x + e||^2_W`` of the whole-body QP and of the MPC."""

from wbc.tasks.damping_task import DampingTask
from wbc.tasks.horizon_input_task import HorizonInputTask
from wbc.tasks.horizon_leveling_task import HorizonLevelingTask
from wbc.tasks.horizon_smoothness_task import HorizonSmoothnessTask
from wbc.tasks.horizon_tracking_task import HorizonTrackingTask
from wbc.tasks.joint_task import JointTask
from wbc.tasks.slack_penalty_task import SlackPenaltyTask
from wbc.tasks.speed_scale_task import SpeedScaleTask
from wbc.tasks.suspension_posture_task import SuspensionPostureTask
from wbc.tasks.task import ConstantJacobianTask, Objective, Task
from wbc.tasks.tcp_position_task import TcpPositionTask

__all__ = [
    "ConstantJacobianTask", "DampingTask", "HorizonInputTask", "HorizonLevelingTask",
    "HorizonSmoothnessTask", "HorizonTrackingTask", "JointTask", "Objective",
    "SlackPenaltyTask", "SpeedScaleTask", "SuspensionPostureTask", "Task", "TcpPositionTask",
]
