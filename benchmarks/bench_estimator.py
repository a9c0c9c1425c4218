"""Normal-force estimator: speed next to Pinocchio's RNEA, batch throughput, accuracy.

``python -m benchmarks --only estimator`` calls `run`; ``python -m benchmarks.bench_estimator``
prints the same figures.

* One `NormalForceEstimator.estimate` call (compiled backend, d-beta and cylinder-force), and
  one ``pin.rnea`` call on the project's Pinocchio model of the same machine with (q, v, a)
  prepared beforehand, timed in the same run: median and p99 [us]. Goal: estimate <= 25 us
  median. Also `PinocchioMachine.base_wrench`, `constraint`, `linearize`, and
  `estimate` on the CasADi VM and the numpy reference backends.
* `NormalForceEstimator.estimate_batch` throughput over 200k states, 1 and 2 threads.
  Goal: >= 200k states/s.
* Accuracy: the flat (25 s) and rough (40 s) open-loop scenarios simulated and evaluated by
  `estimators.evaluate.evaluate_log` (mean error over wheels, % of the static wheel load).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

CALLS = 20000
BATCH = 200_000
GOAL_ESTIMATE_MEDIAN_US = 25.0
GOAL_BATCH_STATES_PER_S = 200_000.0


def _times_us(fn, n: int) -> np.ndarray:
    for _ in range(min(n, 500)):
        fn()
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out * 1e6


def _stats(t: np.ndarray) -> dict:
    return {"median_us": round(float(np.median(t)), 2),
            "p99_us": round(float(np.percentile(t, 99)), 2)}


def timing(calls: int = CALLS, batch: int = BATCH) -> dict:
    """Single-call and batch timings; a flat dict of figures."""
    import pinocchio as pin

    from estimators import NormalForceEstimator, StateBatch
    from models import WheelContacts, build_reference_machine
    from models.pinocchio_model import build_pinocchio
    from testkit.estimator_states import random_state

    machine = build_reference_machine()
    rng = np.random.default_rng(0)
    est = NormalForceEstimator(machine)
    cyl = NormalForceEstimator(machine, fourth="cylinder-force")
    state = random_state(machine, rng, max_tilt=0.3)
    state = replace(state, contacts=WheelContacts(np.ones(4, bool), 300 * rng.normal(size=(4, 3)),
                                   est.estimate(state).contact_points,
                                   np.tile([0, 0, 1.0], (4, 1))))
    state = replace(state, suspension_force=np.array([3e4, 3.2e4]))
    pm = build_pinocchio(machine)
    q, v, a = pm.configuration(state)
    out = {"backend": est.backend}
    # Interleave the two so that both see the same machine load.
    t_rnea, t_est, t_cyl = [], [], []
    for _ in range(4):
        t_rnea.append(_times_us(lambda: pin.rnea(pm.model, pm.data, q, v, a), calls // 4))
        t_est.append(_times_us(lambda: est.estimate(state), calls // 4))
        t_cyl.append(_times_us(lambda: cyl.estimate(state), calls // 4))
    for name, t in (("pin_rnea", t_rnea), ("estimate_d_beta", t_est),
                    ("estimate_cylinder_force", t_cyl)):
        s = _stats(np.concatenate(t))
        out[f"{name}_median_us"] = s["median_us"]
        out[f"{name}_p99_us"] = s["p99_us"]
    out["estimate_over_rnea_median"] = round(out["estimate_d_beta_median_us"]
                                             / out["pin_rnea_median_us"], 2)
    # The rest of the API, and the slower backends (what `estimators/bench.py` printed).
    vm = NormalForceEstimator(machine, backend="casadi")
    ref = NormalForceEstimator(machine, backend="reference")
    # Two wheels touching (Sec. III-B's tipping case): derivatives by batched differences.
    tipping = replace(state, contacts=replace(state.contacts,
                                              in_contact=np.array([1, 0, 0, 1], bool)))
    for name, fn, n in (
            ("pinocchio_base_wrench", lambda: pm.base_wrench(state), calls // 4),
            ("constraint", lambda: est.constraint(state), calls // 4),
            ("linearize", lambda: est.linearize(state), calls // 20),
            ("linearize_tipping", lambda: est.linearize(tipping), 300),
            ("estimate_casadi_vm", lambda: vm.estimate(state), 500),
            ("estimate_reference_numpy", lambda: ref.estimate(state), 100)):
        s = _stats(_times_us(fn, n))
        out[f"{name}_median_us"] = s["median_us"]
        out[f"{name}_p99_us"] = s["p99_us"]
    out["goal_estimate_median_us"] = GOAL_ESTIMATE_MEDIAN_US
    out["goal_estimate_met"] = out["estimate_d_beta_median_us"] <= GOAL_ESTIMATE_MEDIAN_US

    base = [random_state(machine, rng, max_tilt=0.3) for _ in range(1000)]
    sb = StateBatch.from_states(base)
    reps = max(1, batch // len(base))
    big = StateBatch(*(np.concatenate([getattr(sb, f)] * reps) for f in
                       ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd")))
    best = 0.0
    for threads in (1, 2):
        est.estimate_batch(big, threads=threads)
        dts = []
        for _ in range(3):
            t0 = time.perf_counter()
            est.estimate_batch(big, threads=threads)
            dts.append(time.perf_counter() - t0)
        rate = len(big) / min(dts)
        best = max(best, rate)
        out[f"estimate_batch_{threads}_thread_states_per_s"] = round(rate)
    out["estimate_batch_states"] = len(big)
    out["goal_batch_states_per_s"] = GOAL_BATCH_STATES_PER_S
    out["goal_batch_met"] = best >= GOAL_BATCH_STATES_PER_S
    return out


def accuracy(out_dir: Path) -> dict:
    """Simulate flat and rough and evaluate every method; mean errors [%] per scenario."""
    from estimators.evaluate import evaluate_log
    from scenarios.openloop import SCENARIOS, run_open_loop

    out = {}
    for name in ("flat", "rough"):
        folder = Path(out_dir) / "estimator_runs" / name
        run_open_loop(SCENARIOS[name], folder, progress=False)
        rep = evaluate_log(folder, plots=False)
        for method, m in rep["methods"].items():
            out[f"{name}_{method}_error_pct"] = round(m["error_pct"]["mean"], 3)
            four = m["by_contacts"]["four_contact"]["error_pct_mean"]
            if four is not None and method in ("full/d-beta", "full/cylinder-force"):
                out[f"{name}_{method}_four_contact_error_pct"] = round(four, 3)
        out[f"{name}_calibrated_D"] = round(rep["calibration"]["global"]["D"], 4)
        out[f"{name}_calibrated_beta_N"] = round(rep["calibration"]["global"]["beta"], 1)
        out[f"{name}_equilibrium_rows_dynamics_pct"] = round(
            rep["equilibrium_rows"]["full"]["dynamics_pct"], 3)
        out[f"{name}_three_contact_fraction"] = round(
            rep["samples"]["three_contact"] / rep["samples"]["scored"], 3)
    return out


def run(out_dir: Path) -> dict:
    """Every figure of this benchmark as one flat dict (written as JSON by the runner)."""
    t0 = time.perf_counter()
    result = timing()
    result.update(accuracy(Path(out_dir)))
    result["bench_wall_seconds"] = round(time.perf_counter() - t0, 1)
    return result


def main() -> None:
    """Print the figures."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        for k, v in run(Path(tmp)).items():
            print(f"{k:55s} {v}")


if __name__ == "__main__":
    main()
