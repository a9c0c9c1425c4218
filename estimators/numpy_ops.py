"""`NumpyOps`: the numeric array backend of the recursion (the paper-faithful reference).

`estimators.tree` writes the recursion once against this tiny interface;
`estimators._symbolic.CasadiOps` is the symbolic twin that builds a CasADi graph of the same
code.
"""

from __future__ import annotations

import numpy as np

from estimators import spatial

__all__ = ["NumpyOps"]


class NumpyOps:
    """Numeric backend of the recursion: plain numpy, vectors of shape (n,)."""

    cos = staticmethod(np.cos)
    sin = staticmethod(np.sin)
    sqrt = staticmethod(np.sqrt)
    acos = staticmethod(np.arccos)
    fabs = staticmethod(np.abs)

    @staticmethod
    def const(x) -> np.ndarray:
        """A constant array."""
        return np.asarray(x, float)

    @staticmethod
    def vcat(parts) -> np.ndarray:
        """Stack scalars and vectors into one vector."""
        return np.concatenate([np.atleast_1d(np.asarray(p, float)) for p in parts])

    @staticmethod
    def rows(rows) -> np.ndarray:
        """Matrix from a list of rows (each a list of scalars)."""
        return np.array([[float(v) for v in r] for r in rows])

    @staticmethod
    def hcat(cols) -> np.ndarray:
        """Matrix from a list of column vectors."""
        return np.column_stack(cols)

    @staticmethod
    def vstack(mats) -> np.ndarray:
        """Stack matrices vertically."""
        return np.vstack(mats)

    @staticmethod
    def dot(a, b):
        """Inner product of two vectors."""
        return float(np.dot(a, b))

    @staticmethod
    def cross(a, b) -> np.ndarray:
        """Cross product of two 3-vectors."""
        return np.cross(a, b)

    @staticmethod
    def inv(m) -> np.ndarray:
        """Matrix inverse (pseudo-inverse when exactly singular, e.g. while tipping)."""
        try:
            return np.linalg.inv(m)
        except np.linalg.LinAlgError:
            return np.linalg.pinv(m)

    @staticmethod
    def norm_1(m) -> float:
        """Induced 1-norm (max column sum)."""
        return float(np.abs(m).sum(axis=0).max())

    @staticmethod
    def norm_2(v) -> float:
        """Euclidean norm of a vector."""
        return float(np.linalg.norm(v))

    @staticmethod
    def det3(m) -> float:
        """Determinant of a 3x3 matrix."""
        return float(np.linalg.det(m))

    @staticmethod
    def entry(v, i):
        """Scalar entry ``i`` of a vector."""
        return float(v[i])

    @staticmethod
    def col(m, j):
        """Column ``j`` of a matrix as a vector."""
        return m[:, j]

    adjoint_rp = staticmethod(lambda r, p: spatial.adjoint(spatial.se3(r, p)))
    coadjoint_rp = staticmethod(lambda r, p: spatial.coadjoint(spatial.se3(r, p)))
    ad = staticmethod(spatial.ad)
    ad_star = staticmethod(spatial.ad_star)
    skew = staticmethod(spatial.skew)
