r"""Measured load split for the MPC: the cylinder-force closure now, a warp model ahead.

The normal-force model the MPC linearizes along its horizon (the estimator with the d-beta
fourth row, eq. 29) is exact in the three equilibrium rows (eqs. 25-28) but fixes the fourth
direction, the *diagonal* load split ``n = (+1, -1, -1, +1)`` (FL, RL, FR, RR), at a
constant. On the machine that split is set by the chassis warp: terrain twist, drive-torque
reactions, and the two suspension servos, whose setpoint difference twists the chassis
against the wheels: ``df = k_w n d(s_L - s_R)``, linear up to the lift-off of a wheel.
``k_w`` is derived from the machine description (`warp_stiffness`,
`estimators.compliance.WarpCompliance`): the series stiffness, per wheel along ``n``, of the
suspension servos mapped through the bogie chains (``kp / (2 a^2 k1^2)``) and the tyre
contacts (MuJoCo's soft contact at the static wheel load), times ``a |k1| / 2``. For the
reference machine at home that is 6.88 kN per wheel and millimetre of setpoint difference,
-5 % / +8 % over the bogie stroke range; `tests/test_compliance.py` compares it with MuJoCo.
The servos are the soft part (~10x softer than the tyres): a setpoint difference turns into
servo deflection (force) on both sides, and the stroke *difference* moves by only the tyres'
share (~8 %; the common part pitches the chassis), so the *setpoints* are the controlled
quantity.

`ClosureFeedback` gives, once per control tick at the measured state:

* ``forces``: the estimator's cylinder-force closure (the fourth row from the measured
  suspension cylinder forces; exact to 0.01 % of the static wheel load on our logs),
* ``bias = forces - model_forces``: what the horizon model misses now (along ``n`` only,
  since both satisfy the equilibrium rows). The MPC adds it to every node of the horizon:
  the split is held at its measured value, as the d-beta row assumes, but at the right value.

`warp_matrix` is ``df/dq_axes`` of the warp (4, 9): nonzero on the two suspension columns,
``+k_w n`` and ``-k_w n``. The MPC adds it to the model's sensitivity, which makes the
suspension a lever on the load split that the force constraint can use.

`WarpDrift` estimates how fast the ground twists the chassis while the machine drives: the
measured warp ``w = n^T f / 4`` minus what the suspension setpoints explain, ``k_w (s_L -
s_R)``, differentiated and low-pass filtered. The MPC extrapolates it a short time ahead
(it is proportional to the driving speed), so the suspension leads the terrain instead of
lagging it by the loop's time constant (~0.1 s here, against twist rates of 20-40 kN/s at
0.4 m/s on the 10 deg rough terrain).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import isfinite

import numpy as np

from estimators.compliance import WarpCompliance
from estimators.uncertainty import model_normal_forces
from models.description import Machine
from models.numeric import clip
from models.records import trusted
from models.state import MachineState
from wbc.axes import N_AXES, SUSPENSION_AXES
from wbc.errors import ForceModelError
from wbc.force_models.protocol import MODEL_ERRORS, NormalForceModel, contact_flags

__all__ = ["DIAGONAL", "ClosureFeedback", "ForceFeedback", "WarpDrift", "leveling_offset",
           "warp_matrix", "warp_stiffness"]

DIAGONAL = np.array([1.0, -1.0, -1.0, 1.0])  # FL, RL, FR, RR: the free (warp) direction


def warp_stiffness(machine: Machine, q=None) -> float:
    """k_w of ``machine`` [N/m per wheel along `DIAGONAL` per metre of ``s_L - s_R``].

    Derived from the description (`estimators.compliance.WarpCompliance`) at the bogie
    strokes of ``q`` and the static wheel load; compiles the machine's MuJoCo model once
    (~0.1 s), so call it at construction, not per tick.

    Args:
        machine: The machine description.
        q: Independent coordinates, shape (13,); the home pose if None.
    """
    return WarpCompliance(machine).stiffness(q)


@dataclass(frozen=True)
class ForceFeedback:
    """The load split measured at one control tick.

    Attributes:
        forces: Normal forces by the cylinder-force closure [N], shape (4,).
        model_forces: The horizon model's forces at the same state [N], shape (4,).
        in_contact: Contact flags, shape (4,).
        time: State time [s].
    """

    forces: np.ndarray
    model_forces: np.ndarray
    in_contact: np.ndarray
    time: float

    @classmethod
    def of(cls, forces: np.ndarray, model_forces: np.ndarray, in_contact: np.ndarray,
           time: float) -> ForceFeedback:
        """``ForceFeedback(...)`` without the frozen dataclass's per-field setattr.

        The fields set as its ``__init__`` sets them (it has no ``__post_init__``): the
        MPC makes two each tick.
        """
        return trusted(cls, forces=forces, model_forces=model_forces, in_contact=in_contact,
                       time=time)

    @property
    def bias(self) -> np.ndarray:
        """``forces - model_forces`` [N], shape (4,): the correction held over the horizon."""
        return self.forces - self.model_forces


def warp_matrix(stiffness: float) -> np.ndarray:
    """``df/dq`` of the chassis warp over the nine axes [N/m], shape (4, 9).

    Columns: ``+k_w n`` for the left suspension setpoint, ``-k_w n`` for the right one.
    """
    w = np.zeros((4, N_AXES))
    w[:, SUSPENSION_AXES[0]] = stiffness * DIAGONAL
    w[:, SUSPENSION_AXES[1]] = -stiffness * DIAGONAL
    return w


def leveling_offset(forces, thresholds, in_contact=None, limit: float = np.inf) -> float:
    r"""Warp change ``delta`` [N] along `DIAGONAL` that maximizes the smallest margin.

    With margins ``m = f - f_min`` (a wheel out of contact counts as ``-f_min``), adding
    ``delta n`` gives ``min(m_FL + delta, m_RR + delta, m_RL - delta, m_FR - delta)``,
    largest at ``delta = (min(m_RL, m_FR) - min(m_FL, m_RR)) / 2``.

    Args:
        forces: Normal forces [N], shape (4,).
        thresholds: f_min [N], shape (4,).
        in_contact: Contact flags (4,); None: all in contact.
        limit: Clip |delta| to this [N].
    """
    f = np.asarray(forces, float)
    if in_contact is not None:
        f = np.where(np.asarray(in_contact, bool), f, 0.0)
    # the four margins as Python floats: the same IEEE arithmetic as on numpy's scalars
    m0, m1, m2, m3 = (f - np.asarray(thresholds, float)).tolist()
    delta = 0.5 * (min(m1, m2) - min(m0, m3))
    return float(clip(delta, -limit, limit))


class ClosureFeedback:
    """The measured load split (`ForceFeedback`) from a cylinder-force closure model.

    Args:
        closure: A model whose ``estimate`` uses ``state.suspension_force`` (the estimator
            with ``fourth="cylinder-force"``); without measured cylinder forces it falls
            back to its own fourth row, and the bias is then zero.
    """

    def __init__(self, closure: NormalForceModel):
        self.closure = closure

    def measure(self, state: MachineState, model: NormalForceModel) -> ForceFeedback:
        """Closure and model forces at ``state``.

        Raises:
            ForceModelError: A model raised or returned non-finite forces.
        """
        try:
            f = np.asarray(model_normal_forces(self.closure, state), float)
            g = np.asarray(model_normal_forces(model, state), float)
        except MODEL_ERRORS as exc:
            raise ForceModelError(f"force feedback failed at t={state.time:.3f} s: "
                                  f"{type(exc).__name__}: {exc}") from exc
        # the eight finite checks on Python floats (`np.isfinite`'s answers, ~1 us less)
        if f.shape != (4,) or g.shape != (4,) or not all(map(isfinite, f.tolist()
                                                              + g.tolist())):
            raise ForceModelError(f"force feedback returned {f} and {g}")
        if state.suspension_force is None:
            f = g.copy()
        return ForceFeedback.of(f, g, contact_flags(model, state), float(state.time))


class WarpDrift:
    """Rate of the terrain-imposed chassis warp [N/s along `DIAGONAL`], filtered.

    Args:
        stiffness: k_w [N/m] (the warp explained by the suspension setpoints).
        time_constant: Low-pass filter of the rate [s].
        horizon: How long the rate is extrapolated [s] (`drift`).
        limit: Clip of the rate [N/s].
    """

    def __init__(self, stiffness: float, time_constant: float = 0.05, horizon: float = 0.3,
                 limit: float = 1e5):
        self.stiffness = float(stiffness)
        self.time_constant = float(time_constant)
        self.horizon = float(horizon)
        self.limit = float(limit)
        self.reset()

    def reset(self) -> None:
        """Forget the history (rate zero)."""
        self.rate = 0.0
        self._last: tuple[float, float] | None = None  # (time, disturbance)

    def update(self, feedback: ForceFeedback, setpoint_difference: float) -> float:
        """Take the split measured now; returns the filtered rate [N/s].

        With a wheel out of contact the warp is not defined (the chassis rests on three
        wheels): the history is dropped and the rate is zero.
        """
        if not np.logical_and.reduce(feedback.in_contact):  # `np.all`, without its dispatch
            self.reset()
            return 0.0
        d = float(DIAGONAL @ feedback.forces) / 4.0 - self.stiffness * setpoint_difference
        if self._last is not None and feedback.time > self._last[0]:
            dt = feedback.time - self._last[0]
            raw = (d - self._last[1]) / dt
            self.rate += dt / (self.time_constant + dt) * (raw - self.rate)
            self.rate = float(clip(self.rate, -self.limit, self.limit))
        self._last = (feedback.time, d)
        return self.rate

    def drift(self, times) -> np.ndarray:
        """Predicted warp change at ``times`` ahead [N]: ``rate * min(t, horizon)``."""
        return self.rate * np.minimum(np.asarray(times, float), self.horizon)
