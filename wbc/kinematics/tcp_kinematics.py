"""Tool-point (TCP) kinematics in the floating-base frame, from the Pinocchio model.

The TCP frame is `Machine.tcp_body` at `Machine.tcp_position`; Pinocchio's model names it
``tcp`` (`models.pinocchio_model`). Positions here are expressed in fb (the chassis frame):
the crane is mounted on the chassis, so the TCP position in fb depends on the crane
coordinates only.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.pinocchio_model import PinocchioMachine, build_pinocchio
from models.state import MachineState
from wbc.axes import N_AXES
from wbc.errors import WbcInputError
from wbc.kinematics.tcp_c import compiled_tcp_tree

__all__ = ["TcpKinematics"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_Q_SHAPE = (N_INDEPENDENT,)


class TcpKinematics:
    """Position, Jacobian and bias acceleration of the TCP in fb.

    Args:
        machine: The machine description.
        pinocchio_machine: An existing `PinocchioMachine` of ``machine`` (its model is
            shared; this object keeps its own `pin.Data`).
        compiled: `position` writes the TCP's configuration in C (`wbc.kinematics.tcp_c`,
            the same bits) when a compiler is there; False: the Python path (the reference).
    """

    def __init__(self, machine: Machine, pinocchio_machine: PinocchioMachine | None = None,
                 compiled: bool = True):
        self.pm = pinocchio_machine if pinocchio_machine is not None else build_pinocchio(
            machine)
        self.model = self.pm.model
        self.data = self.model.createData()
        self.frame_id = self.pm.frame_id["tcp"]
        names = self.pm.coordinates.joint_names
        self._tree_v = np.array([self.pm.joint_v_index[n] for n in names])
        self._eye = np.eye(3)
        # Pinocchio's configuration of a state at the fb origin, level: the base part of
        # `PinocchioMachine.configuration` for the identity attitude (quaternion 0, 0, 0, 1).
        self._q_level = np.zeros(self.model.nq)
        self._q_level[6] = 1.0
        self._position_plan(compiled)

    def _position_plan(self, compiled: bool) -> None:
        """What `position` computes: the tree coordinates of the TCP's supporting joints.

        The TCP's placement is a product of the placements of the joints that support its
        body (Pinocchio's ``model.supports``): the chassis (level, at the origin) and the
        crane. The other joints (bogies, wheels, the cylinders' barrels and pistons) do not
        enter it, so `position` leaves them at zero and computes no angle for them; it
        still checks every chain's stroke, as `TreeCoordinates.joint_positions` does.
        """
        coords = self.pm.coordinates
        parent = self.model.frames[self.frame_id].parentJoint
        supports = {self.model.names[j] for j in self.model.supports[parent]}
        q_index = self.pm.joint_q_index
        self._direct = tuple((i, q_index[name]) for i, name in
                             enumerate(coords.independent_names)
                             if name in supports and coords.binding(i) is None)
        self._chains = tuple((i, b.chain, q_index[b.driven_joint] if b.driven_joint in supports
                              else None) for i, b in coords.chains())
        self._qp = self._q_level.copy()  # kept: the supporting entries are rewritten each call
        self._q_in = np.zeros(N_INDEPENDENT)  # the C's input
        bound = compiled_tcp_tree(self._direct, self._chains, self._q_in, self._qp) \
            if compiled else None
        self._tree_c, self._keep = (None, None) if bound is None else bound

    @staticmethod
    def _checked(q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (N_INDEPENDENT,) or not np.all(np.isfinite(q)):
            raise WbcInputError(f"q must be finite with shape ({N_INDEPENDENT},), got "
                                f"shape {q.shape}")
        return q

    def _configuration(self, q, qd=None):
        q = self._checked(q)
        qd = np.zeros(N_INDEPENDENT) if qd is None else np.asarray(qd, dtype=float)
        st = MachineState(np.zeros(3), self._eye, np.zeros(6), np.zeros(6), q, qd,
                          np.zeros(N_INDEPENDENT))
        return self.pm.configuration(st)

    def position(self, q) -> np.ndarray:
        """TCP position in fb [m], shape (3,), for independent coordinates q (13,).

        Positions only: of the tree's joint positions (`TreeCoordinates.joint_positions`,
        the same numbers `_configuration` gives) those of the joints that support the TCP
        (`_position_plan`), without velocities and Jacobian.

        Raises:
            WbcInputError: ``q`` of the wrong shape or non-finite.
            StrokeOutOfRangeError: A chain's stroke outside its range.
        """
        if self._tree_c is not None and type(q) is np.ndarray and q.shape == _Q_SHAPE \
                and q.dtype == np.float64:
            self._q_in[:] = q
            if self._tree_c() == 0:
                return self._tcp(self._qp)
        return self._position_python(q)

    def _position_python(self, q) -> np.ndarray:
        """`position` in Python (the reference of `tcp_c`; its typed errors)."""
        x = self._checked(q).tolist()
        qp = self._qp
        for i, j in self._direct:
            qp[j] = x[i]
        for i, chain, j in self._chains:
            if j is None:
                chain.check_stroke(x[i])
            else:
                qp[j] = chain.angles(x[i])[0]
        return self._tcp(qp)

    def _tcp(self, qp: np.ndarray) -> np.ndarray:
        """The TCP's position [m] (3,) at Pinocchio's configuration ``qp`` (a copy).

        The joints' placements, then the TCP frame's alone: `pin.updateFramePlacement` is the
        product `pin.framesForwardKinematics` makes for each of the 53 frames (the same
        bits), of the one frame read.
        """
        pin.forwardKinematics(self.model, self.data, qp)
        return pin.updateFramePlacement(self.model, self.data, self.frame_id).translation.copy()

    def jacobian(self, q) -> np.ndarray:
        """``d p_tcp / d q_axes`` [m/m, m/rad], shape (3, 9), columns the nine axes."""
        qp, _, _ = self._configuration(q)
        j6 = pin.computeFrameJacobian(self.model, self.data, qp, self.frame_id, _LWA)
        jac_ind, _ = self.pm.coordinates.jacobian(q)
        return j6[:3, self._tree_v] @ jac_ind[:, :N_AXES]

    def bias_acceleration(self, q, qd) -> np.ndarray:
        """TCP acceleration at zero independent accelerations [m/s^2], shape (3,).

        This is ``Jdot qd`` of the independent-coordinate Jacobian (the chains' ``k_dot``
        terms included through `TreeCoordinates`).
        """
        qp, vp, ap = self._configuration(q, qd)
        pin.forwardKinematics(self.model, self.data, qp, vp, ap)
        return pin.getFrameClassicalAcceleration(self.model, self.data, self.frame_id,
                                                 _LWA).linear.copy()

    def velocity(self, q, qd) -> np.ndarray:
        """TCP velocity in fb [m/s], shape (3,)."""
        return self.jacobian(q) @ np.asarray(qd, float)[:N_AXES]
