"""What an MPC's QP owes to its structure alone, made when the controller is built.

The MPC's tasks and constraints keep what depends on the layout, the step lengths, the
period and their own settings, not on the state: the tasks' constant Hessians, the force
constraint's node structure and compiled buffers, the limits' constant rows. They make it
at the first tick that asks, which then costs several ticks. `prepare_planner` makes it
before the clock starts, each task and constraint through its ``prepare`` hook on a
`StructureContext`, keyed as a tick's context keys it (`HorizonContext.structure_key`), and
the solver's of the rows they fix (`wbc.qp.PreparedRows`, ``solver.prepare``): the
first tick finds it, and a tick of another structure rebuilds it as before. What a tick
computes is the same: the same operations on the same operands, only earlier; nothing that
depends on the state (counters, ``last_*`` attributes, the solver's workspace) is touched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wbc.axes import AxisLimits
from wbc.layout import VariableLayout

__all__ = ["StructureContext", "prepare_planner"]


@dataclass(frozen=True)
class StructureContext:
    """The fields of a `wbc.mpc.context.HorizonContext` that do not depend on the state.

    Attributes:
        layout: The planner's decision layout (the very object its ticks' contexts hold).
        prediction: Its `wbc.mpc.prediction.CondensedPrediction`.
        dt: The control period [s].
        limits: Its axis limits.
        warp: The warp matrix the ticks' contexts will hold (`HorizonContext.warp`, the
            controller's, read-only), for `wbc.tasks.HorizonLevelingTask`; None: not
            known (that task is then not prepared).
    """

    layout: VariableLayout
    prediction: object
    dt: float
    limits: AxisLimits
    warp: np.ndarray | None = None

    @property
    def structure_key(self) -> tuple:
        """The key of `HorizonContext.structure_key`: layout, step lengths and period."""
        return (self.prediction.structure_key, self.dt)

    @property
    def n_steps(self) -> int:
        """Number of steps N."""
        return self.layout.n_steps


def prepare_planner(planner, warp: np.ndarray | None = None) -> None:
    """Make a `wbc.mpc.MpcPlanner`'s structure-only caches now (the module docstring).

    Called when the planner is built; again after its tasks, constraints or prediction
    change (or not: the first tick of a new structure then makes them), or with the warp
    matrix its controller will put in the contexts (`StructureContext.warp`).
    """
    ctx = StructureContext(planner.layout, planner.prediction, float(planner.dt),
                           planner.limits, warp)
    planner.builder.prepare(ctx)
    rows = planner.builder.prepared_rows
    prepare = getattr(planner.solver, "prepare", None)  # `wbc.solvers.DaqpBackend.prepare`
    if rows is not None and prepare is not None:
        prepare(rows.m, ctx.layout.n, rows.constant_rows, rows.diagonal_rows, rows.lb,
                rows.ub)
