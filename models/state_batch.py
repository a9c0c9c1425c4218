"""`StateBatch`: a log of N machine states as arrays (the batch counterpart of `MachineState`).

Validated once at construction like `MachineState`: every field gets its documented shape,
finite entries and is made read-only; every base rotation must be proper.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from models.coordinates import N_INDEPENDENT
from models.errors import StateError
from models.state import ROTATION_TOLERANCE, MachineState, contact_flags, shaped_array

__all__ = ["StateBatch"]

REQUIRED = ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd")


@dataclass(frozen=True, eq=False)
class StateBatch:
    """A log of N states as arrays.

    Attributes:
        base_rotation: (N, 3, 3), world <- fb.
        base_twist: (N, 6). base_acceleration: (N, 6).
        q, qd, qdd: (N, 13), order of `models.coordinates`.
        in_contact: (N, 4) bool, or None (all wheels in contact).
        force_in_fb: (N, 4, 3) measured ground forces in fb [N], or None (no friction).
        point_in_fb: (N, 4, 3) measured contact points [m], or None (wheel bottoms).
        normal_in_fb: (N, 4, 3) terrain normals, or None.
        suspension_force: (N, 2) suspension cylinder forces (L, R) [N], or None.
        time: (N,) [s], or None.
    """

    base_rotation: np.ndarray
    base_twist: np.ndarray
    base_acceleration: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    in_contact: np.ndarray | None = None
    force_in_fb: np.ndarray | None = None
    point_in_fb: np.ndarray | None = None
    normal_in_fb: np.ndarray | None = None
    suspension_force: np.ndarray | None = None
    time: np.ndarray | None = None

    def __post_init__(self):
        for name in REQUIRED:
            if getattr(self, name) is None:
                raise StateError(f"'{name}' is required (an array of N rows), got None")
        try:
            q_shape = np.shape(self.q)
        except ValueError:  # a ragged sequence
            q_shape = "a ragged sequence"
        n = q_shape[0] if isinstance(q_shape, tuple) and len(q_shape) == 2 else -1
        if n < 0:
            raise StateError(f"'q' must have shape (N, {N_INDEPENDENT}), got {q_shape}")
        shapes = dict(base_rotation=(n, 3, 3), base_twist=(n, 6), base_acceleration=(n, 6),
                      q=(n, N_INDEPENDENT), qd=(n, N_INDEPENDENT), qdd=(n, N_INDEPENDENT),
                      force_in_fb=(n, 4, 3), point_in_fb=(n, 4, 3), normal_in_fb=(n, 4, 3),
                      suspension_force=(n, 2), time=(n,))
        for name, shape in shapes.items():
            v = getattr(self, name)
            if v is None:
                continue
            a = shaped_array(name, v, shape)
            bad = ~np.isfinite(a.reshape(n, -1)).all(axis=1) if n else np.zeros(0, bool)
            if bad.any():
                raise StateError(f"'{name}' has non-finite entries (NaN or inf) at rows "
                                 f"{np.flatnonzero(bad)[:10].tolist()}")
            a.flags.writeable = False
            object.__setattr__(self, name, a)
        if self.in_contact is not None:
            object.__setattr__(self, "in_contact",
                               contact_flags("in_contact", self.in_contact, (n, 4)))
        r = self.base_rotation
        if n:
            big = np.abs(r).max(axis=(1, 2)) > 1.0 + ROTATION_TOLERANCE
            r = np.where(big[:, None, None], 0.0, r)  # no overflow below; flagged anyway
            err = np.abs(r @ r.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
            det = np.einsum("ni,ni->n", np.cross(r[:, 0], r[:, 1]), r[:, 2])
            bad = big | (err > ROTATION_TOLERANCE) | (det < 0)
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise StateError(f"'base_rotation' row {k} is not a rotation matrix "
                                 f"({int(bad.sum())} rows in all; valid: orthonormal, det +1)")

    def __len__(self) -> int:
        return self.q.shape[0]

    def fields(self) -> dict:
        """The constructor arguments, for `StateBatch(**{**batch.fields(), ...})`."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @classmethod
    def from_states(cls, states: Sequence[MachineState]) -> StateBatch:
        """Stack a sequence of `MachineState` (contacts and cylinder forces if all have them).

        Raises:
            StateError: An item is not a `MachineState`, or only some carry contacts.
        """
        states = list(states)
        for i, s in enumerate(states):
            if not isinstance(s, MachineState):
                raise StateError(f"states[{i}] is a {type(s).__name__}, expected MachineState")
        if not states:
            z = np.zeros((0, N_INDEPENDENT))
            return cls(np.zeros((0, 3, 3)), np.zeros((0, 6)), np.zeros((0, 6)), z, z, z)

        def get(name):
            return np.array([getattr(s, name) for s in states], float)

        kw = {}
        if all(s.contacts is not None for s in states):
            kw = dict(
                in_contact=np.array([s.contacts.in_contact for s in states]),
                force_in_fb=np.array([s.contacts.force_in_fb for s in states]),
                point_in_fb=np.array([s.contacts.point_in_fb for s in states]),
                normal_in_fb=np.array([s.contacts.normal_in_fb for s in states]))
        elif any(s.contacts is not None for s in states):
            raise StateError("either every state or none must carry 'contacts'")
        if all(s.suspension_force is not None for s in states):
            kw["suspension_force"] = np.array([s.suspension_force for s in states])
        return cls(get("base_rotation"), get("base_twist"), get("base_acceleration"),
                   get("q"), get("qd"), get("qdd"), time=get("time"), **kw)
