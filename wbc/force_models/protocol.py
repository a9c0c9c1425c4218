"""The interface the controller needs from a wheel normal-force model.

The estimator of the `estimators` package (`NormalForceEstimator`) satisfies it, and so does
the synthetic `AffineForceModel` used by the tests. The controller needs the normal forces
in the exact affine form of the generalized accelerations (paper eqs. 20-28 are linear in
the accelerations once the configuration and the velocities are fixed)::

    f_z = G a + g0,   a = [base_acceleration (6), qdd (13)],

and the sensitivity of the forces to the configuration, ``df_z/dq`` (4, 13), used to predict
the forces along the MPC horizon.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from models.coordinates import N_INDEPENDENT
from models.state import MachineState
from wbc.errors import ForceModelError

__all__ = ["N_GENERALIZED", "ForceLinearization", "NormalForceEstimate", "NormalForceModel",
           "contact_flags",
           "linearize_forces", "split_derivatives"]

N_GENERALIZED = 6 + N_INDEPENDENT  # a = [base acceleration (6), qdd (13)]


@runtime_checkable
class NormalForceEstimate(Protocol):
    """What `NormalForceModel.estimate` returns (attributes only)."""

    normal_forces: np.ndarray  # [N], shape (4,), order FL, RL, FR, RR
    in_contact: np.ndarray  # shape (4,), bool


@runtime_checkable
class NormalForceModel(Protocol):
    """A wheel normal-force model usable as a QP constraint."""

    def estimate(self, state: MachineState) -> NormalForceEstimate:
        """Normal forces [N] and contact flags at ``state``."""
        ...

    def constraint(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """(G, g0): ``f_z = G a + g0`` exactly, G shape (4, 19) [N per m/s^2], g0 (4,) [N]."""
        ...

    def constraint_derivatives(self, state: MachineState) -> Any:
        """``df_z/dq`` [N/m, N/rad], shape (4, 13), optionally with ``df_z/dqd`` (4, 13)."""
        ...


@dataclass(frozen=True)
class ForceLinearization:
    """The force model linearized at one state.

    ``f_z(q + dq, qd + dqd, a) ~= g0 + G a + dq_matrix dq + dqd_matrix dqd``.

    Attributes:
        G: [N per unit acceleration], shape (4, 19).
        g0: [N], shape (4,).
        dq: ``df_z/dq`` [N/m or N/rad], shape (4, 13).
        dqd: ``df_z/dqd`` [N s/m or N s/rad], shape (4, 13), zeros when the model has none.
    """

    G: np.ndarray
    g0: np.ndarray
    dq: np.ndarray
    dqd: np.ndarray


def _checked(name: str, a, shape) -> np.ndarray:
    try:
        a = np.asarray(a, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ForceModelError(f"force model returned a non-numeric {name}: {exc}") from exc
    if a.shape != shape:
        raise ForceModelError(f"force model returned {name} of shape {a.shape}, expected "
                              f"{shape}")
    if not np.all(np.isfinite(a)):
        raise ForceModelError(f"force model returned non-finite {name}: {a}")
    return a


_DQ_NAMES = ("dfz_dq", "d_q", "dq", "wrt_q", "q")
_DQD_NAMES = ("dfz_dqd", "d_qd", "dqd", "wrt_qd", "qd")


def split_derivatives(raw: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """Normalize what ``constraint_derivatives`` returns to ``(df/dq, df/dqd or None)``.

    Accepts a (4, 13) array, a tuple/list ``(dq,)`` or ``(dq, dqd)``, a mapping or an
    object with one of the attribute names ``dfz_dq, d_q, dq, wrt_q, q`` (and the matching
    ``..._qd`` name for the velocity derivative).
    """
    shape = (4, N_INDEPENDENT)
    if isinstance(raw, np.ndarray):
        return _checked("df_z/dq", raw, shape), None
    if isinstance(raw, (tuple, list)):
        if len(raw) == 1 or (len(raw) == 2 and raw[1] is None):
            return _checked("df_z/dq", raw[0], shape), None
        if len(raw) == 2:
            return _checked("df_z/dq", raw[0], shape), _checked("df_z/dqd", raw[1], shape)
        raise ForceModelError(f"constraint_derivatives returned {len(raw)} items, expected "
                              f"1 or 2")
    get = raw.get if isinstance(raw, dict) else (lambda k: getattr(raw, k, None))
    dq = next((get(k) for k in _DQ_NAMES if get(k) is not None), None)
    if dq is None:
        raise ForceModelError(f"cannot read df_z/dq from {type(raw).__name__}; expected an "
                              f"array, a tuple or one of the names {_DQ_NAMES}")
    dqd = next((get(k) for k in _DQD_NAMES if get(k) is not None), None)
    return (_checked("df_z/dq", dq, shape),
            None if dqd is None else _checked("df_z/dqd", dqd, shape))


def linearize_forces(model: NormalForceModel, state: MachineState,
                     derivatives: bool = True) -> ForceLinearization:
    """Evaluate ``model`` at ``state`` and check every array it returns.

    When ``constraint_derivatives`` also returns the forces and ``df_z/da`` (attributes
    ``normal_forces`` and ``d_acceleration``, as the project's estimator does), one model
    call gives everything: ``G = df_z/da`` and ``g0 = f_z - G a_state``.

    Raises:
        ForceModelError: The model raised, or returned an array of the wrong shape or with
            a non-finite entry.
    """
    try:
        raw = model.constraint_derivatives(state) if derivatives else None
        forces = getattr(raw, "normal_forces", None)
        d_acc = getattr(raw, "d_acceleration", None)
        if forces is not None and d_acc is not None:
            G = _checked("G", d_acc, (4, N_GENERALIZED))
            f = _checked("normal forces", forces, (4,))
            g0 = f - G @ np.concatenate([state.base_acceleration, state.qdd])
        else:
            G, g0 = model.constraint(state)
            G = _checked("G", G, (4, N_GENERALIZED))
            g0 = _checked("g0", g0, (4,))
    except ForceModelError:
        raise
    except Exception as exc:  # the model's own failure at this state: the loop falls back
        raise ForceModelError(f"force model failed at t={state.time:.3f} s: "
                              f"{type(exc).__name__}: {exc}") from exc
    if derivatives:
        dq, dqd = split_derivatives(raw)
    else:
        dq, dqd = np.zeros((4, N_INDEPENDENT)), None
    if dqd is None:
        dqd = np.zeros((4, N_INDEPENDENT))
    return ForceLinearization(G, g0, dq, dqd)


def contact_flags(model: NormalForceModel, state: MachineState) -> np.ndarray:
    """Wheels in contact, shape (4,) bool.

    The state's measured flags if it has them, else the model's `estimate(state).in_contact`.
    """
    if state.contacts is not None:
        return np.asarray(state.contacts.in_contact, dtype=bool).reshape(4)
    try:
        flags = np.asarray(model.estimate(state).in_contact)
    except Exception as exc:
        raise ForceModelError(f"force model failed at t={state.time:.3f} s: "
                              f"{type(exc).__name__}: {exc}") from exc
    if flags.shape != (4,):
        raise ForceModelError(f"force model returned in_contact of shape {flags.shape}, "
                              f"expected (4,)")
    return flags.astype(bool)
