"""The paper's independent coordinates and the tree's joint coordinates.

Independent ("actuated") coordinates, the ones a user commands and the estimator takes, in
this order (``N_INDEPENDENT = 13``)::

    [x_bogie_L, x_bogie_R,                       suspension cylinder strokes [m]
     x_slew, x_lift, x_tilt, telescope,          crane cylinder strokes and telescope [m]
     wrist_pitch, wrist_roll, rotator,           wrist joint angles [rad]
     wheel_FL, wheel_RL, wheel_FR, wheel_RR]     wheel spin angles [rad]

Tree coordinates are the 1-DoF joints of `Machine.moving_joints` (the floating base not
included). Each cylinder chain contributes three tree joints (driven joint, barrel, piston)
that are functions of its stroke (eqs. 5-8), so the map is

    q_tree = phi(q_ind),   qd_tree = J qd_ind,   qdd_tree = J qdd_ind + Jdot qd_ind,

with ``J`` holding the chains' k1, k2 and 1, and ``Jdot`` their time derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.description import Machine
from models.errors import StateError

N_INDEPENDENT = 13
SUSPENSION = slice(0, 2)
CRANE = slice(2, 9)
WHEELS = slice(9, 13)


KINDS = ("stroke", "joint", "wheel")


@dataclass(frozen=True)
class Coordinate:
    """One independent coordinate, derived from the machine description.

    Attributes:
        index: Position in the independent vector (order above).
        name: Chain role (``bogie_L``, ``slew``...), direct-drive joint or wheel body name.
        kind: ``stroke`` (cylinder chain, [m]), ``joint`` (directly driven joint, [m] or
            [rad]) or ``wheel`` (spin angle [rad], unbounded).
        lower, upper: Valid position range (stroke range of the chain, joint range, or
            -inf/inf for a wheel) [m or rad].
    """

    index: int
    name: str
    kind: str
    lower: float
    upper: float


class TreeCoordinates:
    """The coordinate table of a machine, and the map independent -> tree coordinates.

    Build it once per machine: `Machine.coordinates` holds one.

    Args:
        machine: The machine description.

    Attributes:
        independent_names: Names of the 13 independent coordinates, order above.
        table: One `Coordinate` per independent coordinate (names, kinds, ranges).
        lower, upper: Valid ranges of all 13, shapes (13,) (wheels: -inf, inf).
        chain_indices: Indices of the chain-driven (stroke) coordinates.
    """

    def __init__(self, machine: Machine):
        self.machine = machine
        self.joint_names = machine.moving_joints
        self.index = {n: i for i, n in enumerate(self.joint_names)}
        self.independent_names = (machine.suspension_coordinates + machine.crane_coordinates
                                  + machine.wheels)
        # (independent index, chain binding) for chain-driven coordinates, else direct joint.
        self._chains = []
        self._direct = []
        table = []
        for i, name in enumerate(self.independent_names):
            if name in machine.chains:
                self._chains.append((i, machine.chains[name]))
                lo, hi = machine.chains[name].chain.stroke_range
                kind = "stroke"
            else:
                self._direct.append((i, self.index[name]))
                if name in machine.wheels:
                    lo, hi, kind = -np.inf, np.inf, "wheel"
                else:
                    rng = machine.body(name).joint.range
                    lo, hi = rng if rng is not None else (-np.inf, np.inf)
                    kind = "joint"
            table.append(Coordinate(i, name, kind, float(lo), float(hi)))
        self.table = tuple(table)
        self.lower = np.array([c.lower for c in table])
        self.upper = np.array([c.upper for c in table])
        self.lower.flags.writeable = False
        self.upper.flags.writeable = False
        self.chain_indices = tuple(i for i, _ in self._chains)

    def binding(self, i: int):
        """The `ChainBinding` of independent coordinate ``i``, or None if not chain-driven."""
        name = self.independent_names[i]
        return self.machine.chains.get(name)

    def chains(self) -> tuple:
        """``(index, ChainBinding)`` of every chain-driven coordinate."""
        return tuple(self._chains)

    def out_of_range(self, q) -> list[tuple[Coordinate, float]]:
        """The coordinates of ``q`` (13,) outside their ranges, with their values."""
        q = np.asarray(q, float)
        bad = np.flatnonzero((q < self.lower) | (q > self.upper))
        return [(self.table[i], float(q[i])) for i in bad]

    def clip(self, q) -> np.ndarray:
        """``q`` (13,) clipped into the valid ranges."""
        return np.clip(np.asarray(q, float), self.lower, self.upper)

    @property
    def n_tree(self) -> int:
        """Number of tree joint coordinates."""
        return len(self.joint_names)

    def _check(self, name: str, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.shape != (N_INDEPENDENT,):
            raise StateError(f"{name} must have shape ({N_INDEPENDENT},), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise StateError(f"{name} has non-finite entries: {x}")
        return x

    def joint_positions(self, q_ind) -> np.ndarray:
        """Tree joint positions from independent positions, shape (n_tree,)."""
        q_ind = self._check("q_ind", q_ind)
        q = np.zeros(self.n_tree)
        for i, j in self._direct:
            q[j] = q_ind[i]
        strokes = q_ind.tolist()
        for i, b in self._chains:
            q[self.index[b.driven_joint]], q[self.index[b.barrel]] = b.chain.angles(strokes[i])
            q[self.index[b.piston]] = q_ind[i]
        return q

    def jacobian(self, q_ind, qd_ind=None) -> tuple[np.ndarray, np.ndarray]:
        """(J, Jdot): d q_tree / d q_ind and its time derivative, shapes (n_tree, 13)."""
        q_ind = self._check("q_ind", q_ind)
        qd_ind = np.zeros(N_INDEPENDENT) if qd_ind is None else self._check("qd_ind", qd_ind)
        jac = np.zeros((self.n_tree, N_INDEPENDENT))
        jdot = np.zeros_like(jac)
        for i, j in self._direct:
            jac[j, i] = 1.0
        strokes = q_ind.tolist()
        for i, b in self._chains:
            s = b.chain.float_state(strokes[i])
            for name, k, dk in ((b.driven_joint, s.k[0], s.dk_dx[0]),
                                (b.barrel, s.k[1], s.dk_dx[1])):
                jac[self.index[name], i] = k
                jdot[self.index[name], i] = dk * qd_ind[i]
            jac[self.index[b.piston], i] = 1.0
        return jac, jdot

    def joint_motion(self, q_ind, qd_ind, qdd_ind) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tree (q, qd, qdd) from independent positions, velocities and accelerations."""
        q = self.joint_positions(q_ind)
        jac, jdot = self.jacobian(q_ind, qd_ind)
        qdd_ind = self._check("qdd_ind", qdd_ind)
        qd_ind = np.asarray(qd_ind, float)
        return q, jac @ qd_ind, jac @ qdd_ind + jdot @ qd_ind

    def home(self) -> np.ndarray:
        """A default independent configuration: level bogies, crane folded over the chassis."""
        m = self.machine
        q = np.zeros(N_INDEPENDENT)
        for i, name in enumerate(self.independent_names[:2]):
            q[i] = m.chains[name].chain.stroke_from_angle(0.0)
        q[2] = m.chains["slew"].chain.stroke_from_angle(0.0)
        q[3] = m.chains["lift"].chain.stroke_from_angle(np.radians(45.0))
        q[4] = m.chains["tilt"].chain.stroke_from_angle(np.radians(-90.0))
        q[5] = 0.5
        q[6] = np.radians(45.0)  # keeps the tool roughly vertical at the home pose
        return q
