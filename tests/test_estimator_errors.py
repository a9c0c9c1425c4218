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


@pytest.mark.parametrize("field,bad,match", [
    ("qdd", np.full(13, np.nan), "'qdd'"), ("qd", np.zeros(5), r"'qd' must have shape \(13,\)"),
    ("base_rotation", 2.0 * np.eye(3), "base_rotation"), ("time", float("inf"), "'time'"),
    ("contacts", "four", "'contacts'"), ("suspension_force", np.zeros(3), "suspension_force"),
    ("payload", 1.0, "no field 'payload'")])
def test_state_replace_checks_what_changed(state, field, bad, match):
    """`MachineState.replace` raises as the constructor does on the changed field."""
    with pytest.raises(StateError, match=match):
        state.replace(**{field: bad})


def test_state_replace_equals_dataclasses_replace(state):
    qdd = np.arange(13.0)
    fast, slow = state.replace(qdd=qdd, time=2), replace(state, qdd=qdd, time=2)
    for name in ("base_position", "base_rotation", "base_twist", "base_acceleration", "q",
                 "qd", "qdd", "suspension_force", "servo_setpoint"):
        a, b = getattr(fast, name), getattr(slow, name)
        assert (a is None and b is None) or (np.array_equal(a, b) and not a.flags.writeable)
    assert fast.time == slow.time == 2.0 and type(fast.time) is float
    assert fast.q is state.q  # unchanged fields are shared (frozen)
    qdd[0] = 99.0
    assert fast.qdd[0] == 0.0  # the changed one is copied


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


def _singular(state):
    """``state`` with all four contact points coincident: the 3x4 system is singular."""
    from models import WheelContacts
    c = WheelContacts(np.ones(4, bool), np.zeros((4, 3)), np.tile([1.0, 0.0, -0.5], (4, 1)),
                      np.tile([0.0, 0.0, 1.0], (4, 1)))
    return replace(state, contacts=c)


@pytest.mark.parametrize("method", ["estimate", "constraint", "linearize"])
def test_singular_geometry_raises_in_every_method(est, state, method):
    with pytest.raises(SingularSystemError, match="singular"):
        getattr(est, method)(_singular(state))


@pytest.mark.parametrize("method", ["estimate", "constraint", "linearize"])
def test_overflow_is_a_typed_error(est, state, method):
    qd = state.qd.copy()
    qd[3] = 1e300
    with pytest.raises(EstimatorInputError, match=r"overflow.*'?qd'?"):
        getattr(est, method)(replace(state, qd=qd))


@pytest.mark.parametrize("index,value,name", [(5, 101.0, "telescope"),
                                              (7, 2.0, "wrist_roll")])
def test_joint_out_of_range_names_joint_and_range(est, state, index, value, name):
    q = state.q.copy()
    q[index] = value
    with pytest.raises(EstimatorInputError, match=f"joint '{name}'.*outside"):
        est.estimate(replace(state, q=q))
    with pytest.raises(EstimatorInputError, match=f"joint '{name}'"):
        est.estimate_batch([replace(state, q=q)])


@pytest.mark.parametrize("value", [np.array(["full"]), None, 3])
def test_options_of_the_wrong_type(machine, value):
    with pytest.raises(EstimatorInputError, match="method"):
        NormalForceEstimator(machine, method=value)
    with pytest.raises(EstimatorInputError, match="D must be a finite real number"):
        NormalForceEstimator(machine, D="0.5")
