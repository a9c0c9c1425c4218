"""Many linearizations in one compiled call (`estimators.linearize_batch`) against one by one."""

from dataclasses import replace

import numpy as np
import pytest

from estimators.linearize_batch import linearize_first, linearize_rows, linearize_states
from estimators.payload import PayloadEstimator
from models import build_reference_machine
from models.coordinates import WHEELS
from models.state import WheelContacts
from testkit.estimator_states import random_state
from testkit.plant import KinematicPlant, make_state
from wbc import ControllerConfig, JointGoal, MpcController
from wbc.axes import N_AXES
from wbc.controllers.registry import estimator_models
from wbc.mpc.prediction import nominal_state, predict_base_rotations

MACHINE = build_reference_machine()


@pytest.fixture(scope="module")
def est():
    e = PayloadEstimator(MACHINE, strokes="clip")
    if e._est.backend != "compiled":
        pytest.skip("no C compiler")
    return e


def _nodes(state, rng, n=4):
    """Times, rotations and axes of ``n`` nominal states near ``state``, in range."""
    dt = np.sort(rng.uniform(0.0, 1.5, n))
    q = state.q[:N_AXES] + 0.01 * rng.standard_normal((n, N_AXES))
    qd = state.qd[:N_AXES] + 0.1 * rng.standard_normal((n, N_AXES))
    return dt, predict_base_rotations(state, dt), q, qd


def _one_by_one(est, state, dt, q, qd):
    return [est._est.linearize(nominal_state(state, t, a, v)) for t, a, v in zip(dt, q, qd)]


def _state(rng, contacts=None, suspension_force=None):
    s = random_state(MACHINE, rng, max_tilt=0.3, speed=0.3, margin=0.05)
    return replace(s, contacts=contacts, suspension_force=suspension_force)


@pytest.mark.parametrize("measured", [False, True])
def test_the_same_bits_as_one_call_per_state(est, measured):
    rng = np.random.default_rng(11)
    for _ in range(3):
        contacts = None
        if measured:
            contacts = WheelContacts(np.array([True, True, False, True]),
                                     rng.normal(size=(4, 3)), 100 * rng.normal(size=(4, 3)),
                                     np.tile([0.0, 0.0, 1.0], (4, 1)))
        state = _state(rng, contacts, rng.uniform(2e4, 5e4, 2))
        est.payload_mass = rng.uniform(0.0, 400.0)
        dt, rot, q, qd = _nodes(state, rng)
        got = est.linearize_states(state, dt, rot, q, qd)
        want = _one_by_one(est, state, dt, q, qd)
        assert got is not None and len(got) == len(want)
        for a, b in zip(got, want):
            for name in ("normal_forces", "G", "g0", "d_q", "d_qd", "in_contact"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
                assert not getattr(a, name).flags.writeable
            assert (a.mode, a.clipped, a.time) == (b.mode, b.clipped, b.time)
            np.testing.assert_array_equal(a.__dict__["_row"], b.__dict__["_row"])


def test_the_other_coordinates_move_at_their_velocities(est):
    """The wheels (after the given axes) turn on at their speed: q + dt qd."""
    rng = np.random.default_rng(2)
    state = replace(_state(rng), qd=np.r_[np.zeros(N_AXES), [1.0, -2.0, 3.0, 0.5]])
    dt, rot, q, qd = _nodes(state, rng, 2)
    got = est.linearize_states(state, dt, rot, q, qd)
    want = _one_by_one(est, state, dt, q, qd)
    assert nominal_state(state, dt[1], q[1], qd[1]).q[WHEELS].tolist() != \
        state.q[WHEELS].tolist()
    np.testing.assert_array_equal(got[1].d_q, want[1].d_q)


def test_what_it_leaves_to_one_by_one(est):
    """Out of range, tipping, non-finite: None, nothing counted; no rows: None."""
    rng = np.random.default_rng(4)
    state = _state(rng)
    dt, rot, q, qd = _nodes(state, rng, 3)
    clipped = est.n_clipped
    far = q.copy()
    far[1, 2] = 50.0  # a stroke far past its range
    assert est.linearize_states(state, dt, rot, far, qd) is None
    assert est.n_clipped == clipped
    huge = qd.copy()
    huge[2] = 1e300
    assert est.linearize_states(state, dt, rot, q, huge) is None
    tipping = WheelContacts(np.array([True, False, False, True]), np.zeros((4, 3)),
                            np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    assert est.linearize_states(replace(state, contacts=tipping), dt, rot, q, qd) is None
    assert linearize_states(est._est, state, dt[:0], rot[:0], q[:0], qd[:0]) is None
    assert est.linearize_states(state, dt, rot, q, qd) is not None  # and still works


def test_predicted_rotations_are_pinocchios_bits(est):
    """`linearize_rows` predicts the base rotations in C: `predict_base_rotations`' bits.

    Twists from 1e-9 rad/s to a few rad/s, rotation angles just under and over the end
    of exp6's Taylor branch (eps^(1/4) ~ 1.2e-4 rad, where its terms show in the bits), and
    dt = 0.
    """
    rng = np.random.default_rng(5)
    for k in range(90):
        twist = rng.standard_normal(6) * 10.0 ** rng.uniform(-9, 0.5)
        dt, _, q, qd = _nodes(_state(rng), rng, 3)
        if k % 3 == 1:  # the middle node's angle near the branch's end
            twist[3:] *= rng.uniform(3e-5, 3e-4) / (np.linalg.norm(twist[3:]) * dt[1])
        if k % 4 == 0:
            dt[0] = 0.0
        state = replace(_state(rng), base_twist=twist)
        rot = predict_base_rotations(state, dt)
        want = est.linearize_states(state, dt, rot, q, qd)
        got = est.linearize_rows(state, dt, q, qd)
        if want is None:
            assert got is None
            continue
        np.testing.assert_array_equal(got, np.stack([w.__dict__["_row"] for w in want]))
        # the rotations themselves (most of their last bits vanish in the rows)
        np.testing.assert_array_equal(est._est._calls.__dict__["linearize_rows"].rot[:3], rot)


def test_rows_are_a_kept_buffer(est):
    """Rows of the thread's buffer (no copy), overwritten by the next call; None as before."""
    rng = np.random.default_rng(6)
    state = _state(rng)
    dt, rot, q, qd = _nodes(state, rng, 3)
    rows = est.linearize_rows(state, dt, q, qd)
    kept = rows.copy()
    assert est.linearize_rows(state, dt[:2], q[:2] + 1e-3, qd[:2]).base is rows.base
    assert not np.array_equal(rows[:2], kept[:2])
    far = q.copy()
    far[1, 2] = 50.0
    assert est.linearize_rows(state, dt, far, qd) is None
    assert linearize_rows(est._est, state, dt[:0], q[:0], qd[:0]) is None


def _same_linearization(a, b):
    np.testing.assert_array_equal(a.__dict__["_row"], b.__dict__["_row"])
    np.testing.assert_array_equal(a.in_contact, b.in_contact)
    assert (a.mode, a.clipped, a.time) == (b.mode, b.clipped, b.time)
    assert not a.__dict__["_row"].flags.writeable


def test_the_first_row_is_linearize(est):
    """`linearize_first`: the state's linearization is `linearize`'s bits.

    Measured contacts, three wheels, cylinder forces, payloads, strokes past their ends
    (clipped and counted; the later nodes past them too: no rows, node 0 still given).
    """
    rng = np.random.default_rng(12)
    n_clipped = 0
    seen = set()
    for k in range(24):
        contacts = None
        if k % 3 == 1:
            contacts = WheelContacts(np.array([True, True, k % 2 == 0, k % 2 == 1]),
                                     100 * rng.normal(size=(4, 3)), rng.normal(size=(4, 3)),
                                     np.tile([0.0, 0.0, 1.0], (4, 1)))
        state = _state(rng, contacts, rng.uniform(2e4, 5e4, 2) if k % 2 else None)
        _, _, i, _, upper = est._est._packer.ranges[k % 3]
        if k % 4 == 2:  # a stroke past its end
            q = state.q.copy()
            q[i] = upper + 0.01
            state = replace(state, q=q)
        est.payload_mass = rng.uniform(0.0, 400.0)
        dt, rot, q, qd = _nodes(state, rng, 2 + k % 2)
        if k % 8 == 2:  # the later nodes in range (else they are left to one by one)
            q[:, i] = upper - 0.01
        before = est.n_clipped
        done = linearize_first(est._est, state, dt, q, qd)
        assert done is not None
        counted = est.n_clipped - before
        ref = est._est.linearize(state)
        assert est.n_clipped - before == 2 * counted  # counted once by each
        n_clipped += counted
        _same_linearization(done[0], ref)
        rows = None if done[1] is None else done[1].copy()
        seen.add((counted, rows is None))
        want = est.linearize_rows(state, dt, q, qd)
        assert (rows is None) == (want is None)
        if rows is not None:
            np.testing.assert_array_equal(rows, want)
    assert n_clipped == 6 and seen >= {(0, False), (1, False), (1, True)}


def test_what_the_first_row_leaves_to_linearize():
    """Out of range under ``strokes="raise"``, tipping: None, nothing counted."""
    strict = PayloadEstimator(MACHINE)
    if strict._est.backend != "compiled":
        pytest.skip("no C compiler")
    rng = np.random.default_rng(13)
    state = _state(rng)
    dt, _, q, qd = _nodes(state, rng, 2)
    assert linearize_first(strict._est, state, dt, q, qd) is not None
    far = state.q.copy()
    _, _, i, _, upper = strict._est._packer.ranges[0]
    far[i] = upper + 0.01
    assert linearize_first(strict._est, replace(state, q=far), dt, q, qd) is None
    tipping = WheelContacts(np.array([True, False, False, True]), np.zeros((4, 3)),
                            np.zeros((4, 3)), np.tile([0.0, 0.0, 1.0], (4, 1)))
    assert linearize_first(strict._est, replace(state, contacts=tipping), dt, q, qd) is None
    assert strict.n_clipped == 0


def test_linearize_nodes_keeps_the_first(est):
    """`PayloadEstimator.linearize_nodes` keeps node 0 as `linearize` does, and reuses it."""
    rng = np.random.default_rng(14)
    state = _state(rng)
    dt, _, q, qd = _nodes(state, rng, 2)
    lin, rows = est.linearize_nodes(state, dt, q, qd)
    assert est.linearize(state) is lin
    rows = rows.copy()
    again, rows_again = est.linearize_nodes(state, dt, q, qd)
    assert again is lin
    np.testing.assert_array_equal(rows_again, rows)
    kept = est.linearize(_state(rng))
    assert est.linearize_nodes(state, dt, q, qd)[0] is not kept


def test_the_caches_are_not_touched(est):
    rng = np.random.default_rng(8)
    state = _state(rng)
    lin = est.linearize(state)
    dt, rot, q, qd = _nodes(state, rng)
    est.linearize_states(state, dt, rot, q, qd)
    assert est.linearize(state) is lin


class _OneByOne:
    """The model without `linearize_states`: the constraint's per-node path."""

    def __init__(self, model):
        self.model = model

    def estimate(self, state):
        return self.model.estimate(state)

    def linearize(self, state):
        return self.model.linearize(state)


def test_the_mpc_nodes_are_those_of_one_call_per_node(machine):
    model, feedback = estimator_models(machine, "full")
    ctrl = MpcController(machine, ControllerConfig(), force_model=model, feedback=feedback)
    st = make_state(machine)
    ctrl.set_goal(JointGoal(crane=st.q[2:9] + 0.1))
    plant = KinematicPlant(st, 0.01)
    for _ in range(4):
        plant.apply(ctrl.step(plant.state))
    ctx = ctrl.context(plant.state)
    con = ctrl.force_constraint
    steps, lins, qn, vn = con.linearize(ctx)
    assert len(steps) > 1 and lins[1].__dict__["_row"].base is lins[-1].__dict__["_row"].base
    con.model = _OneByOne(model)
    try:
        steps_ref, lins_ref, qn_ref, vn_ref = con.linearize(ctx)
    finally:
        con.model = model
    np.testing.assert_array_equal(steps, steps_ref)
    np.testing.assert_array_equal(qn, qn_ref)
    for a, b in zip(lins, lins_ref, strict=True):
        np.testing.assert_array_equal(a.__dict__["_row"], b.__dict__["_row"])
        assert (a.mode, a.time, a.clipped) == (b.mode, b.time, b.clipped)
