"""Closed-loop runs: a controller drives the MuJoCo machine at 100 Hz on rough slopes.

By default the controller sees only what the machine's sensors report, through the observer
(`scenarios.sensing`: ``sensors="realistic"``; ``ideal`` without sensor errors; ``oracle``:
`Simulator.measure`'s exact state, optionally with `MeasurementNoise`), optionally delayed by
whole control periods. The MPC keeps each wheel's force above the threshold plus ``z sigma``
of its uncertainty (`uncertainty_margin`), with the payload the observer estimates (or,
with the oracle, the one it is told at the payload event); the operator's grapple command
before a pick (`ClosedLoopScenario.grapple_close_time`) reaches the observer, which then
takes a growing mass for a pick sooner (`Sensing.expect_pick`). The log's state columns and the
metrics (`scenarios.metrics`) are MuJoCo's ground truth. The scenarios are in
`scenarios.closed_loop_scenarios`, the comparison of the three controllers in
`scenarios.comparison`.
"""

from __future__ import annotations

import contextlib
import gc
import math
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimators.uncertainty import closure_margin, prepare_margin
from models import build_reference_machine
from models.log import ScenarioLog
from scenarios.closed_loop_scenarios import (
    CONTROL_PERIOD,
    DEFAULT_SCENARIO,
    SCENARIOS,
    TASK_TOLERANCE,
    ClosedLoopScenario,
    controller_config,
    scenario_terrain,
    threshold,
)
from scenarios.commands import ActuatorCommand
from scenarios.errors import RunInputError, RunInterrupted
from scenarios.json_io import write_json
from scenarios.kernels import warm_estimator_kernels
from scenarios.metrics import closed_loop_metrics, margin_coverage
from scenarios.noise import MeasurementNoise
from scenarios.physics_rate import NormalForceRecorder
from scenarios.progress import Progress
from scenarios.run_args import check_delay, check_duration, check_seed, check_threshold
from scenarios.scenario_file import scenario_to_toml
from scenarios.sensing import Sensing, check_sensors
from scenarios.simulator import Simulator
from scenarios.startup import READY_TIMEOUT_SECONDS, Readiness
from scenarios.truth_log import TRUTH_COLUMNS, TruthColumns
from wbc import (
    CONTROLLER_NAMES,
    ControllerConfig,
    JointGoal,
    MpcController,
    TcpKinematics,
    make_controller,
)
from wbc.pick_reserve import PickReserve

# DEFAULT_SCENARIO and SCENARIOS are re-exported: callers pick a scenario here by name.
__all__ = ["DEFAULT_SCENARIO", "FORCE_CONFIDENCE", "SCENARIOS", "run_closed_loop",
           "uncertainty_margin"]

FORCE_CONFIDENCE = 0.99  # one-sided: z = 2.33 standard deviations of each wheel's force
_NO_FORCES = np.full(4, np.nan)  # the log's measured forces of a controller without them
_NO_FORCES.flags.writeable = False
_NO_MARGIN = np.zeros(4)  # the force margin of a controller without one [N]
_NO_MARGIN.flags.writeable = False
# The loop's own columns of the log (beside the truth's, `scenarios.truth_log`), in the
# order `ScenarioLog.append` wrote them: name, row shape, dtype.
_LOOP_COLUMNS = (("command", (11,), float), ("tcp_error", (), float), ("goal_index", (), int),
                 ("last_goal_given", (), bool), ("distance", (), float),
                 ("speed_scale", (), float), ("fallback", (), bool), ("step_ms", (), float),
                 ("measured_forces", (4,), float), ("payload_now", (), float),
                 ("payload_estimate", (), float), ("force_margin", (4,), float),
                 ("observer_ms", (), float))
_LOG_ORDER = (*TRUTH_COLUMNS[:8], "command", *TRUTH_COLUMNS[8:-1],  # as `append` had them
              *(name for name, _, _ in _LOOP_COLUMNS[1:9]), "com_world",
              *(name for name, _, _ in _LOOP_COLUMNS[9:]))


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


@contextlib.contextmanager
def frozen_heap():
    """The objects alive before a control loop kept out of the garbage collector's passes.

    Python's oldest-generation collection walks every tracked object: with the models,
    kernels and solvers of a run loaded that took 28 ms inside one control tick (measured:
    `random` draw 6 of master seed 1, a 32 ms tick; the 10 ms period broken in 4 of 20
    runs). `gc.freeze` moves them to a permanent generation for the loop (what the loop makes
    is still collected); `gc.unfreeze` hands them back after it.
    """
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def run_closed_loop(scenario: ClosedLoopScenario | str, out_dir: Path | None = None,
                    controller: str = "mpc-full", seed: int = 0,
                    duration: float | None = None, progress: bool = False,
                    noise: MeasurementNoise | None = None, delay_periods: int = 0,
                    config: ControllerConfig | None = None,
                    inform_payload: bool = True, threshold_n: float | None = None,
                    sensors: str = "realistic", sensor_seed: int | None = None,
                    confidence: float = FORCE_CONFIDENCE, pick_reserve: bool = False) -> dict:
    """Run a closed-loop scenario; write ``log.npz`` and ``metrics.json`` to ``out_dir``.

    Args:
        scenario: A `ClosedLoopScenario` or its name.
        out_dir: Output folder; None: write nothing.
        controller: ``tracking``, ``mpc-quasi-static`` or ``mpc-full``.
        seed: Terrain seed.
        duration: Override the scenario's duration [s].
        progress: Show a progress bar.
        noise: Measurement noise of the oracle state (``sensors="oracle"`` only).
        delay_periods: The controller sees the state of this many control periods ago.
        config: Controller settings; `controller_config` if None.
        inform_payload: ``oracle`` only: tell the MPC the new payload mass at the payload
            event (with sensors the observer estimates it; the payload is never told).
        threshold_n: Normal-force threshold of the metrics and the controllers [N];
            `threshold` (10 % of the static wheel load) if None. Ignored by the controllers
            when ``config`` is given.
        sensors: ``realistic`` (default), ``ideal`` or ``oracle`` (`scenarios.sensing`).
        sensor_seed: Seed of the sensors' errors; None: ``seed``.
        confidence: The MPC keeps each wheel's force above its threshold plus ``z sigma``
            of the force's uncertainty, ``z`` of this one-sided confidence
            (`estimators.uncertainty.force_margin`).
        pick_reserve: The MPC controllers arm the pick reserve at the operator's grapple
            command before a pick (`wbc.pick_reserve`). Off by default: on the held-out
            heavy-pick draws it left 3 of 30 below the threshold against 1 without it
            (`docs/sweeps.md`).

    Returns:
        The metrics (also written to ``metrics.json``), with ``"partial": False``.

    Raises:
        ValueError: Unknown scenario or controller.
        RunInputError: ``duration``, ``seed``, ``delay_periods`` or ``threshold_n`` outside
            its range (`scenarios.run_args`).
        RunInterrupted: Ctrl-C during the run; the log and metrics so far were written
            (``"partial": True``).
    """
    if isinstance(scenario, str):
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown closed-loop scenario '{scenario}'; valid: "
                             f"{', '.join(sorted(SCENARIOS))}")
        scenario = SCENARIOS[scenario]
    if controller not in CONTROLLER_NAMES:
        raise ValueError(f"unknown controller '{controller}'; valid: "
                         f"{', '.join(CONTROLLER_NAMES)}")
    duration = check_duration(duration, scenario.duration)
    seed = check_seed(seed)
    delay_periods = check_delay(delay_periods)
    machine = build_reference_machine(payload_mass=scenario.payload_mass)
    thr = threshold() if threshold_n is None else check_threshold(
        threshold_n, machine.total_mass * machine.gravity / 4)
    config = controller_config(thr, scenario.crane_speed) if config is None else config
    terrain = scenario_terrain(scenario, seed)
    sensors = check_sensors(sensors)
    if noise is not None and sensors != "oracle":
        raise RunInputError("measurement noise applies to the oracle state only "
                            "(sensors='oracle'); the sensor suites have their own errors")
    sim = Simulator(machine, terrain, noise=noise)
    sim.reset(scenario.start_pose.q(machine), scenario.start)
    n_sub = int(round(CONTROL_PERIOD / sim.timestep))
    # Compile before the clock starts (and before the controller and the observer, whose
    # force models load the kernels when built, so that a compile is announced): every
    # payload is a run-time input of one machine's kernels (estimators.payload), so nothing
    # compiles in the loop.
    warm_estimator_kernels(list(_payload_machines(machine)),
                           notice=_notice if progress else None)
    ctrl = make_controller(controller, machine, config)
    sensing = Sensing(sim, machine, sensors, seed if sensor_seed is None else sensor_seed)
    mpc = isinstance(ctrl, MpcController)
    if mpc:  # the margin's first-call buffers now, not in the first tick
        prepare_margin(_closure(ctrl), ctrl.force_model)
    kin = TcpKinematics(machine)
    goals = _GoalSequence([JointGoal(crane=p.coordinates(machine)) for p in scenario.goals],
                          scenario.first_goal_time, scenario.dwell)
    tcp_goal = kin.position(scenario.start_pose.q(machine))
    x0 = sim.measure()[0].base_position.copy()
    heading = sim.measure()[0].base_rotation[:, 0].copy()  # the truth: the task's own measure
    log = ScenarioLog(scenario=scenario.name, controller=controller, seed=seed,
                      payload_mass=scenario.payload_mass, timestep=sim.timestep,
                      control_period=CONTROL_PERIOD, terrain=terrain.name, threshold=thr,
                      delay_periods=delay_periods, scenario_toml=scenario_to_toml(scenario))
    recorder = NormalForceRecorder(sim)
    history: deque = deque(maxlen=delay_periods + 1)
    readiness = Readiness(machine, thr)
    n_ticks = int(round(duration / CONTROL_PERIOD))
    n_max = n_ticks + int(round(READY_TIMEOUT_SECONDS / CONTROL_PERIOD))
    truth = TruthColumns(sim, n_max)  # the log's rows, filled in place
    rows = {name: np.zeros((n_max, *shape), dtype) for name, shape, dtype in _LOOP_COLUMNS}
    # the columns by name once, not by a dict look-up per write
    (row_command, row_tcp_error, row_goal_index, row_last_goal_given, row_distance,
     row_speed_scale, row_fallback, row_step_ms, row_measured_forces, row_payload_now,
     row_payload_estimate, row_force_margin, row_observer_ms) = rows.values()
    truth_time, truth_position, true_q = truth.columns["time"], \
        truth.columns["base_position"], truth.true_q
    n_done = 0
    step_s = np.zeros(n_max)
    fallbacks = 0
    payload_done = scenario.payload_event is None
    grapple_at = scenario.grapple_close_time()
    grapple_closed = False
    reserve = (PickReserve(machine, thr) if pick_reserve and mpc and grapple_at is not None
               else None)
    interrupted = False
    ready, offset = False, 0.0  # `readiness`'s answer and clock offset, fixed once ready
    with Progress(duration, f"{scenario.name}/{controller}",
                  enabled=None if progress else False) as bar, frozen_heap():
        # The loop's clock starts after the heap's freeze (a full collection, 50-60 ms once
        # per run): set-up, like building the simulator and the controller.
        wall0 = time.perf_counter()
        try:
            for k in range(n_max):
                truth.record(k)
                t = float(truth_time[k])
                obs = sensing.observe(t)
                if not ready:  # once ready, it stays (`Readiness.update`): not asked again
                    readiness.set_payload(obs.payload_mass)
                    ready = readiness.update(obs.state)
                    offset = readiness.offset
                tau = t - offset  # the scenario's clock
                if ready and tau >= duration - 1e-9:
                    break
                if not ready:
                    tau = -1.0  # the operator waits: no goal, no driving, no event yet
                told = None
                if not grapple_closed and grapple_at is not None and not payload_done \
                        and tau >= grapple_at - 1e-9:  # the operator's grapple command
                    grapple_closed = True
                    sensing.expect_pick(t)
                    if reserve is not None:
                        reserve.close_grapple(t)
                if not payload_done and tau >= scenario.payload_event[0] - 1e-9:
                    _set_payload(sim, scenario.payload_event[1])
                    if inform_payload and sensors == "oracle":
                        sensing.tell_payload(scenario.payload_event[1])
                        told = "pick"
                    payload_done = True
                tcp = kin.position(true_q)
                tcp_err = _distance(tcp, tcp_goal)
                new_goal = goals.update(tau, tcp_err)
                if new_goal is not None:
                    ctrl.set_goal(new_goal)
                    goal_q_full = true_q.copy()
                    goal_q_full[2:9] = new_goal.crane
                    tcp_goal = kin.position(goal_q_full)
                    tcp_err = _distance(tcp, tcp_goal)
                history.append(obs)
                t0 = time.perf_counter()
                seen = history[0]
                margin = _NO_MARGIN
                if mpc:
                    ctrl.set_payload_mass(seen.payload_mass)
                    margin = uncertainty_margin(ctrl, seen, confidence)
                    if reserve is not None:
                        margin = margin + reserve.update(
                            t, seen.state.q, seen.state.base_rotation, seen.payload_mass,
                            seen.payload_std, seen.payload_event or told, margin)
                    ctrl.set_force_margin(margin)
                cmd = ctrl.step(seen.state)
                step_s[k] = time.perf_counter() - t0 + obs.observer_seconds
                fallbacks += int(cmd.fallback)
                # Driving ramps up from the ready time (not before: the machine stands still).
                w = scenario.wheel_speed(t - readiness.time, machine.wheel_radius) if ready \
                    else 0.0
                wheels = cmd.wheel_speeds(w, w)
                sim.apply(ActuatorCommand.of_servo_rates(cmd.rates, wheels))
                command_row = row_command[k]
                command_row[:9], command_row[9:] = cmd.rates, wheels
                row_tcp_error[k], row_goal_index[k] = tcp_err, goals.index
                row_last_goal_given[k] = goals.last_given
                row_distance[k] = float((truth_position[k] - x0) @ heading)
                row_speed_scale[k], row_fallback[k] = cmd.wheel_speed_scale, cmd.fallback
                row_step_ms[k] = 1e3 * step_s[k]
                row_measured_forces[k] = cmd.info.get("measured_forces", _NO_FORCES)
                row_payload_now[k] = (scenario.payload_event[1] if scenario.payload_event
                                      and payload_done else scenario.payload_mass)
                row_payload_estimate[k], row_force_margin[k] = obs.payload_mass, margin
                row_observer_ms[k] = 1e3 * obs.observer_seconds
                n_done = k + 1  # the tick's row is complete
                sim.step(n_sub)
                if k % 50 == 0:
                    bar.update(min(sim.time - readiness.offset, duration))
        except KeyboardInterrupt:
            interrupted = True
        else:
            bar.update(duration)
    wall = time.perf_counter() - wall0
    recorder.close()
    sensing.close()
    if n_done == 0:  # nothing to save
        raise KeyboardInterrupt
    columns = {**truth.rows(n_done), **{name: a[:n_done] for name, a in rows.items()}}
    log.set_columns(**{name: columns[name] for name in _LOG_ORDER})
    log.set_physics(physics_time=recorder.time, physics_normal_force=recorder.normal_force)
    arrays = log.arrays()
    step_s = step_s[:n_done]
    metrics = {
        "scenario": scenario.name, "description": scenario.description,
        "controller": controller, "terrain": terrain.name, "seed": seed,
        "noise": None if noise is None else vars(noise),
        "sensors": sensors,
        "payload_told": bool(sensors == "oracle" and inform_payload),
        "delay_periods": delay_periods,
        "control_period_s": CONTROL_PERIOD,
        "partial": interrupted,
        "sim_seconds": float(n_done * CONTROL_PERIOD),
        "wall_seconds": wall,
        "real_time_factor": float(n_done * CONTROL_PERIOD / wall),
        "threshold_N": thr,
        "time_to_ready_s": readiness.time,
        "ready_timed_out": readiness.timed_out,
        **closed_loop_metrics(arrays, scenario, thr, ready_time=readiness.time,
                              clock_offset=readiness.offset),
        "control_step_ms": _tick_figures(step_s[:max(n_done, 1)]),
        "observer_step_ms": _tick_figures(arrays["observer_ms"] / 1e3)
        if "observer_ms" in arrays else None,
        "payload_estimate_final_kg": float(arrays["payload_estimate"][-1]),
        "force_margin_N": {"median": float(np.median(arrays["force_margin"])),
                           "max": float(np.max(arrays["force_margin"]))},
        "force_margin_coverage": margin_coverage(arrays, readiness.time, confidence),
        "fallbacks": fallbacks,
    }
    if out_dir is not None:
        out_dir = Path(out_dir)
        log.save(out_dir / "log.npz")
        write_json(out_dir / "metrics.json", metrics)
    if interrupted:
        raise RunInterrupted(out_dir, metrics)
    return metrics


def _payload_machines(machine):
    """The machines whose estimator kernels a run uses: the payload estimator's one."""
    from estimators.payload import anchor_machines

    return anchor_machines(machine)[:1]


def uncertainty_margin(ctrl: MpcController, seen, confidence: float) -> np.ndarray:
    """``z sigma`` [N] (4,) of the forces the MPC constrains, from the observer's errors.

    The MPC predicts the forces of step k as ``f_c(x) + G_m (a_k - a)``: the closure ``f_c``
    (its feedback) at the observed state ``x`` with the measured accelerations ``a``, moved
    by the horizon model's map ``G_m`` to the planned ones. An error ``da`` in the measured
    accelerations (the IMU's specific force, the joints' accelerations) thus enters as
    ``(G_c - G_m) da``: only through the load split the two models disagree on. The joint
    velocities, the suspension cylinder forces and the payload enter through the closure's
    sensitivities (`estimators.uncertainty.normal_force_std`).
    """
    unc = seen.uncertainty
    # the payload's std first: the observer's is never zero, and the arrays' tests cost more
    if not (unc.payload_mass or unc.acceleration.any() or unc.qd.any()
            or unc.suspension_force.any()):
        return np.zeros(4)
    return closure_margin(_closure(ctrl), ctrl.force_model, seen.state, unc, confidence)


def _closure(ctrl: MpcController):
    """The model of the forces now: the feedback's closure, else the MPC's force model."""
    return ctrl.feedback.closure if ctrl.feedback is not None else ctrl.force_model


def _notice(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """``np.linalg.norm(a - b)`` of two points (3,), by its operations, without its checks."""
    d = a - b
    return math.sqrt(d.dot(d))


def _tick_figures(step_s: np.ndarray) -> dict:
    """Control-tick wall times [ms]: median, p99, max, the first and the longest after it.

    The first tick carries the solver's cold start; later ones must fit the control period.
    """
    ms = 1e3 * np.asarray(step_s, float)
    return {"median": float(np.median(ms)), "p99": float(np.percentile(ms, 99)),
            "max": float(ms.max()), "first": float(ms[0]),
            "max_after_first": float(ms[1:].max()) if ms.size > 1 else 0.0}
