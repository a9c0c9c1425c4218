r"""The wheels' contact points, longitudinal forces and contact flags, once per tick.

A wheel whose estimated normal force falls below `CONTACT_OFF_N` is out of contact until
its four-wheel estimate has stayed above `CONTACT_ON_N` for `CONTACT_TICKS` ticks (a wheel
bouncing off the ground reads high before it lands) or exceeds `CONTACT_LANDING_N` once (an
impact; `docs/sensors.md`). The contact points are below the wheels' centres along the
ground's normal (`ContactTracker.points`); the longitudinal forces come from each side's
drive torque (`ContactTracker.longitudinal`).
"""

from __future__ import annotations

import math

import numpy as np

from estimators.observer import contacts_c
from estimators.observer._vec3 import ground_normal, norm
from models.cbuild import bind

__all__ = ["CONTACT_LANDING_N", "CONTACT_OFF_N", "CONTACT_ON_N", "CONTACT_TICKS",
           "ContactTracker"]

CONTACT_OFF_N = 300.0  # [N] below this a wheel is leaving the ground (at once)
CONTACT_ON_N = 800.0  # [N] above this on `CONTACT_TICKS` ticks in a row it is back
CONTACT_TICKS = 3
CONTACT_LANDING_N = 2000.0  # [N] above this once, a lifted wheel has landed (an impact)


class ContactTracker:
    """The contact flags and geometry of the observer's state (module docstring).

    Args:
        radius: The wheels' radius [m].
        inertia: A wheel's spin inertia (with its joint's armature) [kg m^2].
        sphere: Sphere wheels (else discs, their axes fb's y).
        compiled: Run the arithmetic in C (`contacts_c`, the same bits) when a C compiler
            is there; False: Python.

    Attributes:
        wheel_acceleration: The wheels' spin accelerations [rad/s^2] (4 floats, FL, RL, FR,
            RR).
    """

    def __init__(self, radius: float, inertia: float, sphere: bool, compiled: bool = True):
        self.radius, self.inertia, self.sphere = float(radius), float(inertia), bool(sphere)
        self._in_contact = [True] * 4  # Python's (`in_contact`)
        self._above = [0] * 4
        self._drive_py: list | None = None  # Python's (`drive`)
        self.wheel_acceleration = [0.0] * 4
        lib = contacts_c.compiled_contacts() if compiled else None
        self._c = None
        if lib is not None:
            k = np.array([self.radius, self.inertia, float(self.sphere), CONTACT_ON_N,
                          CONTACT_OFF_N, CONTACT_TICKS, CONTACT_LANDING_N])
            self._lowest, self._points, self._normals, self._force = np.zeros((4, 4, 3))
            self._up, self._drive, self._acc, self._fz = np.zeros(3), np.zeros(3), \
                np.zeros(4), np.zeros(4)
            self._touching, self._above_c = np.ones(4), np.zeros(4)
            self._k = k
            self._c = bind(lib.contact_points, k, self._lowest, self._up, self._touching,
                           self._drive, self._acc, self._fz, self._points, self._normals,
                           self._force)
            self._flags_c = bind(lib.contact_flags, k, self._above_c, self._touching,
                                 self._drive, self._acc, self._fz, self._force)

    @property
    def in_contact(self) -> list:
        """The contact flags (4 bools, FL, RL, FR, RR): C's buffer's, or Python's."""
        if self._c is not None:
            return (self._touching != 0.0).tolist()
        return self._in_contact

    @property
    def drive(self) -> list | None:
        """Each side's mean drive torque [N m] (left, right), None before any reading."""
        if self._c is not None:
            return self._drive[1:].tolist() if self._drive[0] != 0.0 else None
        return self._drive_py

    def set_drive(self, torques: np.ndarray) -> None:
        """The tick's drive torques (k, 2) [N m], k > 0: their mean is each side's."""
        n = torques.shape[0]
        if self._c is None:
            self._drive_py = (np.add.reduce(torques, 0) / n).tolist()
            return
        mean = self._drive[1:]
        np.add.reduce(torques, 0, out=mean)  # the same reduction and division
        np.divide(mean, n, out=mean)
        self._drive[0] = 1.0

    def points(self, lowest: np.ndarray, up: list,
               previous: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, bool]:
        """The contact points (4, 3) and normals (4, 3) and the longitudinal forces (4, 3).

        ``lowest``: the wheels' lowest points in fb (4, 3) (`Estimate.contact_points`);
        ``up``: ``R^T e_z`` in fb (3 floats); ``previous``: the normal forces the
        longitudinal forces are split by [N] (4,). Fresh arrays, and whether the points and
        normals, and the forces, are finite. The wheel's centre is its lowest point plus a
        radius up; on a plane, the centres of the wheels touching it lie on a parallel plane
        one radius above it, so the normal of the plane through them (three: exact; four:
        the diagonals' cross product) is the ground's; with fewer than three touching, the
        chassis normal (measured against MuJoCo's: `docs/sensors.md`).
        """
        if self._c is None:
            points, normal = self._points_py(lowest, up)
            normals = np.empty((4, 3))
            normals[:] = normal
            finite = bool(np.isfinite(points).all()) and all(map(math.isfinite, normal))
            force, force_finite = self._force_py(previous)
            return points, normals, force, finite, force_finite
        self._lowest[:] = lowest
        self._up[:] = up
        self._acc[:] = self.wheel_acceleration
        self._fz[:] = previous
        bits = self._c()
        return (self._points.copy(), self._normals.copy(), self._force.copy(),
                bool(bits & 1), bool(bits & 2))

    def update(self, forces: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """The flags after the four-wheel normal forces ``forces`` [N] (4,).

        Fresh arrays: the flags (4,) bool, the longitudinal forces (4, 3) split by
        ``forces``; and whether those are finite.
        """
        if self._c is None:
            f = forces.tolist()
            self._above = above = [n + 1 if x > CONTACT_ON_N else 0
                                   for n, x in zip(self._above, f)]
            self._in_contact = [(c and x >= CONTACT_OFF_N)
                                or (not c and (n >= CONTACT_TICKS or x > CONTACT_LANDING_N))
                                for c, x, n in zip(self._in_contact, f, above)]
            return (np.array(self._in_contact), *self._force_py(forces))
        self._fz[:] = forces
        finite = self._flags_c()
        return self._touching != 0.0, self._force.copy(), bool(finite)

    def _force_py(self, forces: np.ndarray) -> tuple[np.ndarray, bool]:
        """`longitudinal` along fb x, (4, 3), and whether it is finite."""
        longitudinal = self.longitudinal(forces)
        force = np.zeros((4, 3))
        force[:, 0] = longitudinal
        return force, all(map(math.isfinite, longitudinal))

    def longitudinal(self, forces: np.ndarray) -> list:
        """Each wheel's longitudinal ground force [N] (fb x), from its side's drive torque.

        A wheel's spin balance gives the ground's force ``f_x = (tau - I_w w_dot) / r``; a
        side's two wheels share one motor, so its torque gives their sum, split in
        proportion to their normal forces ``forces`` [N] (4,). The bogie balances need the
        sum per side (the contacts lie at about the same depth below the pivot); without
        it, skid-steer turning costs the cylinder-force row 6.5 % of the static wheel load
        (measured on the flat run), with it 0.8 %.
        """
        out = [0.0] * 4
        if self.drive is None:
            return out
        r = self.radius
        fz = forces.tolist()
        acc = self.wheel_acceleration
        for side, (a, b) in enumerate(((0, 1), (2, 3))):
            total = (self.drive[side] - self.inertia * (acc[a] + acc[b])) / r
            fa, fb = max(fz[a], 0.0), max(fz[b], 0.0)  # NaN stays, as np.maximum's
            s = fa + fb
            share = (fa / s, fb / s) if s > 0 else (0.5, 0.5)
            out[a], out[b] = total * share[0], total * share[1]
        return out

    def _points_py(self, lowest: np.ndarray, up: list) -> tuple[np.ndarray, list]:
        """`points`' points (4, 3) and the ground's normal (3 floats), in Python."""
        if not self.sphere:  # a disc: lowest in its own plane, touching in it too
            up[1] = 0.0
            n = norm(up)
            up = [v / n for v in up]
        r = self.radius
        r_up = [r * v for v in up]  # on floats: `lowest + r * up` as numpy would round it
        centre = [[a + b for a, b in zip(row, r_up)] for row in lowest.tolist()]
        normal = ground_normal(centre, self.in_contact)
        if not self.sphere:
            normal[1] = 0.0
            n = norm(normal)
            normal = [v / n for v in normal]
        r_normal = [r * v for v in normal]
        return np.array([[a - b for a, b in zip(row, r_normal)] for row in centre]), normal
