"""Controllers: the whole-body QP and the MPC behind one interface."""

from wbc.controllers.command import ControlCommand
from wbc.controllers.config import (
    ControllerConfig,
    ForceConfig,
    MpcConfig,
    QPConfig,
    ReferenceConfig,
)
from wbc.controllers.controller import Controller
from wbc.controllers.mpc import MpcController
from wbc.controllers.registry import CONTROLLER_NAMES, make_controller
from wbc.controllers.tracking import WholeBodyQPController

__all__ = [
    "CONTROLLER_NAMES", "ControlCommand", "Controller", "ControllerConfig", "ForceConfig",
    "MpcConfig", "MpcController", "QPConfig", "ReferenceConfig", "WholeBodyQPController",
    "make_controller",
]
