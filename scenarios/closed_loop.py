"""Closed-loop scenarios: a controller drives the MuJoCo machine at 100 Hz on rough slopes.

Each scenario runs with each controller (``tracking``, ``mpc-quasi-static``, ``mpc-full``) on
the same terrain and seed. The controller sees only `Simulator.measure`'s state (optionally
with `MeasurementNoise` and a delay of whole control periods); the metrics use MuJoCo's
ground-truth contacts. The base follows scripted wheel speeds (the operator's), which the
MPC may scale down (`ControlCommand.wheel_speeds`); the tracking controller's scale is 1.

Scenarios (`SCENARIOS`; terrain: the seeded rough terrain of `models.terrain.rough` with the
given largest slope, added to the side slope of `models.terrain.side_slope`, left side down):

* ``swing-out`` (the default): the machine drives 6 m across a 5 deg side slope with 10 deg
  rough terrain at 0.4 m/s while the crane swings the payload (150 kg) from its transport
  pose out to full reach (slew 45 deg, lift 20 deg, tilt -40 deg, telescope 1.08 m) on the
  downhill side.
* ``pick-place-slope``: standing 8 m out (where the rough terrain is fully developed) on a
  5 deg side slope with 5 deg rough terrain, the crane reaches out to full reach on the
  downhill side (pick), waits 1 s, and swings the payload over to full reach on the uphill
  side (place).
* ``pick-in-motion``: driving 5 m at 0.3 m/s across the 5 deg side slope with 10 deg rough
  terrain, with the crane out on the downhill side (slew 45, lift 30, tilt -60 deg,
  telescope 0.6 m) and an empty grapple (10 kg); at 3 s it grabs a 220 kg log (the payload
  body's mass is changed in MuJoCo) and brings it to the transport pose.

The crane motions follow the operator's profile ``crane_speed`` = (60 %, 20 %) of the axis
velocity and acceleration limits, the same reference for the three controllers.

Why a controller that only tracks gets into trouble here (measured, `wbc.force_models.
feedback`): the suspension servos are stiff, so with the strokes held the chassis cannot
follow the terrain's twist and the crane's moment at long reach takes the load off one
wheel of a diagonal (statically: full reach at 45 deg on flat ground leaves RR at 0 kN held,
5.1 kN with the chassis leveled); the rough ground twists the chassis by 20-40 kN/s at
0.4 m/s; crane swings at long reach load the wheels by up to ~10 kN per m/s^2 of slew
stroke acceleration.

The payload event: the estimators are built from the machine description (payload
included), so the MPC is told the new mass by swapping in estimators of
``build_reference_machine(payload_mass=...)``, built before the run (the compiled kernels
are cached per machine), at the pick instant (`MpcController.set_force_model`).

Metrics (`metrics.json`), all after `SETTLE_SECONDS`:

* ``min_normal_force_N``, ``time_below_threshold_s``: per wheel (FL, RL, FR, RR), ground
  truth along the terrain normal, sampled at the control rate; ``threshold_N`` = 10 % of the
  static wheel load of the reference machine (150 kg payload).
* ``tipped``: fewer than three wheels in contact for more than `TIP_CONTACT_SECONDS`
  without a break, or base roll or pitch beyond `TIP_ANGLE_DEG`.
* ``task_error_final``: distance of the tool point from the last goal's [m] at the end;
  ``task_completion_time_s``: first time every goal has been given, the tool point is
  within `TASK_TOLERANCE` of the last one and the base has driven its distance (None if
  never); ``task_completed``.
* ``control_step_ms``: median and p99 of the controller's ``step`` wall time;
  ``fallbacks``; ``sim_seconds``, ``wall_seconds``, ``real_time_factor``.
"""

from __future__ import annotations

import json
import math
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models import build_reference_machine
from models.description import WHEEL_ORDER, Machine
from models.log import ScenarioLog
from models.terrain import Terrain, rough, side_slope
from scenarios.progress import Progress
from scenarios.simulator import MeasurementNoise, Simulator
from wbc import (
    CONTROLLER_NAMES,
    ControllerConfig,
    ForceConfig,
    JointGoal,
    MpcController,
    ReferenceConfig,
    TcpKinematics,
    make_controller,
)
from wbc.controllers.registry import estimator_models

__all__ = ["CONTROL_PERIOD", "DEFAULT_SCENARIO", "SCENARIOS", "ClosedLoopScenario",
           "CranePose", "controller_config", "run_closed_loop", "run_comparison",
           "scenario_terrain", "threshold"]

CONTROL_PERIOD = 0.01  # [s] 100 Hz
SETTLE_SECONDS = 1.0  # metrics skip the first second
TASK_TOLERANCE = 0.05  # [m] tool point within this of its goal
TIP_CONTACT_SECONDS = 0.5  # fewer than three wheels in contact this long: tipped
TIP_ANGLE_DEG = 30.0  # base roll or pitch beyond this: tipped
DRIVE_RAMP_SECONDS = 1.0  # the scripted wheel speeds ramp up smoothly over this
THRESHOLD_FRACTION = 0.1  # of the reference machine's static wheel load
DEFAULT_SCENARIO = "swing-out"


@dataclass(frozen=True)
class CranePose:
    """A crane pose by joint angles; the wrist pitch keeps the tool vertical.

    Attributes:
        slew_deg: Slew angle [deg], positive to the left, within about +-69 deg.
        lift_deg, tilt_deg: Lift and tilt joint angles [deg].
        telescope: Telescope extension [m].
    """

    slew_deg: float
    lift_deg: float
    tilt_deg: float
    telescope: float

    def coordinates(self, machine: Machine) -> np.ndarray:
        """The seven crane coordinates (strokes, telescope, wrist), shape (7,)."""
        ch = machine.chains
        return np.array([
            ch["slew"].chain.stroke_from_angle(math.radians(self.slew_deg)),
            ch["lift"].chain.stroke_from_angle(math.radians(self.lift_deg)),
            ch["tilt"].chain.stroke_from_angle(math.radians(self.tilt_deg)),
            self.telescope, -math.radians(self.lift_deg + self.tilt_deg), 0.0, 0.0])

    def q(self, machine: Machine) -> np.ndarray:
        """Independent coordinates at home with this crane pose, shape (13,)."""
        q = machine.coordinates.home()
        q[2:9] = self.coordinates(machine)
        return q


TRANSPORT = CranePose(0.0, 45.0, -90.0, 0.5)  # the home pose: folded over the chassis


@dataclass(frozen=True)
class ClosedLoopScenario:
    """A closed-loop scenario.

    Attributes:
        name, description: For humans and the command line.
        duration: Simulated time [s].
        side_slope_deg: Side slope [deg]; negative: the left (+y) side is down.
        rough_slope_deg: Largest slope of the added rough terrain [deg]; 0: none.
        start_pose: Crane pose at the start.
        goals: Crane poses given one after the other: the first at ``first_goal_time``,
            each next one ``dwell`` after the tool point has reached the previous one.
        first_goal_time: [s].
        dwell: [s].
        drive_speed: Scripted driving speed [m/s] (both sides), ramped up over
            `DRIVE_RAMP_SECONDS`; 0: standing.
        drive_distance: Distance the base must cover for the task [m].
        payload_mass: Payload at the start [kg].
        payload_event: (time [s], new payload mass [kg]) or None.
        start: Base (x [m], y [m], heading [rad]) at the start. The rough terrain is level
            within 3 m of the origin (`models.terrain.rough`), so a machine that does not
            drive starts farther out.
        crane_speed: (velocity, acceleration) fractions of the axis limits the operator's
            motions (the controllers' references) use.
    """

    name: str
    description: str
    duration: float
    side_slope_deg: float
    rough_slope_deg: float
    start_pose: CranePose
    goals: tuple[CranePose, ...]
    first_goal_time: float = 1.0
    dwell: float = 1.0
    drive_speed: float = 0.0
    drive_distance: float = 0.0
    payload_mass: float = 150.0
    payload_event: tuple[float, float] | None = None
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    crane_speed: tuple[float, float] = (0.6, 0.2)

    def wheel_speed(self, t: float, radius: float) -> float:
        """The operator's wheel speed at time ``t`` [rad/s] (both sides)."""
        ramp = min(max(t / DRIVE_RAMP_SECONDS, 0.0), 1.0)
        return self.drive_speed / radius * ramp * ramp * (3.0 - 2.0 * ramp)


FULL_REACH_LEFT = CranePose(45.0, 20.0, -40.0, 1.08)

SCENARIOS = {
    "swing-out": ClosedLoopScenario(
        "swing-out",
        "drive 6 m at 0.4 m/s across a 5 deg side slope with 10 deg rough terrain while "
        "the crane swings 150 kg out to full reach on the downhill side",
        20.0, -5.0, 10.0, TRANSPORT, (FULL_REACH_LEFT,), first_goal_time=1.0,
        drive_speed=0.4, drive_distance=6.0),
    "pick-place-slope": ClosedLoopScenario(
        "pick-place-slope",
        "standing 8 m out on a 5 deg side slope with 5 deg rough terrain: pick at full "
        "reach downhill, place at full reach uphill (150 kg)",
        16.0, -5.0, 5.0, TRANSPORT,
        (FULL_REACH_LEFT, CranePose(-45.0, 20.0, -40.0, 1.08)), first_goal_time=1.0,
        dwell=1.0, start=(8.0, 0.0, 0.0)),
    "pick-in-motion": ClosedLoopScenario(
        "pick-in-motion",
        "drive 5 m at 0.3 m/s across a 5 deg side slope with 10 deg rough terrain; at 3 s "
        "the grapple, out on the downhill side, grabs a 220 kg log and brings it in",
        20.0, -5.0, 10.0, CranePose(45.0, 30.0, -60.0, 0.6), (TRANSPORT,),
        first_goal_time=3.5, drive_speed=0.3, drive_distance=5.0, payload_mass=10.0,
        payload_event=(3.0, 220.0)),
}


def threshold() -> float:
    """The normal-force threshold of the metrics [N]: 10 % of the static wheel load."""
    return float(ForceConfig(threshold_fraction=THRESHOLD_FRACTION)
                 .thresholds_for(build_reference_machine())[0])


def controller_config(threshold_n: float | None = None,
                      crane_speed: tuple[float, float] = (0.6, 0.2)) -> ControllerConfig:
    """The settings every closed-loop scenario runs its controllers with.

    The reference (the operator's motion profile, the same for all three controllers) uses
    ``crane_speed`` = (60 %, 20 %) of the axis velocity and acceleration limits by default:
    a heavy crane at long reach, whose lift cylinder is at 75-85 % of its force statically
    (the description's limits allow 3 rad/s^2 of slew). The MPC keeps ``margin = 1.5 kN``
    above the threshold for what it cannot predict (terrain ahead), and levels the chassis
    through the suspension with weight 10.
    """
    thr = threshold() if threshold_n is None else float(threshold_n)
    return ControllerConfig(
        reference=ReferenceConfig(velocity_fraction=crane_speed[0],
                                  acceleration_fraction=crane_speed[1]),
        force=ForceConfig(thresholds=(thr, thr, thr, thr), margin=1500.0,
                          leveling_weight=10.0))


def scenario_terrain(scenario: ClosedLoopScenario, seed: int = 0) -> Terrain:
    """The side slope plus the seeded rough terrain, on the rough terrain's grid."""
    spacing = 0.25
    side = side_slope(scenario.side_slope_deg, spacing=spacing) if scenario.side_slope_deg \
        else None
    if scenario.rough_slope_deg > 0:
        base = rough(seed, scenario.rough_slope_deg, spacing=spacing)
        heights = base.heights + (side.heights if side is not None else 0.0)
        return Terrain("rough_side_slope", heights, base.x_range, base.y_range,
                       base.friction)
    if side is None:
        raise ValueError(f"scenario '{scenario.name}' has neither a side slope nor rough "
                         f"terrain")
    return side


def _set_payload(sim: Simulator, mass: float) -> None:
    """Change the payload body's mass in MuJoCo (inertia scaled alike).

    MuJoCo reads ``body_mass`` and ``body_inertia`` at every step (composite inertias,
    gravity), so the change takes effect at the next step. ``mj_setConst`` must not be
    called: it recomputes the loop closures' anchors from ``qpos0`` and the crane
    collapses.
    """
    body = sim.model.body(sim.machine.payload)
    old = float(body.mass[0])
    sim.model.body_mass[body.id] = mass
    sim.model.body_inertia[body.id] *= mass / old


def _roll_pitch(rotation: np.ndarray) -> tuple[float, float]:
    """Roll and pitch of the base [rad] (ZYX Euler angles of world <- fb)."""
    return (math.atan2(rotation[2, 1], rotation[2, 2]),
            -math.asin(max(-1.0, min(1.0, rotation[2, 0]))))


def _longest_run(mask: np.ndarray) -> int:
    best = run = 0
    for v in mask:
        run = run + 1 if v else 0
        best = max(best, run)
    return best


@dataclass
class _GoalSequence:
    """Gives the scenario's goals one after the other (the operator)."""

    goals: list
    first_time: float
    dwell: float
    index: int = -1
    reached_at: float | None = None

    def update(self, t: float, tcp_error: float) -> JointGoal | None:
        """The next goal when it is due, else None."""
        if self.index < 0:
            if t >= self.first_time - 1e-9:
                self.index = 0
                return self.goals[0]
            return None
        if tcp_error < TASK_TOLERANCE:
            if self.reached_at is None:
                self.reached_at = t
            if self.index + 1 < len(self.goals) and t - self.reached_at >= self.dwell - 1e-9:
                self.index += 1
                self.reached_at = None
                return self.goals[self.index]
        else:
            self.reached_at = None
        return None

    @property
    def last_given(self) -> bool:
        return self.index == len(self.goals) - 1


def run_closed_loop(scenario: ClosedLoopScenario | str, out_dir: Path | None = None,
                    controller: str = "mpc-full", seed: int = 0,
                    duration: float | None = None, progress: bool = False,
                    noise: MeasurementNoise | None = None, delay_periods: int = 0,
                    config: ControllerConfig | None = None,
                    inform_payload: bool = True) -> dict:
    """Run a closed-loop scenario; write ``log.npz`` and ``metrics.json`` to ``out_dir``.

    Args:
        scenario: A `ClosedLoopScenario` or its name.
        out_dir: Output folder; None: write nothing.
        controller: ``tracking``, ``mpc-quasi-static`` or ``mpc-full``.
        seed: Terrain seed.
        duration: Override the scenario's duration [s].
        progress: Show a progress bar.
        noise: Measurement noise of the state the controller sees.
        delay_periods: The controller sees the state of this many control periods ago.
        config: Controller settings; `controller_config` if None.
        inform_payload: Tell the MPC the new payload mass at the payload event.

    Returns:
        The metrics (also written to ``metrics.json``).
    """
    if isinstance(scenario, str):
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown closed-loop scenario '{scenario}'; valid: "
                             f"{', '.join(sorted(SCENARIOS))}")
        scenario = SCENARIOS[scenario]
    if controller not in CONTROLLER_NAMES:
        raise ValueError(f"unknown controller '{controller}'; valid: "
                         f"{', '.join(CONTROLLER_NAMES)}")
    duration = scenario.duration if duration is None else float(duration)
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be a positive number of seconds, got {duration}")
    if isinstance(delay_periods, bool) or not isinstance(delay_periods, int) \
            or delay_periods < 0:
        raise ValueError(f"delay_periods must be an integer >= 0, got {delay_periods!r}")
    thr = threshold()
    config = controller_config(thr, scenario.crane_speed) if config is None else config
    machine = build_reference_machine(payload_mass=scenario.payload_mass)
    terrain = scenario_terrain(scenario, seed)
    sim = Simulator(machine, terrain, noise=noise)
    sim.reset(scenario.start_pose.q(machine), scenario.start)
    n_sub = int(round(CONTROL_PERIOD / sim.timestep))
    ctrl = make_controller(controller, machine, config)
    new_models = None
    if scenario.payload_event is not None and isinstance(ctrl, MpcController) \
            and inform_payload:
        heavy = build_reference_machine(payload_mass=scenario.payload_event[1])
        new_models = estimator_models(heavy, controller.removeprefix("mpc-"))
    kin = TcpKinematics(machine)
    goals = _GoalSequence([JointGoal(crane=p.coordinates(machine)) for p in scenario.goals],
                          scenario.first_goal_time, scenario.dwell)
    tcp_goal = kin.position(scenario.start_pose.q(machine))
    x0 = sim.measure()[0].base_position.copy()
    heading = sim.measure()[0].base_rotation[:, 0].copy()
    log = ScenarioLog(scenario=scenario.name, controller=controller, seed=seed,
                      payload_mass=scenario.payload_mass, timestep=sim.timestep,
                      control_period=CONTROL_PERIOD, terrain=terrain.name, threshold=thr,
                      delay_periods=delay_periods)
    history: deque = deque(maxlen=delay_periods + 1)
    n_ticks = int(round(duration / CONTROL_PERIOD))
    step_s = np.zeros(n_ticks)
    fallbacks = 0
    payload_done = scenario.payload_event is None
    wall0 = time.perf_counter()
    with Progress(duration, f"{scenario.name}/{controller}",
                  enabled=None if progress else False) as bar:
        for k in range(n_ticks):
            state, truth = sim.measure()
            t = state.time
            if not payload_done and t >= scenario.payload_event[0] - 1e-9:
                _set_payload(sim, scenario.payload_event[1])
                if new_models is not None:
                    ctrl.set_force_model(*new_models)
                payload_done = True
            tcp_err = float(np.linalg.norm(kin.position(_true_q(sim, state)) - tcp_goal))
            new_goal = goals.update(t, tcp_err)
            if new_goal is not None:
                ctrl.set_goal(new_goal)
                goal_q_full = _true_q(sim, state).copy()
                goal_q_full[2:9] = new_goal.crane
                tcp_goal = kin.position(goal_q_full)
                tcp_err = float(np.linalg.norm(kin.position(_true_q(sim, state)) - tcp_goal))
            history.append(state)
            t0 = time.perf_counter()
            cmd = ctrl.step(history[0])
            step_s[k] = time.perf_counter() - t0
            fallbacks += int(cmd.fallback)
            w = scenario.wheel_speed(t, machine.wheel_radius)
            wheels = cmd.wheel_speeds(w, w)
            sim.set_command(cmd.cylinder_rates, cmd.wrist_rates, wheels)
            info = cmd.info
            log.append(state, truth, np.concatenate([cmd.rates, wheels]),
                       sim.closure_violation(),
                       tcp_error=tcp_err, goal_index=goals.index,
                       last_goal_given=goals.last_given,
                       distance=float((state.base_position - x0) @ heading),
                       speed_scale=cmd.wheel_speed_scale, fallback=cmd.fallback,
                       step_ms=1e3 * step_s[k],
                       measured_forces=info.get("measured_forces", np.full(4, np.nan)),
                       payload_now=(scenario.payload_event[1] if scenario.payload_event
                                    and payload_done else scenario.payload_mass))
            sim.step(n_sub)
            if k % 50 == 0:
                bar.update(sim.time)
        bar.update(duration)
    wall = time.perf_counter() - wall0
    arrays = log.arrays()
    metrics = {
        "scenario": scenario.name, "description": scenario.description,
        "controller": controller, "terrain": terrain.name, "seed": seed,
        "noise": None if noise is None else vars(noise),
        "delay_periods": delay_periods,
        "control_period_s": CONTROL_PERIOD,
        "sim_seconds": float(n_ticks * CONTROL_PERIOD),
        "wall_seconds": wall,
        "real_time_factor": float(n_ticks * CONTROL_PERIOD / wall),
        "threshold_N": thr,
        **closed_loop_metrics(arrays, scenario, thr),
        "control_step_ms": {"median": float(1e3 * np.median(step_s)),
                            "p99": float(1e3 * np.percentile(step_s, 99)),
                            "max": float(1e3 * step_s.max())},
        "fallbacks": fallbacks,
    }
    if out_dir is not None:
        out_dir = Path(out_dir)
        log.save(out_dir / "log.npz")
        (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=2, default=_json))
    return metrics


def _true_q(sim: Simulator, state) -> np.ndarray:
    """Ground-truth independent coordinates, strokes clipped into their chains' ranges.

    The measured state may be noisy; MuJoCo's soft joint limits let a stroke pass its end
    by a little, which the kinematics reject.
    """
    if sim.noise is None:
        q = state.q.copy()
    else:
        qpos, _, _ = sim.measured_instant
        q = qpos[sim.index.independent_qpos]
    for i, name in enumerate(sim.index.independent_names[:9]):
        if name in sim.machine.chains:
            lo, hi = sim.machine.chains[name].chain.stroke_range
            q[i] = min(max(q[i], lo), hi)
    return q


def _json(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serializable: {type(o)}")


def closed_loop_metrics(log: dict, scenario: ClosedLoopScenario, threshold_n: float) -> dict:
    """The scenario metrics from a closed-loop log (see the module docstring)."""
    t = log["time"]
    dt = float(np.median(np.diff(t))) if t.size > 1 else CONTROL_PERIOD
    keep = t >= SETTLE_SECONDS - 1e-9
    if not keep.any():  # a run shorter than the settling: judge all of it
        keep = np.ones_like(keep)
    fz = log["normal_force"][keep]
    per_wheel = lambda a: {w: float(v) for w, v in zip(WHEEL_ORDER, a)}  # noqa: E731
    n_contact = log["in_contact"].sum(axis=1)
    roll_pitch = np.array([_roll_pitch(r) for r in log["base_rotation"]])
    tipped_contact = _longest_run(n_contact[keep] < 3) * dt > TIP_CONTACT_SECONDS
    tipped_angle = bool(np.any(np.abs(roll_pitch) > math.radians(TIP_ANGLE_DEG)))
    err = log["tcp_error"]
    done = (log["last_goal_given"].astype(bool) & (err < TASK_TOLERANCE)
            & (log["distance"] >= scenario.drive_distance - 1e-9))
    first = np.flatnonzero(done)
    completion = float(t[first[0]]) if first.size else None
    return {
        "min_normal_force_N": per_wheel(fz.min(axis=0)),
        "time_below_threshold_s": per_wheel((fz < threshold_n).sum(axis=0) * dt),
        "tipped": bool(tipped_contact or tipped_angle),
        "max_roll_deg": float(np.degrees(np.abs(roll_pitch[:, 0]).max())),
        "max_pitch_deg": float(np.degrees(np.abs(roll_pitch[:, 1]).max())),
        "longest_below_3_contacts_s": float(_longest_run(n_contact[keep] < 3) * dt),
        "task_error_final": float(err[-1]),
        "task_completion_time_s": completion,
        "task_completed": bool(completion is not None and err[-1] < TASK_TOLERANCE),
        "drive_distance_m": float(log["distance"][-1]),
        "drive_distance_target_m": scenario.drive_distance,
        "min_wheel_speed_scale": float(log["speed_scale"].min()),
        "mean_wheel_speed_scale": float(log["speed_scale"].mean()),
        "task_tolerance_m": TASK_TOLERANCE,
        "settle_seconds": SETTLE_SECONDS,
    }


def acceptance(results: dict) -> dict:
    """The issue's acceptance checks on one scenario's metrics by controller."""
    full, trk = results.get("mpc-full"), results.get("tracking")
    out = {}
    if full is not None:
        out["mpc_full_never_below_threshold"] = all(
            v == 0.0 for v in full["time_below_threshold_s"].values())
        out["mpc_full_not_tipped"] = not full["tipped"]
        out["mpc_full_completes_task"] = full["task_completed"]
    if trk is not None:
        out["tracking_below_threshold_or_tipped"] = bool(
            trk["tipped"] or any(v > 0 for v in trk["time_below_threshold_s"].values()))
    if full is not None and trk is not None:
        tf, tt = full["task_completion_time_s"], trk["task_completion_time_s"]
        out["task_time_ratio_full_over_tracking"] = (None if tf is None or tt is None
                                                     else tf / tt)
        out["mpc_full_within_30_percent_of_tracking"] = bool(
            tf is not None and (tt is None or tf <= 1.3 * tt))
    out["all_met"] = all(v for k, v in out.items() if isinstance(v, bool))
    return out


def run_comparison(scenario: str = DEFAULT_SCENARIO, out_root: Path = Path("out/compare"),
                   duration: float | None = None, seed: int = 0,
                   progress: bool = False) -> dict:
    """Run the three controllers on ``scenario`` (same terrain and seed).

    Writes ``out_root/<controller>/{log.npz, metrics.json}``, ``out_root/forces.png``
    (`plot_comparison`) and ``out_root/comparison.json`` (metrics by controller and the
    acceptance checks).

    Returns:
        The content of ``comparison.json``.
    """
    from scenarios.closed_loop_plots import plot_comparison

    out_root = Path(out_root)
    results, dirs = {}, {}
    for name in CONTROLLER_NAMES:
        dirs[name] = out_root / name
        results[name] = run_closed_loop(scenario, dirs[name], name, seed=seed,
                                        duration=duration, progress=progress)
    png = plot_comparison(dirs, out_root / "forces.png")
    report = {"scenario": scenario, "seed": seed, "plot": str(png),
              "metrics": results, "acceptance": acceptance(results)}
    (out_root / "comparison.json").write_text(json.dumps(report, indent=2, default=_json))
    return report
