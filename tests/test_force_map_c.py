"""The MPC's force map in C (`wbc.constraints.force_map_c`) against its numpy version."""

import dataclasses

import numpy as np
import pytest

from models.state import WheelContacts
from testkit.force_models import AffineForceModel
from testkit.plant import KinematicPlant, make_state, moving_mpc
from wbc import ControllerConfig, ForceConfig, JointGoal, MpcConfig, MpcController
from wbc.axes import SUSPENSION_AXES
from wbc.constraints.force_map_c import compiled_force_map
from wbc.force_models.feedback import DIAGONAL, ClosureFeedback

DT = 0.01

pytestmark = pytest.mark.skipif(compiled_force_map() is None, reason="no C compiler")


def _both(con, ctx):
    """``forces_map`` through C and through numpy."""
    con.compiled = True
    A, b = con.forces_map(ctx)
    con.compiled = False
    try:
        A_ref, b_ref = con.forces_map(ctx)
    finally:
        con.compiled = True
    return (A, b), (A_ref, b_ref)


def _check(con, ctx):
    (A, b), (A_ref, b_ref) = _both(con, ctx)
    assert A.shape == A_ref.shape and b.shape == b_ref.shape
    # A's input columns hold single products (numpy's sums add exact zeros): the same
    # bits; the speed scale's column is a sum over the accelerations: round-off.
    inputs = ctx.layout.accelerations
    np.testing.assert_array_equal(A[:, inputs], A_ref[:, inputs])
    np.testing.assert_allclose(A, A_ref, rtol=1e-13, atol=1e-12 * np.abs(A_ref).max())
    np.testing.assert_allclose(b, b_ref, rtol=1e-13, atol=1e-9 * np.abs(b_ref).max())
    return A, b


def _affine_mpc(machine, speed_scale: bool):
    st = dataclasses.replace(make_state(machine), suspension_force=np.array([3e4, 3e4]))
    rng = np.random.default_rng(7)
    K = 2e3 * rng.standard_normal((4, 13))
    G = 300.0 * rng.standard_normal((4, 19))
    model = AffineForceModel(np.full(4, 9000.0), st.q, K, G)
    closure = AffineForceModel(9000.0 + 1200.0 * DIAGONAL, st.q, K, G)
    cfg = ControllerConfig(force=ForceConfig(speed_scale=speed_scale), mpc=MpcConfig())
    ctrl = MpcController(machine, cfg, force_model=model, feedback=ClosureFeedback(closure))
    goal = st.q[2:9] + np.array([0.05, -0.05, 0.05, 0.2, 0.0, 0.0, 0.0])
    ctrl.set_goal(JointGoal(crane=goal, suspension=st.q[SUSPENSION_AXES] + 0.02))
    plant = KinematicPlant(dataclasses.replace(
        st, qd=np.r_[st.qd[:9], np.full(4, 1.5)],
        base_twist=np.array([0.4, 0.0, 0.0, 0.01, -0.02, 0.03])), DT)
    for _ in range(6):
        plant.apply(ctrl.step(plant.state))
    return ctrl, plant.state


@pytest.mark.parametrize("speed_scale", [False, True])
def test_every_term_matches_numpy(machine, speed_scale):
    """Feedback bias, warp, terrain drift, terminal rows, the speed scale's column."""
    ctrl, st = _affine_mpc(machine, speed_scale)
    ctx = ctrl.context(st)
    assert ctx.warp is not None and ctx.feedback is not None
    drift = np.linspace(-300.0, 800.0, ctx.n_steps + 1)
    ctx = dataclasses.replace(ctx, warp_drift=drift, speed_scale=0.7)
    A, b = _check(ctrl.force_constraint, ctx)
    if speed_scale:
        assert np.any(A[:, ctx.layout.scale] != 0.0)
    # Each term shows: without the drift, b changes by exactly its kron with DIAGONAL.
    _, b0 = _check(ctrl.force_constraint, dataclasses.replace(ctx, warp_drift=None))
    expect = np.kron(drift, DIAGONAL)
    if speed_scale:
        expect = expect - expect * 0.7 / 0.7
    np.testing.assert_allclose(b - b0, expect, atol=1e-6)


def test_three_wheels_and_no_feedback_match_numpy(machine):
    ctrl, st = _affine_mpc(machine, True)
    lifted = WheelContacts(np.array([True, True, False, True]), np.zeros((4, 3)),
                           np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    ctx = ctrl.context(dataclasses.replace(st, contacts=lifted))
    _check(ctrl.force_constraint, dataclasses.replace(
        ctx, warp_drift=np.ones(ctx.n_steps + 1)))
    _check(ctrl.force_constraint, dataclasses.replace(ctx, feedback=None, warp=None))


def test_estimator_rows_match_numpy(machine):
    """The real model: its linearizations carry kernel rows (read in place, by offsets)."""
    ctrl, plant = moving_mpc(machine, dt=DT)
    ctx = ctrl.context(plant.state)
    lins = ctrl.force_constraint.linearize(ctx)[1]
    assert "_row" in lins[0].__dict__
    A, b = _check(ctrl.force_constraint, ctx)
    assert np.all(np.isfinite(A)) and np.abs(b).max() > 1e3


def test_sizes_that_do_not_fit_are_refused():
    """More nodes than the steps and a terminal node: -1, nothing written."""
    kernel = compiled_force_map()
    shape = dataclasses.make_dataclass("S", ["n_eval", "which", "j", "lq", "lv", "since_j",
                                             "decay"])
    struct = shape(5, np.zeros(5, int), np.zeros(5, int), np.zeros((2, 2)), np.zeros((2, 2)),
                   np.zeros((5, 1)), np.zeros((5, 1)))
    kernel._buffers(struct, 2, 18, None, (1, 184))
    A, b = np.full(1, 7.0), np.full(1, 7.0)
    assert kernel._fun(kernel.pointers, kernel._iv_at, kernel._dv_at, A.ctypes.data,
                       b.ctypes.data) == -1
    assert A[0] == 7.0 and b[0] == 7.0
