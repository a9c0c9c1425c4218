"""Pinocchio model: loop closures hold for states built through the coordinate map."""

import numpy as np
import pinocchio as pin
import pytest

import models
from models.pinocchio_model import build_pinocchio
from tests.conftest import random_state


@pytest.fixture(scope="module")
def pm(machine):
    return build_pinocchio(machine)


def _loop_points(pm, machine, q, v):
    pin.forwardKinematics(pm.model, pm.data, q, v)
    pin.updateFramePlacements(pm.model, pm.data)
    out = []
    for lp in machine.loops:
        pts = []
        for body, p in ((lp.body_a, lp.point_a), (lp.body_b, lp.point_b)):
            fid = pm.frame_id[body]
            oMf = pm.data.oMf[fid]
            vel = pin.getFrameVelocity(pm.model, pm.data, fid, pin.LOCAL_WORLD_ALIGNED)
            pw = oMf.act(np.asarray(p))
            pts.append((pw, vel.linear + np.cross(vel.angular, pw - oMf.translation)))
        out.append((lp.name, pts))
    return out


def test_mass_and_tree(pm, machine):
    assert np.isclose(sum(i.mass for i in pm.model.inertias), machine.total_mass)
    assert pm.model.nv == 6 + len(machine.moving_joints)


def test_loops_closed_in_position_and_velocity(pm, machine):
    rng = np.random.default_rng(0)
    for _ in range(50):
        st = random_state(machine, rng)
        q, v, _ = pm.configuration(st)
        for name, ((pa, va), (pb, vb)) in _loop_points(pm, machine, q, v):
            assert np.linalg.norm(pa - pb) < 1e-12, name
            assert np.linalg.norm(va - vb) < 1e-10, name


def test_loops_closed_in_acceleration(pm, machine):
    # The loop-point accelerations agree: finite difference of the velocities along qdd.
    rng = np.random.default_rng(1)
    st = random_state(machine, rng)
    dt = 1e-6
    st2 = models.MachineState(st.base_position, st.base_rotation, st.base_twist,
                              st.base_acceleration, st.q + dt * st.qd + 0.5 * dt * dt * st.qdd,
                              st.qd + dt * st.qdd, st.qdd)
    q, v, a = pm.configuration(st)
    q2, v2, _ = pm.configuration(st2)
    # Joint accelerations from the map equal finite differences of joint velocities.
    idx = pm._tree_v_idx
    np.testing.assert_allclose(a[idx], (v2[idx] - v[idx]) / dt, rtol=1e-4, atol=1e-5)


def test_center_of_mass_matches_description(pm, machine):
    # Oracle: CoM from the description's own bodies placed by Pinocchio's frames.
    rng = np.random.default_rng(2)
    st = random_state(machine, rng)
    q, _, _ = pm.configuration(st)
    pin.framesForwardKinematics(pm.model, pm.data, q)
    total = np.zeros(3)
    for b in machine.bodies:
        total += b.inertia.mass * pm.data.oMf[pm.frame_id[b.name]].act(np.asarray(b.inertia.com))
    np.testing.assert_allclose(pm.center_of_mass(st), total / machine.total_mass, atol=1e-12)


def test_static_base_wrench_is_weight(pm, machine):
    st = models.MachineState(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6),
                             machine.coordinates.home(), np.zeros(13),
                             np.zeros(13))
    w = pm.base_wrench(st)
    assert np.isclose(w[2], machine.total_mass * machine.gravity, rtol=1e-12)
    np.testing.assert_allclose(w[[0, 1, 5]], 0, atol=1e-9)


def test_joints_are_depth_first_so_crba_is_the_mass_matrix(pm, machine):
    """CRBA walks contiguous subtrees; RNEA's columns ``M e_k`` are the oracle.

    With the description's body order (a cylinder's barrel and piston between a crane joint
    and its descendants) CRBA left couplings such as slew-wrist roll at zero (111 kg m^2).
    """
    parents = list(pm.model.parents)
    for j in range(1, pm.model.njoints):  # each joint's subtree is the joints right after it
        sub = list(pm.model.subtrees[j])
        assert sub == list(range(j, j + len(sub))), pm.model.names[j]
    assert all(parents[j] < j for j in range(1, pm.model.njoints))
    rng = np.random.default_rng(3)
    nv = pm.model.nv
    for _ in range(5):
        q, _, _ = pm.configuration(random_state(machine, rng))
        zero = np.zeros(nv)
        g = pin.rnea(pm.model, pm.data, q, zero, zero).copy()
        columns = np.column_stack([pin.rnea(pm.model, pm.data, q, zero, e) - g
                                   for e in np.eye(nv)])
        upper = np.triu(pin.crba(pm.model, pm.data, q))
        np.testing.assert_allclose(upper + np.triu(upper, 1).T, columns,
                                   atol=1e-9 * np.abs(columns).max())
