"""The screw-theory recursion against Pinocchio's RNEA, the chains, Theorem 1 (eqs. 2-20)."""

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from estimators import NormalForceEstimator
from estimators import full_dynamics as fd
from estimators import spatial as sp
from estimators.errors import EstimatorInputError
from estimators.tree import NumpyOps, TreeModel
from models import MachineState, WheelContacts, build_reference_machine
from models.pinocchio_model import build_pinocchio
from testkit.estimator_states import random_state

N_STATES = 200


@pytest.fixture(scope="module")
def machine():
    return build_reference_machine()


@pytest.fixture(scope="module")
def tree(machine):
    return TreeModel(machine)


@pytest.fixture(scope="module")
def pm(machine):
    return build_pinocchio(machine)


def with_random_contacts(state, rng):
    """The state with random measured friction forces and contact points."""
    pts = np.array([[1.15, 0.875, -0.45], [-1.15, 0.875, -0.45], [1.15, -0.875, -0.45],
                    [-1.15, -0.875, -0.45]]) + 0.05 * rng.normal(size=(4, 3))
    contacts = WheelContacts(np.ones(4, bool), 3000 * rng.normal(size=(4, 3)), pts,
                             np.tile([0.0, 0.0, 1.0], (4, 1)))
    return MachineState(state.base_position, state.base_rotation, state.base_twist,
                        state.base_acceleration, state.q, state.qd, state.qdd,
                        contacts=contacts)


def ground_wrench(estimate):
    """F_Xi plus the friction wrenches carried to fb (eqs. 19-20)."""
    total = estimate.wrench_xi.copy()
    for p, f in zip(estimate.contact_points, estimate.friction):
        fa = np.array([f[0], f[1], 0.0])
        total += np.concatenate([fa, np.cross(p, fa)])
    return total


def test_chain_formulas_match_models_chain(machine, tree):
    for c in tree.chains:
        chain = machine.chains[c.name].chain
        lo, hi = c.stroke_range
        for x in np.linspace(lo + 1e-3, hi - 1e-3, 7):
            s = chain.state(x)
            (th, thd, thdd, br, brd, brdd, k1, k2, dk1, dk2, trig_th,
             trig_br) = tree.chain_motion(NumpyOps, c, x, 0.3, -0.2)
            # The (cos, sin) pairs the recursion uses instead of the angles.
            np.testing.assert_allclose([*trig_th, *trig_br],
                                       [np.cos(s.theta), np.sin(s.theta),
                                        np.cos(s.theta_barrel), np.sin(s.theta_barrel)],
                                       rtol=0, atol=1e-12)
            np.testing.assert_allclose([th, br, k1, k2, dk1, dk2],
                                       [s.theta, s.theta_barrel, s.k[0], s.k[1], s.dk_dx[0],
                                        s.dk_dx[1]], rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose([thd, thdd], [s.k[0] * 0.3,
                                                     s.dk_dx[0] * 0.09 - 0.2 * s.k[0]],
                                       rtol=1e-10, atol=1e-12)


def test_chain_spec_needs_a_unit_sign(tree):
    """`chain_motion`'s (cos, sin) pairs hold for sigma = +-1 only."""
    with pytest.raises(EstimatorInputError, match="sigma must be"):
        replace(tree.chains[0], sigma=0.5)


def test_tree_coordinates_match_models(machine, tree):
    rng = np.random.default_rng(0)
    s = random_state(machine, rng)
    qt, qdt, qddt, *_ = tree.tree_coordinates(NumpyOps, s.q, s.qd, s.qdd)
    ref = tree.coordinates.joint_motion(s.q, s.qd, s.qdd)
    for i, b in enumerate(tree.bodies[1:], start=1):
        j = tree.coordinates.index[b.name]
        np.testing.assert_allclose([qt[i], qdt[i], qddt[i]], [r[j] for r in ref], atol=1e-12)


def test_reference_recursion_matches_rnea(machine, tree, pm):
    """Base wrench and every tree joint force of the numpy recursion equal RNEA's."""
    rng = np.random.default_rng(1)
    for _ in range(N_STATES):
        s = random_state(machine, rng)
        dyn = tree.dynamics(NumpyOps, s.base_rotation, s.base_twist, s.base_acceleration, s.q,
                            s.qd, s.qdd)
        q, v, a = pm.configuration(s)
        tau = pin.rnea(pm.model, pm.data, q, v, a)
        w = tau[:6]
        assert np.linalg.norm(dyn.base_wrench - w) <= 1e-8 * np.linalg.norm(w)
        joint = np.array([tau[pm.joint_v_index[b.name]] for b in tree.bodies[1:]])
        assert np.abs(np.array(dyn.joint_force[1:]) - joint).max() <= 1e-8 * np.abs(tau).max()


@pytest.mark.parametrize("backend", ["compiled", "reference"])
def test_ground_wrench_equals_rnea_base_wrench(machine, pm, backend):
    """F_Xi + projected friction == free-flyer RNEA wrench on 200 random states."""
    est = NormalForceEstimator(machine, backend=backend)
    rng = np.random.default_rng(2)
    for _ in range(N_STATES):
        s = with_random_contacts(random_state(machine, rng), rng)
        w = pm.base_wrench(s)
        total = ground_wrench(est.estimate(s))
        assert np.linalg.norm(total - w) <= 1e-8 * np.linalg.norm(w)


def test_paper_groups_sum_to_the_total(machine, tree):
    """Eq. (18): Ad* F_m + F_B + sum Ad* F_w* is the whole machine's wrench."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        s = random_state(machine, rng)
        dyn = tree.dynamics(NumpyOps, s.base_rotation, s.base_twist, s.base_acceleration, s.q,
                            s.qd, s.qdd)
        pw = fd.paper_wrenches(tree, dyn)
        np.testing.assert_allclose(pw.total_in_fb, dyn.base_wrench,
                                   atol=1e-9 * np.abs(dyn.base_wrench).max())
        # The crane wrench seen in m is the crane root's subtree plus the slew cylinder.
        root = tree.crane_root
        crane_fb = np.zeros(6)
        for i, b in enumerate(tree.bodies):
            if b.group == "crane" and b.parent == 0:
                t = sp.se3(dyn.rotation_fb[i], dyn.position_fb[i])
                crane_fb += sp.coadjoint(t) @ dyn.subtree_wrench[i]
        np.testing.assert_allclose(sp.coadjoint(pw.transform_fb_to_m) @ pw.crane_in_m, crane_fb,
                                   atol=1e-9 * np.abs(crane_fb).max())
        assert tree.bodies[root].name == "slew"


@pytest.mark.parametrize("chain", ["slew", "lift", "tilt", "bogie_L", "bogie_R"])
def test_theorem_1_total_is_invariant_to_distribution_factors(machine, tree, chain):
    rng = np.random.default_rng(4)
    s = random_state(machine, rng)
    dyn = tree.dynamics(NumpyOps, s.base_rotation, s.base_twist, s.base_acceleration, s.q,
                        s.qd, s.qdd)
    ref, through_ref = fd.chain_base_wrench(tree, dyn, chain, 1.0)
    # alpha = 1 is the tree's own routing: the driven link carries the successors.
    c = next(ch for ch in tree.chains if ch.name == chain)
    np.testing.assert_allclose(through_ref, dyn.subtree_wrench[c.driven], rtol=1e-12,
                               atol=1e-9)
    for alpha in rng.uniform(-0.5, 1.5, 8):
        total, through = fd.chain_base_wrench(tree, dyn, chain, alpha)
        np.testing.assert_allclose(total, ref, atol=1e-9 * np.abs(ref).max())
        if chain in ("lift", "tilt"):  # those carry successors, so the split is visible
            assert np.abs(through - through_ref).max() > 1e-3


def test_compiled_and_casadi_backends_match_reference(machine):
    rng = np.random.default_rng(5)
    ests = {b: NormalForceEstimator(machine, backend=b, fourth="cylinder-force")
            for b in ("compiled", "casadi", "reference")}
    for i in range(10):
        s = with_random_contacts(random_state(machine, rng, max_tilt=0.4), rng)
        if i % 2:
            s = replace(s, suspension_force=rng.normal(size=2) * 2e4)
        out = {b: e.estimate(s) for b, e in ests.items()}
        ref = out["reference"]
        for b in ("compiled", "casadi"):
            np.testing.assert_allclose(out[b].normal_forces, ref.normal_forces, rtol=1e-9,
                                       atol=1e-6)
            np.testing.assert_allclose(out[b].wrench_xi, ref.wrench_xi, rtol=1e-9, atol=1e-6)
            assert out[b].mode == ref.mode
            assert out[b].backend == b
