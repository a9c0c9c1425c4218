"""QP solvers on the controllers' own QPs: the recorded corpus (`benchmarks.qp_corpus`).

Each solver replays every block of consecutive ticks in order (ProxQP warm: the project's
`ProxQPWorkspace`, warm-started along the block; DAQP screened: the controllers' default
`DaqpBackend`, redundant rows dropped, in least-distance form with a kept factor of the
Hessian and warm-started along the block, the same cold, and the same warm with DAQP
factorising the Hessian itself on every solve (``-direct``);
the others cold, as `QpsolversBackend` runs them). Per solver: solve time (the backend's own
call, and the whole call with qpsolvers' conversion), iterations, the residuals of
``qpsolvers.Solution`` (primal, dual, duality gap), the objective and solution against the
reference (ProxQP cold at 1e-10).

"Solves" (`solved`): found, primal residual <= 1e-6 and objective at most 1e-6 relative
above the reference (absolute below an objective of 1): not suboptimal. An objective *below*
the reference comes only with a primal violation, bounded by the first test, but amplified:
the MPC's force slacks carry a linear penalty of 1e4, so slacks at -6e-8 (inside ProxQP's
eps_abs) lower the objective by 5e-3; the table also counts the solves within 1e-6 on both
sides (``objective_two_sided``). The rows are in the QP's units: the
force rows are scaled by ``1 / force_scale`` (`wbc.constraints.force_rows`, the static wheel
load, ~2.6e4 N), so 1e-6 is ~0.03 N of normal force where the controller keeps a margin of
1.5 kN above a threshold of ~2.6 kN; the limit rows are in m, m/s, m/s^2 (rad): 1e-6 of a
range of metres. The controller itself asks ProxQP for eps_abs = 1e-7.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path

import numpy as np
import qpsolvers

from benchmarks.qp_corpus import CORPUS_PATH, load_corpus, objective, summary
from wbc.controllers import ControllerConfig
from wbc.solvers import DaqpBackend, ProxQPWorkspace, backend_settings

PRIMAL_TOL = 1e-6
OBJECTIVE_TOL = 1e-6
BACKENDS = ("daqp", "piqp", "osqp", "proxqp")


def solved(found: bool, primal_residual: float, obj: float, obj_ref: float) -> bool:
    """The acceptance test of one solve (see the module docstring)."""
    return bool(found and primal_residual <= PRIMAL_TOL
                and obj - obj_ref <= OBJECTIVE_TOL * max(1.0, abs(obj_ref)))


@contextlib.contextmanager
def _quiet_stdout():
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)


def _workspace_solve(ws: ProxQPWorkspace | DaqpBackend,
                     problem) -> tuple[qpsolvers.Solution, float, int]:
    sol = qpsolvers.Solution(problem)
    t0 = time.perf_counter()
    try:
        res = ws.solve(problem)
    except Exception:  # noqa: BLE001 - a failure is a row in the table
        wall = time.perf_counter() - t0
        sol.found = False
        return sol, wall, -1
    wall = time.perf_counter() - t0
    sol.found = True
    sol.x = res.x
    sol.z, sol.z_box = ws.multipliers
    sol.solve_time = wall
    return sol, wall, res.iterations


def _iterations(sol) -> int:
    info = (getattr(sol, "extras", None) or {}).get("info")
    if info is None:
        return (getattr(sol, "extras", None) or {}).get("iter", -1)
    for name in ("iter", "iteration"):
        if hasattr(info, name):
            return int(getattr(info, name))
    return -1


def _solvers(eps_abs: float, eps_rel: float, max_iter: int) -> dict:
    """name -> (kind, settings)."""
    out = {"proxqp-warm": ("workspace", {"warm_start": True}),
           "proxqp-cold": ("workspace", {"warm_start": False}),
           "daqp-screened-warm": ("daqp", {}),
           "daqp-screened-cold": ("daqp", {"warm_start": False}),
           "daqp-screened-warm-direct": ("daqp", {"least_distance": False})}
    for name in BACKENDS:
        if name in qpsolvers.available_solvers:
            settings = backend_settings(name, eps_abs, eps_rel)
            if name == "proxqp":
                settings.update(max_iter=1000)
            out[f"{name} (qpsolvers)"] = ("qpsolvers", settings)
    return out


def replay(corpus, name: str, kind: str, settings: dict, cfg: ControllerConfig) -> list[dict]:
    """Solve every block of ``corpus`` in order; one row per problem."""
    rows = []
    for block in corpus.blocks():
        ws = (ProxQPWorkspace(eps_abs=cfg.eps_abs, eps_rel=cfg.eps_rel, max_iter=cfg.max_iter,
                              retry_infeasible=True, **settings) if kind == "workspace"
              else DaqpBackend(primal_tol=cfg.eps_abs, **settings) if kind == "daqp"
              else None)
        for i in block:
            p = corpus.problems[i]
            if ws is not None:
                sol, wall, it = _workspace_solve(ws, p)
                inner = sol.solve_time if sol.found else wall
            else:
                t0 = time.perf_counter()
                sol = qpsolvers.solve_problem(p, solver=name.split()[0], **settings)
                wall = time.perf_counter() - t0
                inner, it = sol.solve_time, _iterations(sol)
            found = bool(sol.found and sol.x is not None and np.all(np.isfinite(sol.x)))
            sol.found = found
            x_ref, f_ref = corpus.reference_x[i], float(corpus.reference_objective[i])
            f = objective(p, sol.x) if found else np.inf
            r = {"problem": i, "found": found, "wall_s": wall, "solve_s": inner,
                 "iterations": it, "primal_residual": sol.primal_residual(),
                 "dual_residual": sol.dual_residual(), "duality_gap": sol.duality_gap(),
                 "objective_error": abs(f - f_ref) / max(1.0, abs(f_ref)) if found else np.inf,
                 "x_error": float(np.max(np.abs(sol.x - x_ref))) if found else np.inf}
            r["solved"] = solved(found, r["primal_residual"], f, f_ref)
            rows.append(r)
    return rows


def _figures(rows: list[dict], controller: str | None = None, corpus=None) -> dict:
    if controller is not None:
        rows = [r for r in rows if corpus.records[r["problem"]]["controller"] == controller]
    wall = 1e3 * np.array([r["wall_s"] for r in rows])
    inner = 1e3 * np.array([r["solve_s"] for r in rows])
    it = np.array([r["iterations"] for r in rows], float)

    def worst(key):
        v = [r[key] for r in rows if r["found"]]
        return float(max(v)) if v else None

    return {"problems": len(rows), "solved": int(sum(r["solved"] for r in rows)),
            "failures": [r["problem"] for r in rows if not r["solved"]],
            "objective_two_sided": int(sum(r["objective_error"] <= OBJECTIVE_TOL
                                           for r in rows)),
            "call_median_ms": float(np.median(wall)), "call_p99_ms": float(np.percentile(wall, 99)),
            "solve_median_ms": float(np.median(inner)),
            "solve_p99_ms": float(np.percentile(inner, 99)),
            "iterations_median": float(np.median(it)) if np.all(it >= 0) else None,
            "iterations_max": float(it.max()) if np.all(it >= 0) else None,
            "worst_primal_residual": worst("primal_residual"),
            "worst_dual_residual": worst("dual_residual"),
            "worst_duality_gap": worst("duality_gap"),
            "worst_objective_error": worst("objective_error"),
            "worst_x_error": worst("x_error")}


def table(results: dict) -> list[str]:
    """Human lines of the solver table."""
    head = (f"   {'solver':20s} {'QPs':>8s} {'call med/p99 [ms]':>18s} "
            f"{'solve med/p99 [ms]':>19s} {'iter':>9s} {'primal':>8s} {'dual':>8s} "
            f"{'gap':>8s} {'obj err':>8s} {'|dx|':>8s} {'obj 2-sided':>11s}")
    lines = [head, "   (QPs: solved/all; obj err relative, two-sided; |dx| to the reference)"]

    def e(v):
        return "   -    " if v is None else f"{v:8.1e}"

    for name, by in results.items():
        for part, f in by.items():
            it = ("-" if f["iterations_median"] is None
                  else f"{f['iterations_median']:.0f}/{f['iterations_max']:.0f}")
            lines.append(
                f"   {name + ' ' + part:20s} {f['solved']:>3d}/{f['problems']:<4d} "
                f"{f['call_median_ms']:8.3f}/{f['call_p99_ms']:<8.3f} "
                f"{f['solve_median_ms']:8.3f}/{f['solve_p99_ms']:<9.3f} {it:>9s} "
                f"{e(f['worst_primal_residual'])} {e(f['worst_dual_residual'])} "
                f"{e(f['worst_duality_gap'])} {e(f['worst_objective_error'])} "
                f"{e(f['worst_x_error'])} {f['objective_two_sided']:>7d}")
    return lines


def run(out_dir: Path | None = None, path: Path = CORPUS_PATH, repeats: int = 3) -> dict:
    """Replay the corpus with every solver; print the table, return the figures.

    Times are the minimum over ``repeats`` replays of each problem (the solvers are
    deterministic; the minimum removes the machine's noise), the checks from the first.
    """
    corpus = load_corpus(path)
    cfg = ControllerConfig()
    results: dict = {}
    for name, (kind, settings) in _solvers(cfg.eps_abs, cfg.eps_rel, cfg.max_iter).items():
        with _quiet_stdout():  # OSQP's C code prints "Polishing not needed" on stdout
            runs = [replay(corpus, name, kind, settings, cfg) for _ in range(repeats)]
        rows = runs[0]
        for k, r in enumerate(rows):
            r["wall_s"] = min(run_[k]["wall_s"] for run_ in runs)
            r["solve_s"] = min(run_[k]["solve_s"] for run_ in runs)
        results[name] = {c: _figures(rows, c, corpus) for c in ("mpc-full", "tracking")}
    print("\n".join(table(results)))
    every = {n: all(not f["failures"] for f in by.values()) for n, by in results.items()}
    mpc = {n: by["mpc-full"]["call_median_ms"] for n, by in results.items() if every[n]}
    fastest = min(mpc, key=mpc.get) if mpc else None
    print(f"   fastest solving every QP (MPC call median): {fastest}")
    return {"corpus": summary(corpus, path), "tolerance": {
        "primal_residual": PRIMAL_TOL, "objective_relative": OBJECTIVE_TOL,
        "controller_eps_abs": cfg.eps_abs}, "solvers": results,
        "solves_every_qp": every, "fastest_solving_every_qp": fastest}
