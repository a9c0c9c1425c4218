"""`MujocoIndex`: the ids and addresses of a compiled model, by the description's names."""

from __future__ import annotations

import mujoco
import numpy as np

from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.errors import ModelError
from models.mujoco.elements import root_body


class MujocoIndex:
    """Addresses of the machine's joints, actuators, geoms and sites in a compiled model.

    Args:
        model: A model built by `build_model` (or loaded from `write_mjcf` files).
        machine: The description it was built from.

    Attributes:
        base_body: Body id of the floating base.
        base_qpos: qpos addresses of the free joint (position, quaternion), shape (7,).
        base_dof: dof addresses of the free joint (world linear, local angular), shape (6,).
        qpos_adr: qpos address of every tree joint, by joint name.
        dof_adr: dof address of every tree joint, by joint name.
        tree_qpos: qpos addresses in `Machine.moving_joints` order, shape (n_tree,).
        tree_dof: dof addresses in `Machine.moving_joints` order, shape (n_tree,).
        independent_names: The 13 independent coordinates (order of `models.coordinates`).
        independent_qpos: qpos address carrying each independent coordinate (the piston
            joint for a cylinder chain), shape (13,).
        independent_dof: Same for dofs, shape (13,).
        actuator_id: Actuator id by independent coordinate name (actuator names are those).
        actuators: Actuator ids in independent order, shape (13,).
        servos: The nine servo actuators (cylinders, telescope, wrist), shape (9,).
        servo_qpos: qpos addresses of their joints (piston joints for chains), shape (9,).
        servo_dof: dof addresses of their joints, shape (9,).
        suspension_actuators: Actuator ids of the two suspension cylinders (L, R).
        wheel_actuators: Wheel actuator ids, order FL, RL, FR, RR.
        wheel_bodies: Wheel body ids, order FL, RL, FR, RR.
        wheel_geoms: Wheel collision geom ids, order FL, RL, FR, RR.
        loop_sites: ``{loop name: (site id on body_a, site id on body_b)}``.
        loop_site_pairs: The same as an array, shape (n_loops, 2).
        tcp_site: Site id of the tool centre point.
        terrain_geom: Geom id of the terrain, -1 if the model has none.
    """

    def __init__(self, model: mujoco.MjModel, machine: Machine):
        def find(objtype, name: str) -> int:
            i = mujoco.mj_name2id(model, objtype, name)
            if i < 0:
                raise ModelError(f"model has no {objtype.name[6:].lower()} '{name}'; was it "
                                 f"built from this machine?")
            return i

        joint, body = mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_BODY
        root = root_body(machine)
        free = find(joint, root)
        self.base_body = find(body, root)
        self.base_qpos = np.arange(model.jnt_qposadr[free], model.jnt_qposadr[free] + 7)
        self.base_dof = np.arange(model.jnt_dofadr[free], model.jnt_dofadr[free] + 6)
        ids = {n: find(joint, n) for n in machine.moving_joints}
        self.qpos_adr = {n: int(model.jnt_qposadr[i]) for n, i in ids.items()}
        self.dof_adr = {n: int(model.jnt_dofadr[i]) for n, i in ids.items()}
        self.tree_qpos = np.array([self.qpos_adr[n] for n in machine.moving_joints])
        self.tree_dof = np.array([self.dof_adr[n] for n in machine.moving_joints])
        coords = machine.coordinates
        self.independent_names = coords.independent_names
        carrier = [machine.chains[n].piston if n in machine.chains else n
                   for n in self.independent_names]
        self.independent_qpos = np.array([self.qpos_adr[n] for n in carrier])
        self.independent_dof = np.array([self.dof_adr[n] for n in carrier])
        actuator = mujoco.mjtObj.mjOBJ_ACTUATOR
        self.actuator_id = {n: find(actuator, n) for n in self.independent_names}
        self.actuators = np.array([self.actuator_id[n] for n in self.independent_names])
        n_servo = N_INDEPENDENT - len(machine.wheels)
        self.servos = self.actuators[:n_servo]
        self.servo_qpos = self.independent_qpos[:n_servo]
        self.servo_dof = self.independent_dof[:n_servo]
        self.suspension_actuators = np.array([self.actuator_id[n]
                                              for n in machine.suspension_coordinates])
        self.wheel_actuators = np.array([self.actuator_id[n] for n in machine.wheels])
        self.wheel_bodies = np.array([find(body, n) for n in machine.wheels])
        geom = mujoco.mjtObj.mjOBJ_GEOM
        self.wheel_geoms = np.array([find(geom, f"{n}_collision") for n in machine.wheels])
        site = mujoco.mjtObj.mjOBJ_SITE
        self.loop_sites = {lp.name: (find(site, f"{lp.name}_a"), find(site, f"{lp.name}_b"))
                           for lp in machine.loops}
        self.loop_site_pairs = np.array(list(self.loop_sites.values()), dtype=int).reshape(-1, 2)
        self.tcp_site = find(site, "tcp")
        self.terrain_geom = mujoco.mj_name2id(model, geom, "terrain")
