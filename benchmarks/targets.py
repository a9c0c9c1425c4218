"""The speed targets of the real-time work, as ratios to anchors measured in the same run.

`targets` reads the figures of one `make bench` run (simulator, estimator, controller) and
gives each target its measured value, its anchor, the ratio and whether it is met; the
absolute figures stand beside the ratios. Nothing here asserts: a benchmark reports.
"""

from __future__ import annotations

__all__ = ["TARGETS", "format_table", "targets"]

# name: (what, goal, "<=" or ">=")
TARGETS = {
    "estimate_over_rnea": ("estimate / pin.rnea, median", 1.5, "<="),
    "constraint_over_rnea": ("constraint / pin.rnea, median", 2.0, "<="),
    "linearize_over_rnea": ("linearize (was constraint_derivatives) / pin.rnea", 4.0, "<="),
    "estimate_batch_states_per_s": ("estimate_batch, 2 threads [states/s]", 1e6, ">="),
    "qp_step_over_solver": ("whole-body QP step / its solver time, median", 3.0, "<="),
    "qp_step_median_ms": ("whole-body QP step median [ms]", 0.1, "<="),
    "mpc_step_over_solver": ("MPC step / its solver time, median", 1.5, "<="),
    "mpc_step_median_ms": ("MPC step alone median [ms] (>= 1 s horizon; kinematic plant)",
                           1.0, "<="),
    "mpc_step_p99_ms": ("MPC step alone p99 [ms]", 2.0, "<="),
    # The definition: the tick with the estimator, the load-split feedback, the
    # observer and the margin in it (the closed-loop run's control ticks, realistic sensors).
    "closed_loop_tick_median_ms": ("closed-loop tick median [ms]: observer, margin, MPC", 1.0,
                                   "<="),
    "closed_loop_tick_p99_ms": ("closed-loop tick p99 [ms]: observer, margin, MPC", 2.0,
                                "<="),
    "mpc_first_tick_over_median": ("MPC first tick / median tick", 10.0, "<="),
    "closed_loop_rtf_over_bare": ("closed-loop RTF (mpc-full) / bare simulation RTF", 0.2,
                                  ">="),
    "closed_loop_max_tick_ms": ("closed-loop longest tick after the first [ms]", 10.0, "<="),
    "closed_loop_peak_memory_mb": ("peak memory of a closed-loop run [MB]", 500.0, "<="),
}


def _row(name: str, value, anchor=None, anchor_value=None) -> dict:
    what, goal, sense = TARGETS[name]
    row = {"what": what, "value": value, "goal": goal, "sense": sense}
    if anchor is not None:
        row["anchor"] = anchor
        row["anchor_value"] = anchor_value
    if value is None:
        row["met"] = None
    else:
        row["met"] = bool(value <= goal) if sense == "<=" else bool(value >= goal)
    return row


def _ratio(a, b):
    return None if a is None or b in (None, 0) else round(a / b, 3)


def targets(results: dict) -> dict:
    """The target table from one run's results ``{"simulator": ..., "estimator": ...,
    "controller": ...}`` (missing benchmarks give ``None`` values)."""
    est = results.get("estimator", {}).get("timing", results.get("estimator", {}))
    ctrl = results.get("controller", {})
    sim = results.get("simulator", {})
    rnea = est.get("pin_rnea_median_us")
    rows = {
        "estimate_over_rnea": _row("estimate_over_rnea",
                                   _ratio(est.get("estimate_d_beta_median_us"), rnea),
                                   "pin_rnea_median_us", rnea),
        "constraint_over_rnea": _row("constraint_over_rnea",
                                     _ratio(est.get("constraint_median_us"), rnea),
                                     "pin_rnea_median_us", rnea),
        "linearize_over_rnea": _row("linearize_over_rnea",
                                    _ratio(est.get("linearize_median_us"), rnea),
                                    "pin_rnea_median_us", rnea),
        "estimate_batch_states_per_s": _row(
            "estimate_batch_states_per_s", est.get("estimate_batch_2_thread_states_per_s")),
    }
    qp = ctrl.get("qp_tracking", {})
    mpc = ctrl.get("mpc_full", {})
    rows["qp_step_over_solver"] = _row(
        "qp_step_over_solver", _ratio(qp.get("median_ms"), qp.get("solver_median_ms")),
        "solver_median_ms", qp.get("solver_median_ms"))
    rows["qp_step_median_ms"] = _row("qp_step_median_ms", qp.get("median_ms"))
    rows["mpc_step_over_solver"] = _row(
        "mpc_step_over_solver", _ratio(mpc.get("median_ms"), mpc.get("solver_median_ms")),
        "solver_median_ms", mpc.get("solver_median_ms"))
    # The solver anchor is the backend's whole solve (DAQP's row screening and least-distance
    # form included); the ratio to the library's call alone stands beside it.
    for name, figures in (("qp_step_over_solver", qp), ("mpc_step_over_solver", mpc)):
        call = _ratio(figures.get("median_ms"), figures.get("solver_call_median_ms"))
        if call is not None:
            rows[name]["over_solver_call"] = call
    rows["mpc_step_median_ms"] = _row("mpc_step_median_ms", mpc.get("median_ms"))
    rows["mpc_step_p99_ms"] = _row("mpc_step_p99_ms", mpc.get("p99_ms"))
    rows["mpc_first_tick_over_median"] = _row(
        "mpc_first_tick_over_median", _ratio(mpc.get("first_ms"), mpc.get("median_ms")),
        "median_ms", mpc.get("median_ms"))
    loop = ctrl.get("closed_loop", {})
    bare = sim.get("bare_stepping_real_time_factor")
    rows["closed_loop_rtf_over_bare"] = _row(
        "closed_loop_rtf_over_bare", _ratio(loop.get("real_time_factor"), bare),
        "bare_stepping_real_time_factor", bare)
    ticks = loop.get("control_step_ms") or {}
    rows["closed_loop_tick_median_ms"] = _row("closed_loop_tick_median_ms",
                                              ticks.get("median"))
    rows["closed_loop_tick_p99_ms"] = _row("closed_loop_tick_p99_ms", ticks.get("p99"))
    rows["closed_loop_max_tick_ms"] = _row("closed_loop_max_tick_ms",
                                           loop.get("max_tick_after_first_ms"))
    rows["closed_loop_peak_memory_mb"] = _row("closed_loop_peak_memory_mb",
                                              loop.get("peak_memory_mb"))
    return rows


def format_table(rows: dict) -> list[str]:
    """Human lines: value, goal, met, and the anchor beside a ratio."""
    lines = []
    for row in rows.values():
        v = "n/a" if row["value"] is None else f"{row['value']:.4g}"
        met = {True: "met", False: "NOT met", None: "-"}[row["met"]]
        anchor = (f"  (anchor {row['anchor']} = {row['anchor_value']:.4g})"
                  if row.get("anchor_value") is not None else "")
        call = (f"; {row['over_solver_call']:.3g}x the solver's library call alone"
                if "over_solver_call" in row else "")
        lines.append(f"   {row['what']:52s} {v:>10s}  goal {row['sense']} "
                     f"{row['goal']:g}  {met}{anchor}{call}")
    return lines
