"""The machine as a kinematic tree for the screw-theory recursion (paper eqs. 2-11).

`TreeModel` precomputes, from a `models.description.Machine`, everything the recursion needs:
bodies with fixed joints merged into their moving parent, constant joint placements, screw
axes, spatial inertias, the body groups of the paper (crane ``m``, suspension ``B``, wheels
``w``), the closed cylinder chains and the wheels.

The recursion is written once against a tiny array backend (``ops``): `NumpyOps` evaluates
it numerically (the paper-faithful reference) and `estimators._symbolic.CasadiOps` builds a
CasADi SX graph of the very same code (compiled batch kernel, exact derivatives). A pose is a
pair ``(R, p)``: the rotation and position of a frame in another (the paper's ``G``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimators import spatial
from estimators.errors import EstimatorInputError
from estimators.numpy_ops import NumpyOps
from models.description import Inertia, Machine

__all__ = ["ChainSpec", "NumpyOps", "TreeBody", "TreeDynamics", "TreeModel"]


@dataclass(frozen=True)
class TreeBody:
    """One moving body of the tree (fixed children merged in).

    Attributes:
        name: Body (and joint) name.
        parent: Index of the parent in `TreeModel.bodies`, -1 for the floating base.
        kind: ``free``, ``revolute`` or ``prismatic``.
        axis: Joint axis in the body frame, shape (3,).
        rotation: Body orientation in the parent frame at zero joint coordinate, (3, 3).
        position: Body origin in the parent frame at zero joint coordinate [m], (3,).
        inertia: Inertia of the body and its merged fixed children, body frame.
        spatial: Its spatial inertia M (6, 6), eq. (11).
        screw: Joint screw axis s in the body frame, shape (6,) (the paper's s_x, s_z).
        group: ``suspension`` (chassis, bogies, their cylinders: eq. 15), ``crane`` (eq. 14)
            or ``wheel`` (eqs. 16-17).
        damping: Viscous joint damping [N m s/rad or N s/m].
        armature: Reflected rotor inertia [kg m^2 or kg].
    """

    name: str
    parent: int
    kind: str
    axis: np.ndarray
    rotation: np.ndarray
    position: np.ndarray
    inertia: Inertia
    spatial: np.ndarray
    screw: np.ndarray
    group: str
    damping: float
    armature: float


@dataclass(frozen=True)
class ChainSpec:
    """Constants of one cylinder chain for eqs. (2)-(8), in the form the recursion uses.

    Attributes:
        name: Chain name (its independent coordinate).
        coordinate: Index in the independent coordinates.
        driven, barrel, piston: Body indices in `TreeModel.bodies`.
        la, lb: Triangle sides joint-to-base-pivot and joint-to-rod-eye [m].
        lx0: Pin-to-pin length at zero stroke, L_c0 + L_c [m].
        psi, psi_b: Offsets of eq. (5) for the driven joint and the barrel [rad].
        sigma: Sign of eq. (5) (+1 or -1).
        stroke_range: Valid stroke interval [m].
    """

    name: str
    coordinate: int
    driven: int
    barrel: int
    piston: int
    la: float
    lb: float
    lx0: float
    psi: float
    psi_b: float
    sigma: float
    stroke_range: tuple[float, float]

    def __post_init__(self):
        if self.sigma not in (1.0, -1.0):  # `TreeModel.chain_motion`'s trigonometry needs it
            raise EstimatorInputError(f"ChainSpec {self.name}: sigma must be +1 or -1, got "
                                      f"{self.sigma}")


@dataclass
class TreeDynamics:
    """Result of the forward and backward recursions for one state.

    Lists are indexed like `TreeModel.bodies`. Vectors are numpy arrays or CasADi SX columns.

    Attributes:
        rotation_fb: Rotation fb <- body, per body.
        position_fb: Body origin in fb [m], per body.
        twist: Body twist [v; w] in the body frame, per body, eqs. (9a-b), (10a-c).
        acceleration: Its derivative *plus the gravity offset*, per body, eqs. (9c-d), (10d-f).
        wrench: Euler-Poincare wrench of the body alone (weight included), eq. (11).
        subtree_wrench: Wrench of the body and all its descendants, in the body frame.
        joint_force: Joint torque/force of the tree, ``s^T subtree_wrench`` [N m or N].
        q, qd, qdd: Tree joint coordinates per body (0 for the base).
        k1, k2, dk1, dk2: Per chain (`TreeModel.chains` order), eqs. (6)-(7).
    """

    rotation_fb: list
    position_fb: list
    twist: list
    acceleration: list
    wrench: list
    subtree_wrench: list
    joint_force: list
    q: list
    qd: list
    qdd: list
    k1: list
    k2: list
    dk1: list
    dk2: list

    @property
    def base_wrench(self):
        """Total wrench the environment must apply to the machine, in fb at its origin."""
        return self.subtree_wrench[0]


class TreeModel:
    """Precomputed tree of a `Machine` for the recursion.

    Args:
        machine: The machine description; its first body is the floating base fb.

    Attributes:
        machine: The description.
        bodies: Moving bodies (the base first), parents before children.
        index: Body name -> index.
        hosts: Fixed body name -> (its moving host's name, the body's pose in it (4, 4)).
        chains: One `ChainSpec` per cylinder chain, in independent-coordinate order.
        direct: (independent index, body index) of the directly driven coordinates.
        wheels: Body indices of the wheels, order FL, RL, FR, RR.
        wheel_axes: Spin axis of each wheel in its body frame, shape (4, 3).
        wheel_is_sphere: True when the wheels touch the ground with a sphere (the contact is
            straight below the centre); False for a disc (lowest point of the rim).
        suspension: Chain indices (into `chains`) of the two suspension chains, order L, R.
        side_wheels: For each suspension chain, the wheel slots (0..3) on its bogie.
        crane_root: Index of the crane's first body (its parent frame hosts frame m).
        gravity: [m/s^2] along world -z.
    """

    def __init__(self, machine: Machine):
        self.machine = machine
        self.gravity = float(machine.gravity)
        coords = machine.coordinates
        self.independent_names = coords.independent_names
        host: dict[str, tuple[str, np.ndarray]] = {}  # fixed body -> (moving host, T_host_body)
        merged: dict[str, Inertia] = {}
        order: list = []
        for b in machine.bodies:
            if b.joint.kind == "fixed" and b.parent is not None:
                h, t_hp = host.get(b.parent, (b.parent, np.eye(4)))
                t_hb = t_hp @ spatial.se3(b.rotation, b.position)
                host[b.name] = (h, t_hb)
                merged[h] = merged[h] + b.inertia.transformed(t_hb[:3, :3], t_hb[:3, 3])
            else:
                merged[b.name] = b.inertia
                order.append(b)
        self.index = {b.name: i for i, b in enumerate(order)}
        self.hosts = host
        self._payload_parameters(machine, host)

        suspension_bodies = {order[0].name}
        for name in machine.suspension_coordinates:
            cb = machine.chains[name]
            suspension_bodies.update((cb.driven_joint, cb.barrel, cb.piston))
        bodies = []
        for b in order:
            if b.name in machine.wheels:
                group = "wheel"
            elif b.name in suspension_bodies:
                group = "suspension"
            else:
                group = "crane"
            axis = np.asarray(b.joint.axis, float)
            screw = np.zeros(6)
            if b.joint.kind == "revolute":
                screw[3:] = axis
            elif b.joint.kind == "prismatic":
                screw[:3] = axis
            inertia = merged[b.name]
            bodies.append(TreeBody(
                name=b.name, parent=-1 if b.parent is None else self.index[b.parent],
                kind=b.joint.kind, axis=axis, rotation=np.asarray(b.rotation, float),
                position=np.asarray(b.position, float), inertia=inertia,
                spatial=spatial.spatial_inertia(inertia), screw=screw, group=group,
                damping=float(b.joint.damping), armature=float(b.joint.armature)))
        self.bodies: tuple[TreeBody, ...] = tuple(bodies)
        self.children: tuple[tuple[int, ...], ...] = tuple(
            tuple(j for j, c in enumerate(bodies) if c.parent == i) for i in range(len(bodies)))

        chains, direct = [], []
        for i, name in enumerate(self.independent_names):
            if name in machine.chains:
                cb = machine.chains[name]
                ch = cb.chain
                mid = 0.5 * sum(ch.stroke_range)
                s = ch.state(mid)
                la, lb = ch.side_lengths
                chains.append(ChainSpec(
                    name=name, coordinate=i, driven=self.index[cb.driven_joint],
                    barrel=self.index[cb.barrel], piston=self.index[cb.piston], la=la, lb=lb,
                    lx0=ch.dead_length + ch.rod_length,
                    psi=s.theta - ch.sigma * s.q, psi_b=s.theta_barrel + ch.sigma * s.q1,
                    sigma=ch.sigma, stroke_range=ch.stroke_range))
            else:
                direct.append((i, self.index[name]))
        self.chains: tuple[ChainSpec, ...] = tuple(chains)
        self.direct: tuple[tuple[int, int], ...] = tuple(direct)
        self.wheels = tuple(self.index[w] for w in machine.wheels)
        self.wheel_axes = np.array([bodies[w].axis for w in self.wheels])
        wheel_body = machine.body(machine.wheels[0])
        kinds = [g.kind for g in wheel_body.geoms if g.collision]
        self.wheel_is_sphere = bool(kinds) and kinds[0] == "sphere"
        self.wheel_radius = float(machine.wheel_radius)
        names = [c.name for c in self.chains]
        self.suspension = tuple(names.index(n) for n in machine.suspension_coordinates)
        side = []
        for ci in self.suspension:
            drv = self.chains[ci].driven
            side.append(tuple(k for k, w in enumerate(self.wheels) if self._descends(w, drv)))
        self.side_wheels: tuple[tuple[int, ...], ...] = tuple(side)
        crane = [i for i, b in enumerate(bodies) if b.group == "crane" and b.parent == 0]
        first = self.index.get(machine.crane_coordinates[0], crane[0] if crane else 0)
        self.crane_root = first if bodies[first].group == "crane" else (crane[0] if crane else 0)
        self.coordinates = coords

    _shared: dict = {}

    @classmethod
    def shared(cls, machine: Machine) -> TreeModel:
        """The tree model of ``machine``, one per description (`Machine.fingerprint`)."""
        tree = cls._shared.get(machine.fingerprint)
        if tree is None:
            tree = cls._shared[machine.fingerprint] = cls(machine)
        return tree

    def _payload_parameters(self, machine: Machine, host: dict) -> None:
        """The payload as a run-time parameter of `dynamics` (its mass ``m``).

        The payload's spatial inertia is ``m`` times that of one kilogram of it (its centre
        of mass is fixed in its body and its rotational inertia scales with the mass), and
        spatial inertias about one frame add: the host's (the moving body the payload is
        merged into) is ``M = M_0 + (m - m_0) U`` with ``M_0`` at the description's payload
        ``m_0`` and ``U`` the payload's per kilogram, in the host's frame. Exact, so the
        dynamics are affine in ``m``.
        """
        name = getattr(machine, "payload", None)
        body = next((b for b in machine.bodies if b.name == name), None)
        if body is None or body.inertia.mass <= 0.0:
            self.payload_body, self.payload_mass = -1, 0.0
            self.payload_spatial_per_kg = np.zeros((6, 6))
            return
        h, t_hb = host.get(name, (name, np.eye(4)))
        per_kg = Inertia(1.0, body.inertia.com, body.inertia.inertia / body.inertia.mass)
        self.payload_body = self.index[h]
        self.payload_mass = float(body.inertia.mass)
        self.payload_spatial_per_kg = spatial.spatial_inertia(
            per_kg.transformed(t_hb[:3, :3], t_hb[:3, 3]))

    def _descends(self, i: int, ancestor: int) -> bool:
        while i >= 0:
            if i == ancestor:
                return True
            i = self.bodies[i].parent
        return False

    @property
    def transform_fb_to_m(self) -> np.ndarray:
        """Pose of the manipulator base frame m in fb (4x4): the crane root's joint frame."""
        b = self.bodies[self.crane_root]
        t = np.eye(4)
        i = b.parent
        chain = []
        while i > 0:
            chain.append(self.bodies[i])
            i = self.bodies[i].parent
        for c in reversed(chain):  # crane root on a fixed-in-fb body: constant
            t = t @ spatial.se3(c.rotation, c.position)
        return t @ spatial.se3(b.rotation, b.position)

    # ------------------------------------------------------------------ eqs. (2)-(8)
    @staticmethod
    def chain_motion(ops, c: ChainSpec, x, xd, xdd):
        """Driven-joint and barrel motion of one chain from its stroke, eqs. (2)-(7).

        Returns:
            ``(theta, theta_d, theta_dd, barrel, barrel_d, barrel_dd, k1, k2, dk1, dk2,
            trig_theta, trig_barrel)`` [rad, rad/s, rad/s^2, rad/m, rad/m^2], with
            ``dk = dk/dx`` and ``trig = (cos, sin)`` of the angle, from the triangle's cosines
            without going through the angle (``cos(acos c) = c``, ``sin(acos c) =
            sqrt(1 - c^2)``): the compiled kernels then call no ``acos``, ``sin`` or ``cos``
            for the chains.
        """
        la, lb = c.la, c.lb
        lx = c.lx0 + x
        # eq. (2) with L_x squared (erratum), and its x-derivatives.
        cq = (la * la + lb * lb - lx * lx) / (2 * la * lb)
        sq = ops.sqrt(1 - cq * cq)
        q = -ops.acos(cq)
        dc, ddc = -lx / (la * lb), -1.0 / (la * lb)
        dq = dc / sq
        ddq = ddc / sq + cq * dc * dc / (sq * sq * sq)
        # eq. (3)
        c1 = (la * la + lx * lx - lb * lb) / (2 * la * lx)
        s1 = ops.sqrt(1 - c1 * c1)
        q1 = -ops.acos(c1)
        dc1 = 1.0 / (2 * la) - (la * la - lb * lb) / (2 * la * lx * lx)
        ddc1 = (la * la - lb * lb) / (la * lx * lx * lx)
        dq1 = dc1 / s1
        ddq1 = ddc1 / s1 + c1 * dc1 * dc1 / (s1 * s1 * s1)
        sg = c.sigma
        k1, dk1 = sg * dq, sg * ddq  # eq. (6)
        k2, dk2 = -sg * dq1, -sg * ddq1  # eq. (7)
        # theta = psi + sg q and barrel = psi_b - sg q1 with sg = +-1, cos q = cq,
        # sin q = -sq, cos q1 = c1, sin q1 = -s1 (q, q1 = -acos).
        cp, sp = math.cos(c.psi), math.sin(c.psi)
        cb, sb = math.cos(c.psi_b), math.sin(c.psi_b)
        trig_theta = (cp * cq + sg * sp * sq, sp * cq - sg * cp * sq)
        trig_barrel = (cb * c1 - sg * sb * s1, sb * c1 + sg * cb * s1)
        return (c.psi + sg * q, k1 * xd, dk1 * xd * xd + k1 * xdd,  # eq. (5)
                c.psi_b - sg * q1, k2 * xd, dk2 * xd * xd + k2 * xdd, k1, k2, dk1, dk2,
                trig_theta, trig_barrel)

    def tree_coordinates(self, ops, q, qd, qdd):
        """Tree joint motion (per body) from the independent coordinates, eqs. (5)-(8).

        Returns:
            ``(q_t, qd_t, qdd_t, k1, k2, dk1, dk2, trig)``: per-body lists (``trig[i]``:
            ``(cos, sin)`` of a chain joint's angle, else None) and per-chain lists.
        """
        n = len(self.bodies)
        qt, qdt, qddt = [0.0] * n, [0.0] * n, [0.0] * n
        trig = [None] * n
        for i, b in self.direct:
            qt[b], qdt[b], qddt[b] = q[i], qd[i], qdd[i]
        k1s, k2s, dk1s, dk2s = [], [], [], []
        for c in self.chains:
            i = c.coordinate
            (th, thd, thdd, br, brd, brdd, k1, k2, dk1, dk2, trig[c.driven],
             trig[c.barrel]) = self.chain_motion(ops, c, q[i], qd[i], qdd[i])
            qt[c.driven], qdt[c.driven], qddt[c.driven] = th, thd, thdd
            qt[c.barrel], qdt[c.barrel], qddt[c.barrel] = br, brd, brdd
            qt[c.piston], qdt[c.piston], qddt[c.piston] = q[i], qd[i], qdd[i]
            k1s.append(k1)
            k2s.append(k2)
            dk1s.append(dk1)
            dk2s.append(dk2)
        return qt, qdt, qddt, k1s, k2s, dk1s, dk2s, trig

    def joint_placement(self, ops, i: int, q, trig=None):
        """Pose (R, p) of body ``i`` in its parent at joint coordinate ``q``.

        ``trig``: ``(cos q, sin q)`` of a revolute joint when known (not computed again).
        """
        b = self.bodies[i]
        r0 = ops.const(b.rotation)
        p0 = ops.const(b.position)
        if b.kind == "revolute":
            k = spatial.skew(b.axis)
            cos_q, sin_q = (ops.cos(q), ops.sin(q)) if trig is None else trig
            rot = ops.const(np.eye(3)) + sin_q * ops.const(k) \
                + (1 - cos_q) * ops.const(k @ k)
            return r0 @ rot, p0
        if b.kind == "prismatic":
            return r0, p0 + ops.const(b.rotation @ b.axis) * q
        return r0, p0

    # ------------------------------------------------------------------ eqs. (9)-(11)
    def dynamics(self, ops, rotation_world_fb, twist, acceleration, q, qd, qdd,
                 gravity: bool = True, payload_mass=None) -> TreeDynamics:
        """Forward recursion of twists and accelerations, then the backward wrench sums.

        Args:
            ops: Array backend (`NumpyOps` or `estimators._symbolic.CasadiOps`).
            rotation_world_fb: Base orientation, world <- fb, (3, 3).
            twist: Base body twist [v; w] in fb, shape (6,).
            acceleration: Its time derivative, shape (6,).
            q: Independent coordinates, shape (13,).
            qd: Their velocities, shape (13,).
            qdd: Their accelerations, shape (13,).
            gravity: Include the weights (as the base acceleration offset, see `spatial`).
            payload_mass: The payload's mass [kg] (a number or a symbol); None: the
                description's (`_payload_parameters`).

        Returns:
            The per-body kinematics, wrenches and tree joint forces.
        """
        qt, qdt, qddt, k1, k2, dk1, dk2, trig = self.tree_coordinates(ops, q, qd, qdd)
        n = len(self.bodies)
        rot_fb, pos_fb = [None] * n, [None] * n
        nu, nud, wrench = [None] * n, [None] * n, [None] * n
        local = [None] * n
        g_up = ops.const([0.0, 0.0, self.gravity if gravity else 0.0])
        offset = ops.vcat([rotation_world_fb.T @ g_up, ops.const(np.zeros(3))])
        for i, b in enumerate(self.bodies):
            if b.parent < 0:
                rot_fb[i], pos_fb[i] = ops.const(np.eye(3)), ops.const(np.zeros(3))
                nu[i] = twist
                nud[i] = acceleration + offset
            else:
                p = b.parent
                r_pi, p_pi = self.joint_placement(ops, i, qt[i], trig[i])
                local[i] = (r_pi, p_pi)
                # Ad_{G_i^p}: twist of the parent expressed in this body's frame.
                ad_ip = ops.adjoint_rp(r_pi.T, -(r_pi.T @ p_pi))
                s = ops.const(b.screw)
                nu[i] = ad_ip @ nu[p] + s * qdt[i]  # eqs. (9a), (10a-c)
                nud[i] = (ad_ip @ nud[p] + s * qddt[i]
                          + ops.ad(nu[i]) @ (s * qdt[i]))  # eqs. (9c), (10d-f)
                rot_fb[i] = rot_fb[p] @ r_pi
                pos_fb[i] = pos_fb[p] + rot_fb[p] @ p_pi
            m = ops.const(b.spatial)
            if i == self.payload_body and payload_mass is not None:
                m = m + (payload_mass - self.payload_mass) * ops.const(
                    self.payload_spatial_per_kg)
            wrench[i] = m @ nud[i] + ops.ad_star(nu[i]) @ (m @ nu[i])  # eq. (11)
        # Backward accumulation. By Theorem 1 the total wrench of a closed chain at its base
        # does not depend on how successor wrenches are shared between its two branches, so
        # the tree's own routing (everything through the driven joint) is as good as any.
        sub = list(wrench)
        for i in range(n - 1, 0, -1):
            r_pi, p_pi = local[i]
            sub[self.bodies[i].parent] = sub[self.bodies[i].parent] \
                + ops.coadjoint_rp(r_pi, p_pi) @ sub[i]
        tau = [0.0] + [ops.dot(ops.const(self.bodies[i].screw), sub[i]) for i in range(1, n)]
        return TreeDynamics(rot_fb, pos_fb, nu, nud, wrench, sub, tau, qt, qdt, qddt,
                            k1, k2, dk1, dk2)
