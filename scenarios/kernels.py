"""Warm the estimator's kernels before a run's clock starts.

The MPC's force models call the estimator's compiled kernels (`estimators._symbolic`); each
is generated and compiled on its first use (7-10 s the first time on a machine, then loaded
from the disk cache). Warming them before the run keeps that time out of the run's timing
metrics (``control_step_ms``, ``real_time_factor``); the numbers the kernels compute are
the same either way.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable

from estimators import NormalForceEstimator
from estimators.uncertainty_c import compiled_margin
from models.description import Machine

__all__ = ["COMPILE_NOTICE", "warm_estimator_kernels"]

COMPILE_NOTICE = "compiling estimator kernels for this machine (first use, ~10 s)..."


def warm_estimator_kernels(machines: Iterable[Machine],
                           notice: Callable[[str], None] | None = None,
                           notice_after: float = 0.5) -> float:
    """Build every estimator kernel of ``machines`` now (compiled C, or CasADi's VM).

    And the margin's compiled pass (`estimators.uncertainty_c`), machine-independent.

    Args:
        machines: The machines whose kernels the run will use (e.g. before and after a
            payload change).
        notice: Called once with `COMPILE_NOTICE` when the warm-up takes longer than
            ``notice_after`` (a compile, not a disk-cache hit); None: silent.
        notice_after: [s].

    Returns:
        The warm-up's wall time [s].
    """
    t0 = time.perf_counter()
    timer = None
    if notice is not None:
        timer = threading.Timer(notice_after, notice, args=(COMPILE_NOTICE,))
        timer.daemon = True
        timer.start()
    try:
        for machine in machines:
            NormalForceEstimator(machine, strokes="clip").warm()
        compiled_margin()  # the closed loop's margin (`estimators.uncertainty_c`)
    finally:
        if timer is not None:
            timer.cancel()
    return time.perf_counter() - t0
