"""Pinocchio model of the machine, built from the same `Machine` description as MuJoCo's.

The Pinocchio model is the kinematic *tree* of the description: a free-flyer root (the
chassis, frame fb) and one joint per moving body. Loop closures are not part of the model;
consistency with the closed chains comes from setting the tree coordinates with
`TreeCoordinates` (eqs. 5-8): `PinocchioMachine.configuration(state)` does that, so every
configuration built through it satisfies the loop constraints exactly. Bodies with a
``fixed`` joint are merged into their parent's joint (their inertia appended there) and
keep a frame of their own.

Free-flyer convention (Pinocchio's): ``q[:3]`` fb position in the world, ``q[3:7]`` its
quaternion (x, y, z, w); ``v[:6]`` the body twist [v; w] of fb in fb; ``a[:6]`` its time
derivative. This matches `MachineState`'s base fields one to one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from models.description import Machine
from models.state import MachineState

__all__ = ["PinocchioMachine", "build_pinocchio"]

_UNIT = {(1.0, 0.0, 0.0): pin.JointModelRX, (0.0, 1.0, 0.0): pin.JointModelRY,
         (0.0, 0.0, 1.0): pin.JointModelRZ}
_UNIT_P = {(1.0, 0.0, 0.0): pin.JointModelPX, (0.0, 1.0, 0.0): pin.JointModelPY,
           (0.0, 0.0, 1.0): pin.JointModelPZ}


def _joint_model(kind: str, axis) -> pin.JointModel:
    key = tuple(float(a) for a in axis)
    if kind == "revolute":
        return _UNIT[key]() if key in _UNIT else pin.JointModelRevoluteUnaligned(
            np.asarray(axis, float))
    return _UNIT_P[key]() if key in _UNIT_P else pin.JointModelPrismaticUnaligned(
        np.asarray(axis, float))


class PinocchioMachine:
    """Pinocchio model and data of a `Machine`, plus the map from `MachineState`.

    Args:
        machine: The machine description.

    Attributes:
        model: The `pin.Model` (free flyer + one joint per moving body).
        data: A `pin.Data` for it.
        coordinates: The `TreeCoordinates` used to close the chains.
        joint_q_index: Joint name -> index in ``q``.
        joint_v_index: Joint name -> index in ``v``.
        frame_id: Body (and ``tcp``) name -> frame id.
    """

    def __init__(self, machine: Machine):
        self.machine = machine
        self.coordinates = machine.coordinates
        model = pin.Model()
        model.name = "machine"
        model.gravity = pin.Motion(np.array([0, 0, -machine.gravity, 0, 0, 0]))
        # Body name -> (joint id, placement of the body frame in the joint frame).
        where: dict[str, tuple[int, pin.SE3]] = {}
        self.frame_id: dict[str, int] = {}
        for body in machine.depth_first:  # subtrees contiguous, as CRBA needs
            inertia = pin.Inertia(body.inertia.mass, np.asarray(body.inertia.com),
                                  np.asarray(body.inertia.inertia))
            local = pin.SE3(np.asarray(body.rotation), np.asarray(body.position))
            if body.parent is None:
                jid = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(),
                                     body.name)
                placement = pin.SE3.Identity()
            else:
                pjid, pplace = where[body.parent]
                if body.joint.kind == "fixed":
                    jid, placement = pjid, pplace * local
                else:
                    jid = model.addJoint(pjid, _joint_model(body.joint.kind, body.joint.axis),
                                         pplace * local, body.name)
                    placement = pin.SE3.Identity()
            model.appendBodyToJoint(jid, inertia, placement)
            if body.joint.kind == "fixed" and body.parent is not None:
                parent_frame = self.frame_id[body.parent]
            else:
                parent_frame = model.addJointFrame(jid, 0)
            fid = model.addBodyFrame(body.name, jid, placement, parent_frame)
            self.frame_id[body.name] = fid
            where[body.name] = (jid, placement)
        tjid, tplace = where[machine.tcp_body]
        self.frame_id["tcp"] = model.addFrame(pin.Frame(
            "tcp", tjid, tplace * pin.SE3(np.eye(3), np.asarray(machine.tcp_position)),
            pin.FrameType.OP_FRAME))
        self.model = model
        self.data = model.createData()
        self.joint_q_index = {model.names[j]: model.idx_qs[j] for j in range(1, model.njoints)}
        self.joint_v_index = {model.names[j]: model.idx_vs[j] for j in range(1, model.njoints)}
        names = self.coordinates.joint_names
        self._tree_q_idx = np.array([self.joint_q_index[n] for n in names])
        self._tree_v_idx = np.array([self.joint_v_index[n] for n in names])

    def configuration(self, state: MachineState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pinocchio (q, v, a) of a state, with every closed chain consistent (eqs. 5-8).

        Returns:
            q: shape (nq,), v: shape (nv,), a: shape (nv,).
        """
        q = np.zeros(self.model.nq)
        v = np.zeros(self.model.nv)
        a = np.zeros(self.model.nv)
        q[:3] = state.base_position
        q[3:7] = pin.Quaternion(state.base_rotation).normalized().coeffs()
        v[:6] = state.base_twist
        a[:6] = state.base_acceleration
        qt, vt, at = self.coordinates.joint_motion(state.q, state.qd, state.qdd)
        q[self._tree_q_idx] = qt
        v[self._tree_v_idx] = vt
        a[self._tree_v_idx] = at
        return q, v, a

    def base_wrench(self, state: MachineState) -> np.ndarray:
        """Free-flyer rows of RNEA [N, N m], shape (6,).

        This is the wrench [f; m] in fb that the environment must apply to the machine for
        the state's motion under gravity.
        """
        q, v, a = self.configuration(state)
        return pin.rnea(self.model, self.data, q, v, a)[:6].copy()

    def center_of_mass(self, state: MachineState) -> np.ndarray:
        """Whole-machine centre of mass in the world [m], shape (3,)."""
        q, _, _ = self.configuration(state)
        return pin.centerOfMass(self.model, self.data, q).copy()


def build_pinocchio(machine: Machine) -> PinocchioMachine:
    """Build the Pinocchio model of ``machine``."""
    return PinocchioMachine(machine)


PAYLOAD_PAIR_MASSES = (1.0, 2.0)  # [kg] the payload masses of `payload_pair`
_PAIRS: dict[str, tuple[PinocchioMachine, PinocchioMachine]] = {}


def payload_pair(machine: Machine) -> tuple[PinocchioMachine, PinocchioMachine]:
    """Models of ``machine`` with the payload at the two `PAYLOAD_PAIR_MASSES` (cached).

    The dynamics are linear in the inertial parameters and the payload's inertia scales
    with its mass about a fixed centre of mass, so anything computed from them is affine in
    the payload mass: ``x(m) = x_1 + (m - m_1) (x_2 - x_1) / (m_2 - m_1)``.
    """
    key = machine.fingerprint
    if key not in _PAIRS:
        body = next(b for b in machine.bodies if b.name == machine.payload)
        models = []
        for m in PAYLOAD_PAIR_MASSES:
            inertia = replace(body.inertia, mass=m, inertia=np.asarray(body.inertia.inertia)
                              * (m / body.inertia.mass))
            bodies = tuple(replace(b, inertia=inertia) if b.name == machine.payload else b
                           for b in machine.bodies)
            models.append(PinocchioMachine(replace(machine, bodies=bodies)))
        if len(_PAIRS) >= 8:
            _PAIRS.pop(next(iter(_PAIRS)))
        _PAIRS[key] = (models[0], models[1])
    return _PAIRS[key]
