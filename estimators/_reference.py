"""The numpy ``reference`` backend's derivatives: from repeated estimates.

Without compiled kernels, `NormalForceEstimator.constraint` and `linearize` are built from
`NormalForceEstimator.estimate` itself: ``G`` column by column (exact, the forces being
affine in the accelerations) and ``df_z/dq``, ``df_z/dqd`` by central differences.
"""

from __future__ import annotations

import numpy as np

from models.state import MachineState

__all__ = ["central_differences", "constraint"]


def constraint(est, state: MachineState) -> tuple[np.ndarray, np.ndarray]:
    """``(G, g0)`` of ``f_z = G a + g0``: one estimate per acceleration (exact, affine)."""
    base = est.estimate(state).normal_forces
    acc = state.acceleration
    g = np.zeros((4, acc.size))
    for j in range(acc.size):
        a = acc.copy()
        a[j] += 1.0
        s = state.replace(base_acceleration=a[:6], qdd=a[6:])
        g[:, j] = est.estimate(s).normal_forces - base
    return g, base - g @ acc


def central_differences(est, state: MachineState, step: float
                        ) -> tuple[np.ndarray, np.ndarray]:
    """``(df_z/dq, df_z/dqd)``, each (4, 13): steps in q kept inside the ranges."""
    lower, upper = est.tree.coordinates.lower, est.tree.coordinates.upper
    columns = {}
    for name in ("q", "qd"):
        x = getattr(state, name)
        cols = []
        for j in range(x.size):
            lo, hi = -step, step
            if name == "q":
                lo, hi = max(lo, lower[j] - x[j]), min(hi, upper[j] - x[j])
            if hi - lo <= 0:
                cols.append(np.zeros(4))
                continue
            vals = []
            for h in (lo, hi):
                v = x.copy()
                v[j] += h
                vals.append(est.estimate(state.replace(**{name: v})).normal_forces)
            cols.append((vals[1] - vals[0]) / (hi - lo))
        columns[name] = np.column_stack(cols)
    return columns["q"], columns["qd"]
