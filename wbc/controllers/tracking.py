"""Whole-body QP at the control rate: accelerations of the nine axes, one step ahead."""

from __future__ import annotations

import numpy as np
import qpsolvers

from models.description import Machine
from models.state import MachineState
from wbc.axes import CRANE_AXES, N_AXES
from wbc.constraints import (
    AccelerationLimit,
    NormalForceConstraint,
    PositionLimit,
    SpeedScaleLimit,
    VelocityLimit,
)
from wbc.context import QPContext
from wbc.controllers.config import ControllerConfig
from wbc.controllers.controller import (
    MAX_STATE_MAGNITUDE,
    MAX_STATE_TIME,
    Controller,
    state_magnitudes,
)
from wbc.controllers.tracking_c import compiled_tracking_qp
from wbc.force_models.protocol import NormalForceModel
from wbc.kinematics.tcp_kinematics import TcpKinematics
from wbc.layout import VariableLayout
from wbc.qp import QP, QPBuilder
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

    Each tick's QP is `wbc.qp.QPBuilder`'s, the same bits whichever way it is made: by the
    builder (`build_qp`, and ``compiled = False``), or by the compiled tick
    (`wbc.controllers.tracking_c`: the nine axes' costs and bounds in one C call) with a
    builder of the force model's tasks and constraints alone.

    Args:
        machine: The machine description.
        config: Settings.
        force_model: Normal-force model; None: no force constraint.
        tcp_kinematics: For `TcpGoal`.

    Attributes:
        tasks, constraints: The QP's terms, fixed at construction (tuples).
        compiled: Use the compiled tick when a C compiler is there; False: the builder.
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
        tasks = [
            JointTask(CRANE_AXES, qc.crane_kp, qc.crane_kd, qc.crane_weight),
            SuspensionPostureTask(qc.suspension_kp, qc.suspension_kd, qc.suspension_weight),
            DampingTask(qc.damping_time, qc.damping_weight),
        ]
        constraints = [AccelerationLimit(), VelocityLimit(),
                       PositionLimit(qc.position_horizon, qc.braking_fraction)]
        self.force_constraint: NormalForceConstraint | None = None
        if force:
            self.force_constraint = NormalForceConstraint(
                force_model, self.force_thresholds, qc.force_lookahead,
                self.static_wheel_load, fc.drive_time_constant)
            constraints.append(self.force_constraint)
            constraints.append(SpeedScaleLimit(fc.speed_scale_min, fc.speed_scale_rate))
            tasks += [SpeedScaleTask(fc.speed_scale_weight),
                      SlackPenaltyTask(fc.slack_linear, fc.slack_quadratic)]
        # Fixed from here on: the compiled tick has read them.
        self.tasks, self.constraints = tuple(tasks), tuple(constraints)
        self.solver = make_solver(cfg.solver, cfg.eps_abs, cfg.eps_rel, cfg.max_iter)
        self.builder = QPBuilder(self.tasks, self.constraints)
        self.compiled = True
        self._tick = compiled_tracking_qp(self.tasks, self.constraints,
                                          [r for _, r in self._references()], self.limits,
                                          self.dt, self.layout, MAX_STATE_MAGNITUDE)
        # The tasks and constraints the compiled tick leaves to a builder (the force's).
        self._rest = (None if self._tick is None or len(self.tasks) == 3
                      else QPBuilder(self.tasks[3:], self.constraints[3:]))
        self._hessian: np.ndarray | None = None  # the builder's P, kept from the first tick
        self._qp: QP | None = None  # without a rest: the QP of every tick, written in place

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

    def _check_state(self, state) -> None:
        tick = self._tick if self.compiled else None
        if (tick is None or not isinstance(state, MachineState)
                or not tick.load(state, state_magnitudes(state))
                or abs(state.time) > MAX_STATE_TIME):
            super()._check_state(state)  # raises, naming the field

    def _governor_error(self, ref, tau: float, state: MachineState) -> float:
        tick = self._tick
        if tick is not None and tick.state is state:  # loaded since the last `run`
            r = tick.references.index(ref)
            kept = ref.kept(tau)
            if kept is not None and kept is tick.kept[r]:  # the positions of that `run`
                return float(tick.errors[r])
        return super()._governor_error(ref, tau, state)

    def _compiled_qp(self, state: MachineState) -> QP | None:
        """This tick's QP by `wbc.controllers.tracking_c`; None: the builder's, please.

        The costs and bounds of the nine axes from the compiled tick, those of the speed
        scale and the slacks (and the force rows) from a builder of the other tasks and
        constraints, and the Hessian the full builder made at the first tick (constant: all
        the tasks' Jacobians are). Without a force model the same QP object every tick, its
        arrays written in place (the solver has read them before the next tick).
        """
        tick = self._tick
        if tick is None or self._hessian is None or not self.compiled:
            return None
        if tick.state is not state:
            tick.load(state, state_magnitudes(state))
        times = []
        for r, (key, ref) in enumerate(self._references()):
            tau, sigma = self._clock[key]
            t = tau + sigma * 0.0  # `reference_ahead(0.0)`'s time
            tr, sample = ref.sample_raw(t)
            tick.set_sample(r, sample, sigma)
            times.append((t, tr))
        empty = not tick.run()
        tick.state = None  # its errors are of the positions before this run
        for r, (ref, (t, tr)) in enumerate(zip(tick.references, times)):
            tick.kept[r] = (ref.kept(t) if tr is None
                            else ref.keep_position(tr, tick.position[ref.index]))
        if empty:
            return None  # the builder raises, saying where
        if self._rest is None:
            return self._qp
        # The other terms touch the scale and the slacks only: there they are the full
        # sums and bounds, on the nine axes +0 and infinite (`tests/test_tracking_c.py`).
        qp = self._rest.build(QPContext.from_state(state, self.dt, self.layout, self.limits,
                                                   None, self._speed_scale))
        qp.P = self._hessian
        qp.q[:N_AXES], qp.lb[:N_AXES], qp.ub[:N_AXES] = tick.lin, tick.lower, tick.upper
        return qp

    def _solve(self, state: MachineState) -> tuple[np.ndarray, float, dict]:
        problem = self._compiled_qp(state)
        if problem is None:
            problem = self._build(self.context(state))
            tick = self._tick
            if tick is not None and self._hessian is None:
                self._hessian = problem.P
                self._qp = QP(problem.P, tick.lin, None, None, None, None, tick.lower,
                              tick.upper)
        sol = self.solver.solve(problem)
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
