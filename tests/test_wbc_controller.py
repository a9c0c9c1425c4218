"""Controller interface: names, typed input errors, fallback, goals, closed loop."""

import dataclasses
import logging

import numpy as np
import pytest

import models
from models.errors import StateError
from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state
from wbc import (
    CONTROLLER_NAMES,
    ConfigurationError,
    ControlCommand,
    ControllerConfig,
    ForceConfig,
    ForceModelError,
    IKError,
    JointGoal,
    MpcController,
    TcpGoal,
    UnknownControllerError,
    WbcError,
    WbcInputError,
    WholeBodyQPController,
    make_controller,
)

DT = 0.01


@pytest.fixture(scope="module")
def tracking(machine):
    return make_controller("tracking", machine)


def test_names(machine):
    assert CONTROLLER_NAMES == ("tracking", "mpc-quasi-static", "mpc-full")
    with pytest.raises(UnknownControllerError, match="valid names: tracking"):
        make_controller("pid", machine)
    with pytest.raises(ValueError):
        make_controller("mpc", machine)
    st = make_state(machine)
    model = AffineForceModel.reference(machine, st.q)
    with pytest.raises(ConfigurationError):
        make_controller("tracking", machine, force_model=model)
    for name in CONTROLLER_NAMES[1:]:
        c = make_controller(name, machine, force_model=model)
        assert isinstance(c, MpcController) and c.name == name
    assert make_controller("tracking", machine).name == "tracking"


def test_mpc_by_name_uses_the_estimator_or_says_why(machine):
    for name in CONTROLLER_NAMES[1:]:
        try:
            c = make_controller(name, machine)
        except ForceModelError as exc:
            assert "NormalForceEstimator" in str(exc)
        else:
            assert c.force_constraint.model.method == name.removeprefix("mpc-")


def test_bad_input_raises_typed_errors(machine, tracking):
    st = make_state(machine)
    with pytest.raises(WbcInputError):
        tracking.step("not a state")
    q_nan = make_state(machine).q.copy()
    q_nan[3] = np.nan
    with pytest.raises(StateError, match="'q' has non-finite"):
        make_state(machine, q=q_nan)
    with pytest.raises(StateError, match="shape"):
        dataclasses.replace(make_state(machine), qd=np.zeros(12))
    with pytest.raises(WbcInputError):
        JointGoal(crane=np.zeros(6))
    with pytest.raises(WbcInputError):
        TcpGoal(position_in_fb=[1.0, np.inf, 0.0])
    with pytest.raises(WbcInputError, match="for axis 'telescope'"):
        g = st.q[2:9].copy()
        g[3] = 5.0
        tracking.set_goal(JointGoal(crane=g))
    with pytest.raises(WbcInputError):
        tracking.set_goal(st.q[2:9])
    with pytest.raises(ConfigurationError):
        ControllerConfig(dt=-0.01)
    with pytest.raises(ConfigurationError):
        ForceConfig(thresholds=(1.0, 2.0))
    with pytest.raises(WbcInputError):
        make_controller("tracking", "machine")
    assert issubclass(WbcInputError, WbcError) and issubclass(WbcInputError, ValueError)


def _impossible(machine, st, soft=False):
    """Hard force constraint that no acceleration can meet: every solve is infeasible."""
    G = np.zeros((4, 19))
    G[1, 6 + 5] = -100.0
    model = AffineForceModel(np.full(4, 1000.0), st.q, None, G)
    # A small iteration cap: every solve is infeasible, and ProxQP otherwise spends its whole
    # default budget proving it on each of the test's ticks.
    return model, ControllerConfig(force=ForceConfig(thresholds=(0.0, 5e4, 0.0, 0.0),
                                                     soft=soft, speed_scale=True),
                                   max_iter=100)


@pytest.mark.parametrize("kind", ["qp", "mpc"])
def test_fallback_on_infeasible_brakes(machine, kind, caplog):
    qd = np.zeros(13)
    qd[:9] = [0.05, -0.05, 0.1, -0.2, 0.3, 0.004, 0.5, -0.5, 1.0]
    st = make_state(machine, qd=qd)
    model, cfg = _impossible(machine, st)
    ctrl = (WholeBodyQPController(machine, cfg, force_model=model) if kind == "qp"
            else make_controller("mpc-full", machine, cfg, force_model=model))
    with caplog.at_level(logging.WARNING, logger="wbc"):
        cmd = ctrl.step(st)
    assert cmd.fallback and "fallback_reason" in cmd.info
    assert any("fallback" in r.message for r in caplog.records)
    assert np.all(np.isfinite(cmd.rates)) and np.isfinite(cmd.wheel_speed_scale)
    lim = ctrl.limits
    # Crane: braked at the acceleration limit (or to rest when that is closer).
    crane = slice(2, 9)
    expected = qd[crane] - np.clip(qd[crane] / DT, -lim.acceleration[crane],
                                   lim.acceleration[crane]) * DT
    np.testing.assert_allclose(cmd.crane_rates, expected, atol=1e-12)
    assert np.all(np.abs(cmd.crane_rates) <= np.abs(qd[crane]))
    np.testing.assert_allclose(cmd.suspension_rates, 0.0)  # hold
    assert cmd.wheel_speed_scale == pytest.approx(1.0 - 0.5 * DT)
    assert ctrl.n_fallbacks == 1
    # Braking continues over the following ticks until the crane is at rest.
    plant = KinematicPlant(st, DT)
    for _ in range(200):
        cmd = ctrl.step(plant.state)
        plant.apply(cmd)
    np.testing.assert_allclose(plant.state.qd[:9], 0.0, atol=1e-12)
    # The soft version of the same problem is feasible: no fallback, least violation.
    model, cfg = _impossible(machine, st, soft=True)
    cmd = WholeBodyQPController(machine, cfg, force_model=model).step(st)
    assert not cmd.fallback and cmd.info["slack"][1] > 0


def test_model_failure_falls_back(machine):
    st = make_state(machine)

    class Failing(AffineForceModel):
        def linearize(self, state):
            raise ArithmeticError("singular system")

    ctrl = make_controller("mpc-full", machine, force_model=Failing(np.zeros(4), st.q))
    cmd = ctrl.step(st)
    assert cmd.fallback and "singular system" in cmd.info["fallback_reason"]
    np.testing.assert_allclose(cmd.rates, 0.0)


def test_joint_goal_closed_loop_and_reset(machine):
    st = make_state(machine)
    ctrl = make_controller("tracking", machine)
    goal = st.q[2:9] + np.array([0.1, 0.1, -0.05, 0.3, 0.2, -0.3, 0.5])
    ctrl.set_goal(JointGoal(crane=goal, suspension=st.q[:2] + 0.05))
    plant = KinematicPlant(st, DT, servo_time_constant=0.02)
    for _ in range(700):
        cmd = ctrl.step(plant.state)
        assert isinstance(cmd, ControlCommand) and not cmd.fallback
        plant.apply(cmd)
    np.testing.assert_allclose(plant.state.q[2:9], goal, atol=2e-3)
    np.testing.assert_allclose(plant.state.q[:2], st.q[:2] + 0.05, atol=2e-3)
    assert set(cmd.rates_by_name(ctrl.limits.names)) == set(ctrl.limits.names)
    ctrl.reset()
    cmd = ctrl.step(plant.state)  # holds where it is
    np.testing.assert_allclose(cmd.rates, 0.0, atol=1e-3)


def test_tcp_goal(machine):
    st = make_state(machine)
    ctrl = make_controller("tracking", machine)
    p0 = ctrl.tcp_kinematics.position(st.q)
    target = p0 + np.array([0.4, 0.2, 0.3])
    ctrl.set_goal(TcpGoal(target), st)
    plant = KinematicPlant(st, DT)
    for _ in range(800):
        plant.apply(ctrl.step(plant.state))
    np.testing.assert_allclose(ctrl.tcp_kinematics.position(plant.state.q), target, atol=3e-3)
    # Unreachable: typed error now, or logged and dropped when deferred.
    with pytest.raises(IKError, match="not reached"):
        ctrl.set_goal(TcpGoal([30.0, 0.0, 0.0]), plant.state)
    ctrl.set_goal(TcpGoal([30.0, 0.0, 0.0]))
    cmd = ctrl.step(plant.state)
    assert "goal_error" in cmd.info and not cmd.fallback
    np.testing.assert_allclose(cmd.rates, 0.0, atol=1e-6)


def test_wheel_contacts_measured(machine):
    """Measured contact flags decide which wheels are constrained (MPC)."""
    st0 = make_state(machine)
    model = AffineForceModel.reference(machine, st0.q)
    contacts = models.WheelContacts(np.array([True, True, False, True]), np.zeros((4, 3)),
                                    np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    st = make_state(machine, contacts=contacts)
    ctrl = make_controller("mpc-full", machine, force_model=model)
    prob = ctrl.prepare(st)
    n_force_rows = 3 * (ctrl.layout.n_steps + 1)  # the steps and the terminal brake node
    n_limit_rows = 4 * 9 * ctrl.layout.n_steps
    n_effort_rows = 2 * 4 * ctrl.layout.n_steps  # slew, lift, tilt, telescope
    assert prob.G.shape[0] == n_limit_rows + n_force_rows + n_effort_rows


@pytest.mark.parametrize("name", CONTROLLER_NAMES)
def test_no_goal_and_met_goal_give_zero_motion(machine, name):
    st = make_state(machine)
    model = AffineForceModel.reference(machine, st.q)
    kw = {} if name == "tracking" else {"force_model": model}
    ctrl = make_controller(name, machine, **kw)
    for _ in range(3):
        cmd = ctrl.step(st)
        np.testing.assert_allclose(cmd.rates, 0.0, atol=1e-7)
        assert cmd.wheel_speed_scale == pytest.approx(1.0)
    ctrl.set_goal(JointGoal(crane=st.q[2:9], suspension=st.q[:2]))
    for _ in range(3):
        cmd = ctrl.step(st)
        np.testing.assert_allclose(cmd.rates, 0.0, atol=1e-7)


def test_telescope_goal_at_101_m_is_refused(tracking, machine):
    crane = machine.coordinates.home()[2:9].copy()
    crane[3] = 101.0
    with pytest.raises(WbcInputError, match="telescope"):
        tracking.set_goal(JointGoal(crane=crane))


@pytest.mark.parametrize("field,value", [("qd", 1e300), ("base_twist", 1e200),
                                         ("base_acceleration", -1e200), ("q", 1e250),
                                         ("qdd", -1e300)])
def test_step_refuses_a_state_that_would_overflow(tracking, machine, field, value):
    state = make_state(machine)
    x = getattr(state, field).copy()
    x[-1] = value
    with pytest.raises(WbcInputError, match=rf"state\.{field} has an entry of magnitude"):
        tracking.step(dataclasses.replace(state, **{field: x}))


def test_step_names_the_first_field_that_would_overflow(tracking, machine):
    state = make_state(machine)
    big = dict(qd=state.qd.copy(), qdd=state.qdd.copy())
    big["qd"][0], big["qdd"][0] = 1e300, 1e300
    with pytest.raises(WbcInputError, match=r"state\.qd has"):
        tracking.step(dataclasses.replace(state, **big))


@pytest.mark.parametrize("kw", [dict(dt="0.01"), dict(max_iter=2.5), dict(eps_abs=10**400),
                                dict(solver=3)])
def test_config_values_of_the_wrong_type(kw):
    with pytest.raises(ConfigurationError):
        ControllerConfig(**kw)


def test_force_thresholds_of_the_wrong_type():
    with pytest.raises(ConfigurationError, match="thresholds"):
        ForceConfig(thresholds=["a"] * 4)


@pytest.mark.parametrize("name", [np.array(["tracking"]), None, 3])
def test_controller_name_of_the_wrong_type(machine, name):
    with pytest.raises(UnknownControllerError):
        make_controller(name, machine)


def test_a_goal_in_the_position_margin_is_clamped_and_reported(tracking, machine):
    crane = machine.coordinates.home()[2:9].copy()
    crane[3] = 0.001  # inside the telescope's range [0, 1.1] m, inside the 1 % margin
    tracking.reset()
    tracking.set_goal(JointGoal(crane=crane))
    cmd = tracking.step(make_state(machine))
    assert "goal clamped" in cmd.info["goal_error"] and "'telescope'" in cmd.info["goal_error"]
    assert tracking.crane_reference.goal[3] == pytest.approx(0.011)
    assert np.all(np.isfinite(cmd.rates))


def test_reference_ahead_equals_reference_at(machine):
    """The whole-body QP's one-time reference is `reference_at` at that offset, bit for bit."""
    ctrl = make_controller("tracking", machine)
    st = make_state(machine)
    goal = st.q[2:9].copy()
    goal[3] += 0.3
    ctrl.set_goal(JointGoal(crane=goal, suspension=st.q[:2] + 0.02))
    plant = KinematicPlant(st, DT)
    for k in range(40):
        cmd = ctrl.step(plant.state)
        if k % 7 == 0:
            ctrl._clock["crane"][1] = 0.6  # a slowed reference clock
        for offset in (0.0, 0.013):
            one = ctrl.reference_ahead(offset)
            many = ctrl.reference_at([offset])
            for got, want in zip(dataclasses.astuple(one), dataclasses.astuple(many)):
                np.testing.assert_array_equal(got, want[0])
        plant.apply(cmd)


def test_unit_interval_is_clip():
    from models.numeric import clip
    from wbc.controllers.controller import _unit_interval

    for x in (-0.0, 0.0, 1.0, -1.0, 2.0, 0.5, 1e-320, -1e-320, np.inf, -np.inf,
              np.float64(0.25), np.float64(-0.0), np.float64(3.0)):
        got, want = _unit_interval(x), float(clip(x, 0.0, 1.0))
        assert type(got) is float and got == want
        assert np.signbit(got) == np.signbit(want)
    assert np.isnan(_unit_interval(np.nan))
