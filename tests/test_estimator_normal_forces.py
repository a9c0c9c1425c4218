"""Normal forces: equilibrium rows, exact recovery in consistent worlds, eqs. (25)-(29), III-B."""

from dataclasses import replace

import numpy as np
import pytest

from estimators import NormalForceEstimator, SingularSystemError
from estimators.full_dynamics import D_BETA_COEFFICIENTS, d_beta_row
from models import MachineState, WheelContacts, build_reference_machine
from models.pinocchio_model import build_pinocchio
from testkit.estimator_states import consistent_contact_state, random_state


@pytest.fixture(scope="module")
def machine():
    return build_reference_machine()


@pytest.fixture(scope="module")
def pm(machine):
    return build_pinocchio(machine)


@pytest.fixture(scope="module")
def est(machine):
    return NormalForceEstimator(machine)


def static_state(machine, **kw):
    q = machine.coordinates.home()
    z = np.zeros(13)
    return MachineState(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(6), q, z, z, **kw)


def world(machine, pm, rng, forces, est, in_contact=None, tilt=0.3):
    """A consistent state whose ground forces are ``forces`` at the wheel bottoms (+ noise)."""
    s = random_state(machine, rng, max_tilt=tilt, speed=0.5)
    pts = est.estimate(s).contact_points + 0.02 * rng.normal(size=(4, 3))
    return consistent_contact_state(machine, s, pts, forces, pm, in_contact=in_contact)


def random_forces(rng, n=4):
    f = np.column_stack([1500 * rng.normal(size=(4, 2)), rng.uniform(4e3, 2e4, 4)])
    f[n:] = 0.0
    return f


def test_static_sum_is_the_weight(machine, est):
    e = est.estimate(static_state(machine))
    assert np.isclose(e.normal_forces.sum(), machine.total_mass * machine.gravity, rtol=1e-12)
    assert (e.normal_forces > 0).all()
    assert e.mode == "d-beta" and not e.tipping and e.backend == "compiled"


def test_flat_level_system_is_the_papers(machine, est):
    """Level bogies, flat ground: A and b are eqs. (26) and (28) with eq. (21)'s constants."""
    e = est.estimate(static_state(machine))
    xw, yw, zw, r = 1.15, 0.875, -0.10, machine.wheel_radius
    # eq. (26) in the order FL, RL, FR, RR (paper: FL, FR, RR, RL), x_c = 0.
    a = np.array([[1, 1, 1, 1], [yw, yw, -yw, -yw], [-xw, xw, -xw, xw]])
    np.testing.assert_allclose(e.system_matrix, a, atol=1e-12)
    xi = e.wrench_xi
    b = [xi[2], xi[3] - (r - zw) * xi[1], xi[4] - (zw - r) * xi[0]]  # eq. (28)
    np.testing.assert_allclose(e.system_rhs, b, atol=1e-9)


def test_d_beta_row_is_mapped_by_name():
    d = 0.37
    paper = dict(zip(("FL", "FR", "RR", "RL"), (d - 1, 1 - d, -d, d)))  # eq. (29) order
    np.testing.assert_allclose(d_beta_row(d), [paper[k] for k in ("FL", "RL", "FR", "RR")])
    assert D_BETA_COEFFICIENTS.shape == (4, 2)


def test_equilibrium_rows_are_met_exactly(machine):
    rng = np.random.default_rng(1)
    for fourth in ("d-beta", "cylinder-force"):
        est = NormalForceEstimator(machine, fourth=fourth, D=1.5, beta=-2000.0)
        for _ in range(20):
            s = random_state(machine, rng, max_tilt=0.5)
            s = replace(s, suspension_force=1e4 * rng.normal(size=2))
            e = est.estimate(s)
            scale = np.abs(e.system_rhs).max() + np.abs(e.system_matrix).max() * np.abs(
                e.normal_forces).max()
            assert np.abs(e.residual).max() <= 1e-12 * scale
            np.testing.assert_allclose(e.system_matrix @ e.normal_forces - e.system_rhs,
                                       e.residual, atol=1e-9 * scale)


def test_cylinder_force_mode_recovers_consistent_forces(machine, pm):
    est = NormalForceEstimator(machine, fourth="cylinder-force")
    rng = np.random.default_rng(2)
    for _ in range(10):
        f = random_forces(rng)
        e = est.estimate(world(machine, pm, rng, f, est))
        assert e.mode == "cylinder-force"
        np.testing.assert_allclose(e.normal_forces, f[:, 2], rtol=1e-8, atol=1e-6)


def test_d_beta_mode_recovers_forces_that_satisfy_the_row(machine, pm):
    d, beta = 1.4, -1500.0
    est = NormalForceEstimator(machine, D=d, beta=beta)
    rng = np.random.default_rng(3)
    r = np.array(d_beta_row(d))
    for _ in range(10):
        f = random_forces(rng)
        f[:, 2] -= r * (r @ f[:, 2] - beta) / (r @ r)  # project onto eq. (29)
        e = est.estimate(world(machine, pm, rng, f, est))
        np.testing.assert_allclose(e.normal_forces, f[:, 2], rtol=1e-8, atol=1e-6)


@pytest.mark.parametrize("lost", range(4))
def test_three_contacts_recover_forces_whatever_d(machine, pm, lost):
    """Sec. III-B: one wheel off the ground leaves a 3x3 system with a unique solution."""
    est = NormalForceEstimator(machine, D=0.9, beta=777.0)
    rng = np.random.default_rng(10 + lost)
    f = random_forces(rng)
    f[lost] = 0.0
    flags = np.ones(4, bool)
    flags[lost] = False
    e = est.estimate(world(machine, pm, rng, f, est, in_contact=flags))
    assert e.mode == "3-contact" and not e.tipping
    assert e.normal_forces[lost] == 0.0
    np.testing.assert_allclose(e.normal_forces, f[:, 2], rtol=1e-8, atol=1e-6)
    np.testing.assert_allclose(e.system_matrix[:, lost], 0.0)


@pytest.mark.parametrize("flags", [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 0, 0]])
def test_fewer_than_three_contacts_flag_tipping(machine, est, flags):
    s = random_state(machine, np.random.default_rng(4), max_tilt=0.5)
    contacts = WheelContacts(np.array(flags, bool), np.zeros((4, 3)),
                             est.estimate(s).contact_points, np.tile([0, 0, 1.0], (4, 1)))
    s = replace(s, contacts=contacts)
    e = est.estimate(s)
    assert e.tipping and e.mode == "tipping"
    assert np.isfinite(e.normal_forces).all()
    assert np.isfinite(e.condition) == any(flags)  # no contact: no system to condition
    np.testing.assert_array_equal(e.normal_forces[~np.array(flags, bool)], 0.0)


def test_cylinder_force_without_measurement_falls_back(machine):
    est = NormalForceEstimator(machine, fourth="cylinder-force")
    e = est.estimate(static_state(machine))
    assert e.mode == "d-beta"


def test_terrain_normal_component(machine, est):
    s = static_state(machine)
    n = np.tile([0.0, np.sin(0.2), np.cos(0.2)], (4, 1))
    f = np.array([[100.0, 200.0, 0.0]] * 4)
    s = replace(s, contacts=WheelContacts(np.ones(4, bool), f, est.estimate(s).contact_points, n))
    e = est.estimate(s)
    np.testing.assert_allclose(e.normal_forces_terrain,
                               n[:, 2] * e.normal_forces + n[:, 1] * 200.0)


def test_singular_contact_geometry_raises(machine, est):
    s = static_state(machine)
    pts = np.array([[1.0, 0.5, -0.45], [-1.0, 0.5, -0.45], [0.5, 0.5, -0.45],
                    [-0.5, 0.5, -0.45]])  # all on one line: the roll row is degenerate
    s = replace(s, contacts=WheelContacts(np.ones(4, bool), np.zeros((4, 3)), pts,
                                          np.tile([0, 0, 1.0], (4, 1))))
    with pytest.raises(SingularSystemError) as info:
        est.estimate(s)
    assert info.value.condition > 1e12


def test_quasi_static_equals_full_without_base_and_suspension_motion(machine):
    full = NormalForceEstimator(machine)
    qs = NormalForceEstimator(machine, method="quasi-static")
    rng = np.random.default_rng(5)
    s = random_state(machine, rng, max_tilt=0.3)
    qd, qdd = s.qd.copy(), s.qdd.copy()
    for idx in (0, 1, 9, 10, 11, 12):  # suspension strokes and wheel angles
        qd[idx] = 0.0
        qdd[idx] = 0.0
    s = replace(s, base_twist=np.zeros(6), base_acceleration=np.zeros(6), qd=qd, qdd=qdd)
    np.testing.assert_allclose(qs.estimate(s).normal_forces, full.estimate(s).normal_forces,
                               rtol=1e-12)
    moving = random_state(machine, rng, max_tilt=0.3, speed=2.0)
    assert np.abs(qs.estimate(moving).normal_forces
                  - full.estimate(moving).normal_forces).max() > 10.0
    same_crane = MachineState(moving.base_position, moving.base_rotation, np.zeros(6),
                              np.zeros(6), moving.q, moving.qd * qs._qs.coordinates,
                              moving.qdd * qs._qs.coordinates)
    np.testing.assert_allclose(qs.estimate(moving).normal_forces,
                               qs.estimate(same_crane).normal_forces, rtol=1e-12)


def test_results_pickle_with_every_field():
    """The per-call results make their fields on first access; a pickle carries them all."""
    import dataclasses
    import pickle

    machine = build_reference_machine()
    est = NormalForceEstimator(machine)
    state = random_state(machine, np.random.default_rng(3), max_tilt=0.2)
    for result in (est.estimate(state), est.linearize(state)):
        copy = pickle.loads(pickle.dumps(result))
        assert type(copy) is type(result)
        for field in dataclasses.fields(result):
            a, b = getattr(result, field.name), getattr(copy, field.name)
            assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, field.name
