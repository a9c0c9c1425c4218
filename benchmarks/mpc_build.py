"""Where the MPC's QP assembly goes: per-term medians inside the controller benchmark's loop.

``python -m benchmarks.mpc_build [steps]`` runs `bench_wbc._time_loop` with mpc-full and the
full estimator, each task's ``compute_qp_objective``, each constraint's ``compute``, the
builder's ``build`` and the normal-force constraint's parts timed (perf_counter around each
call, about 0.3 us of its own per call), and prints each median [us] over the ticks after
the warm-up. ``glue`` is the build's median minus the terms' medians: the builder's own
sums, boxes, checks and row copies.
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict

import numpy as np

from benchmarks.bench_wbc import WARMUP, _time_loop
from models import build_reference_machine
from wbc import load_estimator, make_controller


def _timed(timings: dict, obj, method: str, name: str) -> None:
    fun = getattr(obj, method)

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        result = fun(*args, **kwargs)
        timings[name].append(time.perf_counter() - t0)
        return result

    setattr(obj, method, timed)


def profile(steps: int = 600) -> dict:
    """``{term: median us}`` of one benchmark loop, and the step's and solver's medians."""
    machine = build_reference_machine()
    ctrl = make_controller("mpc-full", machine, force_model=load_estimator(machine, "full"))
    planner = ctrl.planner
    timings: dict = defaultdict(list)
    terms = []
    for i, task in enumerate(planner.tasks):
        terms.append(f"task {i} {type(task).__name__}")
        _timed(timings, task, "compute_qp_objective", terms[-1])
    for con in planner.constraints:
        terms.append(type(con).__name__)
        _timed(timings, con, "compute", terms[-1])
        # The normal-force constraint's parts: the tick path (`_rows_map` on the nodes'
        # kernel rows) or the path through one linearization object per node.
        for part in ("_nominal", "_rows_map", "linearize", "_forces_map"):
            if hasattr(con, part):
                _timed(timings, con, part, f"  {terms[-1]}.{part}")
    _timed(timings, planner.builder, "build", "build")
    result = _time_loop(ctrl, machine, steps)
    med = {k: 1e6 * float(np.median(v[WARMUP:] if len(v) > WARMUP else v))
           for k, v in timings.items()}
    med["glue"] = med["build"] - sum(med.get(t, 0.0) for t in terms)
    med["step"], med["solver"] = 1e3 * result["median_ms"], 1e3 * result["solver_median_ms"]
    return med


if __name__ == "__main__":
    figures = profile(int(sys.argv[1]) if len(sys.argv) > 1 else 600)
    for name, us in sorted(figures.items(), key=lambda kv: -kv[1]):
        print(f"   {name:40s} {us:7.1f} us")
