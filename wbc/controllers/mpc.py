"""Stability-aware MPC: the normal-force constraint along a >= 1 s horizon."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import qpsolvers

from estimators.efforts import ActuatorEfforts
from models.description import Machine
from models.numeric import finite_nonnegative
from models.state import N_SERVO_AXES, MachineState
from wbc.axes import CRANE_AXES, N_AXES, SUSPENSION_AXES
from wbc.constraints import (
    AccelerationLimit,
    HorizonEffortLimit,
    HorizonNormalForceConstraint,
    HorizonPositionLimit,
    HorizonVelocityLimit,
    SideReserveConstraint,
    SpeedScaleLimit,
)
from wbc.constraints.force_rows import check_margins
from wbc.controllers.config import ControllerConfig
from wbc.controllers.controller import Controller
from wbc.controllers.servo_state import ServoState
from wbc.errors import ConfigurationError
from wbc.force_models.chain_c import FeedbackChain
from wbc.force_models.feedback import (
    ClosureFeedback,
    ForceFeedback,
    WarpDrift,
    leveling_offset,
    warp_matrix,
)
from wbc.force_models.fluctuation import SideLoadFluctuation, SpeedGovernor
from wbc.force_models.protocol import NormalForceModel
from wbc.kinematics.tcp_kinematics import TcpKinematics
from wbc.layout import VariableLayout
from wbc.mpc.context import HorizonContext
from wbc.mpc.planner import MpcPlan, MpcPlanner
from wbc.solvers import make_solver
from wbc.structure import prepare_planner
from wbc.tasks import (
    HorizonInputTask,
    HorizonLevelingTask,
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

    Load split (`wbc.force_models.feedback`): with a ``feedback`` (`ClosureFeedback`, the
    estimator's cylinder-force closure) and ``config.force.feedback``, the forces the model
    predicts are corrected at every step by the split measured now; with
    ``config.force.warp_stiffness > 0`` the suspension setpoints act on that split through
    the chassis warp, in the force constraint and in `HorizonLevelingTask`. With
    ``config.mpc.setpoint_state`` the axes are predicted from their servo setpoints and
    commanded rates (`wbc.controllers.servo_state`).

    Args:
        machine: The machine description.
        config: Settings.
        force_model: The normal-force model (required).
        tcp_kinematics: For `TcpGoal`.
        feedback: The measured load split; None: the model alone.
        compiled: Run the load split's per-tick chain in C (`wbc.force_models.chain_c`,
            the same bits) where a compiler and numpy's BLAS are found; False: numpy's
            steps (the reference).
    """

    name = "mpc"

    def __init__(self, machine: Machine, config: ControllerConfig | None = None, *,
                 force_model: NormalForceModel, tcp_kinematics: TcpKinematics | None = None,
                 name: str | None = None, feedback: ClosureFeedback | None = None,
                 compiled: bool = True):
        self.compiled = bool(compiled)
        if name is not None:
            self.name = name
        super().__init__(machine, config, tcp_kinematics=tcp_kinematics)
        if force_model is None:
            raise ConfigurationError("MpcController needs a force_model")
        if self.config.force.warp_stiffness is None:  # derived from the machine, once
            fc = self.config.force
            self.config = replace(self.config, force=replace(
                fc, warp_stiffness=fc.warp_stiffness_for(machine)))
        cfg, mc, fc = self.config, self.config.mpc, self.config.force
        self.force_model = force_model
        self.feedback: ClosureFeedback | None = None
        self.warp: np.ndarray | None = None
        self._set_feedback(feedback)
        side = fc.side_reserve > 0 or fc.side_reserve_z > 0  # two more slacks (config: soft)
        layout = VariableLayout(9, mc.n_steps, speed_scale=fc.speed_scale,
                                n_slack=(10 if side else 8) if fc.soft else 0)
        factors = np.asarray(mc.crane_axis_factors, float)
        tasks = [
            HorizonTrackingTask(CRANE_AXES, mc.crane_position_weight * factors,
                                mc.crane_velocity_weight * factors,
                                mc.terminal_factor),
            HorizonTrackingTask(SUSPENSION_AXES, mc.suspension_position_weight,
                                mc.suspension_velocity_weight, mc.terminal_factor),
            HorizonInputTask(mc.input_weight),
            HorizonSmoothnessTask(mc.smoothness_weight),
            SpeedScaleTask(fc.speed_scale_weight),
            SlackPenaltyTask(fc.slack_linear, fc.slack_quadratic),
            HorizonLevelingTask(fc.leveling_weight, self.static_wheel_load),
        ]
        self.force_constraint = HorizonNormalForceConstraint(
            force_model, self.force_thresholds + fc.margin, mc.n_linearizations,
            self.static_wheel_load, fc.drive_time_constant, mc.terminal_brake_time,
            mc.force_constraint_start)
        self.speed_limit = SpeedScaleLimit(fc.speed_scale_min, fc.speed_scale_rate)
        self.side_reserve = (SideReserveConstraint(self.force_constraint,
                                                   fc.side_reserve_time) if side else None)
        constraints = [AccelerationLimit(), HorizonVelocityLimit(), HorizonPositionLimit(),
                       self.force_constraint, self.speed_limit]
        if self.side_reserve is not None:  # after the force rows: it reads their forces
            constraints.insert(4, self.side_reserve)
        self.effort_limit = (HorizonEffortLimit(ActuatorEfforts(machine), mc.effort_margin)
                             if mc.effort_limits else None)
        if self.effort_limit is not None:
            constraints.append(self.effort_limit)
        solver = make_solver(cfg.solver, cfg.eps_abs, cfg.eps_rel, cfg.max_iter,
                             feasible_by_construction=fc.soft)
        self.planner = MpcPlanner(self.limits, layout, mc.step_lengths(cfg.dt), cfg.dt, tasks,
                                  constraints, solver)
        if self.warp is not None:  # the leveling task's terms for the contexts' warp, now
            prepare_planner(self.planner, self.warp)
        self.last_plan: MpcPlan | None = None
        self.force_margin = np.zeros(4)
        ranges = machine.coordinates  # the setpoints may use the full ranges (no margin)
        pred, lim = self.planner.prediction, self.planner.limits  # the servo pass's brake
        self.servo = (ServoState(cfg.dt, mc.deflection_time_constant, ranges.lower[:N_AXES],
                                 ranges.upper[:N_AXES], times=pred.times, brake=(
                                     pred.Lq, pred.Lv, pred.step_lengths, lim.acceleration))
                      if mc.setpoint_state else None)

    @property
    def layout(self) -> VariableLayout:
        """Decision layout of the MPC."""
        return self.planner.layout

    @property
    def horizon(self) -> float:
        """Prediction horizon [s]."""
        return self.planner.horizon

    def set_force_model(self, force_model: NormalForceModel,
                        feedback: ClosureFeedback | None = None) -> None:
        """Replace the force model (and the feedback), e.g. when the payload changes.

        The estimator is built from the machine description, payload included; a new
        payload mass needs estimators of the machine with that payload
        (`wbc.force_models.estimator.load_estimator` of
        ``build_reference_machine(payload_mass=...)``). The plan is kept as warm start.
        """
        if force_model is None:
            raise ConfigurationError("set_force_model needs a force model")
        self.force_model = force_model
        self.force_constraint.model = force_model
        self._set_feedback(feedback)
        if self.warp is not None:
            prepare_planner(self.planner, self.warp)

    def set_payload_mass(self, mass: float) -> None:
        """Tell the models the payload now held [kg] (the observer's estimate, or known).

        The effort model takes it directly; a force model (and the feedback's closure)
        that has a run-time ``payload_mass`` too.
        """
        if self.effort_limit is not None:
            self.effort_limit.efforts.payload_mass = mass
        for model in (self.force_model, getattr(self.feedback, "closure", None)):
            if model is not None and hasattr(type(model), "payload_mass"):
                model.payload_mass = mass

    def set_force_margin(self, margin) -> None:
        """Set the per-wheel margin [N] (4,) added to the thresholds from now on.

        Besides ``ForceConfig.margin``: ``z sigma`` of the forces' uncertainty
        (`estimators.uncertainty.force_margin`), updated every tick.

        Raises:
            ConfigurationError: Not four finite margins >= 0.
        """
        m = np.asarray(margin, float)
        if m.shape != (4,) or not finite_nonnegative(m.tolist()):  # the error's message
            m = check_margins(margin, 4, "force margin")
        self.force_constraint.thresholds = self.force_thresholds + self.config.force.margin + m
        self.force_margin = m

    def _set_feedback(self, feedback: ClosureFeedback | None) -> None:
        """The warp is modelled only where the split is measured (it acts on that split)."""
        fc = self.config.force
        self.feedback = feedback if fc.feedback else None
        self.warp = (warp_matrix(fc.warp_stiffness)
                     if self.feedback is not None and fc.warp_stiffness > 0 else None)
        if self.warp is not None:  # the same matrix every tick (`HorizonLevelingTask` keeps)
            self.warp.setflags(write=False)
        self.warp_drift = (WarpDrift(fc.warp_stiffness, fc.drift_time_constant,
                                     fc.drift_horizon)
                           if self.warp is not None and fc.drift_horizon > 0 else None)
        self.governor = (SpeedGovernor(fc.governor_z, fc.governor_high_pass,
                                       fc.governor_window, fc.drive_time_constant)
                         if self.feedback is not None and fc.governor_z > 0 else None)
        self.side_swing = (SideLoadFluctuation(fc.side_reserve_high_pass,
                                               fc.side_reserve_window,
                                               fc.side_reserve_min_speed)
                           if self.feedback is not None and (fc.side_reserve > 0
                                                             or fc.side_reserve_z > 0)
                           else None)
        self._chain = None if self.warp is None or not self.compiled else self._make_chain()
        self._reserve_kept = None

    def _make_chain(self) -> FeedbackChain | None:
        """The feedback chain in C with the parts' settings (None without a compiler)."""
        chain = FeedbackChain.make(self.warp, N_SERVO_AXES)
        if chain is None:
            return None
        fc = self.config.force
        chain.set(leveling_limit=fc.leveling_limit)
        if self.warp_drift is not None:
            d = self.warp_drift
            chain.set(stiffness=d.stiffness, drift_tc=d.time_constant, drift_horizon=d.horizon,
                      drift_limit=d.limit)
        if self.governor is not None:
            g = self.governor
            chain.set(gov_z=g.z, gov_drive_tc=g.drive_time_constant, gov_high_pass=g.high_pass,
                      gov_window=g.window, gov_min_speed=g.min_speed)
        if self.side_swing is not None:
            chain.set(side_window=self.side_swing.window)
        return chain

    def _init_loop_state(self) -> None:
        super()._init_loop_state()
        self.last_feedback: ForceFeedback | None = None
        self._reserve_kept = None
        for part in ("servo", "warp_drift", "governor", "side_swing"):
            if getattr(self, part, None) is not None:
                getattr(self, part).reset()
        if getattr(self, "speed_limit", None) is not None:
            self.speed_limit.cap = 1.0
        if getattr(self, "side_reserve", None) is not None:
            self.side_reserve.set_reserve(np.zeros(2))

    def _rate_basis(self, state: MachineState) -> np.ndarray:
        """The rates commanded last tick (`MpcConfig.setpoint_state`), else measured (views)."""
        if self.servo is not None and self.servo.setpoint is not None:
            return self.servo.rates
        return state.qd[:N_AXES]

    def _commanded(self, rates: np.ndarray) -> None:
        if self.servo is not None:
            self.servo.commanded(rates)

    def _rates(self, state: MachineState, qdd: np.ndarray) -> np.ndarray:
        """The base class's rates, by `ServoState.command` once the servo is observed."""
        servo, limits = self.servo, self.limits
        if servo is None or servo.setpoint is None:
            return super()._rates(state, qdd)
        return servo.command(qdd, self.dt, limits.velocity_lower, limits.velocity_upper)

    def _compensated(self, fb: ForceFeedback, state: MachineState) -> ForceFeedback:
        """The split measured in ``state``, carried to the setpoints commanded since.

        The state is the servos' at its time (``state.servo_setpoint``); the
        controller has commanded more since (one period, or more with a measurement
        delay). Through the warp model those commands have already moved the split:
        ``f += W (s_now - s_state)``, a Smith predictor on the suspension. Only with all
        four wheels on the ground (otherwise the warp is free).
        """
        measured = state.servo_setpoint
        if (self.warp is None or self.servo is None or self.servo.setpoint is None
                or measured is None or not np.logical_and.reduce(fb.in_contact)):
            return fb
        shift = self.warp @ (self.servo.setpoint - np.asarray(measured, float)[:N_AXES])
        return ForceFeedback.of(fb.forces + shift, fb.model_forces, fb.in_contact, fb.time)

    def context(self, state: MachineState) -> HorizonContext:
        """The horizon context of ``state`` (measures the load split, see the class)."""
        planner, start = self.planner, None
        ref = self.reference_at(planner.node_times)
        if self.servo is not None:  # with the free response and the brake, in one pass
            start = self.servo.observe_brake(state, planner.prediction,
                                             planner.limits.acceleration)
            q, qd = start[0], start[1]
        else:
            q, qd = state.q[:N_AXES].copy(), state.qd[:N_AXES].copy()
        fb = None
        offset = 0.0
        drift = None
        if self.feedback is not None:
            measured = self.feedback.measure(state, self.force_model)
            done = (None if self._chain is None
                    else self._chained_feedback(measured, state, q))
            fb, offset, drift = (self._feedback_steps(measured, state, q) if done is None
                                 else done)
        return planner.context(state, ref, self._last_qdd, self._speed_scale, q=q, qd=qd,
                               start=start, feedback=fb, warp=self.warp,
                               leveling_offset=offset, warp_drift=drift)

    def _feedback_steps(self, measured: ForceFeedback, state: MachineState,
                        q: np.ndarray) -> tuple[ForceFeedback, float, np.ndarray | None]:
        """(feedback, leveling offset, warp drift) of the split measured: numpy's steps.

        The reference of `_chained_feedback`: the compensation, the leveling offset, the
        warp drift, the speed governor's cap and the side reserve.
        """
        fb = self._compensated(measured, state)
        self.last_feedback = fb
        offset = 0.0
        drift = None
        if self.warp is not None:
            offset = leveling_offset(fb.forces, self.force_constraint.thresholds,
                                     fb.in_contact, self.config.force.leveling_limit)
            if self.warp_drift is not None:
                self.warp_drift.update(fb, float(q[SUSPENSION_AXES[0]]
                                                 - q[SUSPENSION_AXES[1]]))
                drift = self.warp_drift.drift(self.planner.node_starts)
        if self.governor is not None or self.side_swing is not None:
            speed = float(np.hypot(state.base_twist[0], state.base_twist[1]))
            if self.governor is not None:
                self._govern(fb, speed)
            if self.side_swing is not None and self.side_reserve is not None:
                self._side_reserve(fb, speed)
        return fb, offset, drift

    def _chained_feedback(self, measured: ForceFeedback, state: MachineState,
                          q: np.ndarray) -> tuple | None:
        """`_feedback_steps` in one C call (`wbc.force_models.chain_c`), the same bits.

        None where the chain does not take the tick (a governor on the numpy path); the
        side swing's measure (``side_reserve_z > 0``) stays numpy's, after the call.
        """
        servo, side = self.servo, None
        swing = self.config.force.side_reserve_z > 0
        if self.side_swing is not None and self.side_reserve is not None and not swing:
            side = self.side_swing
        fcon = self.force_constraint
        out = self._chain.run(
            measured, None if servo is None else servo.setpoint, state.servo_setpoint,
            q[SUSPENSION_AXES[0]] - q[SUSPENSION_AXES[1]], state.base_twist,
            self._speed_scale, fcon.thresholds, self.planner.node_starts, self.warp_drift,
            self.governor, side)
        if out is None:
            return None
        forces, offset, drift, speed, cap = out
        fb = (measured if forces is None else
              ForceFeedback.of(forces, measured.model_forces, measured.in_contact,
                               measured.time))
        self.last_feedback = fb
        if cap is not None:
            self.speed_limit.cap = cap
        if self.side_swing is not None and self.side_reserve is not None:
            if side is None:
                self._side_reserve(fb, speed)
            else:
                self._set_side_reserve()
        return fb, offset, drift

    def _govern(self, fb: ForceFeedback, speed: float) -> None:
        """Cap the speed scale by the speed governor (`wbc.force_models.fluctuation`).

        ``speed``: the base's horizontal speed [m/s].
        """
        self.governor.update(fb.forces, fb.in_contact, fb.time, speed, self._speed_scale)
        self.speed_limit.cap = self.governor.cap(self.force_constraint.thresholds, speed,
                                                 fb.in_contact)

    def _side_reserve(self, fb: ForceFeedback, speed: float) -> None:
        """The side pairs' reserve ``max(r_0, z sigma_j)`` while driving, none standing.

        ``speed``: the base's horizontal speed [m/s].
        """
        fc = self.config.force
        self.side_swing.update(fb.forces, fb.in_contact, fb.time, speed,
                               swing=fc.side_reserve_z > 0)  # the floor needs the speed only
        self._set_side_reserve()

    def _set_side_reserve(self) -> None:
        """`SideReserveConstraint.set_reserve` of the side swing's reserve now.

        Its value changes only with ``driving`` and ``sigma`` (a new array at each update):
        while both and the constraint's reserve are the ones set last, it is not set again
        (the same numbers).
        """
        fc, swing = self.config.force, self.side_swing
        key = (swing.driving, swing.sigma)
        kept = self._reserve_kept
        if (kept is not None and kept[0] == key[0] and kept[1] is key[1]
                and self.side_reserve.reserve is kept[2]):
            return
        reserve = np.maximum(fc.side_reserve, fc.side_reserve_z * swing.sigma)
        self.side_reserve.set_reserve(reserve if key[0] else np.zeros(2))
        self._reserve_kept = (*key, self.side_reserve.reserve)

    def _build(self, ctx: HorizonContext) -> qpsolvers.Problem:
        return self.planner.build(ctx)

    def _reset(self) -> None:
        self.planner.reset()
        self.last_plan = None

    def _reset_solver(self) -> None:
        self.planner.reset()

    def _solve(self, state: MachineState) -> tuple[np.ndarray, float, dict]:
        ctx = self.context(state)
        plan = self.planner.solve(ctx, self._build(ctx))
        self.last_plan = plan
        sol = plan.solution
        N = self.layout.n_steps
        info = {"status": sol.status, "iterations": sol.iterations,
                "solve_time": sol.solve_time, "warm_started": sol.warm_started,
                "solver_call_time": sol.call_time,
                "slack": plan.slack, "horizon": self.horizon,
                "linearization_steps": self.force_constraint.linearization_steps.copy()}
        if ctx.feedback is not None:
            info["measured_forces"] = ctx.feedback.forces.copy()
            info["leveling_offset"] = ctx.leveling_offset
            if self.warp_drift is not None:
                info["warp_drift_rate"] = self.warp_drift.rate
        fcon = self.force_constraint
        if fcon.last_forces_map is not None:
            A, b = fcon.last_forces_map
            f = (A @ sol.x + b).reshape(-1, 4)
            info["predicted_forces"] = f[:N]
            if f.shape[0] > N:
                info["terminal_forces"] = f[N]
            info["in_contact"] = fcon.last_in_contact.copy()
        return plan.inputs[0], plan.speed_scale, info  # `_command` copies what it keeps
