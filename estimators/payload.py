r"""The payload as a run-time input: two compiled estimators, interpolated exactly.

The normal forces, their map in the accelerations and their sensitivities are affine in the
payload mass ``m`` (the dynamics are linear in the inertial parameters, the payload's centre
of mass is fixed in its body, and every fourth row is linear in the wrench). Two estimators
of the same machine with payloads ``m_a`` and ``m_b``, compiled once before the control loop
starts, therefore give every other payload exactly:

.. math:: x(m) = x(m_a) + w\,(x(m_b) - x(m_a)), \qquad w = (m - m_a) / (m_b - m_a).

`PayloadEstimator` does that for `estimate`, `constraint` and `linearize`, with ``payload_mass``
settable at every tick (an observer's estimate) and ``payload_sensitivity`` (``df/dm``) for
the force margin. No kernel is compiled after construction, whatever the mass.

The two estimators are those of the machine with its payload at the fixed
`ANCHOR_MASSES` (`anchor_machines`), not at the machine's own payload: machines that differ
only in the payload's mass (every scenario of a sweep) share the same two compiled kernel
sets, so a new payload never compiles anything (before, each draw of a sweep with its own
payload built six kernels, 25.6 s, on a cold cache; now 0.5 s from the disk cache).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from estimators.errors import EstimatorError
from estimators.estimator import NormalForceEstimator
from estimators.linearization import ForceLinearization
from estimators.results import Estimate
from estimators.suspension_response import stepped_forces
from models.description import Machine
from models.reference_machine import MAX_PAYLOAD_MASS
from models.state import MachineState

__all__ = ["ANCHOR_MASSES", "SPAN", "PayloadEstimator", "anchor_machines"]

ANCHOR_MASSES = (150.0, 250.0)  # [kg] m_a (the reference machine's payload) and m_b
SPAN = ANCHOR_MASSES[1] - ANCHOR_MASSES[0]  # [kg] m_b - m_a
_INERTIA_DIGITS = 12  # significant digits of the payload's inertia per kg (`anchor_machines`)
_LINEAR_FIELDS = ("normal_forces", "G", "g0", "d_q", "d_qd")  # what a mix interpolates


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


_RECENT = 4  # states whose anchor estimates a `PayloadEstimator` keeps (`_anchor`)


class PayloadEstimator:
    """A `NormalForceEstimator` whose payload mass is set at run time (module docstring).

    Args:
        machine: The machine description (its payload's shape; its mass is the first
            ``payload_mass``).
        **options: `NormalForceEstimator` options (method, fourth, D, beta, strokes, ...).

    Attributes:
        payload_mass: The payload now [kg]; settable, finite, in [0, `MAX_PAYLOAD_MASS`].
        method, fourth: As the wrapped estimators'.
    """

    def __init__(self, machine: Machine, **options):
        body = next(b for b in machine.bodies if b.name == machine.payload)
        self.machine = machine
        self._m_a = ANCHOR_MASSES[0]
        machine_a, machine_b = anchor_machines(machine)
        self._a = NormalForceEstimator(machine_a, **options)
        self._b = NormalForceEstimator(machine_b, **options)
        self._kept: dict = {self._a: (), self._b: ()}  # `_anchor`
        for est in (self._a, self._b):  # loaded now, not in a controller's first tick
            est.warm()
        self.method, self.fourth = self._a.method, self._a.fourth
        self._last: tuple | None = None  # (key, linearization) of the last `linearize`
        # `stepped_suspension_forces`' (state, the anchors' D and beta, f_a, f_b)
        self._stepped: tuple | None = None
        self.payload_mass = float(body.inertia.mass)  # the machine's payload to begin with

    @property
    def payload_mass(self) -> float:
        """The payload now [kg]."""
        return self._mass

    @payload_mass.setter
    def payload_mass(self, value) -> None:
        ok = isinstance(value, (int, float, np.floating)) and not isinstance(value, bool)
        m = float(value) if ok else float("nan")
        if not (np.isfinite(m) and 0.0 <= m <= MAX_PAYLOAD_MASS):
            raise EstimatorError(f"payload_mass must be a mass in [0, {MAX_PAYLOAD_MASS:g}] "
                                 f"kg, got {value!r}")
        self._mass = m
        self._w = (m - self._m_a) / SPAN

    def _mix(self, x_a, x_b):
        return x_a + self._w * (np.asarray(x_b) - np.asarray(x_a))

    def _anchor(self, est: NormalForceEstimator, state: MachineState) -> Estimate:
        """``est.estimate(state)`` of an anchor, its last `_RECENT` states' results kept.

        By identity (states are immutable) and for the anchor's D and beta then. A control
        tick asks about the same observed state several times (the margin's payload and
        suspension sensitivities, the MPC's feedback) between perturbed ones: about 4 of its
        15 estimates. A kept estimate (the common, regular four- or three-wheel case: its
        fields are views of one row) is made read-only, as it is shared; a tipping or
        singular one is not kept.
        """
        kept = self._kept[est]
        for s, d, beta, e in kept:  # one read of the tuple: safe across threads
            if s is state and d == est.D and beta == est.beta:
                return e
        e = est.estimate(state)
        row = e.__dict__.get("_row")
        if row is not None:  # read-only before any field is made
            row.flags.writeable = False
            self._kept[est] = ((state, est.D, est.beta, e),) + kept[:_RECENT - 1]
        return e

    def estimate(self, state: MachineState) -> Estimate:
        """`NormalForceEstimator.estimate` at the current payload mass."""
        ea = self._anchor(self._a, state)
        if self._w == 0.0:
            return ea
        eb = self._anchor(self._b, state)
        return dataclasses.replace(
            ea, normal_forces=self._mix(ea.normal_forces, eb.normal_forces),
            wrench_xi=self._mix(ea.wrench_xi, eb.wrench_xi),
            residual=self._mix(ea.residual, eb.residual),
            system_rhs=self._mix(ea.system_rhs, eb.system_rhs))

    def normal_forces(self, state: MachineState) -> np.ndarray:
        """``estimate(state).normal_forces``, without mixing the fields nobody reads.

        The observer's per-tick call: the same two estimates and the same mix of the
        forces (~30 us less than making the whole mixed `Estimate`).
        """
        ea = self._anchor(self._a, state)
        if self._w == 0.0:
            return ea.normal_forces
        return self._mix(ea.normal_forces, self._anchor(self._b, state).normal_forces)

    def stepped_suspension_forces(self, state: MachineState, step: float) -> np.ndarray | None:
        """`estimators.suspension_response.stepped_forces` at the current payload mass.

        Mixed as `normal_forces` mixes (the same bits); None where either anchor gives None.
        Both anchors' forces at the state are kept for `payload_sensitivity` (the margin asks
        for both at the same state).
        """
        fa = stepped_forces(self._a, state, step)
        fb = None if fa is None else stepped_forces(self._b, state, step)
        if fb is None:
            return None
        self._stepped = (state, self._d_betas(), fa[0], fb[0])
        return fa if self._w == 0.0 else self._mix(fa, fb)

    def _d_betas(self) -> tuple:
        return (self._a.D, self._a.beta, self._b.D, self._b.beta)

    def contact_points(self, state: MachineState) -> np.ndarray:
        """`Estimate.contact_points` of ``state`` (4, 3) [m].

        Geometry, whatever the payload: one estimate at the first mass gives them.
        """
        return self._anchor(self._a, state).contact_points

    def constraint(self, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
        """`NormalForceEstimator.constraint` at the current payload mass."""
        ga, ha = self._a.constraint(state)
        if self._w == 0.0:
            return ga, ha
        gb, hb = self._b.constraint(state)
        return self._mix(ga, gb), self._mix(ha, hb)

    def linearize(self, state: MachineState) -> ForceLinearization:
        """`NormalForceEstimator.linearize` at the current payload mass.

        The last result is kept for the same state object (states are immutable) at the
        same mass, D and beta: a control tick linearizes the observed state twice, for its
        uncertainty margin and for the plan's first node (~0.9 ms saved a tick while
        tipping, where the derivatives are differences).
        """
        key = (self._mass, self._a.D, self._a.beta)
        last = self._last
        if last is not None and last[0] is state and last[1] == key:
            return last[2]
        la = self._a.linearize(state)
        if self._w == 0.0:
            result = la
        else:
            lb = self._b.linearize(state)
            result = la.interpolated(lb, self._w)  # both from kernel rows: one mix
            if result is None:
                mixed = [self._mix(getattr(la, f), getattr(lb, f)) for f in _LINEAR_FIELDS]
                if all(math.isfinite(x.sum()) for x in mixed):  # a finite mix of checked rows
                    result = ForceLinearization.trusted(*mixed, la.in_contact, la.mode,
                                                        la.clipped, la.time)
                else:  # the checks of the constructor: they raise
                    result = dataclasses.replace(la, **dict(zip(_LINEAR_FIELDS, mixed)))
        self._last = (state, key, result)
        return result

    def normal_forces_batch(self, batch, payload, strict: bool = False) -> np.ndarray:
        """Normal forces [N] (N, 4) of a `StateBatch`, each row at its own payload [kg] (N,).

        ``strict`` as in `NormalForceEstimator.estimate_batch`.
        """
        fa = self._a.estimate_batch(batch, strict=strict).normal_forces
        fb = self._b.estimate_batch(batch, strict=strict).normal_forces
        w = (np.asarray(payload, float) - self._m_a) / SPAN
        return fa + w[:, None] * (fb - fa)

    def payload_sensitivity(self, state: MachineState) -> np.ndarray:
        """``df/dm`` of the normal forces [N/kg], shape (4,) (exact: affine in ``m``)."""
        kept = self._stepped
        if kept is not None and kept[0] is state and kept[1] == self._d_betas():
            _, _, fa, fb = kept  # the rows of the anchors' estimates at this state
        else:
            fa = self._anchor(self._a, state).normal_forces
            fb = self._anchor(self._b, state).normal_forces
        return (np.asarray(fb) - np.asarray(fa)) / SPAN

    @property
    def n_clipped(self) -> int:
        """Evaluations whose coordinates were clipped into their ranges (``strokes="clip"``)."""
        return self._a.n_clipped

    @property
    def tree(self):
        """The estimators' tree model (geometry)."""
        return self._a.tree

    @property
    def machines(self) -> tuple[Machine, Machine]:
        """The two machines whose kernels it uses (to warm them before a run)."""
        return self._a.machine, self._b.machine
