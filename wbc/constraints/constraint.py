"""Abstract constraint: linear inequalities or bounds on the decision vector."""

from __future__ import annotations

import abc
import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["Box", "Constraint", "DiagonalBlocks", "Inequality", "PreparedForm", "unbounded"]


@dataclass(frozen=True)
class DiagonalBlocks:
    """Where the rows of a ``G`` can be nonzero: blocks along a diagonal of columns.

    The ``n_blocks * rows`` rows come in ``n_blocks`` consecutive blocks of ``rows`` rows;
    block k is zero outside the ``width`` columns from ``first + k * width`` on (the MPC's
    per-step rows: step k's inputs only). A solver may then multiply each block's columns
    alone (`wbc.solvers.DaqpBackend`).
    """

    rows: int
    first: int
    width: int
    n_blocks: int


@dataclass(frozen=True, init=False)
class Inequality:
    """``G x <= h``: G shape (m, n), h shape (m,).

    ``diagonal``: the rows' `DiagonalBlocks`, if the constraint knows its ``G`` is zero
    outside them (None: any entry may be nonzero).
    """

    G: np.ndarray
    h: np.ndarray
    diagonal: DiagonalBlocks | None = None

    def __init__(self, G: np.ndarray, h: np.ndarray, diagonal: DiagonalBlocks | None = None):
        # The fields written into the instance's dict: the frozen dataclass's own __init__
        # sets each through object.__setattr__, twice the time, and every constraint makes
        # one of these every tick. Still frozen for anyone else.
        fields = self.__dict__
        fields["G"] = G
        fields["h"] = h
        fields["diagonal"] = diagonal


@dataclass(frozen=True)
class Box:
    """``lower <= x <= upper``, shapes (n,); +-inf where a variable is not bounded."""

    lower: np.ndarray
    upper: np.ndarray


@dataclass(frozen=True)
class PreparedForm:
    """What every tick of a structure gives of a constraint, as far as the structure fixes it.

    `Constraint.prepared_form`: a solver may make what it derives from these before the
    first tick (`wbc.structure.prepare_planner`).

    Attributes:
        box: The `Box` `Constraint.compute` returns (None: no box, or not fixed).
        G: The read-only ``G`` of the `Inequality` it returns (None: not fixed).
        diagonal: That `Inequality`'s `DiagonalBlocks` (None: none, or not fixed).
    """

    box: Box | None = None
    G: np.ndarray | None = None
    diagonal: DiagonalBlocks | None = None


class Constraint(abc.ABC):
    """A constraint says ``G x <= h`` or a box for the current context, or is inactive."""

    @abc.abstractmethod
    def compute(self, ctx) -> Inequality | Box | None:
        """The constraint at this context; None when inactive."""

    def prepare(self, ctx) -> int | None:
        """Make what depends on the structure alone before the first tick (`wbc.structure`).

        ``ctx`` is a `wbc.structure.StructureContext` (layout, prediction, period, limits):
        what `compute` would make for that structure at its first tick, the same arrays,
        and nothing that depends on the state. Nothing by default.

        Returns:
            The number of rows of ``G`` that `compute` gives at a tick of this structure
            (0: a box, or inactive; for a state-dependent count its likely one, e.g. every
            wheel in contact), None: not known (the default).
        """
        return None

    def prepared_form(self, ctx) -> PreparedForm | None:
        """After `prepare` with ``ctx``: what `compute` gives at every tick of its structure.

        The same objects the ticks get (the read-only ``G``, the `Box`), or an equal
        `DiagonalBlocks`. None: nothing fixed (the default).
        """
        return None


@functools.lru_cache(maxsize=8)
def _unbounded(n: int) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = np.full(n, -np.inf), np.full(n, np.inf)
    lower.setflags(write=False)
    upper.setflags(write=False)
    return lower, upper


def unbounded(n: int) -> tuple[np.ndarray, np.ndarray]:
    """New arrays ``(-inf, +inf)`` of shape (n,): a box's start before it bounds anything.

    Copies of kept read-only templates (a per-tick path: `np.full` costs four copies).
    """
    lower, upper = _unbounded(n)
    return lower.copy(), upper.copy()
