"""`ForceLinearization`: the one object the estimator hands a controller.

It is the seam between the estimator and any controller that uses the normal forces as a
constraint: the forces at a state, their exact affine map in the generalised accelerations
(the normal forces are affine in ``a`` once q, qd and the contacts are fixed: eqs. 20-28)
and their sensitivities to the configuration and the velocities, with the contact flags and
the mode of the system that produced them::

    f_z(q + dq, qd + dqd, a) ~= g0 + G a + d_q dq + d_qd dqd,
    a = [base_acceleration (6), qdd (13)].

Valid in every contact mode (four wheels, three wheels of Sec. III-B, tipping): every array
is finite. Immutable, arrays read-only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.errors import EstimatorError
from estimators.results import RowFields
from models.coordinates import N_INDEPENDENT

__all__ = ["N_GENERALIZED", "ForceLinearization"]

N_GENERALIZED = 6 + N_INDEPENDENT  # a = [base acceleration (6), qdd (13)]
MODES = ("d-beta", "cylinder-force", "3-contact", "tipping")


def _frozen(name: str, value, shape, dtype=float) -> np.ndarray:
    a = np.array(value, dtype=dtype)
    if a.shape != shape:
        raise EstimatorError(f"ForceLinearization.{name} must have shape {shape}, got {a.shape}")
    if dtype is float and not np.all(np.isfinite(a)):
        raise EstimatorError(f"ForceLinearization.{name} has non-finite entries: {a}")
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class ForceLinearization(RowFields):
    """The normal forces linearized at one state.

    Attributes:
        normal_forces: f_z at the state [N], shape (4,), order FL, RL, FR, RR.
        G: ``df_z/da`` [N per m/s^2 or N per rad/s^2], shape (4, 19).
        g0: ``f_z - G a_state`` [N], shape (4,).
        d_q: ``df_z/dq`` at fixed ``a`` [N/m or N/rad], shape (4, 13).
        d_qd: ``df_z/dqd`` at fixed ``a`` [N s/m or N s/rad], shape (4, 13).
        in_contact: Contact flags the system used, shape (4,) bool.
        mode: ``d-beta``, ``cylinder-force``, ``3-contact`` or ``tipping``.
        clipped: Names of the coordinates clipped into their ranges before evaluation
            (the estimator's ``strokes="clip"`` policy); empty when none was.
        time: The state's time [s].
    """

    normal_forces: np.ndarray
    G: np.ndarray
    g0: np.ndarray
    d_q: np.ndarray
    d_qd: np.ndarray
    in_contact: np.ndarray
    mode: str
    clipped: tuple[str, ...] = ()
    time: float = 0.0

    def __post_init__(self):
        for name, shape in (("normal_forces", (4,)), ("G", (4, N_GENERALIZED)), ("g0", (4,)),
                            ("d_q", (4, N_INDEPENDENT)), ("d_qd", (4, N_INDEPENDENT))):
            object.__setattr__(self, name, _frozen(name, getattr(self, name), shape))
        object.__setattr__(self, "in_contact", _frozen("in_contact", self.in_contact, (4,),
                                                       bool))
        if self.mode not in MODES:
            raise EstimatorError(f"ForceLinearization.mode {self.mode!r} not in {MODES}")
        object.__setattr__(self, "clipped", tuple(self.clipped))

    @classmethod
    def trusted(cls, normal_forces: np.ndarray, G: np.ndarray, g0: np.ndarray,  # noqa: N803
                d_q: np.ndarray, d_qd: np.ndarray, in_contact: np.ndarray, mode: str,
                clipped: tuple[str, ...], time: float) -> ForceLinearization:
        """Wrap arrays the estimator's kernel made, without the checks of the constructor.

        For the estimator's per-tick path: the caller guarantees the shapes, float dtype, a
        finite kernel checksum, a valid mode and a read-only ``in_contact``; the arrays are
        made read-only here (not copied: they are views of a row nobody else holds).
        The estimator's own per-tick path is `RowFields.from_row` on a read-only row: the
        arrays are then views of it, made on first access.
        """
        for a in (normal_forces, G, g0, d_q, d_qd):
            a.flags.writeable = False
        obj = object.__new__(cls)
        object.__setattr__(obj, "__dict__", {
            "normal_forces": normal_forces, "G": G, "g0": g0, "d_q": d_q, "d_qd": d_qd,
            "in_contact": in_contact, "mode": mode, "clipped": clipped, "time": time})
        return obj

    def forces_at(self, a: np.ndarray, dq: np.ndarray | None = None,
                  dqd: np.ndarray | None = None) -> np.ndarray:
        """``g0 + G a + d_q dq + d_qd dqd`` [N], shape (4,)."""
        f = self.g0 + self.G @ np.asarray(a, float)
        if dq is not None:
            f = f + self.d_q @ np.asarray(dq, float)
        if dqd is not None:
            f = f + self.d_qd @ np.asarray(dqd, float)
        return f
