"""Whole-body QP at the control rate: accelerations of the nine axes, one step ahead."""

from __future__ import annotations

import numpy as np
import qpsolvers

from models.description import Machine
from models.state import MachineState
from wbc.axes import CRANE_AXES
from wbc.constraints import (
    AccelerationLimit,
    NormalForceConstraint,
    PositionLimit,
    SpeedScaleLimit,
    VelocityLimit,
)
from wbc.context import QPContext
from wbc.controllers.config import ControllerConfig
from wbc.controllers.controller import Controller
from wbc.force_models.protocol import NormalForceModel
from wbc.kinematics.tcp_kinematics import TcpKinematics
from wbc.layout import VariableLayout
from wbc.qp import QPBuilder
from wbc.solvers import make_solver
from wbc.tasks import (
    DampingTask,
    JointTask,
    SlackPenaltyTask,
    SpeedScaleTask,
    SuspensionPostureTask,
)

__all__ = ["WholeBodyQPController"]


class WholeBodyQPController(Controller):
    r"""Whole-body QP over the nine axis accelerations, at the control rate.

    With a force model, the wheel-speed scale and per-wheel slacks are decision variables too.
    Costs: crane `JointTask` (PD on the Ruckig reference), `SuspensionPostureTask`,
    `DampingTask`; with a force model also `SpeedScaleTask` and `SlackPenaltyTask`.
    Constraints: `AccelerationLimit`, `VelocityLimit`, `PositionLimit`; with a force model
    also `NormalForceConstraint` and `SpeedScaleLimit`.

    Registered as ``tracking`` without a force model (the QP without the force constraint).

    Args:
        machine: The machine description.
        config: Settings.
        force_model: Normal-force model; None: no force constraint.
        tcp_kinematics: For `TcpGoal`.
    """

    name = "tracking"

    def __init__(self, machine: Machine, config: ControllerConfig | None = None, *,
                 force_model: NormalForceModel | None = None,
                 tcp_kinematics: TcpKinematics | None = None):
        super().__init__(machine, config, tcp_kinematics=tcp_kinematics)
        cfg, qc, fc = self.config, self.config.qp, self.config.force
        force = force_model is not None
        self.layout = VariableLayout(9, 1, speed_scale=force and fc.speed_scale,
                                     n_slack=4 if force and fc.soft else 0)
        self.tasks = [
            JointTask(CRANE_AXES, qc.crane_kp, qc.crane_kd, qc.crane_weight),
            SuspensionPostureTask(qc.suspension_kp, qc.suspension_kd, qc.suspension_weight),
            DampingTask(qc.damping_time, qc.damping_weight),
        ]
        self.constraints = [AccelerationLimit(), VelocityLimit(),
                            PositionLimit(qc.position_horizon, qc.braking_fraction)]
        self.force_constraint: NormalForceConstraint | None = None
        if force:
            self.force_constraint = NormalForceConstraint(
                force_model, self.force_thresholds, qc.force_lookahead,
                self.static_wheel_load, fc.drive_time_constant)
            self.constraints.append(self.force_constraint)
            self.constraints.append(SpeedScaleLimit(fc.speed_scale_min, fc.speed_scale_rate))
            self.tasks += [SpeedScaleTask(fc.speed_scale_weight),
                           SlackPenaltyTask(fc.slack_linear, fc.slack_quadratic)]
        self.solver = make_solver(cfg.solver, cfg.eps_abs, cfg.eps_rel, cfg.max_iter)
        self.builder = QPBuilder(self.tasks, self.constraints)

    def context(self, state: MachineState) -> QPContext:
        """The QP context of ``state`` (references at the current reference time)."""
        return QPContext.from_state(state, self.dt, self.layout, self.limits,
                                    self.reference_ahead(0.0),
                                    self._speed_scale)

    def _build(self, ctx: QPContext) -> qpsolvers.Problem:
        return self.builder.build(ctx)

    def _reset(self) -> None:
        self.solver.reset()

    def _reset_solver(self) -> None:
        self.solver.reset()

    def _solve(self, state: MachineState) -> tuple[np.ndarray, float, dict]:
        sol = self.solver.solve(self._build(self.context(state)))
        lay = self.layout
        qdd = sol.x[lay.step(0)].copy()
        scale = 1.0 if lay.scale is None else float(sol.x[lay.scale])
        info = {"status": sol.status, "iterations": sol.iterations,
                "solve_time": sol.solve_time, "warm_started": sol.warm_started,
                "solver_call_time": sol.call_time}
        fcon = self.force_constraint
        if fcon is not None and fcon.last_forces_map is not None:
            A, b = fcon.last_forces_map
            info["predicted_forces"] = A @ sol.x + b
            info["in_contact"] = fcon.last_in_contact.copy()
            if lay.slack is not None:
                info["slack"] = sol.x[lay.slack].copy()
        return qdd, scale, info
