"""Controller speed: the whole-body QP step and the MPC step, per control tick.

Goals (2-core machine): whole-body QP median <= 0.5 ms and p99 <= 2 ms; MPC (>= 1 s
horizon) median <= 10 ms. Each figure is the wall time of ``controller.step(state)`` (goal
handling, references, building the QP, solving it, the command), in closed loop with a
kinematic stand-in for the machine (`testkit.plant.KinematicPlant`) while the crane moves to
a goal that the normal-force constraint partly blocks.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from models import build_reference_machine
from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state
from wbc import (
    ForceModelError,
    JointGoal,
    WholeBodyQPController,
    load_estimator,
    make_controller,
)

DT = 0.01
WARMUP = 20
STEPS = 600
GOALS = {"qp_median_ms": 0.5, "qp_p99_ms": 2.0, "mpc_median_ms": 10.0}


def _time_loop(controller, machine, steps: int = STEPS) -> dict:
    st = make_state(machine)
    goal = st.q[2:9].copy()
    goal[0] += 0.12  # slew: moves load to one side
    goal[1] += 0.14  # lift, to 0.479 m: inside the range the end stop leaves (0.485 m)
    goal[3] += 0.45  # telescope out
    controller.set_goal(JointGoal(crane=goal, suspension=st.q[:2] + 0.03))
    plant = KinematicPlant(st, DT, servo_time_constant=0.02)
    times, iters, solve, call = [], [], [], []
    fallbacks = 0
    first = None
    for k in range(WARMUP + steps):
        t0 = time.perf_counter()
        cmd = controller.step(plant.state)
        elapsed = time.perf_counter() - t0
        plant.apply(cmd)
        if k == 0:
            first = elapsed
        if k >= WARMUP:
            times.append(elapsed)
            iters.append(cmd.info.get("iterations", -1))
            solve.append(cmd.info.get("solve_time", np.nan))
            c = cmd.info.get("solver_call_time")
            call.append(np.nan if c is None else c)
        fallbacks += int(cmd.fallback)
    t = 1e3 * np.asarray(times)
    return {"median_ms": float(np.median(t)), "p99_ms": float(np.percentile(t, 99)),
            "max_ms": float(t.max()), "mean_ms": float(t.mean()),
            "solver_median_ms": float(1e3 * np.nanmedian(solve)),
            # the solver library's call alone (DAQP), without the backend's screening and
            # least-distance form, which `solver_median_ms` includes
            "solver_call_median_ms": (float(1e3 * np.nanmedian(call))
                                      if np.isfinite(call).any() else None),
            "iterations_median": float(np.median(iters)), "fallbacks": fallbacks,
            "steps": steps, "first_ms": float(1e3 * first)}


def _call(figures: dict) -> str:
    c = figures.get("solver_call_median_ms")
    return "" if c is None else f" (its library call {c:.3f} ms)"


def run(out_dir: Path | None = None) -> dict:
    """Time the controllers; return (and print) the figures."""
    machine = build_reference_machine()
    st = make_state(machine)
    synthetic = AffineForceModel.reference(machine, st.q)
    models = {"synthetic": synthetic}
    for method in ("full", "quasi-static"):
        try:
            models[method] = load_estimator(machine, method)
        except ForceModelError as exc:
            print(f"   estimator '{method}' not available: {exc}")
    result: dict = {"goals": GOALS, "dt_s": DT}
    result["qp_tracking"] = _time_loop(make_controller("tracking", machine), machine)
    for name, model in models.items():
        ctrl = WholeBodyQPController(machine, force_model=model)
        result[f"qp_force_{name}"] = _time_loop(ctrl, machine)
    for name, model in models.items():
        label = {"synthetic": "mpc-full", "full": "mpc-full",
                 "quasi-static": "mpc-quasi-static"}[name]
        ctrl = make_controller(label, machine, force_model=model)
        r = _time_loop(ctrl, machine)
        r["horizon_s"] = ctrl.horizon
        r["n_steps"] = ctrl.layout.n_steps
        r["n_linearizations"] = ctrl.config.mpc.n_linearizations
        result[f"mpc_{name}"] = r
    qp = result["qp_tracking"]
    mpcs = [v for k, v in result.items() if k.startswith("mpc_")]
    result["meets_goals"] = {
        "qp_median": qp["median_ms"] <= GOALS["qp_median_ms"],
        "qp_p99": qp["p99_ms"] <= GOALS["qp_p99_ms"],
        "mpc_median": all(m["median_ms"] <= GOALS["mpc_median_ms"] for m in mpcs),
    }
    for k, v in result.items():
        if isinstance(v, dict) and "median_ms" in v:
            extra = f", horizon {v['horizon_s']:.2f} s" if "horizon_s" in v else ""
            print(f"   {k:24s} median {v['median_ms']:.3f} ms, p99 {v['p99_ms']:.3f} ms, "
                  f"max {v['max_ms']:.2f} ms, solver {v['solver_median_ms']:.3f} ms"
                  f"{_call(v)}, fallbacks {v['fallbacks']}{extra}")
    print(f"   goals met: {result['meets_goals']}")
    result["closed_loop"] = closed_loop_real_time_factor(out_dir)
    return result


CLOSED_LOOP_SECONDS = 8.0  # [s] of the default scenario with mpc-full
MEMORY_RUN_SECONDS = 20.0  # [s] of the closed-loop run whose peak memory is recorded


def peak_memory_mb(seconds: float = MEMORY_RUN_SECONDS) -> float:
    """Peak resident memory [MB] of a fresh process running ``seconds`` of the default
    closed-loop scenario with mpc-full (its own process: this one's imports don't count)."""
    import subprocess
    import sys

    # VmHWM is the high-water mark of this process's own memory map (exec starts a new one);
    # getrusage's ru_maxrss carries the parent's peak over from the fork (Linux), which
    # inside `make bench` is the estimator benchmark's arrays.
    code = ("import re, resource, tempfile\n"
            "from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop\n"
            f"run_closed_loop(DEFAULT_SCENARIO, tempfile.mkdtemp(), 'mpc-full', "
            f"duration={float(seconds)!r}, progress=False)\n"
            "try:\n"
            "    text = open('/proc/self/status').read()\n"
            "    print(re.search(r'VmHWM:\\s+(\\d+) kB', text).group(1))\n"
            "except (OSError, AttributeError):\n"
            "    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=str(Path(__file__).resolve().parents[1]), timeout=1800)
    return round(int(out.stdout.strip().splitlines()[-1]) / 1024.0, 1)  # Linux: KB


def closed_loop_real_time_factor(out_dir: Path | None = None) -> dict:
    """Real-time factor of the default closed-loop scenario with ``mpc-full`` (one core)."""
    import tempfile

    from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop

    out = Path(out_dir) / "closed_loop_run" if out_dir else Path(tempfile.mkdtemp())
    m = run_closed_loop(DEFAULT_SCENARIO, out, "mpc-full", duration=CLOSED_LOOP_SECONDS,
                        progress=False)
    figures = {"scenario": DEFAULT_SCENARIO, "controller": "mpc-full",
               "sim_seconds": m["sim_seconds"], "wall_seconds": m["wall_seconds"],
               "real_time_factor": m["real_time_factor"],
               # the tick: observer, margin and MPC step; the observer's part beside it
               "control_step_ms": m["control_step_ms"],
               "observer_step_ms": m.get("observer_step_ms"), "fallbacks": m["fallbacks"],
               "max_tick_after_first_ms": m["control_step_ms"]["max_after_first"],
               "peak_memory_mb": peak_memory_mb(MEMORY_RUN_SECONDS)}
    ticks, obs = m["control_step_ms"], m.get("observer_step_ms") or {}
    print(f"   closed loop {DEFAULT_SCENARIO} mpc-full: {m['real_time_factor']:.2f}x real time "
          f"({m['sim_seconds']:.1f} s in {m['wall_seconds']:.1f} s); tick median "
          f"{ticks['median']:.2f} ms, p99 {ticks['p99']:.2f} ms (observer "
          f"{obs.get('median', float('nan')):.2f} ms of it)")
    return figures


if __name__ == "__main__":
    run()
