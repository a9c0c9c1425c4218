"""TCP kinematics against finite differences and Pinocchio's own frame; TCP IK; TCP task."""

import numpy as np
import pinocchio as pin
import pytest

from models.pinocchio_model import build_pinocchio
from testkit.plant import make_state
from tests.conftest import random_independent
from wbc import (
    AxisLimits,
    IKError,
    QPContext,
    TcpKinematics,
    TcpPositionTask,
    VariableLayout,
    WbcInputError,
    solve_tcp_ik,
)
from wbc.kinematics.tcp_c import compiled_tcp_tree


@pytest.fixture(scope="module")
def kin(machine):
    return TcpKinematics(machine)


def test_position_matches_pinocchio_frame(machine, kin):
    rng = np.random.default_rng(0)
    pm = build_pinocchio(machine)
    for _ in range(5):
        st = make_state(machine, q=random_independent(machine, rng))
        q, _, _ = pm.configuration(st)
        pin.framesForwardKinematics(pm.model, pm.data, q)
        world = pm.data.oMf[pm.frame_id["tcp"]].translation
        # kin is in fb; the state's base is at base_position with identity rotation.
        np.testing.assert_allclose(kin.position(st.q) + st.base_position, world, atol=1e-12)
    for bad in (np.full(13, np.nan), np.zeros(12)):
        with pytest.raises(WbcInputError, match="q must be finite"):
            kin.position(bad)


def _full_position(full, q):
    """The TCP from the full tree's configuration (`_configuration`: every joint)."""
    qp, _, _ = full._configuration(q)
    pin.framesForwardKinematics(full.model, full.data, qp)
    return full.data.oMf[full.frame_id].translation.copy()


def test_position_is_the_full_configurations_bits(machine, kin):
    """`position` fills the TCP's supporting joints only, in C and in Python: the full
    tree's numbers, to the bit; the same typed errors."""
    from models.errors import StrokeOutOfRangeError

    rng = np.random.default_rng(3)
    full, python = TcpKinematics(machine), TcpKinematics(machine, compiled=False)
    assert python._tree_c is None
    for _ in range(50):
        q = random_independent(machine, rng)
        ref = _full_position(full, q)
        assert np.array_equal(kin.position(q), ref)
        assert np.array_equal(python.position(q), ref)
    for i in (0, 2, 4):  # a bogie's stroke (not computed), the slew's and the tilt's
        for side in (machine.coordinates.lower[i] - 0.1, machine.coordinates.upper[i] + 0.1):
            q = random_independent(machine, rng)
            q[i] = side
            for k in (kin, python):
                with pytest.raises(StrokeOutOfRangeError):
                    k.position(q)
    q = random_independent(machine, rng)
    q[10] = np.inf  # a wheel's angle: not used, still checked
    for k in (kin, python):
        with pytest.raises(WbcInputError, match="q must be finite"):
            k.position(q)


@pytest.mark.skipif(compiled_tcp_tree((), (), np.zeros(13), np.zeros(30)) is None,
                    reason="no C compiler")
def test_compiled_position_on_closed_loop_ticks_is_the_python_bits(machine, tmp_path):
    """The truth's coordinates of a closed loop's ticks (the harness's TCP error), with the
    strokes clipped as the harness does (`scenarios.truth_log`); and at the stroke ends."""
    from scenarios.closed_loop import run_closed_loop

    run_closed_loop("pick-in-motion", tmp_path, "tracking", duration=4.0)
    qs = np.load(tmp_path / "log.npz")["q"]
    coords = machine.coordinates
    fast, python = TcpKinematics(machine), TcpKinematics(machine, compiled=False)
    assert fast._tree_c is not None
    ends = [np.where(np.arange(13) == i, bound, qs[0]) for i in coords.chain_indices
            for bound in (coords.lower[i], coords.upper[i])]
    for q in [*qs, *ends]:
        q = q.copy()
        q[list(coords.chain_indices)] = coords.clip(q)[list(coords.chain_indices)]
        assert fast.position(q).tobytes() == python.position(q).tobytes()
    assert len(qs) >= 390


def test_jacobian_finite_differences(machine, kin):
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = random_independent(machine, rng, margin=0.1)
        jac = kin.jacobian(q)
        h = 1e-6
        fd = np.zeros((3, 9))
        for i in range(9):
            dq = np.zeros(13)
            dq[i] = h
            fd[:, i] = (kin.position(q + dq) - kin.position(q - dq)) / (2 * h)
        np.testing.assert_allclose(jac, fd, atol=1e-7)
        assert np.allclose(jac[:, :2], 0.0)  # the suspension does not move the TCP in fb


def test_bias_acceleration_finite_differences(machine, kin):
    rng = np.random.default_rng(2)
    q = random_independent(machine, rng, margin=0.1)
    qd = np.zeros(13)
    qd[:9] = 0.2 * rng.standard_normal(9)
    # d/dt (J(q(t)) qd) at constant qd is the TCP acceleration at zero qdd.
    h = 1e-6
    fd = (kin.jacobian(q + h * qd) @ qd[:9] - kin.jacobian(q - h * qd) @ qd[:9]) / (2 * h)
    np.testing.assert_allclose(kin.bias_acceleration(q, qd), fd, atol=1e-6)


def test_ik_round_trip(machine, kin):
    rng = np.random.default_rng(3)
    limits = AxisLimits.from_machine(machine)
    for _ in range(4):
        q_true = random_independent(machine, rng, margin=0.1)
        q_true[6:9] = make_state(machine).q[6:9]  # keep the wrist at home
        target = kin.position(q_true)
        q0 = make_state(machine).q
        res = solve_tcp_ik(kin, target, q0, limits, tolerance=1e-4)
        np.testing.assert_allclose(kin.position(res.q), target, atol=1e-4)
        assert np.all(res.q[:9] >= limits.position_lower - 1e-12)
        assert np.all(res.q[:9] <= limits.position_upper + 1e-12)
        np.testing.assert_allclose(res.q[:2], q0[:2])  # only crane axes move
    with pytest.raises(IKError):
        solve_tcp_ik(kin, [20.0, 0.0, 0.0], q0, limits)
    with pytest.raises(WbcInputError):
        solve_tcp_ik(kin, [1.0, 0.0], q0, limits)


def test_tcp_task_objective(machine, kin):
    limits = AxisLimits.from_machine(machine)
    qd = np.zeros(13)
    qd[2:9] = 0.05
    st = make_state(machine, qd=qd)
    ctx = QPContext.from_state(st, 0.01, VariableLayout(), limits)
    target = kin.position(st.q) + [0.1, 0.0, -0.1]
    task = TcpPositionTask(kin, target, kp=4.0, kd=3.0, weight=2.0)
    H, c = task.compute_qp_objective(ctx)
    J = kin.jacobian(st.q)
    a_star = 4.0 * (target - kin.position(st.q)) - 3.0 * (J @ qd[:9])
    e = kin.bias_acceleration(st.q, st.qd) - a_star
    np.testing.assert_allclose(H, 2.0 * J.T @ J, atol=1e-12)
    np.testing.assert_allclose(c, 2.0 * J.T @ e, atol=1e-12)
    assert not TcpPositionTask(kin).is_active(ctx)
