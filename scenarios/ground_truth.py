"""Ground-truth wheel contacts: MuJoCo's contact forces summed per wheel, in fb."""

from __future__ import annotations

import mujoco
import numpy as np

from models.description import Machine
from models.errors import TerrainError
from models.mujoco import MujocoIndex
from models.state import WheelContacts
from models.terrain import Terrain
from scenarios.errors import SimulatorError

__all__ = ["CONTACT_FORCE_THRESHOLD", "GroundTruthContacts"]

CONTACT_FORCE_THRESHOLD = 1.0  # [N] normal force above which a wheel counts as in contact
_CONTACT_ROWS = np.arange(3)  # an elliptic condim-3 contact: normal, tangent 1, tangent 2


class GroundTruthContacts:
    """Reads the four wheels' contacts from MuJoCo's contact list.

    For each wheel, the ground's force on it is summed over the wheel's contacts. Per
    contact this is ``mj_contactForce`` (in the contact frame, acting on the contact's
    second geom; its sign is flipped when the wheel is the first geom), which for the
    model's elliptic cones is the contact's rows of ``efc_force``, read here for all
    contacts at once. The contact point is the normal-force-weighted mean of the contact
    points, the normal the normalised weighted mean of the contact normals (out of the
    ground). A wheel is in contact when its normal force exceeds
    `CONTACT_FORCE_THRESHOLD`; otherwise its point is the wheel's point nearest the
    terrain plane below it and its normal that plane's normal.

    Args:
        model: The MuJoCo model of the machine on the terrain.
        index: Addresses in ``model``.
        machine: The machine description (wheel radius).
        terrain: The ground (normals under airborne wheels).

    Raises:
        SimulatorError: The model's wheel contacts are not elliptic condim-3 contacts.
    """

    def __init__(self, model: mujoco.MjModel, index: MujocoIndex, machine: Machine,
                 terrain: Terrain):
        self._index = index
        self._wheel_radius = machine.wheel_radius
        self._terrain = terrain
        self._wheel_of_geom = np.full(model.ngeom, -1)
        self._wheel_of_geom[index.wheel_geoms] = np.arange(4)
        terrain_geom = index.terrain_geom
        if (model.opt.cone != mujoco.mjtCone.mjCONE_ELLIPTIC
                or model.geom_condim[terrain_geom] != 3
                or model.geom_priority[terrain_geom] <= 0):
            raise SimulatorError("wheel contacts are read as elliptic condim-3 contacts, "
                                 "which this model does not have")

    def read(self, d: mujoco.MjData, base_position: np.ndarray,
             base_rotation: np.ndarray) -> WheelContacts:
        """The wheel contacts of the state ``d``'s contact list belongs to.

        Args:
            d: MuJoCo data after a forward evaluation (or a step).
            base_position: fb origin in the world [m], shape (3,).
            base_rotation: Rotation world <- fb, shape (3, 3).

        Returns:
            Forces [N], points [m] and normals in fb, shape (4, 3) each, order FL, RL, FR,
            RR, and the contact flags.
        """
        ix = self._index
        force, point, normal, normal_force = (np.zeros((4, 3)), np.zeros((4, 3)),
                                              np.zeros((4, 3)), np.zeros(4))
        n = d.ncon
        if n:
            contact = d.contact
            geoms = contact.geom
            wheel = self._wheel_of_geom[geoms[:, 1]]
            sign = 1.0
            rows = contact.efc_address
            if (wheel < 0).any() or (rows < 0).any():  # not the usual (ground, wheel) pairs
                first = wheel < 0
                wheel = np.where(first, self._wheel_of_geom[geoms[:, 0]], wheel)
                sign = np.where(first, -1.0, 1.0)[:, None]
                keep = (wheel >= 0) & (rows >= 0)
                wheel, rows, sign = wheel[keep], rows[keep], sign[keep]
                frames = contact.frame[keep].reshape(-1, 3, 3)
                positions = contact.pos[keep]
            else:
                frames = contact.frame.reshape(n, 3, 3)
                positions = contact.pos
            if wheel.size:
                f_contact = d.efc_force[rows[:, None] + _CONTACT_ROWS]  # normal, t1, t2
                fn = f_contact[:, :1]
                select = np.zeros((4, wheel.size))
                select[wheel, np.arange(wheel.size)] = 1.0
                # Rows of frames are the normal (geom 0 -> geom 1) and tangents: f^T frame.
                force = select @ (sign * (f_contact[:, None, :] @ frames)[:, 0])
                normal_force = select @ fn[:, 0]
                point = select @ (fn * positions)
                normal = select @ (sign * fn * frames[:, 0])
        in_contact = normal_force > CONTACT_FORCE_THRESHOLD
        if in_contact.all():
            point /= normal_force[:, None]
            normal /= np.sqrt(np.einsum("ij,ij->i", normal, normal))[:, None]
        else:
            touching = np.flatnonzero(in_contact)
            point[touching] /= normal_force[touching, None]
            normal[touching] /= np.sqrt(np.einsum("ij,ij->i", normal[touching],
                                                  normal[touching]))[:, None]
            radius = self._wheel_radius
            for k in np.flatnonzero(~in_contact):
                c = d.xpos[ix.wheel_bodies[k]]
                try:
                    normal[k] = self._terrain.normal(c[0], c[1])
                except TerrainError:  # driven off the terrain
                    normal[k] = (0.0, 0.0, 1.0)
                point[k] = c - radius * normal[k]
        rotation = np.asarray(base_rotation)  # rows of (f @ R) are R^T f
        return WheelContacts.from_owned(in_contact=in_contact, force_in_fb=force @ rotation,
                                        point_in_fb=(point - base_position) @ rotation,
                                        normal_in_fb=normal @ rotation)
