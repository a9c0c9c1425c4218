"""One state into one kernel input row (layout `estimators._symbolic.Layout`), fast.

`NormalForceEstimator` calls its compiled kernels once per state in a control loop, where the
Python around the call costs more than the call itself. `RowPacker` keeps that part small:
the range check reads the coordinates once as Python floats, the row is written into the
kernel's own input buffer by one `bytes.join` of the state's arrays (a third of the cost of
`numpy.concatenate`, which spends most of its time per argument), and the selectors of a
contact pattern (with D and beta appended) are built once and cached.
"""

from __future__ import annotations

import numpy as np

from estimators import full_dynamics as fd
from estimators._symbolic import LAYOUT
from estimators.checks import coordinate_ranges
from estimators.errors import EstimatorInputError
from models.description import Machine
from models.state import MachineState

__all__ = ["RANGE_TOLERANCE", "RowPacker"]

RANGE_TOLERANCE = 1e-12  # [m, rad]: how far past its range a coordinate still counts as in it

_ONES4 = np.ones(4)
_ZEROS2 = np.zeros(2)
_NO_CONTACTS = np.zeros(LAYOUT.force.stop - LAYOUT.points.start)  # points, flags, forces
_ALL_IN = np.ones(4, bool)
_join = b"".join


class RowPacker:
    """Packs `MachineState`s into kernel input rows for one machine and fourth equation.

    Args:
        machine: The machine (its coordinate ranges).
        fourth: The estimator's fourth equation (``d-beta`` or ``cylinder-force``).
        zeroed: Input positions to zero after packing (the quasi-static method's dropped
            terms), or None.
        payload_mass: The payload's mass [kg] packed into every row.

    Attributes:
        payload: The payload's mass [kg] as a (1,) array, packed as it is: its owner
            (`NormalForceEstimator.payload_mass`) writes it.
    """

    def __init__(self, machine: Machine, fourth: str, zeroed: np.ndarray | None = None,
                 payload_mass: float = 0.0):
        self.fourth = fourth
        self.zeroed = zeroed
        self.payload = np.array([float(payload_mass)])
        self.ranges = coordinate_ranges(machine)
        # (index, lower, upper) with the tolerance applied, for `out_of_range`.
        self.bounds = tuple((i, lo - RANGE_TOLERANCE, hi + RANGE_TOLERANCE)
                             for _, _, i, lo, hi in self.ranges)
        self._cache: dict = {}

    def out_of_range(self, q: np.ndarray) -> list[tuple[str, str, int, float, float]]:
        """The ranges (as in `estimators.checks.coordinate_ranges`) that ``q`` leaves."""
        values = q.tolist()
        for i, lo, hi in self.bounds:
            if not lo <= values[i] <= hi:
                break
        else:
            return []
        return [r for r, (i, lo, hi) in zip(self.ranges, self.bounds)
                if not lo <= values[i] <= hi]

    def clipped(self, q: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
        """A copy of ``q`` with every coordinate outside its range set to the nearest end.

        Returns:
            The clipped coordinates and the names of the ranges they left (empty: none).
        """
        bad = self.out_of_range(q)
        q = q.copy()
        for _, _, i, lo, hi in bad:
            q[i] = min(max(q[i], lo), hi)
        return q, tuple(name for name, *_ in bad)

    def state_selectors(self, state: MachineState, d: float, beta: float
                        ) -> tuple[np.ndarray, fd.Selectors, np.ndarray]:
        """`selectors` of ``state`` as `fill` takes them (all wheels in without contacts)."""
        c = state.contacts
        return self.selectors(_ALL_IN if c is None else c.in_contact,
                              state.suspension_force is not None, d, beta)

    def selectors(self, in_contact: np.ndarray, has_cylinder_force: bool, d: float,
                  beta: float) -> tuple[np.ndarray, fd.Selectors, np.ndarray]:
        """(packed selector block with D and beta, `Selectors`, read-only contact flags)."""
        key = (in_contact.tobytes(), has_cylinder_force, d, beta)
        hit = self._cache.get(key)
        if hit is None:
            s = fd.select_system(in_contact, self.fourth, has_cylinder_force)
            packed = np.concatenate([s.mask, s.height_weights, [s.s_dbeta, s.s_cylinder],
                                     s.lost, [d, beta]])
            flags = s.mask > 0
            flags.setflags(write=False)
            hit = self._cache[key] = (packed, s, flags)
        return hit

    def fill(self, inp: np.ndarray, state: MachineState, d: float, beta: float,
             raw: memoryview | None = None) -> tuple[fd.Selectors, np.ndarray]:
        """Write ``state`` into the input row ``inp``.

        With ``raw``, the bytes of ``inp`` (``memoryview(inp).cast("B")``), the row is the
        joined bytes of the state's arrays: `MachineState` and `WheelContacts` hold read-only
        C-contiguous float64 copies of the right shapes (checked once, at construction), so
        the bytes are those `numpy.concatenate` would write. Anything else (a row of another
        length, an array without a contiguous buffer) takes the `numpy.concatenate` path,
        which converts or raises as before.

        Returns:
            The `Selectors` used and the contact flags they stand for (read-only, (4,)).

        Raises:
            EstimatorInputError: The state's fields cannot be read (a malformed object).
        """
        try:
            c = state.contacts
            f = state.suspension_force
            if c is None:
                packed, sel, flags = self.selectors(_ALL_IN, f is not None, d, beta)
            else:
                packed, sel, flags = self.selectors(c.in_contact, f is not None, d, beta)
            if raw is not None:
                try:
                    row = _join((state.base_rotation, state.base_twist,
                                 state.base_acceleration, state.q, state.qd, state.qdd,
                                 *((_NO_CONTACTS,) if c is None else
                                   (c.point_in_fb, _ONES4, c.force_in_fb)),
                                 packed, _ZEROS2 if f is None else f, self.payload))
                except (TypeError, ValueError, BufferError):
                    row = b""
                if len(row) == len(raw):
                    raw[:] = row
                    if self.zeroed is not None:
                        inp[self.zeroed] = 0.0
                    return sel, flags
            if c is None:
                contacts = (_NO_CONTACTS,)
            else:
                contacts = (c.point_in_fb.reshape(12), _ONES4, c.force_in_fb.reshape(12))
            np.concatenate((state.base_rotation.reshape(9), state.base_twist,
                            state.base_acceleration, state.q, state.qd, state.qdd, *contacts,
                            packed, _ZEROS2 if f is None else f, self.payload), out=inp)
        except (ValueError, AttributeError, TypeError) as exc:
            raise EstimatorInputError(f"cannot read the state: {exc}") from exc
        if self.zeroed is not None:
            inp[self.zeroed] = 0.0
        return sel, flags
