"""MPC: prediction, real-time-iteration force linearization, seeing the constraint coming."""

import numpy as np
import pytest

from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state
from wbc import (
    ConfigurationError,
    ControllerConfig,
    ForceConfig,
    JointGoal,
    MpcConfig,
    VariableLayout,
    WholeBodyQPController,
    load_estimator,
    make_controller,
)
from wbc.mpc import CondensedPrediction, predict_base_pose

DT = 0.01
TEL, RL = 5, 1


@pytest.mark.parametrize("first", [0.1, 0.01])
def test_condensed_prediction_matches_step_by_step_integration(first):
    rng = np.random.default_rng(0)
    layout = VariableLayout(n_axes=9, n_steps=12, speed_scale=True, n_slack=4)
    h = np.full(12, 0.1)
    h[0] = first
    pred = CondensedPrediction(layout, h)
    q0, qd0 = rng.standard_normal(9), rng.standard_normal(9)
    u = rng.standard_normal((12, 9))
    x = np.zeros(layout.n)
    x[layout.accelerations] = u.ravel()
    q, v = q0.copy(), qd0.copy()
    qs, vs = [], []
    for k in range(12):  # exact integration of a piecewise-constant acceleration
        q = q + h[k] * v + 0.5 * h[k] ** 2 * u[k]
        v = v + h[k] * u[k]
        qs.append(q)
        vs.append(v)
    qf, vf = pred.free_response(q0, qd0)
    np.testing.assert_allclose((pred.Pq @ x).reshape(12, 9) + qf, qs, atol=1e-12)
    np.testing.assert_allclose((pred.Pv @ x).reshape(12, 9) + vf, vs, atol=1e-12)
    ub, qb, vb = pred.brake_trajectory(q0, qd0, np.ones(9))
    assert np.all(np.abs(ub) <= 1.0 + 1e-12)
    stopped = np.abs(qd0) <= 1.0 * (h.sum() - 0.1) - 1e-9  # can stop within the horizon
    np.testing.assert_allclose(vb[-1][stopped], 0.0, atol=1e-12)


def test_constant_twist_base_prediction():
    from models import build_reference_machine
    s = make_state(build_reference_machine(), base_twist=[1.0, 0, 0, 0, 0, 0.5])
    p, R = predict_base_pose(s, 0.0)
    np.testing.assert_allclose(p, s.base_position)
    p, R = predict_base_pose(s, np.pi)  # a quarter turn about z at 0.5 rad/s
    np.testing.assert_allclose(R[:2, :2], [[0, -1], [1, 0]], atol=1e-12)
    np.testing.assert_allclose(p - s.base_position, [2.0, 2.0, 0.0], atol=1e-12)



def test_base_pose_is_pinocchios_product_to_the_bit():
    """`predict_base_pose` (kept start pose, exp6 of the vector) = ``T_0 exp6(Motion)``."""
    import pinocchio as pin

    from models import build_reference_machine
    machine = build_reference_machine()
    rng = np.random.default_rng(5)
    states = [make_state(machine, base_twist=rng.normal(0.0, 1.0, 6)).replace(
        base_position=rng.normal(0.0, 3.0, 3),
        base_rotation=pin.Quaternion(*rng.normal(size=4)).normalized().toRotationMatrix())
        for _ in range(4)]
    for k in range(40):  # alternating states: the kept pose follows the state asked for
        s, t = states[k % 3 if k < 20 else k % 4], float(rng.uniform(0.0, 2.0))
        m = (pin.SE3(s.base_rotation, s.base_position)
             * pin.exp6(pin.Motion(s.base_twist * t)))
        p, R = predict_base_pose(s, t)
        np.testing.assert_array_equal(p, m.translation)
        np.testing.assert_array_equal(R, m.rotation)

def _mpc(machine, model, **force):
    cfg = ControllerConfig(force=ForceConfig(**force))
    return make_controller("mpc-full", machine, cfg, force_model=model)


def _extension_model(machine, st):
    """f_RL = 3000 - 5000 (q_tel - q_tel0) [N]: at +0.4 m the wheel reaches 1000 N."""
    K = np.zeros((4, 13))
    K[RL, TEL] = -5000.0
    return AffineForceModel([9000.0, 3000.0, 9000.0, 9000.0], st.q, K, None)


def test_horizon_is_at_least_one_second(machine):
    with pytest.raises(ConfigurationError, match="shorter than 1 s"):
        ControllerConfig(mpc=MpcConfig(step=0.1, n_steps=10))  # 0.01 + 0.03 + 0.06 + 7 x 0.1 s
    st = make_state(machine)
    c = _mpc(machine, _extension_model(machine, st))
    assert c.horizon >= 1.0 - 1e-9  # 1 s up to round-off


def test_early_steps_refine_the_start_of_the_horizon(machine):
    assert MpcConfig().step_lengths(0.01).tolist() == pytest.approx([0.01, 0.03, 0.06]
                                                                     + [0.1] * 9)
    assert MpcConfig(early_steps=(), n_steps=11).step_lengths(0.01).tolist() == (
        pytest.approx([0.01] + [0.1] * 10))  # the grid before early_steps
    cfg = ControllerConfig(mpc=MpcConfig(early_steps=(0.02, 0.04, 0.04), n_steps=13))
    h = cfg.mpc.step_lengths(cfg.dt)
    assert h.tolist() == pytest.approx([cfg.dt, 0.02, 0.04, 0.04] + [0.1] * 9)
    st = make_state(machine)
    c = make_controller("mpc-full", machine, cfg, force_model=_extension_model(machine, st))
    assert c.layout.n_steps == 13 and c.horizon == pytest.approx(h.sum())
    c.set_goal(JointGoal(crane=st.q[2:9] + 0.05))
    plant = KinematicPlant(st, DT)
    for _ in range(20):
        cmd = c.step(plant.state)
        assert not cmd.fallback and np.all(np.isfinite(cmd.rates))
        plant.apply(cmd)
    with pytest.raises(ConfigurationError, match="shorter than 1 s"):
        ControllerConfig(mpc=MpcConfig(early_steps=(0.03, 0.06), n_steps=11))  # 0.9 s
    for bad in (0.03, None, (0.03, -0.01), ("a",), (0.01,) * 12, (float("nan"),)):
        with pytest.raises(ConfigurationError, match="early_steps"):
            MpcConfig(early_steps=bad)


def test_linearization_along_the_plan_is_exact_for_an_affine_model(machine):
    rng = np.random.default_rng(1)
    st = make_state(machine)
    G = 500.0 * rng.standard_normal((4, 19))
    K = 800.0 * rng.standard_normal((4, 13))
    model = AffineForceModel(np.full(4, 9000.0), st.q, K, G)
    c = _mpc(machine, model, speed_scale=False)
    goal = st.q[2:9] + np.array([0.05, 0.1, -0.05, 0.3, 0.2, 0.0, 0.0])
    c.set_goal(JointGoal(crane=goal))
    plant = KinematicPlant(st, DT)
    for _ in range(30):
        cmd = c.step(plant.state)
        plant.apply(cmd)
    calls = model.calls
    cmd = c.step(plant.state)
    assert model.calls - calls == c.config.mpc.n_linearizations  # flags from node 0's
    plan, f_pred = c.last_plan, cmd.info["predicted_forces"]
    s0 = plant.state
    for k in range(plan.inputs.shape[0]):
        q = s0.q.copy()
        qd = s0.qd.copy()
        if k > 0:
            q[:9], qd[:9] = plan.positions[k - 1], plan.velocities[k - 1]
        q[9:] += c.planner.prediction.start_times[k] * s0.qd[9:]
        qdd = np.concatenate([plan.inputs[k], np.zeros(4)])
        truth = model.estimate(make_state(machine, q=q, qd=qd, qdd=qdd)).normal_forces
        np.testing.assert_allclose(f_pred[k], truth, rtol=1e-9, atol=1e-6)


def _closed_loop(ctrl, model, st, steps):
    plant = KinematicPlant(st, DT)
    forces, accs, rates = [], [], []
    for _ in range(steps):
        cmd = ctrl.step(plant.state)
        assert not cmd.fallback
        plant.apply(cmd)
        forces.append(model.estimate(plant.state).normal_forces)
        accs.append(cmd.accelerations[TEL])
        rates.append(cmd.rates[TEL])
    return plant, np.array(forces), np.array(accs), np.array(rates)


def test_mpc_sees_the_force_constraint_coming(machine):
    st = make_state(machine)
    model = _extension_model(machine, st)
    goal = st.q[2:9].copy()
    goal[TEL - 2] += 0.55  # beyond the +0.4 m where wheel RL reaches its threshold
    thr = [1000.0] * 4
    # The tracking QP has no force model and drives the wheel far below the threshold.
    trk = make_controller("tracking", machine)
    trk.set_goal(JointGoal(crane=goal))
    _, f_trk, _, _ = _closed_loop(trk, model, st, 500)
    assert f_trk[:, RL].min() < 1000.0 - 600.0
    # A one-step QP with the force constraint is blind to the configuration change (G = 0
    # here): it only reacts once the force is already below the threshold.
    myopic = WholeBodyQPController(machine, ControllerConfig(force=ForceConfig(thresholds=thr)),
                                   force_model=model)
    myopic.set_goal(JointGoal(crane=goal))
    _, f_my, _, _ = _closed_loop(myopic, model, st, 500)
    assert f_my[:, RL].min() < 1000.0 - 100.0
    # The MPC brakes ahead and stops the telescope at the threshold.
    mpc = _mpc(machine, model, thresholds=thr)
    mpc.set_goal(JointGoal(crane=goal))
    plant, f, acc, rate = _closed_loop(mpc, model, st, 500)
    assert f[:, RL].min() >= 1000.0 - 5.0
    assert f[-1, RL] == pytest.approx(1000.0, abs=20.0)
    assert abs(plant.state.qd[TEL]) < 1e-3
    # It starts braking while the wheel still has a clear margin above the threshold.
    first_brake = np.flatnonzero((acc < -0.05) & (rate > 0.01))[0]
    assert f[first_brake, RL] > 1000.0 + 200.0


def test_mpc_wheel_speed_scale_and_warm_start(machine):
    """ProxQP (selectable) warm-starts from its second tick; DAQP, the default, is cold."""
    st = make_state(machine)
    cfg = ControllerConfig(solver="proxqp")
    c = make_controller("mpc-full", machine, cfg, force_model=_extension_model(machine, st))
    cmd = c.step(st)
    assert cmd.wheel_speed_scale == pytest.approx(1.0, abs=1e-6)
    assert not cmd.info["warm_started"]
    cmd = c.step(st)
    assert cmd.info["warm_started"]
    assert cmd.info["predicted_forces"].shape == (c.config.mpc.n_steps, 4)


@pytest.mark.parametrize("name", ["mpc-full", "mpc-quasi-static"])
def test_mpc_with_the_estimator(machine, name):
    method = name.removeprefix("mpc-")
    model = load_estimator(machine, method)
    c = make_controller(name, machine, force_model=model)
    st = make_state(machine)
    goal = st.q[2:9].copy()
    goal[0] += 0.1  # slew: moves load onto one side
    goal[3] += 0.3
    c.set_goal(JointGoal(crane=goal))
    plant = KinematicPlant(st, DT)
    thr = c.force_thresholds
    for _ in range(200):
        cmd = c.step(plant.state)
        assert not cmd.fallback
        assert np.all(np.isfinite(cmd.rates))
        # Step 0 of the plan is exact: the estimator's forces at the commanded acceleration.
        s = plant.state
        qdd = np.concatenate([cmd.accelerations, np.zeros(4)])
        truth = model.estimate(make_state(machine, q=s.q, qd=s.qd, qdd=qdd, time=s.time))
        np.testing.assert_allclose(cmd.info["predicted_forces"][0], truth.normal_forces,
                                   rtol=1e-6, atol=1e-3)
        plant.apply(cmd)
        f = model.estimate(plant.state).normal_forces
        assert np.all(f >= thr - 50.0)


def test_weights_can_change_between_ticks(machine):
    """Cached Hessians follow a change of weights (the cache is keyed by them)."""
    st = make_state(machine)
    c = _mpc(machine, _extension_model(machine, st))
    goal = st.q[2:9].copy()
    goal[3] += 0.2
    c.set_goal(JointGoal(crane=goal))
    c.step(st)
    task = c.planner.tasks[0]
    ctx = c.context(st)
    P1, w1 = c.prepare(st).P.copy(), task.compute_weight(ctx)
    task.position_weight = 2.0 * task.position_weight
    P2, w2 = c.prepare(st).P, task.compute_weight(ctx)
    J = task.compute_jacobian(ctx)
    np.testing.assert_allclose(P2 - P1, J.T @ ((w2 - w1)[:, None] * J), atol=1e-8)
    assert not np.allclose(P1, P2)


def test_kept_and_direct_task_costs_are_the_products(machine):
    """Every MPC task's ``(H, c)`` = `Task.compute_qp_objective`'s ``J^T W J, J^T W e``.

    The cached Hessians and constant costs, and the costs written without ``J^T W``
    (`HorizonInputTask`, `HorizonSmoothnessTask`: one nonzero term an entry), on random
    references and previous accelerations: c to the bit (an exact zero added to a finite
    sum changes nothing but a zero's sign, which `assert_array_equal` does not see).
    """
    from dataclasses import replace

    from wbc.context import ReferenceSample
    from wbc.tasks import SlackPenaltyTask
    from wbc.tasks.task import Task
    st = make_state(machine)
    c = _mpc(machine, _extension_model(machine, st))
    c.set_goal(JointGoal(crane=st.q[2:9] + 0.1))
    c.step(st)
    rng = np.random.default_rng(3)
    ctx = c.context(st)
    N = ctx.layout.n_steps
    for k in range(5):
        ref = ReferenceSample(*(rng.normal(0.0, 1.0, (N + 1, 9)) for _ in range(3)))
        ctx = replace(ctx, reference=ref, previous_acceleration=rng.normal(0.0, 1.0, 9)
                      * (k > 0))
        for task in c.planner.tasks:
            if task.is_active(ctx):
                H, cost = task.compute_qp_objective(ctx)
                H_ref, cost_ref = Task.compute_qp_objective(task, ctx)
                if isinstance(task, SlackPenaltyTask):  # and its linear term
                    cost_ref[ctx.layout.slack] += task.linear
                np.testing.assert_array_equal(H, H_ref)
                np.testing.assert_array_equal(cost, cost_ref, err_msg=type(task).__name__)


def test_node_times_are_kept_per_prediction(machine):
    st = make_state(machine)
    planner = _mpc(machine, _extension_model(machine, st)).planner
    pred = planner.prediction
    for _ in range(2):
        np.testing.assert_array_equal(planner.node_times, np.r_[0.0, pred.times])
        np.testing.assert_array_equal(planner.node_starts, np.r_[pred.start_times,
                                                                 pred.horizon])
        assert not planner.node_times.flags.writeable
        assert not planner.node_starts.flags.writeable
    planner.prediction = CondensedPrediction(planner.layout, 2 * pred.step_lengths)
    assert planner.node_times[-1] == pytest.approx(2 * pred.horizon)
