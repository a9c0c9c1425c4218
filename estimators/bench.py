"""Timing of the normal-force estimator; prints figures (``python -m estimators.bench``).

Reference point: one ``pin.rnea`` call on the project's Pinocchio model of the same machine
(just the C++ recursion, with (q, v, a) prepared beforehand).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from estimators.estimator import NormalForceEstimator, StateBatch
from estimators.testing import random_state
from models import WheelContacts, build_reference_machine


def _times(fn, n: int) -> np.ndarray:
    for _ in range(min(n, 200)):
        fn()
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out * 1e6


def _line(name: str, t: np.ndarray) -> str:
    return (f"{name:<44} median {np.median(t):8.2f} us   p99 {np.percentile(t, 99):8.2f} us")


def main(argv=None) -> None:
    """Run the benchmark and print the figures."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--calls", type=int, default=20000, help="single-call repetitions")
    ap.add_argument("--batch", type=int, default=200000, help="states in the batch run")
    args = ap.parse_args(argv)

    import pinocchio as pin

    from models.pinocchio_model import build_pinocchio

    machine = build_reference_machine()
    rng = np.random.default_rng(0)
    est = NormalForceEstimator(machine)
    state = random_state(machine, rng, max_tilt=0.3)
    state.contacts = WheelContacts(np.ones(4, bool), 300 * rng.normal(size=(4, 3)),
                                   est.estimate(state).contact_points,
                                   np.tile([0, 0, 1.0], (4, 1)))
    pm = build_pinocchio(machine)
    q, v, a = pm.configuration(state)
    print(f"machine: {len(machine.bodies)} bodies, pin model nq={pm.model.nq} nv={pm.model.nv}")
    print(_line("pin.rnea (prepared q, v, a)",
                _times(lambda: pin.rnea(pm.model, pm.data, q, v, a), args.calls)))
    print(_line("PinocchioMachine.base_wrench(state)",
                _times(lambda: pm.base_wrench(state), args.calls // 4)))
    print(_line(f"estimate, backend={est.backend}", _times(lambda: est.estimate(state),
                                                            args.calls)))
    cyl = NormalForceEstimator(machine, fourth="cylinder-force")
    state.suspension_force = np.array([1e4, 1.2e4])
    print(_line("estimate, cylinder-force", _times(lambda: cyl.estimate(state), args.calls)))
    print(_line("constraint (G, g0)", _times(lambda: est.constraint(state), args.calls // 4)))
    print(_line("constraint_derivatives", _times(lambda: est.constraint_derivatives(state),
                                                 args.calls // 20)))
    vm = NormalForceEstimator(machine, backend="casadi")
    print(_line("estimate, backend=casadi (VM)", _times(lambda: vm.estimate(state), 500)))
    ref = NormalForceEstimator(machine, backend="reference")
    print(_line("estimate, backend=reference (numpy)", _times(lambda: ref.estimate(state),
                                                               100)))

    base = [random_state(machine, rng, max_tilt=0.3) for _ in range(1000)]
    sb = StateBatch.from_states(base)
    reps = max(1, args.batch // len(base))
    big = StateBatch(*(np.concatenate([getattr(sb, f)] * reps) for f in
                       ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd")))
    for threads in (1, 2):
        est.estimate_batch(big, threads=threads)
        t0 = time.perf_counter()
        est.estimate_batch(big, threads=threads)
        dt = time.perf_counter() - t0
        print(f"estimate_batch, {len(big)} states, {threads} thread(s): {dt * 1e3:8.1f} ms "
              f"= {len(big) / dt / 1e3:8.1f} k states/s")


if __name__ == "__main__":
    main()
