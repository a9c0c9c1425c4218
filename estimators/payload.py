r"""The payload as a run-time input: one compiled estimator for every payload mass.

The payload's mass ``m`` is an input of the estimator's compiled kernels (`TreeModel.dynamics`:
the payload's spatial inertia is ``m`` times its inertia per kilogram), and the normal
forces, their map in the accelerations and their sensitivities are affine in it (the dynamics
are linear in the inertial parameters, the payload's centre of mass is fixed in its body,
and every fourth row is linear in the wrench). `PayloadEstimator` holds one
`NormalForceEstimator` and sets its ``payload_mass`` at every tick (an observer's estimate):
one kernel call per estimate or linearization, and ``payload_sensitivity`` (``df/dm``, for the
force margin) from one more row of the same packed input. No kernel is compiled after
construction, whatever the mass.

The estimator is that of the machine with its payload at ``ANCHOR_MASSES[0]``
(`anchor_machines`), not at the machine's own payload: machines that differ only in the
payload's mass (every scenario of a sweep) share the same compiled kernels, so a new payload
never compiles anything. (Until the payload became a kernel input, two estimators at the two
`ANCHOR_MASSES` were interpolated; `estimators.efforts_kernel` still is, at those anchors.)
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from estimators._symbolic import LAYOUT
from estimators.batch import SINGULAR_CONDITION
from estimators.estimator import NormalForceEstimator
from estimators.linearization import ForceLinearization
from estimators.linearize_batch import (
    linearize_first,
    linearize_rows,
    linearize_states,
    prepare_rows,
)
from estimators.margin_kernel import (
    MARGIN_STEP,
    joint_kernel,
    linearize_with_margin,
    margin_kernel,
    margin_terms,
    prepare_joint,
)
from estimators.results import Estimate
from estimators.suspension_response import stepped_forces
from models.description import Machine
from models.reference_machine import MAX_PAYLOAD_MASS
from models.state import MachineState

__all__ = ["ANCHOR_MASSES", "SPAN", "PayloadEstimator", "anchor_machines"]

ANCHOR_MASSES = (150.0, 250.0)  # [kg] m_a (the reference machine's payload) and m_b
SPAN = ANCHOR_MASSES[1] - ANCHOR_MASSES[0]  # [kg] m_b - m_a
_INERTIA_DIGITS = 12  # significant digits of the payload's inertia per kg (`anchor_machines`)


def anchor_machines(machine: Machine) -> tuple[Machine, Machine]:
    """``machine`` with its payload at each of the `ANCHOR_MASSES`, the same for any payload.

    The payload's rotational inertia per kg (its shape: it scales with the mass about a
    fixed centre of mass) is rounded to 12 significant digits before it is scaled to each
    anchor, so that machines that differ only in the payload's mass, whose inertias per kg
    differ in the last bits, give the same two machines and hence the same compiled kernels
    (a rounding boundary between two of them would cost one more compile, no error). The
    description's note on the payload (``sources``, part of the fingerprint the kernels are
    cached by) says the anchor's mass.
    """
    body = next(b for b in machine.bodies if b.name == machine.payload)
    per_kg = np.asarray(body.inertia.inertia, float) / body.inertia.mass
    per_kg = np.array([float(f"{v:.{_INERTIA_DIGITS}g}") for v in per_kg.ravel()]).reshape(3, 3)

    def at(mass: float) -> Machine:
        inertia = dataclasses.replace(body.inertia, mass=float(mass), inertia=per_kg * mass)
        note = (machine.payload, f"{mass:g} kg, the payload estimator's anchor", "derived")
        return dataclasses.replace(
            machine,
            bodies=tuple(dataclasses.replace(b, inertia=inertia) if b.name == machine.payload
                         else b for b in machine.bodies),
            sources=tuple(note if src[0] == machine.payload else src
                          for src in machine.sources))

    return at(ANCHOR_MASSES[0]), at(ANCHOR_MASSES[1])


_RECENT = 4  # states whose estimates a `PayloadEstimator` keeps (`estimate`)


class PayloadEstimator:
    """A `NormalForceEstimator` whose payload mass is set at run time (module docstring).

    Args:
        machine: The machine description (its payload's shape; its mass is the first
            ``payload_mass``).
        **options: `NormalForceEstimator` options (method, fourth, D, beta, strokes, ...).

    Attributes:
        payload_mass: The payload now [kg]; settable, finite, in [0, `MAX_PAYLOAD_MASS`].
        D, beta: The d-beta row's parameters (eq. 29); settable.
        method, fourth: As the wrapped estimator's.
    """

    def __init__(self, machine: Machine, **options):
        body = next(b for b in machine.bodies if b.name == machine.payload)
        self.machine = machine
        self._est = NormalForceEstimator(anchor_machines(machine)[0], **options)
        self._est.warm()  # loaded now, not in a controller's first tick
        if self._est._kernels is not None and self._est.fourth == "cylinder-force":
            # The margin's kernel (`margin_terms`), likewise: a closure's.
            margin_kernel(self._est._kernels, MARGIN_STEP, SPAN)
            joint_kernel(self._est._kernels, MARGIN_STEP, SPAN)  # `linearize_with_margin`'s
        self.method, self.fourth = self._est.method, self._est.fourth
        self._kept: tuple = ()  # `estimate`'s (state, key, estimate), newest first
        self._last: tuple | None = None  # (state, key, linearization) of the last `linearize`
        # `stepped_suspension_forces`' (state, key, f at m, f at m + SPAN)
        self._stepped: tuple | None = None
        self.payload_mass = float(body.inertia.mass)  # the machine's payload to begin with

    @property
    def payload_mass(self) -> float:
        """The payload now [kg]."""
        return self._est.payload_mass

    @payload_mass.setter
    def payload_mass(self, value) -> None:
        self._est.payload_mass = value  # checked there (`EstimatorInputError`)

    @property
    def D(self) -> float:  # noqa: N802 (the paper's name)
        """The d-beta row's D (eq. 29)."""
        return self._est.D

    @D.setter
    def D(self, value: float) -> None:  # noqa: N802
        self._est.D = value

    @property
    def beta(self) -> float:
        """The d-beta row's beta (eq. 29)."""
        return self._est.beta

    @beta.setter
    def beta(self, value: float) -> None:
        self._est.beta = value

    def _key(self) -> tuple:
        """What a kept result depends on besides the state: the mass, D and beta."""
        est = self._est
        return (float(est._packer.payload[0]), est.D, est.beta)

    def estimate(self, state: MachineState) -> Estimate:
        """`NormalForceEstimator.estimate` at the current payload mass.

        The last `_RECENT` states' estimates are kept, by identity (states are immutable),
        for the mass, D and beta they were made at: a control tick asks about the same
        observed state several times (the margin's sensitivities, the MPC's feedback, the
        observer's contact points and forces). A kept estimate (the common, regular four- or
        three-wheel case: its fields are views of one row) is made read-only, as it is
        shared; a tipping or singular one is not kept.
        """
        key = self._key()
        kept = self._kept
        for s, k, e in kept:  # one read of the tuple: safe across threads
            if s is state and k == key:
                return e
        e = self._est.estimate(state)
        row = e.__dict__.get("_row")
        if row is not None:  # read-only before any field is made
            row.flags.writeable = False
            self._kept = ((state, key, e),) + kept[:_RECENT - 1]
        return e

    def normal_forces(self, state: MachineState) -> np.ndarray:
        """``estimate(state).normal_forces``, from what this tick already made if it can.

        A control tick linearizes the observed state (the margin) before it asks for its
        forces (the feedback): the derivative kernel's forces are the estimate kernel's
        bits (the same expressions; a test checks it), and so are the first row of
        `stepped_suspension_forces`. Else (another state, mass, D or beta, or a tipping
        state's least-squares linearization) the estimate.
        """
        key = self._key()
        for s, k, e in self._kept:
            if s is state and k == key:
                return e.normal_forces
        last = self._last
        if (last is not None and last[0] is state and last[1] == key
                and "_row" in last[2].__dict__):  # the kernel's row: a regular system
            return last[2].normal_forces
        kept = self._stepped
        if kept is not None and kept[0] is state and kept[1] == key:
            return kept[2]
        return self.estimate(state).normal_forces

    def contact_points(self, state: MachineState) -> np.ndarray:
        """`Estimate.contact_points` of ``state`` (4, 3) [m], a fresh array.

        The observer's, once per state: the estimate kernel's row without the `Estimate`
        (`_regular_row`), nothing kept.
        """
        row, checked = self._regular_row(state)
        if row is None:
            return self._est.estimate(checked).contact_points
        return row[LAYOUT.out_points].reshape(4, 3)

    def normal_forces_once(self, state: MachineState) -> np.ndarray:
        """``estimate(state).normal_forces`` (4,) [N] (read-only) of a state asked once.

        The observer's four-wheel state of its contact flags: the estimate kernel's row
        without the `Estimate` (`_regular_row`), nothing kept.
        """
        row, checked = self._regular_row(state)
        if row is None:
            return self._est.estimate(checked).normal_forces
        forces = row[LAYOUT.out_x]
        forces.flags.writeable = False
        return forces

    def _regular_row(self, state: MachineState) -> tuple[np.ndarray | None, MachineState]:
        """(a copy of the estimate kernel's output row at ``state``, the state evaluated).

        The row of `NormalForceEstimator.estimate`'s regular case (the same pack, the same
        call: its bits, ~2 us less than the `Estimate` and its cache); None where it takes
        another path (no kernels, tipping, singular or not finite): the caller then calls
        ``estimate`` on the state evaluated (range-checked and, under ``strokes="clip"``,
        clipped and counted once).
        """
        est = self._est
        checked, _ = est._checked(state)
        if est._kernels is None:
            return None, checked
        inp, out, call, raw, _ = est._call("nf_estimate")
        sel, _ = est._pack(inp, checked, est.D, est.beta, raw)
        if sel.tipping:
            return None, checked
        call()
        if not (math.isfinite(out[LAYOUT.out_sum]) and out[LAYOUT.out_cond] < SINGULAR_CONDITION):
            return None, checked
        return out.copy(), checked

    def stepped_suspension_forces(self, state: MachineState, step: float) -> np.ndarray | None:
        """`estimators.suspension_response.stepped_forces` at the current payload mass.

        The same packed input gives the forces at the mass plus `SPAN` too, kept for
        `payload_sensitivity` (the margin asks for both at the same state).
        """
        forces = stepped_forces(self._est, state, step, payload_step=SPAN)
        if forces is None:
            return None
        forces.flags.writeable = False  # its rows are kept and handed out
        self._stepped = (state, self._key(), forces[0], forces[3])
        return forces[:3]

    def constraint(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """`NormalForceEstimator.constraint` at the current payload mass."""
        return self._est.constraint(state)

    def linearize(self, state: MachineState) -> ForceLinearization:
        """`NormalForceEstimator.linearize` at the current payload mass.

        The last result is kept for the same state object (states are immutable) at the
        same mass, D and beta: a control tick linearizes the observed state twice, for its
        uncertainty margin and for the plan's first node.
        """
        key = self._key()
        last = self._last
        if last is not None and last[0] is state and last[1] == key:
            return last[2]
        result = self._est.linearize(state)
        self._last = (state, key, result)
        return result

    def margin_terms(self, state: MachineState, step: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """What the force margin reads of this estimator at ``state``, in one kernel call.

        (``G``, ``d_qd``, ``in_contact``) of `linearize` and `stepped_suspension_forces`
        ``(state, step)`` at the current payload mass, the same bits
        (`estimators.margin_kernel.margin_terms`; ``G`` and ``d_qd`` are views of a buffer
        valid until this thread's next call). The forces at the mass plus `SPAN` are kept
        for `payload_sensitivity` as `stepped_suspension_forces` keeps them; the
        linearization is not kept (nothing else in a tick asks for the closure's). None
        where it does not apply: then `linearize` and `stepped_suspension_forces`.
        """
        got = margin_terms(self._est, state, step, SPAN)
        return None if got is None else self._kept_terms(state, *got)

    def _kept_terms(self, state: MachineState, terms, flags: np.ndarray) -> tuple:
        """`margin_terms`' result from an evaluated `estimators.margin_kernel.MarginTerms`."""
        forces = terms.forces.copy()
        forces.flags.writeable = False  # its rows are kept and handed out
        self._stepped = (state, self._key(), forces[0], forces[3])
        return terms.G, terms.d_qd, flags, forces[:3]

    def linearize_with_margin(self, state: MachineState, closure: PayloadEstimator,
                              step: float) -> tuple[ForceLinearization, tuple | None] | None:
        """`linearize` of ``state`` and ``closure.margin_terms(state, step)`` in one call.

        The force margin's (`estimators.uncertainty.closure_margin`): it reads this model's
        ``G`` and the closure's terms, and the controller then linearizes this model at the
        same state (its plan's first node). One kernel makes both, the dynamics of the state
        once (`estimators.margin_kernel.linearize_with_margin`, the same bits); the
        linearization is kept as `linearize` keeps it, the closure's stepped forces as its
        `margin_terms` keeps them.

        Returns:
            (``linearize(state)``, ``closure.margin_terms(state, step)`` or None where that
            would be None); None where ``state``'s linearization is kept already or the two
            cannot share the call: then `linearize` and the closure's `margin_terms`.
        """
        key = self._key()
        last = self._last
        if last is not None and last[0] is state and last[1] == key:
            return None
        got = linearize_with_margin(self._est, closure._est, state, step, SPAN)
        if got is None:
            return None
        lin, terms = got
        self._last = (state, key, lin)
        return lin, None if terms is None else closure._kept_terms(state, *terms)

    def linearize_states(self, state: MachineState, dt: np.ndarray, rotation: np.ndarray,
                         q_head: np.ndarray, qd_head: np.ndarray
                         ) -> list[ForceLinearization] | None:
        """`linearize` of ``state`` moved on by ``dt`` (n,) to other poses and coordinates.

        One compiled call for the n states at the current payload mass
        (`estimators.linearize_batch.linearize_states`, which has the arguments): a
        controller's nominal trajectory. None where they must be linearized one by one.
        The states are new ones: no cache is read or written.
        """
        return linearize_states(self._est, state, dt, rotation, q_head, qd_head)

    def linearize_rows(self, state: MachineState, dt: np.ndarray, q_head: np.ndarray,
                       qd_head: np.ndarray) -> np.ndarray | None:
        """The kernel rows of `linearize_states` with the base at its constant twist.

        `estimators.linearize_batch.linearize_rows` at the current payload mass: the rows
        (n, der_size) of a kept buffer, valid until the next call; None where the states
        must be linearized one by one.
        """
        return linearize_rows(self._est, state, dt, q_head, qd_head)

    def prepare_margin(self, closure: PayloadEstimator, step: float) -> None:
        """Make what `linearize_with_margin`'s first call with ``closure`` makes, now.

        `estimators.margin_kernel.prepare_joint`: this thread's buffers and call of the
        joint kernel, the closure's likely selectors; nothing of a state is evaluated,
        counted or kept.
        """
        prepare_joint(self._est, closure._est, step, SPAN)

    def prepare_nodes(self, n: int, m: int) -> tuple | None:
        """Make what `linearize_nodes`' first call with n later states makes, now.

        `estimators.linearize_batch.prepare_rows`: this thread's buffers and C call for
        n states of m given coordinates, bound to the coordinate ranges, made before a
        controller's clock starts (`wbc.structure`); nothing of a state is evaluated,
        counted or kept (the payload mass, the kept linearization as they were).

        Returns:
            ``(views, width)``: the `RowViews` and width of the kernel rows
            `linearize_nodes` gives; None where it gives none.
        """
        return prepare_rows(self._est, n, m)

    def linearize_nodes(self, state: MachineState, dt: np.ndarray, q_head: np.ndarray,
                        qd_head: np.ndarray) -> tuple[ForceLinearization, np.ndarray | None]:
        """`linearize` of ``state`` and `linearize_rows` of the states after it.

        One compiled call for both where ``state``'s linearization is not kept already
        (`estimators.linearize_batch.linearize_first`: `linearize`'s bits, kept as
        `linearize` keeps it), else `linearize` and `linearize_rows`.

        Returns:
            (``linearize(state)``, the later rows or None, as `linearize_rows` gives them).

        Raises:
            As `linearize`.
        """
        key = self._key()
        last = self._last
        if last is not None and last[0] is state and last[1] == key:  # `linearize`'s kept
            return last[2], linearize_rows(self._est, state, dt, q_head, qd_head)
        done = linearize_first(self._est, state, dt, q_head, qd_head)
        if done is not None:
            self._last = (state, key, done[0])
            return done
        return self.linearize(state), linearize_rows(self._est, state, dt, q_head, qd_head)

    def normal_forces_batch(self, batch, payload, strict: bool = False) -> np.ndarray:
        """Normal forces [N] (N, 4) of a `StateBatch`, each row at its own payload [kg] (N,).

        One batch evaluation, each row's mass a kernel input. ``strict`` as in
        `NormalForceEstimator.estimate_batch`.
        """
        return self._est.estimate_batch(batch, strict=strict,
                                        payload_mass=payload).normal_forces

    def payload_sensitivity(self, state: MachineState) -> np.ndarray:
        """``df/dm`` of the normal forces [N/kg], shape (4,) (exact: affine in ``m``).

        The difference of the forces at the mass and at the mass plus `SPAN` (minus, near
        `MAX_PAYLOAD_MASS`).
        """
        kept = self._stepped
        if kept is not None and kept[0] is state and kept[1] == self._key():
            return (kept[3] - kept[2]) / SPAN
        mass = self.payload_mass
        dm = SPAN if mass + SPAN <= MAX_PAYLOAD_MASS else -SPAN
        f0 = self.normal_forces(state)
        try:
            self.payload_mass = mass + dm
            f1 = self.normal_forces(state)
        finally:
            self.payload_mass = mass
        return (np.asarray(f1) - np.asarray(f0)) / dm

    @property
    def n_clipped(self) -> int:
        """Evaluations whose coordinates were clipped into their ranges (``strokes="clip"``)."""
        return self._est.n_clipped

    @property
    def tree(self):
        """The estimator's tree model (geometry)."""
        return self._est.tree

    @property
    def machines(self) -> tuple[Machine]:
        """The machine whose kernels it uses (to warm them before a run)."""
        return (self._est.machine,)
