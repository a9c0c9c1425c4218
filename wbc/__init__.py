"""Stability-aware whole-body control of heavy-duty hydraulic mobile manipulators.

The public API of the controller library::

    from wbc import make_controller, JointGoal, TcpGoal, ControllerConfig

    controller = make_controller("mpc-full", machine)
    controller.set_goal(JointGoal(crane=q_goal))
    command = controller.step(state)          # every config.dt seconds

Design notes: `wbc/DESIGN.md`.
"""

__version__ = "0.1.0"

from wbc.axes import CRANE_AXES, N_AXES, SUSPENSION_AXES, AxisLimits
from wbc.constraints import (
    AccelerationLimit,
    Box,
    Constraint,
    HorizonLimit,
    HorizonNormalForceConstraint,
    HorizonPositionLimit,
    HorizonVelocityLimit,
    Inequality,
    NormalForceConstraint,
    PositionLimit,
    SpeedScaleLimit,
    VelocityLimit,
)
from wbc.context import ControlContext, QPContext, ReferenceSample
from wbc.controllers import (
    CONTROLLER_NAMES,
    ControlCommand,
    Controller,
    ControllerConfig,
    ForceConfig,
    MpcConfig,
    MpcController,
    QPConfig,
    ReferenceConfig,
    WholeBodyQPController,
    make_controller,
)
from wbc.errors import (
    ConfigurationError,
    ForceModelError,
    IKError,
    QPSolveError,
    TrajectoryError,
    UnknownControllerError,
    UnknownSolverError,
    WbcError,
    WbcInputError,
)
from wbc.force_models import ForceLinearization, NormalForceModel, load_estimator
from wbc.kinematics import TcpKinematics, solve_tcp_ik
from wbc.layout import VariableLayout
from wbc.mpc import CondensedPrediction, HorizonContext, MpcPlan, MpcPlanner
from wbc.qp import build_qp
from wbc.references import JointGoal, RuckigReference, TcpGoal
from wbc.solvers import ProxQPWorkspace, QPSolution, QpsolversBackend, make_solver
from wbc.tasks import (
    DampingTask,
    HorizonInputTask,
    HorizonSmoothnessTask,
    HorizonTrackingTask,
    JointTask,
    SlackPenaltyTask,
    SpeedScaleTask,
    SuspensionPostureTask,
    Task,
    TcpPositionTask,
)

__all__ = [
    "__version__", "CONTROLLER_NAMES", "CRANE_AXES", "N_AXES", "SUSPENSION_AXES",
    "AccelerationLimit", "AxisLimits", "Box", "CondensedPrediction", "ConfigurationError",
    "Constraint", "ControlCommand", "ControlContext", "Controller", "ControllerConfig",
    "DampingTask", "ForceConfig", "ForceLinearization", "ForceModelError", "HorizonContext",
    "HorizonInputTask", "HorizonLimit", "HorizonNormalForceConstraint", "HorizonPositionLimit",
    "HorizonSmoothnessTask", "HorizonTrackingTask", "HorizonVelocityLimit", "IKError",
    "Inequality", "JointGoal", "JointTask", "MpcConfig", "MpcController", "MpcPlan", "MpcPlanner",
    "NormalForceConstraint", "NormalForceModel", "PositionLimit", "ProxQPWorkspace", "QPConfig",
    "QPContext", "QPSolution", "QPSolveError", "QpsolversBackend", "ReferenceConfig",
    "ReferenceSample", "RuckigReference", "SlackPenaltyTask", "SpeedScaleLimit", "SpeedScaleTask",
    "SuspensionPostureTask", "Task", "TcpGoal", "TcpKinematics", "TcpPositionTask",
    "TrajectoryError", "UnknownControllerError", "UnknownSolverError", "VariableLayout",
    "VelocityLimit", "WbcError", "WbcInputError", "WholeBodyQPController", "build_qp",
    "load_estimator", "make_controller", "make_solver", "solve_tcp_ik",
]
