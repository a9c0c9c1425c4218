"""The MPC of one control tick: build the condensed QP, solve it warm-started, keep the plan."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import qpsolvers

from models.records import trusted
from models.state import MachineState
from wbc.axes import N_AXES, AxisLimits
from wbc.constraints.constraint import Constraint
from wbc.context import ReferenceSample
from wbc.errors import ConfigurationError, QPSolveError
from wbc.layout import VariableLayout
from wbc.mpc.context import HorizonContext
from wbc.mpc.prediction import CondensedPrediction
from wbc.qp import QPBuilder
from wbc.solvers import DaqpBackend, ProxQPWorkspace, QPSolution, QpsolversBackend
from wbc.structure import prepare_planner
from wbc.tasks.task import Task

__all__ = ["MpcPlan", "MpcPlanner"]


@dataclass(frozen=True)
class MpcPlan:
    """A solved MPC problem.

    Attributes:
        inputs: Accelerations of the steps, (N, 9); ``inputs[0]`` is applied now.
        speed_scale: Wheel-speed scale (1.0 without the variable).
        slack: Force slacks (n_slack,) [scaled]: per wheel now, per wheel later, and with
            the side reserve the left and the right pair's; zeros (4,) without them.
        solution: The solver's result.
        start: What `positions` and `velocities` are predicted from: ``(prediction, q, qd,
            (free positions, free velocities), inputs)`` of the context and the plan (the
            inputs a copy of their own).
    """

    inputs: np.ndarray
    speed_scale: float
    slack: np.ndarray
    solution: QPSolution
    start: tuple

    @classmethod
    def of(cls, inputs: np.ndarray, speed_scale: float, slack: np.ndarray,
           solution: QPSolution, start: tuple) -> MpcPlan:
        """``MpcPlan(...)`` without the frozen dataclass's per-field setattr.

        The fields set as its ``__init__`` sets them (it has no ``__post_init__``): one a
        tick.
        """
        return trusted(cls, inputs=inputs, speed_scale=speed_scale, slack=slack,
                       solution=solution, start=start)

    @property
    def positions(self) -> np.ndarray:
        """Predicted node positions, (N, 9), nodes 1..N."""
        return self._nodes()[0]

    @property
    def velocities(self) -> np.ndarray:
        """Predicted node velocities, (N, 9), nodes 1..N."""
        return self._nodes()[1]

    def _nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """`CondensedPrediction.trajectory` of `start`, made on the first access and kept.

        The control loop applies ``inputs[0]`` and never reads the nodes: they are not made
        every tick.
        """
        nodes = self.__dict__.get("_nodes_kept")
        if nodes is None:
            prediction, q, qd, free, inputs = self.start
            nodes = self.__dict__["_nodes_kept"] = prediction.trajectory(q, qd, inputs, free)
        return nodes


class MpcPlanner:
    """Receding-horizon QP over a condensed double-integrator prediction.

    Args:
        limits: Axis limits.
        layout: Decision layout (``n_axes = 9``, ``n_steps = N``).
        steps: Step lengths [s], scalar or (N,); their sum is the horizon.
        dt: Control period [s].
        tasks: Cost terms (horizon tasks, `SpeedScaleTask`, `SlackPenaltyTask`).
        constraints: Constraints (horizon limits, `AccelerationLimit`, force constraint).
        solver: `DaqpBackend`, `ProxQPWorkspace` (both warm-started) or `QpsolversBackend`.
        regularization: Tikhonov term of the Hessian.
    """

    def __init__(self, limits: AxisLimits, layout: VariableLayout, steps, dt: float,
                 tasks: Sequence[Task], constraints: Sequence[Constraint],
                 solver: DaqpBackend | ProxQPWorkspace | QpsolversBackend,
                 regularization: float = 1e-9):
        if layout.n_axes != N_AXES:
            raise ConfigurationError(f"MPC layout must have {N_AXES} axes, got {layout.n_axes}")
        if not (np.all(np.asarray(steps, float) > 0) and dt > 0):
            raise ConfigurationError(f"steps and dt must be > 0, got {steps}, {dt}")
        self.limits = limits
        self.layout = layout
        self.prediction = CondensedPrediction(layout, steps)
        self.dt = float(dt)
        self.tasks = list(tasks)
        self.constraints = list(constraints)
        self.solver = solver
        self.regularization = float(regularization)
        self.builder = QPBuilder(self.tasks, self.constraints, self.regularization)
        self._plan: np.ndarray | None = None  # (N, 9) inputs of the last plan
        self._plan_time = 0.0
        self._shift: tuple | None = None  # (elapsed time, the plan's step for each step)
        self._kept_times: tuple | None = None  # (prediction, `_times`)
        prepare_planner(self)  # the structure's caches now, not in the first tick

    @property
    def horizon(self) -> float:
        """Sum of the step lengths [s] (kept with `node_times`: asked every tick)."""
        return self._times()[2]

    @property
    def node_times(self) -> np.ndarray:
        """Times of the reference samples relative to now: 0, t_1, ..., t_N [s].

        Read-only, made once per prediction (asked every tick).
        """
        return self._times()[0]

    @property
    def node_starts(self) -> np.ndarray:
        """The step start times and the horizon: t_0, ..., t_{N-1}, t_N [s], read-only."""
        return self._times()[1]

    def _times(self) -> tuple:
        """(`node_times`, `node_starts`, `horizon`), kept while the prediction is the same."""
        pred = self.prediction
        kept = self._kept_times
        if kept is None or kept[0] is not pred:
            times = (np.concatenate([[0.0], pred.times]),
                     np.append(pred.start_times, pred.horizon))
            for t in times:
                t.setflags(write=False)
            self._kept_times = kept = (pred, *times, pred.horizon)
        return kept[1:]

    def reset(self) -> None:
        """Forget the previous plan and the solver workspace."""
        self._plan = None
        self.solver.reset()

    def nominal_inputs(self, time: float) -> np.ndarray:
        """The previous plan shifted to ``time`` [s] (zeros without a plan), (N, 9).

        The plan is piecewise constant in time; step k of the new plan takes the input that
        the old plan had at its start time, the last input held past the old horizon.
        """
        N = self.layout.n_steps
        if self._plan is None:
            return np.zeros((N, N_AXES))
        elapsed = max(time - self._plan_time, 0.0)
        starts = self.prediction.start_times
        shift = self._shift  # the last tick's: the same elapsed time, tick after tick
        if shift is None or shift[0] != elapsed or shift[2] is not starts:
            idx = np.searchsorted(starts, starts + elapsed + 1e-9, side="right") - 1
            self._shift = (elapsed, np.clip(idx, 0, N - 1), starts)
        return self._plan.take(self._shift[1], 0)  # `_plan[idx]`: the rows, a quarter the cost

    def context(self, state: MachineState, reference: ReferenceSample,
                previous_acceleration: np.ndarray, speed_scale: float, *,
                q: np.ndarray | None = None, qd: np.ndarray | None = None,
                start: tuple | None = None, **extra) -> HorizonContext:
        """The horizon context at ``state`` (reference sampled at `node_times`).

        Args:
            state: The measured state.
            reference: The reference at the node times.
            previous_acceleration: Acceleration commanded at the previous tick, (9,).
            speed_scale: Wheel-speed scale commanded at the previous tick.
            q: Initial axis positions of the prediction, (9,), copied; the measured ones if
                None.
            qd: Initial axis velocities, (9,), copied; the measured ones if None.
            start: Instead of ``q`` and ``qd``: ``(q, qd, qf, vf, ub, qb, vb)``, the start,
                ``prediction.free_response(q, qd)`` and ``prediction.brake_trajectory(q, qd,
                limits.acceleration, (qf, vf))``, as `ServoState.observe_brake` gives them
                (the MPC's servo state, `wbc.controllers.servo_state`): new arrays of the
                caller's, taken as they are.
            extra: Further `HorizonContext` fields (feedback, warp, leveling_offset).
        """
        if start is not None:
            q, qd, qf, vf, ub, qb, vb = start
        else:
            q = state.q[:N_AXES].copy() if q is None else np.array(q, float)
            qd = state.qd[:N_AXES].copy() if qd is None else np.array(qd, float)
            qf, vf = self.prediction.free_response(q, qd)
            ub, qb, vb = self.prediction.brake_trajectory(q, qd, self.limits.acceleration,
                                                          (qf, vf))
        return HorizonContext.assemble(state, q, qd, self.dt, self.layout, self.limits,
                                       self.prediction, reference,
                                       self.nominal_inputs(state.time),
                                       np.asarray(previous_acceleration, float),
                                       float(speed_scale), qf, vf, ub, qb, vb, **extra)

    def build(self, ctx: HorizonContext) -> qpsolvers.Problem:
        """The condensed QP of this tick."""
        return self.builder.build(ctx)

    def solve(self, ctx: HorizonContext, problem: qpsolvers.Problem) -> MpcPlan:
        """Solve and remember the plan (for the next tick's linearization).

        Raises:
            QPSolveError: The solver failed; the previous plan is dropped.
        """
        try:
            sol = self.solver.solve(problem)
        except QPSolveError:
            self._plan = None
            raise
        lay = self.layout
        u = sol.x[lay.accelerations].reshape(lay.n_steps, lay.n_axes)
        s = 1.0 if lay.scale is None else float(sol.x[lay.scale])
        slack = np.zeros(4) if lay.slack is None else sol.x[lay.slack].copy()
        self._plan, self._plan_time = u.copy(), ctx.state.time
        return MpcPlan.of(u, s, slack, sol, (self.prediction, ctx.q, ctx.qd,
                                             (ctx.free_positions, ctx.free_velocities),
                                             self._plan))
