"""Stability-aware MPC: the normal-force constraint along a >= 1 s horizon."""

from __future__ import annotations

import numpy as np
import qpsolvers

from models.description import Machine
from models.state import MachineState
from wbc.axes import CRANE_AXES, SUSPENSION_AXES
from wbc.constraints import (
    AccelerationLimit,
    HorizonNormalForceConstraint,
    HorizonPositionLimit,
    HorizonVelocityLimit,
    SpeedScaleLimit,
)
from wbc.controllers.config import ControllerConfig
from wbc.controllers.controller import Controller
from wbc.errors import ConfigurationError
from wbc.force_models.protocol import NormalForceModel
from wbc.kinematics.tcp_kinematics import TcpKinematics
from wbc.layout import VariableLayout
from wbc.mpc.context import HorizonContext
from wbc.mpc.planner import MpcPlan, MpcPlanner
from wbc.solvers import make_solver
from wbc.tasks import (
    HorizonInputTask,
    HorizonSmoothnessTask,
    HorizonTrackingTask,
    SlackPenaltyTask,
    SpeedScaleTask,
)

__all__ = ["MpcController"]


class MpcController(Controller):
    r"""Receding-horizon QP with the wheel normal-force constraint at every step.

    Prediction: the nine axes as double integrators (condensed), the base at its measured
    constant twist, the wheels at constant speed (`wbc.mpc.prediction`). Costs: tracking of
    the crane reference and of the suspension posture at every node, inputs towards the
    reference acceleration, input steps, wheel-speed scale, slacks. Constraints: position,
    velocity and acceleration limits at every node, `HorizonNormalForceConstraint`
    (linearized along the previous plan shifted, real-time iteration) and
    `SpeedScaleLimit`. One QP per tick, warm-started from the previous solution; the first
    input is applied.

    Registered as ``mpc-full`` and ``mpc-quasi-static`` (the estimator's method).

    Args:
        machine: The machine description.
        config: Settings.
        force_model: The normal-force model (required).
        tcp_kinematics: For `TcpGoal`.
    """

    name = "mpc"

    def __init__(self, machine: Machine, config: ControllerConfig | None = None, *,
                 force_model: NormalForceModel, tcp_kinematics: TcpKinematics | None = None,
                 name: str | None = None):
        if name is not None:
            self.name = name
        super().__init__(machine, config, tcp_kinematics=tcp_kinematics)
        if force_model is None:
            raise ConfigurationError("MpcController needs a force_model")
        cfg, mc, fc = self.config, self.config.mpc, self.config.force
        layout = VariableLayout(9, mc.n_steps, speed_scale=fc.speed_scale,
                                n_slack=4 if fc.soft else 0)
        tasks = [
            HorizonTrackingTask(CRANE_AXES, mc.crane_position_weight, mc.crane_velocity_weight,
                                mc.terminal_factor),
            HorizonTrackingTask(SUSPENSION_AXES, mc.suspension_position_weight,
                                mc.suspension_velocity_weight, mc.terminal_factor),
            HorizonInputTask(mc.input_weight),
            HorizonSmoothnessTask(mc.smoothness_weight),
            SpeedScaleTask(fc.speed_scale_weight),
            SlackPenaltyTask(fc.slack_linear, fc.slack_quadratic),
        ]
        self.force_constraint = HorizonNormalForceConstraint(
            force_model, self.force_thresholds, mc.n_linearizations, self.static_wheel_load,
            fc.drive_time_constant)
        constraints = [AccelerationLimit(), HorizonVelocityLimit(), HorizonPositionLimit(),
                       self.force_constraint, SpeedScaleLimit(fc.speed_scale_min,
                                                              fc.speed_scale_rate)]
        solver = make_solver(cfg.solver, cfg.eps_abs, cfg.eps_rel, cfg.max_iter)
        self.planner = MpcPlanner(self.limits, layout, mc.step_lengths(cfg.dt), cfg.dt, tasks,
                                  constraints, solver)
        self.last_plan: MpcPlan | None = None

    @property
    def layout(self) -> VariableLayout:
        """Decision layout of the MPC."""
        return self.planner.layout

    @property
    def horizon(self) -> float:
        """Prediction horizon [s]."""
        return self.planner.horizon

    def context(self, state: MachineState) -> HorizonContext:
        """The horizon context of ``state``."""
        ref = self.reference_at(self.planner.node_times)
        return self.planner.context(state, ref, self._last_qdd, self._speed_scale)

    def build_qp(self, state: MachineState) -> qpsolvers.Problem:
        """The condensed QP of this tick (references must be set)."""
        return self.planner.build(self.context(state))

    def prepare(self, state: MachineState) -> qpsolvers.Problem:
        """Update the references as `step` would, then return this tick's QP."""
        self._check_state(state)
        self._update_references(state)
        return self.build_qp(state)

    def _reset(self) -> None:
        self.planner.reset()
        self.last_plan = None

    def _reset_solver(self) -> None:
        self.planner.reset()

    def _solve(self, state: MachineState) -> tuple[np.ndarray, float, dict]:
        ctx = self.context(state)
        problem = self.planner.build(ctx)
        plan = self.planner.solve(ctx, problem)
        self.last_plan = plan
        sol = plan.solution
        N = self.layout.n_steps
        info = {"status": sol.status, "iterations": sol.iterations,
                "solve_time": sol.solve_time, "warm_started": sol.warm_started,
                "slack": plan.slack, "horizon": self.horizon,
                "linearization_steps": self.force_constraint.linearization_steps.copy()}
        fcon = self.force_constraint
        if fcon.last_forces_map is not None:
            A, b = fcon.last_forces_map
            info["predicted_forces"] = (A @ sol.x + b).reshape(N, 4)
            info["in_contact"] = fcon.last_in_contact.copy()
        return plan.inputs[0].copy(), plan.speed_scale, info
