r"""Prediction model of the MPC: every axis a double integrator, condensed.

State ``(q, \dot q)`` of the nine axes, input ``u_j = \ddot q`` held over step j of length
``h_j``; ``t_k = h_0 + ... + h_{k-1}``. After ``k`` steps (``k = 1..N``)::

    qd_k = qd_0 + sum_{j<k} h_j u_j
    q_k  = q_0 + t_k qd_0 + sum_{j<k} (h_j (t_k - t_{j+1}) + h_j^2 / 2) u_j

The first step is normally one control period long and the others longer: the input that
is applied (u_0, for one period) then sees the constraints exactly one period ahead, which
avoids limit cycles at an active constraint, while the long steps reach over >= 1 s.

The base is not controlled: its pose is predicted at the measured, constant twist
(`predict_base_pose`), the wheels at constant speed. The hydraulic servos track rate
commands well below their bandwidth, which is what makes the double integrator adequate.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from models.coordinates import N_INDEPENDENT, WHEELS
from models.state import MachineState
from wbc.axes import N_AXES
from wbc.constraints.limits_c import compiled_brake
from wbc.layout import VariableLayout

__all__ = ["CondensedPrediction", "nominal_state", "predict_base_pose",
           "predict_base_rotations"]

_ZEROS_6 = np.zeros(6)
_ZEROS_6.flags.writeable = False
_ZEROS_Q = np.zeros(N_INDEPENDENT)
_ZEROS_Q.flags.writeable = False


class CondensedPrediction:
    """Node positions and velocities as affine functions of the decision vector.

    ``Q = Pq x + q_free`` and ``V = Pv x + v_free`` with Q, V stacked node-major
    (node k = 1..N, then axis), shapes (N * n_axes,).

    Args:
        layout: Decision layout (``n_steps = N``).
        steps: Step lengths h_j [s], scalar (uniform) or shape (N,).

    Attributes:
        Pq, Pv: (N * n_axes, layout.n).
        Lq, Lv: The scalar (N, N) lower-triangular factors: ``Pq = kron(Lq, I)`` on the
            accelerations.
        step_lengths: h_j [s], shape (N,).
        times: Node times t_k, k = 1..N [s], shape (N,).
        start_times: Step start times t_j, j = 0..N-1 [s], shape (N,).
    """

    def __init__(self, layout: VariableLayout, steps):
        N, na = layout.n_steps, layout.n_axes
        h = np.broadcast_to(np.asarray(steps, dtype=float), (N,)).copy()
        t = np.cumsum(h)
        k = np.arange(N)[:, None]  # row: node k + 1
        j = np.arange(N)[None, :]
        before = j <= k
        self.Lv = np.where(before, h[None, :], 0.0)
        self.Lq = np.where(before, h[None, :] * (t[:, None] - t[None, :]) + 0.5 * h[None, :]**2,
                           0.0)
        self.Pq = np.zeros((N * na, layout.n))
        self.Pv = np.zeros((N * na, layout.n))
        eye = np.eye(na)
        self.Pq[:, layout.accelerations] = np.kron(self.Lq, eye)
        self.Pv[:, layout.accelerations] = np.kron(self.Lv, eye)
        self.layout = layout
        self.step_lengths = h
        self.times = t
        self.start_times = t - h
        # `brake_trajectory`'s loop in C (`limits_c`; None without a compiler), for the
        # layout's axes: built, or loaded from the cache, here, not inside a control tick.
        self._brake = compiled_brake(h, na)

    @property
    def horizon(self) -> float:
        """t_N [s]."""
        return float(self.times[-1])

    @property
    def structure_key(self) -> tuple:
        """Layout and step lengths."""
        return (self.layout, self.step_lengths.tobytes())

    def free_response(self, q0: np.ndarray, qd0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Node positions and velocities at zero input, shapes (N, n_axes)."""
        q = q0[None, :] + self.times[:, None] * qd0[None, :]
        v = np.empty(q.shape, qd0.dtype)
        v[:] = qd0  # every node at the initial velocity
        return q, v

    def trajectory(self, q0, qd0, inputs, free=None) -> tuple[np.ndarray, np.ndarray]:
        """Node positions and velocities for inputs (N, n_axes): shapes (N, n_axes).

        ``free``: `free_response` of ``q0, qd0`` if the caller has it (a context does).
        """
        qf, vf = self.free_response(q0, qd0) if free is None else free
        return qf + self.Lq @ inputs, vf + self.Lv @ inputs

    def brake_trajectory(self, q0, qd0, acceleration, free=None) -> tuple[np.ndarray, ...]:
        """Brake every axis to rest at the acceleration limit, then hold.

        ``free``: as for `trajectory`.

        Returns:
            (inputs, positions, velocities), shapes (N, n_axes); the inputs respect
            ``|u| <= acceleration`` and reach zero velocity exactly.
        """
        c = self._brake
        if c is not None and c.v0.size == q0.size:
            u = c.inputs(qd0, acceleration)
            q, vel = self.trajectory(q0, qd0, u, free)
            return u, q, vel
        u = np.zeros((self.layout.n_steps, q0.size))
        v = qd0.astype(float).copy()
        lower = -acceleration
        for k, h in enumerate(self.step_lengths):
            # -clip(v / h, -a, a) as its two ufuncs (no np.clip dispatch per step)
            np.negative(np.minimum(np.maximum(v / h, lower), acceleration), out=u[k])
            v = v + h * u[k]
            if not v.any():  # at rest (every v now +0): the later inputs are -0
                u[k + 1:] = -0.0
                break
        q, vel = self.trajectory(q0, qd0, u, free)
        return u, q, vel


class _StartPose:
    """``(state, T_0)`` of the last state asked for (`predict_base_pose`), or None.

    The MPC predicts from one state several times a tick; a state is immutable, so the same
    object has the same pose. One tuple, replaced whole: a thread reads a consistent pair.
    """

    kept: tuple | None = None


def _start_pose(state: MachineState) -> pin.SE3:
    """``T_0`` of ``state``, kept for the same state object (`_StartPose`)."""
    kept = _StartPose.kept
    if kept is None or kept[0] is not state:
        kept = _StartPose.kept = (state, pin.SE3(state.base_rotation, state.base_position))
    return kept[1]


def predict_base_pose(state: MachineState, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose of fb after ``t`` [s] at the state's constant twist: (position (3,), R (3, 3)).

    ``T(t) = T_0 exp(t [v; w])`` (right-multiplied: the twist is in fb). ``exp6`` of the
    6-vector is the one of its `pin.Motion` (the same function), without that object.
    """
    mt = _start_pose(state) * pin.exp6(state.base_twist * t)
    return mt.translation.copy(), mt.rotation.copy()


def predict_base_rotations(state: MachineState, times: np.ndarray) -> np.ndarray:
    """The rotations (world <- fb) of `predict_base_pose` at ``times`` [s] (n,): (n, 3, 3)."""
    start, twist = _start_pose(state), state.base_twist
    rotations = np.empty((len(times), 3, 3))
    for k, t in enumerate(times.tolist()):
        rotations[k] = (start * pin.exp6(twist * t)).rotation
    return rotations


def nominal_state(state: MachineState, t: float, q_axes: np.ndarray,
                  qd_axes: np.ndarray) -> MachineState:
    """The state ``t`` [s] after ``state`` on a nominal trajectory (a linearization point).

    The axes at ``q_axes, qd_axes`` (9,), the base at its constant twist, the wheels at
    constant speed, no accelerations, the measurements carried over. Built from ``state``'s
    validated fields, so not validated again (the constraints build several per tick).
    """
    pos, rot = predict_base_pose(state, t)
    q, qd = state.q.copy(), state.qd.copy()
    q[:N_AXES], qd[:N_AXES] = q_axes, qd_axes
    q[WHEELS] += t * state.qd[WHEELS]
    return MachineState._trusted(pos, rot, state.base_twist, _ZEROS_6, q, qd, _ZEROS_Q,
                                 state.time + t, state.contacts, state.suspension_force)
