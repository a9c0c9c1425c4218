r"""Actuator efforts the motion needs: each cylinder's force, affine in the accelerations.

For a state (base pose, twist and acceleration; independent q, qd) the tree's joint torques
are ``tau = M(q) qdd_tree + h(q, v)`` (RNEA of the machine description: the same rigid-body
dynamics as the normal-force estimator, whose wrench matches Pinocchio's RNEA to round-off).
With the chains closed through their Jacobian (``qd_tree = J qd``, ``qdd_tree = J qdd +
Jdot qd``, eqs. 6-7), the effort on independent coordinate ``i`` is ``e_i = J_i^T tau``
(virtual work): the cylinder force of a chain [N], the torque or force of a direct drive.
On the nine servo axes, with their accelerations ``u`` free and everything else given:

.. math:: e = E u + e_0, \qquad E = J_a^T M J_a, \quad e_0 = J_a^T (M (J_r qdd_r
          + \dot J qd) + h)

(``J_a``: the axes' columns, ``r``: the other coordinates, the wheels). The base
acceleration is an input (the ground supplies whatever the motion needs), as in the
estimator. Affine in the payload mass as well (`models.pinocchio_model.payload_pair`).

The per-tick path is compiled (`estimators.efforts_kernel`: one C call gives both payload
anchors' ``E`` and ``e_0``, another the link accelerometers' ``A`` and ``b``); Pinocchio's
RNEA and CRBA of the same description are the reference the kernels are tested against, and
the path taken without a C compiler (``compiled=False``).

The suspension cylinders also carry the ground's reaction, which the tree's dynamics do not
contain: their rows here are the tree's share only (the estimator's bogie rows add the
ground); the MPC bounds the crane's efforts.
"""

from __future__ import annotations

import functools

import numpy as np
import pinocchio as pin

from estimators.efforts_kernel import ANCHORS, EffortKernels, kernels_for
from estimators.errors import EstimatorError
from models.coordinates import N_INDEPENDENT
from models.description import Machine
from models.load_chart import effort_ranges as machine_effort_ranges
from models.pinocchio_model import PAYLOAD_PAIR_MASSES, payload_pair
from models.rotations import cross3, skew
from models.state import N_SERVO_AXES, MachineState

__all__ = ["ActuatorEfforts", "effort_ranges"]


def _upper_entries(idx: np.ndarray, n: int) -> np.ndarray:
    """Flat indices of the ``[idx, idx]`` block of an (n, n) matrix, in its upper triangle.

    ``M.take(...)`` is then the block of the symmetric matrix whose upper triangle (diagonal
    included) ``M`` holds: one gather instead of a symmetrized copy and a block index.
    """
    i, j = np.meshgrid(idx, idx, indexing="ij")
    return np.minimum(i, j) * n + np.maximum(i, j)


def effort_ranges(machine: Machine) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) effort of each servo axis [N or N m], shape (9,) each.

    The nine axes' rows of `models.load_chart.effort_ranges`.
    """
    lo, hi = machine_effort_ranges(machine)
    if not (np.all(np.isfinite(lo[:N_SERVO_AXES])) and np.all(np.isfinite(hi[:N_SERVO_AXES]))):
        raise EstimatorError("every servo axis needs a cylinder or a drive with limits")
    return lo[:N_SERVO_AXES], hi[:N_SERVO_AXES]


@functools.lru_cache(maxsize=8)
def _shared_last(fingerprint: str) -> list:
    """``[key, ((E_1, e_1), (E_2, e_2)), (m_1, m_2)]``: the last motion's maps, one per machine.

    The pair's results at masses ``m_1, m_2`` [kg]: the kernels' anchors or Pinocchio's pair.
    Kept by the machine's fingerprint, so every `ActuatorEfforts` of the same description
    (whatever its payload mass: the pair's results do not depend on it) reads and writes the
    same entry. Callers must not write into the arrays.
    """
    return [None, None, None]


def _motion_key(state: MachineState) -> bytes:
    """What `ActuatorEfforts._tree_motion` reads from ``state``, as bytes (exact equality).

    The nine axes' accelerations are left out: `affine` takes them as its free ``u``.
    """
    return b"".join((state.base_position.tobytes(), state.base_rotation.tobytes(),
                     state.base_twist.tobytes(), state.base_acceleration.tobytes(),
                     state.q.tobytes(), state.qd.tobytes(),
                     state.qdd[N_SERVO_AXES:].tobytes()))


class ActuatorEfforts:
    """``e = E u + e_0`` of the nine servo axes (module docstring).

    Args:
        machine: The machine description.
        payload_mass: Payload [kg]; the description's if None.
        compiled: Use the compiled kernels (`estimators.efforts_kernel`, built now if not
            cached); False, or no C compiler: Pinocchio.

    Attributes:
        payload_mass: Settable (finite, >= 0).
    """

    def __init__(self, machine: Machine, payload_mass: float | None = None,
                 compiled: bool = True):
        self.machine = machine
        self._kernels: EffortKernels | None = kernels_for(machine) if compiled else None
        self._pair = payload_pair(machine)
        self._mass_entries = [_upper_entries(pm._tree_v_idx, pm.model.nv) for pm in self._pair]
        self._tree_map()
        self._frames: dict[str, int] = {}  # `_body_frame`
        self._motion_of: bytes | None = None  # `_tree_motion`'s last state's key and result
        self._motion: tuple | None = None
        self._shared = _shared_last(machine.fingerprint)
        body = next(b for b in machine.bodies if b.name == machine.payload)
        self.payload_mass = body.inertia.mass if payload_mass is None else payload_mass

    @property
    def payload_mass(self) -> float:
        """Payload mass [kg]."""
        return self._mass

    @payload_mass.setter
    def payload_mass(self, value) -> None:
        m = float(value) if isinstance(value, (int, float, np.floating)) else float("nan")
        if not (np.isfinite(m) and m >= 0):
            raise EstimatorError(f"payload_mass must be a finite mass >= 0 [kg], got {value!r}")
        self._mass = m

    def _tree_map(self) -> None:
        """What `_tree_motion` takes from the coordinates, once.

        The directly driven joints (tree index, coordinate index), the chains (coordinate,
        chain, tree indices of its driven joint, barrel and piston) and the Jacobian's
        constant entries (1 on the direct joints and the pistons).
        """
        coords = self._pair[0].coordinates
        self._direct = np.array(coords._direct, int).reshape(-1, 2).T  # (i's, j's)
        self._chains = [(i, b.chain, coords.index[b.driven_joint], coords.index[b.barrel],
                         coords.index[b.piston]) for i, b in coords._chains]
        self._jac_constant = np.zeros((coords.n_tree, N_INDEPENDENT))
        for i, j in coords._direct:
            self._jac_constant[j, i] = 1.0
        for i, _, _, _, piston in self._chains:
            self._jac_constant[piston, i] = 1.0

    def _tree_motion(self, state: MachineState):
        """(q, v, a, J_axes): Pinocchio's configuration with the axes' accelerations zero.

        Every chain's state is evaluated once (the chains' kinematics are the costly part),
        and the last motion's result is kept, by what it reads (`_motion_key`: the axes'
        accelerations do not enter): the observer asks `point_specific_forces`,
        `payload_regressor` and `affine` about states that differ only there each tick
        (callers must not write into the arrays).
        """
        key = _motion_key(state)
        if self._motion_of == key:
            return self._motion
        pm = self._pair[0]
        jac = self._jac_constant.copy()
        q_tree = np.zeros(jac.shape[0])
        jdot_qd = np.zeros(jac.shape[0])
        direct_i, direct_j = self._direct
        q_tree[direct_j] = state.q[direct_i]
        # The chains' scalar arithmetic on Python floats (the same IEEE operations, faster
        # than on numpy scalars).
        q_ind, qd_ind = state.q.tolist(), state.qd.tolist()
        for i, chain, d, br, pi in self._chains:
            x, xd = q_ind[i], qd_ind[i]
            theta, theta_barrel, k1, k2, dk1, dk2 = chain.driven_terms(x)
            q_tree[d], q_tree[br], q_tree[pi] = theta, theta_barrel, x
            jac[d, i], jac[br, i] = k1, k2
            jdot_qd[d] = dk1 * xd * xd
            jdot_qd[br] = dk2 * xd * xd
        q = np.zeros(pm.model.nq)
        v = np.zeros(pm.model.nv)
        a = np.zeros(pm.model.nv)
        q[:3] = state.base_position
        q[3:7] = pin.Quaternion(state.base_rotation).normalized().coeffs()
        q[pm._tree_q_idx] = q_tree
        v[:6] = state.base_twist
        v[pm._tree_v_idx] = jac @ state.qd
        a[:6] = state.base_acceleration
        qdd_rest = np.array(state.qdd, float)
        qdd_rest[:N_SERVO_AXES] = 0.0
        a[pm._tree_v_idx] = jac @ qdd_rest + jdot_qd
        self._motion_of, self._motion = key, (q, v, a, jac[:, :N_SERVO_AXES])
        return self._motion

    @staticmethod
    def _one(pm, mass_entries, q, v, a, ja) -> tuple[np.ndarray, np.ndarray]:
        tau = pin.rnea(pm.model, pm.data, q, v, a)[pm._tree_v_idx]
        # E = J_a^T M J_a from Pinocchio's CRBA, whose upper triangle is what it guarantees
        # (the model's joints are depth-first, as CRBA needs): ``mass_entries`` reads the
        # tree's block from it (`_upper_entries`).
        mass = pin.crba(pm.model, pm.data, q).take(mass_entries)
        return ja.T @ mass @ ja, ja.T @ tau

    def affine(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """``(E (9, 9), e_0 (9,))`` at ``state`` for the current payload mass.

        ``state.qdd`` of the nine axes is ignored (they are the free ``u``); the wheels'
        and the base's accelerations are used. The two payload models' results of the last
        motion are kept for every `ActuatorEfforts` of the same machine (`_shared_last`):
        the observer and the MPC's effort limit ask about the same motion each tick.
        """
        return self.blend(self.affine_pair(state))

    @staticmethod
    def blend(pair: tuple) -> tuple[np.ndarray, np.ndarray]:
        """``(E_1 + w (E_2 - E_1), e_1 + w (e_2 - e_1))`` of an `affine_pair`: `affine`."""
        (e1, f1), (e2, f2), w = pair
        return e1 + w * (e2 - e1), f1 + w * (f2 - f1)

    def affine_pair(self, state: MachineState) -> tuple:
        """``((E_1, e_1), (E_2, e_2), w)``: `affine` is ``E_1 + w (E_2 - E_1)``, same for e.

        The maps at the two payload masses (`_pair_results`: shared, callers must not write
        into them) and the current mass's weight between them: a caller that needs only
        some rows blends those (`wbc.constraints.HorizonEffortLimit`), with `affine`'s
        operations, for its bits.
        """
        if not isinstance(state, MachineState):
            raise EstimatorError(f"expected a MachineState, got {type(state).__name__}")
        first, second, (m1, m2) = self._pair_results(state)
        return first, second, (self._mass - m1) / (m2 - m1)

    def _pair_results(self, state: MachineState) -> tuple:
        """``((E_1, e_1), (E_2, e_2), (m_1, m_2))``: the efforts' maps at two payload masses.

        The compiled kernel's (at its `ANCHORS`), else Pinocchio's (its pair's masses); the
        last motion's kept for every `ActuatorEfforts` of the machine (`_shared_last`).
        """
        key = _motion_key(state)
        shared = self._shared
        if shared[0] != key:
            pair = None if self._kernels is None else self._kernels.efforts(state)
            masses = ANCHORS
            if pair is None:  # no compiler, or a state the kernel gives no finite result
                motion = self._tree_motion(state)
                pair = tuple(self._one(pm, entries, *motion)
                             for pm, entries in zip(self._pair, self._mass_entries))
                masses = PAYLOAD_PAIR_MASSES
            shared[:] = [key, pair, masses]
        return (*shared[1], shared[2])

    def payload_regressor(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """``(e_0, Y)``: the efforts at the state's own accelerations are ``e_0 + m Y``.

        Shapes (9,) each [N or N m, and per kg]: the efforts' maps at two masses
        (`_pair_results`) at the state's ``u``.
        """
        if not isinstance(state, MachineState):
            raise EstimatorError(f"expected a MachineState, got {type(state).__name__}")
        (e1, f1), (e2, f2), (m1, m2) = self._pair_results(state)
        u = state.qdd[:N_SERVO_AXES]
        at_1, at_2 = e1 @ u + f1, e2 @ u + f2
        y = (at_2 - at_1) / (m2 - m1)
        return at_1 - m1 * y, y

    def payload_regressor_at(self, state: MachineState,
                             axes: tuple[int, ...]) -> tuple[list[float], list[float]]:
        """`payload_regressor`'s entries of ``axes`` (indices of the nine), as floats.

        The observer's per tick (the lift and tilt): the same products (``ndarray.dot``
        makes `@`'s BLAS call, ``dgemv``, for half its Python cost), then the element-wise
        steps on those entries alone in Python floats: the same operations on the same
        doubles, the same bits, ~1.5 us less.
        """
        if not isinstance(state, MachineState):
            raise EstimatorError(f"expected a MachineState, got {type(state).__name__}")
        (e1, f1), (e2, f2), (m1, m2) = self._pair_results(state)
        u = state.qdd[:N_SERVO_AXES]
        at_1, at_2 = (e1.dot(u) + f1).tolist(), (e2.dot(u) + f2).tolist()
        m1 = float(m1)
        span = float(m2) - m1
        y = [(at_2[i] - at_1[i]) / span for i in axes]
        return [at_1[i] - m1 * yi for i, yi in zip(axes, y)], y

    def point_specific_forces(self, state: MachineState,
                              mounts) -> tuple[np.ndarray, np.ndarray]:
        """``(A (3 k, 9), b (3 k,))``: the specific forces at k points are ``A u + b``.

        Each point's in its body's axes [m/s^2]: ``R_b^T (a_p - g)`` with ``a_p`` the
        classical acceleration of the point, affine in the nine axes' accelerations ``u``
        (``state.qdd[:9]`` is ignored; the base's and the wheels' accelerations are used), as
        an accelerometer fixed there reads it.

        Args:
            state: The machine state.
            mounts: ``(body, point)`` pairs: a body of the description and a point in its
                frame [m], shape (3,).

        Raises:
            EstimatorError: A body that is not one of the description's.
        """
        if self._kernels is not None:
            out = self._kernels.points(state, mounts)
            if out is not None:
                return out
        pm = self._pair[0]
        model, data = pm.model, pm.data
        fids = [self._body_frame(body) for body, _ in mounts]
        q, v, a, ja = self._tree_motion(state)
        pin.forwardKinematics(model, data, q, v, a)
        pin.computeJointJacobians(model, data)  # on forwardKinematics' placements: one pass
        rows, bias = [], []
        for fid, (_, point) in zip(fids, mounts):
            pin.updateFramePlacement(model, data, fid)
            p = [float(x) for x in point]
            jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL)[:, pm._tree_v_idx] @ ja
            rows.append(jac[:3] - skew(p) @ jac[3:])  # v_p = v_o + w x p
            vf = pin.getFrameVelocity(model, data, fid, pin.LOCAL)
            af = pin.getFrameAcceleration(model, data, fid, pin.LOCAL)
            w = vf.angular.tolist()
            v_p = np.add(vf.linear, cross3(w, p))
            a_p = af.linear + cross3(af.angular.tolist(), p) + cross3(w, v_p.tolist())
            bias.append(a_p - data.oMf[fid].rotation.T @ model.gravity.linear)
        return np.vstack(rows), np.concatenate(bias)

    def point_specific_forces_row(self, state: MachineState, mounts) -> np.ndarray | None:
        """`point_specific_forces` as the compiled kernel's output row, not copied.

        ``A`` (3 k x 9, row-major), ``b`` (3 k) and a checksum: this thread's buffer, valid
        until the next call. None without the kernel, or when its result is not finite
        (`point_specific_forces` then takes Pinocchio's path).
        """
        if self._kernels is None:
            return None
        return self._kernels.points_row(state, mounts)

    def prepare_points(self, mounts) -> None:
        """Build `point_specific_forces`' kernel for ``mounts`` now (start-up, not a tick).

        Raises:
            EstimatorError: As `point_specific_forces` for a bad mount.
        """
        if self._kernels is not None:
            self._kernels.points_kernel(mounts)
        else:
            for body, _ in mounts:
                self._body_frame(body)

    def _body_frame(self, body: str) -> int:
        """Pinocchio's frame id of the description's body ``body`` (kept)."""
        fid = self._frames.get(body)
        if fid is None:
            model = self._pair[0].model
            if not model.existFrame(body, pin.FrameType.BODY):
                raise EstimatorError(f"no body {body!r} in the machine description")
            fid = self._frames[body] = model.getFrameId(body, pin.FrameType.BODY)
        return fid

    def efforts(self, state: MachineState) -> np.ndarray:
        """The nine efforts at the state's own accelerations [N or N m], shape (9,)."""
        E, e0 = self.affine(state)
        return E @ state.qdd[:N_SERVO_AXES] + e0
