"""Which slices of the compiled kernels' output rows are which result fields.

`NormalForceEstimator`'s per-call path keeps one output row per result and makes each field
from it on first access (`estimators.results.RowFields`); these tables say how.
"""

from __future__ import annotations

import numpy as np

from estimators._symbolic import LAYOUT
from estimators.results import RowViews

__all__ = ["ESTIMATE_VIEWS", "LINEARIZATION_VIEWS", "OUT_VIEWS", "ROW_CHECKS"]

_L = LAYOUT
# The `Estimate` fields of an ``nf_estimate`` output row; ``_rotation`` gives the flat-ground
# normals of a state without measured contacts (world z in fb for every wheel).
ESTIMATE_VIEWS = {
    "normal_forces": lambda d: d["_row"][_L.out_x],
    "wrench_xi": lambda d: d["_row"][_L.out_xi],
    "condition": lambda d: float(d["_row"][_L.out_cond]),
    "residual": lambda d: d["_row"][_L.out_residual],
    "contact_points": lambda d: d["_row"][_L.out_points].reshape(4, 3),
    "system_matrix": lambda d: d["_row"][_L.out_a].reshape(3, 4),
    "system_rhs": lambda d: d["_row"][_L.out_b],
    "normals": lambda d: np.repeat(d["_rotation"][2:3], 4, axis=0),
}
# The `ForceLinearization` arrays of an ``nf_derivatives`` output row.
# Their places in the row, for `RowFields.stacked` (one stack of rows, not one per field).
LINEARIZATION_VIEWS = RowViews({
    "normal_forces": lambda d: d["_row"][_L.der_x],
    "G": lambda d: d["_row"][_L.der_a].reshape(4, 19),
    "g0": lambda d: d["_row"][_L.der_g0],
    "d_q": lambda d: d["_row"][_L.der_q].reshape(4, 13),
    "d_qd": lambda d: d["_row"][_L.der_qd].reshape(4, 13),
}, slices={"normal_forces": (_L.der_x, (4,)), "G": (_L.der_a, (4, 19)),
           "g0": (_L.der_g0, (4,)), "d_q": (_L.der_q, (4, 13)), "d_qd": (_L.der_qd, (4, 13))})
# Views of a kernel's output buffer that `constraint` copies out: (G, g0).
OUT_VIEWS = {"nf_constraint": lambda out: (out[_L.con_g].reshape(4, 19), out[_L.con_g0])}
# (condition, checksum) positions in each kernel's output row.
ROW_CHECKS = {"nf_estimate": (_L.out_cond, _L.out_sum),
              "nf_constraint": (_L.con_cond, _L.con_sum),
              "nf_derivatives": (_L.der_cond, _L.der_sum)}
