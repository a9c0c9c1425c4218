"""One contact per wheel and terrain face: MuJoCo's coincident height-field contacts merged.

MuJoCo collides a convex geom with a height field prism by prism (each grid cell's two
triangles) and reports one contact for every prism the geom reaches. A wheel sphere on a patch
of the terrain made of several triangles therefore gets two to four contacts within a few
centimetres of each other with the same normal, and one riding along the ridge between two
triangles gets two at the same point. Each is a constraint of its own, so the ground under
that wheel is two to four times as stiff as under a wheel in the middle of a triangle, and the
count changes every time a wheel rolls over a triangle's edge. Measured on the development
draws (random family, master seed 1, draw 22): a wheel riding along a ridge with two
coincident contacts leaves the ground for single 2 ms steps while it carries 2.6-3.1 kN, a
drop to 0 N that no tyre would show and that the physics-rate safety metric counts.

`ContactMerge` runs MuJoCo's step in its two halves and, in between, keeps of each group of
coincident contacts of one wheel (normals within `MERGE_ANGLE`, points within
`MERGE_DISTANCE`) only the deepest, the point a sphere on that plane touches. The others are
excluded (MuJoCo's ``mjContact.exclude``) and the constraints are rebuilt, so the dropped
contacts carry no force and have no ``efc_address``. Contacts with normals further apart (a
wheel in a valley touching both flanks) all stay. On a plane the sphere has one contact and
nothing changes.

Simplification, said so: a tyre's contact patch is not modelled; the merged contact is the
one point of the paper's wheel model on each face.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from models.errors import ModelError

__all__ = ["MERGE_ANGLE", "MERGE_DISTANCE", "ContactMerge"]

MERGE_ANGLE = math.radians(3.0)  # [rad] normals closer than this: the same face
MERGE_DISTANCE = 0.05  # [m] points closer than this: the same contact (a few cm of patch)


class ContactMerge:
    """MuJoCo's step and forward with coincident wheel contacts merged (see module doc).

    Args:
        model: The MuJoCo model.
        wheel_geoms: The wheels' collision geom ids (any order).
        angle: Normals within this angle [rad] belong to the same face.
        distance: Contact points within this distance [m] belong to the same contact.
    """

    def __init__(self, model: mujoco.MjModel, wheel_geoms, angle: float = MERGE_ANGLE,
                 distance: float = MERGE_DISTANCE):
        if not (math.isfinite(angle) and 0.0 <= angle < math.pi / 2):
            raise ModelError(f"angle must be in [0, pi/2) rad, got {angle!r}")
        if not (math.isfinite(distance) and distance >= 0.0):
            raise ModelError(f"distance must be a finite length >= 0 m, got {distance!r}")
        geoms = np.asarray(wheel_geoms, dtype=int).ravel()
        if geoms.size == 0 or geoms.min() < 0 or geoms.max() >= model.ngeom:
            raise ModelError(f"wheel_geoms must be geom ids in [0, {model.ngeom}), "
                             f"got {wheel_geoms!r}")
        self._model = model
        self._owner = np.full(model.ngeom, -1)
        self._owner[geoms] = np.arange(geoms.size)
        self._n_wheels = geoms.size
        self._cos = math.cos(angle)
        self._distance2 = distance * distance

    def step(self, data: mujoco.MjData) -> None:
        """`mujoco.mj_step` with the coincident contacts merged.

        For the Euler and implicit integrators, as `mujoco.mj_step2`.
        """
        m = self._model
        mujoco.mj_step1(m, data)
        if self.merge(data):
            self._rebuild(data)
        mujoco.mj_step2(m, data)

    def forward(self, data: mujoco.MjData) -> None:
        """`mujoco.mj_forward` with the coincident contacts merged."""
        m = self._model
        mujoco.mj_step1(m, data)  # position and velocity stages; does not integrate
        if self.merge(data):
            self._rebuild(data)
        mujoco.mj_fwdActuation(m, data)
        mujoco.mj_fwdAcceleration(m, data)
        mujoco.mj_fwdConstraint(m, data)
        mujoco.mj_sensorAcc(m, data)

    def merge(self, data: mujoco.MjData) -> int:
        """Exclude the coincident contacts in ``data.contact``; returns how many.

        Call between MuJoCo's collision and its constraint stage; the constraints must then
        be rebuilt (`step` and `forward` do both).
        """
        n = data.ncon
        if n < 2:
            return 0
        con = data.contact
        geom = con.geom
        owner = np.maximum(self._owner[geom[:, 0]], self._owner[geom[:, 1]])
        if np.bincount(owner + 1, minlength=self._n_wheels + 1)[1:].max() < 2:
            return 0
        normal = con.frame[:, :3]
        pos = con.pos
        depth = -con.dist
        live = con.exclude == 0
        same = (owner[:, None] == owner[None, :]) & (owner[:, None] >= 0) & live[:, None]
        same &= normal @ normal.T > self._cos
        diff = pos[:, None, :] - pos[None, :, :]
        same &= np.einsum("ijk,ijk->ij", diff, diff) < self._distance2
        # Of each group the deepest stays (ties: the first reported): contact j goes if a
        # deeper (or equally deep and earlier) contact i of its group exists.
        index = np.arange(n)
        deeper = (depth[:, None] > depth[None, :]) | (
            (depth[:, None] == depth[None, :]) & (index[:, None] < index[None, :]))
        drop = np.flatnonzero((same & deeper).any(axis=0) & live)
        if drop.size:
            con.exclude[drop] = 1
            con.efc_address[drop] = -1
        return int(drop.size)

    def _rebuild(self, data: mujoco.MjData) -> None:
        """The constraint stage again, after `merge` changed the contacts."""
        m = self._model
        mujoco.mj_makeConstraint(m, data)
        mujoco.mj_island(m, data)
        mujoco.mj_projectConstraint(m, data)
        mujoco.mj_referenceConstraint(m, data)
