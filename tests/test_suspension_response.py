"""The stepped forces' C loop (`estimators.suspension_response.STEPPED_C`) against Python's."""

from dataclasses import replace

import numpy as np
import pytest

from estimators import NormalForceEstimator
from estimators.suspension_response import library, stepped_forces
from models import build_reference_machine
from testkit.estimator_states import random_state

MACHINE = build_reference_machine()


@pytest.fixture(scope="module")
def estimator():
    est = NormalForceEstimator(MACHINE, fourth="cylinder-force")
    if est.backend != "compiled" or library() is None:
        pytest.skip("no C compiler: the Python loop is the only one")
    return est


def _state(seed: int):
    rng = np.random.default_rng(seed)
    s = random_state(MACHINE, rng, max_tilt=0.2, speed=0.3)
    return replace(s, suspension_force=rng.uniform(2e4, 6e4, 2))


@pytest.mark.parametrize("payload_step", [None, 100.0])
def test_compiled_loop_gives_the_python_loops_bits(estimator, payload_step):
    for seed in range(6):
        s = _state(seed)
        fast = stepped_forces(estimator, s, 250.0, payload_step)
        assert "stepped_rows" in estimator._calls.__dict__  # the C loop ran
        slow = stepped_forces(estimator, s, 250.0, payload_step, compiled=False)
        assert fast.shape == slow.shape == (3 if payload_step is None else 4, 4)
        assert fast.tobytes() == slow.tobytes()
        assert np.abs(fast[1] - fast[0]).max() > 1.0  # the step moved the forces
        assert np.abs(fast[2] - fast[0]).max() > 1.0


def test_a_non_finite_row_gives_none_in_both(estimator):
    s = replace(_state(7), suspension_force=np.array([1e308, 1e308]))
    assert stepped_forces(estimator, s, 1e308, 100.0) is None
    assert stepped_forces(estimator, s, 1e308, 100.0, compiled=False) is None
