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

The merge runs as a few lines of C over MuJoCo's contact array (`MERGE_C`, compiled once with
the system compiler, `models.cbuild`, and called through ctypes: ~50 us of numpy on small
arrays became a few microseconds); `merge_reference` is the same rule in numpy, the fallback
without a compiler and the test's oracle.

Simplification, said so: a tyre's contact patch is not modelled; the merged contact is the
one point of the paper's wheel model on each face.
"""

from __future__ import annotations

import ctypes
import math

import mujoco
import numpy as np

from models.cbuild import load_shared
from models.errors import ModelError

__all__ = ["MERGE_ANGLE", "MERGE_DISTANCE", "MERGE_C", "ContactMerge"]

MERGE_ANGLE = math.radians(3.0)  # [rad] normals closer than this: the same face
MERGE_DISTANCE = 0.05  # [m] points closer than this: the same contact (a few cm of patch)

# `ContactMerge.merge_reference` over mjContact records (byte offsets of the fields given):
# contact j is excluded when a live contact i of the same wheel, normal and place is deeper
# (or as deep and reported first). Returns how many it excluded.
MERGE_C = r"""
#include <string.h>
#define AT(T, base, k, off) (*(T*)((base) + (long)(k) * stride + (off)))
int merge(char* base, int n, long stride, long o_dist, long o_pos, long o_frame,
          long o_geom, long o_exclude, long o_efc, const int* owner_of_geom,
          int n_wheels, double cos_angle, double distance2, int* owner, int* drop) {
  int i, j, count = 0, most = 0;
  int per_wheel[64];
  if (n < 2 || n_wheels > 64) return n < 2 ? 0 : -1;
  memset(per_wheel, 0, sizeof(per_wheel));
  for (i = 0; i < n; ++i) {
    int a = owner_of_geom[AT(int, base, i, o_geom)];
    int b = owner_of_geom[AT(int, base, i, o_geom + 4)];
    owner[i] = a > b ? a : b;
    if (owner[i] >= 0 && ++per_wheel[owner[i]] > most) most = per_wheel[owner[i]];
  }
  if (most < 2) return 0;
  for (j = 0; j < n; ++j) {
    const double* nj = &AT(double, base, j, o_frame);
    const double* pj = &AT(double, base, j, o_pos);
    double dj = -AT(double, base, j, o_dist);
    drop[j] = 0;
    if (owner[j] < 0 || AT(int, base, j, o_exclude) != 0) continue;
    for (i = 0; i < n && !drop[j]; ++i) {
      const double* ni = &AT(double, base, i, o_frame);
      const double* pi = &AT(double, base, i, o_pos);
      double di = -AT(double, base, i, o_dist), dx, dy, dz;
      if (i == j || owner[i] != owner[j] || AT(int, base, i, o_exclude) != 0) continue;
      if (!(di > dj || (di == dj && i < j))) continue;
      if (!(ni[0] * nj[0] + ni[1] * nj[1] + ni[2] * nj[2] > cos_angle)) continue;
      dx = pi[0] - pj[0]; dy = pi[1] - pj[1]; dz = pi[2] - pj[2];
      if (dx * dx + dy * dy + dz * dz < distance2) drop[j] = 1;
    }
  }
  for (j = 0; j < n; ++j)
    if (drop[j]) {
      AT(int, base, j, o_exclude) = 1;
      AT(int, base, j, o_efc) = -1;
      ++count;
    }
  return count;
}
"""


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
        self._owner_c = self._owner.astype(np.int32)  # kept alive: the C code reads it
        self._owner_ptr = self._owner_c.ctypes.data
        self._scratch = np.zeros((2, 0), np.int32)
        self._scratch_ptrs = (0, 0)
        self._offsets: tuple | None = None
        self._merge_c = _compiled_merge() if geoms.size <= 64 else None

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

    @property
    def compiled(self) -> bool:
        """Whether `merge` runs the compiled `MERGE_C` (else `merge_reference`)."""
        return self._merge_c is not None

    def c_arguments(self) -> tuple[np.ndarray, int, float, float]:
        """`MERGE_C`'s rule for a caller in C: (geom -> wheel as int32, wheels, cos, d^2)."""
        return self._owner_c, self._n_wheels, self._cos, self._distance2

    def merge(self, data: mujoco.MjData) -> int:
        """Exclude the coincident contacts in ``data.contact``; returns how many.

        Call between MuJoCo's collision and its constraint stage; the constraints must then
        be rebuilt (`step` and `forward` do both).
        """
        n = data.ncon
        if self._merge_c is None:
            return self.merge_reference(data)
        if n < 2:
            return 0
        con = data.contact
        dist = con.dist
        base = dist.__array_interface__["data"][0]
        if self._offsets is None:  # the mjContact layout: one record's field offsets
            self._offsets = (dist.strides[0],) + tuple(
                getattr(con, f).__array_interface__["data"][0] - base
                for f in ("dist", "pos", "frame", "geom", "exclude", "efc_address"))
        if self._scratch.shape[1] < n:
            self._scratch = np.zeros((2, 2 * n), np.int32)
            self._scratch_ptrs = (self._scratch[0].ctypes.data, self._scratch[1].ctypes.data)
        return self._merge_c(base, n, *self._offsets, self._owner_ptr, self._n_wheels,
                             self._cos, self._distance2, *self._scratch_ptrs)

    def merge_reference(self, data: mujoco.MjData) -> int:
        """`merge` in numpy: the fallback without a C compiler, and the tests' oracle."""
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


def _compiled_merge():
    """`MERGE_C` compiled and loaded (cached), or None without a working compiler."""
    lib = load_shared(MERGE_C, "contact_merge", {"merge": (
        [ctypes.c_void_p, ctypes.c_int] + [ctypes.c_long] * 7
        + [ctypes.c_void_p, ctypes.c_int, ctypes.c_double, ctypes.c_double, ctypes.c_void_p,
           ctypes.c_void_p], ctypes.c_int)}, "numpy")
    return None if lib is None else lib.merge
