"""Normal-force constraint of the whole-body QP, with a synthetic affine force model."""

import numpy as np
import pytest

import models
from testkit.force_models import AffineForceModel
from testkit.plant import make_state
from wbc import (
    CRANE_AXES,
    AccelerationLimit,
    AxisLimits,
    DampingTask,
    ForceModelError,
    Inequality,
    JointTask,
    NormalForceConstraint,
    ProxQPWorkspace,
    QPContext,
    ReferenceSample,
    SlackPenaltyTask,
    SpeedScaleLimit,
    SpeedScaleTask,
    VariableLayout,
    VelocityLimit,
    WholeBodyQPController,
    build_qp,
    load_estimator,
)
from wbc.constraints.force_rows import lifted_wheel_thresholds
from wbc.force_models import (
    ForceLinearization,
    contact_flags,
    linearize_forces,
    linearized_contact_flags,
)

DT = 0.01
TEL = 5  # telescope axis (and index in q)
RL = 1


@pytest.fixture(scope="module")
def limits(machine):
    return AxisLimits.from_machine(machine)


@pytest.fixture(scope="module")
def estimator_full(machine):
    """The project's full-dynamics estimator."""
    return load_estimator(machine, "full")


def _model(q_ref, g_tel=0.0, k_tel=0.0, f0=3000.0, **kw):
    """Extending the telescope (accelerating it or moving it out) unloads wheel RL."""
    G = np.zeros((4, 19))
    G[RL, 6 + TEL] = g_tel
    K = np.zeros((4, 13))
    K[RL, TEL] = k_tel
    return AffineForceModel([10000.0, f0, 10000.0, 10000.0], q_ref, K, G, **kw)


def _telescope_problem(machine, limits, model, thresholds=1000.0, soft=False, qd_tel=0.0,
                       lookahead=0.0, contacts=None):
    qd = np.zeros(13)
    qd[TEL] = qd_tel
    st = make_state(machine, qd=qd, contacts=contacts)
    ref = ReferenceSample(st.q[:9].copy(), np.zeros(9), np.zeros(9))
    ref.position[TEL] += 1.0  # far: the PD asks for more than the acceleration limit
    layout = VariableLayout(n_slack=4 if soft else 0)
    ctx = QPContext.from_state(st, DT, layout, limits, ref)
    con = NormalForceConstraint(model, thresholds, lookahead=lookahead, force_scale=1e4)
    tasks = [JointTask([TEL], 16.0, 8.0), DampingTask()]
    if soft:
        tasks.append(SlackPenaltyTask())
    prob = build_qp(ctx, tasks, [AccelerationLimit(), VelocityLimit(), con])
    x = ProxQPWorkspace(eps_abs=1e-10).solve(prob).x
    return ctx, con, prob, x


def test_force_constraint_binds_when_the_model_says_so(machine, limits):
    st = make_state(machine)
    # Free: the telescope accelerates at its limit (1 m/s^2).
    _, _, prob, x = _telescope_problem(machine, limits, _model(st.q, g_tel=0.0))
    assert x[TEL] == pytest.approx(limits.acceleration[TEL], abs=1e-6)
    # f_RL = 3000 - 4000 a_tel >= 1000  =>  a_tel <= 0.5: the constraint binds.
    model = _model(st.q, g_tel=-4000.0)
    ctx, con, prob, x = _telescope_problem(machine, limits, model)
    assert x[TEL] == pytest.approx(0.5, abs=1e-6)
    A, b = con.last_forces_map
    assert (A @ x + b)[RL] == pytest.approx(1000.0, abs=1e-3)
    # The Problem's rows are the constraint's: -(A x + b)/f_s <= -f_min/f_s, one per wheel.
    assert prob.G.shape == (4, 9)
    np.testing.assert_allclose(prob.G, -A / 1e4)
    np.testing.assert_allclose(prob.h, (b - 1000.0) / 1e4)
    # The oracle: the model's own forces at the solution's accelerations.
    st2 = make_state(machine, qdd=np.concatenate([x, np.zeros(4)]))
    assert model.estimate(st2).normal_forces[RL] == pytest.approx(1000.0, abs=1e-3)


def test_soft_constraint_is_exact_when_feasible(machine, limits):
    st = make_state(machine)
    model = _model(st.q, g_tel=-4000.0)
    _, _, _, x_hard = _telescope_problem(machine, limits, model)
    _, _, prob, x_soft = _telescope_problem(machine, limits, model, soft=True)
    assert prob.G.shape == (4, 13)
    np.testing.assert_allclose(x_soft[:9], x_hard, atol=1e-6)
    np.testing.assert_allclose(x_soft[9:], 0.0, atol=1e-6)
    # Infeasible threshold: the soft QP still solves, with the least violation.
    _, _, _, x = _telescope_problem(machine, limits, model, thresholds=[0, 9000.0, 0, 0],
                                    soft=True)
    assert x[TEL] == pytest.approx(-limits.acceleration[TEL], abs=1e-5)
    assert x[9 + RL] > 0


def test_only_wheels_in_contact_are_constrained(machine, limits):
    st = make_state(machine)
    model = _model(st.q, g_tel=-4000.0)
    contacts = models.WheelContacts(np.array([True, False, True, True]), np.zeros((4, 3)),
                                    np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    _, con, prob, x = _telescope_problem(machine, limits, model, contacts=contacts)
    assert prob.G.shape == (3, 9)
    assert x[TEL] == pytest.approx(limits.acceleration[TEL], abs=1e-6)
    # Flags from the model's estimate when the state has no measured contacts.
    model_flags = _model(st.q, g_tel=-4000.0, in_contact=[True, True, False, False])
    _, _, prob, _ = _telescope_problem(machine, limits, model_flags)
    assert prob.G.shape == (2, 9)
    # No wheel in contact: the constraint is inactive.
    off = models.WheelContacts(np.zeros(4, bool), np.zeros((4, 3)), np.zeros((4, 3)),
                               np.tile([0.0, 0.0, 1.0], (4, 1)))
    ctx, con, prob, _ = _telescope_problem(machine, limits, model, contacts=off)
    assert prob.G is None and con.compute(ctx) is None


def test_lifted_wheel_threshold_goes_to_its_neighbours(machine, limits):
    t = np.array([1000.0, 2000.0, 3000.0, 4000.0])  # FL, RL, FR, RR
    np.testing.assert_array_equal(lifted_wheel_thresholds(t, np.ones(4, bool)), t)
    # RL lifted: its neighbours are FL and RR (the other diagonal), not its partner FR.
    np.testing.assert_array_equal(lifted_wheel_thresholds(t, [True, False, True, True]),
                                  [3000.0, 2000.0, 3000.0, 6000.0])
    np.testing.assert_array_equal(lifted_wheel_thresholds(t, [False, True, True, False]),
                                  [1000.0, 7000.0, 8000.0, 4000.0])
    # In the QP: extending the telescope unloads FL, f_FL = 3000 - 4000 a >= f_min.
    st = make_state(machine)
    G = np.zeros((4, 19))
    G[0, 6 + TEL] = -4000.0
    model = AffineForceModel([3000.0, 10000.0, 10000.0, 10000.0], st.q, np.zeros((4, 13)), G)
    _, _, _, x = _telescope_problem(machine, limits, model)
    assert x[TEL] == pytest.approx(0.5, abs=1e-6)
    contacts = models.WheelContacts(np.array([True, False, True, True]), np.zeros((4, 3)),
                                    np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    _, _, _, x = _telescope_problem(machine, limits, model, contacts=contacts)
    assert x[TEL] == pytest.approx(0.25, abs=1e-6)  # FL keeps 1000 N more for RL


def test_lookahead_uses_the_configuration_derivative(machine, limits):
    st = make_state(machine)
    # f_RL = 3000 - 4000 (q_tel - q0): over T = 1 s, q_tel moves by 0.3 + x / 2.
    model = _model(st.q, k_tel=-4000.0)
    _, _, _, x = _telescope_problem(machine, limits, model, qd_tel=0.3, lookahead=0.0)
    assert x[TEL] > 0.9  # blind to the configuration change
    _, _, _, x = _telescope_problem(machine, limits, model, qd_tel=0.3, lookahead=1.0)
    assert x[TEL] == pytest.approx(0.4, abs=1e-6)


def test_speed_scale_is_a_lever_on_the_forces(machine, limits):
    """Braking the carrier loads wheel FL; the QP slows down just enough."""
    st = make_state(machine, base_twist=[1.0, 0, 0, 0, 0, 0])
    G = np.zeros((4, 19))
    G[0, 0] = -2000.0  # f_FL grows when the base decelerates (a_x < 0)
    model = AffineForceModel([600.0, 5000.0, 5000.0, 5000.0], st.q, None, G)
    layout = VariableLayout(speed_scale=True)
    ctx = QPContext.from_state(st, DT, layout, limits, None, speed_scale=1.0)
    con = NormalForceConstraint(model, 1000.0, drive_time_constant=0.5)
    prob = build_qp(ctx, [DampingTask(), SpeedScaleTask(10.0)],
                    [AccelerationLimit(), con, SpeedScaleLimit(0.0, rate=30.0)])
    x = ProxQPWorkspace(eps_abs=1e-10).solve(prob).x
    # a_x = (s - 1) v / tau = 2 (s - 1);  600 - 2000 a_x >= 1000  =>  s <= 0.9.
    assert x[9] == pytest.approx(0.9, abs=1e-6)
    # The rate limit bounds the change per tick.
    assert SpeedScaleLimit(0.2, 0.5).bounds(1.0, DT) == pytest.approx((0.995, 1.0))
    assert SpeedScaleLimit(0.2, 0.5).bounds(0.2, DT) == pytest.approx((0.2, 0.205))


def test_controller_with_force_model_reports_predicted_forces(machine):
    st = make_state(machine)
    model = _model(st.q, g_tel=-4000.0)
    ctrl = WholeBodyQPController(machine, force_model=model)
    cmd = ctrl.step(st)
    assert cmd.info["predicted_forces"].shape == (4,)
    np.testing.assert_allclose(cmd.info["predicted_forces"], model.f_static, atol=1e-3)
    assert ctrl.layout.n == 9 + 1 + 4


def test_model_errors(machine):
    st = make_state(machine)

    class Broken(AffineForceModel):
        def linearize(self, state):
            lin = super().linearize(state)
            return ForceLinearization(lin.normal_forces, np.full((4, 19), np.nan), lin.g0,
                                      lin.d_q, lin.d_qd, lin.in_contact, lin.mode)
    with pytest.raises(ForceModelError, match="G has non-finite"):
        linearize_forces(Broken(np.zeros(4), st.q), st)

    class Raises(AffineForceModel):
        def linearize(self, state):
            raise ArithmeticError("singular")
    with pytest.raises(ForceModelError, match="singular"):
        linearize_forces(Raises(np.zeros(4), st.q), st)

    class Untyped(AffineForceModel):
        def linearize(self, state):
            return np.zeros((4, 13))
    with pytest.raises(ForceModelError, match="ForceLinearization"):
        linearize_forces(Untyped(np.zeros(4), st.q), st)
    assert isinstance(Inequality(np.zeros((1, 2)), np.zeros(1)).G, np.ndarray)


def test_real_estimator_affine_form_is_exact(machine, limits, estimator_full):
    """QP forces ``A x + b`` equal the estimator's forces at the solution (independent)."""
    st = make_state(machine)
    ref = ReferenceSample(st.q[:9] + 0.1, np.zeros(9), np.zeros(9))
    ctx = QPContext.from_state(st, DT, VariableLayout(), limits, ref)
    con = NormalForceConstraint(estimator_full, 0.1 * machine.total_mass * 9.81 / 4)
    prob = build_qp(ctx, [JointTask(CRANE_AXES, 16.0, 8.0), DampingTask()],
                    [AccelerationLimit(), VelocityLimit(), con])
    x = ProxQPWorkspace().solve(prob).x
    A, b = con.last_forces_map
    st2 = make_state(machine, qdd=np.concatenate([x, np.zeros(4)]))
    np.testing.assert_allclose(A @ x + b, estimator_full.estimate(st2).normal_forces,
                               rtol=1e-9, atol=1e-6)


def test_kept_rows_follow_the_contact_flags_and_thresholds(machine, limits):
    """One constraint object across flag and threshold changes: the rows it keeps for a
    pattern are those a fresh constraint makes."""
    st = make_state(machine)
    model = _model(st.q, g_tel=-4000.0)
    layout = VariableLayout(n_slack=4)
    ref = ReferenceSample(st.q[:9].copy(), np.zeros(9), np.zeros(9))
    kept = NormalForceConstraint(model, 1000.0, force_scale=1e4)
    patterns = [[True] * 4, [True, False, True, True], [True] * 4, [False, True, True, False]]
    for k, flags in enumerate(patterns):
        if k == 2:
            kept.thresholds = np.array([900.0, 1000.0, 1100.0, 1200.0])
        contacts = models.WheelContacts(np.array(flags), np.zeros((4, 3)), np.zeros((4, 3)),
                                        np.tile([0.0, 0.0, 1.0], (4, 1)))
        ctx = QPContext.from_state(make_state(machine, contacts=contacts), DT, layout,
                                   limits, ref)
        fresh = NormalForceConstraint(model, kept.thresholds, force_scale=1e4)
        a, b = kept.compute(ctx), fresh.compute(ctx)
        assert np.array_equal(a.G, b.G) and np.array_equal(a.h, b.h)
        assert a.G.shape[0] == sum(flags)


@pytest.mark.parametrize("method", ["full", "quasi-static"])
def test_flags_read_from_the_linearization_are_contact_flags(machine, limits, method):
    """The estimator linearizes with its estimate's flags: the force rows take the flags now
    from their linearization at the state, with measured contacts or without."""
    from testkit.estimator_states import random_state

    model = load_estimator(machine, method)
    rng = np.random.default_rng(4)
    ref = ReferenceSample(np.zeros(9), np.zeros(9), np.zeros(9))
    for k in range(6):
        st = random_state(machine, rng, max_tilt=0.2)
        if k % 2:
            flags = np.array([True, True, k != 3, True])
            st = st.replace(contacts=models.WheelContacts(
                flags, np.zeros((4, 3)), model.contact_points(st), np.tile([0, 0, 1.0], (4, 1))))
        expected = contact_flags(model, st)
        lin = linearize_forces(model, st)
        assert np.array_equal(linearized_contact_flags(st, lin), expected)
        con = NormalForceConstraint(model, 1000.0)
        con.compute(QPContext.from_state(st, DT, VariableLayout(), limits, ref))
        assert np.array_equal(con.last_in_contact, expected)
