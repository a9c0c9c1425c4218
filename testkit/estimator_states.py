"""Helpers that make random and physically consistent states, for tests and benchmarks.

`consistent_contact_state` builds a state whose base acceleration and suspension cylinder
forces are exactly what given ground contact forces produce, computed with the project's
Pinocchio model (`models.pinocchio_model`), independently of this package's recursion.
"""

from __future__ import annotations

import numpy as np

from models.description import Machine
from models.rotations import axis_rotation
from models.state import MachineState, WheelContacts

__all__ = ["consistent_contact_state", "random_rotation", "random_state"]


def random_rotation(rng: np.random.Generator, max_angle: float = np.pi) -> np.ndarray:
    """A random rotation of at most ``max_angle`` [rad] about a random axis, (3, 3)."""
    axis = rng.normal(size=3)
    return axis_rotation(axis, rng.uniform(-max_angle, max_angle))


def random_state(machine: Machine, rng: np.random.Generator, *, max_tilt: float = np.pi,
                 speed: float = 1.0, margin: float = 0.005) -> MachineState:
    """A random state with every stroke in range (closed chains consistent by construction).

    Args:
        machine: The machine.
        rng: Random generator.
        max_tilt: Largest base rotation angle [rad].
        speed: Scale of velocities and accelerations.
        margin: Distance kept from the stroke limits [m].
    """
    tc = machine.coordinates
    q = tc.home()
    for i, name in enumerate(tc.independent_names):
        if name in machine.chains:
            lo, hi = machine.chains[name].chain.stroke_range
            q[i] = rng.uniform(lo + margin, hi - margin)
        elif name in machine.wheels:
            q[i] = rng.uniform(-np.pi, np.pi)
        else:
            body = machine.body(name)
            lo, hi = body.joint.range if body.joint.range else (-np.pi, np.pi)
            q[i] = rng.uniform(lo, hi)
    return MachineState(
        base_position=rng.normal(size=3), base_rotation=random_rotation(rng, max_tilt),
        base_twist=speed * rng.normal(size=6), base_acceleration=speed * rng.normal(size=6),
        q=q, qd=speed * rng.normal(size=13), qdd=speed * rng.normal(size=13))


def consistent_contact_state(machine: Machine, state: MachineState, points_in_fb: np.ndarray,
                             forces_in_fb: np.ndarray, pinocchio_machine=None,
                             in_contact=None) -> MachineState:
    """The state whose dynamics the given ground forces produce exactly (Pinocchio oracle).

    The base acceleration is solved from the free-flyer rows of the equations of motion
    (``M_bb a_b + h_b(qdd) = sum of contact wrenches``), and the suspension cylinder forces
    from the chains' generalised-force equations ``J_x^T (tau_tree - tau_contact) = F_cyl``.

    Args:
        machine: The machine.
        state: Template state (pose, twist, q, qd, qdd are kept).
        points_in_fb: Contact point of each wheel in fb [m], (4, 3), order FL, RL, FR, RR.
        forces_in_fb: Ground force on each wheel in fb [N], (4, 3).
        pinocchio_machine: A `models.pinocchio_model.PinocchioMachine` (built if None).
        in_contact: Contact flags (default: wheels with a non-zero force).

    Returns:
        The state with consistent base acceleration, contacts and suspension forces.
    """
    import pinocchio as pin

    from models.pinocchio_model import build_pinocchio

    pm = pinocchio_machine if pinocchio_machine is not None else build_pinocchio(machine)
    model, data = pm.model, pm.data
    points = np.asarray(points_in_fb, float)
    forces = np.asarray(forces_in_fb, float)
    contact = np.zeros(6)
    for p, f in zip(points, forces):
        contact += np.concatenate([f, np.cross(p, f)])
    zero = MachineState(state.base_position, state.base_rotation, state.base_twist,
                        np.zeros(6), state.q, state.qd, state.qdd)
    q, v, a = pm.configuration(zero)
    w0 = pin.rnea(model, data, q, v, a)[:6].copy()
    mass = pin.crba(model, data, q)
    mbb = np.triu(mass[:6, :6]) + np.triu(mass[:6, :6], 1).T
    base_acc = np.linalg.solve(mbb, contact - w0)
    solved = MachineState(state.base_position, state.base_rotation, state.base_twist,
                          base_acc, state.q, state.qd, state.qdd)
    q, v, a = pm.configuration(solved)
    pin.forwardKinematics(model, data, q)
    rot, pos = state.base_rotation, state.base_position
    fext = [pin.Force.Zero() for _ in range(model.njoints)]
    for w, p, f in zip(machine.wheels, points, forces):
        j = model.getJointId(w)
        pw, fw = rot @ p + pos, rot @ f
        fext[j] = fext[j] + data.oMi[j].actInv(pin.Force(fw, np.cross(pw, fw)))
    tau = pin.rnea(model, data, q, v, a, fext)
    tc = pm.coordinates
    jac, _ = tc.jacobian(state.q, state.qd)
    susp = []
    for name in machine.suspension_coordinates:
        i = tc.independent_names.index(name)
        cb = machine.chains[name]
        f_cyl = 0.0
        for joint in (cb.driven_joint, cb.barrel, cb.piston):
            body = machine.body(joint)
            k = jac[tc.index[joint], i]
            jv = pm.joint_v_index[joint]
            f_cyl += k * (tau[jv] + body.joint.damping * v[jv] + body.joint.armature * a[jv])
        susp.append(f_cyl)
    flags = np.linalg.norm(forces, axis=1) > 0 if in_contact is None else in_contact
    normals = np.tile(rot[2], (4, 1))
    return MachineState(state.base_position, state.base_rotation, state.base_twist, base_acc,
                        state.q, state.qd, state.qdd, state.time,
                        WheelContacts(flags, forces, points, normals), np.array(susp))
