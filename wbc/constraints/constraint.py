"""Abstract constraint: linear inequalities or bounds on the decision vector."""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

__all__ = ["Box", "Constraint", "Inequality"]


@dataclass(frozen=True)
class Inequality:
    """``G x <= h``: G shape (m, n), h shape (m,)."""

    G: np.ndarray
    h: np.ndarray


@dataclass(frozen=True)
class Box:
    """``lower <= x <= upper``, shapes (n,); +-inf where a variable is not bounded."""

    lower: np.ndarray
    upper: np.ndarray


class Constraint(abc.ABC):
    """A constraint says ``G x <= h`` or a box for the current context, or is inactive."""

    @abc.abstractmethod
    def compute(self, ctx) -> Inequality | Box | None:
        """The constraint at this context; None when inactive."""
