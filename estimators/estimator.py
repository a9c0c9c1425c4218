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

import math
import threading

import numpy as np

from estimators import _reference, batch, linearize_batch, suspension_response
from estimators import full_dynamics as fd
from estimators._row_views import ESTIMATE_VIEWS, LINEARIZATION_VIEWS, OUT_VIEWS, ROW_CHECKS
from estimators._symbolic import LAYOUT, Kernels
from estimators.batch import SINGULAR_CONDITION
from estimators.checks import check_finite_result, check_options, check_payload_mass
from estimators.errors import EstimatorInputError, SingularSystemError, range_message
from estimators.linearization import ForceLinearization
from estimators.packing import RowPacker
from estimators.quasi_static import QuasiStaticMask
from estimators.results import BatchEstimate, Estimate
from estimators.tipping import central_differences, least_squares, masked_pinv
from estimators.tree import TreeModel
from models.description import Machine
from models.state import MachineState

__all__ = ["NormalForceEstimator"]

_FD_STEP = 1e-6  # [m, rad], [m/s, rad/s]: central-difference step where no exact column exists
_NO_FRICTION = np.zeros((4, 3))
_NO_FRICTION.setflags(write=False)

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
        self.D, self.beta = check_options(method, fourth, D, beta, backend, strokes)
        self.machine = machine
        self.method = method
        self.fourth = fourth
        self.strokes = strokes
        self.n_clipped = 0
        self.tree = TreeModel.shared(machine)
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
        zeroed = None
        if self._qs is not None:
            drop = self._qs.dropped_index
            zeroed = np.concatenate([np.arange(LAYOUT.twist.start, LAYOUT.acceleration.stop),
                                     LAYOUT.qd.start + drop, LAYOUT.qdd.start + drop])
        self._packer = RowPacker(machine, fourth, zeroed, self.tree.payload_mass)
        self._pack = self._packer.fill  # bound once: the per-call path looks them up often
        self._bounds = self._packer.bounds
        self._ranges = self._packer.ranges
        self._calls = threading.local()

    @property
    def payload_mass(self) -> float:
        """The payload's mass [kg]: a kernel input, settable (the description's at first)."""
        return float(self._packer.payload[0])

    @payload_mass.setter
    def payload_mass(self, value) -> None:
        self._packer.payload[0] = check_payload_mass(value)

    def warm(self) -> None:
        """Build or load every kernel now rather than at its first call.

        A kernel is generated, compiled (or read from the disk cache) and loaded when first
        called: ~0.1 s each, which a controller would otherwise spend in its first tick.
        Nothing to do for the ``reference`` backend.
        """
        if self._kernels is not None:
            for name in self._kernels.functions:
                self._kernels.kernel(name)
            linearize_batch.library()  # the horizon's nodes in one call (`linearize_states`)
            suspension_response.library()  # the margin's stepped forces in one call

    # ------------------------------------------------------------------ inputs
    def _checked(self, state) -> tuple[MachineState, tuple[str, ...]]:
        """The state to evaluate, after the stroke policy; and the coordinates clipped.

        Shapes, finiteness and the rotation were checked when the state was built
        (`MachineState` is validated once, at construction); the ranges depend on the
        machine and are checked here.
        """
        if not isinstance(state, MachineState):
            raise EstimatorInputError(f"state must be a MachineState, got {type(state).__name__}")
        q = state.q
        values = q.tolist()
        for i, lo, hi in self._bounds:  # `RowPacker.out_of_range`, inlined: every call runs it
            if not lo <= values[i] <= hi:
                break
        else:
            return state, ()
        if self.strokes == "raise":
            name, unit, i, lo, hi = self._packer.out_of_range(q)[0]
            raise EstimatorInputError(range_message(name, unit, i, float(q[i]), (lo, hi)))
        q, names = self._packer.clipped(q)
        self.n_clipped += 1
        return state.replace(q=q), names

    def _fill(self, inp: np.ndarray, state: MachineState) -> fd.Selectors:
        """Pack ``state`` into a kernel input row; returns the `Selectors` used."""
        return self._packer.fill(inp, state, self.D, self.beta)[0]

    def _call(self, name: str):
        """(input buffer, output buffer, call, input bytes, output views) of kernel ``name``.

        This thread's: the input bytes (a memoryview of the buffer) are what `RowPacker.fill`
        writes; the output views (`OUT_VIEWS`), made once, are what a caller copies out.
        """
        calls = self._calls.__dict__
        hit = calls.get(name)
        if hit is None:
            inp, out, call = self._kernels.single(name)
            views = OUT_VIEWS[name](out) if name in OUT_VIEWS else ()
            hit = calls[name] = (inp, out, call, memoryview(inp).cast("B"), views)
        return hit

    def _reference_row(self, inp: np.ndarray, sel: fd.Selectors) -> np.ndarray:
        """The kernel's ``nf_estimate`` output row computed by the numpy reference."""
        lay = LAYOUT
        rot = inp[lay.rotation].reshape(3, 3)
        dyn, out = fd.evaluate(
            self.tree, rot, inp[lay.twist], inp[lay.acceleration], inp[lay.q], inp[lay.qd],
            inp[lay.qdd], inp[lay.points].reshape(4, 3), inp[lay.use_measured],
            inp[lay.force].reshape(4, 3), sel, inp[lay.d], inp[lay.beta],
            inp[lay.suspension_force], float(inp[lay.payload_mass]))
        x = out["x"]
        row = np.concatenate([x, out["xi"], out["A"].ravel(), out["b"], [out["cond"]],
                              np.ravel(out["points"]), out["A"] @ x - out["b"]])
        return np.append(row, row.sum())

    def _normals(self, state: MachineState) -> np.ndarray:
        if state.contacts is not None:
            return state.contacts.normal_in_fb
        return np.repeat(state.base_rotation[2:3], 4, axis=0)  # world z in fb: flat ground

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
            EstimatorInputError: Not a `MachineState`, a stroke (or telescope or wrist joint)
                outside its range under ``strokes="raise"`` (the message names the coordinate
                and the range), or inputs so large that the result overflows.
            SingularSystemError: The system is singular (condition number above 1e12).
        """
        state, _ = self._checked(state)
        if self._kernels is not None:
            inp, out, call, raw, _ = self._call("nf_estimate")
            sel, flags = self._pack(inp, state, self.D, self.beta, raw)
            call()
            row = out.copy()
        else:
            inp = np.zeros(LAYOUT.size)
            sel, flags = self._pack(inp, state, self.D, self.beta)
            row = self._reference_row(inp, sel)
        if sel.tipping or not (math.isfinite(row[LAYOUT.out_sum])
                               and row[LAYOUT.out_cond] < SINGULAR_CONDITION):
            return self._estimate_special(state, row, sel, flags)
        # The common case: a finite, regular four- or three-wheel system. One row, one copy;
        # the array fields are views into it, made when first read.
        c = state.contacts
        if c is None:
            fields = {"in_contact": flags, "mode": sel.mode, "tipping": sel.tipping,
                      "backend": self.backend, "friction": _NO_FRICTION,
                      "_rotation": state.base_rotation}
        else:
            fields = {"in_contact": flags, "mode": sel.mode, "tipping": sel.tipping,
                      "backend": self.backend, "normals": c.normal_in_fb,
                      "friction": c.force_in_fb}
        return Estimate.from_row(fields, ESTIMATE_VIEWS, row)

    def _estimate_special(self, state: MachineState, row: np.ndarray, sel: fd.Selectors,
                          flags: np.ndarray) -> Estimate:
        """`estimate` of a tipping, singular or non-finite row: solved or checked, or raised."""
        lay = LAYOUT
        x = row[lay.out_x]
        a = row[lay.out_a].reshape(3, 4)
        b = row[lay.out_b]
        cond = float(row[lay.out_cond])
        residual = row[lay.out_residual]
        points = row[lay.out_points].reshape(4, 3)
        finite = math.isfinite(row[lay.out_sum])  # the whole row at once: the common case
        if not finite:
            check_finite_result("the normal-force system", state, a, b, row[lay.out_xi])
        if sel.tipping:
            x, cond = least_squares(a, b, sel.mask)
            residual = a @ x - b
        elif not cond < SINGULAR_CONDITION:
            self._singular(sel, cond)
        if not finite or sel.tipping:
            check_finite_result("the normal forces", state, x, residual, points)
        c = state.contacts
        friction = c.force_in_fb if c is not None else _NO_FRICTION
        return Estimate(x, flags, row[lay.out_xi], cond, sel.mode, sel.tipping,
                        residual, points, a, b, self.backend, self._normals(state), friction)

    def _singular(self, sel: fd.Selectors, cond: float) -> None:
        """Raise `SingularSystemError` for the non-tipping system of condition ``cond``."""
        raise SingularSystemError(
            f"{sel.mode} system is singular (1-norm condition {cond:.3g} >= "
            f"{SINGULAR_CONDITION:.0e}); check D (={self.D}) and the contact geometry", cond)

    def _kernel_row(self, name: str, state: MachineState, what: str,
                    tipping_call: bool = True):
        """(output row, `Selectors`, contact flags) of kernel ``name`` at ``state``.

        Without ``tipping_call``, a tipping state is packed but not evaluated (the row is
        None): the caller evaluates the packed input otherwise.

        The row is this thread's output buffer of the kernel, valid until the kernel runs
        again on this thread: callers copy what they keep.

        The row's checksum and condition entries (`estimators._symbolic.Layout`) are checked:
        a non-finite system is an `EstimatorInputError`, a singular non-tipping one a
        `SingularSystemError`, as in `estimate`. Tipping rows are returned unchecked (their
        callers solve them in least squares).
        """
        inp, row, call, raw, _ = self._call(name)
        sel, flags = self._pack(inp, state, self.D, self.beta, raw)
        if sel.tipping and not tipping_call:
            return None, sel, flags
        call()
        cond_at, sum_at = ROW_CHECKS[name]
        if not sel.tipping and not (math.isfinite(row[sum_at])
                                    and row[cond_at] < SINGULAR_CONDITION):
            # The estimate kernel's outputs say which: overflow or a singular system.
            lay = LAYOUT
            ein, eout, ecall, *_ = self._call("nf_estimate")
            ein[:] = inp
            ecall()
            if not math.isfinite(eout[lay.out_sum]):
                check_finite_result("the normal-force system", state, eout[lay.out_a],
                                    eout[lay.out_b])
            cond = float(eout[lay.out_cond])
            if not cond < SINGULAR_CONDITION:
                self._singular(sel, cond)
            check_finite_result(what, state, row)
        return row, sel, flags

    def constraint(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """Affine map of the normal forces in the generalised accelerations.

        ``f_z = G a + g0`` exactly, with ``a = [base_acceleration (6), qdd (13)]`` at the
        state's q, qd, base twist and measured friction (the normal forces are affine in
        ``a``: F_Xi is, and the system matrix does not depend on ``a``).

        Returns:
            ``(G, g0)``: shapes (4, 19) and (4,) [N per unit acceleration, N].

        Raises:
            EstimatorInputError: As for `estimate` (not a state, a coordinate out of range
                under ``strokes="raise"``, inputs so large that the result overflows).
            SingularSystemError: The system is singular (the same test as `estimate`).
        """
        state, _ = self._checked(state)
        if self._kernels is None:
            return _reference.constraint(self, state)
        row, sel, _ = self._kernel_row("nf_constraint", state, "the force constraint (G, g0)")
        if sel.tipping or self._qs is not None:
            return self._constraint_special(state, sel, row, row[LAYOUT.con_g].reshape(4, 19))
        g_out, g0_out = self._call("nf_constraint")[4]
        return g_out.copy(), g0_out.copy()

    def _constraint_special(self, state, sel, row, g):
        """(G, g0) of a tipping state (least squares) or of the quasi-static method."""
        lay = LAYOUT
        x = row[lay.con_x]
        if sel.tipping:
            ein, eout, ecall, *_ = self._call("nf_estimate")
            self._fill(ein, state)
            ecall()
            pinv = masked_pinv(eout[lay.out_a].reshape(3, 4), sel.mask)
            with np.errstate(invalid="ignore", over="ignore"):  # overflow: checked below
                x = pinv @ eout[lay.out_b]
                g = pinv @ row[lay.con_jb].reshape(3, 19)
        if self._qs is not None:
            g = g * self._qs.accelerations
        with np.errstate(invalid="ignore", over="ignore"):  # overflow: checked below
            g0 = x - g @ state.acceleration
        check_finite_result("the force constraint (G, g0)", state, g, g0)
        return g, g0

    def linearize(self, state: MachineState) -> ForceLinearization:
        """Everything a controller needs at ``state``, in one immutable object.

        The forces, ``G = df_z/da``, ``g0 = f_z - G a``, ``df_z/dq``, ``df_z/dqd``, the
        contact flags and the mode, finite in every contact mode. Derivatives with respect
        to q move the wheel bottoms with the bogies; measured contact points
        (`MachineState.contacts`) are held fixed. They are exact (the compiled derivative
        kernel) with four or three wheels in contact; while tipping, and with the numpy
        ``reference`` backend, they are central differences of the least-squares solution
        (step 1e-6, kept inside the stroke ranges; while tipping, every perturbed input row
        in one batch call of the compiled kernel: `estimators.tipping.central_differences`).
        Strokes outside their ranges follow the estimator's ``strokes`` policy (raise, or
        clip and report in `ForceLinearization.clipped`).

        Raises:
            EstimatorInputError: Not a state, (``strokes="raise"``) a stroke or joint out of
                range, or inputs so large that a result overflows.
            SingularSystemError: The system is singular (as in `estimate`).
        """
        state, clipped = self._checked(state)
        if self._kernels is not None:
            out, sel, flags = self._kernel_row("nf_derivatives", state, "the linearization",
                                               tipping_call=False)
            if not sel.tipping:
                if self._qs is None:
                    # A read-only copy of the row (one call); the arrays are its views, made
                    # on first access, read-only like those of `ForceLinearization.trusted`.
                    return ForceLinearization.from_row(
                        {"in_contact": flags, "mode": sel.mode, "clipped": clipped,
                         "time": state.time}, LINEARIZATION_VIEWS, np.frombuffer(out.tobytes()))
                row = out.copy()
                lay = LAYOUT
                g, g0 = row[lay.der_a].reshape(4, 19), row[lay.der_g0]
                d_q, d_qd = row[lay.der_q].reshape(4, 13), row[lay.der_qd].reshape(4, 13)
                g = g * self._qs.accelerations
                d_qd = d_qd * self._qs.coordinates
                forces = row[lay.der_x]
                return ForceLinearization(forces, g, forces - g @ state.acceleration, d_q,
                                          d_qd, flags, sel.mode, clipped, state.time)
            g, _ = self.constraint(state)  # its own buffers: the packed row below stays
            coords = self.tree.coordinates
            forces, d_q, d_qd = central_differences(
                self._kernels.kernel("nf_estimate"), LAYOUT, self._call("nf_derivatives")[0],
                sel.mask, coords.lower, coords.upper, _FD_STEP, self._packer.zeroed)
            g0 = forces - g @ state.acceleration
            check_finite_result("the linearization", state, forces, g, g0, d_q, d_qd)
            return ForceLinearization(forces, g, g0, d_q, d_qd, flags, sel.mode, clipped,
                                      state.time)
        est = self.estimate(state)
        g, _ = self.constraint(state)
        d_q, d_qd = _reference.central_differences(self, state, _FD_STEP)
        g0 = est.normal_forces - g @ state.acceleration
        check_finite_result("the linearization", state, est.normal_forces, g, g0, d_q, d_qd)
        return ForceLinearization(est.normal_forces, g, g0, d_q, d_qd, est.in_contact,
                                  est.mode, clipped, state.time)

    def estimate_batch(self, states, *, strict: bool = True, chunk: int = 4096,
                       threads: int = 2, payload_mass=None) -> BatchEstimate:
        """Normal forces of a log of states, vectorised.

        Args:
            states: A `StateBatch`, a mapping of its field names to arrays, or a sequence of
                `MachineState`.
            strict: Raise `SingularSystemError` for a singular row; otherwise solve it in
                least squares and flag it in `BatchEstimate.singular`.
            chunk: States per compiled call.
            threads: Threads over chunks (the compiled code releases the GIL).
            payload_mass: Each row's payload [kg], shape (N,); None: `payload_mass`.

        Returns:
            The `BatchEstimate`.

        Raises:
            EstimatorInputError: A field has a wrong shape, NaN/inf, or a stroke is out of
                range (the message names the field, the rows and the range), or a payload
                mass outside [0, `MAX_PAYLOAD_MASS`].
            SingularSystemError: With ``strict``, a row's system is singular.
        """
        return batch.estimate_batch(self, states, strict=strict, chunk=chunk, threads=threads,
                                    payload_mass=payload_mass)


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
        from estimators.calibration import calibrate_batch

        return calibrate_batch(self.estimate_batch(states, strict=False), normal_forces_gt,
                               window, stride, solver)
