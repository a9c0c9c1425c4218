"""`NormalForceEstimator`: the public face of the full-dynamics and quasi-static methods.

Backends (which code computes the numbers; `Estimate.backend` says which ran):

* ``compiled`` (default when a C compiler works): the CasADi graph of the screw-theory
  recursion and the normal-force system (`estimators._symbolic`), compiled to C and called
  through ctypes; one call per state, one C loop per chunk of a batch.
* ``casadi``: the same graph in CasADi's virtual machine (no compiler needed; slower).
* ``reference``: the numpy recursion of `estimators.tree` / `estimators.full_dynamics`,
  readable and paper-faithful, about a millisecond per state.

All three run the same source (`TreeModel.dynamics` and `full_dynamics.normal_force_system`)
and agree to round-off; the tests check them against Pinocchio's RNEA.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from estimators import full_dynamics as fd
from estimators._symbolic import LAYOUT, Kernels
from estimators.errors import EstimatorInputError, SingularSystemError
from estimators.linearization import ForceLinearization
from estimators.quasi_static import QuasiStaticMask
from estimators.tree import TreeModel
from models.description import Machine
from models.errors import StateError
from models.state import MachineState
from models.state_batch import StateBatch

__all__ = [
    "BatchEstimate",
    "ConstraintDerivatives",
    "Estimate",
    "NormalForceEstimator",
    "StateBatch",
]

STROKE_POLICIES = ("raise", "clip")
_FD_STEP = 1e-6  # [m, rad], [m/s, rad/s]: central-difference step where no exact column exists

METHODS = ("full", "quasi-static")
FOURTH = ("d-beta", "cylinder-force")
BACKENDS = ("auto", "compiled", "casadi", "reference")
SINGULAR_CONDITION = 1e12  # 1-norm condition number above which a system counts as singular


@dataclass(slots=True)
class Estimate:
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


@dataclass
class ConstraintDerivatives:
    """Normal forces and their exact derivatives at one state (for MPC linearisation).

    Attributes:
        normal_forces: f_z [N], shape (4,).
        d_acceleration: d f_z / d a, a = [base_acceleration (6), qdd (13)], shape (4, 19).
        d_q: d f_z / d q (independent coordinates, measured contact points held fixed),
            shape (4, 13).
        d_qd: d f_z / d qd, shape (4, 13).
    """

    normal_forces: np.ndarray
    d_acceleration: np.ndarray
    d_q: np.ndarray
    d_qd: np.ndarray


def _range_message(name: str, index: int, value: float, rng: tuple[float, float]) -> str:
    return (f"q[{index}] (stroke of cylinder chain '{name}') = {value:.6g} m outside "
            f"[{rng[0]:.6g}, {rng[1]:.6g}] m")


class NormalForceEstimator:
    """Wheel-ground normal forces of a machine state (paper Sec. III).

    Args:
        machine: The machine description (`models.description.Machine`).
        method: ``full`` (the paper's full dynamics) or ``quasi-static`` (ref. [13], see
            `estimators.quasi_static`).
        fourth: Equation that closes the 3x4 system: ``d-beta`` (eq. 29) or
            ``cylinder-force`` (bogie moment balances with the measured suspension cylinder
            forces; falls back to ``d-beta`` for a state without them, see `Estimate.mode`).
        D: Parameter D of eq. (29) [-].
        beta: Parameter beta of eq. (29) [N].
        backend: ``auto`` (compiled if a C compiler works, else ``casadi``), ``compiled``,
            ``casadi`` or ``reference``.
        strokes: What a state whose stroke (or joint) lies outside its valid range gets:
            ``raise`` (`EstimatorInputError` naming the chain and the range) or ``clip``
            (evaluated at the nearest valid value; the clipped coordinates are reported in
            `ForceLinearization.clipped` and counted in `n_clipped`). Closed loops use
            ``clip``: MuJoCo's soft joint limits let a measured stroke pass its end by
            millimetres, and MPC nominal states ahead can lie a little outside.

    Raises:
        EstimatorInputError: Unknown option or non-finite D or beta.
    """

    def __init__(self, machine: Machine, method: str = "full", fourth: str = "d-beta",
                 D: float = 0.5, beta: float = 0.0, backend: str = "auto",  # noqa: N803
                 strokes: str = "raise"):
        if not isinstance(machine, Machine):
            raise EstimatorInputError(f"machine must be a Machine, got {type(machine).__name__}")
        for name, value, valid in (("method", method, METHODS), ("fourth", fourth, FOURTH),
                                   ("backend", backend, BACKENDS),
                                   ("strokes", strokes, STROKE_POLICIES)):
            if value not in valid:
                raise EstimatorInputError(f"{name}={value!r} is not one of {valid}")
        for name, value in (("D", D), ("beta", beta)):
            if not np.isfinite(value):
                raise EstimatorInputError(f"{name} must be finite, got {value}")
        self.machine = machine
        self.method = method
        self.fourth = fourth
        self.D = float(D)
        self.beta = float(beta)
        self.strokes = strokes
        self.n_clipped = 0
        self.tree = _tree_for(machine)
        self._qs = QuasiStaticMask(machine) if method == "quasi-static" else None
        self._kernels: Kernels | None = None
        if backend in ("auto", "compiled", "casadi"):
            self._kernels = Kernels.for_tree(self.tree, compile=backend != "casadi")
            if backend == "compiled" and not self._kernels.compiled:
                raise EstimatorInputError("backend='compiled' needs a working C compiler "
                                          "(set CC); use backend='auto' or 'casadi'")
            self.backend = "compiled" if self._kernels.compiled else "casadi"
        else:
            self.backend = "reference"
        self._ranges = tuple((c.name, c.coordinate, c.stroke_range[0], c.stroke_range[1])
                             for c in self.tree.chains)
        self._selector_cache: dict = {}
        self._no_contacts = np.zeros(LAYOUT.force.stop - LAYOUT.points.start)
        self._all_in = np.ones(4, bool)
        self._up_cache: tuple | None = None
        if self._qs is not None:
            drop = self._qs.dropped_index
            self._qs_zero = np.concatenate([np.arange(LAYOUT.twist.start,
                                                      LAYOUT.acceleration.stop),
                                            LAYOUT.qd.start + drop, LAYOUT.qdd.start + drop])

    # ------------------------------------------------------------------ inputs
    def _selectors(self, in_contact: np.ndarray, has_cyl: bool):
        key = (in_contact.tobytes(), has_cyl)
        hit = self._selector_cache.get(key)
        if hit is None:
            s = fd.select_system(in_contact, self.fourth, has_cyl)
            packed = np.concatenate([s.mask, s.height_weights, [s.s_dbeta, s.s_cylinder],
                                     s.lost])
            hit = (packed, s)
            self._selector_cache[key] = hit
        return hit

    def _checked(self, state) -> tuple[MachineState, tuple[str, ...]]:
        """The state to evaluate, after the stroke policy; and the coordinates clipped.

        Shapes, finiteness and the rotation were checked when the state was built
        (`MachineState` is validated once, at construction); the ranges depend on the
        machine and are checked here.
        """
        if not isinstance(state, MachineState):
            raise EstimatorInputError(f"state must be a MachineState, got {type(state).__name__}")
        q = state.q
        bad = [(name, i, lo, hi) for name, i, lo, hi in self._ranges
               if not lo - 1e-12 <= q[i] <= hi + 1e-12]
        if not bad:
            return state, ()
        if self.strokes == "raise":
            name, i, lo, hi = bad[0]
            raise EstimatorInputError(_range_message(name, i, float(q[i]), (lo, hi)))
        q = q.copy()
        for name, i, lo, hi in bad:
            q[i] = min(max(q[i], lo), hi)
        self.n_clipped += 1
        return replace(state, q=q), tuple(name for name, *_ in bad)

    def _fill(self, inp: np.ndarray, state: MachineState):
        """Pack ``state`` into a kernel input row; returns the `Selectors` used."""
        lay = LAYOUT
        try:
            r = state.base_rotation
            np.concatenate((r.reshape(9), state.base_twist, state.base_acceleration, state.q,
                            state.qd, state.qdd), out=inp[:lay.points.start])
            c = state.contacts
            if c is None:
                inp[lay.points.start:lay.force.stop] = self._no_contacts
                in_contact = self._all_in
            else:
                np.concatenate((c.point_in_fb.reshape(12), self._ones4,
                                c.force_in_fb.reshape(12)),
                               out=inp[lay.points.start:lay.force.stop])
                in_contact = c.in_contact
            f = state.suspension_force
            packed, sel = self._selectors(in_contact, f is not None)
            inp[lay.mask.start:lay.lost.stop] = packed
            inp[lay.d] = self.D
            inp[lay.beta] = self.beta
            if f is None:
                inp[lay.suspension_force] = 0.0
            else:
                inp[lay.suspension_force] = f
        except (ValueError, AttributeError, TypeError) as exc:
            raise EstimatorInputError(f"cannot read the state: {exc}") from exc
        if self._qs is not None:
            inp[self._qs_zero] = 0.0
        return sel

    _ones4 = np.ones(4)

    def _reference_row(self, inp: np.ndarray, sel: fd.Selectors) -> np.ndarray:
        """The kernel's ``nf_estimate`` output row computed by the numpy reference."""
        lay = LAYOUT
        rot = inp[lay.rotation].reshape(3, 3)
        dyn, out = fd.evaluate(
            self.tree, rot, inp[lay.twist], inp[lay.acceleration], inp[lay.q], inp[lay.qd],
            inp[lay.qdd], inp[lay.points].reshape(4, 3), inp[lay.use_measured],
            inp[lay.force].reshape(4, 3), sel, inp[lay.d], inp[lay.beta],
            inp[lay.suspension_force])
        x = out["x"]
        return np.concatenate([x, out["xi"], out["A"].ravel(), out["b"], [out["cond"]],
                               np.ravel(out["points"]), out["A"] @ x - out["b"]])

    def _normals(self, state: MachineState) -> np.ndarray:
        if state.contacts is not None:
            return state.contacts.normal_in_fb
        up = state.base_rotation[2]  # world z in fb: the flat-ground normal
        return np.tile(up, (4, 1))

    # ------------------------------------------------------------------ public API
    def estimate(self, state: MachineState) -> Estimate:
        """Normal forces of one state.

        Args:
            state: The machine state (with `MachineState.contacts` for measured friction,
                contact points and contact flags; with `MachineState.suspension_force` for
                the ``cylinder-force`` fourth equation).

        Returns:
            The `Estimate`.

        Raises:
            EstimatorInputError: NaN/inf, a wrong shape, a non-rotation base orientation or a
                stroke outside its chain's range (the message names the field and range).
            SingularSystemError: The system is singular (condition number above 1e12).
        """
        state, _ = self._checked(state)
        lay = LAYOUT
        if self._kernels is not None:
            inp, out, call = self._kernels.single("nf_estimate")
            sel = self._fill(inp, state)
            call()
        else:
            inp = np.zeros(lay.size)
            sel = self._fill(inp, state)
            out = self._reference_row(inp, sel)
        x = out[0:4].copy()
        a = out[lay.out_a].reshape(3, 4).copy()
        b = out[lay.out_b].copy()
        cond = float(out[lay.out_cond])
        residual = out[lay.out_residual].copy()
        if sel.tipping:
            x, cond = _least_squares(a, b, sel.mask)
            residual = a @ x - b
        elif not cond < SINGULAR_CONDITION:
            raise SingularSystemError(
                f"{sel.mode} system is singular (1-norm condition {cond:.3g} >= "
                f"{SINGULAR_CONDITION:.0e}); check D (={self.D}) and the contact geometry",
                cond)
        c = state.contacts
        friction = c.force_in_fb if c is not None else self._no_contacts[:12].reshape(4, 3)
        return Estimate(x, sel.mask > 0, out[lay.out_xi].copy(), cond, sel.mode, sel.tipping,
                        residual, out[lay.out_points].reshape(4, 3).copy(), a, b, self.backend,
                        self._normals(state), friction)

    def constraint(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """Affine map of the normal forces in the generalised accelerations.

        ``f_z = G a + g0`` exactly, with ``a = [base_acceleration (6), qdd (13)]`` at the
        state's q, qd, base twist and measured friction (the normal forces are affine in
        ``a``: F_Xi is, and the system matrix does not depend on ``a``).

        Returns:
            ``(G, g0)``: shapes (4, 19) and (4,) [N per unit acceleration, N].
        """
        state, _ = self._checked(state)
        lay = LAYOUT
        if self._kernels is None:
            return self._constraint_reference(state)
        inp, out, call = self._kernels.single("nf_constraint")
        sel = self._fill(inp, state)
        call()
        g = out[lay.con_g].reshape(4, 19).copy()
        x = out[lay.con_x].copy()
        if sel.tipping:
            ein, eout, ecall = self._kernels.single("nf_estimate")
            ein[:] = inp
            ecall()
            a = eout[lay.out_a].reshape(3, 4)
            pinv = _masked_pinv(a, sel.mask)
            x = pinv @ eout[lay.out_b]
            g = pinv @ out[lay.con_jb].reshape(3, 19)
        if self._qs is not None:
            g = g * self._qs.accelerations
        acc = np.concatenate([state.base_acceleration, state.qdd])
        return g, x - g @ acc

    def _constraint_reference(self, state: MachineState):
        base = self.estimate(state).normal_forces
        acc = np.concatenate([state.base_acceleration, state.qdd])
        g = np.zeros((4, 19))
        for j in range(19):
            a = acc.copy()
            a[j] += 1.0  # exact: the map is affine
            s = replace(state, base_acceleration=a[:6], qdd=a[6:])
            g[:, j] = self.estimate(s).normal_forces - base
        return g, base - g @ acc

    def constraint_derivatives(self, state: MachineState) -> ConstraintDerivatives:
        """Exact derivatives of the normal forces for MPC linearisation.

        Derivatives with respect to q move the wheel bottoms with the bogies; measured
        contact points (`MachineState.contacts`) are held fixed. While tipping the
        derivatives come from central differences of the least-squares solution.

        Returns:
            `ConstraintDerivatives` with d f_z / d a (4, 19), d f_z / d q (4, 13) and
            d f_z / d qd (4, 13).
        """
        state, _ = self._checked(state)
        lay = LAYOUT
        if self._kernels is None or self.estimate(state).tipping:
            return self._derivatives_fd(state)
        inp, out, call = self._kernels.single("nf_derivatives")
        self._fill(inp, state)
        call()
        ga = out[lay.der_a].reshape(4, 19).copy()
        gq = out[lay.der_q].reshape(4, 13).copy()
        gqd = out[lay.der_qd].reshape(4, 13).copy()
        if self._qs is not None:
            ga *= self._qs.accelerations
            gqd *= self._qs.coordinates
        return ConstraintDerivatives(out[lay.der_x].copy(), ga, gq, gqd)

    def _derivatives_fd(self, state: MachineState, h: float = 1e-6) -> ConstraintDerivatives:
        g, g0 = self.constraint(state)
        base = self.estimate(state).normal_forces
        gq = np.zeros((4, 13))
        gqd = np.zeros((4, 13))
        for j in range(13):
            for target, field_name in ((gq, "q"), (gqd, "qd")):
                lo, hi = -h, h
                for name, i, rlo, rhi in self._ranges:
                    if i == j and field_name == "q":
                        lo = max(-h, rlo - state.q[i])
                        hi = min(h, rhi - state.q[i])
                vals = []
                for step in (lo, hi):
                    v = getattr(state, field_name).copy()
                    v[j] += step
                    s = replace(state, **{field_name: v})
                    vals.append(self.estimate(s).normal_forces)
                target[:, j] = (vals[1] - vals[0]) / (hi - lo)
        return ConstraintDerivatives(base, g, gq, gqd)

    def linearize(self, state: MachineState) -> ForceLinearization:
        """Everything a controller needs at ``state``, in one immutable object.

        The forces, ``G = df_z/da``, ``g0``, ``df_z/dq``, ``df_z/dqd``, the contact flags and
        the mode, finite in every contact mode. Strokes outside their ranges follow the
        estimator's ``strokes`` policy (raise, or clip and report in
        `ForceLinearization.clipped`).

        Raises:
            EstimatorInputError: Not a state, or (``strokes="raise"``) a stroke out of range.
            SingularSystemError: The system is singular.
        """
        state, clipped = self._checked(state)
        d = self.constraint_derivatives(state)
        d_q, d_qd = d.d_q, d.d_qd
        if not (np.isfinite(d_q).all() and np.isfinite(d_qd).all()):
            d_q, d_qd = d_q.copy(), d_qd.copy()
            for name, arr in (("q", d_q), ("qd", d_qd)):
                for j in np.flatnonzero(~np.isfinite(arr).all(axis=0)):
                    arr[:, j] = self._central_difference(state, name, j)
        est = self.estimate(state)
        g0 = d.normal_forces - d.d_acceleration @ state.acceleration
        return ForceLinearization(d.normal_forces, d.d_acceleration, g0, d_q, d_qd,
                                  est.in_contact, est.mode, clipped, state.time)

    def _central_difference(self, state: MachineState, name: str, j: int) -> np.ndarray:
        """``df_z/d(name)[j]`` by central differences, staying inside the stroke range."""
        x = getattr(state, name)
        lo, hi = -_FD_STEP, _FD_STEP
        if name == "q":
            lo = max(lo, self.tree.coordinates.lower[j] - x[j])
            hi = min(hi, self.tree.coordinates.upper[j] - x[j])
        if hi - lo <= 0:
            return np.zeros(4)
        vals = []
        for step in (lo, hi):
            v = x.copy()
            v[j] += step
            vals.append(self.estimate(replace(state, **{name: v})).normal_forces)
        return (vals[1] - vals[0]) / (hi - lo)

    def estimate_batch(self, states, *, strict: bool = True, chunk: int = 4096,
                       threads: int = 2) -> BatchEstimate:
        """Normal forces of a log of states, vectorised.

        Args:
            states: A `StateBatch`, a mapping of its field names to arrays, or a sequence of
                `MachineState`.
            strict: Raise `SingularSystemError` for a singular row; otherwise solve it in
                least squares and flag it in `BatchEstimate.singular`.
            chunk: States per compiled call.
            threads: Threads over chunks (the compiled code releases the GIL).

        Returns:
            The `BatchEstimate`.

        Raises:
            EstimatorInputError: A field has a wrong shape, NaN/inf, or a stroke is out of
                range (the message names the field, the rows and the range).
            SingularSystemError: With ``strict``, a row's system is singular.
        """
        sb = _as_batch(states)
        self._validate_batch(sb)
        lay = LAYOUT
        n = len(sb)
        x = np.zeros((n, 4))
        xi = np.zeros((n, 6))
        a = np.zeros((n, 3, 4))
        b = np.zeros((n, 3))
        cond = np.zeros(n)
        residual = np.zeros((n, 3))
        points = np.zeros((n, 4, 3))
        kernel = self._kernels.kernel("nf_estimate") if self._kernels is not None else None

        def run(lo: int) -> None:
            sl = slice(lo, min(lo + chunk, n))
            inp, sel = self._pack_rows(sb, sl)
            if kernel is not None:
                out = np.empty((inp.shape[0], lay.out_size))
                kernel.batch(inp, out)
            else:
                out = np.array([self._reference_row(row, _row_selectors(sel, i))
                                for i, row in enumerate(inp)]).reshape(-1, lay.out_size)
            x[sl] = out[:, lay.out_x]
            xi[sl] = out[:, lay.out_xi]
            a[sl] = out[:, lay.out_a].reshape(-1, 3, 4)
            b[sl] = out[:, lay.out_b]
            cond[sl] = out[:, lay.out_cond]
            residual[sl] = out[:, lay.out_residual]
            points[sl] = out[:, lay.out_points].reshape(-1, 4, 3)

        starts = range(0, n, max(1, int(chunk)))
        if threads > 1 and kernel is not None and len(starts) > 1:
            list(self._kernels.pool(threads).map(run, starts))
        else:
            for lo in starts:
                run(lo)
        ic = sb.in_contact if sb.in_contact is not None else np.ones((n, 4), bool)
        nc = ic.sum(axis=1)
        tip = nc < 3
        cyl = self.fourth == "cylinder-force" and sb.suspension_force is not None
        mode = np.where(nc == 4, "cylinder-force" if cyl else "d-beta",
                        np.where(nc == 3, "3-contact", "tipping")).astype(object)
        singular = ~tip & ~(cond < SINGULAR_CONDITION)
        if strict and singular.any():
            i = int(np.flatnonzero(singular)[0])
            raise SingularSystemError(
                f"row {i}: {mode[i]} system is singular (1-norm condition "
                f"{cond[i]:.3g}); {int(singular.sum())} singular rows in all", cond[i])
        for i in np.flatnonzero(tip | singular):
            x[i], cond[i] = _least_squares(a[i], b[i], ic[i].astype(float))
            residual[i] = a[i] @ x[i] - b[i]
        normals = sb.normal_in_fb if sb.normal_in_fb is not None else np.repeat(
            sb.base_rotation[:, 2][:, None, :], 4, axis=1)
        friction = sb.force_in_fb if sb.force_in_fb is not None else np.zeros((n, 4, 3))
        return BatchEstimate(x, ic.copy(), xi, cond, mode, tip, residual, points, a, b,
                             singular, self.backend, normals, friction)

    def _validate_batch(self, sb: StateBatch) -> None:
        n = len(sb)
        for name, i, lo, hi in self._ranges:
            x = sb.q[:, i]
            bad = ~((x >= lo - 1e-12) & (x <= hi + 1e-12))
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise EstimatorInputError(
                    f"row {k} ({int(bad.sum())} rows in all): "
                    + _range_message(name, i, float(x[k]), (lo, hi)))
        r = sb.base_rotation
        if n:
            err = np.abs(r @ r.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
            det = np.einsum("ni,ni->n", np.cross(r[:, 0], r[:, 1]), r[:, 2])
            bad = (err > 1e-6) | (det < 0)
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise EstimatorInputError(f"'base_rotation' row {k} is not a rotation matrix "
                                          f"({int(bad.sum())} rows in all)")

    def _pack_rows(self, sb: StateBatch, sl: slice):
        """Kernel input rows and selectors of the states ``sl`` of a validated batch."""
        lay = LAYOUT
        r = sb.base_rotation[sl]
        n = r.shape[0]
        inp = np.zeros((n, lay.size))
        inp[:, lay.rotation] = r.reshape(n, 9)
        twist, acc, qd, qdd = (sb.base_twist[sl], sb.base_acceleration[sl], sb.qd[sl],
                               sb.qdd[sl])
        if self._qs is not None:
            twist, acc, qd, qdd = self._qs.apply(twist, acc, qd, qdd)
        inp[:, lay.twist] = twist
        inp[:, lay.acceleration] = acc
        inp[:, lay.q] = sb.q[sl]
        inp[:, lay.qd] = qd
        inp[:, lay.qdd] = qdd
        if sb.point_in_fb is not None:
            inp[:, lay.points] = sb.point_in_fb[sl].reshape(n, 12)
            inp[:, lay.use_measured] = 1.0
        if sb.force_in_fb is not None:
            inp[:, lay.force] = sb.force_in_fb[sl].reshape(n, 12)
        ic = sb.in_contact[sl] if sb.in_contact is not None else np.ones((n, 4), bool)
        mask = ic.astype(float)
        nc = ic.sum(axis=1)
        hw = np.where(nc[:, None] > 0, mask / np.maximum(nc, 1)[:, None], 0.25)
        cyl = self.fourth == "cylinder-force" and sb.suspension_force is not None
        four = nc == 4
        lost = (~ic & (nc == 3)[:, None]).astype(float)
        inp[:, lay.mask] = mask
        inp[:, lay.height_weights] = hw
        inp[:, lay.s_dbeta] = four & (not cyl)
        inp[:, lay.s_cylinder] = four & cyl
        inp[:, lay.lost] = lost
        inp[:, lay.d] = self.D
        inp[:, lay.beta] = self.beta
        if sb.suspension_force is not None:
            inp[:, lay.suspension_force] = sb.suspension_force[sl]
        mode = np.where(four, "cylinder-force" if cyl else "d-beta",
                        np.where(nc == 3, "3-contact", "tipping"))
        sel = dict(mask=mask, hw=hw, lost=lost, mode=mode, tipping=nc < 3,
                   s_dbeta=inp[:, lay.s_dbeta], s_cylinder=inp[:, lay.s_cylinder])
        return inp, sel

    # ------------------------------------------------------------------ calibration
    def calibrate(self, states, normal_forces_gt: np.ndarray, window: int | None = None,
                  stride: int | None = None, solver: str = "scipy"):
        """Fit D and beta of eq. (29) to ground-truth normal forces, eq. (30).

        Args:
            states: As for `estimate_batch`.
            normal_forces_gt: Ground-truth f_z [N], shape (N, 4), order FL, RL, FR, RR.
            window: None for one global pair; else the window length (samples) of a sliding
                fit (paper Fig. 9).
            stride: Step between windows (default ``window // 2``).
            solver: ``scipy`` (least squares) or ``ipopt`` (CasADi).

        Returns:
            A `estimators.calibration.CalibrationResult` (global) or
            `estimators.calibration.SlidingCalibration` (windowed).
        """
        from estimators import calibration

        res = self.estimate_batch(states, strict=False)
        gt = np.asarray(normal_forces_gt, float)
        if gt.shape != res.normal_forces.shape:
            raise EstimatorInputError(f"'normal_forces_gt' must have shape "
                                      f"{res.normal_forces.shape}, got {gt.shape}")
        use = ~res.tipping & (res.in_contact.sum(axis=1) == 4)
        if window is None:
            return calibration.calibrate_d_beta(res.system_matrix[use], res.system_rhs[use],
                                                gt[use], solver=solver)
        return calibration.calibrate_d_beta_sliding(
            res.system_matrix, res.system_rhs, gt, window, stride, valid=use, solver=solver)


_TREES: dict = {}


def _tree_for(machine: Machine) -> TreeModel:
    hit = _TREES.get(id(machine))
    if hit is None or hit[0] is not machine:
        hit = (machine, TreeModel(machine))
        _TREES[id(machine)] = hit
    return hit[1]


def _as_batch(states) -> StateBatch:
    """``states`` as a validated `StateBatch`; a bad field is an `EstimatorInputError`."""
    if isinstance(states, StateBatch):
        return states
    try:
        if isinstance(states, Mapping):
            return StateBatch(**states)
        if isinstance(states, Sequence) or hasattr(states, "__iter__"):
            return StateBatch.from_states(list(states))
    except TypeError as exc:
        raise EstimatorInputError(f"bad state log fields: {exc}") from exc
    except StateError as exc:
        raise EstimatorInputError(str(exc)) from exc
    raise EstimatorInputError(f"cannot read states from a {type(states).__name__}")


def _row_selectors(sel: dict, i: int) -> fd.Selectors:
    return fd.Selectors(str(sel["mode"][i]), sel["mask"][i], sel["hw"][i],
                        float(sel["s_dbeta"][i]), float(sel["s_cylinder"][i]), sel["lost"][i],
                        bool(sel["tipping"][i]))


def _masked_pinv(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    cols = np.flatnonzero(np.asarray(mask) > 0)
    pinv = np.zeros((4, 3))
    if cols.size:
        pinv[cols] = np.linalg.pinv(a[:, cols])
    return pinv


def _least_squares(a: np.ndarray, b: np.ndarray, mask) -> tuple[np.ndarray, float]:
    """Minimum-norm least squares on the wheels in contact; (x, condition)."""
    cols = np.flatnonzero(np.asarray(mask) > 0)
    x = np.zeros(4)
    if cols.size == 0:
        return x, float("inf")
    sub = a[:, cols]
    x[cols] = np.linalg.lstsq(sub, b, rcond=None)[0]
    return x, float(np.linalg.cond(sub))
