"""The closed loop's per-tick parts outside the controller, made cheaper: the same values.

The simulator's wheel command clipped on Python floats (numpy's ``minimum(maximum(...))``
choices), its setpoint handed to a reading with one copy, its measured arrays read in place
by the truth's row; the margin pass's uncertainty copied only when it is new."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from estimators.payload import PayloadEstimator
from estimators.uncertainty import (
    StateUncertainty,
    _compiled_margin,
    _margin_pass,
    closure_margin,
    numpy_closure_margin,
)
from models import StateError, build_reference_machine
from models import terrain as T
from models.sensor_suites import sensor_suite
from scenarios.commands import ActuatorCommand
from scenarios.sensors import SensorSimulator
from scenarios.simulator import Simulator
from testkit.estimator_states import random_state

MACHINE = build_reference_machine()


@pytest.fixture(scope="module")
def sim():
    return Simulator(MACHINE, T.flat())


def test_the_wheel_command_is_numpys_clip(sim):
    lo, hi = sim._wheel_range
    edges = [0.0, -0.0, lo[0], hi[0], np.nextafter(hi[0], 0.0), np.nextafter(lo[0], 0.0),
             2.0 * hi[0], 2.0 * lo[0], 0.3, -0.7]
    for left in edges:
        for right in edges[::-1]:
            sim.apply(ActuatorCommand(np.zeros(6), np.zeros(3), [left, right]))
            got = sim.data.ctrl[sim._wheel_ctrl]
            want = np.minimum(np.maximum(np.array((left, left, right, right)), lo), hi)
            assert got.tobytes() == want.tobytes(), (left, right)


def test_the_setpoint_and_the_measured_arrays_are_the_simulators(sim):
    sim.apply(ActuatorCommand([0.0, 0.0, 0.1, 0.02, -0.02, 0.01], np.zeros(3), [0.5, 0.5]))
    sim.step(5)
    qpos, qvel, t, setpoint = sim.measured_arrays()
    q2, v2, t2 = sim.measured_instant
    assert (qpos.tobytes(), qvel.tobytes(), t, setpoint.tobytes()) == (
        q2.tobytes(), v2.tobytes(), t2, sim.servo_setpoint.tobytes())
    sensors = SensorSimulator(sim, sensor_suite("realistic", 1))
    sim.step(5)
    r = sensors.readings(sim.time)
    assert not r.servo_setpoint.flags.writeable
    assert r.servo_setpoint.tobytes() == sim.servo_setpoint.tobytes()
    kept = sim._snapshot_setpoint
    sim._snapshot_setpoint = np.full(9, np.nan)
    try:
        with pytest.raises(StateError):
            sensors.readings(sim.time + 0.01)
    finally:
        sim._snapshot_setpoint = kept
        sensors.close()




@pytest.mark.skipif(_compiled_margin() is None, reason="no C compiler")
def test_the_margin_pass_copies_a_new_uncertainty_only():
    """The same uncertainty object tick after tick (the observer's arrays), another one
    between, and arrays that can change (writable, written between calls): numpy's bits."""
    closure = PayloadEstimator(MACHINE, fourth="cylinder-force", strokes="clip")
    model = PayloadEstimator(MACHINE, fourth="d-beta", strokes="clip")
    rng = np.random.default_rng(5)
    kept = StateUncertainty(rng.uniform(0.0, 0.1, 19), rng.uniform(0.0, 0.02, 13),
                            rng.uniform(0.0, 500.0, 2), 20.0)
    loose = SimpleNamespace(acceleration=rng.uniform(0.0, 0.1, 19),
                            qd=rng.uniform(0.0, 0.02, 13),
                            suspension_force=rng.uniform(0.0, 500.0, 2), payload_mass=5.0)
    for k in range(12):
        s = replace(random_state(MACHINE, rng, max_tilt=0.3, speed=0.5),
                    suspension_force=rng.uniform(2e4, 6e4, 2))
        unc = loose if k % 4 == 3 else (kept if k % 4 else kept.with_payload_mass(30.0 + k))
        loose.acceleration *= 1.5  # written in place: must be read again
        loose.suspension_force[k % 2] += 10.0
        fast = closure_margin(closure, model, s, unc, 0.99)
        ref = unc if unc is not loose else StateUncertainty(
            loose.acceleration, loose.qd, loose.suspension_force, loose.payload_mass)
        assert fast.tobytes() == numpy_closure_margin(closure, model, s, ref, 0.99).tobytes(), k
    assert _margin_pass()._sigmas is None  # the last one (loose) is not kept


def test_the_damping_parts_are_the_full_ones():
    """The simulator's damping update (`DampingSchedule`): each chain's ``(k1, k2)`` alone
    are `driven_terms`' (in the range, past it, at a flat triangle's division by zero),
    and the wrapper-free inverse's free inertia is `free_inertia`'s, or its error."""
    import warnings

    from models.mujoco.servos import _free_inertia, free_inertia

    coords = MACHINE.coordinates
    for i in coords.chain_indices:
        chain = coords.binding(i).chain
        lo, hi = chain.stroke_range
        la, lb = chain.side_lengths
        flat = abs(la - lb) - chain._consts["lx0"]  # lx = |la - lb|: sin(q) = 0
        for x in [*np.linspace(lo, hi, 23), lo - 0.3, hi + 0.3, flat, np.float64(hi)]:
            with np.errstate(divide="ignore", invalid="ignore"):
                got, want = chain.driven_rates(x), chain.driven_terms(x)[2:4]
            assert repr(got) == repr(want), (chain.name, x)
    rng = np.random.default_rng(2)
    for _ in range(20):
        a = rng.standard_normal((19, 19)) * 10.0 ** rng.uniform(-2, 3, (19, 19))
        a = a @ a.T + np.eye(19)
        assert _free_inertia(a).tobytes() == free_inertia(a).tobytes()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(np.linalg.LinAlgError):
            _free_inertia(np.zeros((19, 19)))
