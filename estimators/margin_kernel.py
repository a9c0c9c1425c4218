"""What the force margin reads of the closure at one state, in one kernel call of its own.

`estimators.uncertainty.closure_margin` reads, of the closure's `ForceLinearization`, only
``G``, ``d_qd`` and the contact flags, and it differences the closure's forces at the state
with its suspension cylinder forces and its payload mass stepped
(`estimators.suspension_response.stepped_forces`: four calls of the estimate kernel). The
derivative kernel (``nf_derivatives``, ~47,600 instructions) also makes ``d_q``, more than
half of it, and in a closed loop it runs cold (the simulator and the QP solver have been
through the caches since the last tick): with the stepped forces ~35 us of the margin's ~65.

``nf_margin`` makes just those numbers in one call (~18,000 instructions): the derivative
function's ``x``, ``G``, ``d_qd`` and condition, and the estimate function's forces,
condition and checksum at the packed input and at it with each suspension force plus
``step`` and with the payload's mass plus ``payload_step`` (the entries stepped as the
stepped forces' loop steps them, by one double addition). It is built from the very same
CasADi functions, evaluated on the input symbols, and its common subexpressions are merged
(`casadi.cse`: one node per identical operation on identical operands, which changes no
value), compiled without floating-point contraction like every kernel: the same operations,
hence the same bits (`tests/test_margin_kernel.py` compares them on closed-loop ticks).

The controller then linearizes its own force model at the same state (its plan's first
node), whose system differs from the closure's only in its fourth row (and payload mass):
``nf_linearize_margin`` (`joint_function`, `linearize_with_margin`) makes that model's
whole ``nf_derivatives`` row and the closure's ``nf_margin`` row in one call, the state's
dynamics once (`casadi.cse`): ~45,400 instructions for both, fewer than ``nf_derivatives``
alone, where the two kernels ran cold one after the other.

Only the regular case takes it (a compiled estimator of the full method, the steps it was
built for, four or three wheels, every row finite and non-singular); anything else is None,
and the caller linearizes and steps, which handle or raise as they do. (Not checked here:
the finiteness of ``d_q``, which the margin does not read.)
"""

from __future__ import annotations

import ctypes
import functools
import math

import casadi as ca
import numpy as np

from estimators._kernel_calls import Compiled
from estimators._row_views import LINEARIZATION_VIEWS
from estimators._symbolic import LAYOUT, checked_row, kernel_source
from estimators.batch import SINGULAR_CONDITION
from estimators.linearization import N_GENERALIZED, ForceLinearization
from models.coordinates import N_INDEPENDENT
from models.state import MachineState

__all__ = ["MARGIN_COND", "MARGIN_FORCES", "MARGIN_G", "MARGIN_QD", "MARGIN_STEP",
           "MARGIN_STEPPED_COND", "MARGIN_STEPPED_SUM", "MARGIN_SUM", "MarginTerms",
           "joint_function", "joint_kernel", "linearize_with_margin", "margin_function",
           "margin_kernel", "margin_terms", "prepare_joint"]

MARGIN_STEP = 100.0  # [N] the suspension forces' step of the force margin
_ALL_IN = np.ones(4, bool)  # `prepare_joint`'s contact flags

# Positions in ``nf_margin``'s output row: the derivative kernel's G, d_qd (row-major) and
# condition; the estimate kernel's forces (4 rows of 4: at the state, each suspension force
# stepped, the payload stepped), their conditions and their rows' checksums; the checksum.
MARGIN_G = slice(0, 4 * N_GENERALIZED)
MARGIN_QD = slice(MARGIN_G.stop, MARGIN_G.stop + 4 * N_INDEPENDENT)
MARGIN_COND = MARGIN_QD.stop
MARGIN_FORCES = slice(MARGIN_COND + 1, MARGIN_COND + 17)
MARGIN_STEPPED_COND = slice(MARGIN_FORCES.stop, MARGIN_FORCES.stop + 4)
MARGIN_STEPPED_SUM = slice(MARGIN_STEPPED_COND.stop, MARGIN_STEPPED_COND.stop + 4)
MARGIN_SUM = MARGIN_STEPPED_SUM.stop


def margin_function(derivatives: ca.Function, estimate: ca.Function, step: float,
                    payload_step: float) -> ca.Function:
    """``nf_margin`` (module docstring) of an estimator's two CasADi functions.

    Args:
        derivatives: The estimator's ``nf_derivatives`` (one packed input row).
        estimate: Its ``nf_estimate`` (the same input).
        step: The suspension forces' step [N].
        payload_step: The payload mass's step [kg].
    """
    lay = LAYOUT
    z = derivatives.sx_in(0)
    row = derivatives(z)
    at = lay.suspension_force.start
    inputs = [z]
    for k in range(3):
        zk = ca.SX(z)
        if k < 2:
            zk[at + k] = z[at + k] + step
        else:
            zk[lay.payload_mass] = z[lay.payload_mass] + payload_step
        inputs.append(zk)
    rows = [estimate(zk) for zk in inputs]
    body = ca.vertcat(row[lay.der_a], row[lay.der_qd], row[lay.der_cond],
                      *[r[lay.out_x] for r in rows], *[r[lay.out_cond] for r in rows],
                      *[r[lay.out_sum] for r in rows])
    return ca.Function("nf_margin", [z], [ca.cse(checked_row(body))])


@functools.cache
def margin_kernel(kernels, step: float, payload_step: float) -> Compiled | None:
    """The compiled ``nf_margin`` of an estimator's `estimators._symbolic.Kernels`.

    Compiled (or found in the disk cache) once per kernels object and steps, at ``-O1``
    like ``nf_derivatives``; None where those kernels are not compiled (no C compiler).
    """
    return _compiled(kernels, margin_function, step, payload_step, "-O1")


# The closure's own entries of ``nf_linearize_margin``'s input, after the model's packed row:
# its selector block (mask .. beta, as `RowPacker.selectors` packs it) and its payload mass.
_SELECTORS = slice(LAYOUT.mask.start, LAYOUT.beta + 1)
_N_SELECTORS = _SELECTORS.stop - _SELECTORS.start


def joint_function(derivatives: ca.Function, estimate: ca.Function, step: float,
                   payload_step: float) -> ca.Function:
    """``nf_linearize_margin``: the model's ``nf_derivatives`` row, then the closure's margin.

    The input is the model's packed row, then the closure's selector block and payload mass
    (the rest of a closure's row is the model's: the same state). The output is
    ``derivatives`` of the model's row, then `margin_function` of the closure's row. The two
    systems share the dynamics (the same state), which `casadi.cse` evaluates once: ~45,400
    instructions, fewer than ``nf_derivatives`` alone (47,600), for both.

    Args:
        derivatives: The estimator's ``nf_derivatives`` (one packed input row).
        estimate: Its ``nf_estimate`` (the same input).
        step: The suspension forces' step [N].
        payload_step: The payload mass's step [kg].
    """
    lay = LAYOUT
    n = lay.size
    zz = ca.SX.sym("z", n + _N_SELECTORS + 1)
    z = zz[:n]
    closure = ca.vertcat(z[:_SELECTORS.start], zz[n:n + _N_SELECTORS],
                         z[_SELECTORS.stop:lay.payload_mass], zz[n + _N_SELECTORS],
                         z[lay.payload_mass + 1:])
    margin = margin_function(derivatives, estimate, step, payload_step)
    return ca.Function("nf_linearize_margin", [zz],
                       [ca.cse(ca.vertcat(derivatives(z), margin(closure)))])


@functools.cache
def joint_kernel(kernels, step: float, payload_step: float) -> Compiled | None:
    """The compiled ``nf_linearize_margin`` of `estimators._symbolic.Kernels`.

    As `margin_kernel` compiles ``nf_margin`` (once per kernels object and steps), but at
    ``-O2``: its code (~450 kB) is ~6 % smaller than at ``-O1`` and runs from a cold cache
    in ~15 us instead of ~20 (a 4 MB array written between calls; warm, both ~8 us), where
    a closed loop runs it once a tick. The first compile takes ~25 s (then the disk cache);
    no contraction at either level, so the same bits.
    """
    return _compiled(kernels, joint_function, step, payload_step, "-O2")


def _compiled(kernels, make, step: float, payload_step: float, level: str
              ) -> Compiled | None:
    """``make``'s function of ``kernels``' derivatives and estimate, compiled at ``level``.

    None where those kernels are not compiled (no C compiler) or the compiler fails.
    """
    if not kernels.compiled:
        return None
    from models.cbuild import compile_shared

    fun = make(kernels.functions["nf_derivatives"], kernels.functions["nf_estimate"], step,
               payload_step)
    try:
        lib = compile_shared(kernel_source(fun), fun.name(), level)
    except OSError:
        return None
    return Compiled(ctypes.CDLL(str(lib)), fun)


class MarginTerms:
    """One thread's ``nf_margin`` of one estimator: its buffers and their views, bound once.

    Attributes:
        G: ``linearize(state).G`` (4, 19), a view of the output buffer.
        d_qd: ``linearize(state).d_qd`` (4, 13), likewise.
        forces: The stepped forces (4, 4) [N], likewise: at the state, with suspension force
            0, then 1, plus the step, with the payload plus its step.
        conditions: The four estimate rows' condition numbers, likewise.
    """

    def __init__(self, kernel: Compiled, at: int = 0):
        inp, out = kernel.buffers()
        self.inp, self.out = inp[:LAYOUT.size], out[at:]
        self.call = kernel.bound_call()
        self.raw = memoryview(self.inp).cast("B")
        self.G = self.out[MARGIN_G].reshape(4, N_GENERALIZED)
        self.d_qd = self.out[MARGIN_QD].reshape(4, N_INDEPENDENT)
        self.forces = self.out[MARGIN_FORCES].reshape(4, 4)
        self.conditions = self.out[MARGIN_STEPPED_COND]
        # `nf_linearize_margin`'s: the closure's entries of the input, the model's row.
        self.closure_selectors = inp[LAYOUT.size:LAYOUT.size + _N_SELECTORS]
        self.closure_payload = inp[LAYOUT.size + _N_SELECTORS:]
        self.model_row = out[:at]

    def regular(self) -> bool:
        """Whether the margin's rows are finite and their systems not singular."""
        out = self.out
        return (math.isfinite(out[MARGIN_SUM]) and out[MARGIN_COND] < SINGULAR_CONDITION
                and max(self.conditions.tolist()) < SINGULAR_CONDITION)


def _kept_terms(estimator, make_kernel, step: float, payload_step: float, *offset
                ) -> MarginTerms | None:
    """The `MarginTerms` of ``make_kernel``'s kernel kept in ``estimator``'s per-thread calls.

    Made at the first call for these steps (``offset``: where the margin's row starts in the
    kernel's output, `MarginTerms`); None where the kernel is not compiled.
    """
    calls = estimator._calls.__dict__
    key = (make_kernel.__name__, step, payload_step)
    terms = calls.get(key)
    if terms is None:
        kernel = make_kernel(estimator._kernels, step, payload_step)
        if kernel is None:
            return None
        terms = calls[key] = MarginTerms(kernel, *offset)
    return terms


def prepare_joint(model, closure, step: float, payload_step: float) -> None:
    """Make what `linearize_with_margin`'s first call with these makes of them alone, now.

    This thread's `MarginTerms` of ``model``'s joint kernel, and the closure's packer
    selectors of every wheel in contact, with and without suspension forces
    (`RowPacker.selectors`, the likely first states): before a closed loop's clock starts.
    Nothing of a state is evaluated, counted or kept; nothing where the two would not share
    the call (`linearize_with_margin`'s checks of the estimators).
    """
    if (model._kernels is None or closure._kernels is not model._kernels
            or model._qs is not None or closure._qs is not None):
        return
    if _kept_terms(model, joint_kernel, step, payload_step, LAYOUT.der_size) is not None:
        for suspension_force in (False, True):
            closure._packer.selectors(_ALL_IN, suspension_force, closure.D, closure.beta)


def margin_terms(estimator, state: MachineState, step: float, payload_step: float
                 ) -> tuple[MarginTerms, np.ndarray] | None:
    """(this thread's `MarginTerms` evaluated at ``state``, the contact flags (4,)).

    ``estimator``: a `NormalForceEstimator`. The terms are ``linearize(state)``'s ``G`` and
    ``d_qd`` and ``stepped_forces(estimator, state, step, payload_step)``, the same bits,
    valid until ``nf_margin`` runs again on this thread: callers copy what they keep. None
    where those would not take their kernels' regular paths (no compiled kernels, the
    quasi-static method, no suspension forces, a tipping, singular or non-finite system):
    the caller then linearizes and steps.
    """
    kernels = estimator._kernels
    if (kernels is None or estimator._qs is not None or estimator._packer.zeroed is not None
            or state.suspension_force is None):
        return None
    terms = _kept_terms(estimator, margin_kernel, step, payload_step)
    if terms is None:
        return None
    state, _ = estimator._checked(state)
    sel, flags = estimator._pack(terms.inp, state, estimator.D, estimator.beta, terms.raw)
    if sel.tipping:
        return None
    terms.call()
    return (terms, flags) if terms.regular() else None


def linearize_with_margin(model, closure, state: MachineState, step: float,
                          payload_step: float):
    """``model.linearize(state)`` and `margin_terms` of ``closure`` in one kernel call.

    ``model``, ``closure``: `NormalForceEstimator`s of the same kernels (they differ in the
    fourth equation, D, beta and the payload mass). Returns (the model's
    `ForceLinearization`, as `NormalForceEstimator.linearize` makes it: the same bits;
    (`MarginTerms`, the closure's contact flags), or None where `margin_terms` would be
    None), or None where the model's linearization would not take the derivative kernel's
    regular path or the two do not share their kernels: the caller then goes one by one.
    """
    kernels = model._kernels
    if (kernels is None or closure._kernels is not kernels or model._qs is not None
            or closure._qs is not None or model._packer.zeroed is not None
            or closure._packer.zeroed is not None or state.suspension_force is None
            or model.strokes != closure.strokes):
        return None
    terms = _kept_terms(model, joint_kernel, step, payload_step, LAYOUT.der_size)
    if terms is None:
        return None
    state, clipped = model._checked(state)
    sel, flags = model._pack(terms.inp, state, model.D, model.beta, terms.raw)
    if sel.tipping:
        return None
    packed, closure_sel, closure_flags = closure._packer.state_selectors(
        state, closure.D, closure.beta)
    terms.closure_selectors[:] = packed
    terms.closure_payload[0] = closure._packer.payload[0]
    terms.call()
    row = terms.model_row
    cond_at, sum_at = LAYOUT.der_cond, LAYOUT.der_sum
    if not (math.isfinite(row[sum_at]) and row[cond_at] < SINGULAR_CONDITION):
        return None
    lin = ForceLinearization.from_row(
        {"in_contact": flags, "mode": sel.mode, "clipped": clipped, "time": state.time},
        LINEARIZATION_VIEWS, np.frombuffer(row.tobytes()))
    if closure_sel.tipping or not terms.regular():
        return lin, None
    return lin, (terms, closure_flags)
