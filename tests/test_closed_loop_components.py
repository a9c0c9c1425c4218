"""The pieces the closed loop added to the MPC: load-split feedback, warp, drift, leveling,
servo state, the guarded estimator, terminal rows; and the comparison plot."""

import dataclasses
import json

import numpy as np
import pytest

from models.state import MachineState, WheelContacts
from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state
from wbc import (
    ControllerConfig,
    ForceConfig,
    ForceModelError,
    JointGoal,
    MpcConfig,
    MpcController,
)
from wbc.axes import N_AXES, SUSPENSION_AXES
from wbc.controllers.registry import estimator_models
from wbc.controllers.servo_state import ServoState
from wbc.force_models import ForceLinearization, linearize_forces
from wbc.force_models.feedback import (
    DIAGONAL,
    ClosureFeedback,
    ForceFeedback,
    WarpDrift,
    leveling_offset,
    warp_matrix,
)
from wbc.tasks import HorizonLevelingTask

DT = 0.01


def test_leveling_offset_equalizes_the_smallest_margins():
    f = np.array([25000.0, 18000.0, 7000.0, 0.0])
    thr = np.full(4, 1000.0)
    d = leveling_offset(f, thr)
    g = f + d * DIAGONAL
    assert min(g[0], g[3]) == pytest.approx(min(g[1], g[2]))  # both diagonals' minima
    for other in (d - 100.0, d + 100.0):  # and no other split does better
        assert (f + other * DIAGONAL).min() < g.min()
    assert leveling_offset(f, thr, limit=500.0) == 500.0
    # A wheel out of contact counts as unloaded, whatever the force says.
    assert leveling_offset([9e3, 9e3, 9e3, 9e3], thr, [True, True, True, False]) > 0


def test_warp_matrix_twists_along_the_diagonal():
    W = warp_matrix(2.0e6)
    assert W.shape == (4, N_AXES)
    np.testing.assert_allclose(W[:, SUSPENSION_AXES[0]], 2.0e6 * DIAGONAL)
    np.testing.assert_allclose(W[:, SUSPENSION_AXES[1]], -2.0e6 * DIAGONAL)
    assert np.count_nonzero(W[:, 2:]) == 0
    dq = np.zeros(N_AXES)
    dq[SUSPENSION_AXES] = (1e-4, 1e-4)  # both bogies alike: no twist
    np.testing.assert_allclose(W @ dq, 0.0)


def _feedback(forces, t, contact=(True,) * 4):
    return ForceFeedback(np.asarray(forces, float), np.zeros(4), np.asarray(contact), t)


def test_warp_drift_measures_the_terrain_twist_rate():
    k_w = 1e6
    drift = WarpDrift(k_w, time_constant=0.02, horizon=0.3)
    rate = 5000.0  # [N/s] along the diagonal, with the setpoints still
    for i in range(100):
        t = i * DT
        drift.update(_feedback(10000.0 + rate * t * DIAGONAL, t), 0.0)
    assert drift.rate == pytest.approx(rate, rel=1e-3)
    np.testing.assert_allclose(drift.drift([0.1, 1.0]), [0.1 * rate, 0.3 * rate])
    # The same twist made by the suspension setpoints is no terrain drift.
    drift.reset()
    for i in range(100):
        t = i * DT
        drift.update(_feedback(10000.0 + rate * t * DIAGONAL, t), rate * t / k_w)
    assert abs(drift.rate) < 1e-6
    drift.update(_feedback(np.full(4, 1e4), 2.0, (True, True, False, True)), 0.0)
    assert drift.rate == 0.0


def test_servo_state_integrates_commands_and_filters_the_deflection(machine):
    lo, hi = np.full(N_AXES, -1.0), np.full(N_AXES, 1.0)
    servo = ServoState(DT, 0.5, lo, hi)
    st0 = make_state(machine)
    st = dataclasses.replace(st0, servo_setpoint=st0.q[:N_AXES].copy())
    q, qd = servo.observe(st)
    np.testing.assert_allclose(q, st.q[:N_AXES])
    rates = np.full(N_AXES, 0.01)
    for _ in range(10):
        servo.commanded(rates)
    np.testing.assert_allclose(servo.setpoint, st.q[:N_AXES] + 0.1 * rates, atol=1e-12)
    # A stroke bouncing about its setpoint is seen through the filter, the suspension not.
    bounce = 1e-3
    q2 = st.q.copy()
    q2[:N_AXES] = servo.setpoint + bounce
    st2 = dataclasses.replace(make_state(machine, q=q2, time=0.1),
                              servo_setpoint=servo.setpoint.copy())
    q, qd = servo.observe(st2)
    np.testing.assert_allclose(qd, rates)
    seen = q - servo.setpoint
    np.testing.assert_allclose(seen[2:], bounce * 0.1 / (0.5 + 0.1))  # first-order filter
    np.testing.assert_allclose(seen[SUSPENSION_AXES], 0.0)
    # A servo setpoint far from the integrated one (clipped, wound down) wins.
    st3 = dataclasses.replace(make_state(machine, time=0.2),
                              servo_setpoint=servo.setpoint - 0.05)
    servo.observe(st3)
    np.testing.assert_allclose(servo.setpoint, st3.servo_setpoint)


def _contacts_without(model, st, wheel):
    """Measured contacts at the model's own contact points, ``wheel`` off the ground."""
    flags = np.ones(4, bool)
    flags[wheel] = False
    return WheelContacts(flags, np.zeros((4, 3)), model.estimate(st).contact_points,
                         np.tile([0.0, 0.0, 1.0], (4, 1)))


def test_mpc_force_model_clips_strokes_and_has_finite_derivatives_off_a_wheel(machine):
    """The estimator as the MPC loads it: valid strokes in, finite derivatives out."""
    model, _ = estimator_models(machine, "full")
    st = make_state(machine)
    contacts = _contacts_without(model, st, 1)
    off = make_state(machine, contacts=contacts)
    lin = linearize_forces(model, off)
    fd = np.zeros((4, 13))  # the oracle: central differences of the forces
    for j in range(13):
        vals = []
        for step in (-1e-6, 1e-6):
            q = off.q.copy()
            q[j] += step
            vals.append(model.estimate(make_state(machine, q=q, contacts=contacts))
                        .normal_forces)
        fd[:, j] = (vals[1] - vals[0]) / 2e-6
    np.testing.assert_allclose(lin.d_q, fd, rtol=1e-6, atol=1e-3)
    n_clipped = model.n_clipped
    bad = make_state(machine, q=np.r_[st.q[:2], [5.0], st.q[3:]])  # slew far past its end
    assert linearize_forces(model, bad).clipped == ("slew",)
    assert model.n_clipped == n_clipped + 1
    with pytest.raises(ForceModelError):
        linearize_forces(_AlwaysNan(), st)


class _AlwaysNan:
    def linearize(self, state):
        return ForceLinearization(np.zeros(4), np.zeros((4, 19)), np.zeros(4),
                                  np.full((4, 13), np.nan), np.zeros((4, 13)),
                                  np.ones(4, bool), "d-beta")


def _mpc_with_feedback(machine, bias=1500.0, **mpc):
    # Measured cylinder forces: the closure's bias applies only with them.
    st = dataclasses.replace(make_state(machine), suspension_force=np.array([3e4, 3e4]))
    rng = np.random.default_rng(2)
    K = 2e3 * rng.standard_normal((4, 13))
    G = 300.0 * rng.standard_normal((4, 19))
    K[:, SUSPENSION_AXES] = 0.0  # with the warp model the suspension acts through it only
    G[:, 6 + SUSPENSION_AXES] = 0.0
    model = AffineForceModel(np.full(4, 9000.0), st.q, K, G)
    closure = AffineForceModel(9000.0 + bias * DIAGONAL, st.q, K, G)
    cfg = ControllerConfig(force=ForceConfig(speed_scale=False),
                           mpc=MpcConfig(**mpc))
    ctrl = MpcController(machine, cfg, force_model=model,
                         feedback=ClosureFeedback(closure))
    return ctrl, model, st


def test_horizon_forces_with_feedback_warp_drift_and_terminal_rows(machine):
    ctrl, model, st = _mpc_with_feedback(machine)
    goal = st.q[2:9] + np.array([0.05, -0.05, 0.05, 0.2, 0.0, 0.0, 0.0])
    ctrl.set_goal(JointGoal(crane=goal))
    plant = KinematicPlant(st, DT)
    for _ in range(5):
        plant.apply(ctrl.step(plant.state))
    s0 = plant.state
    ctx = ctrl.context(s0)
    drift = np.linspace(0.0, 800.0, ctx.n_steps + 1)
    ctx = dataclasses.replace(ctx, warp_drift=drift)
    A, b = ctrl.force_constraint.forces_map(ctx)
    N, lay, pred = ctx.n_steps, ctx.layout, ctx.prediction
    assert A.shape[0] == 4 * (N + 1)
    x = np.random.default_rng(3).standard_normal(lay.n) * 0.1
    u = x[lay.accelerations].reshape(N, N_AXES)
    Q, V = pred.trajectory(ctx.q, ctx.qd, u)
    f = (A @ x + b).reshape(N + 1, 4)
    K, G = model.K, model.G
    W = warp_matrix(ctrl.config.force.warp_stiffness)
    bias = 1500.0 * DIAGONAL
    times = np.append(pred.start_times, pred.horizon)
    for k in range(N + 1):
        q = s0.q.copy()  # step 0: the measured state
        if k > 0:
            q[:N_AXES] = Q[k - 1]
        q[N_AXES:] += times[k] * s0.qd[N_AXES:]
        if k < N:
            acc = u[k]
        else:  # terminal node: brake to rest in T_b
            acc = -V[-1] / ctrl.config.mpc.terminal_brake_time
        warp = W @ (q[:N_AXES] - ctx.q) if k > 0 else 0.0
        expect = (model.f_static + K @ (q - model.q_ref) + G[:, 6:6 + N_AXES] @ acc + bias
                  + warp + drift[k] * DIAGONAL)
        np.testing.assert_allclose(f[k], expect, rtol=1e-9, atol=1e-6, err_msg=f"step {k}")


def test_lifted_wheel_frees_the_warp_and_loads_its_neighbours(machine):
    ctrl, model, st = _mpc_with_feedback(machine)
    plant = KinematicPlant(st, DT)
    for _ in range(3):
        plant.apply(ctrl.step(plant.state))
    s4 = plant.state
    lifted = WheelContacts(np.array([True, False, True, True]), np.zeros((4, 3)),
                           np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    s3 = dataclasses.replace(s4, contacts=lifted)
    drift = np.linspace(0.0, 800.0, ctrl.layout.n_steps + 1)
    ctx4 = dataclasses.replace(ctrl.context(s4), warp_drift=drift)
    ctx3 = dataclasses.replace(ctrl.context(s3), warp_drift=drift)
    con = ctrl.force_constraint
    A4, b4 = con.forces_map(ctx4)
    A3, b3 = con.forces_map(ctx3)
    # On three wheels the suspension's warp and the terrain's twist move no load: the
    # difference is exactly the warp model's terms.
    x = np.random.default_rng(4).standard_normal(ctx4.layout.n) * 0.1
    u = x[ctx4.layout.accelerations].reshape(ctx4.n_steps, N_AXES)
    Q, _ = ctx4.prediction.trajectory(ctx4.q, ctx4.qd, u)
    W = warp_matrix(ctrl.config.force.warp_stiffness)
    diff = ((A4 - A3) @ x + b4 - b3).reshape(-1, 4)
    np.testing.assert_allclose(diff[0], drift[0] * DIAGONAL, atol=1e-6)
    for k in range(1, diff.shape[0]):
        np.testing.assert_allclose(diff[k], W @ (Q[k - 1] - ctx4.q) + drift[k] * DIAGONAL,
                                   rtol=1e-9, atol=1e-6)
    # The rows: RL's threshold is added to its neighbours FL and RR, none for RL itself.
    f_min = con.thresholds
    ineq = con.compute(ctx3)
    rows = ineq.h.size // 3
    h = ineq.h.reshape(rows, 3) * con.force_scale
    f3 = b3.reshape(-1, 4)[con._constrained_nodes(ctx3, b3.size // 4)[0]]
    np.testing.assert_allclose(f3[:, [0, 2, 3]] - h,
                               np.tile(f_min[[0, 2, 3]] + f_min[1] * np.array([1, 0, 1]),
                                       (rows, 1)), atol=1e-6)


def test_force_rows_start_at_the_configured_time(machine):
    ctrl, _, st = _mpc_with_feedback(machine, force_constraint_start=0.05)
    ctrl.step(st)
    ineq = ctrl.force_constraint.compute(ctrl.context(st))
    # Steps starting at 0, 0.01 and 0.04 s (the first step, the first early step) have no
    # rows; the other N - 3 steps and the terminal node have one per wheel.
    assert ctrl.planner.prediction.start_times[:4] == pytest.approx([0.0, 0.01, 0.04, 0.1])
    assert ineq.G.shape[0] == 4 * (ctrl.layout.n_steps - 3 + 1)


def test_leveling_task_residual_is_the_warp_it_names(machine):
    ctrl, _, st = _mpc_with_feedback(machine)
    ctrl.step(st)
    ctx = dataclasses.replace(ctrl.context(st), leveling_offset=700.0,
                              warp_drift=np.full(ctrl.layout.n_steps + 1, 300.0))
    task = HorizonLevelingTask(1.0, 1e4)
    x = np.random.default_rng(4).standard_normal(ctx.layout.n) * 0.1
    r = task.compute_jacobian(ctx) @ x + task.compute_error(ctx)
    u = x[ctx.layout.accelerations].reshape(ctx.n_steps, N_AXES)
    Q, _ = ctx.prediction.trajectory(ctx.q, ctx.qd, u)
    k_w = ctrl.config.force.warp_stiffness
    twist = (Q[:, 0] - Q[:, 1]) - (ctx.q[0] - ctx.q[1])
    np.testing.assert_allclose(r, (k_w * twist + 300.0 - 700.0) / 1e4, rtol=1e-9, atol=1e-12)


def test_mpc_levels_the_chassis_through_the_suspension(machine):
    """A measured split off the best one moves the suspension setpoints apart, the right way."""
    ctrl, _, st = _mpc_with_feedback(machine, bias=-3000.0)  # FL, RR light: twist +n
    plant = KinematicPlant(st, DT)
    for _ in range(30):
        plant.apply(ctrl.step(plant.state))
    twist = ctrl.servo.setpoint[0] - ctrl.servo.setpoint[1]
    assert twist > 0.0  # +n loads FL and RR
    assert ctrl.last_feedback is not None and ctrl.last_feedback.bias[0] == pytest.approx(
        -3000.0)


def test_set_force_model_swaps_the_model_and_the_feedback(machine):
    ctrl, model, st = _mpc_with_feedback(machine)
    heavier = AffineForceModel(np.full(4, 9500.0), st.q)
    ctrl.set_force_model(heavier, ClosureFeedback(heavier))
    cmd = ctrl.step(st)
    assert ctrl.force_constraint.model is heavier
    np.testing.assert_allclose(cmd.info["measured_forces"], 9500.0)
    ctrl.set_force_model(heavier)  # no feedback: no warp model either
    assert ctrl.feedback is None and ctrl.warp is None


def test_closure_feedback_without_cylinder_forces_has_no_bias(machine):
    st = make_state(machine)
    model = AffineForceModel(np.full(4, 9000.0), st.q)
    closure = AffineForceModel(np.full(4, 9000.0) + 500.0 * DIAGONAL, st.q)
    fb = ClosureFeedback(closure).measure(st, model)
    np.testing.assert_allclose(fb.bias, 0.0)  # the state has no suspension_force
    st2 = MachineState(st.base_position, st.base_rotation, st.base_twist,
                       st.base_acceleration, st.q, st.qd, st.qdd,
                       suspension_force=np.array([3e4, 3e4]))
    np.testing.assert_allclose(ClosureFeedback(closure).measure(st2, model).bias,
                               500.0 * DIAGONAL)


def test_plot_and_comparison_files(tmp_path):
    from scenarios.closed_loop import SCENARIOS, run_closed_loop
    from scenarios.closed_loop_plots import plot_comparison
    from scenarios.comparison import run_comparison

    short = dataclasses.replace(SCENARIOS["swing-out"], duration=1.2)
    dirs = {}
    for name in ("tracking", "mpc-full"):
        dirs[name] = tmp_path / name
        run_closed_loop(short, dirs[name], name)
    png = plot_comparison(dirs, tmp_path / "forces.png")
    assert png.stat().st_size > 10_000
    report = run_comparison("pick-place-slope", tmp_path / "cmp", duration=1.1)
    saved = json.loads((tmp_path / "cmp" / "comparison.json").read_text())
    assert set(saved["metrics"]) == {"tracking", "mpc-quasi-static", "mpc-full"}
    assert "mpc_full_within_30_percent_of_tracking" in saved["acceptance"]
    assert (tmp_path / "cmp" / "forces.png").exists()
    assert report["scenario"] == "pick-place-slope"


def test_frozen_heap_keeps_the_loop_out_of_the_collector():
    """Inside the loop's context the objects alive before it are frozen (the oldest
    generation's pass does not walk them); after it, and after an error, they are not."""
    import gc

    from scenarios.closed_loop import frozen_heap

    held = [object() for _ in range(1000)]
    with frozen_heap():
        assert gc.get_freeze_count() >= len(held)
    assert gc.get_freeze_count() == 0
    with pytest.raises(RuntimeError), frozen_heap():
        raise RuntimeError("a failing tick")
    assert gc.get_freeze_count() == 0




def test_the_task_distance_is_numpys_norm_to_the_bit():
    from scenarios.closed_loop import _distance

    rng = np.random.default_rng(11)
    for _ in range(500):
        a, b = rng.normal(size=3) * 10.0 ** rng.integers(-4, 3), rng.normal(size=3)
        assert _distance(a, b) == float(np.linalg.norm(a - b))
