"""What an MPC's QP owes to its structure alone, made when the controller is built.

The MPC's tasks and constraints keep what depends on the layout, the step lengths, the
period and their own settings, not on the state: the tasks' constant Hessians, the force
constraint's node structure and compiled buffers, the limits' constant rows. They make it
at the first tick that asks, which then costs several ticks. `prepare_planner` makes it
before the clock starts, each task and constraint through its ``prepare`` hook on a
`StructureContext`, keyed as a tick's context keys it (`HorizonContext.structure_key`), and
the solver's of the rows they fix (`PreparedRows`, ``solver.prepare``): the
first tick finds it, and a tick of another structure rebuilds it as before. What a tick
computes is the same: the same operations on the same operands, only earlier; nothing that
depends on the state (counters, ``last_*`` attributes, the solver's workspace) is touched.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from wbc.axes import AxisLimits
from wbc.layout import VariableLayout

__all__ = ["PreparedRows", "StructureContext", "prepare_planner", "prepared_rows"]


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
    counts = planner.builder.prepare(ctx)
    prepare = getattr(planner.solver, "prepare", None)  # `wbc.solvers.DaqpBackend.prepare`
    if prepare is not None and counts and None not in counts:
        rows = prepared_rows(planner.builder.constraints, counts, ctx)
        prepare(rows.m, ctx.layout.n, rows.constant_rows, rows.diagonal_rows, rows.lb,
                rows.ub)


class PreparedRows(NamedTuple):
    """The rows of the first QP of a structure, as far as its constraints fix them.

    For the solver's own preparation (`prepare_planner`): the number of rows of ``G`` (every
    wheel in contact), the `wbc.qp.QP.constant_rows` and `wbc.qp.QP.diagonal_rows` a tick
    of the structure gives, and the layout's default bounds narrowed by the boxes the
    constraints fix (``lb``, ``ub``, (n,): a tick's other boxes narrow them further).
    """

    m: int
    constant_rows: tuple
    diagonal_rows: tuple
    lb: np.ndarray
    ub: np.ndarray


def prepared_rows(constraints, counts: list, ctx: StructureContext) -> PreparedRows:
    """The `PreparedRows` of ``constraints`` prepared for ``ctx`` (their row ``counts``).

    As `wbc.qp.QPBuilder.build` places them: a read-only ``G`` a constraint fixes
    (`wbc.constraints.Constraint.prepared_form`) is a constant block at its first row, else
    its `wbc.constraints.DiagonalBlocks`, if it fixes them; the defaults narrowed by the
    fixed boxes in order, as the builder narrows them.
    """
    constant, diagonal = [], []
    lb, ub = (np.array(b, dtype=float) for b in ctx.layout.default_bounds())
    first = 0
    for con, m in zip(constraints, counts):
        say = getattr(con, "prepared_form", None)  # a duck-typed constraint: nothing
        form = None if say is None else say(ctx)
        if form is not None and form.box is not None:
            np.maximum(lb, form.box.lower, out=lb)
            np.minimum(ub, form.box.upper, out=ub)
        if form is not None and m:
            if form.G is not None and not form.G.flags.writeable:
                constant.append((first, form.G))
            elif form.diagonal is not None:
                diagonal.append((first, form.diagonal))
        first += m
    return PreparedRows(first, tuple(constant), tuple(diagonal), lb, ub)
