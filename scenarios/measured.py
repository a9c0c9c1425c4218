"""The simulator's measured instant as a `MachineState` and the ground-truth wheel contacts.

`Simulator.measure` reads here: pose, twist and its derivative of the chassis, the
independent coordinates and their rates (stroke rates through the driven joints), the
suspension cylinders' forces and the servos' setpoints, all of the instant the simulator's
snapshot belongs to (see `scenarios.simulator`), with the optional `MeasurementNoise`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.mujoco import MujocoIndex
from models.state import MachineState, WheelContacts
from models.terrain import Terrain
from scenarios.base_motion import body_motion
from scenarios.ground_truth import GroundTruthContacts
from scenarios.noise import MeasurementNoise

__all__ = ["Measurement"]


class Measurement:
    """Turns MuJoCo's data of a measured instant into what `Simulator.measure` reports.

    Args:
        model, data: The simulator's MuJoCo model and data.
        index: Addresses in the model.
        machine: The machine description.
        terrain: The ground (normals under airborne wheels).
        noise: Noise added to the measured state, or None.
        rng: The noise's random generator.
    """

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, index: MujocoIndex,
                 machine: Machine, terrain: Terrain, noise: MeasurementNoise | None,
                 rng: np.random.Generator):
        self._data, self._index = data, index
        self._noise, self._rng = noise, rng
        self.contacts = GroundTruthContacts(model, index, machine, terrain)
        coordinates = machine.coordinates
        bindings = [(i, coordinates.binding(i)) for i in coordinates.chain_indices]
        self._chain_rates = [(i, b.chain, index.dof_adr[b.driven_joint]) for i, b in bindings]

    def measure(self, snapshot: tuple, setpoint: np.ndarray
                ) -> tuple[MachineState, WheelContacts]:
        """`Simulator.measure` of the instant ``snapshot = (qpos, qvel, time)``.

        Args:
            snapshot: MuJoCo's ``qpos``, ``qvel`` and time of the measured instant (the
                derived quantities in ``data`` belong to it).
            setpoint: The servos' setpoints of that instant (kept by the state: never
                written afterwards).
        """
        qpos, qvel, t = snapshot
        d, ix = self._data, self._index
        rotation = d.xmat[ix.base_body].reshape(3, 3).copy()  # of the measured instant
        position = d.xpos[ix.base_body].copy()
        twist, accel = body_motion(rotation, qvel[ix.base_dof], d.qacc[ix.base_dof])
        truth = self.contacts.read(d, position, rotation)
        q = qpos[ix.independent_qpos]
        qd = qvel[ix.independent_dof].copy()
        qdd = d.qacc[ix.independent_dof].copy()
        # Stroke rates through the driven joint (eq. 6: x_dot = theta_dot / k1): MuJoCo's
        # soft loop closures let the light piston's acceleration differ from the heavy driven
        # link's by their stabilisation term, and the driven link carries the dynamics.
        # (Python floats: numpy scalars' IEEE operations at a fraction of the cost.)
        strokes, qvel_all, qacc_all = q.tolist(), qvel.tolist(), d.qacc.tolist()
        for i, chain, dof in self._chain_rates:
            k1, dk1 = chain.driven_rate_coefficients(strokes[i])
            rate = qvel_all[dof] / k1
            qd[i] = rate
            qdd[i] = (qacc_all[dof] - dk1 * rate * rate) / k1
        suspension = d.actuator_force[ix.suspension_actuators]
        measured = truth
        if self._noise is not None:
            nz, rng = self._noise, self._rng
            twist = twist + rng.normal(0.0, nz.base_twist, 6)
            accel = accel + rng.normal(0.0, nz.base_acceleration, 6)
            q = q + rng.normal(0.0, nz.q, N_INDEPENDENT)
            qd = qd + rng.normal(0.0, nz.qd, N_INDEPENDENT)
            qdd = qdd + rng.normal(0.0, nz.qdd, N_INDEPENDENT)
            suspension = suspension + rng.normal(0.0, nz.suspension_force, 2)
            measured = WheelContacts(
                truth.in_contact.copy(),
                truth.force_in_fb + rng.normal(0.0, nz.contact_force, (4, 3)),
                truth.point_in_fb.copy(), truth.normal_in_fb.copy())
        # This call's own arrays (the setpoint snapshot is replaced, never written): kept.
        state = MachineState.from_owned(position, rotation, twist, accel, q, qd, qdd, t, measured,
                                        suspension, setpoint)
        return state, truth
