"""Bad input raises the documented, typed errors with useful messages."""

from dataclasses import replace

import numpy as np
import pytest

from estimators import (
    EstimatorError,
    EstimatorInputError,
    NormalForceEstimator,
    SingularSystemError,
    StateBatch,
)
from models import StateError, build_reference_machine
from testkit.estimator_states import random_state


@pytest.fixture(scope="module")
def machine():
    return build_reference_machine()


@pytest.fixture(scope="module")
def est(machine):
    return NormalForceEstimator(machine)


@pytest.fixture
def state(machine):
    return random_state(machine, np.random.default_rng(0), max_tilt=0.3)


def test_hierarchy():
    assert issubclass(EstimatorInputError, EstimatorError)
    assert issubclass(EstimatorInputError, ValueError)
    assert issubclass(SingularSystemError, EstimatorError)


@pytest.mark.parametrize("field", ["q", "qd", "qdd", "base_twist", "base_acceleration"])
def test_non_finite_field_is_named(est, state, field):
    # The state is validated once, at construction: the bad state never reaches `estimate`.
    bad = getattr(state, field).copy()
    bad[1] = np.nan
    with pytest.raises(StateError, match=f"'{field}'"):
        replace(state, **{field: bad})


def test_wrong_shape_is_named(est, state):
    with pytest.raises(StateError, match=r"'qd' must have shape \(13,\)"):
        replace(state, qd=np.zeros(5))


@pytest.mark.parametrize("index,name", [(0, "bogie_L"), (3, "lift")])
def test_stroke_out_of_range_names_chain_and_range(est, state, index, name):
    q = state.q.copy()
    q[index] = 0.93
    with pytest.raises(EstimatorInputError, match=rf"q\[{index}\].*'{name}'.*outside \["):
        est.estimate(replace(state, q=q))


def test_not_a_rotation(est, state):
    with pytest.raises(StateError, match="base_rotation"):
        replace(state, base_rotation=2.0 * np.eye(3))


def test_not_a_state(est):
    with pytest.raises(EstimatorInputError, match="MachineState"):
        est.estimate({"q": np.zeros(13)})


@pytest.mark.parametrize("kw", [dict(method="dynamic"), dict(fourth="gamma"),
                                dict(backend="gpu"), dict(D=np.nan), dict(beta=np.inf)])
def test_bad_options(machine, kw):
    with pytest.raises(EstimatorInputError):
        NormalForceEstimator(machine, **kw)


def test_batch_errors_name_field_and_rows(est, machine):
    states = [random_state(machine, np.random.default_rng(i)) for i in range(4)]
    sb = StateBatch.from_states(states)
    q = sb.q.copy()
    q[2, 4] = 5.0
    with pytest.raises(EstimatorInputError, match=r"row 2.*'tilt'"):
        est.estimate_batch(StateBatch(sb.base_rotation, sb.base_twist, sb.base_acceleration, q,
                                      sb.qd, sb.qdd))
    qd = sb.qd.copy()
    qd[1, 0] = np.inf
    with pytest.raises(StateError, match=r"'qd'.*rows \[1\]"):
        StateBatch(sb.base_rotation, sb.base_twist, sb.base_acceleration, sb.q, qd, sb.qdd)
    with pytest.raises(StateError, match="'base_twist' must have shape"):
        StateBatch(sb.base_rotation, sb.base_twist[:, :3], sb.base_acceleration, sb.q, sb.qd,
                   sb.qdd)
    with pytest.raises(EstimatorInputError, match=r"states\[1\]"):
        est.estimate_batch([states[0], "not a state"])
