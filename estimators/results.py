"""Results of the normal-force estimator: one state (`Estimate`), a log (`BatchEstimate`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.errors import EstimatorInputError

__all__ = ["BatchEstimate", "Estimate", "RowFields", "RowViews"]


class RowViews(dict):
    """A `RowFields` views table that also says where its array fields lie in the row.

    Args:
        views: Field name -> function of the instance ``__dict__`` (the table itself).
        slices: Field name -> ``(slice of the row, shape)`` of the array fields.
    """

    def __init__(self, views: dict, slices: dict):
        super().__init__(views)
        self.slices = slices


class RowFields:
    """Mixin: fields made from a kernel output row on first access (the per-call path).

    Each numpy view of the row costs about as much as the kernel call's own Python, and a
    controller reads two or three fields of a result; so `from_row` keeps the row and a
    table ``views`` (field name -> function of the instance ``__dict__``), and
    `__getattr__`, which Python calls only for an attribute not yet in ``__dict__``, makes
    the field once and stores it there. Values and types are those of an eagerly built
    result; the public constructor stays as it was.
    """

    __slots__ = ()

    @classmethod
    def from_row(cls, fields: dict, views: dict, row: np.ndarray):
        """An instance with ``fields`` set and the others made by ``views`` from ``row``."""
        fields["_views"] = views
        fields["_row"] = row
        obj = object.__new__(cls)
        object.__setattr__(obj, "__dict__", fields)  # also for frozen dataclasses
        return obj

    @staticmethod
    def stacked(objs, index: np.ndarray, names: tuple[str, ...]) -> tuple[np.ndarray, ...]:
        """Array fields ``names`` of ``objs[i] for i in index``, stacked: shapes (len(index), ...).

        Fresh arrays, or views of one fresh array, whose fields do not overlap: the caller
        may write them. When every object was made from a row with the same `RowViews`, the
        rows are stacked once and the fields sliced from the stack; the values are the same.
        """
        views = getattr(objs[0], "__dict__", {}).get("_views")
        slices = getattr(views, "slices", None)
        if slices is None or any(o.__dict__.get("_views") is not views for o in objs):
            return tuple(np.stack([getattr(o, name) for o in objs])[index] for name in names)
        rows = np.stack([o.__dict__["_row"] for o in objs])[index]
        k = rows.shape[0]
        return tuple(rows[:, slices[name][0]].reshape(k, *slices[name][1]) for name in names)

    def __getstate__(self) -> dict:
        """Every field made, without the row and the table (whose functions don't pickle)."""
        d = self.__dict__
        for name in d.get("_views", _NO_VIEWS):
            getattr(self, name)
        return {k: v for k, v in d.items() if k not in _LAZY_KEYS}

    def __setstate__(self, state: dict) -> None:
        object.__setattr__(self, "__dict__", dict(state))  # also for frozen dataclasses

    def __getattr__(self, name: str):
        d = self.__dict__
        view = d.get("_views", _NO_VIEWS).get(name)
        if view is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        value = d[name] = view(d)
        return value


_NO_VIEWS: dict = {}
_LAZY_KEYS = ("_views", "_row", "_rotation")  # `from_row`'s own entries (and an input)


@dataclass
class Estimate(RowFields):
    """Normal forces of one state.

    Attributes:
        normal_forces: f_z of each wheel along the fb z axis (contact frames aligned with fb,
            eqs. 22-24) [N], shape (4,), order FL, RL, FR, RR; positive pushes the wheel up.
        in_contact: Contact flags used, shape (4,).
        wrench_xi: ``F_Xi`` (eq. 20) in fb [N, N m], shape (6,).
        condition: 1-norm condition number of the solved system (4x4, or the reduced
            least-squares matrix when tipping).
        mode: ``d-beta``, ``cylinder-force``, ``3-contact`` or ``tipping``.
        tipping: Fewer than three wheels in contact; the forces are then the minimum-norm
            least-squares solution of the three equilibrium rows (finite, not unique).
        residual: ``A x - b`` of the three equilibrium rows (eqs. 25-28) [N, N m], (3,).
        contact_points: Contact points used, in fb [m], shape (4, 3).
        system_matrix: ``A`` of eq. (26) with lost wheels' columns zeroed, shape (3, 4).
        system_rhs: ``b`` of eq. (28), shape (3,).
        backend: Which code computed it: ``compiled``, ``casadi`` or ``reference``.
        normals: Terrain normals in fb used for `normal_forces_terrain`, shape (4, 3).
        friction: Measured tangential (fb x-y) ground forces [N], shape (4, 3).
    """

    normal_forces: np.ndarray
    in_contact: np.ndarray
    wrench_xi: np.ndarray
    condition: float
    mode: str
    tipping: bool
    residual: np.ndarray
    contact_points: np.ndarray
    system_matrix: np.ndarray
    system_rhs: np.ndarray
    backend: str
    normals: np.ndarray
    friction: np.ndarray

    @property
    def normal_forces_terrain(self) -> np.ndarray:
        """Ground force along the terrain normal [N], shape (4,): ``n . (F_a + f_z e_z)``."""
        return self.normals[:, 2] * self.normal_forces \
            + np.einsum("ij,ij->i", self.normals[:, :2], self.friction[:, :2])


@dataclass
class BatchEstimate:
    """Normal forces of many states; fields as in `Estimate` with a leading axis N.

    Attributes:
        normal_forces: (N, 4) [N]. in_contact: (N, 4). wrench_xi: (N, 6).
        condition: (N,). mode: (N,) strings. tipping: (N,). residual: (N, 3).
        contact_points: (N, 4, 3). system_matrix: (N, 3, 4). system_rhs: (N, 3).
        singular: (N,) rows whose system was singular (only with ``strict=False``; their
            forces are the least-squares solution).
        backend: Which code computed it.
        normals: (N, 4, 3) terrain normals in fb used for `normal_forces_terrain` (the
            logged ones, else the world z axis in fb).
        friction: (N, 4, 3) measured ground forces in fb (only their x-y part is used;
            zeros without measured contacts) [N].
    """

    normal_forces: np.ndarray
    in_contact: np.ndarray
    wrench_xi: np.ndarray
    condition: np.ndarray
    mode: np.ndarray
    tipping: np.ndarray
    residual: np.ndarray
    contact_points: np.ndarray
    system_matrix: np.ndarray
    system_rhs: np.ndarray
    singular: np.ndarray
    backend: str
    normals: np.ndarray | None = None
    friction: np.ndarray | None = None

    def __len__(self) -> int:
        return self.normal_forces.shape[0]

    @property
    def normal_forces_terrain(self) -> np.ndarray:
        """Ground force along the terrain normal [N], (N, 4): ``n . (F_a + f_z e_z)``.

        As `Estimate.normal_forces_terrain`: the estimated f_z plus the measured friction
        (fb x-y part of `friction`) projected on the terrain normal.
        """
        n = self.normals
        if n is None:
            raise EstimatorInputError("this BatchEstimate carries no terrain normals")
        f = self.friction if self.friction is not None else np.zeros_like(n)
        return n[..., 2] * self.normal_forces + np.einsum("nkj,nkj->nk", n[..., :2],
                                                          f[..., :2])
