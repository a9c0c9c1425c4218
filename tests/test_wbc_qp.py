"""Whole-body QP: the Problem is what the tasks and constraints say; limits hold."""

import numpy as np
import pytest
import qpsolvers

from testkit.plant import KinematicPlant, make_state
from wbc import (
    CRANE_AXES,
    AccelerationLimit,
    AxisLimits,
    Box,
    ControlCommand,
    DampingTask,
    Inequality,
    JointGoal,
    JointTask,
    PositionLimit,
    ProxQPWorkspace,
    QPContext,
    ReferenceSample,
    SuspensionPostureTask,
    VariableLayout,
    VelocityLimit,
    build_qp,
    make_controller,
)

DT = 0.01


@pytest.fixture(scope="module")
def limits(machine):
    return AxisLimits.from_machine(machine)


def _ctx(machine, limits, q=None, qd=None, ref=None, layout=None):
    st = make_state(machine, q=q, qd=qd)
    return QPContext.from_state(st, DT, layout or VariableLayout(), limits, ref)


def _solve(problem):
    return ProxQPWorkspace(eps_abs=1e-10).solve(problem).x


def test_no_task_gives_zero_motion(machine, limits):
    ctx = _ctx(machine, limits)
    cons = [AccelerationLimit(), VelocityLimit(), PositionLimit()]
    x = _solve(build_qp(ctx, [], cons))
    np.testing.assert_allclose(x, 0.0, atol=1e-9)
    # And a controller without a goal keeps a machine at rest still.
    c = make_controller("tracking", machine)
    cmd = c.step(make_state(machine))
    np.testing.assert_allclose(cmd.rates, 0.0, atol=1e-9)
    assert cmd.wheel_speed_scale == 1.0 and not cmd.fallback


def test_met_task_gives_zero_motion(machine, limits):
    st = make_state(machine)
    q9 = st.q[:9]
    ref = ReferenceSample(q9.copy(), np.zeros(9), np.zeros(9))
    ctx = _ctx(machine, limits, ref=ref)
    tasks = [JointTask(CRANE_AXES, 16.0, 8.0), SuspensionPostureTask(), DampingTask()]
    x = _solve(build_qp(ctx, tasks, [AccelerationLimit(), VelocityLimit(), PositionLimit()]))
    np.testing.assert_allclose(x, 0.0, atol=1e-9)
    c = make_controller("tracking", machine)
    c.set_goal(JointGoal(crane=st.q[2:9], suspension=st.q[:2]))
    for _ in range(3):
        cmd = c.step(st)
        np.testing.assert_allclose(cmd.rates, 0.0, atol=1e-9)


def test_problem_matrices_are_what_tasks_and_constraints_say(machine, limits):
    rng = np.random.default_rng(0)
    st = make_state(machine)
    qd = np.zeros(13)
    qd[:9] = 0.05 * rng.standard_normal(9)
    ref = ReferenceSample(st.q[:9] + 0.02 * rng.standard_normal(9),
                          0.05 * rng.standard_normal(9), 0.1 * rng.standard_normal(9))
    ctx = _ctx(machine, limits, qd=qd, ref=ref)
    kp, kd, w = 9.0, 6.0, 2.0
    joint = JointTask(CRANE_AXES, kp, kd, w)
    damp = DampingTask(0.5, 1e-3)
    cons = [AccelerationLimit(), VelocityLimit(), PositionLimit()]
    reg = 1e-9
    prob = build_qp(ctx, [joint, damp], cons, regularization=reg)
    assert isinstance(prob, qpsolvers.Problem)
    # Cost: 1/2 ||S x - qdd*||^2 w + 1/2 ||x + qd/T||^2 w_d, written out by hand.
    S = np.zeros((7, 9))
    S[np.arange(7), CRANE_AXES] = 1.0
    qdd_star = (ref.acceleration + kp * (ref.position - ctx.q) + kd * (ref.velocity - ctx.qd))
    P = w * S.T @ S + 1e-3 * np.eye(9) + reg * np.eye(9)
    q = -w * S.T @ qdd_star[CRANE_AXES] + 1e-3 * ctx.qd / 0.5
    np.testing.assert_allclose(prob.P, P, atol=1e-12)
    np.testing.assert_allclose(prob.q, q, atol=1e-12)
    # Bounds: the intersection of the three boxes, each one as its docstring says.
    a = limits.acceleration
    brake = -np.clip(ctx.qd / DT, -a, a)
    v_lo = np.minimum((limits.velocity_lower - ctx.qd) / DT, brake)
    v_hi = np.maximum((limits.velocity_upper - ctx.qd) / DT, brake)
    boxes = [c.compute(ctx) for c in cons]
    assert all(isinstance(b, Box) for b in boxes)
    np.testing.assert_allclose(boxes[0].lower, -a)
    np.testing.assert_allclose(boxes[1].lower, v_lo)
    np.testing.assert_allclose(boxes[1].upper, v_hi)
    np.testing.assert_allclose(prob.lb, np.max([b.lower for b in boxes], axis=0))
    np.testing.assert_allclose(prob.ub, np.min([b.upper for b in boxes], axis=0))
    assert prob.G is None and prob.A is None
    # The solution is the unconstrained optimum clipped where a bound is active.
    x = _solve(prob)
    assert np.all(x >= prob.lb - 1e-8) and np.all(x <= prob.ub + 1e-8)
    x_free = np.linalg.solve(P, -q)
    inside = (x_free > prob.lb) & (x_free < prob.ub)
    np.testing.assert_allclose(x[inside], x_free[inside], atol=1e-7)


def test_position_limit_bounds(machine, limits):
    st = make_state(machine)
    q = st.q.copy()
    i = 5  # telescope
    q[i] = limits.position_upper[i] - 0.01
    qd = np.zeros(13)
    qd[i] = 0.3
    ctx = _ctx(machine, limits, q=q, qd=qd)
    box = PositionLimit(braking_fraction=0.5).compute(ctx)
    b = 0.5 * limits.acceleration[i]
    v_next = -b * DT + np.sqrt((b * DT) ** 2 + 2 * b * max(0.01 - 0.3 * DT / 2, 0))
    viab = (v_next - 0.3) / DT
    horizon = 2 * (0.01 - 0.3 * DT) / DT**2
    brake = -min(0.3 / DT, limits.acceleration[i])
    assert box.upper[i] == pytest.approx(max(min(viab, horizon), brake))
    # Past the limit and moving out: braking is still admitted (never infeasible).
    q[i] = limits.position_upper[i] + 0.02
    ctx = _ctx(machine, limits, q=q, qd=qd)
    box = PositionLimit().compute(ctx)
    assert box.lower[i] <= brake <= box.upper[i]
    assert box.upper[i] == pytest.approx(brake)  # nothing but braking is allowed


def test_limits_hold_in_closed_loop(machine, limits):
    """Goals at the ends of the ranges: positions, rates, accelerations stay inside."""
    c = make_controller("tracking", machine)
    st = make_state(machine)
    plant = KinematicPlant(st, DT)
    goal = limits.position_upper[CRANE_AXES].copy()
    goal[4:] = limits.position_lower[CRANE_AXES][4:]
    c.set_goal(JointGoal(crane=goal, suspension=limits.position_lower[:2]))
    prev = plant.state.qd[:9].copy()
    for _ in range(800):
        cmd = c.step(plant.state)
        assert np.all(cmd.rates <= limits.velocity_upper + 1e-9)
        assert np.all(cmd.rates >= limits.velocity_lower - 1e-9)
        assert np.all(np.abs(cmd.rates - prev) <= limits.acceleration * DT + 1e-7)
        plant.apply(cmd)
        prev = cmd.rates.copy()
        q = plant.state.q[:9]
        assert np.all(q <= limits.position_upper + 1e-9)
        assert np.all(q >= limits.position_lower - 1e-9)
    np.testing.assert_allclose(plant.state.q[2:9], goal, atol=2e-3)


def test_position_limit_stops_a_fast_axis(machine, limits):
    """An axis driven at the limit at full speed stops before it (viability bound)."""
    ctx_layout = VariableLayout()
    i = 5
    q = make_state(machine).q.copy()
    q[i] = limits.position_upper[i] - 0.2
    qd = np.zeros(13)
    qd[i] = limits.velocity_upper[i]
    plant = KinematicPlant(make_state(machine, q=q, qd=qd), DT)
    for _ in range(300):
        st = plant.state
        ref = ReferenceSample(st.q[:9].copy(), np.zeros(9), np.zeros(9))
        ref.position[i] = 10.0  # pull far beyond the limit
        ctx = QPContext.from_state(st, DT, ctx_layout, limits, ref)
        prob = build_qp(ctx, [JointTask([i], 16.0, 8.0), DampingTask()],
                        [AccelerationLimit(), VelocityLimit(), PositionLimit()])
        x = _solve(prob)
        rates = np.clip(st.qd[:9] + x * DT, limits.velocity_lower, limits.velocity_upper)
        plant.apply(ControlCommand(rates, 1.0, x))
        assert plant.state.q[i] <= limits.position_upper[i] + 1e-9
    assert abs(plant.state.qd[i]) < 1e-3
    assert plant.state.q[i] > limits.position_upper[i] - 1e-3


def test_qpsolvers_backend_agrees(machine, limits):
    """The Problem solves to the same x through qpsolvers' own ProxQP interface."""
    rng = np.random.default_rng(5)
    st = make_state(machine)
    ref = ReferenceSample(st.q[:9] + 0.3 * rng.standard_normal(9), np.zeros(9), np.zeros(9))
    ctx = _ctx(machine, limits, ref=ref)
    prob = build_qp(ctx, [JointTask(CRANE_AXES, 16, 8), DampingTask()],
                    [AccelerationLimit(), VelocityLimit(), PositionLimit()])
    x = _solve(prob)
    sol = qpsolvers.solve_problem(prob, solver="proxqp", eps_abs=1e-10, eps_rel=0.0)
    np.testing.assert_allclose(x, sol.x, atol=1e-7)


def test_inequality_type_is_checked(machine, limits):
    from wbc import Constraint, WbcError

    class Bad(Constraint):
        def compute(self, ctx):
            return Inequality(np.zeros((1, 3)), np.zeros(1))

    with pytest.raises(WbcError, match="expected"):
        build_qp(_ctx(machine, limits), [], [Bad()])


def test_diagonal_blocks_are_passed_on_and_checked(machine, limits):
    from wbc import Constraint, WbcError
    from wbc.constraints import DiagonalBlocks

    class Rows(Constraint):
        def __init__(self, blocks):
            self.blocks = blocks

        def compute(self, ctx):
            return Inequality(np.zeros((4, ctx.layout.n)), np.zeros(4), self.blocks)

    ctx = _ctx(machine, limits)
    good = DiagonalBlocks(2, 0, 4, 2)
    qp = build_qp(ctx, [], [Rows(None), Rows(good)])
    assert qp.diagonal_rows == ((4, good),)
    for bad in (DiagonalBlocks(3, 0, 4, 2), DiagonalBlocks(2, 3, 4, 2)):
        with pytest.raises(WbcError, match="DiagonalBlocks"):
            build_qp(ctx, [], [Rows(bad)])


def test_rows_of_g_are_reused_only_when_nobody_holds_them(machine, limits):
    """`QPBuilder` writes the last tick's G again when only it holds that array: the values
    are the concatenation's, and a problem kept by its caller is never written."""
    from wbc import Constraint
    from wbc.qp import QPBuilder

    ctx = _ctx(machine, limits)
    n = ctx.layout.n
    block = np.arange(3.0 * n).reshape(3, n)
    block.setflags(write=False)
    rng = np.random.default_rng(2)

    class Rows(Constraint):
        def __init__(self, G):
            self.G = G

        def compute(self, ctx):
            self.last = rng.normal(size=(2, n)) if self.G is None else self.G
            return Inequality(self.last, np.zeros(self.last.shape[0]))

    rows = [Rows(None), Rows(block), Rows(None)]
    builder = QPBuilder([], rows)
    first = builder.build(ctx)
    kept, kept_G, kept_id = first.G.copy(), first.G, id(first.G)
    del first
    for _ in range(3):
        qp = builder.build(ctx)
        assert id(qp.G) != kept_id  # the caller still holds the first array
        assert np.array_equal(qp.G, np.concatenate([r.last for r in rows]))
        assert qp.constant_rows == ((2, block),)
        last_id = id(qp.G)
        del qp
    assert np.array_equal(kept_G, kept)
    assert id(builder.build(ctx).G) == last_id  # nobody held it: written again


def test_diagonal_rows_reused_write_their_blocks_only(machine, limits):
    """Rows with the last tick's `DiagonalBlocks` in the same place: only the blocks are
    written into the reused G (zeros elsewhere in both); other blocks, or another place,
    the whole rows. G is the concatenation's every tick."""
    from wbc import Constraint
    from wbc.constraints import DiagonalBlocks
    from wbc.qp import QPBuilder

    ctx = _ctx(machine, limits)
    n = ctx.layout.n
    rng = np.random.default_rng(5)

    class Rows(Constraint):
        def __init__(self, m, blocks):
            self.m, self.blocks = m, blocks

        def compute(self, ctx):
            d = self.blocks
            G = rng.normal(size=(self.m, n))
            if d is not None:
                mask = np.zeros((self.m, n), bool)
                for k in range(d.n_blocks):
                    mask[k * d.rows:(k + 1) * d.rows,
                         d.first + k * d.width:d.first + (k + 1) * d.width] = True
                G[~mask] = 0.0
            self.last = G
            return Inequality(G, np.zeros(self.m), d)

    constant = np.ones((2, n))
    constant.setflags(write=False)

    class Constant(Constraint):
        def compute(self, ctx):
            self.last = constant
            return Inequality(constant, np.zeros(2))

    diagonal = Rows(6, DiagonalBlocks(2, 0, 3, 3))
    rows = [Rows(2, None), Constant(), diagonal]
    builder = QPBuilder([], rows)
    ids = set()
    for blocks in [diagonal.blocks] * 3 + [DiagonalBlocks(3, 1, 4, 2)] * 2 + [None]:
        diagonal.blocks = blocks
        qp = builder.build(ctx)
        assert np.array_equal(qp.G, np.concatenate([r.last for r in rows]))
        ids.add(id(qp.G))
        del qp
    assert len(ids) == 1  # reused throughout


def _limit_boxes(ctx, limits, T, fraction):
    """Both limits' boxes written out as the docstrings' formulas, both sides apart."""
    q, qd, a = ctx.q, ctx.qd, limits.acceleration
    brake = -np.clip(qd / DT, -a, a)
    b = fraction * a

    def bound(d, v):
        rest = np.maximum(d - 0.5 * v * DT, 0.0)
        viable = -(b * DT) + np.sqrt((b * DT) ** 2 + (2.0 * b) * rest)
        return np.minimum(2.0 * (d - v * T) / T**2, (viable - v) / DT)

    pos = (np.minimum(-bound(q - limits.position_lower, -qd), brake),
           np.maximum(bound(limits.position_upper - q, qd), brake))
    vel = (np.minimum((limits.velocity_lower - qd) / DT, brake),
           np.maximum((limits.velocity_upper - qd) / DT, brake))
    return pos, vel


def test_limit_boxes_are_their_formulas_to_the_bit(machine, limits):
    """The in-place arithmetic of the limits computes the formulas' very numbers."""
    rng = np.random.default_rng(4)
    layouts = (VariableLayout(), VariableLayout(9, 1, speed_scale=True, n_slack=4))
    pos_limits = (PositionLimit(), PositionLimit(horizon=0.05, braking_fraction=0.7))
    vel_limit = VelocityLimit()
    kept = []
    for k in range(300):
        layout, con = layouts[k % 2], pos_limits[k // 2 % 2]
        q = make_state(machine).q.copy()
        q[:9] = rng.uniform(limits.position_lower - 0.03, limits.position_upper + 0.03)
        qd = np.zeros(13)
        qd[:9] = rng.uniform(-1.3, 1.3, 9) * limits.velocity_upper
        qd[rng.integers(9)] = 0.0
        ctx = _ctx(machine, limits, q=q, qd=qd, layout=layout)
        T = DT if con.horizon is None else con.horizon
        pos, vel = _limit_boxes(ctx, limits, T, con.braking_fraction)
        for box, (lower, upper) in ((con.compute(ctx), pos), (vel_limit.compute(ctx), vel)):
            np.testing.assert_array_equal(box.lower[:9], lower)
            np.testing.assert_array_equal(box.upper[:9], upper)
            assert np.isneginf(box.lower[9:]).all() and np.isposinf(box.upper[9:]).all()
            kept.append((box, box.lower.copy(), box.upper.copy()))
    for box, lower, upper in kept:  # a later call does not write into an earlier box
        np.testing.assert_array_equal(box.lower, lower)
        np.testing.assert_array_equal(box.upper, upper)


def test_context_from_state_sets_every_field(machine, limits):
    import dataclasses

    st = make_state(machine, qd=np.linspace(-0.1, 0.1, 13))
    ref = ReferenceSample(st.q[:9], np.zeros(9), np.zeros(9))
    ctx = QPContext.from_state(st, DT, VariableLayout(), limits, ref, 0.7)
    full = QPContext(st, st.q[:9], st.qd[:9], DT, VariableLayout(), limits, ref, 0.7)
    for f in dataclasses.fields(QPContext):
        np.testing.assert_array_equal(getattr(ctx, f.name), getattr(full, f.name))
    assert not ctx.q.flags.writeable and not ctx.qd.flags.writeable
    assert ctx.brake is ctx.brake and not ctx.brake.flags.writeable
    np.testing.assert_array_equal(ctx.brake, limits.brake_acceleration(ctx.qd, DT))
    with pytest.raises(dataclasses.FrozenInstanceError):
        ctx.dt = 0.02


def test_kept_costs_of_constant_errors_are_the_formula(machine, limits):
    """`SpeedScaleTask`, `SlackPenaltyTask`: ``c`` kept (read-only) = ``J^T W e`` (+ rho_1)."""
    from wbc.tasks import SlackPenaltyTask, SpeedScaleTask
    layout = VariableLayout(speed_scale=True, n_slack=4)
    ctx = _ctx(machine, limits, layout=layout)
    slack, scale = SlackPenaltyTask(7.0, 3.0), SpeedScaleTask(5.0)
    for task, linear in ((slack, 7.0), (scale, 0.0)):
        for _ in range(2):  # built, then kept
            H, c = task.compute_qp_objective(ctx)
            jac = task.compute_jacobian(ctx)
            want = (jac.T * task.weight) @ task.compute_error(ctx)
            if linear:
                want[layout.slack] += linear
            np.testing.assert_array_equal(c, want)
            assert not c.flags.writeable
    slack.linear = 9.0  # a new rho_1 is seen at once
    assert slack.compute_qp_objective(ctx)[1][layout.slack].tolist() == [9.0] * 4
