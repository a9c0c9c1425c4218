"""Result of a QP solve."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["QPSolution"]


@dataclass(frozen=True)
class QPSolution:
    """A solver's result.

    Attributes:
        x: Primal solution, shape (n,).
        status: The solver's status word.
        iterations: Iterations (-1 if the backend does not say).
        solve_time: Wall-clock time of update and solve [s].
        warm_started: Whether the solve started from the previous result.
    """

    x: np.ndarray
    status: str
    iterations: int
    solve_time: float
    warm_started: bool
