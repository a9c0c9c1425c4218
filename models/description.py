"""Generic, model-agnostic description of a rigid multibody machine.

This is the single source of truth from which the MuJoCo model, the Pinocchio model and the
analytic estimator are all built. A machine is a kinematic *tree* of bodies (each with at most
one joint to its parent) plus *loop closures* (point-coincidence constraints) that close the
cylinder four-bar chains, plus the actuators and their limits.

Frames: every body has a frame; ``Body.position``/``Body.rotation`` place it in its parent's
frame at zero joint coordinate. A revolute joint turns the body about ``Joint.axis`` (in the
body frame) through the body frame origin; a prismatic joint slides the body along it.
Units: SI throughout ([m], [kg], [kg m^2], [N], [rad]).
"""

from __future__ import annotations

import functools
import hashlib
import pickle
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np

from models.chain import CylinderChain
from models.errors import ModelError

JointKind = Literal["free", "revolute", "prismatic", "fixed"]
WHEEL_ORDER = ("FL", "RL", "FR", "RR")  # paper eq. (1); used for every per-wheel array


def _vec(x, n=3) -> np.ndarray:
    a = np.asarray(x, dtype=float).reshape(n)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Inertia:
    """Rigid-body inertia.

    Attributes:
        mass: [kg].
        com: Centre of mass in the body frame [m], shape (3,).
        inertia: Rotational inertia about the centre of mass, body axes [kg m^2], (3, 3).
    """

    mass: float
    com: np.ndarray
    inertia: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "com", _vec(self.com))
        i = np.asarray(self.inertia, float).reshape(3, 3)
        i = 0.5 * (i + i.T)
        i.setflags(write=False)
        object.__setattr__(self, "inertia", i)
        if not self.mass > 0:
            raise ModelError(f"mass must be positive, got {self.mass}")
        ev = np.linalg.eigvalsh(i)
        if ev[0] <= 0 or ev[0] + ev[1] < ev[2] * (1 - 1e-9):
            raise ModelError(f"inertia is not physical (eigenvalues {ev})")

    def transformed(self, rotation: np.ndarray, position: np.ndarray) -> Inertia:
        """This inertia expressed in a frame where the old frame sits at (rotation, position)."""
        r = np.asarray(rotation, float)
        return Inertia(self.mass, r @ self.com + np.asarray(position, float),
                       r @ self.inertia @ r.T)

    def __add__(self, other: Inertia) -> Inertia:
        m = self.mass + other.mass
        c = (self.mass * self.com + other.mass * other.com) / m
        def shift(i: Inertia) -> np.ndarray:
            d = i.com - c
            return i.inertia + i.mass * (d @ d * np.eye(3) - np.outer(d, d))
        return Inertia(m, c, shift(self) + shift(other))


def box_inertia(mass: float, size, com=(0, 0, 0)) -> Inertia:
    """Solid box of full edge lengths ``size`` [m]."""
    a, b, c = size
    return Inertia(mass, com, np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * mass / 12)


def cylinder_inertia(mass: float, radius: float, length: float, axis: int,
                     com=(0, 0, 0), inner_radius: float = 0.0) -> Inertia:
    """Solid (or hollow) cylinder with its symmetry axis along body axis ``axis``."""
    r2 = radius * radius + inner_radius * inner_radius
    ia = 0.5 * mass * r2
    it = mass * (3 * r2 + length * length) / 12
    d = [it, it, it]
    d[axis] = ia
    return Inertia(mass, com, np.diag(d))


@dataclass(frozen=True)
class Joint:
    """The joint between a body and its parent.

    Attributes:
        kind: ``free`` (floating base), ``revolute``, ``prismatic`` or ``fixed``.
        axis: Unit axis in the body frame, shape (3,) (ignored for free/fixed).
        range: (lower, upper) position limits [rad or m], or None.
        damping: Viscous damping [N m s/rad or N s/m] (simulator only).
        armature: Reflected rotor inertia [kg m^2 or kg] (simulator only).
    """

    kind: JointKind
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    range: tuple[float, float] | None = None
    damping: float = 0.0
    armature: float = 0.0


@dataclass(frozen=True)
class Geom:
    """A shape attached to a body. ``collision`` geoms touch the terrain; the rest are visual.

    Attributes:
        kind: MuJoCo geom type name: box, cylinder, sphere, capsule, ellipsoid.
        size: MuJoCo size parameters (half-sizes, radius, half-length) [m].
        position: In the body frame [m].
        rotation: In the body frame, (3, 3).
        rgba: Colour.
        collision: True for geoms that make contact with the terrain.
    """

    kind: str
    size: tuple[float, ...]
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    rgba: tuple[float, float, float, float] = (0.8, 0.6, 0.1, 1.0)
    collision: bool = False


@dataclass(frozen=True)
class Body:
    """One rigid body of the tree.

    Attributes:
        name: Unique name; the joint carries the same name.
        parent: Parent body name, None for the root.
        position: Body origin in the parent frame at zero joint coordinate [m].
        rotation: Body orientation in the parent frame at zero joint coordinate.
        joint: The joint to the parent.
        inertia: The body's inertia in its own frame.
        geoms: Visual and collision shapes.
    """

    name: str
    parent: str | None
    position: np.ndarray
    rotation: np.ndarray
    joint: Joint
    inertia: Inertia
    geoms: tuple[Geom, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "position", _vec(self.position))
        r = np.asarray(self.rotation, float).reshape(3, 3)
        r.setflags(write=False)
        object.__setattr__(self, "rotation", r)


@dataclass(frozen=True)
class Loop:
    """A point coincidence closing a kinematic loop: point_a on body_a equals point_b on body_b.

    Points are given in the respective body frames [m].
    """

    name: str
    body_a: str
    point_a: tuple[float, float, float]
    body_b: str
    point_b: tuple[float, float, float]


@dataclass(frozen=True)
class HydraulicCylinder:
    """A double-acting hydraulic cylinder and its limits.

    Attributes:
        name: Name of the cylinder (and of its chain).
        bore: Piston diameter [m].
        rod: Rod diameter [m].
        stroke: Stroke [m].
        supply_pressure: Pump pressure [Pa].
        rated_flow: Valve flow at full opening under the load-sensing margin [m^3/s].
        max_acceleration: Stroke acceleration limit used by planners [m/s^2].
        seal_friction: Coulomb friction of the piston and rod seals [N]: the simulated
            cylinder's piston joint carries it (MuJoCo ``frictionloss``), so the force the
            chamber pressures report differs from the force on the mechanism by it. The
            estimators do not model it.
    """

    name: str
    bore: float
    rod: float
    stroke: float
    supply_pressure: float
    rated_flow: float
    max_acceleration: float
    seal_friction: float = 0.0

    @property
    def area_piston(self) -> float:
        """Piston-side area A_a [m^2]."""
        return np.pi * self.bore ** 2 / 4

    @property
    def area_rod(self) -> float:
        """Rod-side annulus area A_b [m^2]."""
        return np.pi * (self.bore ** 2 - self.rod ** 2) / 4

    @property
    def force_range(self) -> tuple[float, float]:
        """(retract, extend) force limits p_s A_b and p_s A_a [N]."""
        return (-self.supply_pressure * self.area_rod, self.supply_pressure * self.area_piston)

    @property
    def velocity_range(self) -> tuple[float, float]:
        """(retract, extend) speed limits Q/A_b and Q/A_a [m/s]."""
        return (-self.rated_flow / self.area_rod, self.rated_flow / self.area_piston)


@dataclass(frozen=True)
class ChainBinding:
    """Where a cylinder chain sits in the tree.

    Attributes:
        chain: The planar chain kinematics.
        cylinder: The cylinder that drives it.
        driven_joint: Revolute joint the chain turns (body name).
        barrel: Body name of the cylinder barrel (revolute about the base pivot).
        piston: Body name of the piston and rod (prismatic along the barrel).
    """

    chain: CylinderChain
    cylinder: HydraulicCylinder
    driven_joint: str
    barrel: str
    piston: str


@dataclass(frozen=True)
class RotaryDrive:
    """A directly driven joint (telescope cylinder or wrist motor) and its limits.

    Attributes:
        joint: Body/joint name.
        velocity_limit: [rad/s or m/s].
        effort_limit: [N m or N].
        acceleration_limit: [rad/s^2 or m/s^2].
    """

    joint: str
    velocity_limit: float
    effort_limit: float
    acceleration_limit: float


@dataclass(frozen=True)
class Machine:
    """The whole machine: tree, loops, actuators and named roles.

    Attributes:
        bodies: Tree bodies, parents before children; the first is the floating base.
        loops: Loop closures of the cylinder chains.
        chains: Cylinder chains by role: ``slew``, ``lift``, ``tilt``, ``bogie_L``, ``bogie_R``.
        direct_drives: Directly actuated joints: telescope and wrist joints.
        wheels: Wheel body names in order FL, RL, FR, RR.
        wheel_radius: [m].
        wheel_drive: Max wheel speed [rad/s] and torque [N m].
        crane_coordinates: Names of the 7 crane coordinates in the paper's terms.
        payload: Name of the payload body.
        tcp_body, tcp_position: Tool point frame: body and position in it [m].
        gravity: [m/s^2], positive number along -z of the world.
        sources: Table of every number and its source (documentation).
    """

    bodies: tuple[Body, ...]
    loops: tuple[Loop, ...]
    chains: dict[str, ChainBinding]
    direct_drives: dict[str, RotaryDrive]
    wheels: tuple[str, str, str, str]
    wheel_radius: float
    wheel_drive: tuple[float, float]
    crane_coordinates: tuple[str, ...]
    suspension_coordinates: tuple[str, str]
    payload: str
    tcp_body: str
    tcp_position: tuple[float, float, float]
    gravity: float = 9.81
    sources: tuple[tuple[str, str, str], ...] = ()

    def __post_init__(self):
        seen = set()
        for b in self.bodies:
            if b.parent is not None and b.parent not in seen:
                raise ModelError(f"body '{b.name}' listed before its parent '{b.parent}'")
            if b.name in seen:
                raise ModelError(f"duplicate body name '{b.name}'")
            seen.add(b.name)

    @functools.cached_property
    def depth_first(self) -> tuple[Body, ...]:
        """The bodies in depth-first order: each subtree contiguous, children as listed.

        MuJoCo's body arrays follow it, and so must Pinocchio's joints: its algorithms over
        subtrees (CRBA) assume them contiguous; in ``bodies`` order a cylinder's barrel and
        piston sit between a crane joint and its descendants.
        """
        children: dict[str | None, list[Body]] = {}
        for b in self.bodies:
            children.setdefault(b.parent, []).append(b)
        order: list[Body] = []
        stack = list(reversed(children.get(None, [])))
        while stack:
            b = stack.pop()
            order.append(b)
            stack.extend(reversed(children.get(b.name, [])))
        return tuple(order)

    def body(self, name: str) -> Body:
        """Body by name."""
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(f"no body '{name}'; bodies: {[b.name for b in self.bodies]}")

    @property
    def total_mass(self) -> float:
        """[kg]."""
        return float(sum(b.inertia.mass for b in self.bodies))

    @functools.cached_property
    def fingerprint(self) -> str:
        """Content hash of the description (SHA-256 of its fields, hex).

        Equal numbers give an equal fingerprint; derived models and compiled kernels are
        cached by it, never by ``id``.
        """
        data = pickle.dumps(tuple(getattr(self, f.name) for f in fields(self)), protocol=4)
        return hashlib.sha256(data).hexdigest()

    @functools.cached_property
    def coordinates(self):
        """The machine's `models.coordinates.TreeCoordinates` (coordinate table), built once."""
        from models.coordinates import TreeCoordinates  # coordinates imports this module

        return TreeCoordinates(self)

    @property
    def moving_joints(self) -> tuple[str, ...]:
        """Names of the 1-DoF joints in tree order (the free base excluded)."""
        return tuple(b.name for b in self.bodies if b.joint.kind in ("revolute", "prismatic"))
