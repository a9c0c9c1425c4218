"""Property tests of the screw-theory core (estimators.spatial) and its CasADi twin."""

import casadi as ca
import numpy as np
import pytest
from scipy.linalg import expm

from estimators import spatial as sp
from estimators._symbolic import CasadiOps
from models.description import Inertia
from testkit.estimator_states import random_rotation

RNG = np.random.default_rng(11)


def random_pose(rng=RNG):
    return sp.se3(random_rotation(rng), rng.normal(size=3))


@pytest.mark.parametrize("trial", range(10))
def test_adjoint_of_product_is_product_of_adjoints(trial):
    t1, t2 = random_pose(), random_pose()
    np.testing.assert_allclose(sp.adjoint(t1 @ t2), sp.adjoint(t1) @ sp.adjoint(t2), atol=1e-12)
    np.testing.assert_allclose(sp.coadjoint(t1 @ t2), sp.coadjoint(t1) @ sp.coadjoint(t2),
                               atol=1e-12)


@pytest.mark.parametrize("trial", range(10))
def test_adjoint_inverse(trial):
    t = random_pose()
    np.testing.assert_allclose(sp.adjoint(sp.se3_inverse(t)), np.linalg.inv(sp.adjoint(t)),
                               atol=1e-12)
    np.testing.assert_allclose(sp.se3_inverse(t) @ t, np.eye(4), atol=1e-12)


@pytest.mark.parametrize("trial", range(10))
def test_coadjoint_is_dual_and_power_is_frame_invariant(trial):
    t = random_pose()
    f, nu = RNG.normal(size=6), RNG.normal(size=6)
    np.testing.assert_allclose(sp.coadjoint(t), np.linalg.inv(sp.adjoint(t)).T, atol=1e-12)
    assert np.isclose((sp.coadjoint(t) @ f) @ (sp.adjoint(t) @ nu), f @ nu, rtol=1e-12)


@pytest.mark.parametrize("trial", range(10))
def test_ad_star_duality(trial):
    nu, f, x = RNG.normal(size=6), RNG.normal(size=6), RNG.normal(size=6)
    np.testing.assert_allclose(sp.ad_star(nu), -sp.ad(nu).T, atol=0)
    assert np.isclose((sp.ad_star(nu) @ f) @ x, -(f @ (sp.ad(nu) @ x)), rtol=1e-12)


def test_ad_and_ad_star_are_derivatives_of_the_group_actions():
    nu = RNG.normal(size=6)
    h = 1e-6
    d_ad = (sp.adjoint(expm(h * sp.twist_hat(nu))) - sp.adjoint(expm(-h * sp.twist_hat(nu))))
    np.testing.assert_allclose(d_ad / (2 * h), sp.ad(nu), atol=1e-8)
    d_co = (sp.coadjoint(expm(h * sp.twist_hat(nu)))
            - sp.coadjoint(expm(-h * sp.twist_hat(nu))))
    np.testing.assert_allclose(d_co / (2 * h), sp.ad_star(nu), atol=1e-8)


def test_ad_is_equivariant_and_a_lie_bracket():
    t, nu, x = random_pose(), RNG.normal(size=6), RNG.normal(size=6)
    adt = sp.adjoint(t)
    np.testing.assert_allclose(adt @ sp.ad(nu) @ np.linalg.inv(adt), sp.ad(adt @ nu), atol=1e-12)
    bracket = sp.twist_hat(nu) @ sp.twist_hat(x) - sp.twist_hat(x) @ sp.twist_hat(nu)
    np.testing.assert_allclose(sp.twist_hat(sp.ad(nu) @ x), bracket, atol=1e-12)


def test_spatial_inertia_matches_pinocchio_and_is_spd():
    import pinocchio as pin

    i = Inertia(12.0, [0.1, -0.2, 0.3], np.diag([1.0, 2.0, 2.5]))
    m = sp.spatial_inertia(i)
    oracle = pin.Inertia(i.mass, np.asarray(i.com), np.asarray(i.inertia)).matrix()
    np.testing.assert_allclose(m, oracle, atol=1e-12)
    np.testing.assert_allclose(m, m.T, atol=0)
    assert np.linalg.eigvalsh(m).min() > 0


def test_euler_poincare_is_newton_euler():
    inertia = np.diag([1.0, 2.0, 2.5])
    com = np.array([0.3, -0.1, 0.2])
    m = sp.spatial_inertia(Inertia(7.0, com, inertia))
    nu, nud = RNG.normal(size=6), RNG.normal(size=6)
    f = sp.euler_poincare_wrench(m, nu, nud)
    v, w = nu[:3], nu[3:]
    a_c = nud[:3] + np.cross(nud[3:], com) + np.cross(w, v + np.cross(w, com))
    force = 7.0 * a_c
    moment = inertia @ nud[3:] + np.cross(w, inertia @ w) + np.cross(com, force)
    np.testing.assert_allclose(f, np.concatenate([force, moment]), atol=1e-12)


def test_gravity_offset_gives_the_weight():
    r = random_rotation(RNG)
    com = np.array([0.2, 0.1, -0.4])
    m = sp.spatial_inertia(Inertia(5.0, com, np.eye(3)))
    weight = r.T @ np.array([0.0, 0.0, -5.0 * 9.81])
    expected = np.concatenate([weight, np.cross(com, weight)])
    np.testing.assert_allclose(sp.gravity_wrench(m, r, 9.81), expected, atol=1e-12)


def test_casadi_ops_match_numpy():
    r, p, nu = random_rotation(RNG), RNG.normal(size=3), RNG.normal(size=6)
    t = sp.se3(r, p)
    ev = lambda e: np.asarray(ca.evalf(e))  # noqa: E731
    np.testing.assert_allclose(ev(CasadiOps.adjoint_rp(ca.DM(r), ca.DM(p))), sp.adjoint(t),
                               atol=1e-14)
    np.testing.assert_allclose(ev(CasadiOps.coadjoint_rp(ca.DM(r), ca.DM(p))),
                               sp.coadjoint(t), atol=1e-14)
    np.testing.assert_allclose(ev(CasadiOps.ad(ca.DM(nu))), sp.ad(nu), atol=1e-14)
    np.testing.assert_allclose(ev(CasadiOps.ad_star(ca.DM(nu))), sp.ad_star(nu), atol=1e-14)
