"""Typed machine state, in the paper's terms, and per-wheel contact quantities.

Every per-wheel array is ordered FL, RL, FR, RR (paper eq. 1, `WHEEL_ORDER`). Twists are
[v; w] (linear first, as in the paper), expressed in the floating-base frame fb.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from models.coordinates import N_INDEPENDENT
from models.description import WHEEL_ORDER
from models.errors import StateError

__all__ = ["MachineState", "WheelContacts", "WHEEL_ORDER"]


def _arr(name: str, value, shape) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.shape != shape:
        raise StateError(f"'{name}' must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise StateError(f"'{name}' has non-finite entries (NaN or inf): {a}")
    return a


@dataclass
class WheelContacts:
    """Per-wheel contact quantities, measured (simulator, sensors) or estimated.

    Attributes:
        in_contact: Contact flags, shape (4,), order FL, RL, FR, RR.
        force_in_fb: Total ground force on each wheel in fb axes [N], shape (4, 3).
        point_in_fb: Force-weighted contact point of each wheel in fb [m], shape (4, 3);
            the wheel's lowest point when out of contact.
        normal_in_fb: Terrain normal at each contact in fb axes, shape (4, 3).
    """

    in_contact: np.ndarray
    force_in_fb: np.ndarray
    point_in_fb: np.ndarray
    normal_in_fb: np.ndarray

    def __post_init__(self):
        self.in_contact = np.asarray(self.in_contact, dtype=bool).reshape(4)
        self.force_in_fb = _arr("force_in_fb", self.force_in_fb, (4, 3))
        self.point_in_fb = _arr("point_in_fb", self.point_in_fb, (4, 3))
        self.normal_in_fb = _arr("normal_in_fb", self.normal_in_fb, (4, 3))

    @property
    def normal_force(self) -> np.ndarray:
        """Force along the terrain normal [N], shape (4,)."""
        return np.einsum("ij,ij->i", self.force_in_fb, self.normal_in_fb)

    @property
    def fz_in_fb(self) -> np.ndarray:
        """Force along the fb z axis [N], shape (4,): the paper's f_z (eqs. 22-24)."""
        return self.force_in_fb[:, 2].copy()

    @property
    def friction_in_fb(self) -> np.ndarray:
        """The x-y (fb) part of each wheel force [N], shape (4, 3): the paper's F_a."""
        f = self.force_in_fb.copy()
        f[:, 2] = 0.0
        return f


@dataclass
class MachineState:
    """State of the machine in the paper's independent coordinates.

    Attributes:
        base_position: fb origin in the world [m], shape (3,).
        base_rotation: Rotation world <- fb, shape (3, 3).
        base_twist: Body twist [v; w] of fb in fb [m/s, rad/s], shape (6,).
        base_acceleration: Time derivative of `base_twist` [m/s^2, rad/s^2], shape (6,)
            (the body-frame spatial acceleration, Pinocchio's free-flyer ``a``).
        q: Independent coordinates, shape (13,), order in `models.coordinates`.
        qd: Their velocities, shape (13,).
        qdd: Their accelerations, shape (13,).
        time: Simulation time [s].
        contacts: Measured wheel contacts (friction and flags), if known.
        suspension_force: Measured suspension cylinder forces [N], shape (2,), if known
            (order L, R; positive pushes the rod out).
        payload_mass: Mass of the payload currently held [kg], if known.
    """

    base_position: np.ndarray
    base_rotation: np.ndarray
    base_twist: np.ndarray
    base_acceleration: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    time: float = 0.0
    contacts: WheelContacts | None = None
    suspension_force: np.ndarray | None = None
    payload_mass: float | None = None
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        self.base_position = _arr("base_position", self.base_position, (3,))
        self.base_rotation = _arr("base_rotation", self.base_rotation, (3, 3))
        self.base_twist = _arr("base_twist", self.base_twist, (6,))
        self.base_acceleration = _arr("base_acceleration", self.base_acceleration, (6,))
        self.q = _arr("q", self.q, (N_INDEPENDENT,))
        self.qd = _arr("qd", self.qd, (N_INDEPENDENT,))
        self.qdd = _arr("qdd", self.qdd, (N_INDEPENDENT,))
        if self.suspension_force is not None:
            self.suspension_force = _arr("suspension_force", self.suspension_force, (2,))
