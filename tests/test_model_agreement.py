"""Pinocchio and MuJoCo, both built from one description, agree (independent engines)."""

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from models.mujoco import MujocoIndex, build_model
from models.pinocchio_model import build_pinocchio
from models.terrain import flat
from tests.conftest import random_state


@pytest.fixture(scope="module")
def engines(machine):
    model = build_model(machine, flat())
    return model, mujoco.MjData(model), MujocoIndex(model, machine), build_pinocchio(machine)


def _load_mujoco(engines, state):
    """Put a consistent state into MuJoCo's coordinates (free-joint conventions)."""
    model, data, index, pm = engines
    qt, vt, at = pm.coordinates.joint_motion(state.q, state.qd, state.qdd)
    r = state.base_rotation
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, r.reshape(-1))
    v_fb, w_fb = state.base_twist[:3], state.base_twist[3:]
    dv_fb, dw_fb = state.base_acceleration[:3], state.base_acceleration[3:]
    data.qpos[index.base_qpos] = np.concatenate([state.base_position, quat])
    data.qpos[index.tree_qpos] = qt
    data.qvel[index.base_dof] = np.concatenate([r @ v_fb, w_fb])
    data.qvel[index.tree_dof] = vt
    mujoco.mj_forward(model, data)
    data.qacc[index.base_dof] = np.concatenate([r @ (dv_fb + np.cross(w_fb, v_fb)), dw_fb])
    data.qacc[index.tree_dof] = at


def test_total_mass(engines, machine):
    model, *_ = engines
    pm = engines[3]
    m_mj = model.body_subtreemass[engines[2].base_body]
    m_pin = sum(i.mass for i in pm.model.inertias)
    assert m_mj == pytest.approx(machine.total_mass, rel=1e-12)
    assert m_pin == pytest.approx(machine.total_mass, rel=1e-12)


def test_center_of_mass_and_base_inverse_dynamics(engines, machine):
    model, data, index, pm = engines
    rng = np.random.default_rng(7)
    worst_com, worst_wrench = 0.0, 0.0
    for _ in range(100):
        st = random_state(machine, rng)
        _load_mujoco(engines, st)
        com_mj = data.subtree_com[index.base_body]
        com_pin = pm.center_of_mass(st)
        worst_com = max(worst_com, np.linalg.norm(com_mj - com_pin))
        # MuJoCo's RNE: M(q) qacc + c(q, qd) (gravity included), free joint rows.
        res = np.zeros(model.nv)
        mujoco.mj_rne(model, data, 1, res)
        f_world, tau_fb = res[index.base_dof[:3]], res[index.base_dof[3:]]
        wrench_mj = np.concatenate([st.base_rotation.T @ f_world, tau_fb])
        wrench_pin = pm.base_wrench(st)
        worst_wrench = max(worst_wrench, np.linalg.norm(wrench_mj - wrench_pin)
                           / np.linalg.norm(wrench_pin))
        # The tree joints agree too (one joint's generalized force each).
        q, v, a = pm.configuration(st)
        tau_pin = pin.rnea(pm.model, pm.data, q, v, a)[pm._tree_v_idx]
        np.testing.assert_allclose(res[index.tree_dof], tau_pin, rtol=1e-6,
                                   atol=1e-6 * np.abs(tau_pin).max())
    assert worst_com < 1e-9
    assert worst_wrench < 1e-6
