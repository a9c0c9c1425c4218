"""Machine description, closed-chain kinematics and the models built from them."""

from models.chain import ChainState, CylinderChain
from models.coordinates import CRANE, N_INDEPENDENT, SUSPENSION, WHEELS, TreeCoordinates
from models.description import WHEEL_ORDER, Body, Inertia, Joint, Loop, Machine
from models.errors import (
    JointOutOfRangeError,
    ModelError,
    StateError,
    StrokeOutOfRangeError,
)
from models.reference_machine import build_reference_machine
from models.state import MachineState, WheelContacts

__all__ = [
    "Body", "CRANE", "ChainState", "CylinderChain", "Inertia", "Joint", "JointOutOfRangeError",
    "Loop", "Machine", "MachineState", "ModelError", "N_INDEPENDENT", "SUSPENSION",
    "StateError", "StrokeOutOfRangeError", "TreeCoordinates", "WHEELS", "WHEEL_ORDER",
    "WheelContacts", "build_reference_machine",
]
