"""Metrics of a closed-loop run (``metrics.json``), computed from its log.

All from the moment the machine was ready (`scenarios.startup`; at the earliest after
`models.log.SETTLE_SECONDS`):

* ``min_normal_force_N``, ``time_below_threshold_s``, ``longest_below_threshold_s``: per
  wheel (FL, RL, FR, RR), ground truth along the terrain normal, counted at every physics
  step when the log has the physics-rate arrays (`models.log.PHYSICS_COLUMNS`; the
  ``metrics_rate`` says which), else at the control rate; ``threshold_N`` = 10 % of the
  static wheel load of the reference machine (150 kg payload).
* ``tipped``: fewer than three wheels in contact for `TIP_CONTACT_SECONDS` or longer without
  a break (at the same rate), or base roll or pitch beyond `TIP_ANGLE_DEG`.
* ``min_force_angle_measure_Nm``, ``min_force_angle_deg``, ``min_zmp_margin_m``: the
  force-angle stability measure and the zero-moment point's distance to the support
  polygon's edge, smallest over the run (`scenarios.stability_margins`; control rate).
* ``task_error_final``: distance of the tool point from the last goal's [m] at the end;
  ``task_completion_time_s``: first time every goal has been given, the tool point is
  within `TASK_TOLERANCE` of the last one and the base has driven its distance (standing
  tasks: none) (None if never); ``task_completed``.

`scenarios.closed_loop.run_closed_loop` adds ``control_step_ms`` (median and p99 of the
controller's ``step`` wall time), ``fallbacks``, ``sim_seconds``, ``wall_seconds``,
``real_time_factor`` and ``force_margin_coverage`` (`margin_coverage`).
"""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from models.description import WHEEL_ORDER
from models.log import SETTLE_SECONDS
from scenarios.closed_loop_scenarios import CONTROL_PERIOD, TASK_TOLERANCE, ClosedLoopScenario
from scenarios.stability_margins import force_angle_and_zmp

__all__ = ["TIP_ANGLE_DEG", "TIP_CONTACT_SECONDS", "closed_loop_metrics", "json_default",
           "margin_coverage"]

TIP_CONTACT_SECONDS = 0.2  # fewer than three wheels in contact this long: tipped
CONTACT_FORCE_N = 1.0  # a wheel with more normal force than this is in contact
TIP_ANGLE_DEG = 30.0  # base roll or pitch beyond this: tipped


def _roll_pitch(rotation: np.ndarray) -> tuple[float, float]:
    """Roll and pitch of the base [rad] (ZYX Euler angles of world <- fb)."""
    return (math.atan2(rotation[2, 1], rotation[2, 2]),
            -math.asin(max(-1.0, min(1.0, rotation[2, 0]))))


def _longest_run(mask: np.ndarray) -> int:
    """Length of the longest run of True in a 1-D boolean array."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return int((edges[1::2] - edges[::2]).max()) if edges.size else 0


def json_default(o):
    """``json.dumps`` ``default`` for NumPy scalars and arrays.

    Raises:
        TypeError: ``o`` is neither.
    """
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serializable: {type(o)}")


def _start(ready_time: float | None) -> float:
    """When the safety metrics start counting [s]: ready, and settled at the earliest."""
    return SETTLE_SECONDS if ready_time is None else max(ready_time, SETTLE_SECONDS)


def margin_coverage(log: dict, ready_time: float | None, confidence: float) -> dict | None:
    """How often the MPC's per-wheel margin covered the error of the forces it was fed.

    The MPC keeps each wheel's measured force (the closure feedback, ``measured_forces``)
    ``z sigma`` (``force_margin``) above its threshold, ``z`` of a one-sided ``confidence``;
    that bound is right when the true force is at least ``measured - margin`` on that share
    of the samples. Counted per wheel on the control ticks from the start of the safety
    metrics (``ready_time`` as in `closed_loop_metrics`) on where all four wheels touch
    (truth) and a margin was set.

    Returns:
        ``{"stated", "covered", "samples", "error_rms_N", "sigma_median_N",
        "error_over_sigma_p1"}`` (``covered``: the share of wheel samples with the truth at
        or above ``measured - margin``; ``error_over_sigma_p1``: the 1st percentile of
        ``(true - measured) / sigma``, ``-z`` when the model is right), or None without
        margins (oracle, or no feedback).
    """
    if "measured_forces" not in log or "force_margin" not in log:
        return None
    t, measured, margin = log["time"], log["measured_forces"], log["force_margin"]
    ok = ((t >= _start(ready_time) - 1e-9) & log["in_contact"].all(axis=1)
          & np.isfinite(measured).all(axis=1) & (margin > 0).all(axis=1))
    if not ok.any():
        return None
    z = NormalDist().inv_cdf(confidence)
    error = (log["normal_force"] - measured)[ok]
    sigma = margin[ok] / z
    return {"stated": float(confidence),
            "covered": float(np.mean(error >= -margin[ok])),
            "samples": int(error.size),
            "error_rms_N": float(np.sqrt(np.mean(error ** 2))),
            "sigma_median_N": float(np.median(sigma)),
            "error_over_sigma_p1": float(np.percentile(error / sigma, 1))}


def closed_loop_metrics(log: dict, scenario: ClosedLoopScenario, threshold_n: float,
                        ready_time: float | None = None, clock_offset: float = 0.0) -> dict:
    """The scenario metrics from a closed-loop log (see the module docstring).

    Args:
        log: The log's arrays (`models.log.ScenarioLog.arrays`), with the closed loop's
            columns ``tcp_error``, ``last_goal_given``, ``distance`` and ``speed_scale``.
        scenario: The scenario that was run.
        threshold_n: Normal-force threshold [N].
        ready_time: When the machine was ready and the operator's commands began
            (`scenarios.startup`) [s]; the safety metrics count from then. None: from
            `SETTLE_SECONDS`.
        clock_offset: How much later than planned the scenario's clock started [s]; the
            task completion time is on the scenario's clock.

    Returns:
        The metrics by name.
    """
    t = log["time"]
    physics = "physics_time" in log and np.size(log["physics_time"]) > 1
    if physics:
        ts, fz_all = log["physics_time"], log["physics_normal_force"]
        n_contact = (fz_all > CONTACT_FORCE_N).sum(axis=1)
    else:
        ts, fz_all = t, log["normal_force"]
        n_contact = log["in_contact"].sum(axis=1)
    dt = float(np.median(np.diff(ts))) if ts.size > 1 else CONTROL_PERIOD
    start = _start(ready_time)
    keep = ts >= start - 1e-9
    if not keep.any():  # a run shorter than the settling: judge all of it
        keep = np.ones_like(keep)
    fz = fz_all[keep]
    below = fz < threshold_n
    per_wheel = lambda a: {w: float(v) for w, v in zip(WHEEL_ORDER, a)}  # noqa: E731
    roll_pitch = np.array([_roll_pitch(r) for r in log["base_rotation"]])
    tipped_contact = _longest_run(n_contact[keep] < 3) * dt >= TIP_CONTACT_SECONDS - 1e-9
    tipped_angle = bool(np.any(np.abs(roll_pitch) > math.radians(TIP_ANGLE_DEG)))
    err = log["tcp_error"]
    # A standing task has no distance to cover (a few mm of creep either way do not count).
    drove = (log["distance"] >= scenario.drive_distance - 1e-9
             if scenario.drive_distance > 0 else np.ones(t.shape, bool))
    done = log["last_goal_given"].astype(bool) & (err < TASK_TOLERANCE) & drove
    first = np.flatnonzero(done)
    completion = float(t[first[0]] - clock_offset) if first.size else None
    margins = {}
    if "com_world" in log:
        keep_c = t >= start - 1e-9
        sm = force_angle_and_zmp(log["base_position"][keep_c], log["base_rotation"][keep_c],
                                 log["point_in_fb"][keep_c], log["force_in_fb"][keep_c],
                                 log["in_contact"][keep_c], log["com_world"][keep_c])
        if sm["beta_Nm"].size:
            margins = {"min_force_angle_measure_Nm": float(sm["beta_Nm"].min()),
                       "min_force_angle_deg": float(np.degrees(sm["theta_rad"].min())),
                       "min_zmp_margin_m": float(sm["zmp_margin_m"].min())}
    return {
        **margins,
        "min_normal_force_N": per_wheel(fz.min(axis=0)),
        "time_below_threshold_s": per_wheel(below.sum(axis=0) * dt),
        "longest_below_threshold_s": per_wheel([_longest_run(b) * dt for b in below.T]),
        "any_below_threshold_s": float(below.any(axis=1).sum() * dt),
        "metrics_rate_hz": float(1.0 / dt),
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
