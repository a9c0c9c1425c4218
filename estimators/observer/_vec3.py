"""3-vectors as Python floats: the observer's per-tick geometry.

A numpy call on three numbers costs ~1 us, a float operation ~30 ns. These helpers do the
arithmetic of the numpy expressions they replace in the same order, so the results are the
same bit for bit: ``np.linalg.norm`` of a 3-vector is ``sqrt(v . v)``, whose dot product sums
left to right without fused multiply-adds (checked against numpy). Matrix products stay
numpy's (`@`): BLAS fuses their multiply-adds, which plain floats would round differently.
"""

from __future__ import annotations

import math

__all__ = ["cross", "ground_normal", "norm", "sub"]


def norm(v) -> float:
    """``np.linalg.norm`` of a 3-vector."""
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def cross(a, b) -> tuple[float, float, float]:
    """``a x b`` (`models.rotations.cross3`)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def sub(a, b) -> tuple[float, float, float]:
    """``a - b``."""
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def ground_normal(centres, touching) -> list:
    """The unit normal (fb, z up) of the plane through the touching wheels' centres.

    ``centres`` (4, 3) in the order FL, RL, FR, RR; fb's z with fewer than three touching.
    """
    idx = [i for i, c in enumerate(touching) if c]
    if len(idx) == 4:  # the quad FL, FR, RR, RL: its diagonals' cross product
        n = cross(sub(centres[3], centres[0]), sub(centres[1], centres[2]))
    elif len(idx) == 3:
        a, b, c = (centres[i] for i in idx)
        n = cross(sub(b, a), sub(c, a))
    else:
        return [0.0, 0.0, 1.0]
    length = norm(n)
    if not length > 1e-9:
        return [0.0, 0.0, 1.0]
    return [v / length for v in n] if n[2] > 0 else [-v / length for v in n]
