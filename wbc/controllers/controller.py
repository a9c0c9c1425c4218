"""The controller interface: goals in, actuator rate commands out, one `step` per tick.

A closed loop reads::

    controller = make_controller("mpc-full", machine)
    controller.set_goal(JointGoal(crane=q_goal))
    while running:
        state, _ = sim.measure()
        cmd = controller.step(state)
        sim.set_command(cmd.cylinder_rates, cmd.wrist_rates,
                        cmd.wheel_speeds(left_nominal, right_nominal))

`step` must be called every ``config.dt`` seconds; references are timed with
``state.time``.
"""

from __future__ import annotations

import abc
import logging
import operator
from typing import ClassVar

import numpy as np
import qpsolvers

from models.description import Machine
from models.numeric import clip
from models.state import MachineState
from wbc.axes import CRANE_AXES, N_AXES, SUSPENSION_AXES, AxisLimits
from wbc.context import ControlContext, ReferenceSample
from wbc.controllers.command import ControlCommand
from wbc.controllers.config import ControllerConfig
from wbc.errors import (
    ConfigurationError,
    ForceModelError,
    IKError,
    QPSolveError,
    TrajectoryError,
    WbcInputError,
)
from wbc.kinematics.tcp_ik import solve_tcp_ik
from wbc.kinematics.tcp_kinematics import TcpKinematics
from wbc.references.goals import JointGoal, TcpGoal
from wbc.references.ruckig_reference import RuckigReference

__all__ = ["Controller", "MAX_STATE_MAGNITUDE", "MAX_STATE_TIME", "state_magnitudes"]

# Bounds of a measured state: far beyond any real machine, well inside double precision.
MAX_STATE_MAGNITUDE = 1e6  # [m, rad, m/s, rad/s, m/s^2, rad/s^2]
MAX_STATE_TIME = 1e9  # [s], about 30 years
_MAGNITUDE_FIELDS = ("base_twist", "base_acceleration", "q", "qd", "qdd")  # checked per tick
state_magnitudes = operator.attrgetter(*_MAGNITUDE_FIELDS)  # the arrays checked, a tuple
_max = np.maximum.reduce  # `np.max` of a 1-D array without its Python dispatch


def _unit_interval(x: float) -> float:
    """``float(clip(x, 0.0, 1.0))`` without a ufunc call, NaN and -0.0 passed alike."""
    return float(min(max(x, 0.0), 1.0))  # max and min keep their first argument on ties


class Controller(abc.ABC):
    """Common part of the controllers: goals, Ruckig references, commands, fallback.

    Subclasses implement `_solve`, which returns the nine axis accelerations and the
    wheel-speed scale for this tick, or raises `QPSolveError` / `ForceModelError`; the
    base class then takes the safe action (`fallback_command`) and logs it.

    Args:
        machine: The machine description.
        config: Settings; defaults if None.
        tcp_kinematics: TCP kinematics for `TcpGoal` (built from the Pinocchio model on
            first use if None).
    """

    name: ClassVar[str] = ""

    def __init__(self, machine: Machine, config: ControllerConfig | None = None, *,
                 tcp_kinematics: TcpKinematics | None = None):
        if not isinstance(machine, Machine):
            raise WbcInputError(f"machine must be a models.Machine, got {type(machine)!r}")
        config = ControllerConfig() if config is None else config
        if not isinstance(config, ControllerConfig):
            raise ConfigurationError(f"config must be a ControllerConfig, got {type(config)!r}")
        self.machine = machine
        self.config = config
        self.dt = config.dt
        self.limits = AxisLimits.from_machine(machine, config.position_margin)
        rc = config.reference
        self.crane_reference = RuckigReference(self.limits, CRANE_AXES, rc.jerk_time,
                                               rc.velocity_fraction, rc.acceleration_fraction)
        self.suspension_reference = RuckigReference(self.limits, SUSPENSION_AXES, rc.jerk_time,
                                                    rc.velocity_fraction,
                                                    rc.acceleration_fraction)
        self.static_wheel_load = machine.total_mass * machine.gravity / 4
        fc = config.force
        self.force_thresholds = fc.thresholds_for(machine)
        self._tcp = tcp_kinematics
        self.logger = logging.getLogger(f"wbc.controllers.{self.name or type(self).__name__}")
        self.n_fallbacks = 0
        self._init_loop_state()

    # ------------------------------------------------------------------ goals
    @property
    def tcp_kinematics(self) -> TcpKinematics:
        """TCP kinematics (built on first use)."""
        if self._tcp is None:
            self._tcp = TcpKinematics(self.machine)
        return self._tcp

    def resolve_tcp_goal(self, goal: TcpGoal, state: MachineState) -> JointGoal:
        """Crane joint goals that put the TCP at ``goal.position_in_fb``, from ``state``.

        Raises:
            IKError: The position is not reachable.
        """
        self._check_state(state)
        res = solve_tcp_ik(self.tcp_kinematics, goal.position_in_fb, state.q, self.limits)
        return JointGoal(crane=res.q[CRANE_AXES], suspension=goal.suspension)

    def set_goal(self, goal: JointGoal | TcpGoal, state: MachineState | None = None) -> None:
        """Set a new goal; the references are planned at the next `step`.

        A `TcpGoal` is resolved by inverse kinematics now when ``state`` is given (an
        unreachable target raises `IKError`), otherwise at the next step (an unreachable
        target is then logged, reported in ``info['goal_error']`` and dropped).

        Raises:
            WbcInputError: Wrong goal type, or a joint goal outside an axis's physical
                range. A goal inside the physical range but in the margin the controller
                keeps from each end (`ControllerConfig.position_margin`) is clamped to the
                margin, logged and reported in ``info['goal_error']``: a running controller
                does not stop on a goal a few millimetres off.
            IKError: Unreachable TCP target (only with ``state``).
        """
        if isinstance(goal, TcpGoal) and state is not None:
            goal = self.resolve_tcp_goal(goal, state)
        if isinstance(goal, JointGoal):
            self._goal_error = None
            goal = self._clamped(goal)
        elif not isinstance(goal, TcpGoal):
            raise WbcInputError(f"goal must be a JointGoal or a TcpGoal, got {type(goal)!r}")
        self._pending = goal

    def _clamped(self, goal: JointGoal) -> JointGoal:
        """``goal`` within the margin-shrunk limits (see `set_goal`)."""
        coords = self.machine.coordinates
        parts, notes = {}, []
        for key, ref, axes in (("crane", self.crane_reference, CRANE_AXES),
                               ("suspension", self.suspension_reference, SUSPENSION_AXES)):
            g = getattr(goal, key)
            if g is None:
                parts[key] = None
                continue
            lo, hi = coords.lower[axes], coords.upper[axes]
            outside = (g < lo - 1e-12) | (g > hi + 1e-12)
            if outside.any():
                k = int(np.argmax(outside))
                raise WbcInputError(f"goal {g[k]:.6g} outside [{lo[k]:.6g}, {hi[k]:.6g}] for "
                                    f"axis '{ref.names[k]}' (its physical range)")
            c = clip(g, ref.position_lower, ref.position_upper)
            for k in np.flatnonzero(c != g):
                notes.append(f"'{ref.names[k]}' {g[k]:.6g} -> {c[k]:.6g}")
            parts[key] = c
        if notes:
            self._goal_error = "goal clamped into the position margin: " + ", ".join(notes)
            self.logger.warning(self._goal_error)
            return JointGoal(**parts)
        return goal

    def reset(self) -> None:
        """Forget goals, references, the previous command and solver warm starts."""
        self._init_loop_state()
        self._reset()

    def _init_loop_state(self) -> None:
        self._pending: JointGoal | TcpGoal | None = None
        self._references_ready = False
        self._speed_scale = 1.0
        self._last_qdd = np.zeros(N_AXES)
        self._last_time: float | None = None
        # Reference clocks (time-scaled): reference time and rate of the crane and suspension.
        self._clock = {"crane": [0.0, 1.0], "suspension": [0.0, 1.0]}
        self._goal_error: str | None = None

    def _reset(self) -> None:
        """Subclass hook of `reset`."""

    # ------------------------------------------------------------------ references
    def _plan(self, ref: RuckigReference, state: MachineState, goal) -> None:
        i = ref.axes
        ref.plan(state.time, state.q[i], state.qd[i], state.qdd[i], goal)

    def _references(self):
        return (("crane", self.crane_reference), ("suspension", self.suspension_reference))

    def _update_references(self, state: MachineState) -> None:
        """Hold at the first step, plan pending goals, advance the reference clocks.

        Time scaling (a reference governor): each reference's clock advances at the rate
        ``sigma = clip(2 (1 - e / e_g), 0, 1)`` with ``e`` the largest tracking error of its
        axes and ``e_g = governor_error``.
        """
        if not self._references_ready:
            self.crane_reference.hold(state.q[CRANE_AXES])
            self.suspension_reference.hold(state.q[SUSPENSION_AXES])
            self._references_ready = True
        elapsed = 0.0 if self._last_time is None else max(state.time - self._last_time, 0.0)
        self._last_time = state.time
        goal, self._pending = self._pending, None
        if isinstance(goal, TcpGoal):
            try:
                goal = self.resolve_tcp_goal(goal, state)
            except IKError as exc:
                self._goal_error = str(exc)
                self.logger.error("TCP goal dropped: %s", exc)
                goal = None
        planned = ()
        if goal is not None:
            planned = set()
            for key, ref, g in (("crane", self.crane_reference, goal.crane),
                                ("suspension", self.suspension_reference, goal.suspension)):
                if g is not None:
                    self._plan(ref, state, g)
                    self._clock[key] = [state.time, 1.0]
                    planned.add(key)
        e_g = self.config.reference.governor_error
        for key, ref in self._references():
            if key in planned:
                continue
            clock = self._clock[key]
            err = self._governor_error(ref, clock[0], state)
            clock[1] = float(min(max(2.0 * (1.0 - err / e_g), 0.0), 1.0))  # a scalar clip
            clock[0] += clock[1] * elapsed

    def _governor_error(self, ref: RuckigReference, tau: float, state: MachineState) -> float:
        """The governor's ``e``: the largest ``|reference position at tau - q|`` of ``ref``.

        numpy's ``max(abs(d))`` on the differences as Python floats (the same IEEE
        results; a NaN wins, as in numpy's maximum), the reference's kept position read
        without a copy: ~1 us less a reference, every tick.
        """
        position = ref.kept(tau)
        if position is None:
            position = ref.position(tau)
        d = (position - state.q[ref.index]).tolist()  # a reference has axes: d[0] exists
        err = abs(d[0])
        for x in d[1:]:  # numpy's maximum: the larger, a NaN kept once met
            x = abs(x)
            if not (err >= x or err != err):
                err = x
        return err

    def reference_at(self, offsets) -> ReferenceSample:
        """Reference of the nine axes ahead of now: arrays (len(offsets), 9).

        Args:
            offsets: Times ahead of the current reference time [s]; each reference is
                sampled at ``tau + sigma * offset`` (its clock and clock rate), with
                velocities scaled by sigma and accelerations by sigma^2.
        """
        offsets = np.asarray(offsets, float)
        if offsets.ndim != 1:  # a 1-D array stays the caller's (the MPC's kept node times)
            offsets = offsets.reshape(-1)
        shape = (offsets.size, N_AXES)
        p, v, a = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        for key, ref in self._references():
            tau, sigma = self._clock[key]
            i = ref.index
            if isinstance(i, slice):  # its columns, written in place
                ref.sample_nodes_into(tau, sigma, offsets, p, v, a)
            else:
                rp, rv, ra = (np.empty((offsets.size, ref.n)) for _ in range(3))
                ref.sample_many_into(tau + sigma * offsets, sigma, rp, rv, ra)
                p[:, i], v[:, i], a[:, i] = rp, rv, ra
        return ReferenceSample.of(p, v, a)

    def reference_ahead(self, offset: float = 0.0) -> ReferenceSample:
        """`reference_at` at one offset: arrays of shape (9,), the same numbers.

        The whole-body QP's reference, every tick: written in place, without the
        (1, 9) arrays and the per-time loop of `reference_at`.
        """
        p, v, a = np.zeros(N_AXES), np.zeros(N_AXES), np.zeros(N_AXES)
        for key, ref in self._references():
            tau, sigma = self._clock[key]
            i = ref.index
            ref.sample_into(tau + sigma * offset, sigma, p[i], v[i], a[i])
        return ReferenceSample(p, v, a)

    # ------------------------------------------------------------------ loop
    def _check_state(self, state) -> None:
        """`WbcInputError` unless ``state`` is a `MachineState` of bounded magnitudes.

        Shapes, finiteness and the rotation were checked when the state was built; the
        magnitudes that would overflow the control arithmetic are checked here.
        """
        if not isinstance(state, MachineState):
            raise WbcInputError(f"state must be a models.MachineState, got {type(state)!r}")
        if _max(np.abs(np.concatenate(state_magnitudes(state)))) > MAX_STATE_MAGNITUDE:
            for name in _MAGNITUDE_FIELDS:  # one pass above; here which field it was
                big = float(np.abs(getattr(state, name)).max())
                if big > MAX_STATE_MAGNITUDE:
                    raise WbcInputError(f"state.{name} has an entry of magnitude {big:.3g}; "
                                        f"valid: |{name}| <= {MAX_STATE_MAGNITUDE:g} (a sensor "
                                        f"fault?)")
        if abs(state.time) > MAX_STATE_TIME:
            raise WbcInputError(f"state.time {state.time:.6g} s outside "
                                f"[-{MAX_STATE_TIME:g}, {MAX_STATE_TIME:g}] s")

    @abc.abstractmethod
    def context(self, state: MachineState) -> ControlContext:
        """What this tick's QP is built from (references at the current reference time)."""

    @abc.abstractmethod
    def _build(self, ctx: ControlContext) -> qpsolvers.Problem:
        """The QP of ``ctx``."""

    def build_qp(self, state: MachineState) -> qpsolvers.Problem:
        """The QP of this tick (references must be set: after a `step`, or use `prepare`)."""
        return self._build(self.context(state))

    def prepare(self, state: MachineState) -> qpsolvers.Problem:
        """Update the references as `step` would, then return this tick's QP."""
        self._check_state(state)
        self._update_references(state)
        return self.build_qp(state)

    @abc.abstractmethod
    def _solve(self, state: MachineState) -> tuple[np.ndarray, float, dict]:
        """(qdd (9,), wheel-speed scale, info) for this tick; may raise QPSolveError.

        ``qdd`` is read, and copied where it is kept (`_command`).
        """

    def step(self, state: MachineState) -> ControlCommand:
        """One control tick: measured state in, rate commands out.

        Raises:
            WbcInputError: ``state`` is not a `MachineState`, or an entry of its twist,
                accelerations, coordinates or rates exceeds `MAX_STATE_MAGNITUDE` (or its time
                `MAX_STATE_TIME`): a sensor fault that would overflow the arithmetic.
        """
        self._check_state(state)
        try:
            self._update_references(state)
            qdd, scale, info = self._solve(state)
        except (QPSolveError, ForceModelError, TrajectoryError) as exc:
            return self.fallback_command(state, exc)
        return self._command(state, qdd, scale, info, fallback=False)

    def _rate_basis(self, state: MachineState) -> np.ndarray:
        """Axis velocities the accelerations are added to, (9,): the measured ones.

        Read, never written (`_command` and `fallback_command` make new arrays of them).
        """
        return state.qd[:N_AXES]

    def _commanded(self, rates: np.ndarray) -> None:
        """Subclass hook: the rates just commanded."""

    def _rates(self, state: MachineState, qdd: np.ndarray) -> np.ndarray:
        """The rates (9,) commanded for the accelerations ``qdd`` (a new array).

        ``clip(basis + qdd dt)`` at the velocity limits (`_rate_basis`), then `_commanded`
        of them.
        """
        rates = clip(self._rate_basis(state) + qdd * self.dt, self.limits.velocity_lower,
                     self.limits.velocity_upper)
        self._commanded(rates)
        return rates

    def _command(self, state: MachineState, qdd: np.ndarray, scale: float, info: dict,
                 fallback: bool) -> ControlCommand:
        rates = self._rates(state, qdd)
        scale = _unit_interval(scale)  # solver tolerance aside, s is in [0, 1]
        self._last_qdd = qdd.copy()
        self._speed_scale = scale
        if self._goal_error is not None:
            info["goal_error"] = self._goal_error
        info["controller"] = self.name
        return ControlCommand.of(rates, scale, qdd.copy(), fallback, info)

    def fallback_command(self, state: MachineState, reason: Exception | str) -> ControlCommand:
        """The safe action, always finite.

        Brake the crane at its acceleration limits to rest, hold the suspension (zero stroke
        rate), lower the wheel-speed scale at its rate limit. Logged as a warning.
        """
        self.n_fallbacks += 1
        self.logger.warning("fallback at t=%.3f s: %s", state.time, reason)
        qd = self._rate_basis(state)
        qdd = self.limits.brake_acceleration(qd, self.dt)
        qdd[SUSPENSION_AXES] = -qd[SUSPENSION_AXES] / self.dt
        fc = self.config.force
        scale = max(fc.speed_scale_min, self._speed_scale - fc.speed_scale_rate * self.dt)
        # The plan or workspace that failed must not seed the next solve.
        self._reset_solver()
        return self._command(state, qdd, scale, {"fallback_reason": str(reason)}, fallback=True)

    def _reset_solver(self) -> None:
        """Subclass hook: drop warm starts after a failure."""
