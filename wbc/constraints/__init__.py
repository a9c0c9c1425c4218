"""Constraints: ``G x <= h`` or bounds, for the whole-body QP and the MPC."""

from wbc.constraints.acceleration_limit import AccelerationLimit
from wbc.constraints.constraint import (
    Box,
    Constraint,
    DiagonalBlocks,
    Inequality,
    PreparedForm,
)
from wbc.constraints.horizon_effort_limit import HorizonEffortLimit
from wbc.constraints.horizon_limits import (
    HorizonLimit,
    HorizonPositionLimit,
    HorizonVelocityLimit,
)
from wbc.constraints.horizon_normal_force import HorizonNormalForceConstraint
from wbc.constraints.normal_force import NormalForceConstraint
from wbc.constraints.position_limit import PositionLimit
from wbc.constraints.side_reserve import SideReserveConstraint
from wbc.constraints.speed_scale_limit import SpeedScaleLimit
from wbc.constraints.velocity_limit import VelocityLimit

__all__ = [
    "AccelerationLimit", "Box", "Constraint", "DiagonalBlocks", "HorizonEffortLimit",
    "HorizonLimit",
    "HorizonNormalForceConstraint",
    "HorizonPositionLimit", "HorizonVelocityLimit", "Inequality", "NormalForceConstraint",
    "PositionLimit", "PreparedForm", "SideReserveConstraint", "SpeedScaleLimit", "VelocityLimit",
]
