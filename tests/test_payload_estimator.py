"""The payload as a run-time input: exact against an estimator built for that payload."""

from dataclasses import replace

import numpy as np
import pytest

from estimators import NormalForceEstimator
from estimators._symbolic import Kernels
from estimators.errors import EstimatorError
from estimators.linearization import ForceLinearization
from estimators.payload import ANCHOR_MASSES, PayloadEstimator, anchor_machines
from models import build_reference_machine
from models.state import WheelContacts
from testkit.estimator_states import random_state

MACHINE = build_reference_machine()


@pytest.mark.parametrize("fourth", ["d-beta", "cylinder-force"])
def test_any_payload_equals_the_estimator_built_for_it(fourth):
    est = PayloadEstimator(MACHINE, fourth=fourth, strokes="clip")
    # The oracles run in CasADi's virtual machine: no compile for them.
    heavy = NormalForceEstimator(build_reference_machine(payload_mass=287.0), fourth=fourth,
                                 strokes="clip", backend="casadi")
    est.payload_mass = 287.0
    rng = np.random.default_rng(3)
    for _ in range(5):
        s = replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                    suspension_force=rng.uniform(2e4, 6e4, 2))
        scale = 1e-9 * max(1.0, np.abs(heavy.estimate(s).normal_forces).max())
        np.testing.assert_allclose(est.estimate(s).normal_forces,
                                   heavy.estimate(s).normal_forces, atol=1e3 * scale)
        la, lb = est.linearize(s), heavy.linearize(s)
        for name in ("G", "g0", "d_q", "d_qd"):
            np.testing.assert_allclose(getattr(la, name), getattr(lb, name), rtol=1e-7,
                                       atol=1e-6 * np.abs(getattr(lb, name)).max())
        g, g0 = est.constraint(s)
        np.testing.assert_allclose(g, heavy.constraint(s)[0], rtol=1e-7, atol=1e-6)
        # df/dm against a central difference of two more machines.
        f_plus = NormalForceEstimator(build_reference_machine(payload_mass=297.0),
                                      fourth=fourth, strokes="clip",
                                      backend="casadi").estimate(s).normal_forces
        f_minus = NormalForceEstimator(build_reference_machine(payload_mass=277.0),
                                       fourth=fourth, strokes="clip",
                                       backend="casadi").estimate(s).normal_forces
        np.testing.assert_allclose(est.payload_sensitivity(s), (f_plus - f_minus) / 20.0,
                                   rtol=1e-6, atol=1e-6)


def test_bad_masses_raise():
    est = PayloadEstimator(MACHINE)
    for bad in (-1.0, float("nan"), "heavy", True, 2e4):
        with pytest.raises(EstimatorError, match="payload_mass"):
            est.payload_mass = bad


def test_a_repeated_linearization_is_kept_only_for_the_same_state_and_mass():
    est = PayloadEstimator(MACHINE, strokes="clip")
    rng = np.random.default_rng(5)
    s = random_state(MACHINE, rng, max_tilt=0.3, speed=0.5)
    first = est.linearize(s)
    assert est.linearize(s) is first  # the same state object: kept
    equal = replace(s)  # an equal state, another object: computed again, the same values
    again = est.linearize(equal)
    assert again is not first
    np.testing.assert_array_equal(again.G, first.G)
    est.payload_mass = 250.0  # another mass: computed again
    heavy = est.linearize(equal)
    assert heavy is not again and not np.allclose(heavy.g0, again.g0)
    est.D = 0.9  # another D (the d-beta row): computed again
    assert est.linearize(equal) is not heavy


def test_the_estimates_of_the_last_states_are_kept():
    """A tick asks about the same state several times: its estimate is kept (the same
    read-only object) for the last few states, by identity; another D or mass drops it."""
    from estimators.payload import _RECENT

    est = PayloadEstimator(MACHINE, fourth="d-beta")
    rng = np.random.default_rng(5)
    s = random_state(MACHINE, rng, max_tilt=0.3, speed=0.5)
    first = est.estimate(s)
    assert est.estimate(s) is first and not first.normal_forces.flags.writeable
    f = est.normal_forces(s)
    np.testing.assert_array_equal(est.normal_forces(s), f)
    np.testing.assert_array_equal(est.payload_sensitivity(s), est.payload_sensitivity(s))
    assert est.estimate(s) is first  # the sensitivity's other mass did not push it out
    again = est.estimate(replace(s))  # an equal state, another object: computed again
    assert again is not first
    np.testing.assert_array_equal(again.normal_forces, first.normal_forces)
    for _ in range(_RECENT):
        est.estimate(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5))
    assert est.estimate(s) is not first  # pushed out by newer states
    kept = est.estimate(s)
    est.D = 0.9  # another d-beta row: computed again, with it
    other = est.estimate(s)
    assert other is not kept and not np.allclose(other.normal_forces, kept.normal_forces)
    assert other.normal_forces.tolist() == est._est.estimate(s).normal_forces.tolist()
    est.payload_mass = 200.0  # another mass: computed again
    assert est.estimate(s) is not other


@pytest.mark.parametrize("fourth", ["d-beta", "cylinder-force"])
def test_one_kernel_call_at_the_mass_is_the_mix_of_the_anchors(fourth):
    """The kernels' payload input against the interpolation it replaced: the forces and the
    linearization at a mass are the anchors' mix, to round-off; df/dm from the stepped
    rows equals its difference of two estimates."""
    est = PayloadEstimator(MACHINE, fourth=fourth, strokes="clip")
    rng = np.random.default_rng(8)
    for mass in (0.0, 87.5, 231.7, 420.0):
        for _ in range(3):
            s = replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                        suspension_force=rng.uniform(2e4, 6e4, 2))
            anchors = []
            for m in ANCHOR_MASSES:
                est.payload_mass = m
                anchors.append(est.linearize(s))
            est.payload_mass = mass
            now = est.linearize(s)
            w = (mass - ANCHOR_MASSES[0]) / (ANCHOR_MASSES[1] - ANCHOR_MASSES[0])
            for name in ("normal_forces", "G", "g0", "d_q", "d_qd"):
                a, b = (getattr(x, name) for x in anchors)
                np.testing.assert_allclose(getattr(now, name), a + w * (b - a), rtol=0,
                                           atol=1e-9 * max(1.0, np.abs(b).max()))
            stepped = est.stepped_suspension_forces(s, 1.0)
            np.testing.assert_array_equal(stepped[0], est.normal_forces(s))
            fast = est.payload_sensitivity(s)
            est._stepped = None  # the difference of two estimates instead
            np.testing.assert_allclose(fast, est.payload_sensitivity(s), rtol=0, atol=1e-9)


def test_machines_that_differ_in_the_payload_share_the_anchor_kernels():
    """Every scenario's payload gives the same anchor machines: no compile per payload."""
    prints = {tuple(m.fingerprint for m in anchor_machines(build_reference_machine(mass)))
              for mass in (10.0, 77.7, 150.0, 231.4, 300.0)}
    assert len(prints) == 1
    a, b = anchor_machines(MACHINE)
    masses = [next(x for x in m.bodies if x.name == m.payload).inertia.mass for m in (a, b)]
    assert masses == list(ANCHOR_MASSES)
    # The estimators of two scenarios use the very same kernels, and each starts at its
    # machine's own payload.
    e1 = PayloadEstimator(build_reference_machine(10.0), strokes="clip")
    e2 = PayloadEstimator(build_reference_machine(231.4), strokes="clip")
    assert e1._est._kernels is e2._est._kernels
    assert (e1.payload_mass, e2.payload_mass) == (10.0, 231.4)


def test_the_kernels_are_loaded_when_it_is_built(monkeypatch):
    """A controller's first tick does not generate or load kernels."""
    monkeypatch.setattr(Kernels, "_registry", {})  # this process's loaded kernels forgotten
    lazy = NormalForceEstimator(MACHINE, strokes="clip")
    assert set(lazy._kernels._kernels) != set(lazy._kernels.functions)  # loaded on first use
    lazy.warm()
    assert set(lazy._kernels._kernels) == set(lazy._kernels.functions)
    monkeypatch.setattr(Kernels, "_registry", {})
    est = PayloadEstimator(build_reference_machine(42.0), strokes="clip")
    assert set(est._est._kernels._kernels) == set(est._est._kernels.functions)


def test_stacked_rows_give_the_fields_of_each_linearization():
    """`RowFields.stacked` slices one stack of kernel rows: each node's fields are its
    linearization's, bit for bit, and the same as stacking the fields one by one."""
    from testkit.plant import make_state

    machine = build_reference_machine()
    est = PayloadEstimator(machine)
    home = machine.coordinates.home()
    lins = [est.linearize(make_state(machine, q=home + dq)) for dq in (0.0, 0.01, -0.02)]
    which = np.array([0, 0, 1, 2, 2, 1])
    names = ("G", "d_q", "d_qd", "g0", "normal_forces")
    fast = ForceLinearization.stacked(lins, which, names)
    plain = ForceLinearization.stacked([*lins[:2], _copied(lins[2])], which, names)
    for name, a, b in zip(names, fast, plain):
        assert np.array_equal(a, b), name
        for k, i in enumerate(which):
            assert np.array_equal(a[k], getattr(lins[i], name)), name
    fast[0][:] = 0.0  # writable, and apart from the other fields
    assert np.array_equal(fast[1][0], lins[0].d_q)


def _copied(lin):
    """The same linearization made by the public constructor (no kernel row)."""
    return ForceLinearization(lin.normal_forces, lin.G, lin.g0, lin.d_q, lin.d_qd,
                              lin.in_contact, lin.mode, lin.clipped, lin.time)


@pytest.mark.parametrize("fourth", ["d-beta", "cylinder-force"])
def test_forces_after_a_linearization_are_the_estimates_bits(fourth):
    """`normal_forces` after `linearize` (or the stepped pack) of the same state reads the
    forces those made: the estimate kernel's bits, also with a wheel in the air."""
    est = PayloadEstimator(MACHINE, fourth=fourth, strokes="clip")
    fresh = NormalForceEstimator(anchor_machines(MACHINE)[0], fourth=fourth, strokes="clip")
    rng = np.random.default_rng(11)
    reused = 0
    for k in range(24):
        s = replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                    suspension_force=rng.uniform(2e4, 6e4, 2))
        if k % 3 == 1:  # a rear wheel lifted: the three-wheel system
            flags = np.array([True, k % 2 == 0, True, k % 2 == 1])
            points = fresh.estimate(s).contact_points  # the wheels' lowest points
            s = replace(s, contacts=WheelContacts(flags, np.zeros((4, 3)), points,
                                                  np.tile(s.base_rotation[2], (4, 1))))
        est.payload_mass = fresh.payload_mass = float(rng.uniform(0.0, 300.0))
        if k % 2:
            est.linearize(s)
        else:
            est.stepped_suspension_forces(s, 1.0)
        f = est.normal_forces(s)
        reused += est._kept == () or est._kept[0][0] is not s  # not from an estimate
        assert f.tolist() == fresh.estimate(s).normal_forces.tolist()
        assert not f.flags.writeable
    assert reused == 24


def test_a_batch_evaluates_each_row_at_its_own_payload():
    """`normal_forces_batch`: each row's mass a kernel input, the single estimates' bits;
    a mass out of range or of the wrong count is refused, naming it."""
    from estimators.batch import as_batch

    est = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    rng = np.random.default_rng(12)
    states = [replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                      suspension_force=rng.uniform(2e4, 6e4, 2)) for _ in range(7)]
    masses = rng.uniform(0.0, 400.0, len(states))
    forces = est.normal_forces_batch(as_batch(states), masses)
    for s, m, f in zip(states, masses, forces):
        est.payload_mass = float(m)
        assert f.tolist() == est.estimate(s).normal_forces.tolist()
    with pytest.raises(EstimatorError, match=r"payload_mass\[2\]"):
        est.normal_forces_batch(as_batch(states), np.where(np.arange(7) == 2, -1.0, masses))
    with pytest.raises(EstimatorError, match="one mass per state"):
        est.normal_forces_batch(as_batch(states), masses[:3])


def test_the_observers_once_paths_give_the_estimates_bits_and_keep_nothing():
    """`contact_points` and `normal_forces_once` (the observer's states, asked once) are the
    estimate's fields to the bit without an `Estimate` or its cache, in every contact mode
    (tipping through the estimate); a clipped state is counted once, as by `estimate`."""
    est = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    ref = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    rng = np.random.default_rng(11)
    for k in range(8):
        s = replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                    suspension_force=rng.uniform(2e4, 6e4, 2))
        if k % 4:  # four, three (one out) and two wheels (tipping) in contact
            flags = np.ones(4, bool)
            flags[:k % 4 - 1] = False
            points = ref.estimate(s).contact_points
            s = replace(s, contacts=WheelContacts(flags, np.zeros((4, 3)), points,
                                                  np.tile(s.base_rotation[2], (4, 1))))
        if k == 5:  # a stroke past its end: clipped
            q = s.q.copy()
            q[0] = MACHINE.coordinates.upper[0] + 0.01
            s = replace(s, q=q)
        n = est.n_clipped
        want = ref.estimate(s)
        assert est.contact_points(s).tobytes() == want.contact_points.tobytes()
        forces = est.normal_forces_once(s)
        assert forces.tobytes() == want.normal_forces.tobytes()
        assert forces.flags.writeable == (k % 4 == 3)  # read-only but a tipping estimate's
        assert est.n_clipped - n == 2 * (k == 5)
        assert est._kept == ()
