"""The normal forces at a state and at each suspension cylinder force stepped, in one pack.

`estimators.uncertainty.suspension_sensitivity` differences the forces at a state with those
at the state with each of its two suspension cylinder forces stepped (the forces are affine
in them). Through `NormalForceEstimator.estimate` that is three states made and packed per
payload anchor; here the state is packed once into the compiled estimate kernel's input row
and only the two cylinder-force entries change between its three calls: the same input rows,
hence the same forces to the bit, at a third of the cost.
"""

from __future__ import annotations

import math

import numpy as np

from estimators._symbolic import LAYOUT
from estimators.batch import SINGULAR_CONDITION
from models.state import MachineState

__all__ = ["stepped_forces"]


def stepped_forces(estimator, state: MachineState, step: float,
                   payload_step: float | None = None) -> np.ndarray | None:
    """Forces (3, 4) [N]: at ``state``, then with suspension force 0, then 1, plus ``step``.

    With ``payload_step`` [kg], a fourth row (4, 4): the forces at ``state`` with the
    payload's mass (a run-time input of the kernel) plus ``payload_step``.

    ``estimator``: a `NormalForceEstimator`. None where the estimate would not take the
    kernel's regular path (no compiled kernels, the quasi-static method's zeroed inputs, no
    suspension forces, a tipping, singular or non-finite system): the caller then goes
    through ``estimate``, which handles or raises those.
    """
    if (getattr(estimator, "_kernels", None) is None or estimator._packer.zeroed is not None
            or state.suspension_force is None):
        return None
    state, _ = estimator._checked(state)
    inp, out, call, raw, _ = estimator._call("nf_estimate")
    sel, _ = estimator._pack(inp, state, estimator.D, estimator.beta, raw)
    if sel.tipping:
        return None
    lay = LAYOUT
    at = lay.suspension_force.start
    base = inp[at:at + 2].tolist()
    forces = np.empty((3 if payload_step is None else 4, 4))
    for k in range(len(forces)):
        if k:
            inp[at:at + 2] = base
            if k < 3:
                inp[at + k - 1] = base[k - 1] + step
            else:
                inp[lay.payload_mass] += payload_step
        call()
        if not (math.isfinite(out[lay.out_sum]) and out[lay.out_cond] < SINGULAR_CONDITION):
            return None
        forces[k] = out[lay.out_x]
    return forces
