"""The link accelerometers' fit in C (`fusion_c`) against its numpy code, on random inputs."""

import numpy as np
import pytest

from estimators.efforts import ActuatorEfforts
from estimators.observer.fusion_c import compiled_fusion
from estimators.observer.link_fusion import AXES, LinkFusion
from models import build_reference_machine
from models.sensing import Samples
from models.sensor_suites import sensor_suite
from testkit.estimator_states import random_state

pytestmark = pytest.mark.skipif(compiled_fusion() is None, reason="no C compiler")


def test_link_fusion_in_c_is_the_numpy_fit():
    """Random states and readings (1 to 5 samples a tick, about the predicted specific
    forces, so the fit moves the axes by a fair amount); fitted accelerations and their std
    to round-off, and the fit's buffers left alone when a tick is skipped."""
    machine = build_reference_machine()
    efforts = ActuatorEfforts(machine)
    spec = sensor_suite("realistic", 0)
    prior = np.linspace(0.03, 0.3, 9)
    fc = LinkFusion(efforts, spec.link_accelerometers, 0.05, prior)
    fp = LinkFusion(efforts, spec.link_accelerometers, 0.05, prior, compiled=False)
    assert fc._c is not None and fp._c is None
    rng = np.random.default_rng(3)
    moved = 0.0
    for k in range(200):
        state = random_state(machine, rng)
        a, b = efforts.point_specific_forces(state, fc._mounts)
        n = 1 + k % 5
        value = (a @ state.qdd[:9] + b + rng.normal(scale=2.0, size=(n, a.shape[0])))
        readings = Samples(0.001 * np.arange(n), value)
        qc, qp = fc.accelerations(state, readings), fp.accelerations(state, readings)
        np.testing.assert_allclose(qc, qp, rtol=1e-10, atol=1e-12, err_msg=f"tick {k}")
        np.testing.assert_allclose(fc.std, fp.std, rtol=1e-10, err_msg=f"tick {k}")
        np.testing.assert_array_equal(np.delete(qc, AXES), state.qdd[np.delete(np.arange(13),
                                                                               AXES)])
        moved = max(moved, float(np.abs(qp - state.qdd).max()))
    assert moved > 0.1  # the fit did move the crane's axes
    empty = Samples(np.zeros(0), np.zeros((0, 3 * len(spec.link_accelerometers))))
    np.testing.assert_array_equal(fc.accelerations(state, empty), state.qdd)


def test_the_tick_means_in_c_are_numpys_bits():
    """`link_mean` (the readings' tick means) against numpy's reduction, bit for bit, over
    1 to 40 samples (past the samples buffer: rebound), and NaN / inf refused as there."""
    machine = build_reference_machine()
    spec = sensor_suite("realistic", 0)
    fc = LinkFusion(ActuatorEfforts(machine), spec.link_accelerometers, 0.05,
                    np.linspace(0.03, 0.3, 9))
    rng = np.random.default_rng(5)
    m = fc._mean.size
    for n in [*range(1, 41), 3, 7]:
        value = rng.normal(scale=10.0 ** rng.uniform(-2, 3), size=(n, m))
        assert fc._tick_mean(value, n)
        assert fc._mean.tobytes() == (np.add.reduce(value, 0) / n).tobytes()
    assert fc._samples.shape[0] >= 40
    for bad in (np.nan, np.inf):
        value = rng.normal(size=(4, m))
        value[2, m - 1] = bad
        assert not fc._tick_mean(value, 4)


def test_observer_in_c_is_the_python_observer():
    """The whole observer, its C parts (`filters_c`, `fusion_c`) against Python and numpy,
    on the swing test's readings (realistic sensors, the crane and the wheels moving):
    every estimate to round-off, tick after tick."""
    from estimators.observer import Observer
    from estimators.payload import PayloadEstimator
    from tests.test_link_accelerometers import _swinging

    spec = sensor_suite("realistic", 1)
    obs = None
    for k, (machine, _, readings) in enumerate(_swinging(spec, ticks=150)):
        if obs is None:
            obs = [Observer(machine, spec, PayloadEstimator(machine, fourth="cylinder-force",
                                                            strokes="clip"), compiled=c)
                   for c in (True, False)]
            assert obs[0].links._c is not None and obs[1].links._c is None
        ec, ep = (o.update(readings) for o in obs)
        for name in ("base_rotation", "base_twist", "base_acceleration", "q", "qd", "qdd",
                     "suspension_force"):
            a, b = getattr(ec.state, name), getattr(ep.state, name)
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max(),
                                       err_msg=f"{name} at tick {k}")
        np.testing.assert_allclose(ec.forces_four, ep.forces_four, rtol=1e-9)
        np.testing.assert_allclose(ec.state.contacts.force_in_fb, ep.state.contacts.force_in_fb,
                                   rtol=1e-9, atol=1e-6)
        np.testing.assert_array_equal(ec.state.contacts.in_contact, ep.state.contacts.in_contact)
        assert abs(ec.payload_mass - ep.payload_mass) <= 1e-9 * abs(ep.payload_mass)
