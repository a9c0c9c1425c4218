"""Constraint form f_z = G a + g0 (exact) and derivatives against finite differences."""

from dataclasses import replace

import numpy as np
import pytest

from estimators import EstimatorInputError, NormalForceEstimator
from models import MachineState, WheelContacts, build_reference_machine
from testkit.estimator_states import random_state


@pytest.fixture(scope="module")
def machine():
    return build_reference_machine()


def with_acc(s, a):
    return MachineState(s.base_position, s.base_rotation, s.base_twist, a[:6], s.q, s.qd, a[6:],
                        contacts=s.contacts, suspension_force=s.suspension_force)


def with_contacts(est, s, flags, rng):
    pts = est.estimate(s).contact_points + 0.02 * rng.normal(size=(4, 3))
    contacts = WheelContacts(np.array(flags, bool), 1000 * rng.normal(size=(4, 3)), pts,
                             np.tile([0, 0, 1.0], (4, 1)))
    return replace(s, contacts=contacts)


CASES = [("full", "d-beta", [1, 1, 1, 1]), ("full", "cylinder-force", [1, 1, 1, 1]),
         ("quasi-static", "d-beta", [1, 1, 1, 1]), ("full", "d-beta", [1, 0, 1, 1]),
         ("full", "d-beta", [0, 1, 1, 0])]


@pytest.mark.parametrize("method,fourth,flags", CASES)
def test_affine_in_accelerations(machine, method, fourth, flags):
    est = NormalForceEstimator(machine, method=method, fourth=fourth, D=1.2, beta=300.0)
    rng = np.random.default_rng(1)
    for _ in range(3):
        s = with_contacts(est, random_state(machine, rng, max_tilt=0.4), flags, rng)
        s = replace(s, suspension_force=1e4 * rng.normal(size=2))
        g, g0 = est.constraint(s)
        assert g.shape == (4, 19) and g0.shape == (4,)
        for _ in range(4):
            a = 3 * rng.normal(size=19)
            e = est.estimate(with_acc(s, a)).normal_forces
            np.testing.assert_allclose(g @ a + g0, e, rtol=1e-9,
                                       atol=1e-9 * np.abs(e).max())
        if method == "quasi-static":
            np.testing.assert_array_equal(g[:, :6], 0.0)
            np.testing.assert_array_equal(g[:, 6 + np.array([0, 1, 9, 10, 11, 12])], 0.0)


def test_reference_backend_constraint_matches_compiled(machine):
    rng = np.random.default_rng(2)
    s = random_state(machine, rng, max_tilt=0.4)
    g1, c1 = NormalForceEstimator(machine).constraint(s)
    g2, c2 = NormalForceEstimator(machine, backend="reference").constraint(s)
    np.testing.assert_allclose(g1, g2, rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(c1, c2, rtol=1e-9, atol=1e-6)


def fd_jacobian(est, s, name, h=1e-6):
    base = getattr(s, name)
    out = np.zeros((4, 13))
    for j in range(13):
        vals = []
        for step in (-h, h):
            v = base.copy()
            v[j] += step
            kw = dict(base_position=s.base_position, base_rotation=s.base_rotation,
                      base_twist=s.base_twist, base_acceleration=s.base_acceleration, q=s.q,
                      qd=s.qd, qdd=s.qdd, contacts=s.contacts,
                      suspension_force=s.suspension_force)
            kw[name] = v
            vals.append(est.estimate(MachineState(**kw)).normal_forces)
        out[:, j] = (vals[1] - vals[0]) / (2 * h)
    return out


@pytest.mark.parametrize("method,fourth,contacts", [("full", "d-beta", False),
                                                    ("full", "cylinder-force", True),
                                                    ("quasi-static", "d-beta", False)])
def test_derivatives_match_finite_differences(machine, method, fourth, contacts):
    est = NormalForceEstimator(machine, method=method, fourth=fourth, D=0.8)
    rng = np.random.default_rng(3)
    s = random_state(machine, rng, max_tilt=0.4, margin=0.01)
    if contacts:
        s = with_contacts(est, s, [1, 1, 1, 1], rng)
        s = replace(s, suspension_force=1e4 * rng.normal(size=2))
    d = est.linearize(s)
    np.testing.assert_allclose(d.normal_forces, est.estimate(s).normal_forces, rtol=1e-12)
    np.testing.assert_allclose(d.G, est.constraint(s)[0], rtol=1e-9, atol=1e-6)
    for name, jac in (("q", d.d_q), ("qd", d.d_qd)):
        fd = fd_jacobian(est, s, name)
        scale = np.abs(fd).max()
        np.testing.assert_allclose(jac, fd, atol=2e-6 * scale)
    if method == "quasi-static":
        np.testing.assert_array_equal(d.d_qd[:, [0, 1, 9, 10, 11, 12]], 0.0)


@pytest.mark.parametrize("method,flags", [("full", [1, 0, 0, 1]), ("full", [0, 1, 0, 0]),
                                          ("quasi-static", [0, 0, 1, 1])])
def test_tipping_derivatives_match_finite_differences(machine, method, flags):
    """Fewer than three contacts: the batched differences of the compiled kernel against
    differences of `estimate` on rebuilt states, and against the numpy reference backend."""
    est = NormalForceEstimator(machine, method=method)
    rng = np.random.default_rng(4)
    s = with_contacts(est, random_state(machine, rng, max_tilt=0.3, margin=0.01), flags, rng)
    d = est.linearize(s)
    assert all(np.isfinite(x).all() for x in (d.normal_forces, d.G, d.d_q, d.d_qd))
    assert d.mode == "tipping" and d.in_contact.tolist() == [bool(f) for f in flags]
    np.testing.assert_allclose(d.normal_forces, est.estimate(s).normal_forces, rtol=1e-10,
                               atol=1e-8)
    np.testing.assert_allclose(d.G, est.constraint(s)[0], rtol=1e-9, atol=1e-6)
    ref = NormalForceEstimator(machine, method=method, backend="reference").linearize(s)
    for name, jac, ref_jac in (("q", d.d_q, ref.d_q), ("qd", d.d_qd, ref.d_qd)):
        fd = fd_jacobian(est, s, name)
        scale = max(np.abs(fd).max(), 1.0)
        np.testing.assert_allclose(jac, fd, atol=1e-6 * scale)
        np.testing.assert_allclose(jac, ref_jac, atol=1e-5 * scale)
    if method == "quasi-static":
        np.testing.assert_array_equal(d.d_qd[:, [0, 1, 9, 10, 11, 12]], 0.0)


@pytest.mark.parametrize("fourth", ["d-beta", "cylinder-force"])
@pytest.mark.parametrize("lost", [0, 1, 2, 3])
def test_three_contact_linearization_is_exact(machine, fourth, lost):
    """Sec. III-B: the compiled derivatives are exact (no NaN) with a wheel off the ground."""
    est = NormalForceEstimator(machine, fourth=fourth, D=0.8)
    rng = np.random.default_rng(10 + lost)
    flags = [1, 1, 1, 1]
    flags[lost] = 0
    s = with_contacts(est, random_state(machine, rng, max_tilt=0.4, margin=0.01), flags, rng)
    s = replace(s, suspension_force=1e4 * rng.normal(size=2))
    d = est.linearize(s)
    assert d.mode == "3-contact" and d.in_contact.tolist() == [bool(f) for f in flags]
    np.testing.assert_allclose(d.normal_forces, est.estimate(s).normal_forces, rtol=1e-12)
    np.testing.assert_allclose(d.G, est.constraint(s)[0], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(d.forces_at(s.acceleration), d.normal_forces, atol=1e-6)
    for name, jac in (("q", d.d_q), ("qd", d.d_qd)):
        assert np.isfinite(jac).all()
        fd = fd_jacobian(est, s, name)
        np.testing.assert_allclose(jac, fd, atol=2e-6 * np.abs(fd).max())


def test_stroke_policy_clip_reports_and_raise_raises(machine):
    rng = np.random.default_rng(5)
    s = random_state(machine, rng, max_tilt=0.3, margin=0.01)
    lo, hi = machine.coordinates.lower[3], machine.coordinates.upper[3]
    q = s.q.copy()
    q[3] = hi + 0.004  # a few mm past the end, as MuJoCo's soft limits allow
    over = replace(s, q=q)
    with pytest.raises(EstimatorInputError, match="'lift'"):
        NormalForceEstimator(machine).linearize(over)
    clip = NormalForceEstimator(machine, strokes="clip")
    d = clip.linearize(over)
    assert d.clipped == ("lift",) and clip.n_clipped >= 1
    q[3] = hi
    np.testing.assert_allclose(d.normal_forces,
                               clip.estimate(replace(s, q=q)).normal_forces, rtol=1e-12)
    assert clip.linearize(s).clipped == ()
    assert lo < hi


def test_fast_path_results_are_read_only_and_equal_the_checked_constructor(machine):
    """`linearize` wraps the kernel's row without the constructor's checks
    (`ForceLinearization.trusted`): the same numbers, read-only, fresh arrays per call."""
    from estimators.linearization import ForceLinearization

    est = NormalForceEstimator(machine)
    s = random_state(machine, np.random.default_rng(4), max_tilt=0.2)
    lin, again = est.linearize(s), est.linearize(s)
    checked = ForceLinearization(lin.normal_forces, lin.G, lin.g0, lin.d_q, lin.d_qd,
                                 lin.in_contact, lin.mode, lin.clipped, lin.time)
    for name in ("normal_forces", "G", "g0", "d_q", "d_qd", "in_contact"):
        a = getattr(lin, name)
        np.testing.assert_array_equal(a, getattr(checked, name))
        assert not a.flags.writeable, name
        if name != "in_contact":  # the flags of a contact pattern: one read-only array
            assert not np.shares_memory(a, getattr(again, name)), name
    np.testing.assert_allclose(lin.g0, lin.normal_forces - lin.G @ s.acceleration, atol=1e-6)
    g, g0 = est.constraint(s)
    np.testing.assert_allclose(g, lin.G, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(g0, lin.g0, rtol=1e-12, atol=1e-6)
    e = est.estimate(s)
    assert not np.shares_memory(e.normal_forces, est.estimate(s).normal_forces)


def test_tipping_least_squares_of_a_batch_equals_lstsq_and_survives_bad_systems():
    from estimators.tipping import _min_norm

    rng = np.random.default_rng(12)
    for k in (1, 2):
        a, b = rng.normal(size=(20, 3, k)), rng.normal(size=(20, 3))
        ref = np.array([np.linalg.lstsq(a[i], b[i], rcond=None)[0] for i in range(20)])
        np.testing.assert_allclose(_min_norm(a, b), ref, atol=1e-12)
    zero = np.zeros((2, 3, 1))  # a wheel whose column vanishes: the pseudo-inverse, 0 N
    np.testing.assert_array_equal(_min_norm(zero, np.ones((2, 3))), 0.0)
    bad = np.ones((2, 3, 2))
    bad[0, 0, 0] = np.nan  # non-finite: NaN out (the estimator's finiteness check raises)
    assert np.isnan(_min_norm(bad, np.ones((2, 3)))).all()
