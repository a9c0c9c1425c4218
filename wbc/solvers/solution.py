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
        solve_time: Wall-clock time of update and solve [s] (the backend's own work on the
            problem included: `DaqpBackend`'s row screening and least-distance form).
        warm_started: Whether the solve started from the previous result.
        call_time: Of that, the time inside the solver library's call(s) [s]; None when the
            backend does not measure it.
    """

    x: np.ndarray
    status: str
    iterations: int
    solve_time: float
    warm_started: bool
    call_time: float | None = None
