"""Controller settings. Every number has a unit; every tolerance is explicit."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from wbc.errors import ConfigurationError
from wbc.force_models.feedback import warp_stiffness

__all__ = ["ControllerConfig", "ForceConfig", "MpcConfig", "QPConfig", "ReferenceConfig"]


def _real(v) -> bool:
    """True for a finite real number (Python or numpy scalar; not a bool, string, complex)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer,
                                                            np.floating)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:  # an int beyond the float range
        return False


def _flags(obj, *names):
    for n in names:
        if not isinstance(getattr(obj, n), (bool, np.bool_)):
            raise ConfigurationError(f"{type(obj).__name__}.{n} must be True or False, got "
                                     f"{getattr(obj, n)!r}")


def _integers(obj, *names):
    for n in names:
        v = getattr(obj, n)
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ConfigurationError(f"{type(obj).__name__}.{n} must be an integer >= 1, "
                                     f"got {v!r}")


def _numbers(obj, name: str, value, n: int) -> np.ndarray:
    try:
        a = np.asarray(value, float) if not np.iscomplexobj(value) else None
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ConfigurationError(f"{type(obj).__name__}.{name} must be {n} finite numbers, "
                                 f"got {value!r}")
    return a


def _positive(obj, *names, allow_zero=False):
    for n in names:
        v = getattr(obj, n)
        ok = _real(v) and (v >= 0 if allow_zero else v > 0)
        if not ok:
            raise ConfigurationError(f"{type(obj).__name__}.{n} must be "
                                     f"{'>= 0' if allow_zero else '> 0'} and finite, got {v}")


@dataclass(frozen=True)
class ReferenceConfig:
    """Ruckig references.

    Attributes:
        jerk_time: Time to build up full acceleration [s] (jerk = a / jerk_time). Every
            change of acceleration is a ramp of this length, whose spectrum is the step's
            times ``sinc(pi f T)``: zero at ``f = 1 / T`` and small above it. With 0.5 s
            the crane's starts and stops excite the machine's rocking (the chassis on its
            tyres and the boom on its servos, 2-4 Hz in the simulated runs) less: ramps of
            0.25 s pass up to 64 % of a step's excitation there, 0.5 s at most 22 %
            (docs/sweeps.md).
        velocity_fraction: Fraction of the axis velocity limits the reference uses.
        acceleration_fraction: Fraction of the axis acceleration limits.
        governor_error: Tracking error [m or rad] at which the reference clock stops. The
            clock slows down from half this error on (time scaling), so a reference does
            not run away from a machine held back by a constraint and then pull it with a
            lurch when the constraint releases.
    """

    jerk_time: float = 0.5
    velocity_fraction: float = 0.8
    acceleration_fraction: float = 0.8
    governor_error: float = 0.05

    def __post_init__(self):
        _positive(self, "jerk_time", "velocity_fraction", "acceleration_fraction",
                  "governor_error")
        if self.velocity_fraction > 1 or self.acceleration_fraction > 1:
            raise ConfigurationError("reference fractions must be <= 1")


@dataclass(frozen=True)
class QPConfig:
    """Whole-body QP (the ``tracking`` controller).

    Attributes:
        crane_kp, crane_kd: PD gains of the crane task [1/s^2], [1/s].
        crane_weight: Weight of the crane task.
        suspension_kp, suspension_kd, suspension_weight: Suspension posture task.
        damping_weight, damping_time: Damping regularization (`DampingTask`).
        position_horizon: T of `PositionLimit` [s]; None: the control period.
        braking_fraction: Braking deceleration of `PositionLimit`, fraction of a_max.
        force_lookahead: T of `NormalForceConstraint` [s] when a force model is given.
    """

    crane_kp: float = 16.0
    crane_kd: float = 8.0
    crane_weight: float = 1.0
    suspension_kp: float = 4.0
    suspension_kd: float = 4.0
    suspension_weight: float = 0.1
    damping_weight: float = 1e-3
    damping_time: float = 0.5
    position_horizon: float | None = None
    braking_fraction: float = 0.5
    force_lookahead: float = 0.0

    def __post_init__(self):
        _positive(self, "crane_kp", "crane_kd", "crane_weight", "suspension_kp",
                  "suspension_kd", "suspension_weight", "damping_weight", "damping_time",
                  "braking_fraction")
        _positive(self, "force_lookahead", allow_zero=True)
        if self.position_horizon is not None:
            _positive(self, "position_horizon")


@dataclass(frozen=True)
class MpcConfig:
    """MPC (the ``mpc-*`` controllers).

    Attributes:
        step: Length of the steps after the first and the early ones [s].
        n_steps: N, the number of steps (the first, the early ones and the rest).
        first_step: Length of the first step [s]; None: the control period (the applied
            input then sees the constraints exactly one period ahead).
        early_steps: Lengths of the steps after the first and before the ``step``-long
            ones [s]: a finer grid where the plan must answer a sudden change (a pick's
            load swing lasts about 0.1 s, within which one ``step`` would hold one
            acceleration).
        crane_position_weight, crane_velocity_weight: Tracking weights of the crane axes,
            scalar or per axis (7,), order slew, lift, tilt, telescope, wrist pitch, roll,
            rotator.
        crane_axis_factors: Per-axis factors (7,) on both crane weights. They say which
            axis the MPC gives up first when the force constraint binds: the telescope
            (factor < 1) takes reach back at the least cost in cylinder force, where
            lowering the boom would load the lift cylinder towards its force limit.
        suspension_position_weight, suspension_velocity_weight: Suspension posture weights.
        input_weight: Inputs towards the reference acceleration.
        smoothness_weight: Input steps (discrete jerk).
        terminal_factor: Weight factor of the last node.
        n_linearizations: Force-model evaluations per tick along the horizon.
        terminal_brake_time: The force constraint also holds at the end of the horizon
            while every axis brakes to rest in this time [s]; None: no terminal rows.
        force_constraint_start: The force constraint applies to the steps starting at or
            after this time [s] (and the terminal node); 0: from step 0. Within the first
            period the forces follow from the state now: only crane accelerations could
            move them, a lever the plan must repay (see `HorizonNormalForceConstraint`).
        setpoint_state: Predict every axis from its servo setpoint and the rate commanded
            last tick, plus the low-pass filtered deflection of the stroke from the
            setpoint (none for the suspension), instead of from the measured stroke and
            velocity (`wbc.controllers.servo_state`): the measured ones carry the boom's
            bounce, and against the stiff chassis warp a suspension setpoint loads the
            wheels while its stroke hardly moves.
        deflection_time_constant: Filter of that deflection [s].
        effort_limits: Keep every crane cylinder's and drive's force within its range along
            the horizon (`wbc.constraints.HorizonEffortLimit`).
        effort_margin: Fraction of each effort range kept free: the seals' friction (1 % of
            the rated force) and what the rigid-body efforts miss while an axis accelerates
            hard (up to 10 % of the range on the slew's soft four-bar, `tests/test_efforts`).

    The horizon ``first_step + sum(early_steps) + (n_steps - 1 - len(early_steps)) step``
    must be >= 1 s.
    """

    step: float = 0.1
    n_steps: int = 12
    first_step: float | None = None
    early_steps: tuple = (0.03, 0.06)
    crane_position_weight: float = 400.0
    crane_velocity_weight: float = 20.0
    crane_axis_factors: tuple = (1.0, 4.0, 4.0, 0.01, 1.0, 1.0, 1.0)
    suspension_position_weight: float = 4.0
    suspension_velocity_weight: float = 1.0
    input_weight: float = 0.05
    smoothness_weight: float = 0.5
    terminal_factor: float = 5.0
    n_linearizations: int = 3
    terminal_brake_time: float | None = 0.5
    force_constraint_start: float = 0.0
    setpoint_state: bool = True
    deflection_time_constant: float = 0.5
    effort_limits: bool = True
    effort_margin: float = 0.10

    def __post_init__(self):
        _flags(self, "effort_limits")
        if not (isinstance(self.effort_margin, (int, float)) and 0 <= self.effort_margin < 0.5):
            raise ConfigurationError(f"effort_margin must be in [0, 0.5), got "
                                     f"{self.effort_margin!r}")
        _positive(self, "step", "n_steps", "crane_position_weight", "crane_velocity_weight",
                  "suspension_position_weight", "suspension_velocity_weight", "input_weight",
                  "n_linearizations")
        _integers(self, "n_steps", "n_linearizations")
        _positive(self, "smoothness_weight", "force_constraint_start",
                  "deflection_time_constant", allow_zero=True)
        _flags(self, "setpoint_state")
        f = _numbers(self, "crane_axis_factors", self.crane_axis_factors, 7)
        if np.any(f <= 0):
            raise ConfigurationError(f"crane_axis_factors must be 7 positive numbers, got "
                                     f"{self.crane_axis_factors}")
        object.__setattr__(self, "crane_axis_factors", tuple(float(x) for x in f))
        if not isinstance(self.early_steps, (tuple, list)):
            raise ConfigurationError(f"early_steps must be a sequence of step lengths [s], "
                                     f"got {self.early_steps!r}")
        early = _numbers(self, "early_steps", self.early_steps, len(self.early_steps))
        if np.any(early <= 0) or len(early) > self.n_steps - 1:
            raise ConfigurationError(f"early_steps must be at most n_steps - 1 = "
                                     f"{self.n_steps - 1} lengths > 0 [s], got "
                                     f"{self.early_steps!r}")
        object.__setattr__(self, "early_steps", tuple(float(x) for x in early))
        for name in ("first_step", "terminal_brake_time"):
            if getattr(self, name) is not None:
                _positive(self, name)
        _positive(self, "terminal_factor")
        if self.terminal_factor < 1:
            raise ConfigurationError(f"terminal_factor must be >= 1, got {self.terminal_factor}")

    def step_lengths(self, dt: float) -> np.ndarray:
        """Step lengths [s], shape (n_steps,), for control period ``dt``.

        Raises:
            ConfigurationError: The horizon is shorter than 1 s.
        """
        h = np.full(self.n_steps, float(self.step))
        h[0] = dt if self.first_step is None else self.first_step
        early = len(self.early_steps)
        h[1:1 + early] = self.early_steps
        if h.sum() < 1.0 - 1e-9:
            raise ConfigurationError(
                f"MPC horizon {h[0]:g} + {sum(self.early_steps):g} + "
                f"{self.n_steps - 1 - early} x {self.step:g} s = {h.sum():g} s is shorter "
                f"than 1 s")
        return h


@dataclass(frozen=True)
class ForceConfig:
    """Normal-force constraint and base-drive slow-down.

    Attributes:
        thresholds: Per-wheel f_min [N], order FL, RL, FR, RR; None: ``threshold_fraction``
            of the static wheel load (total weight / 4).
        threshold_fraction: See above.
        soft: Exact-penalty slacks (one per wheel) instead of hard rows.
        slack_linear, slack_quadratic: Penalties of the slacks (`SlackPenaltyTask`).
        speed_scale: Whether the wheel-speed scale is a decision variable.
        speed_scale_min: Its lower bound. speed_scale_rate: Its rate limit [1/s].
        speed_scale_weight: Cost of slowing down (`SpeedScaleTask`).
        drive_time_constant: tau of the base drive [s] (`wbc.drive_model`).
        margin: Added to the thresholds inside the MPC [N]: what the prediction may miss
            (terrain ahead, servo lag); the thresholds stay the figure of merit.
        feedback: MPC only: correct the horizon model by the load split measured now, the
            estimator's cylinder-force closure (`wbc.force_models.feedback`).
        warp_stiffness: MPC only: k_w of the chassis warp by the suspension setpoints
            [N/m per wheel per metre of ``s_L - s_R``]; 0: the suspension does not act on
            the load split in the model; None: derived from the machine at construction
            (`warp_stiffness_for`).
        leveling_weight: MPC only: weight of `HorizonLevelingTask` (0: off).
        leveling_limit: MPC only: largest warp change the leveling asks for at once [N].
        drift_horizon: MPC only: how far ahead the measured rate of the terrain's twist is
            extrapolated [s] (`WarpDrift`); 0: not at all.
        drift_time_constant: MPC only: low-pass filter of that rate [s].
        governor_z: MPC only: the drive's speed governor (`wbc.force_models.fluctuation`)
            keeps every wheel's slow load this many RMS load fluctuations (measured per
            unit driving speed, at the commanded speed) above its threshold; 0: off.
        governor_high_pass, governor_window: Its filters' time constants [s].
        side_reserve: MPC only (soft rows): while the machine drives, each side pair's load
            sum (FL + RL, FR + RR), which the warp does not move, keeps this much [N] above
            the pair's thresholds along the horizon (`wbc.constraints.SideReserveConstraint`,
            a contraction in ``side_reserve_time``); 0: off (unless ``side_reserve_z``).
        side_reserve_z: MPC only: the same, with the reserve ``z sigma_j`` from the swing of
            each side sum measured while driving
            (`wbc.force_models.fluctuation.SideLoadFluctuation`) where it exceeds
            ``side_reserve``; 0: off.
        side_reserve_time: Time constant [s] in which the side rows ask the plan to close a
            side's shortfall.
        side_reserve_high_pass, side_reserve_window: The measure's filters' time constants
            [s].
        side_reserve_min_speed: Below this horizontal speed [m/s] the measure is kept and
            the side rows are off.
    """

    thresholds: tuple[float, float, float, float] | None = None
    threshold_fraction: float = 0.1
    soft: bool = True
    slack_linear: float = 1e4
    slack_quadratic: float = 1e4
    speed_scale: bool = True
    speed_scale_min: float = 0.0
    speed_scale_rate: float = 0.5
    speed_scale_weight: float = 10.0
    drive_time_constant: float = 0.5
    margin: float = 0.0
    feedback: bool = True
    warp_stiffness: float | None = None
    leveling_weight: float = 1.0
    leveling_limit: float = 5000.0
    drift_horizon: float = 0.3
    drift_time_constant: float = 0.05
    governor_z: float = 2.33
    governor_high_pass: float = 0.2
    governor_window: float = 1.0
    side_reserve: float = 0.0
    side_reserve_z: float = 0.0
    side_reserve_time: float = 1.0
    side_reserve_high_pass: float = 0.2
    side_reserve_window: float = 1.0
    side_reserve_min_speed: float = 0.02

    def __post_init__(self):
        _positive(self, "slack_linear", "slack_quadratic",
                  "speed_scale_rate", "speed_scale_weight", "drive_time_constant",
                  "leveling_limit")
        _positive(self, "margin", "leveling_weight", "drift_horizon", "governor_z",
                  "side_reserve", "side_reserve_z", "side_reserve_min_speed", allow_zero=True)
        _positive(self, "side_reserve_high_pass", "side_reserve_window", "side_reserve_time")
        _flags(self, "soft", "speed_scale", "feedback")  # before `soft` is read below
        if (self.side_reserve > 0 or self.side_reserve_z > 0) and not self.soft:
            raise ConfigurationError("side_reserve or side_reserve_z > 0 needs soft force rows "
                                     "(soft=True)")
        if self.warp_stiffness is not None:
            _positive(self, "warp_stiffness", allow_zero=True)
        _positive(self, "drift_time_constant", "governor_high_pass", "governor_window")
        _positive(self, "threshold_fraction", "speed_scale_min", allow_zero=True)
        if self.thresholds is not None:
            t = _numbers(self, "thresholds", self.thresholds, 4)
            object.__setattr__(self, "thresholds", tuple(float(x) for x in t))
        if not 0 <= self.speed_scale_min < 1:
            raise ConfigurationError(f"speed_scale_min must be in [0, 1), got "
                                     f"{self.speed_scale_min}")

    def warp_stiffness_for(self, machine) -> float:
        """`warp_stiffness` if set, else derived from ``machine`` at home [N/m].

        The derivation is `wbc.force_models.feedback.warp_stiffness` (it compiles the
        machine's MuJoCo model once, ~0.1 s).
        """
        if self.warp_stiffness is not None:
            return float(self.warp_stiffness)
        return warp_stiffness(machine)

    def thresholds_for(self, machine) -> np.ndarray:
        """Per-wheel f_min of ``machine`` [N], shape (4,).

        `thresholds` if set, else ``threshold_fraction`` of the static wheel load
        (total weight / 4).
        """
        if self.thresholds is not None:
            return np.array(self.thresholds)
        return np.full(4, self.threshold_fraction * machine.total_mass * machine.gravity / 4)


@dataclass(frozen=True)
class ControllerConfig:
    """All settings of a controller.

    Attributes:
        dt: Control period [s].
        solver: ``daqp`` (default: the fastest backend that solved every QP of the
            recorded corpus, `benchmarks.bench_qp_solvers`), ``proxqp`` (warm-started
            workspace) or any other qpsolvers backend name.
        eps_abs, eps_rel: Solver tolerances.
        max_iter: Cap on the solver's outer (proximal) iterations per solve; ProxQP runs at
            most 60 inner iterations in each (`ProxQPWorkspace`), so a tick's worst case
            stays bounded (3000 iterations, ~0.25 s for the MPC's 108 variables).
        position_margin: Fraction of each position range kept free at both ends.
        reference, qp, mpc, force: Sub-settings.
    """

    dt: float = 0.01
    solver: str = "daqp"
    eps_abs: float = 1e-7
    eps_rel: float = 0.0
    max_iter: int = 50
    position_margin: float = 0.01
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    qp: QPConfig = field(default_factory=QPConfig)
    mpc: MpcConfig = field(default_factory=MpcConfig)
    force: ForceConfig = field(default_factory=ForceConfig)

    def __post_init__(self):
        _positive(self, "dt", "eps_abs")
        _integers(self, "max_iter")
        _positive(self, "eps_rel", "position_margin", allow_zero=True)
        for f, cls in (("reference", ReferenceConfig), ("qp", QPConfig), ("mpc", MpcConfig),
                       ("force", ForceConfig)):
            if not isinstance(getattr(self, f), cls):
                raise ConfigurationError(f"ControllerConfig.{f} must be a {cls.__name__}")
        if not isinstance(self.solver, str):
            raise ConfigurationError(f"solver must be a name, got {self.solver!r}")
        self.mpc.step_lengths(self.dt)  # the horizon must reach 1 s
