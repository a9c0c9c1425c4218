"""`CondensedPrediction.trajectory` in C through numpy's BLAS (`wbc.mpc.trajectory_c`)."""

import tempfile

import numpy as np
import pytest

from scenarios.closed_loop import DEFAULT_SCENARIO, run_closed_loop
from wbc.layout import VariableLayout
from wbc.mpc import prediction as prediction_module
from wbc.mpc.prediction import CondensedPrediction
from wbc.mpc.trajectory_c import TrajectoryProducts

STEPS = [0.01, 0.03, 0.06] + [0.1] * 10  # the MPC's: a period, then longer steps

pytestmark = pytest.mark.skipif(TrajectoryProducts.make(np.eye(2), np.eye(2), 2) is None,
                                reason="no C compiler or not numpy's OpenBLAS")


def _pair(steps=STEPS, n_axes=9):
    layout = VariableLayout(n_axes, len(steps))
    fast, slow = CondensedPrediction(layout, steps), CondensedPrediction(layout, steps)
    slow._products = None
    assert fast._products is not None
    return fast, slow


def _bits(*arrays) -> bytes:
    return b"|".join(np.ascontiguousarray(a, float).tobytes() for a in arrays)


def test_trajectories_are_numpys_bits():
    """Random and odd starts and inputs (signed zeros, infinities, NaN, huge and tiny)."""
    rng = np.random.default_rng(2)
    odd = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1e300, -1e-300, 3.0])
    for steps in (STEPS, [0.02] * 50, [0.1]):
        fast, slow = _pair(steps)
        N = len(steps)
        for trial in range(300):
            q0, qd0 = rng.normal(size=9), rng.normal(size=9)
            u = rng.normal(scale=10.0 ** rng.integers(-3, 4), size=(N, 9))
            if trial % 3 == 0:
                u.flat[rng.integers(u.size, size=5)] = rng.choice(odd, 5)
                qd0[rng.integers(9)] = rng.choice(odd)
            with np.errstate(all="ignore"):
                free = slow.free_response(q0, qd0)
                got = fast.trajectory(q0, qd0, u, free)
                want = slow.trajectory(q0, qd0, u, free)
                assert _bits(*got) == _bits(*want), trial
                got = fast.brake_trajectory(q0, qd0, np.full(9, 2.0), free)
                want = slow.brake_trajectory(q0, qd0, np.full(9, 2.0), free)
                assert _bits(*got) == _bits(*want), trial


def test_closed_loop_products_are_numpys_bits(monkeypatch):
    """Every product of a closed-loop run (brake trajectories, plans) taken by the C call."""
    calls = []
    original = TrajectoryProducts.run

    def checked(self, qf, vf, u):
        done = original(self, qf, vf, u)
        calls.append(done is not None)
        L = (self.Lq, self.Lv)
        assert done is not None and _bits(*done) == _bits(qf + L[0] @ u, vf + L[1] @ u)
        return done

    monkeypatch.setattr(TrajectoryProducts, "run", checked)
    run_closed_loop(DEFAULT_SCENARIO, tempfile.mkdtemp(), "mpc-full", duration=1.5,
                    progress=False)
    assert len(calls) > 200 and all(calls)


def test_inputs_it_cannot_take_go_to_numpy():
    fast, slow = _pair()
    q0, qd0 = np.ones(9), np.full(9, 0.5)
    u = np.asfortranarray(np.arange(13 * 9, dtype=float).reshape(13, 9))
    assert fast._products.run(*fast.free_response(q0, qd0), u) is None
    assert _bits(*fast.trajectory(q0, qd0, u)) == _bits(*slow.trajectory(q0, qd0, u))
    assert fast._products.run(*fast.free_response(q0, qd0), u[:, :8].copy()) is None


def test_without_numpys_blas_numpy_runs(monkeypatch):
    monkeypatch.setattr("wbc.mpc.trajectory_c.numpy_blas", lambda: None)
    layout = VariableLayout(9, len(STEPS))
    assert prediction_module.CondensedPrediction(layout, STEPS)._products is None
